//! The rasterisation passes behind [`mod@super::intersection`] and [`super::regions`]: for each view
//! over a region, the layered depth images of the surfaces involved and the intervals of each
//! pixel's ray that lie inside both (or inside two layers of one).
//!
//! A frame runs several passes over the same surfaces, so what can be shared is: each
//! triangle's box is found once per frame ([`TriangleBoxes`]), and the images and lists are
//! kept between passes ([`Passes`]), so that once warm a frame allocates little.
//!
//! **What a view rasterises.** A triangle can matter to a view only if its box meets the
//! region's in the image plane (otherwise it crosses none of the view's rays) and does not lie
//! wholly beyond the region along the rays: the winding number at a depth counts the crossings
//! before it, never those after, and nothing beyond the region is looked at (a pair's region
//! holds their whole intersection; a surface against itself is cut to its region). For two
//! surfaces, the second rasterised also skips every triangle that lies, at each pixel it covers,
//! beyond the first's last crossing there: nothing of the first lies there to overlap. An
//! interval left open by the crossings skipped ends where the other surface's ends (a pair) or
//! at the region's far face (a surface against itself), as it would anyway. None of this
//! changes an interval (a test checks this against the definition, every crossing of every ray).

use super::intersection::Side;
use super::ldi::{Fragment, Ldi, TriangleSurface, View, plane_axes};
use super::regions::OverlapInterval;
use incise_math::Vec3;

/// Every triangle's axis-aligned box, and the surface's.
#[derive(Clone, Debug, Default)]
pub struct TriangleBoxes {
    /// Per triangle, its lower and upper corner.
    boxes: Vec<[Vec3; 2]>,
    bounds: Option<(Vec3, Vec3)>,
}

impl TriangleBoxes {
    /// The boxes of `surface`'s triangles.
    #[must_use]
    pub fn of(surface: &TriangleSurface<'_>) -> Self {
        let mut boxes = Self::default();
        boxes.update(surface);
        boxes
    }

    /// Makes these the boxes of `surface`'s triangles, reusing the allocation.
    pub fn update(&mut self, surface: &TriangleSurface<'_>) {
        self.boxes.clear();
        self.boxes.extend(surface.triangles.iter().map(|tri| {
            let p = tri.map(|i| surface.positions[i as usize]);
            [
                std::array::from_fn(|k| p[0][k].min(p[1][k]).min(p[2][k])),
                std::array::from_fn(|k| p[0][k].max(p[1][k]).max(p[2][k])),
            ]
        }));
        self.bounds = self.boxes.split_first().map(|(first, rest)| {
            rest.iter().fold((first[0], first[1]), |(lo, hi), b| {
                (
                    std::array::from_fn(|k| lo[k].min(b[0][k])),
                    std::array::from_fn(|k| hi[k].max(b[1][k])),
                )
            })
        });
    }

    /// The box holding every triangle (`None` without triangles), as
    /// [`TriangleSurface::bounds`].
    #[must_use]
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }
}

/// A surface with its triangles' boxes (which must be the surface's current ones).
pub type Boxed<'s, 'b> = (&'s TriangleSurface<'s>, &'b TriangleBoxes);

/// One end of an interval along a ray: the crossing that makes it, or a face of the region
/// looked at, which cuts it and which no vertex moves.
#[derive(Clone, Copy, Debug)]
pub(crate) struct End<'f> {
    pub(crate) depth: f64,
    pub(crate) crossing: Option<&'f Fragment>,
}

impl End<'_> {
    /// As an interval's bound: the side, the crossed triangle and the crossing's weights; a cut
    /// end has zero weights.
    pub(crate) fn bound(
        self,
        side: Side,
        surface: &TriangleSurface<'_>,
    ) -> (Side, [u32; 3], [f64; 3]) {
        match self.crossing {
            Some(f) => (side, surface.triangles[f.triangle as usize], f.weights),
            None => (side, [0; 3], [0.0; 3]),
        }
    }
}

/// An end of an overlap interval and the surface it belongs to.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bound<'f> {
    pub(crate) end: End<'f>,
    pub(crate) side: Side,
}

/// The images and lists the passes reuse.
#[derive(Debug, Default)]
pub struct Passes {
    images: [Ldi; 2],
    candidates: [Vec<u32>; 2],
    /// Per pixel of the first surface's image, the depth past which nothing of it can bound an
    /// interval.
    reach: Vec<f64>,
}

impl Passes {
    /// Appends [`super::overlap_intervals`]'s intervals of `a` and `b` to `out`.
    pub fn overlap_intervals(
        &mut self,
        a: Boxed<'_, '_>,
        b: Boxed<'_, '_>,
        region: (Vec3, Vec3),
        resolution: usize,
        out: &mut Vec<OverlapInterval>,
    ) {
        self.each_overlap(a, b, region, resolution, |axis, pixel, area, start, end| {
            out.push(OverlapInterval {
                axis,
                pixel,
                area,
                depths: [start.end.depth, end.end.depth],
                bounds: [start, end].map(|bd| {
                    let surface = match bd.side {
                        Side::A => a.0,
                        Side::B => b.0,
                    };
                    bd.end.bound(bd.side, surface)
                }),
            });
        });
    }

