//! The device behind volume contact: the surface's embeddings, its triangle slots and its
//! deformed vertices kept on the GPU between frames, and the overlap passes run there; and the
//! marking of the voxels a cutting tool holds.

use crate::buffers::Mirrored;
use crate::context::{Gpu, GpuChoice, GpuError};
use crate::cut_mark::CutMark;
use crate::deform::Deform;
use crate::ldi::{Ldi, Slots};
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;
use incise_tool::volume_contact::{ContactDevice, OverlapInterval};
use incise_tool::{Pose, Shape};

/// Volume contact's passes on a GPU.
pub struct GpuContact {
    gpu: Gpu,
    deform: Deform,
    ldi: Ldi,
    /// Every triangle slot: three vertex slots and its group (`u32::MAX`: free).
    triangles: Mirrored,
    cut_mark: CutMark,
}

impl std::fmt::Debug for GpuContact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContact").field("gpu", &self.gpu).finish_non_exhaustive()
    }
}

impl GpuContact {
    /// The passes on the adapter `choice` takes.
    pub fn new(choice: GpuChoice) -> Result<Self, GpuError> {
        Ok(Self::on(Gpu::new(choice)?))
    }

    /// The passes on `gpu`.
    #[must_use]
    pub fn on(gpu: Gpu) -> Self {
        let deform = Deform::new(&gpu);
        let ldi = Ldi::new(&gpu);
        let triangles = Mirrored::new(&gpu, "triangles", 4);
        let cut_mark = CutMark::new(&gpu);
        Self { gpu, deform, ldi, triangles, cut_mark }
    }

    /// The device.
    #[must_use]
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Whether any live triangle slot is of group `g`.
    fn has_group(&self, g: u16) -> bool {
        (0..self.triangles.len()).any(|t| self.triangles.record(t)[3] == u32::from(g))
    }
}

impl ContactDevice for GpuContact {
    fn name(&self) -> String {
        self.gpu.name()
    }

    fn set_embeddings(&mut self, embeddings: &[EmbeddedPoint], node_count: usize) {
        self.deform.set_embeddings(&self.gpu, embeddings, node_count);
    }

    fn set_triangles(&mut self, slots: &[([u32; 3], Option<u16>)]) {
        let words = slots
            .iter()
            .flat_map(|(v, group)| [v[0], v[1], v[2], group.map_or(u32::MAX, u32::from)])
            .collect();
        self.triangles.set(&self.gpu, words);
    }

    fn deform(&mut self, nodes: &[Vec3]) {
        self.deform.run(&self.gpu, nodes);
    }

    fn vertices(&mut self) -> Vec<Vec3> {
        self.deform.vertices(&self.gpu)
    }

    fn overlap_intervals(
        &mut self,
        a: u16,
        b: Option<u16>,
        region: (Vec3, Vec3),
        resolution: usize,
    ) -> Option<Vec<OverlapInterval>> {
        if !self.has_group(a) || b.is_some_and(|b| !self.has_group(b)) {
            return Some(Vec::new());
        }
        let triangles = &self.triangles;
        let vertices = |t: u32| {
            let r = triangles.record(t as usize);
            [r[0], r[1], r[2]]
        };
        let slots =
            Slots { buffer: triangles.buffer(), count: triangles.len(), vertices: &vertices };
        self.ldi.overlap_intervals(
            &self.gpu,
            self.deform.vertex_buffer(),
            slots,
            a,
            b,
            region,
            resolution,
        )
    }

    fn cut_marks(
        &mut self,
        shape: &Shape,
        pose: &Pose,
        nodes: &[Vec3],
        centres: &[EmbeddedPoint],
    ) -> Option<Vec<bool>> {
        self.cut_mark.run(&self.gpu, shape, pose, nodes, centres)
    }
}
