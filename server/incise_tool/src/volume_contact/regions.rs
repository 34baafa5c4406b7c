//! The intersection split into its connected regions, each with its own volume and gradient.
//!
//! A penalty on the total volume would couple every overlap of a pair: a deep overlap at one end
//! of a liver would push hard at a graze at the other. Each connected overlap is pushed by its
//! own volume instead (Faure et al. 2008 do the same per pair of intersecting objects).
//!
//! Regions are found on a cell grid over the views' box with the views' resolution per axis, so
//! that a pixel of the view along `k` is a column of cells along `k`. Every interval of every view
//! marks the cells its segment passes through; intervals that share a cell, or lie in cells that
//! touch (faces, edges or corners), are one region. A connected overlap's intervals all meet
//! this way (its cells are connected); two overlaps less than a cell apart count as one, which
//! only couples them.

use super::intersection::{Side, overlap_intervals, self_overlap_intervals};
use super::ldi::TriangleSurface;
use incise_math::Vec3;

/// One connected overlap: its volume and its gradient with respect to the vertices that bound
/// it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overlap {
    /// The volume (the mean of the three axes' estimates).
    pub volume: f64,
    /// The volume seen along x, y and z.
    pub volume_by_axis: [f64; 3],
    /// `(vertex, ∂volume/∂p)` for the first surface's vertices that bound it (of the surface
    /// itself for a self-overlap), by ascending vertex; component `k` is the view along `k`'s
    /// derivative, as in [`super::Intersection`].
    pub gradient_a: Vec<(u32, Vec3)>,
    /// The same for the second surface (empty for a self-overlap).
    pub gradient_b: Vec<(u32, Vec3)>,
}

/// One interval of a pixel's ray inside the overlap, with the crossings that bound it: what the
/// rasterisation passes produce (here, or on a GPU) and [`regions_of`] sums.
#[derive(Clone, Debug, PartialEq)]
pub struct OverlapInterval {
    /// The view's axis (the ray's direction).
    pub axis: usize,
    /// The pixel's column and row in its view.
    pub pixel: [usize; 2],
    /// The pixel's area.
    pub area: f64,
    /// Where the interval starts and ends along the ray.
    pub depths: [f64; 2],
    /// For its start (the volume shrinks as it moves along the ray) and its end (grows): the
    /// side, the crossed triangle's vertices and their barycentric weights (all zero for an end
    /// cut off by the region looked at, which no vertex moves).
    pub bounds: [(Side, [u32; 3], [f64; 3]); 2],
}

/// The intersection of `a` and `b` as its connected regions (views of `resolution` pixels per
/// side over the overlap of their bounding boxes, as [`super::intersection()`]), ordered by their
/// first interval (views x, y, z; pixels row by row). Their volumes and gradients sum to
/// [`super::intersection()`]'s.
#[must_use]
pub fn overlaps(
    a: &TriangleSurface<'_>,
    b: &TriangleSurface<'_>,
    resolution: usize,
) -> Vec<Overlap> {
    let (Some((alo, ahi)), Some((blo, bhi))) = (a.bounds(), b.bounds()) else {
        return Vec::new();
    };
    let lo: Vec3 = std::array::from_fn(|k| alo[k].max(blo[k]));
    let hi: Vec3 = std::array::from_fn(|k| ahi[k].min(bhi[k]));
    let intervals = overlap_intervals(a, b, (lo, hi), resolution);
    regions_of(&intervals, (lo, hi), resolution)
}

/// Where `surface` overlaps itself, as its connected regions (views over its bounding box, as
/// [`super::self_intersection`]); gradients in [`Overlap::gradient_a`].
#[must_use]
pub fn self_overlaps(surface: &TriangleSurface<'_>, resolution: usize) -> Vec<Overlap> {
    let Some(region) = surface.bounds() else { return Vec::new() };
    let intervals = self_overlap_intervals(surface, region, resolution);
    regions_of(&intervals, region, resolution)
}

/// Where `surface` overlaps itself within `region` (views over that box only: the rest of the
/// surface is rasterised but its pixels are not looked at), as its connected regions. A scene
/// tests only where an overlap can start (around a cut's walls) instead of the whole organ.
#[must_use]
pub fn self_overlaps_in(
    surface: &TriangleSurface<'_>,
    region: (Vec3, Vec3),
    resolution: usize,
) -> Vec<Overlap> {
    let intervals = self_overlap_intervals(surface, region, resolution);
    regions_of(&intervals, region, resolution)
}

