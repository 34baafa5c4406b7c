//! What a tool's inner shape cuts at this frame (Jeřábková 2010, §3, Fig. 9): the fine voxels
//! whose deformed centres it contains, found by a flood from the voxels under the surface
//! points it reaches; in separation mode the links its blade's mid-plane swept across; in a
//! tensor-mass scene the tetrahedra whose deformed centroids it contains.
//!
//! A voxel's deformed centre is its rest centre's trilinear interpolation in the element that
//! owns it, the same embedding the surface vertices have.
//!
//! On a device (the GPU volume contact runs on), the voxels near the shape are tested there,
//! all at once, from the node positions; the flood then keeps to the voxels it marked.
//!
//! The flood is seeded where the shape meets the surface, and also inside the elements whose
//! deformed boxes the shape's box overlaps: paper 1 finds the voxels from the surface of the
//! *intersection volume*, which includes the tool's own surface inside the organ, so a blade
//! already buried below the organ's surface (drawn along a cut it made) keeps cutting.

use super::surface::OrganSurface;
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_grid::hex8::shape;
use incise_grid::{Block, BranchedGrid};
use incise_math::Vec3;
use incise_mesh::TetTopology;
use incise_tool::proxy::Facet;
use incise_tool::volume_contact::ContactDevice;
use incise_tool::{Pose, Shape, SweptBlade, flood};
use std::cell::RefCell;

/// Deformed positions of the grid's nodes by grid node id, and the grid: what a voxel's deformed
/// centre is interpolated from.
pub struct DeformedGrid<'a> {
    /// The grid.
    pub grid: &'a BranchedGrid,
    /// Node positions by grid node id.
    pub by_grid_node: &'a [Vec3],
}

/// An element's deformed corners and its cell: what its voxels' centres are interpolated from.
struct ElementFrame {
    corners: [Vec3; 8],
    cell: [u32; 3],
}

