//! The intersection volume of two closed surfaces and its gradient with respect to every vertex
//! (Faure et al. 2008; paper 1 §3, Fig. 10), from layered depth images along x, y and z over the
//! overlap of the two surfaces' bounding boxes.
//!
//! Along one axis, each pixel's ray is inside a surface where its winding number (crossings
//! entered minus crossings left, in depth order) is positive; the intersection is where both
//! are, and its length times the pixel's area summed over the pixels is the volume seen along that
//! axis. The volume is the mean of the three axes' estimates.
//!
//! The gradient's component along an axis comes from that axis's view alone. Only the crossings
//! that bound the intersection move it: a vertex moved by `δ` along the rays moves a crossing of
//! its triangle by `weight · δ`, so the crossing where an intersection ends adds `area · weight`
//! to its vertices' component and the one where it begins subtracts it. Summed over the pixels
//! this samples `∫ weight · n_axis dA` over the intersection's boundary, faces along the rays
//! included (they contribute nothing to that component). A view's other components would have to
//! come from how the surface tilts, infinitely so for a face along its rays: those are left to the
//! views that see the face.
//!
//! Nothing is precomputed and nothing assumes the surfaces apart: any overlap, however deep, has
//! a volume and a gradient that shrinks it (what paper 1 relies on to keep simulating while it
//! cuts).

use super::ldi::{Fragment, TriangleSurface};
use super::passes::Passes;
use super::regions::OverlapInterval;
use incise_math::Vec3;

/// The intersection of two surfaces as three views see it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Intersection {
    /// The intersection volume (the mean of the three axes' estimates).
    pub volume: f64,
    /// The volume seen along x, y and z.
    pub volume_by_axis: [f64; 3],
    /// The volume's gradient for every vertex of the first surface (zero for vertices it does
    /// not touch): component `k` is `∂volume_by_axis[k]/∂p_k` on a fixed pixel grid.
    pub gradient_a: Vec<Vec3>,
    /// The same for the second surface.
    pub gradient_b: Vec<Vec3>,
}

/// The intersection volume of `a` and `b` and its gradient, from views of `resolution` pixels
/// per side over the overlap of their bounding boxes. Surfaces whose boxes do not overlap have
/// none (zero volume and gradients, nothing rasterised).
#[must_use]
pub fn intersection(
    a: &TriangleSurface<'_>,
    b: &TriangleSurface<'_>,
    resolution: usize,
) -> Intersection {
    let (Some((alo, ahi)), Some((blo, bhi))) = (a.bounds(), b.bounds()) else {
        return nothing(a, b);
    };
    let lo: Vec3 = std::array::from_fn(|k| alo[k].max(blo[k]));
    let hi: Vec3 = std::array::from_fn(|k| ahi[k].min(bhi[k]));
    intersection_in(a, b, (lo, hi), resolution)
}

/// [`intersection`] seen through views over the box `region` (only what lies in it counts). The
/// gradient is the volume's for this fixed pixel grid: the grid does not follow the vertices.
#[must_use]
pub fn intersection_in(
    a: &TriangleSurface<'_>,
    b: &TriangleSurface<'_>,
    region: (Vec3, Vec3),
    resolution: usize,
) -> Intersection {
    let mut out = nothing(a, b);
    Passes::default().each_overlap(a, b, region, resolution, |axis, _, area, start, end| {
        out.volume_by_axis[axis] += area * (end.end.depth - start.end.depth);
        for (bound, sign) in [(start, -1.0), (end, 1.0)] {
            let (surface, gradient) = match bound.side {
                Side::A => (a, &mut out.gradient_a),
                Side::B => (b, &mut out.gradient_b),
            };
            if let Some(crossing) = bound.end.crossing {
                add_crossing(surface, gradient, crossing, axis, sign * area);
            }
        }
    });
    out.volume = out.volume_by_axis.iter().sum::<f64>() / 3.0;
    out
}

