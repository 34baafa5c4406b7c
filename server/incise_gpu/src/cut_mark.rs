//! Cut-voxel marking on the device (`cut_mark.wgsl`): of candidate voxels, each embedded like a
//! surface vertex (its centre a weighted sum of its element's nodes), those whose deformed
//! centres an analytic cutting shape holds.

use crate::buffers::{Words, f, packed, uniform};
use crate::context::Gpu;
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;
use incise_tool::{Pose, Primitive, Shape};

const SOURCE: &str = concat!(include_str!("embedded.wgsl"), include_str!("cut_mark.wgsl"));

/// The marking pass.
pub struct CutMark {
    pipeline: wgpu::ComputePipeline,
    nodes: Words,
    voxels: Words,
    marks: Words,
}

impl CutMark {
    /// The pipeline.
    #[must_use]
    pub fn new(gpu: &Gpu) -> Self {
        Self {
            pipeline: gpu.pipeline(SOURCE, "cut_mark"),
            nodes: Words::new(gpu, "cut nodes", 3),
            voxels: Words::new(gpu, "cut voxels", 16),
            marks: Words::new(gpu, "cut marks", 1),
        }
    }

    /// For each voxel of `centres` (embedded in `nodes`), whether `shape` at `pose` holds its
    /// deformed centre. `None` for a shape that is no analytic primitive (a mesh).
    pub fn run(
        &mut self,
        gpu: &Gpu,
        shape: &Shape,
        pose: &Pose,
        nodes: &[Vec3],
        centres: &[EmbeddedPoint],
    ) -> Option<Vec<bool>> {
        let (kind, size) = match shape.primitive()? {
            Primitive::Sphere { radius } => (0, [radius, 0.0, 0.0]),
            Primitive::Capsule { radius, length } => (1, [radius, length, 0.0]),
            Primitive::Cuboid { half_extents } => (2, half_extents),
            Primitive::Blade { length, height, thickness } => (3, [length, height, thickness]),
        };
        if centres.is_empty() {
            return Some(Vec::new());
        }
        let r = pose.matrix();
        let column = |c: usize| [f(r[0][c]), f(r[1][c]), f(r[2][c]), 0];
        let position = pose.position();
        let offset = shape.offset();
        let mut words: Vec<u32> = Vec::with_capacity(28);
        words.extend(column(0));
        words.extend(column(1));
        words.extend(column(2));
        words.extend([f(position[0]), f(position[1]), f(position[2]), 0]);
        words.extend([f(offset[0]), f(offset[1]), f(offset[2]), 0]);
        words.extend([f(size[0]), f(size[1]), f(size[2]), 0]);
        words.extend([kind, centres.len() as u32, 0, 0]);
        let params = uniform(gpu, "cut tool", &words);
        self.nodes.reserve(gpu, 3 * nodes.len());
        self.nodes.write(gpu, 0, &packed(nodes));
        let embedded: Vec<u32> = centres.iter().flat_map(crate::deform::words).collect();
        self.voxels.reserve(gpu, embedded.len());
        self.voxels.write(gpu, 0, &embedded);
        self.marks.reserve(gpu, centres.len());
        let bind = gpu.bind(
            &self.pipeline,
            &[&params, self.nodes.buffer(), self.voxels.buffer(), self.marks.buffer()],
        );
        gpu.dispatch(&self.pipeline, &bind, centres.len());
        Some(gpu.read(self.marks.buffer(), centres.len()).into_iter().map(|m| m != 0).collect())
    }
}