/// Sums `intervals`, found in views of `resolution` pixels per side over `region`, into their
/// connected regions, in the order of their first interval. The sums run in the intervals'
/// order: give them sorted (by axis, pixel row, column, depth), as the CPU passes make them, for
/// sums that do not depend on how they were found.
#[must_use]
pub fn regions_of(
    intervals: &[OverlapInterval],
    region: (Vec3, Vec3),
    resolution: usize,
) -> Vec<Overlap> {
    let labels = connect(intervals, region, resolution);
    let count = labels.iter().map(|&l| l + 1).max().unwrap_or(0);
    let mut out = vec![Overlap::default(); count];
    for (iv, &l) in intervals.iter().zip(&labels) {
        let o = &mut out[l];
        o.volume_by_axis[iv.axis] += iv.area * (iv.depths[1] - iv.depths[0]);
        for ((side, tri, weights), sign) in iv.bounds.iter().zip([-1.0, 1.0]) {
            let g = match side {
                Side::A => &mut o.gradient_a,
                Side::B => &mut o.gradient_b,
            };
            // A cut end (zero weights) moves with no vertex.
            for (&v, &w) in tri.iter().zip(weights).filter(|&(_, &w)| w != 0.0) {
                let mut d = [0.0; 3];
                d[iv.axis] = sign * iv.area * w;
                g.push((v, d));
            }
        }
    }
    for o in &mut out {
        o.volume = o.volume_by_axis.iter().sum::<f64>() / 3.0;
        merge(&mut o.gradient_a);
        merge(&mut o.gradient_b);
    }
    out
}

/// Sorts `(vertex, vector)` pairs by vertex and sums those of one vertex, in their order.
fn merge(g: &mut Vec<(u32, Vec3)>) {
    // Stable: a vertex's terms are summed in the order they were found, whatever the sort.
    g.sort_by_key(|&(v, _)| v);
    let mut out: Vec<(u32, Vec3)> = Vec::with_capacity(g.len());
    for &(v, d) in g.iter() {
        match out.last_mut() {
            Some((last, sum)) if *last == v => {
                for k in 0..3 {
                    sum[k] += d[k];
                }
            }
            _ => out.push((v, d)),
        }
    }
    *g = out;
}

/// Each interval's region, numbered in order of first appearance.
fn connect(intervals: &[OverlapInterval], (lo, hi): (Vec3, Vec3), resolution: usize) -> Vec<usize> {
    let n = resolution.max(1);
    let cell_of = |k: usize, x: f64| -> usize {
        let h = (hi[k] - lo[k]) / n as f64;
        let c = ((x - lo[k]) / h).floor();
        if c.is_finite() { (c.max(0.0) as usize).min(n - 1) } else { 0 }
    };
    // (cell, interval) for every cell an interval's segment passes through.
    let mut marks: Vec<(usize, u32)> = Vec::new();
    for (id, iv) in intervals.iter().enumerate() {
        let (u, v) = super::ldi::plane_axes(iv.axis);
        let mut c = [0usize; 3];
        c[u] = iv.pixel[0].min(n - 1);
        c[v] = iv.pixel[1].min(n - 1);
        for along in cell_of(iv.axis, iv.depths[0])..=cell_of(iv.axis, iv.depths[1]) {
            c[iv.axis] = along;
            marks.push((c[0] + n * (c[1] + n * c[2]), id as u32));
        }
    }
    marks.sort_unstable();
    let mut sets = UnionFind::new(intervals.len());
    // Intervals sharing a cell.
    for pair in marks.windows(2) {
        if pair[0].0 == pair[1].0 {
            sets.union(pair[0].1, pair[1].1);
        }
    }
    // Cells that touch: each occupied cell with its 13 neighbours ahead of it in linear order.
    let mut cells: Vec<(usize, u32)> = marks;
    cells.dedup_by_key(|m| m.0);
    let find = |cell: usize| cells.binary_search_by_key(&cell, |m| m.0).ok().map(|i| cells[i].1);
    for &(cell, id) in &cells {
        let c = [cell % n, cell / n % n, cell / (n * n)];
        for d in forward_neighbours() {
            let nb: [i64; 3] = std::array::from_fn(|k| c[k] as i64 + d[k]);
            if nb.iter().any(|&x| x < 0 || x >= n as i64) {
                continue;
            }
            let nb = nb[0] as usize + n * (nb[1] as usize + n * nb[2] as usize);
            if let Some(other) = find(nb) {
                sets.union(id, other);
            }
        }
    }
    let mut label_of_root = vec![usize::MAX; intervals.len()];
    let mut next = 0;
    (0..intervals.len() as u32)
        .map(|i| {
            let root = sets.find(i) as usize;
            if label_of_root[root] == usize::MAX {
                label_of_root[root] = next;
                next += 1;
            }
            label_of_root[root]
        })
        .collect()
}

/// The 13 of a cell's 26 neighbours that come after it in linear order (x fastest).
fn forward_neighbours() -> impl Iterator<Item = [i64; 3]> {
    (-1..=1i64)
        .flat_map(|z| (-1..=1i64).flat_map(move |y| (-1..=1i64).map(move |x| [x, y, z])))
        .filter(|d| (d[2], d[1], d[0]) > (0, 0, 0))
}

/// Disjoint sets of intervals.
struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self { parent: (0..n as u32).collect() }
    }

    fn find(&mut self, mut i: u32) -> u32 {
        while self.parent[i as usize] != i {
            let up = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = up;
            i = up;
        }
        i
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        // The smaller root wins, so the sets do not depend on the order of unions.
        if ra < rb {
            self.parent[rb as usize] = ra;
        } else if rb < ra {
            self.parent[ra as usize] = rb;
        }
    }
}
