//! Volume contact's per-frame passes on a GPU, through wgpu compute shaders (paper 1 §4.1: the
//! surface and its layered depth images live on the GPU, and the transfers between CPU and GPU
//! are what to keep small).
//!
//! Each kernel is a `name.rs` with its `name.wgsl`, and has a CPU twin in the pure crates that
//! its parity test compares it with (`tests/parity.rs`, on whatever adapter the machine has: a
//! software one, lavapipe, in CI):
//!
//! - [`deform`]: the embedded surface's vertices as weighted sums of node positions
//!   (`incise_surface::SurfaceMapping::deformed`);
//! - [`ldi`]: layered depth images of two surfaces (or one) along an axis, and the intervals
//!   of each pixel's ray where they overlap (`incise_tool::volume_contact::overlap_intervals`);
//! - [`cut_mark`]: which voxels' deformed centres lie inside a tool's cutting shape
//!   (`incise_tool::Shape::distance`).
//!
//! [`GpuContact`] strings the first two together as an
//! `incise_tool::volume_contact::ContactDevice`: node positions go up every frame, embeddings
//! and triangles only where a cut changed them, the overlap intervals come back, and the CPU
//! sums them into regions exactly as it does its own.
//!
//! Everything on the device is `f32`; the physics stays `f64` on the CPU. The parity tests state
//! how far the two may differ and why.

mod buffers;
mod contact;
mod context;
pub mod cut_mark;
pub mod deform;
pub mod ldi;

pub use contact::GpuContact;
pub use context::{Gpu, GpuChoice, GpuError};
