//! Label volumes and the Dynamic Branched Grid (Jeřábková 2010, §2).
//!
//! A segmented image becomes fine voxels carrying tissue labels; coarse hexahedral elements group
//! `2^l × 2^l × 2^l` voxels, branch into superimposed elements where the material inside a cell is
//! disconnected, and get their stiffness and mass by direct condensation of the voxels they own.
//! Cutting removes voxels or severs links and updates all of it incrementally.

pub mod canonical;
pub mod composite;
pub mod condense;
pub mod error;
pub mod grid;
pub mod hex8;
pub mod incompatible;
pub mod material;
pub mod procedural;
mod schur;
pub mod topology;
pub mod volume;

pub use error::{EditError, VolumeError};
pub use grid::{Block, BranchedGrid, ElementMatrices, GridChanges, GridEdit, LevelSummary};
pub use material::{LabelFilter, Material, MaterialTable};
pub use topology::{Element, Level, LevelChanges, Node};
pub use volume::LabelVolume;