/// The intervals of every pixel's ray, in each of the three views of `resolution` pixels per
/// side over `region`, that lie inside both `a` and `b`; by view, pixel row and column, depth.
/// The region must hold the whole intersection (the surfaces' common box does): it sets the
/// pixel grid and what is rasterised, and an interval is bounded by the crossings that make it.
#[must_use]
pub fn overlap_intervals(
    a: &TriangleSurface<'_>,
    b: &TriangleSurface<'_>,
    region: (Vec3, Vec3),
    resolution: usize,
) -> Vec<OverlapInterval> {
    let mut out = Vec::new();
    Passes::default().overlap_intervals(a, b, region, resolution, &mut out);
    out
}

/// The intervals of every pixel's ray, in each of the three views of `resolution` pixels per
/// side over `region`, that lie inside two of `surface`'s layers at once (all on [`Side::A`]);
/// by view, pixel row and column, depth. Only what lies inside `region` counts: a ray runs
/// through the whole surface, and an interval reaching past the region along it is cut at the
/// region's face, where its bound has zero weights (moving the surface does not move that end).
#[must_use]
pub fn self_overlap_intervals(
    surface: &TriangleSurface<'_>,
    region: (Vec3, Vec3),
    resolution: usize,
) -> Vec<OverlapInterval> {
    let mut out = Vec::new();
    Passes::default().self_overlap_intervals(surface, region, resolution, &mut out);
    out
}

/// Where one surface overlaps itself (a cut's flap pressed into the tissue beside it).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SelfIntersection {
    /// The volume inside two of the surface's layers at once (mean of the three axes).
    pub volume: f64,
    /// The volume seen along x, y and z.
    pub volume_by_axis: [f64; 3],
    /// The volume's gradient for every vertex, as [`Intersection::gradient_a`].
    pub gradient: Vec<Vec3>,
}

/// The volume where `surface` overlaps itself (winding number two or more: inside two of its
/// layers at once) and its gradient, from views of `resolution` pixels per side over its bounding
/// box. A surface that does not overlap itself has none, however it folds.
#[must_use]
pub fn self_intersection(surface: &TriangleSurface<'_>, resolution: usize) -> SelfIntersection {
    let mut out = SelfIntersection {
        gradient: vec![[0.0; 3]; surface.positions.len()],
        ..Default::default()
    };
    let Some(region) = surface.bounds() else { return out };
    Passes::default().each_self_overlap(
        surface,
        region,
        resolution,
        |axis, _, area, start, end| {
            out.volume_by_axis[axis] += area * (end.depth - start.depth);
            for (e, scale) in [(start, -area), (end, area)] {
                if let Some(crossing) = e.crossing {
                    add_crossing(surface, &mut out.gradient, crossing, axis, scale);
                }
            }
        },
    );
    out.volume = out.volume_by_axis.iter().sum::<f64>() / 3.0;
    out
}

/// No intersection: zero volume and gradients sized for both surfaces.
fn nothing(a: &TriangleSurface<'_>, b: &TriangleSurface<'_>) -> Intersection {
    Intersection {
        gradient_a: vec![[0.0; 3]; a.positions.len()],
        gradient_b: vec![[0.0; 3]; b.positions.len()],
        ..Intersection::default()
    }
}

/// Which surface a crossing belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The first surface (or the only one, for a surface against itself).
    A,
    /// The second surface.
    B,
}

/// Adds `scale` times one crossing's depth derivative to component `axis` of its triangle's
/// vertices' gradient.
fn add_crossing(
    surface: &TriangleSurface<'_>,
    gradient: &mut [Vec3],
    f: &Fragment,
    axis: usize,
    scale: f64,
) {
    let tri = surface.triangles[f.triangle as usize];
    for (k, &v) in tri.iter().enumerate() {
        gradient[v as usize][axis] += scale * f.weights[k];
    }
}
