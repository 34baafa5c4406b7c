//! A scene built from a [`SceneConfig`] with only the parts it uses, stepped by
//! [`Simulation::step`] into [`Frame`]s.
//!
//! Pure: no file I/O. A scene whose volume is a file gets its [`incise_grid::LabelVolume`] from
//! the caller (`incise_io` reads it); procedural volumes are built here.

pub mod calibration;
pub mod config;
#[cfg(test)]
mod config_fuzz;
mod regions;
pub mod simulation;

pub use config::{SceneConfig, SceneError};
pub use simulation::{
    CutError, Frame, Geometry, InputError, Simulation, StageCounters, StepInputs,
};
