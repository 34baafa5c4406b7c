//! Layered depth images (Faure et al. 2008, used by paper 1 §3, Fig. 10): closed triangle
//! surfaces rasterised along one axis, keeping every surface crossing of every pixel's ray, not
//! only the nearest. Sorted by depth, a ray's crossings give the depth intervals inside the
//! surface, whatever its shape or overlaps.
//!
//! A pixel's ray runs along `+axis` through the pixel's centre. A triangle covers a pixel when the
//! centre lies inside its projection, with a tie rule on edges and vertices (below) so that a
//! closed surface is crossed exactly once where its triangles meet: no double crossings and no
//! gaps, on any grid, even with vertices exactly on pixel centres.

use crate::mesh_shape::sub;
use incise_math::Vec3;
use incise_math::mat3::cross;

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

    fn centre(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin[0] + (i as f64 + 0.5) * self.pixel[0],
            self.origin[1] + (j as f64 + 0.5) * self.pixel[1],
        ]
    }
}

/// The two axes of the image plane of a view along `axis`.
#[must_use]
pub fn plane_axes(axis: usize) -> (usize, usize) {
    ((axis + 1) % 3, (axis + 2) % 3)
}

/// One crossing of a pixel's ray with a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
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
#[derive(Clone, Debug)]
pub struct Ldi {
    view: View,
    /// Pixel `p`'s fragments are `fragments[starts[p]..starts[p + 1]]`; pixels row by row.
    starts: Vec<u32>,
    fragments: Vec<Fragment>,
}

impl Ldi {
    /// Rasterises `surface` in `view`.
    #[must_use]
    pub fn rasterize(surface: &TriangleSurface<'_>, view: &View) -> Self {
        let mut hits: Vec<(u32, Fragment)> = Vec::new();
        for (t, tri) in surface.triangles.iter().enumerate() {
            rasterize_triangle(surface, view, t as u32, *tri, &mut hits);
        }
        // At equal depth entering first: a ray grazing the surface at a silhouette vertex or edge
        // enters and leaves at once, an empty interval rather than an inside-out one.
        hits.sort_by(|a, b| {
            a.0.cmp(&b.0)
                .then(a.1.depth.total_cmp(&b.1.depth))
                .then(b.1.entering.cmp(&a.1.entering))
                .then(a.1.triangle.cmp(&b.1.triangle))
        });
        let pixels = view.size[0] * view.size[1];
        let mut starts = vec![0u32; pixels + 1];
        for &(p, _) in &hits {
            starts[p as usize + 1] += 1;
        }
        for p in 0..pixels {
            starts[p + 1] += starts[p];
        }
        Self { view: *view, starts, fragments: hits.into_iter().map(|(_, f)| f).collect() }
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
    let normal = cross(&sub(p[1], p[0]), &sub(p[2], p[0]));
    let nz = normal[view.axis];
    if nz == 0.0 || !nz.is_finite() {
        // Edge-on: its neighbours' crossings close the surface along this ray.
        return;
    }
    let q = p.map(|x| [x[u], x[v]]);
    // Counter-clockwise in the image plane, with each vertex's barycentric slot remembered.
    let order: [usize; 3] = if nz > 0.0 { [0, 1, 2] } else { [0, 2, 1] };
    let (a, b, c) =
        ((tri[order[0]], q[order[0]]), (tri[order[1]], q[order[1]]), (tri[order[2]], q[order[2]]));
    let lo = [q[0][0].min(q[1][0]).min(q[2][0]), q[0][1].min(q[1][1]).min(q[2][1])];
    let hi = [q[0][0].max(q[1][0]).max(q[2][0]), q[0][1].max(q[1][1]).max(q[2][1])];
    let first = |k: usize| {
        (((lo[k] - view.origin[k]) / view.pixel[k] - 0.5).ceil().max(0.0) as usize)
            .min(view.size[k])
    };
    let last = |k: usize| {
        let x = ((hi[k] - view.origin[k]) / view.pixel[k] - 0.5).floor();
        if x < 0.0 { 0 } else { (x as usize + 1).min(view.size[k]) }
    };
    let depth_of =
        |w: [f64; 3]| w[0] * p[0][view.axis] + w[1] * p[1][view.axis] + w[2] * p[2][view.axis];
    for j in first(1)..last(1) {
        for i in first(0)..last(0) {
            let centre = view.centre(i, j);
            // Edge functions opposite each vertex of the counter-clockwise order.
            let ea = edge(b, c, centre);
            let eb = edge(c, a, centre);
            let ec = edge(a, b, centre);
            if !(covers(ea, b.1, c.1) && covers(eb, c.1, a.1) && covers(ec, a.1, b.1)) {
                continue;
            }
            let sum = ea + eb + ec;
            if sum <= 0.0 {
                continue;
            }
            let mut weights = [0.0; 3];
            weights[order[0]] = ea / sum;
            weights[order[1]] = eb / sum;
            weights[order[2]] = ec / sum;
            let fragment =
                Fragment { depth: depth_of(weights), triangle: t, weights, entering: nz < 0.0 };
            out.push(((i + view.size[0] * j) as u32, fragment));
        }
    }
}

/// The edge function of the directed edge `from → to` at `x` (positive on its left), computed
/// from the endpoint with the smaller vertex index whichever way the edge runs, so that two
/// triangles sharing the edge get values of exactly opposite sign.
fn edge(from: (u32, [f64; 2]), to: (u32, [f64; 2]), x: [f64; 2]) -> f64 {
    let (p, q, sign) = if from.0 <= to.0 { (from.1, to.1, 1.0) } else { (to.1, from.1, -1.0) };
    sign * ((q[0] - p[0]) * (x[1] - p[1]) - (q[1] - p[1]) * (x[0] - p[0]))
}

/// Whether a pixel centre with edge function `e` for the edge `from → to` of a
/// counter-clockwise triangle lies on its inner side: strictly, or on the edge when the edge is a
/// "left or top" one. Of two triangles sharing an edge (running opposite ways), exactly one owns
/// a centre on it.
fn covers(e: f64, from: [f64; 2], to: [f64; 2]) -> bool {
    if e != 0.0 {
        return e > 0.0;
    }
    let (du, dv) = (to[0] - from[0], to[1] - from[1]);
    dv < 0.0 || (dv == 0.0 && du > 0.0)
}