    /// Appends [`super::self_overlap_intervals`]'s intervals of `surface` to `out`.
    pub fn self_overlap_intervals(
        &mut self,
        surface: Boxed<'_, '_>,
        region: (Vec3, Vec3),
        resolution: usize,
        out: &mut Vec<OverlapInterval>,
    ) {
        self.each_self_overlap(surface, region, resolution, |axis, pixel, area, start, end| {
            out.push(OverlapInterval {
                axis,
                pixel,
                area,
                depths: [start.depth, end.depth],
                bounds: [start, end].map(|e| e.bound(Side::A, surface.0)),
            });
        });
    }

    /// Calls `f(axis, pixel, pixel area, start, end)` for every interval of every pixel's ray,
    /// in each of the three views of `resolution` pixels per side over `region` (which must hold
    /// the whole intersection), that lies inside both `a` and `b`; by view, pixel row and
    /// column, depth.
    pub(crate) fn each_overlap(
        &mut self,
        (a, ba): Boxed<'_, '_>,
        (b, bb): Boxed<'_, '_>,
        region: (Vec3, Vec3),
        resolution: usize,
        mut f: impl FnMut(usize, [usize; 2], f64, Bound<'_>, Bound<'_>),
    ) {
        let (lo, hi) = region;
        if !is_box(region) {
            return;
        }
        for axis in 0..3 {
            let view = View::covering(axis, lo, hi, resolution);
            let depths = (lo[axis], hi[axis]);
            let Self { images, candidates, reach } = self;
            candidates_into(ba, region, axis, &mut candidates[0]);
            candidates_into(bb, region, axis, &mut candidates[1]);
            // The surface with fewer candidates first; the other skips what lies beyond it.
            let (first, second) =
                if candidates[1].len() < candidates[0].len() { (1, 0) } else { (0, 1) };
            let surfaces = [a, b];
            let boxes = [ba, bb];
            images[first].rasterize_into(surfaces[first], &view, candidates[first].iter().copied());
            reach_into(&images[first], reach);
            let slack = slack(depths);
            let second_boxes = boxes[second];
            let reached = |t: &u32| {
                let [lo_t, hi_t] = second_boxes.boxes[*t as usize];
                let (u, v) = plane_axes(axis);
                let [columns, rows] = view.pixels_in([lo_t[u], lo_t[v]], [hi_t[u], hi_t[v]]);
                rows.flat_map(|j| columns.clone().map(move |i| i + view.size[0] * j))
                    .any(|p| lo_t[axis] <= reach[p] + slack)
            };
            candidates[second].retain(reached);
            images[second].rasterize_into(
                surfaces[second],
                &view,
                candidates[second].iter().copied(),
            );
            let [la, lb] = &*images;
            let area = view.pixel_area();
            let (mut ia, mut ib) = (Vec::new(), Vec::new());
            for p in 0..view.size[0] * view.size[1] {
                ia.clear();
                inside(la.pixel(p), 1, depths, false, &mut ia);
                if ia.is_empty() {
                    continue;
                }
                ib.clear();
                inside(lb.pixel(p), 1, depths, false, &mut ib);
                let pixel = [p % view.size[0], p / view.size[0]];
                overlaps(&ia, &ib, |start, mut end| {
                    // Both still inside past every crossing listed: only a region that does not
                    // hold the whole intersection sees this, and it ends at its face.
                    if end.end.crossing.is_none() && end.end.depth > depths.1 {
                        end.end.depth = depths.1;
                        if end.end.depth <= start.end.depth {
                            return;
                        }
                    }
                    f(axis, pixel, area, start, end);
                });
            }
        }
    }

    /// Calls `f(axis, pixel, pixel area, start, end)` for every interval of every pixel's ray,
    /// in each of the three views over `region`, that lies inside two of `surface`'s layers at
    /// once and inside `region`; by view, pixel row and column, depth.
    pub(crate) fn each_self_overlap(
        &mut self,
        (surface, boxes): Boxed<'_, '_>,
        region: (Vec3, Vec3),
        resolution: usize,
        mut f: impl FnMut(usize, [usize; 2], f64, End<'_>, End<'_>),
    ) {
        let (lo, hi) = region;
        if !is_box(region) {
            return;
        }
        for axis in 0..3 {
            let mut intervals = Vec::new();
            let view = View::covering(axis, lo, hi, resolution);
            candidates_into(boxes, region, axis, &mut self.candidates[0]);
            let ldi = &mut self.images[0];
            ldi.rasterize_into(surface, &view, self.candidates[0].iter().copied());
            let area = view.pixel_area();
            for p in 0..ldi.pixel_count() {
                intervals.clear();
                inside(ldi.pixel(p), 2, (lo[axis], hi[axis]), true, &mut intervals);
                let pixel = [p % view.size[0], p / view.size[0]];
                for &(start, end) in &intervals {
                    f(axis, pixel, area, start, end);
                }
            }
        }
    }
}

