//! The embedded surface's deformation on the device (`deform.wgsl`): each vertex slot is the
//! weighted sum of its embedding's node positions. The embeddings stay on the device; a cut
//! sends only the slots it changed.

use crate::buffers::{Mirrored, Words, f, packed, uniform, unpacked};
use crate::context::Gpu;
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;

const SOURCE: &str = concat!(include_str!("embedded.wgsl"), include_str!("deform.wgsl"));
/// Words per embedding: 8 node ids, 8 weights.
const STRIDE: usize = 16;

/// The surface's embeddings and deformed vertices on the device.
pub struct Deform {
    pipeline: wgpu::ComputePipeline,
    nodes: Words,
    embeddings: Mirrored,
    vertices: Words,
    node_count: usize,
}

/// An embedding's words.
pub(crate) fn words(e: &EmbeddedPoint) -> [u32; STRIDE] {
    let mut w = [0u32; STRIDE];
    for k in 0..8 {
        // A zero weight names no node: node 0 keeps the kernel's reads in range.
        let used = e.weights[k] != 0.0;
        w[k] = if used { e.nodes[k] } else { 0 };
        w[8 + k] = if used { f(e.weights[k]) } else { 0 };
    }
    w
}

impl Deform {
    /// An empty surface.
    #[must_use]
    pub fn new(gpu: &Gpu) -> Self {
        Self {
            pipeline: gpu.pipeline(SOURCE, "deform"),
            nodes: Words::new(gpu, "nodes", 3),
            embeddings: Mirrored::new(gpu, "embeddings", STRIDE),
            vertices: Words::new(gpu, "vertices", 3),
            node_count: 0,
        }
    }

    /// Makes the device's embeddings `embeddings` (one per vertex slot, naming nodes
    /// `0..node_count`); returns how many slots were sent. Only slots that differ from what the
    /// device holds are sent, in runs of consecutive slots.
    ///
    /// # Panics
    /// If an embedding names a node at or past `node_count` with a non-zero weight.
    pub fn set_embeddings(
        &mut self,
        gpu: &Gpu,
        embeddings: &[EmbeddedPoint],
        node_count: usize,
    ) -> usize {
        for e in embeddings {
            for k in 0..8 {
                assert!(
                    e.weights[k] == 0.0 || (e.nodes[k] as usize) < node_count,
                    "an embedding names node {} of {node_count}",
                    e.nodes[k]
                );
            }
        }
        self.node_count = node_count;
        self.vertices.reserve(gpu, 3 * embeddings.len());
        self.embeddings.set(gpu, embeddings.iter().flat_map(words).collect())
    }

    /// Vertex slots.
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.embeddings.len()
    }

    /// Sends `nodes` (at least the embeddings' node count) and deforms every slot on the
    /// device.
    ///
    /// # Panics
    /// If fewer nodes are given than the embeddings name.
    pub fn run(&mut self, gpu: &Gpu, nodes: &[Vec3]) {
        assert!(
            nodes.len() >= self.node_count,
            "{} nodes for embeddings over {}",
            nodes.len(),
            self.node_count
        );
        self.nodes.reserve(gpu, 3 * nodes.len());
        self.nodes.write(gpu, 0, &packed(nodes));
        let count = self.vertex_count();
        if count == 0 {
            return;
        }
        let params = uniform(gpu, "deform params", &[count as u32, 0, 0, 0]);
        let bind = gpu.bind(
            &self.pipeline,
            &[&params, self.nodes.buffer(), self.embeddings.buffer(), self.vertices.buffer()],
        );
        gpu.dispatch(&self.pipeline, &bind, count);
    }

    /// The deformed vertex slots, read back.
    #[must_use]
    pub fn vertices(&self, gpu: &Gpu) -> Vec<Vec3> {
        unpacked(&gpu.read(self.vertices.buffer(), 3 * self.vertex_count()))
    }

    /// The deformed vertices' buffer (packed `f32` triples), for the passes that read them.
    pub(crate) fn vertex_buffer(&self) -> &wgpu::Buffer {
        self.vertices.buffer()
    }
}
