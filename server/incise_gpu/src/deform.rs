//! The embedded surface's deformation on the device (`deform.wgsl`): each vertex slot is the
//! weighted sum of its embedding's node positions. The embeddings stay on the device; a cut
//! sends only the slots it changed.

use crate::buffers::{Words, f, packed, uniform, unpacked};
use crate::context::Gpu;
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;

const SOURCE: &str = include_str!("deform.wgsl");
/// Words per embedding: 8 node ids, 8 weights.
const STRIDE: usize = 16;

/// The surface's embeddings and deformed vertices on the device.
pub struct Deform {
    pipeline: wgpu::ComputePipeline,
    nodes: Words,
    embeddings: Words,
    vertices: Words,
    /// What the device holds, word for word (a cut's changes are found against it).
    shadow: Vec<u32>,
    node_count: usize,
}

/// An embedding's words.
fn words(e: &EmbeddedPoint) -> [u32; STRIDE] {
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
            embeddings: Words::new(gpu, "embeddings", STRIDE),
            vertices: Words::new(gpu, "vertices", 3),
            shadow: Vec::new(),
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
        let new: Vec<u32> = embeddings.iter().flat_map(words).collect();
        let replaced = self.embeddings.reserve(gpu, new.len());
        self.vertices.reserve(gpu, 3 * embeddings.len());
        let mut sent = 0;
        let mut slot = 0;
        let count = embeddings.len();
        while slot < count {
            let same = |s: usize| {
                !replaced
                    && self.shadow.get(s * STRIDE..(s + 1) * STRIDE)
                        == Some(&new[s * STRIDE..(s + 1) * STRIDE])
            };
            if same(slot) {
                slot += 1;
                continue;
            }
            let start = slot;
            while slot < count && !same(slot) {
                slot += 1;
            }
            self.embeddings.write(gpu, start * STRIDE, &new[start * STRIDE..slot * STRIDE]);
            sent += slot - start;
        }
        self.shadow = new;
        sent
    }

    /// Vertex slots.
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.shadow.len() / STRIDE
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