impl DeformedGrid<'_> {
    /// The deformed centre of voxel `v`, `None` when it is empty.
    pub fn centre(&self, v: u32) -> Option<Vec3> {
        let e = self.grid.voxel_element(v)?;
        let element = self.grid.top().element(e)?;
        Some(self.centre_in(&self.frame(element), v))
    }

    fn frame(&self, element: &incise_grid::Element) -> ElementFrame {
        ElementFrame {
            corners: element.nodes.map(|n| self.by_grid_node[n as usize]),
            cell: self.grid.top().cell_coords(element.cell),
        }
    }

    /// The deformed centre of voxel `v` of the element `frame` describes.
    fn centre_in(&self, frame: &ElementFrame, v: u32) -> Vec3 {
        let dims = self.grid.fine().dims();
        self.centre_at(frame, [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])])
    }

    /// The trilinear weights of voxel `v`'s centre on the corners of the element `frame`
    /// describes.
    fn weights_in(&self, frame: &ElementFrame, v: u32) -> [f64; 8] {
        let dims = self.grid.fine().dims();
        self.weights_at(frame, [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])])
    }

    /// The deformed centre of the voxel at fine coordinates `c` in the element `frame`
    /// describes (also where no voxel is).
    fn centre_at(&self, frame: &ElementFrame, c: [u32; 3]) -> Vec3 {
        let mut p = [0.0; 3];
        for (q, w) in frame.corners.iter().zip(self.weights_at(frame, c)) {
            for k in 0..3 {
                p[k] += w * q[k];
            }
        }
        p
    }

    /// The trilinear weights of the centre of the voxel at fine coordinates `c` on the corners
    /// of the element `frame` describes.
    fn weights_at(&self, frame: &ElementFrame, c: [u32; 3]) -> [f64; 8] {
        let grid = self.grid;
        let (size, h) = (grid.element_size(), grid.spacing());
        let xi: Vec3 = std::array::from_fn(|a| {
            ((f64::from(c[a]) + 0.5) * h[a] - f64::from(frame.cell[a]) * size[a]) / size[a]
        });
        std::array::from_fn(|n| shape(n, xi))
    }

    /// The face neighbours of `v` that hold material and are still linked to it.
    pub fn linked(&self, v: u32, out: &mut Vec<u32>) {
        let fine = self.grid.fine();
        let d = fine.dims();
        let c = [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])];
        let stride = [1, d[0], d[0] * d[1]];
        for a in 0..3 {
            if c[a] > 0 {
                let w = v - stride[a];
                if fine.material(w).is_some() && !fine.is_severed_along(w, a) {
                    out.push(w);
                }
            }
            if c[a] + 1 < d[a] {
                let w = v + stride[a];
                if fine.material(w).is_some() && !fine.is_severed_along(v, a) {
                    out.push(w);
                }
            }
        }
    }

    /// The largest voxel edge (m).
    fn voxel(&self) -> f64 {
        self.grid.spacing().into_iter().fold(0.0, f64::max)
    }

    /// The voxels whose deformed centres satisfy `keep`, which holds nowhere outside `(lo, hi)`
    /// grown by `reach`: those of the elements whose deformed bounding boxes overlap that box.
    fn voxels_near(
        &self,
        bounds: (Vec3, Vec3),
        reach: f64,
        keep: impl Fn(Vec3) -> bool,
    ) -> Vec<u32> {
        let mut out = Vec::new();
        self.each_near(bounds, reach, |v, c, _| {
            if keep(c) {
                out.push(v);
            }
        });
        out
    }

    /// Calls `f(voxel, deformed centre, the centre's embedding in the grid's nodes)` for every
    /// voxel whose deformed centre lies in `(lo, hi)` grown by `reach`, element by element.
    fn each_near(
        &self,
        (lo, hi): (Vec3, Vec3),
        reach: f64,
        mut f: impl FnMut(u32, Vec3, &dyn Fn() -> EmbeddedPoint),
    ) {
        // A centre outside the box is not tested (the tool's distance costs more than the
        // centre); the margin, far above the rounding of the tool's transforms, keeps a centre
        // that a test takes on the box's boundary.
        let margin = 1e-6 * self.voxel();
        let (box_lo, box_hi): (Vec3, Vec3) = (
            std::array::from_fn(|k| lo[k] - reach - margin),
            std::array::from_fn(|k| hi[k] + reach + margin),
        );
        let in_box = |c: &Vec3| (0..3).all(|k| c[k] >= box_lo[k] && c[k] <= box_hi[k]);
        let mut voxels = Vec::new();
        for (id, element) in self.grid.top().elements() {
            let mut a = [f64::INFINITY; 3];
            let mut b = [f64::NEG_INFINITY; 3];
            for &n in &element.nodes {
                let p = self.by_grid_node[n as usize];
                for k in 0..3 {
                    a[k] = a[k].min(p[k]);
                    b[k] = b[k].max(p[k]);
                }
            }
            if (0..3).any(|k| b[k] < lo[k] - reach || a[k] > hi[k] + reach) {
                continue;
            }
            // The element's voxels are its own: their centres from its frame, looked up once,
            // in the blocks (its descendants' cells) whose deformed boxes meet the box: a block's
            // centres are trilinear in the frame, so they lie within the box of its corners'.
            voxels.clear();
            let frame = self.frame(element);
            let mut meets = |first: [u32; 3], size: u32| {
                let (mut a, mut b) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for corner in 0..8u32 {
                    let at: [u32; 3] = std::array::from_fn(|k| {
                        first[k] + if corner >> k & 1 == 0 { 0 } else { size - 1 }
                    });
                    let p = self.centre_at(&frame, at);
                    for k in 0..3 {
                        a[k] = a[k].min(p[k]);
                        b[k] = b[k].max(p[k]);
                    }
                }
                if (0..3).any(|k| b[k] < box_lo[k] || a[k] > box_hi[k]) {
                    Block::Skip
                } else if (0..3).all(|k| a[k] >= box_lo[k] && b[k] <= box_hi[k]) {
                    Block::All
                } else {
                    Block::Some
                }
            };
            self.grid.element_voxels_where(id, &mut meets, &mut voxels);
            for &v in &voxels {
                let c = self.centre_in(&frame, v);
                if in_box(&c) {
                    let embedding = || EmbeddedPoint {
                        nodes: element.nodes,
                        weights: self.weights_in(&frame, v),
                    };
                    f(v, c, &embedding);
                }
            }
        }
    }
}

