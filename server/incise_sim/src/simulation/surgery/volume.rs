//! Volume contact in the step (Faure et al. 2008, as paper 1 §3 and Fig. 10 use it): where two
//! tissues' surfaces overlap, or the organ's surface overlaps itself around a cut, each connected
//! overlap is measured from layered depth images along x, y and z
//! (`incise_tool::volume_contact`) and pushed apart by the penalty of its volume
//! (`incise_fem::forcefield::volume`), a force field solved with the tissue.
//!
//! Nothing is precomputed and no distance field is kept, so an overlap of any depth, one a fast
//! motion or a cut left, is pushed apart the same way.
//!
//! **Where it looks.** A pair of tissues is tested over the overlap of their surfaces' bounding
//! boxes, unless one of them is held in place (every vertex carried by fixed nodes alone, a
//! kidney under the liver): then over that tissue's own box, which holds the whole intersection
//! too and does not move, so that the still tissue's depth images are drawn once and reused
//! from step to step ([`incise_tool::volume_contact::Passes::overlap_intervals_against_still`])
//! instead of being culled against the moving one's every step. Either box is grown a little
//! off the voxel lattice (`off_lattice`). A surface against itself is tested only around the
//! walls of its cuts: the box of the vertices cuts created (each cut's re-mesh names them),
//! grown by two mean edge lengths. An uncut organ does not fold onto itself at the strains a
//! surgery simulator sees, and a whole-organ self test every frame would cost more than the
//! frame. The cut vertices are topology,
//! rebuilt by re-applying a session's edits, so a replay from a keyframe looks where the
//! session looked.
//!
//! **On a device** (a GPU, given by [`crate::Simulation::set_contact_device`] where the scene's
//! `gpu` key asks for one; `incise_scene::attach_gpu` does that): the surface's embeddings and
//! triangles stay on the device, which deforms the surface from the node positions sent each
//! step and runs the layered depth images there; the overlap intervals come back and are summed
//! here, as the CPU's own are. A pass that does not fit the device runs on the CPU. The device
//! also tests which voxels a tool's cutting shape holds, for the cut search
//! ([`super::cut::voxels_inside`]).

use super::OrganSurface;
use super::cut;
use crate::config::VolumeContactSpec;
use incise_fem::forcefield::volume::{OverlapRegion, VolumePenalty};
use incise_fem::{Executor, FixedNodes, HexModel};
use incise_math::Vec3;
use incise_surface::SurfaceChanges;
use incise_tool::volume_contact::{
    ContactDevice, Overlap, OverlapInterval, Passes, TriangleSurface, regions_of,
};

/// A scene's volume contact between steps.
pub(crate) struct VolumeContact {
    spec: VolumeContactSpec,
    /// The surface groups of each pair of tissues.
    pairs: Vec<[u16; 2]>,
    /// The live vertices cuts created, sorted: where the self test looks.
    cut_vertices: Vec<u32>,
    /// How far around the cut vertices the self test looks (m).
    margin: f64,
    /// The device the passes run on, if any.
    device: Option<Box<dyn ContactDevice>>,
    /// Whether the device's embeddings and triangles are behind the surface.
    stale: bool,
    /// Whether each device pass is run on the CPU too, for [`super::super::StageCounters`]'s
    /// `gpu_cpu_volume_diff`.
    check: bool,
    /// Each surface group's live triangles and the vertices they use, as of the last re-mesh
    /// (`None`: to be found).
    groups: Option<Vec<Group>>,
    /// What the CPU passes reuse from step to step.
    passes: Passes,
    /// The tool meshes' overlaps in the last step's field.
    tool_overlaps: Vec<ToolOverlap>,
}

impl VolumeContact {
    /// The contact of `spec` on `surface`, whose vertices rest at `rest` (per slot) and whose
    /// tissues' surface groups are `group_of_label`.
    pub(crate) fn new(
        spec: &VolumeContactSpec,
        surface: &OrganSurface,
        rest: &[Vec3],
        group_of_label: impl Fn(u16) -> Option<u16>,
    ) -> Result<Self, String> {
        let pairs = spec
            .pairs
            .iter()
            .map(|&[a, b]| match (group_of_label(a), group_of_label(b)) {
                (Some(ga), Some(gb)) => Ok([ga, gb]),
                _ => Err(format!(
                    "volume_contact.pairs: [{a}, {b}]: the volume holds no voxel of one of them"
                )),
            })
            .collect::<Result<Vec<_>, String>>()?;
        Ok(Self {
            spec: spec.clone(),
            pairs,
            cut_vertices: Vec::new(),
            margin: 2.0 * mean_edge(surface, rest),
            device: None,
            stale: true,
            check: false,
            groups: None,
            passes: Passes::default(),
            tool_overlaps: Vec::new(),
        })
    }

