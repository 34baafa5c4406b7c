//! The device behind volume contact: the surface's embeddings, its groups' triangles and its
//! deformed vertices kept on the GPU between frames, and the overlap passes run there.

use crate::buffers::Words;
use crate::context::{Gpu, GpuChoice, GpuError};
use crate::deform::Deform;
use crate::ldi::{Ldi, Triangles};
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;
use incise_tool::volume_contact::{ContactDevice, OverlapInterval};

/// Volume contact's passes on a GPU.
pub struct GpuContact {
    gpu: Gpu,
    deform: Deform,
    ldi: Ldi,
    /// Each surface group's triangles, on the device and on the CPU.
    groups: Vec<Option<(Words, Vec<[u32; 3]>)>>,
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
        Self { gpu, deform, ldi, groups: Vec::new() }
    }

    /// The device.
    #[must_use]
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }
}

impl ContactDevice for GpuContact {
    fn name(&self) -> String {
        self.gpu.name()
    }

    fn set_embeddings(&mut self, embeddings: &[EmbeddedPoint], node_count: usize) {
        self.deform.set_embeddings(&self.gpu, embeddings, node_count);
    }

    fn set_triangles(&mut self, group: u16, triangles: &[[u32; 3]]) {
        let g = usize::from(group);
        if self.groups.len() <= g {
            self.groups.resize_with(g + 1, || None);
        }
        let words: Vec<u32> = triangles.iter().flatten().copied().collect();
        let slot = self.groups[g]
            .get_or_insert_with(|| (Words::new(&self.gpu, "triangles", words.len()), Vec::new()));
        slot.0.reserve(&self.gpu, words.len());
        slot.0.write(&self.gpu, 0, &words);
        slot.1 = triangles.to_vec();
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
        let side = |g: u16| {
            self.groups.get(usize::from(g)).and_then(Option::as_ref).map(|(buffer, triangles)| {
                Triangles { buffer: buffer.buffer(), triangles: triangles.as_slice() }
            })
        };
        let Some(first) = side(a) else { return Some(Vec::new()) };
        let second = match b {
            Some(b) => match side(b) {
                Some(s) => Some(s),
                None => return Some(Vec::new()),
            },
            None => None,
        };
        if first.triangles.is_empty() || second.is_some_and(|s| s.triangles.is_empty()) {
            return Some(Vec::new());
        }
        self.ldi.overlap_intervals(
            &self.gpu,
            self.deform.vertex_buffer(),
            first,
            second,
            region,
            resolution,
        )
    }
}
