//! The rasterisation passes behind [`mod@super::intersection`] and [`super::regions`]: for each view
//! over a region, the layered depth images of the surfaces involved and the intervals of each
//! pixel's ray that lie inside both (or inside two layers of one).
//!
//! A frame runs several passes over the same surfaces, so the images and lists are kept between
//! passes ([`Passes`]): once warm, a frame allocates little.
//!
//! **What a view rasterises.** A triangle can matter to a view only if its box meets the
//! region's in the image plane (otherwise it crosses none of the view's rays). Each vertex is
//! coded once per pass by where it lies against the region's faces, and the bits a triangle's
//! three vertices share say on which side of a face its box lies, with no box computed.
//!
//! Along the rays, a closed surface's winding number is zero before its first crossing and
//! past its last, so it can be counted from either end. Counted from the near end, the
//! crossings beyond the region are not needed (nothing beyond it is looked at: a pair's region
//! holds their whole intersection, and a surface against itself is cut to its region); counted
//! from the far end, those before it are not. Each view counts each surface from whichever end
//! leaves fewer triangles to rasterise. An interval left open by the crossings skipped ends
//! where the other surface's ends (a pair) or at the region's face (a surface against itself),
//! as it would anyway.
//!
//! For two surfaces, the one with fewer triangles to rasterise goes first; the second then
//! needs, at each pixel, only what the first's inside span there can meet: counted from the near
//! end, the triangles not beyond that span at some pixel they cover; from the far end, those not
//! before it; again whichever keeps fewer. None of this changes an interval (a test checks it
//! against the definition, every crossing of every ray).

use super::intersection::Side;
use super::ldi::{Fragment, Ldi, TriangleSurface, View, plane_axes};
use super::regions::OverlapInterval;
use incise_math::Vec3;

/// Where a vertex lies against a region, per axis `k` in bits `4k..4k + 4`: below its lower
/// face, above its upper face, and before or beyond those faces by more than [`slack`]. The
/// bits that all three of a triangle's vertices share say on which side of a face its box lies
/// (a NaN coordinate sets every bit of its axis, so that, as with `f64::min` and `f64::max`, it
/// does not widen the box).
mod code {
    pub(super) const BELOW: u16 = 1;
    pub(super) const ABOVE: u16 = 2;
    pub(super) const BEFORE: u16 = 4;
    pub(super) const BEYOND: u16 = 8;

    /// `bits` for axis `k`.
    pub(super) const fn on(bits: u16, k: usize) -> u16 {
        bits << (4 * k)
    }
}

/// Each vertex's [`code`] against `region`, into `out`.
fn codes_into(positions: &[Vec3], (lo, hi): (Vec3, Vec3), out: &mut Vec<u16>) {
    const ALL: u16 = code::BELOW | code::ABOVE | code::BEFORE | code::BEYOND;
    let slacks: [f64; 3] = std::array::from_fn(|k| slack((lo[k], hi[k])));
    let before: Vec3 = std::array::from_fn(|k| lo[k] - slacks[k]);
    let beyond: Vec3 = std::array::from_fn(|k| hi[k] + slacks[k]);
    out.clear();
    // Every bit from a comparison, with no branch; a NaN sets them all.
    out.extend(positions.iter().map(|p| {
        let mut c = 0;
        for k in 0..3 {
            let x = p[k];
            let bits = (u16::from(x < lo[k]) * code::BELOW)
                | (u16::from(x > hi[k]) * code::ABOVE)
                | (u16::from(x < before[k]) * code::BEFORE)
                | (u16::from(x > beyond[k]) * code::BEYOND)
                | (u16::from(x.is_nan()) * ALL);
            c |= code::on(bits, k);
        }
        c
    }));
}

/// The [`code`] bits a triangle's three vertices share.
#[inline]
fn shared(codes: &[u16], tri: [u32; 3]) -> u16 {
    codes[tri[0] as usize] & codes[tri[1] as usize] & codes[tri[2] as usize]
}