/// The surface vertices within `reach` of a shape (by `distance`) and inside the box
/// `(lo, hi)` grown by `reach`, as their owner voxels.
fn seeds(
    surface: &OrganSurface,
    positions: &[Vec3],
    reach: f64,
    (lo, hi): (Vec3, Vec3),
    distance: impl Fn(Vec3) -> f64,
) -> Vec<u32> {
    let near = |p: &Vec3| (0..3).all(|k| p[k] >= lo[k] - reach && p[k] <= hi[k] + reach);
    let mut seeds: Vec<u32> = surface
        .live_vertices()
        .iter()
        .copied()
        .filter(|&v| near(&positions[v as usize]) && distance(positions[v as usize]) < reach)
        .filter_map(|v| surface.owner_voxel(v))
        .collect();
    seeds.sort_unstable();
    seeds.dedup();
    seeds
}

/// A device that tests which voxels a cutting shape holds, for [`voxels_inside`].
pub struct Marker<'a> {
    /// The device.
    pub device: &'a mut dyn ContactDevice,
    /// Whether the CPU tests the voxels too.
    pub check: bool,
    /// With `check`: voxels the device and the CPU disagree on, added to.
    pub mismatches: &'a mut usize,
}

/// The voxels `inner` at `pose` cuts: those whose deformed centres it contains, connected to
/// the voxels under the surface points within a voxel of it. Sorted. With a `marker` the
/// centres near the shape are tested on its device (in `f32`: a centre within rounding of
/// the shape's surface may be taken either way), unless it does not mark this shape.
pub fn voxels_inside(
    inner: &Shape,
    pose: &Pose,
    grid: &DeformedGrid,
    surface: &OrganSurface,
    positions: &[Vec3],
    marker: Option<Marker>,
) -> Vec<u32> {
    let inside = |p: Vec3| inner.distance(pose.tool_from_grid(p)).0;
    let bounds = inner.grid_bounds(pose);
    let mut seeds = seeds(surface, positions, grid.voxel(), bounds, inside);
    if let Some(held) = marker.and_then(|mut m| marked(&mut m, inner, pose, grid, bounds)) {
        // Every voxel the shape holds has its centre in the shape's box, and so is a candidate
        // the device marked: a voxel it did not mark is not held.
        seeds.extend_from_slice(&held);
        return flood(seeds, |v| held.binary_search(&v).is_ok(), |v, out| grid.linked(v, out));
    }
    seeds.extend(grid.voxels_near(bounds, 0.0, |c| inside(c) < 0.0));
    if seeds.is_empty() {
        return seeds;
    }
    flood(seeds, |v| grid.centre(v).is_some_and(|c| inside(c) < 0.0), |v, out| grid.linked(v, out))
}

/// The voxels in `bounds` the marker's device finds `inner` at `pose` holds, sorted; `None`
/// when it does not mark this shape.
fn marked(
    marker: &mut Marker,
    inner: &Shape,
    pose: &Pose,
    grid: &DeformedGrid,
    bounds: (Vec3, Vec3),
) -> Option<Vec<u32>> {
    // The centres are kept only for the check: the device tests its own, in f32.
    let (mut voxels, mut centres, mut embeddings) = (Vec::new(), Vec::new(), Vec::new());
    grid.each_near(bounds, 0.0, |v, c, embedding| {
        voxels.push(v);
        if marker.check {
            centres.push(c);
        }
        embeddings.push(embedding());
    });
    let marks = marker.device.cut_marks(inner, pose, grid.by_grid_node, &embeddings)?;
    if marker.check {
        let cpu = centres.iter().map(|&c| inner.distance(pose.tool_from_grid(c)).0 < 0.0);
        *marker.mismatches += cpu.zip(&marks).filter(|&(c, &m)| c != m).count();
    }
    let mut held: Vec<u32> =
        voxels.into_iter().zip(marks).filter_map(|(v, m)| m.then_some(v)).collect();
    held.sort_unstable();
    Some(held)
}

