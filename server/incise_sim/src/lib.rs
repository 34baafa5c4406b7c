//! A scene built from a [`SceneConfig`] with only the parts it uses, stepped by
//! [`Simulation::step`] into [`Frame`]s.
//!
//! A [`SceneConfig`] comes from a TOML scene file ([`SceneConfig::from_toml`], which names the key
//! and line of every error) or is written in Rust. Its types carry only what applies: a
//! [`config::Model`] is hexahedra on a label volume or tensor-mass tetrahedra (generated from a
//! volume or read from a mesh file), each with its own integrator, and each integrator has only
//! its own settings. So the decoder is the one place that checks a scene;
//! [`Simulation::new`] refuses only what needs the built model (an explicit step above the mesh's
//! stable step, a hold that holds nothing, a label or region without a material).
//!
//! Pure: no file I/O. The caller reads the scene's geometry (`incise_scene::read_scene` does, with
//! `incise_io`) and passes it as a [`Geometry`]: the label volume as read (the scene's label
//! merges, kept labels and stride are applied here) or the tetrahedral mesh as read (converted
//! from the scene's unit here); procedural volumes are built by
//! [`SceneConfig::procedural_volume`].
//!
//! ```
//! use incise_sim::{SceneConfig, Simulation, StepInputs};
//!
//! let text = r#"
//!     name = "block"
//!     [volume]
//!     procedural = "block"
//!     size_m = [0.1, 0.1, 0.1]
//!     voxels = [2, 2, 2]
//!     [[materials]]
//!     label = 1
//!     youngs_modulus = 3000.0
//!     poisson_ratio = 0.45
//!     density = 1000.0
//!     [integrator]
//!     kind = "implicit-euler"
//!     dt = 0.001
//!     [[fixed]]
//!     plane = "z"
//!     value = 0.1
//! "#;
//! let config = SceneConfig::from_toml(text, "block.toml")?;
//! let volume = config.procedural_volume().expect("a procedural block");
//! let mut sim = Simulation::new(&config, &volume, "block.toml")?;
//! let frame = sim.step(&StepInputs::default())?;
//! assert_eq!(frame.index, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod calibration;
pub mod config;
#[cfg(test)]
mod config_fuzz;
mod regions;
pub mod simulation;

pub use config::{SceneConfig, SceneError};
pub use simulation::{
    CutError, CutEvent, Frame, Geometry, InputError, KEYFRAME_INTERVAL_S, Keyframe, KeyframeError,
    OrganSurface, Simulation, StageCounters, StepInputs, SurfaceGeometry, SurgicalFrame, ToolFrame,
    ToolInput, ToolState,
};
