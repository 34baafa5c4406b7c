//! Layered depth images and their overlap intervals on the device (`ldi.wgsl`): the three views
//! over a region, rasterised from the deformed vertices already on the device, and the intervals
//! of each pixel's ray where two surfaces overlap (or one overlaps itself), read back for the
//! CPU to sum into regions.

use crate::buffers::{Words, f, groups, uniform};
use crate::context::Gpu;
use incise_math::Vec3;
use incise_tool::volume_contact::{OverlapInterval, Side, View};

const SOURCE: &str = include_str!("ldi.wgsl");
/// Fragments a pixel keeps per surface (`CAP` in the shader).
pub const CAPACITY: usize = 16;
const FRAGMENT: usize = 5;
const INTERVAL: usize = 12;

/// The passes' pipelines and their scratch buffers (grown as views grow).
pub struct Ldi {
    raster: wgpu::ComputePipeline,
    intervals: wgpu::ComputePipeline,
    counts: Words,
    fragments: Words,
    out: Words,
    status: Words,
}

/// The triangle slots on the device: three vertex slots and a group per slot (`u32::MAX` for a
/// free slot), as [`crate::GpuContact`] keeps them.
#[derive(Clone, Copy)]
pub struct Slots<'a> {
    /// The slots' words on the device.
    pub buffer: &'a wgpu::Buffer,
    /// Slots.
    pub count: usize,
    /// Slot `t`'s vertex slots (the intervals name slots; their vertices come from here).
    pub vertices: &'a dyn Fn(u32) -> [u32; 3],
}

impl Ldi {
    /// The pipelines.
    #[must_use]
    pub fn new(gpu: &Gpu) -> Self {
        Self {
            raster: gpu.pipeline(SOURCE, "raster"),
            intervals: gpu.pipeline(SOURCE, "intervals_of_pixels"),
            counts: Words::new(gpu, "ldi counts", 2),
            fragments: Words::new(gpu, "ldi fragments", FRAGMENT),
            out: Words::new(gpu, "ldi intervals", INTERVAL),
            status: Words::new(gpu, "ldi status", 2),
        }
    }

    /// The overlap intervals of the triangles of group `a` and those of group `b` (of `a`
    /// with itself, two layers deep, when `b` is `None`) in the views of `resolution` pixels per
    /// side over `region`, from the deformed vertices in `vertices`; sorted as the CPU's passes
    /// give them (by view, pixel row and column, depth). `None` when a pixel had more crossings
    /// than the device keeps, there were more intervals than it has room for, or a view's
    /// buffers would pass the device's limit.
    #[allow(clippy::too_many_arguments)]
    pub fn overlap_intervals(
        &mut self,
        gpu: &Gpu,
        vertices: &wgpu::Buffer,
        slots: Slots<'_>,
        a: u16,
        b: Option<u16>,
        (lo, hi): (Vec3, Vec3),
        resolution: usize,
    ) -> Option<Vec<OverlapInterval>> {
        if (0..3).any(|k| lo[k].partial_cmp(&hi[k]) != Some(std::cmp::Ordering::Less)) {
            return Some(Vec::new());
        }
        let n = resolution.max(1);
        let pixels = n * n;
        let max_intervals = 3 * pixels;
        let fragment_words = 2 * pixels * CAPACITY * FRAGMENT;
        if (fragment_words * 4) as u64 > gpu.max_binding()
            || (max_intervals * INTERVAL * 4) as u64 > gpu.max_binding()
        {
            return None;
        }
        self.counts.reserve(gpu, 2 * pixels);
        self.fragments.reserve(gpu, fragment_words);
        self.out.reserve(gpu, max_intervals * INTERVAL);
        let views: Vec<View> = (0..3).map(|axis| View::covering(axis, lo, hi, n)).collect();
        let mut encoder =
            gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        encoder.clear_buffer(self.status.buffer(), 0, None);
        let mut binds = Vec::new();
        for view in &views {
            let params = uniform(
                gpu,
                "ldi view",
                &[
                    f(view.origin[0]),
                    f(view.origin[1]),
                    f(view.pixel[0]),
                    f(view.pixel[1]),
                    n as u32,
                    n as u32,
                    view.axis as u32,
                    if b.is_some() { 1 } else { 2 },
                    slots.count as u32,
                    u32::from(a),
                    b.map_or(u32::MAX - 1, u32::from),
                    CAPACITY as u32,
                    max_intervals as u32,
                    u32::from(b.is_some()),
                    f(lo[view.axis]),
                    f(hi[view.axis]),
                ],
            );
            let (counts, fragments) = (self.counts.buffer(), self.fragments.buffer());
            let status = self.status.buffer();
            // Each entry point's layout holds the bindings it uses.
            let raster = gpu.bind_some(
                &self.raster,
                &[
                    (0, &params),
                    (1, vertices),
                    (2, slots.buffer),
                    (4, counts),
                    (5, fragments),
                    (7, status),
                ],
            );
            let intervals = gpu.bind_some(
                &self.intervals,
                &[(0, &params), (4, counts), (5, fragments), (6, self.out.buffer()), (7, status)],
            );
            binds.push((raster, intervals));
        }
        for (raster, intervals) in &binds {
            encoder.clear_buffer(self.counts.buffer(), 0, None);
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(&self.raster);
            pass.set_bind_group(0, raster, &[]);
            pass.dispatch_workgroups(groups(slots.count), 1, 1);
            pass.set_pipeline(&self.intervals);
            pass.set_bind_group(0, intervals, &[]);
            pass.dispatch_workgroups(groups(pixels), 1, 1);
        }
        gpu.queue.submit([encoder.finish()]);
        let status = gpu.read(self.status.buffer(), 2);
        if status[1] != 0 {
            return None;
        }
        let count = status[0] as usize;
        let words = gpu.read(self.out.buffer(), count * INTERVAL);
        let mut out: Vec<OverlapInterval> = words
            .chunks_exact(INTERVAL)
            .map(|w| {
                let flags = w[1];
                let axis = (flags >> 2 & 3) as usize;
                let view = &views[axis];
                let p = w[0] as usize;
                let bound = |side_bit: u32, tri: u32, at: usize| {
                    let side = if side_bit == 0 { Side::A } else { Side::B };
                    let weights = [0, 1, 2].map(|c| f64::from(f32::from_bits(w[at + c])));
                    (side, (slots.vertices)(tri), weights)
                };
                OverlapInterval {
                    axis,
                    pixel: [p % n, p / n],
                    area: view.pixel_area(),
                    depths: [f64::from(f32::from_bits(w[2])), f64::from(f32::from_bits(w[3]))],
                    bounds: [bound(flags & 1, w[4], 6), bound(flags >> 1 & 1, w[5], 9)],
                }
            })
            .collect();
        // The device appends intervals in whatever order its threads finish; the CPU's order
        // makes the sums over them the same on every run.
        out.sort_by(|x, y| {
            (x.axis, x.pixel[1], x.pixel[0])
                .cmp(&(y.axis, y.pixel[1], y.pixel[0]))
                .then(x.depths[0].total_cmp(&y.depths[0]))
        });
        Some(out)
    }
}