/// The links `blade`'s mid-plane swept across between the two frames: pairs of linked voxels
/// (smaller index first) whose deformed centres lie on either side of it, among the voxels
/// within reach of it that are connected to the surface points it reached. Sorted.
pub fn links_crossed(
    blade: &SweptBlade,
    grid: &DeformedGrid,
    surface: &OrganSurface,
    positions: &[Vec3],
) -> Vec<(u32, u32)> {
    let reach = 1.5 * grid.voxel();
    let mut seeds = seeds(surface, positions, reach, blade.bounds(), |p| blade.distance(p));
    seeds.extend(grid.voxels_near(blade.bounds(), reach, |c| blade.distance(c) < reach));
    if seeds.is_empty() {
        return Vec::new();
    }
    let near = flood(
        seeds,
        |v| grid.centre(v).is_some_and(|c| blade.distance(c) < reach),
        |v, out| grid.linked(v, out),
    );
    let mut links = Vec::new();
    let mut around = Vec::new();
    for &v in &near {
        let Some(a) = grid.centre(v) else { continue };
        around.clear();
        grid.linked(v, &mut around);
        for &w in &around {
            // Each pair once: from its smaller end, or from the end in the near set.
            if w < v && near.binary_search(&w).is_ok() {
                continue;
            }
            if let Some(b) = grid.centre(w)
                && blade.crosses(a, b)
            {
                links.push((v.min(w), v.max(w)));
            }
        }
    }
    links.sort_unstable();
    links.dedup();
    links
}

/// The voxels a step's tests of a cutting shape looked up, kept for its later tests.
#[derive(Default)]
pub struct VoxelCache(RefCell<Option<VoxelCentres>>);

/// Whether `inner` moved from `from` to `to` holds a voxel's deformed centre at `to` that it did
/// not hold at `from`: material it would have to cut before it can be there.
///
/// The motion tests many poses a step, all from the step's start: the voxels are looked up at
/// the first test over the box the shape sweeps from `from` to `to` (and a twentieth of its
/// thinnest size), kept in `cache`, and looked up again, over that box and the one before, only
/// for a pose whose shape leaves it.
pub fn holds_new_voxels(
    inner: &Shape,
    from: &Pose,
    to: &Pose,
    grid: &DeformedGrid,
    cache: &VoxelCache,
) -> bool {
    let (lo, hi) = inner.grid_bounds(to);
    let mut voxels = cache.0.borrow_mut();
    let within = |(a, b): (Vec3, Vec3)| (0..3).all(|k| lo[k] >= a[k] && hi[k] <= b[k]);
    if !voxels.as_ref().is_some_and(|v| within(v.bounds)) {
        let margin = 0.05 * inner.thinnest();
        let (a, b) = inner.grid_bounds(from);
        let mut bounds: (Vec3, Vec3) = (
            std::array::from_fn(|k| (a[k] - margin).min(lo[k] - margin)),
            std::array::from_fn(|k| (b[k] + margin).max(hi[k] + margin)),
        );
        if let Some(v) = voxels.as_ref() {
            bounds = (
                std::array::from_fn(|k| bounds.0[k].min(v.bounds.0[k])),
                std::array::from_fn(|k| bounds.1[k].max(v.bounds.1[k])),
            );
        }
        *voxels = Some(VoxelCentres::near(grid, bounds));
    }
    voxels.as_ref().is_some_and(|v| v.holds_new(inner, from, to))
}

/// The deformed centres of the voxels in `bounds`, looked up once for many tests of
/// [`VoxelCentres::holds_new`] (sorted along x, so that a test scans only its shape's slab).
struct VoxelCentres {
    centres: Vec<Vec3>,
    /// The region they were looked up in.
    bounds: (Vec3, Vec3),
}

impl VoxelCentres {
    /// The voxels of `grid` whose deformed centres lie in `bounds`.
    fn near(grid: &DeformedGrid, bounds: (Vec3, Vec3)) -> Self {
        let mut centres = Vec::new();
        grid.each_near(bounds, 0.0, |_, c, _| centres.push(c));
        centres.sort_by(|a, b| a[0].total_cmp(&b[0]));
        Self { centres, bounds }
    }

    /// [`holds_new_voxels`] for a pose `to` whose shape lies within the bounds.
    fn holds_new(&self, inner: &Shape, from: &Pose, to: &Pose) -> bool {
        let holds = |pose: &Pose, c: Vec3| inner.distance(pose.tool_from_grid(c)).0 < 0.0;
        let (lo, hi) = inner.grid_bounds(to);
        let first = self.centres.partition_point(|c| c[0] < lo[0]);
        self.centres[first..]
            .iter()
            .take_while(|c| c[0] <= hi[0])
            .filter(|c| (1..3).all(|k| c[k] >= lo[k] && c[k] <= hi[k]))
            .any(|&c| holds(to, c) && !holds(from, c))
    }
}

