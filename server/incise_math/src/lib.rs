//! Small numeric building blocks shared by the incise physics crates: SI aliases, Morton
//! (octree) indices, 3×3 kernels and rotation extraction for corotational elements.
//!
//! Everything here is pure and allocation-free so it can sit under every other crate.

pub mod lanes;
pub mod mat3;
pub mod morton;
pub mod rotation;
pub mod units;

pub use morton::{morton_decode, morton_encode};
pub use units::{Metres, Pascals, Real, Vec3};