    /// The tool meshes' overlaps in the last step's field.
    pub(crate) fn tool_overlaps(&self) -> &[ToolOverlap] {
        &self.tool_overlaps
    }

    /// Runs the passes on `device` from the next step on.
    pub(crate) fn set_device(&mut self, device: Box<dyn ContactDevice>) {
        self.device = Some(device);
        self.stale = true;
    }

    /// The device's name, if the passes run on one.
    pub(crate) fn device_name(&self) -> Option<String> {
        self.device.as_ref().map(|d| d.name())
    }

    /// The device, as the cut search's voxel marker (`None` on the CPU), counting into
    /// `mismatches` the voxels it and the CPU disagree on when checked.
    pub(crate) fn marker<'a>(&'a mut self, mismatches: &'a mut usize) -> Option<cut::Marker<'a>> {
        let check = self.check;
        let device = self.device.as_deref_mut()?;
        Some(cut::Marker { device, check, mismatches })
    }

    /// Whether each device pass is also run on the CPU and compared.
    pub(crate) fn set_check(&mut self, check: bool) {
        self.check = check;
    }

    /// Follows a re-mesh: vertices it created are cut walls, vertices it freed are gone.
    pub(crate) fn surface_changed(&mut self, changes: &SurfaceChanges) {
        self.stale = true;
        self.groups = None;
        self.cut_vertices.retain(|v| changes.vertices_removed.binary_search(v).is_err());
        self.cut_vertices.extend_from_slice(&changes.vertices_added);
        self.cut_vertices.sort_unstable();
        self.cut_vertices.dedup();
    }

    /// Forgets every cut vertex (the severing that makes a scene's tissues separate bodies is no
    /// cut to look around).
    pub(crate) fn forget_cuts(&mut self) {
        self.cut_vertices.clear();
    }