/// A triangle's axis-aligned box.
#[inline]
fn triangle_box(surface: &TriangleSurface<'_>, tri: [u32; 3]) -> [Vec3; 2] {
    let p = tri.map(|i| surface.positions[i as usize]);
    [
        std::array::from_fn(|k| p[0][k].min(p[1][k]).min(p[2][k])),
        std::array::from_fn(|k| p[0][k].max(p[1][k]).max(p[2][k])),
    ]
}

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
    /// Still surfaces' complete images, for [`Passes::overlap_intervals_against_still`], the
    /// last used first.
    still: Vec<StillImages>,
    /// Per surface, its vertices' [`code`]s against the region.
    codes: [Vec<u16>; 2],
    /// Per surface and view axis, the triangles over the region's pixels in that view.
    in_plane: [[Vec<u32>; 3]; 2],
    candidates: [Vec<u32>; 2],
    spare: Vec<u32>,
    /// Per pixel of the first surface's image, the depths between which it is inside.
    reach: Vec<[f64; 2]>,
}

impl Passes {
    /// Appends [`super::overlap_intervals`]'s intervals of `a` and `b` to `out`.
    pub fn overlap_intervals(
        &mut self,
        a: &TriangleSurface<'_>,
        b: &TriangleSurface<'_>,
        region: (Vec3, Vec3),
        resolution: usize,
        out: &mut Vec<OverlapInterval>,
    ) {
        self.each_overlap(a, b, region, resolution, |axis, pixel, area, start, end| {
            out.push(pair_interval([a, b], axis, pixel, area, [start, end]));
        });
    }

    /// As [`Passes::overlap_intervals`], with `b` still: its complete images in the three
    /// views over `region` are kept, and reused while `b`'s triangles, their vertices' positions
    /// (bit for bit), `region` and `resolution` stay the same, so that a tissue held in place
    /// costs nothing once drawn. The intervals are those of [`Passes::overlap_intervals`]: a
    /// complete image bounds every interval a partial one does, by the same crossings.
    ///
    /// Only a region that stays put while `a` moves, such as `b`'s own box (which holds the
    /// whole intersection), lets the images be reused.
    pub fn overlap_intervals_against_still(
        &mut self,
        a: &TriangleSurface<'_>,
        b: &TriangleSurface<'_>,
        region: (Vec3, Vec3),
        resolution: usize,
        out: &mut Vec<OverlapInterval>,
    ) {
        /// How many still surfaces' images are kept (a scene rarely holds more than one
        /// tissue in place).
        const KEPT: usize = 4;
        let still = if let Some(i) = self.still.iter().position(|s| s.holds(b, region, resolution))
        {
            self.still.remove(i)
        } else {
            let mut s = if self.still.len() < KEPT {
                StillImages::default()
            } else {
                self.still.pop().unwrap_or_default()
            };
            s.draw(b, region, resolution);
            s
        };
        self.each_overlap_with(
            a,
            b,
            Some(&still),
            region,
            resolution,
            |axis, pixel, area, start, end| {
                out.push(pair_interval([a, b], axis, pixel, area, [start, end]));
            },
        );
        self.still.insert(0, still);
    }

