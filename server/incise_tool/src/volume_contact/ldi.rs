//! Layered depth images (Faure et al. 2008, used by paper 1 §3, Fig. 10): closed triangle
//! surfaces rasterised along one axis, keeping every surface crossing of every pixel's ray, not
//! only the nearest. Sorted by depth, a ray's crossings give the depth intervals inside the
//! surface, whatever its shape or overlaps.
//!
//! A pixel's ray runs along `+axis` through the pixel's centre. A triangle covers a pixel when the
//! centre lies inside its projection, with a tie rule on edges and vertices (below) so that a
//! closed surface is crossed exactly once where its triangles meet: no double crossings and no
//! gaps, on any grid, even with vertices exactly on pixel centres. Which side of an edge a
//! centre lies on is decided by an exact sign (Shewchuk's adaptive orientation predicate), not
//! a rounded one: a voxel surface's walls, seen along an axis, are edge-on or within rounding of
//! it, and the pixel centres of a view over a box from the same lattice fall on their lines, so
//! rounded signs there counted some rays' crossings twice or not at all.

use incise_math::Vec3;

/// A closed, consistently oriented triangle surface (normals outwards): node positions and
/// triangles of indices into them.
#[derive(Clone, Copy, Debug)]
pub struct TriangleSurface<'a> {
    /// Vertex positions.
    pub positions: &'a [Vec3],
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: &'a [[u32; 3]],
}

impl TriangleSurface<'_> {
    /// The axis-aligned box holding every vertex (`None` without triangles).
    #[must_use]
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.triangles.iter().flatten().map(|&v| self.positions[v as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| {
            (std::array::from_fn(|a| lo[a].min(p[a])), std::array::from_fn(|a| hi[a].max(p[a])))
        }))
    }
}

/// The pixel grid of one view: rays along `axis` through the centres of `size[0] × size[1]`
/// pixels of `pixel` extent, the first pixel's corner at `origin`, in the plane of the two other
/// axes (`(axis + 1) % 3` first).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// The rays' direction: 0, 1 or 2.
    pub axis: usize,
    /// Corner of the grid in the two other axes.
    pub origin: [f64; 2],
    /// Pixel extent in the two other axes.
    pub pixel: [f64; 2],
    /// Pixels in the two other axes.
    pub size: [usize; 2],
}

impl View {
    /// The view along `axis` covering the box `lo..hi` with `resolution` pixels per side.
    #[must_use]
    pub fn covering(axis: usize, lo: Vec3, hi: Vec3, resolution: usize) -> Self {
        let (u, v) = plane_axes(axis);
        let n = resolution.max(1);
        Self {
            axis,
            origin: [lo[u], lo[v]],
            pixel: [(hi[u] - lo[u]) / n as f64, (hi[v] - lo[v]) / n as f64],
            size: [n, n],
        }
    }

    /// Area of one pixel.
    #[must_use]
    pub fn pixel_area(&self) -> f64 {
        self.pixel[0] * self.pixel[1]
    }

    /// The columns and rows of the pixels whose centres lie in the image-plane box `lo..hi`
    /// (in the view's two plane axes), and of those within a ten-millionth of a pixel of it: a
    /// centre on the box's edge (a vertex on a pixel centre) must not be lost to the rounding
    /// of the scaling.
    #[must_use]
    #[inline]
    pub fn pixels_in(&self, lo: [f64; 2], hi: [f64; 2]) -> [std::ops::Range<usize>; 2] {
        const SLACK: f64 = 1e-7;
        let range = |k: usize| {
            let size = self.size[k] as i64;
            // One division for both ends; the slack, far above its rounding, keeps it safe.
            let per = 1.0 / self.pixel[k];
            let first = ceil((lo[k] - self.origin[k]) * per - 0.5 - SLACK).clamp(0, size);
            let last = (floor((hi[k] - self.origin[k]) * per - 0.5 + SLACK) + 1).clamp(0, size);
            first as usize..last as usize
        };
        [range(0), range(1)]
    }

    #[inline]
    fn centre(&self, i: usize, j: usize) -> [f64; 2] {
        // Through `u32` (a view has far fewer pixels a side): exact, and one instruction on
        // x86-64, where a `usize` takes several.
        [
            self.origin[0] + (f64::from(i as u32) + 0.5) * self.pixel[0],
            self.origin[1] + (f64::from(j as u32) + 0.5) * self.pixel[1],
        ]
    }
}

/// The two axes of the image plane of a view along `axis`.
#[must_use]
pub fn plane_axes(axis: usize) -> (usize, usize) {
    ((axis + 1) % 3, (axis + 2) % 3)
}

/// One crossing of a pixel's ray with a triangle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Fragment {
    /// Position along the view's axis.
    pub depth: f64,
    /// The triangle crossed.
    pub triangle: u32,
    /// Barycentric weights of the crossing in the triangle's vertices: a vertex moved by `δ`
    /// along the axis moves the crossing by `weight · δ` (the pixel's ray stays put).
    pub weights: [f64; 3],
    /// True where the ray enters the surface (the outward normal faces against the ray).
    pub entering: bool,
}