    /// The overlaps of `surface` at vertex positions `positions` (per slot), as a penalty field
    /// linearised at the `nodes`' positions; `None` when nothing overlaps; the posed `tools`
    /// meshes' overlaps with every tissue join the field, and are kept for
    /// [`Self::tool_overlaps`]. With a check, `diff` gets the largest relative
    /// difference between a device pass's volume and the CPU's.
    pub(crate) fn step(
        &mut self,
        surface: &OrganSurface,
        positions: &[Vec3],
        nodes: Nodes<'_>,
        tools: &[PosedMesh],
        diff: &mut f64,
    ) -> Option<VolumePenalty> {
        let Nodes { x, model, fixed } = nodes;
        self.tool_overlaps.clear();
        let cut_regions =
            if self.spec.self_contact { self.cut_regions(surface, positions) } else { Vec::new() };
        let Self { spec, pairs, device, stale, check, groups, passes: cpu, tool_overlaps, .. } =
            self;
        let groups = groups.get_or_insert_with(|| {
            let groups = surface.triangles_by_group().into_iter();
            groups.map(|triangles| Group::new(triangles, surface, fixed)).collect()
        });
        if let Some(device) = device {
            if *stale {
                let (embeddings, nodes) = surface.stable_embeddings();
                device.set_embeddings(&embeddings, nodes);
                device.set_triangles(&surface.group_slots());
                *stale = false;
            }
            device.deform(&surface.stable_nodes(x, model));
        }
        let group = |g: u16| groups.get(usize::from(g)).map_or(&[][..], |g| &g.triangles);
        let side = |g: u16| TriangleSurface { positions, triangles: group(g) };
        let bounds = |g: u16| groups.get(usize::from(g)).and_then(|g| g.bounds(positions));
        let still = |g: u16| groups.get(usize::from(g)).is_some_and(|g| g.still);
        let mut passes: Vec<Pass> = Vec::new();
        for &[a, b] in pairs.iter() {
            let (Some(box_a), Some(box_b)) = (bounds(a), bounds(b)) else { continue };
            let Some(shared) = common(box_a, box_b) else { continue };
            // A tissue held in place is looked at over its own box, which holds the whole
            // intersection and stays put, so that its images are drawn once.
            match (still(a), still(b)) {
                (false, true) => passes.push((a, Some(b), off_lattice(box_b), true)),
                (true, false) => passes.push((b, Some(a), off_lattice(box_a), true)),
                _ => passes.push((a, Some(b), off_lattice(shared), false)),
            }
        }
        for (g, region) in cut_regions {
            passes.push((g, None, region, false));
        }
        let resolution = spec.resolution;
        let mut found: Vec<Overlap> = Vec::new();
        let mut on_cpu: Vec<OverlapInterval> = Vec::new();
        for (a, b, region, b_still) in passes {
            let mut cpu_pass = |out: &mut Vec<OverlapInterval>| {
                out.clear();
                let sa = side(a);
                match b {
                    Some(b) if b_still => {
                        cpu.overlap_intervals_against_still(&sa, &side(b), region, resolution, out);
                    }
                    Some(b) => cpu.overlap_intervals(&sa, &side(b), region, resolution, out),
                    None => cpu.self_overlap_intervals(&sa, region, resolution, out),
                }
            };
            let from_device =
                device.as_mut().and_then(|d| d.overlap_intervals(a, b, region, resolution));
            let intervals: &[OverlapInterval] = if let Some(intervals) = &from_device {
                if *check {
                    let volume = |iv: &[OverlapInterval]| {
                        iv.iter().map(|i| i.area * (i.depths[1] - i.depths[0])).sum::<f64>()
                    };
                    cpu_pass(&mut on_cpu);
                    let (dev, cpu) = (volume(intervals), volume(&on_cpu));
                    if cpu > 0.0 || dev > 0.0 {
                        *diff = diff.max((dev - cpu).abs() / cpu.max(dev));
                    }
                }
                intervals
            } else {
                cpu_pass(&mut on_cpu);
                &on_cpu
            };
            found.extend(regions_of(intervals, region, resolution));
        }
        let mut regions: Vec<OverlapRegion> = found
            .iter()
            .filter_map(|o| {
                let gradients = o.gradient_a.iter().chain(&o.gradient_b);
                let embedded = gradients.map(|&(v, g)| (surface.embedding(v), g));
                OverlapRegion::new(o.volume, embedded, spec.pressure, x)
            })
            .collect();
        // A tool's mesh against every tissue's surface, on the CPU (the device holds only the
        // organ's surface). The tool is posed from outside: its side of each overlap moves no
        // node, and its gradient becomes the tool's force after the solve.
        for tool in tools {
            let Some(tool_box) = box_of(tool.positions.iter().copied()) else { continue };
            let mesh = TriangleSurface { positions: &tool.positions, triangles: tool.triangles };
            for g in 0..groups.len() as u16 {
                let Some(region) = bounds(g).and_then(|b| common(tool_box, b)) else { continue };
                cpu.overlap_intervals(&side(g), &mesh, region, resolution, &mut on_cpu);
                for o in regions_of(&on_cpu, region, resolution) {
                    let embedded = o.gradient_a.iter().map(|&(v, g)| (surface.embedding(v), g));
                    let fixed = o.gradient_b.iter().map(|&(_, g)| g);
                    let Some(r) =
                        OverlapRegion::against(o.volume, embedded, fixed, spec.pressure, x)
                    else {
                        continue;
                    };
                    tool_overlaps.push(ToolOverlap {
                        tool: tool.tool,
                        region: regions.len(),
                        volume: o.volume,
                        gradients: o
                            .gradient_b
                            .iter()
                            .map(|&(v, g)| (tool.positions[v as usize], g))
                            .collect(),
                        surface_points: o.gradient_a.len(),
                    });
                    regions.push(r);
                }
            }
        }
        if regions.is_empty() {
            return None;
        }
        Some(VolumePenalty::new(regions, Executor::single_thread()))
    }

    /// For each surface group with cut vertices, the box around them where the self test looks.
    fn cut_regions(&self, surface: &OrganSurface, positions: &[Vec3]) -> Vec<(u16, (Vec3, Vec3))> {
        let mut boxes: Vec<(u16, (Vec3, Vec3))> = Vec::new();
        for &v in &self.cut_vertices {
            let p = positions[v as usize];
            let g = surface.vertex_group(v);
            match boxes.iter_mut().find(|(group, _)| *group == g) {
                Some((_, (lo, hi))) => {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
                None => boxes.push((g, (p, p))),
            }
        }
        boxes.sort_by_key(|&(g, _)| g);
        for (_, (lo, hi)) in &mut boxes {
            for k in 0..3 {
                lo[k] -= self.margin;
                hi[k] += self.margin;
            }
        }
        boxes
    }
}

/// The model's nodes as a step's volume contact sees them.
#[derive(Clone, Copy)]
pub(crate) struct Nodes<'a> {
    /// Their positions.
    pub(crate) x: &'a [Vec3],
    /// The model they belong to, for a voxel surface.
    pub(crate) model: Option<&'a HexModel>,
    /// Which are held in place.
    pub(crate) fixed: &'a FixedNodes,
}