    /// Appends [`super::self_overlap_intervals`]'s intervals of `surface` to `out`.
    pub fn self_overlap_intervals(
        &mut self,
        surface: &TriangleSurface<'_>,
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
                bounds: [start, end].map(|e| e.bound(Side::A, surface)),
            });
        });
    }

    /// Calls `f(axis, pixel, pixel area, start, end)` for every interval of every pixel's ray,
    /// in each of the three views of `resolution` pixels per side over `region` (which must hold
    /// the whole intersection), that lies inside both `a` and `b`; by view, pixel row and
    /// column, depth.
    pub(crate) fn each_overlap(
        &mut self,
        a: &TriangleSurface<'_>,
        b: &TriangleSurface<'_>,
        region: (Vec3, Vec3),
        resolution: usize,
        f: impl FnMut(usize, [usize; 2], f64, Bound<'_>, Bound<'_>),
    ) {
        self.each_overlap_with(a, b, None, region, resolution, f);
    }

    /// [`Passes::each_overlap`], with `b`'s complete images in the three views already drawn
    /// where `still` gives them.
    fn each_overlap_with(
        &mut self,
        a: &TriangleSurface<'_>,
        b: &TriangleSurface<'_>,
        still: Option<&StillImages>,
        region: (Vec3, Vec3),
        resolution: usize,
        mut f: impl FnMut(usize, [usize; 2], f64, Bound<'_>, Bound<'_>),
    ) {
        let (lo, hi) = region;
        if !is_box(region) {
            return;
        }
        let surfaces = [a, b];
        codes_into(a.positions, region, &mut self.codes[0]);
        in_plane_into(a, &self.codes[0], &mut self.in_plane[0]);
        if still.is_none() {
            if std::ptr::eq(a.positions, b.positions) {
                let [ca, cb] = &mut self.codes;
                cb.clone_from(ca);
            } else {
                codes_into(b.positions, region, &mut self.codes[1]);
            }
            in_plane_into(b, &self.codes[1], &mut self.in_plane[1]);
        }
        for axis in 0..3 {
            let view = View::covering(axis, lo, hi, resolution);
            let depths = (lo[axis], hi[axis]);
            let Self { images, codes, in_plane, candidates, spare, reach, .. } = self;
            let mut directions = [Direction::Forward; 2];
            directions[0] =
                candidates_into(a, &codes[0], &in_plane[0][axis], axis, &mut candidates[0], spare);
            if let Some(still) = still {
                // `b` complete, counted from the near end: `a` needs no more than what can
                // meet it.
                keep_reaching(a, &view, &still.reach[axis], directions[0], &mut candidates[0]);
                images[0].rasterize_into(a, &view, candidates[0].iter().copied());
                let [la, _] = &*images;
                each_pixel_overlap(&view, depths, [la, &still.images[axis]], directions, &mut f);
                continue;
            }
            directions[1] =
                candidates_into(b, &codes[1], &in_plane[1][axis], axis, &mut candidates[1], spare);
            // The surface with fewer candidates first; the other skips what lies outside it.
            let (first, second) =
                if candidates[1].len() < candidates[0].len() { (1, 0) } else { (0, 1) };
            images[first].rasterize_into(surfaces[first], &view, candidates[first].iter().copied());
            reach_into(&images[first], directions[first], depths, reach);
            candidates[second].clone_from(&in_plane[second][axis]);
            directions[second] =
                reached(surfaces[second], &view, reach, &mut candidates[second], spare);
            images[second].rasterize_into(
                surfaces[second],
                &view,
                candidates[second].iter().copied(),
            );
            let [la, lb] = &*images;
            each_pixel_overlap(&view, depths, [la, lb], directions, &mut f);
        }
    }

    /// Calls `f(axis, pixel, pixel area, start, end)` for every interval of every pixel's ray,
    /// in each of the three views over `region`, that lies inside two of `surface`'s layers at
    /// once and inside `region`; by view, pixel row and column, depth.
    pub(crate) fn each_self_overlap(
        &mut self,
        surface: &TriangleSurface<'_>,
        region: (Vec3, Vec3),
        resolution: usize,
        mut f: impl FnMut(usize, [usize; 2], f64, End<'_>, End<'_>),
    ) {
        let (lo, hi) = region;
        if !is_box(region) {
            return;
        }
        codes_into(surface.positions, region, &mut self.codes[0]);
        in_plane_into(surface, &self.codes[0], &mut self.in_plane[0]);
        for axis in 0..3 {
            let mut intervals = Vec::new();
            let view = View::covering(axis, lo, hi, resolution);
            let Self { codes, in_plane, candidates, spare, .. } = self;
            let (c, plane) = (&mut candidates[0], &in_plane[0][axis]);
            let direction = candidates_into(surface, &codes[0], plane, axis, c, spare);
            let ldi = &mut self.images[0];
            ldi.rasterize_into(surface, &view, self.candidates[0].iter().copied());
            let area = view.pixel_area();
            for p in 0..ldi.pixel_count() {
                intervals.clear();
                inside(ldi.pixel(p), direction, 2, (lo[axis], hi[axis]), true, &mut intervals);
                let pixel = [p % view.size[0], p / view.size[0]];
                for &(start, end) in &intervals {
                    f(axis, pixel, area, start, end);
                }
            }
        }
    }
}

