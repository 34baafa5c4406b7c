//! What a tool's inner shape cuts at this frame (Jeřábková 2010, §3, Fig. 9): the fine voxels
//! whose deformed centres it contains, found by a flood from the voxels under the surface
//! points it reaches; in separation mode the links its blade's mid-plane swept across; in a
//! tensor-mass scene the tetrahedra whose deformed centroids it contains.
//!
//! A voxel's deformed centre is its rest centre's trilinear interpolation in the element that
//! owns it, the same embedding the surface vertices have.
//!
//! The flood is seeded where the shape meets the surface, and also inside the elements whose
//! deformed boxes the shape's box overlaps: paper 1 finds the voxels from the surface of the
//! *intersection volume*, which includes the tool's own surface inside the organ, so a blade
//! already buried below the organ's surface (drawn along a cut it made) keeps cutting.

use super::surface::OrganSurface;
use incise_grid::BranchedGrid;
use incise_grid::hex8::shape;
use incise_math::Vec3;
use incise_mesh::TetTopology;
use incise_tool::{Pose, Shape, SweptBlade, flood};

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
        let grid = self.grid;
        let (size, h, dims) = (grid.element_size(), grid.spacing(), grid.fine().dims());
        let c = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
        let xi: Vec3 = std::array::from_fn(|a| {
            ((f64::from(c[a]) + 0.5) * h[a] - f64::from(frame.cell[a]) * size[a]) / size[a]
        });
        let mut p = [0.0; 3];
        for (n, q) in frame.corners.iter().enumerate() {
            let w = shape(n, xi);
            for k in 0..3 {
                p[k] += w * q[k];
            }
        }
        p
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
        (lo, hi): (Vec3, Vec3),
        reach: f64,
        keep: impl Fn(Vec3) -> bool,
    ) -> Vec<u32> {
        // A centre outside the box is not tested (the tool's distance costs more than the
        // centre); the margin, far above the rounding of the tool's transforms, keeps a centre
        // that `keep` takes on the box's boundary.
        let margin = 1e-6 * self.voxel();
        let (box_lo, box_hi): (Vec3, Vec3) = (
            std::array::from_fn(|k| lo[k] - reach - margin),
            std::array::from_fn(|k| hi[k] + reach + margin),
        );
        let in_box = |c: &Vec3| (0..3).all(|k| c[k] >= box_lo[k] && c[k] <= box_hi[k]);
        let mut out = Vec::new();
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
            // The element's voxels are its own: their centres from its frame, looked up once.
            voxels.clear();
            self.grid.element_voxels_into(id, &mut voxels);
            let frame = self.frame(element);
            out.extend(voxels.iter().copied().filter(|&v| {
                let c = self.centre_in(&frame, v);
                in_box(&c) && keep(c)
            }));
        }
        out
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

/// The voxels `inner` at `pose` cuts: those whose deformed centres it contains, connected to
/// the voxels under the surface points within a voxel of it. Sorted.
pub fn voxels_inside(
    inner: &Shape,
    pose: &Pose,
    grid: &DeformedGrid,
    surface: &OrganSurface,
    positions: &[Vec3],
) -> Vec<u32> {
    let inside = |p: Vec3| inner.distance(pose.tool_from_grid(p)).0;
    let bounds = inner.grid_bounds(pose);
    let mut seeds = seeds(surface, positions, grid.voxel(), bounds, inside);
    seeds.extend(grid.voxels_near(bounds, 0.0, |c| inside(c) < 0.0));
    if seeds.is_empty() {
        return seeds;
    }
    flood(seeds, |v| grid.centre(v).is_some_and(|c| inside(c) < 0.0), |v, out| grid.linked(v, out))
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