/// Whether `lo < hi` along every axis.
fn is_box((lo, hi): (Vec3, Vec3)) -> bool {
    (0..3).all(|k| lo[k].partial_cmp(&hi[k]) == Some(std::cmp::Ordering::Less))
}

/// The triangles (ascending) that can decide what the view along `axis` sees inside `region`:
/// those whose box meets the region's in the image plane and does not lie wholly beyond it.
fn candidates_into(boxes: &TriangleBoxes, (lo, hi): (Vec3, Vec3), axis: usize, out: &mut Vec<u32>) {
    let (u, v) = plane_axes(axis);
    let beyond = hi[axis] + slack((lo[axis], hi[axis]));
    out.clear();
    out.extend(
        boxes
            .boxes
            .iter()
            .enumerate()
            .filter(|(_, [bl, bh])| {
                bl[u] <= hi[u]
                    && bh[u] >= lo[u]
                    && bl[v] <= hi[v]
                    && bh[v] >= lo[v]
                    && bl[axis] <= beyond
            })
            .map(|(t, _)| t as u32),
    );
}

/// Per pixel of `ldi`, the depth past which its surface has no crossing that can bound an
/// interval: its last crossing, or infinity where the ray is still inside after it (a crossing
/// beyond the region was skipped); minus infinity where it has none.
fn reach_into(ldi: &Ldi, out: &mut Vec<f64>) {
    out.clear();
    out.extend((0..ldi.pixel_count()).map(|p| {
        let fragments = ldi.pixel(p);
        let winding: i32 = fragments.iter().map(|f| if f.entering { 1 } else { -1 }).sum();
        match fragments.last() {
            None => f64::NEG_INFINITY,
            Some(_) if winding > 0 => f64::INFINITY,
            Some(f) => f.depth,
        }
    }));
}

/// How far past a depth a triangle must start to be skipped as lying beyond it: a crossing's
/// depth is interpolated from its vertices' and may land a few units in the last place on
/// either side of a vertex's, so a triangle that merely touches the depth is kept.
fn slack((near, far): (f64, f64)) -> f64 {
    1e-9 * (far.abs() + (far - near).abs())
}

/// Appends the intervals of one ray inside at least `layers` of a surface (winding number
/// `layers` or more). Crossings beyond `far` may be missing: an interval still open after the
/// last crossing listed runs to `far` and is cut there. With `clip`, every interval is cut to
/// `near..far`; without, the crossings bound it wherever they lie, and an open one is cut
/// beyond every depth (at infinity), which the other surface's interval always ends before.
fn inside<'f>(
    fragments: &'f [Fragment],
    layers: i32,
    (near, far): (f64, f64),
    clip: bool,
    out: &mut Vec<(End<'f>, End<'f>)>,
) {
    let mut push = |start: &'f Fragment, end: Option<&'f Fragment>| {
        let start = if clip && start.depth < near {
            End { depth: near, crossing: None }
        } else {
            End { depth: start.depth, crossing: Some(start) }
        };
        let end = match end {
            Some(e) if !clip || e.depth <= far => End { depth: e.depth, crossing: Some(e) },
            _ if clip => End { depth: far, crossing: None },
            _ => End { depth: f64::INFINITY, crossing: None },
        };
        if end.depth > start.depth {
            out.push((start, end));
        }
    };
    let mut winding = 0i32;
    let mut start = None;
    for f in fragments {
        let before = winding;
        winding += if f.entering { 1 } else { -1 };
        if before < layers && winding >= layers {
            start = Some(f);
        } else if before >= layers
            && winding < layers
            && let Some(s) = start.take()
        {
            push(s, Some(f));
        }
    }
    if let Some(s) = start {
        push(s, None);
    }
}

/// Calls `f(start, end)` for each non-empty intersection of two sorted interval lists, each end
/// with the surface whose interval makes it. At equal depths the first surface's crossing wins,
/// and any crossing wins over a cut end.
fn overlaps<'f>(
    a: &[(End<'f>, End<'f>)],
    b: &[(End<'f>, End<'f>)],
    mut f: impl FnMut(Bound<'f>, Bound<'f>),
) {
    use std::cmp::Ordering::{Equal, Greater, Less};
    // Whether `x` (of A) is taken over `y` (of B) at equal depth.
    let a_first = |x: &End<'_>, y: &End<'_>| x.crossing.is_some() || y.crossing.is_none();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let ((sa, ea), (sb, eb)) = (a[i], b[j]);
        let later = match sa.depth.partial_cmp(&sb.depth) {
            Some(Greater) => true,
            Some(Equal) => a_first(&sa, &sb),
            _ => false,
        };
        let start =
            if later { Bound { end: sa, side: Side::A } } else { Bound { end: sb, side: Side::B } };
        let earlier = match ea.depth.partial_cmp(&eb.depth) {
            Some(Less) => true,
            Some(Equal) => a_first(&ea, &eb),
            _ => false,
        };
        let end = if earlier {
            Bound { end: ea, side: Side::A }
        } else {
            Bound { end: eb, side: Side::B }
        };
        if end.end.depth > start.end.depth {
            f(start, end);
        }
        if ea.depth <= eb.depth {
            i += 1;
        } else {
            j += 1;
        }
    }
}