/// A layered depth image: every pixel's crossings, sorted by depth (at equal depth entering
/// first, then by triangle).
#[derive(Clone, Debug, Default)]
pub struct Ldi {
    view: View,
    /// Pixel `p`'s fragments are `fragments[starts[p]..starts[p + 1]]`; pixels row by row.
    starts: Vec<u32>,
    fragments: Vec<Fragment>,
    /// The crossings as found, with their pixels (kept only for its allocation).
    hits: Vec<(u32, Fragment)>,
}

impl Default for View {
    fn default() -> Self {
        Self { axis: 0, origin: [0.0; 2], pixel: [1.0; 2], size: [0; 2] }
    }
}

impl Ldi {
    /// Rasterises `surface` in `view`.
    #[must_use]
    pub fn rasterize(surface: &TriangleSurface<'_>, view: &View) -> Self {
        let mut ldi = Self::default();
        ldi.rasterize_into(surface, view, 0..surface.triangles.len() as u32);
        ldi
    }

    /// Makes this the image of the triangles `triangles` (indices into `surface.triangles`,
    /// ascending) of `surface` in `view`, reusing its buffers: the same image as
    /// [`Ldi::rasterize`] where the others cross none of the view's rays.
    pub fn rasterize_into(
        &mut self,
        surface: &TriangleSurface<'_>,
        view: &View,
        triangles: impl IntoIterator<Item = u32>,
    ) {
        let Self { starts, fragments, hits, .. } = self;
        hits.clear();
        for t in triangles {
            rasterize_triangle(surface, view, t, surface.triangles[t as usize], hits);
        }
        // Bucketed by pixel (a counting sort, which keeps the triangles' ascending order within
        // a pixel), then each pixel's few crossings sorted by depth in place.
        let pixels = view.size[0] * view.size[1];
        starts.clear();
        starts.resize(pixels + 1, 0);
        for &(p, _) in hits.iter() {
            starts[p as usize + 1] += 1;
        }
        for p in 0..pixels {
            starts[p + 1] += starts[p];
        }
        fragments.clear();
        fragments.resize(hits.len(), Fragment::default());
        for &(p, f) in hits.iter() {
            // `starts[p]` runs ahead as the pixel fills, and is set back below.
            fragments[starts[p as usize] as usize] = f;
            starts[p as usize] += 1;
        }
        for p in (0..pixels).rev() {
            starts[p + 1] = starts[p];
        }
        starts[0] = 0;
        for p in 0..pixels {
            sort_by_depth(&mut fragments[starts[p] as usize..starts[p + 1] as usize]);
        }
        self.view = *view;
    }

    /// The view rasterised.
    #[must_use]
    pub fn view(&self) -> &View {
        &self.view
    }

    /// Pixel `p`'s crossings (pixels row by row: `p = i + size[0] · j`), sorted by depth.
    #[must_use]
    pub fn pixel(&self, p: usize) -> &[Fragment] {
        &self.fragments[self.starts[p] as usize..self.starts[p + 1] as usize]
    }

    /// Number of pixels.
    #[must_use]
    pub fn pixel_count(&self) -> usize {
        self.starts.len() - 1
    }
}

/// Sorts one pixel's crossings, given in ascending triangle order, by depth; at equal depth
/// entering first (a ray grazing the surface at a silhouette vertex or edge enters and leaves at
/// once, an empty interval rather than an inside-out one), then by triangle. An insertion sort,
/// stable, so the triangles' order decides the last tie: a ray crosses a handful of layers.
fn sort_by_depth(fragments: &mut [Fragment]) {
    let before = |a: &Fragment, b: &Fragment| {
        a.depth.total_cmp(&b.depth).then(b.entering.cmp(&a.entering)) == std::cmp::Ordering::Less
    };
    for i in 1..fragments.len() {
        let f = fragments[i];
        let mut j = i;
        while j > 0 && before(&f, &fragments[j - 1]) {
            fragments[j] = fragments[j - 1];
            j -= 1;
        }
        fragments[j] = f;
    }
}

