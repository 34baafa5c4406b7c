//! Small numeric building blocks shared by the incise physics crates: SI aliases and Morton
//! (octree) indices.
//!
//! Everything here is pure and allocation-free so it can sit under every other crate.

pub mod morton;
pub mod units;

pub use morton::{morton_decode, morton_encode};
pub use units::{Metres, Pascals, Real, Vec3};