/// An overlap interval of two surfaces, from its two bounds.
fn pair_interval(
    [a, b]: [&TriangleSurface<'_>; 2],
    axis: usize,
    pixel: [usize; 2],
    area: f64,
    ends: [Bound<'_>; 2],
) -> OverlapInterval {
    OverlapInterval {
        axis,
        pixel,
        area,
        depths: ends.map(|bd| bd.end.depth),
        bounds: ends.map(|bd| {
            let surface = match bd.side {
                Side::A => a,
                Side::B => b,
            };
            bd.end.bound(bd.side, surface)
        }),
    }
}

/// Calls `f(axis, pixel, pixel area, start, end)` for every interval of every pixel's ray in
/// `view` that lies inside both surfaces of `images` (each counted in its `directions`), by
/// pixel row and column, then depth; `depths` is the region's extent along the rays.
fn each_pixel_overlap<'f>(
    view: &View,
    depths: (f64, f64),
    [la, lb]: [&'f Ldi; 2],
    directions: [Direction; 2],
    f: &mut impl FnMut(usize, [usize; 2], f64, Bound<'f>, Bound<'f>),
) {
    let area = view.pixel_area();
    let (mut ia, mut ib) = (Vec::new(), Vec::new());
    for p in 0..view.size[0] * view.size[1] {
        ia.clear();
        inside(la.pixel(p), directions[0], 1, depths, false, &mut ia);
        if ia.is_empty() {
            continue;
        }
        ib.clear();
        inside(lb.pixel(p), directions[1], 1, depths, false, &mut ib);
        let pixel = [p % view.size[0], p / view.size[0]];
        overlaps(&ia, &ib, |mut start, mut end| {
            // Both still inside before or past every crossing listed: only a region that does
            // not hold the whole intersection sees this, and it ends at its face.
            if start.end.crossing.is_none() && start.end.depth < depths.0 {
                start.end.depth = depths.0;
            }
            if end.end.crossing.is_none() && end.end.depth > depths.1 {
                end.end.depth = depths.1;
            }
            if end.end.depth > start.end.depth {
                f(view.axis, pixel, area, start, end);
            }
        });
    }
}

/// A still surface's complete images in the three views over a region: every triangle over the
/// region's pixels drawn, so that every pixel's crossings are all there.
#[derive(Debug, Default)]
struct StillImages {
    /// The region and resolution drawn for (`None`: nothing drawn).
    views: Option<((Vec3, Vec3), usize)>,
    /// The surface's triangles when drawn.
    triangles: Vec<[u32; 3]>,
    /// Each vertex the triangles use, ascending, with its position's bits when drawn.
    vertices: Vec<(u32, [u64; 3])>,
    images: [Ldi; 3],
    /// Per view, each pixel's inside span ([`reach_into`]).
    reach: [Vec<[f64; 2]>; 3],
}

impl StillImages {
    /// Whether these are `surface`'s images over `region` at `resolution`, the surface
    /// unchanged bit for bit since they were drawn.
    fn holds(
        &self,
        surface: &TriangleSurface<'_>,
        region: (Vec3, Vec3),
        resolution: usize,
    ) -> bool {
        let same_views = self.views.is_some_and(|(r, n)| {
            n == resolution
                && bits_of(r.0) == bits_of(region.0)
                && bits_of(r.1) == bits_of(region.1)
        });
        same_views
            && self.triangles == surface.triangles
            && self.vertices.iter().all(|&(v, bits)| {
                surface.positions.get(v as usize).is_some_and(|&p| bits_of(p) == bits)
            })
    }

    /// Draws `surface`'s complete images over `region` at `resolution`.
    fn draw(&mut self, surface: &TriangleSurface<'_>, region: (Vec3, Vec3), resolution: usize) {
        self.triangles.clear();
        self.triangles.extend_from_slice(surface.triangles);
        let mut used: Vec<u32> = surface.triangles.iter().flatten().copied().collect();
        used.sort_unstable();
        used.dedup();
        self.vertices.clear();
        self.vertices.extend(
            used.iter()
                .filter_map(|&v| surface.positions.get(v as usize).map(|&p| (v, bits_of(p)))),
        );
        let (lo, hi) = region;
        let mut codes = Vec::new();
        let mut in_plane: [Vec<u32>; 3] = Default::default();
        if is_box(region) {
            codes_into(surface.positions, region, &mut codes);
            in_plane_into(surface, &codes, &mut in_plane);
        }
        for (axis, (image, triangles)) in self.images.iter_mut().zip(&in_plane).enumerate() {
            let view = View::covering(axis, lo, hi, resolution);
            image.rasterize_into(surface, &view, triangles.iter().copied());
            reach_into(image, Direction::Forward, (lo[axis], hi[axis]), &mut self.reach[axis]);
        }
        self.views = Some((region, resolution));
    }
}

/// A point's coordinates as bits, for comparisons that tell `-0.0` from `0.0`.
fn bits_of(p: Vec3) -> [u64; 3] {
    p.map(f64::to_bits)
}

/// Whether `lo < hi` along every axis.
fn is_box((lo, hi): (Vec3, Vec3)) -> bool {
    (0..3).all(|k| lo[k].partial_cmp(&hi[k]) == Some(std::cmp::Ordering::Less))
}

/// Which of a surface's crossings along a view's rays a pass keeps, and so from which end of a
/// ray the winding number is counted. A closed surface's winding number is zero before every
/// crossing and past every one, so it can be counted from either end; the crossings at the other
/// end may then be left out wherever they cannot bound an interval.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Direction {
    /// Counted from the near end: crossings beyond what is looked at may be missing.
    Forward,
    /// Counted from the far end: crossings before what is looked at may be missing.
    Backward,
}

/// Per view axis, the triangles (ascending) of `surface` whose box meets the region's (that of
/// the vertices' `codes`) in that view's image plane: the only ones that can cross its rays.
fn in_plane_into(surface: &TriangleSurface<'_>, codes: &[u16], out: &mut [Vec<u32>; 3]) {
    for list in out.iter_mut() {
        list.clear();
    }
    let outside = |k: usize| code::on(code::BELOW | code::ABOVE, k);
    let off_plane: [u16; 3] = std::array::from_fn(|axis| {
        let (u, v) = plane_axes(axis);
        outside(u) | outside(v)
    });
    for (t, &tri) in surface.triangles.iter().enumerate() {
        let all = shared(codes, tri);
        for (list, off) in out.iter_mut().zip(off_plane) {
            if all & off == 0 {
                list.push(t as u32);
            }
        }
    }
}

/// Of the triangles `in_plane` (of `surface`, over the region's pixels in the view along
/// `axis`), those (in `out`) that can decide what the view sees inside the region of the
/// vertices' `codes`: those not wholly beyond it (counted forward) or not wholly before it
/// (counted backward), whichever keeps fewer; and the direction chosen. `spare` is scratch.
fn candidates_into(
    surface: &TriangleSurface<'_>,
    codes: &[u16],
    in_plane: &[u32],
    axis: usize,
    out: &mut Vec<u32>,
    spare: &mut Vec<u32>,
) -> Direction {
    let (beyond, before) = (code::on(code::BEYOND, axis), code::on(code::BEFORE, axis));
    out.clear();
    spare.clear();
    for &t in in_plane {
        let all = shared(codes, surface.triangles[t as usize]);
        if all & beyond == 0 {
            out.push(t);
        }
        if all & before == 0 {
            spare.push(t);
        }
    }
    if spare.len() < out.len() {
        std::mem::swap(out, spare);
        Direction::Backward
    } else {
        Direction::Forward
    }
}

/// Per pixel of `ldi` (counted in `direction`), the depths between which a crossing of another
/// surface can bound an overlap with it: its inside span (from its first interval's start to its
/// last's end, open ends at infinity) cut to `depths` (the region's extent along the rays) and
/// widened by its [`slack`]; an empty span (`+∞..−∞`) where it has none.
fn reach_into(ldi: &Ldi, direction: Direction, depths: (f64, f64), out: &mut Vec<[f64; 2]>) {
    let slack = slack(depths);
    let mut intervals = Vec::new();
    out.clear();
    out.extend((0..ldi.pixel_count()).map(|p| {
        intervals.clear();
        let everywhere = (f64::NEG_INFINITY, f64::INFINITY);
        inside(ldi.pixel(p), direction, 1, everywhere, false, &mut intervals);
        match (intervals.first(), intervals.last()) {
            (Some((start, _)), Some((_, end))) => {
                [start.depth.max(depths.0) - slack, end.depth.min(depths.1) + slack]
            }
            _ => [f64::INFINITY, f64::NEG_INFINITY],
        }
    }));
}

/// Keeps of `candidates` (the second surface's triangles over the region's pixels) those
/// needed to find its overlaps with the first surface, whose spans per pixel are `reach`
/// ([`reach_into`]): counted forward, those not beyond the span at some pixel they cover;
/// counted backward, those not before it; whichever direction keeps fewer is returned. `spare`
/// is scratch.
fn reached(
    surface: &TriangleSurface<'_>,
    view: &View,
    reach: &[[f64; 2]],
    candidates: &mut Vec<u32>,
    spare: &mut Vec<u32>,
) -> Direction {
    let (mut forward, mut backward) = (Vec::new(), Vec::new());
    std::mem::swap(&mut forward, candidates);
    std::mem::swap(&mut backward, spare);
    backward.clear();
    forward.retain(|&t| {
        let [ahead, behind] = reaches(surface, view, reach, t, [true, true]);
        if behind {
            backward.push(t);
        }
        ahead
    });
    let direction = if backward.len() < forward.len() {
        std::mem::swap(&mut forward, &mut backward);
        Direction::Backward
    } else {
        Direction::Forward
    };
    *candidates = forward;
    *spare = backward;
    direction
}

/// Keeps of `candidates` (triangles of `surface` counted in `direction` in `view`) those that
/// can bound an overlap with a surface whose spans per pixel are `reach` ([`reach_into`]):
/// counted forward, those not beyond the span at some pixel they cover; backward, those not
/// before it. What is dropped crosses each ray only where the other surface is not inside.
fn keep_reaching(
    surface: &TriangleSurface<'_>,
    view: &View,
    reach: &[[f64; 2]],
    direction: Direction,
    candidates: &mut Vec<u32>,
) {
    let wanted = [direction == Direction::Forward, direction == Direction::Backward];
    candidates.retain(|&t| reaches(surface, view, reach, t, wanted) == wanted);
}

/// Of the `wanted` answers, whether triangle `t` of `surface` is, at some pixel of `view` its
/// box covers, not beyond the span `reach` gives there (counted forward: it is needed) and not
/// before it (counted backward); an answer not wanted is false.
#[inline]
fn reaches(
    surface: &TriangleSurface<'_>,
    view: &View,
    reach: &[[f64; 2]],
    t: u32,
    wanted: [bool; 2],
) -> [bool; 2] {
    let (axis, (u, v)) = (view.axis, plane_axes(view.axis));
    let [lo_t, hi_t] = triangle_box(surface, surface.triangles[t as usize]);
    let [columns, rows] = view.pixels_in([lo_t[u], lo_t[v]], [hi_t[u], hi_t[v]]);
    let (mut ahead, mut behind) = (false, false);
    for j in rows {
        for &[start, end] in &reach[view.size[0] * j..][columns.clone()] {
            ahead |= wanted[0] && lo_t[axis] <= end;
            behind |= wanted[1] && hi_t[axis] >= start;
            if ahead == wanted[0] && behind == wanted[1] {
                return [ahead, behind];
            }
        }
    }
    [ahead, behind]
}

/// How far past a depth a triangle must start to be skipped as lying beyond it: a crossing's
/// depth is interpolated from its vertices' and may land a few units in the last place on
/// either side of a vertex's, so a triangle that merely touches the depth is kept.
fn slack((near, far): (f64, f64)) -> f64 {
    1e-9 * (far.abs() + (far - near).abs())
}

/// Appends the intervals of one ray inside at least `layers` of a surface (winding number
/// `layers` or more), its crossings counted in `direction`. Counted forward, crossings beyond
/// `far` may be missing: an interval still open after the last crossing listed runs on past it.
/// Counted backward, crossings before `near` may be missing: an interval open before the first
/// crossing listed starts before it. With `clip`, every interval is cut to `near..far`;
/// without, the crossings bound it wherever they lie, and an open end lies at infinity, which the
/// other surface's interval always ends before.
fn inside<'f>(
    fragments: &'f [Fragment],
    direction: Direction,
    layers: i32,
    (near, far): (f64, f64),
    clip: bool,
    out: &mut Vec<(End<'f>, End<'f>)>,
) {
    let mut push = |start: Option<&'f Fragment>, end: Option<&'f Fragment>| {
        let start = match start {
            Some(s) if !clip || s.depth >= near => End { depth: s.depth, crossing: Some(s) },
            _ if clip => End { depth: near, crossing: None },
            _ => End { depth: f64::NEG_INFINITY, crossing: None },
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
    let sign = |f: &Fragment| if f.entering { 1 } else { -1 };
    // The winding number before the first crossing listed: zero, or, counted from the far end
    // where the surface's winding is zero again, minus the sum of all those listed.
    let mut winding = match direction {
        Direction::Forward => 0,
        Direction::Backward => -fragments.iter().map(sign).sum::<i32>(),
    };
    let mut start: Option<Option<&'f Fragment>> = (winding >= layers).then_some(None);
    for f in fragments {
        let before = winding;
        winding += sign(f);
        if before < layers && winding >= layers {
            start = Some(Some(f));
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
