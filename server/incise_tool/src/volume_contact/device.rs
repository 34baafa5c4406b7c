//! The seam between volume contact and a device that runs its per-frame passes (a GPU through
//! `incise_gpu`): the surface's deformation and the layered depth images. The physics crates
//! name only this trait; the device's crate implements it, and a scene that asks for one gets
//! it through `incise_sim`'s `gpu` feature.
//!
//! What stays on the device between frames: the embedding of every surface vertex slot, every
//! triangle slot with its group, and the deformed vertices. What goes to it: node positions every
//! frame; embeddings and triangles only where a cut changed them. What comes back: the overlap
//! intervals, which the CPU sums into regions ([`super::regions_of`]), the same as for its own
//! passes.
//!
//! The same device marks which voxels a cutting tool holds ([`ContactDevice::cut_marks`]):
//! paper 1 §4.1 finds the cut voxels on the GPU, beside the contact, from the node positions
//! the contact sends anyway.

use super::regions::OverlapInterval;
use crate::{Pose, Shape};
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;

/// A device for volume contact's passes.
pub trait ContactDevice: Send {
    /// The adapter's name and kind, for logs and reports.
    fn name(&self) -> String;

    /// Makes the device's embeddings those of `embeddings` (one per vertex slot, over node ids
    /// `0..node_count`), sending only the slots that differ from what it holds.
    fn set_embeddings(&mut self, embeddings: &[EmbeddedPoint], node_count: usize);

    /// Makes the device's triangles `slots`: each slot's vertex slots and surface group, `None`
    /// for a free slot. Only slots that differ from what it holds are sent (a cut frees and
    /// fills a few dozen).
    fn set_triangles(&mut self, slots: &[([u32; 3], Option<u16>)]);

    /// Sends the node positions and deforms every vertex slot on the device.
    fn deform(&mut self, nodes: &[Vec3]);

    /// The deformed vertex slots, read back (a check's; the passes read them on the device).
    fn vertices(&mut self) -> Vec<Vec3>;

    /// The overlap intervals of groups `a` and `b` (or of `a` with itself, where at least two
    /// of its layers overlap, when `b` is `None`) in views of `resolution` pixels per side over
    /// `region`, sorted by view, pixel row and column, and depth, as the CPU's
    /// [`super::overlap_intervals`] and [`super::self_overlap_intervals`] give them for each
    /// group's live triangles in slot order. `None`
    /// when the pass did not fit the device's buffers (a ray with more crossings than it keeps):
    /// the caller runs the CPU's pass instead.
    fn overlap_intervals(
        &mut self,
        a: u16,
        b: Option<u16>,
        region: (Vec3, Vec3),
        resolution: usize,
    ) -> Option<Vec<OverlapInterval>>;

    /// For each point of `centres` (embedded in `nodes`), whether `shape` at `pose` holds it
    /// strictly inside (`Shape::distance` < 0, in the device's `f32`). `None` when the device
    /// does not mark this shape (a mesh): the caller tests the points on the CPU.
    fn cut_marks(
        &mut self,
        shape: &Shape,
        pose: &Pose,
        nodes: &[Vec3],
        centres: &[EmbeddedPoint],
    ) -> Option<Vec<bool>>;
}