/// One pass of a step: surface group `a` against group `b` (`None`: against itself) over
/// `region`, with whether `b` is still.
type Pass = (u16, Option<u16>, (Vec3, Vec3), bool);

/// A tool's closed mesh at its pose this step, for volume contact with the tissue.
pub(crate) struct PosedMesh<'a> {
    /// The tool's index in the scene.
    pub(crate) tool: usize,
    /// Its vertices in the grid frame (m).
    pub(crate) positions: Vec<Vec3>,
    /// Its outward triangles.
    pub(crate) triangles: &'a [[u32; 3]],
}

/// A tool mesh's overlap with the tissue in a step's penalty field.
pub(crate) struct ToolOverlap {
    /// The tool's index in the scene.
    pub(crate) tool: usize,
    /// The overlap's index in the field's regions.
    pub(crate) region: usize,
    /// Its volume where it was measured (m³).
    pub(crate) volume: f64,
    /// Each tool vertex bounding it: its position (m) and the volume's gradient there (m²).
    pub(crate) gradients: Vec<(Vec3, Vec3)>,
    /// The tissue's surface vertices bounding it.
    pub(crate) surface_points: usize,
}

/// One surface group's live triangles and the vertices they use.
struct Group {
    triangles: Vec<[u32; 3]>,
    /// Ascending.
    vertices: Vec<u32>,
    /// Whether every vertex is carried by fixed nodes alone, so that the group never moves
    /// (fixed nodes change only with the grid, and the surface is re-meshed with it).
    still: bool,
}

impl Group {
    fn new(triangles: Vec<[u32; 3]>, surface: &OrganSurface, fixed: &FixedNodes) -> Self {
        let mut vertices: Vec<u32> = triangles.iter().flatten().copied().collect();
        vertices.sort_unstable();
        vertices.dedup();
        let still = !vertices.is_empty()
            && vertices.iter().all(|&v| {
                let e = surface.embedding(v);
                let mut nodes = e.nodes.iter().zip(&e.weights);
                nodes.all(|(&n, &w)| w == 0.0 || fixed.is_fixed(n as usize))
            });
        Self { triangles, vertices, still }
    }

    /// The box holding the group at vertex positions `positions` (per slot); `None` when empty.
    fn bounds(&self, positions: &[Vec3]) -> Option<(Vec3, Vec3)> {
        box_of(self.vertices.iter().map(|&v| positions[v as usize]))
    }
}

/// The box holding `points`; `None` without any.
fn box_of(mut points: impl Iterator<Item = Vec3>) -> Option<(Vec3, Vec3)> {
    let first = points.next()?;
    Some(points.fold((first, first), |(lo, hi), p| {
        (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))
    }))
}

/// `region` grown by a little over a thousandth of its size (√2/1000 below, half that above),
/// which moves the views' pixel centres off the voxel lattice. A tissue at rest (one held in
/// place) has its surface's walls exactly on lattice planes, and a box from its own vertices
/// divided into pixels puts pixel centres on those walls' edges. The CPU decides such a tie
/// exactly; a device in `f32` cannot, and took a crossing twice or not at all on some rays (a
/// volume 3–7 % off the CPU's at the 109,201-voxel liver on the kidney).
fn off_lattice((lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3) {
    const GROWTH: f64 = std::f64::consts::SQRT_2 * 1e-3;
    (
        std::array::from_fn(|k| lo[k] - GROWTH * (hi[k] - lo[k])),
        std::array::from_fn(|k| hi[k] + 0.5 * GROWTH * (hi[k] - lo[k])),
    )
}

/// The box two boxes share; `None` when they share no volume.
fn common((alo, ahi): (Vec3, Vec3), (blo, bhi): (Vec3, Vec3)) -> Option<(Vec3, Vec3)> {
    let lo: Vec3 = std::array::from_fn(|k| alo[k].max(blo[k]));
    let hi: Vec3 = std::array::from_fn(|k| ahi[k].min(bhi[k]));
    (0..3).all(|k| lo[k] < hi[k]).then_some((lo, hi))
}

/// The mean length of the surface's edges at `rest` (m; 0 without triangles).
fn mean_edge(surface: &OrganSurface, rest: &[Vec3]) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for t in surface.triangle_slots().iter().filter(|t| t.alive) {
        for k in 0..3 {
            let (a, b) = (rest[t.v[k] as usize], rest[t.v[(k + 1) % 3] as usize]);
            sum += (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f64>().sqrt();
            count += 1;
        }
    }
    if count == 0 { 0.0 } else { sum / count as f64 }
}