/// The crossings of one triangle with the view's rays, as (pixel, fragment).
fn rasterize_triangle(
    surface: &TriangleSurface<'_>,
    view: &View,
    t: u32,
    tri: [u32; 3],
    out: &mut Vec<(u32, Fragment)>,
) {
    let (u, v) = plane_axes(view.axis);
    let p = tri.map(|i| surface.positions[i as usize]);
    let q = p.map(|x| [x[u], x[v]]);
    // The pixels whose centres the projection's box holds, found first so that a triangle
    // beside the view costs no more than this.
    let lo = [0, 1].map(|k| q[0][k].min(q[1][k]).min(q[2][k]));
    let hi = [0, 1].map(|k| q[0][k].max(q[1][k]).max(q[2][k]));
    let [columns, rows] = view.pixels_in(lo, hi);
    if columns.is_empty() || rows.is_empty() {
        return;
    }
    // The projection's orientation, exactly: its sign is the normal's along the rays.
    let facing = orient(q[0], q[1], q[2]);
    if facing == 0.0 || !facing.is_finite() {
        // Edge-on: its neighbours' crossings close the surface along this ray.
        return;
    }
    // Counter-clockwise in the image plane, with each vertex's barycentric slot remembered.
    let order: [usize; 3] = if facing > 0.0 { [0, 1, 2] } else { [0, 2, 1] };
    let (a, b, c) =
        ((tri[order[0]], q[order[0]]), (tri[order[1]], q[order[1]]), (tri[order[2]], q[order[2]]));
    // Edge functions opposite each vertex of the counter-clockwise order.
    let edges = [Edge::new(b, c), Edge::new(c, a), Edge::new(a, b)];
    let depth_of =
        |w: [f64; 3]| w[0] * p[0][view.axis] + w[1] * p[1][view.axis] + w[2] * p[2][view.axis];
    for j in rows {
        for i in columns.clone() {
            let centre = view.centre(i, j);
            let e = edges.map(|edge| edge.at(centre));
            if !(edges[0].covers(e[0]) && edges[1].covers(e[1]) && edges[2].covers(e[2])) {
                continue;
            }
            // Each value has its exact sign, so a covered centre has none below zero and, the
            // triangle not being edge-on, not all three zero.
            let sum = e[0] + e[1] + e[2];
            if sum <= 0.0 {
                continue;
            }
            let mut weights = [0.0; 3];
            weights[order[0]] = e[0] / sum;
            weights[order[1]] = e[1] / sum;
            weights[order[2]] = e[2] / sum;
            let fragment =
                Fragment { depth: depth_of(weights), triangle: t, weights, entering: facing < 0.0 };
            out.push(((i + view.size[0] * j) as u32, fragment));
        }
    }
}

/// Twice the signed area of the image-plane triangle `a, b, c` (positive counter-clockwise),
/// with its sign exact (Shewchuk's adaptive predicate): the coverage decisions that make a
/// closed surface watertight are decided by signs, and those must not depend on rounding.
#[inline]
fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let coord = |p: [f64; 2]| robust::Coord { x: p[0], y: p[1] };
    robust::orient2d(coord(a), coord(b), coord(c))
}

/// `⌈x⌉` as an integer (saturating; 0 for NaN). Truncation and a compare: `f64::ceil` is a
/// library call on the baseline x86-64 target, and this runs for every triangle of every view.
fn ceil(x: f64) -> i64 {
    let t = x as i64;
    t + i64::from((t as f64) < x)
}

/// `⌊x⌋` as an integer (saturating; 0 for NaN), as [`ceil`].
fn floor(x: f64) -> i64 {
    let t = x as i64;
    t - i64::from((t as f64) > x)
}

/// The edge function of a triangle's directed edge `from → to` (positive on its left, with its
/// sign exact), and which of the two triangles sharing the edge owns a pixel centre on it.
///
/// It is the orientation of `p, q, x` with `p` and `q` the edge's ends in vertex-index order,
/// whichever way the edge runs: with exact signs, every centre lies on one side of the edge
/// for every triangle that has it, or exactly on it, where the "left or top" rule gives it to one
/// of the two triangles sharing the edge.
#[derive(Clone, Copy)]
struct Edge {
    /// The end with the smaller vertex index.
    p: [f64; 2],
    /// The other end.
    q: [f64; 2],
    /// +1 where the edge runs from `p`, −1 where it runs towards it.
    sign: f64,
    /// Whether a centre on the edge is inside: a "left or top" edge of a counter-clockwise
    /// triangle owns it, so that of two triangles sharing the edge (running opposite ways)
    /// exactly one does.
    owns_zero: bool,
}

impl Edge {
    fn new(from: (u32, [f64; 2]), to: (u32, [f64; 2])) -> Self {
        let (p, q, sign) = if from.0 <= to.0 { (from.1, to.1, 1.0) } else { (to.1, from.1, -1.0) };
        let (du, dv) = (to.1[0] - from.1[0], to.1[1] - from.1[1]);
        Self { p, q, sign, owns_zero: dv < 0.0 || (dv == 0.0 && du > 0.0) }
    }

    /// The edge function at `x`.
    #[inline]
    fn at(&self, x: [f64; 2]) -> f64 {
        self.sign * orient(self.p, self.q, x)
    }

    /// Whether a centre with edge function `e` lies on the triangle's inner side of the edge.
    #[inline]
    fn covers(&self, e: f64) -> bool {
        if e == 0.0 { self.owns_zero } else { e > 0.0 }
    }
}