/// Whether a blade's mid-plane swept from `from` to `to` would cross a link that is not
/// severed: material it would have to separate before it can be there.
pub fn crosses_linked(
    inner: &Shape,
    from: &Pose,
    to: &Pose,
    grid: &DeformedGrid,
    surface: &OrganSurface,
    positions: &[Vec3],
) -> bool {
    let link = grid.grid.spacing().into_iter().fold(f64::INFINITY, f64::min);
    SweptBlade::new(inner, from, to, link)
        .is_some_and(|blade| !links_crossed(&blade, grid, surface, positions).is_empty())
}

/// The live tetrahedra under the boundary triangles `facets`: those with a face on one.
pub fn tets_under(topology: &TetTopology, facets: &[Facet]) -> Vec<usize> {
    if facets.is_empty() {
        return Vec::new();
    }
    let mut faces: Vec<[u32; 3]> = facets
        .iter()
        .map(|f| {
            let mut v = f.vertices;
            v.sort_unstable();
            v
        })
        .collect();
    faces.sort_unstable();
    (0..topology.tets().len())
        .filter(|&t| topology.is_alive(t))
        .filter(|&t| {
            let v = topology.tets()[t];
            (0..4).any(|skip| {
                let mut face: Vec<u32> = (0..4).filter(|&i| i != skip).map(|i| v[i]).collect();
                face.sort_unstable();
                faces.binary_search(&[face[0], face[1], face[2]]).is_ok()
            })
        })
        .collect()
}

/// The live tetrahedra whose deformed centroids lie in the box `(lo, hi)`, in id order.
pub fn tets_near(topology: &TetTopology, x: &[Vec3], (lo, hi): (Vec3, Vec3)) -> Vec<usize> {
    (0..topology.tets().len())
        .filter(|&t| topology.is_alive(t))
        .filter(|&t| {
            let c = centroid(topology, x, t);
            (0..3).all(|k| c[k] >= lo[k] && c[k] <= hi[k])
        })
        .collect()
}

/// Whether `inner` moved from `from` to `to` holds the deformed centroid of one of the live
/// tetrahedra `among` at `to` that it did not hold at `from`.
pub fn holds_new_tets(
    inner: &Shape,
    from: &Pose,
    to: &Pose,
    topology: &TetTopology,
    x: &[Vec3],
    among: &[usize],
) -> bool {
    let holds = |pose: &Pose, c: Vec3| inner.distance(pose.tool_from_grid(c)).0 < 0.0;
    among.iter().any(|&t| {
        let c = centroid(topology, x, t);
        holds(to, c) && !holds(from, c)
    })
}

/// The deformed centroid of tetrahedron `t`.
fn centroid(topology: &TetTopology, x: &[Vec3], t: usize) -> Vec3 {
    let v = &topology.tets()[t];
    std::array::from_fn(|k| 0.25 * v.iter().map(|&i| x[i as usize][k]).sum::<f64>())
}

/// The live tetrahedra whose deformed centroids `inner` at `pose` contains. Sorted.
pub fn tets_inside(inner: &Shape, pose: &Pose, topology: &TetTopology, x: &[Vec3]) -> Vec<usize> {
    let (lo, hi) = inner.bounds();
    let r = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let centre = pose.grid_from_tool(std::array::from_fn(|k| 0.5 * (lo[k] + hi[k])));
    topology
        .tets()
        .iter()
        .enumerate()
        .filter(|&(t, _)| topology.is_alive(t))
        .filter_map(|(t, v)| {
            let c: Vec3 =
                std::array::from_fn(|k| 0.25 * v.iter().map(|&i| x[i as usize][k]).sum::<f64>());
            let near = (0..3).map(|k| (c[k] - centre[k]).powi(2)).sum::<f64>() <= r * r;
            (near && inner.distance(pose.tool_from_grid(c)).0 < 0.0).then_some(t)
        })
        .collect()
}
