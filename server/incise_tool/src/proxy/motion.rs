//! The proxy's motion in one step: from where it was toward the device's pose, stopped where
//! its outer shape meets the tissue, sliding along what stopped it (the god-object of Zilles &
//! Salisbury 1995, with a finite shape as in Ruspini et al. 1997 and the pose's rotation moved
//! along with its position, as in Ortega et al. 2007).
//!
//! **What may not be entered.** A pose is allowed when no triangle of the tissue's surface that
//! was clear of the shape at the step's start, or touching it, reaches more than
//! [`PENETRATION_TOLERANCE`] into it, and the shape's centre has not gone from outside the
//! tissue's volume to inside it. The first rule stops a shape of any size, thinner than a
//! triangle included, wherever it meets a triangle. The second catches a shape that would be
//! wholly inside, touching no triangle. A triangle the proxy already overlaps at the step's
//! start may not reach deeper into it than it does (the tolerance again): the walls of the cut
//! its own blade made, which it moves along, or tissue that came onto it. Such tissue is pushed
//! out by the contact's penalty, and tissue that moves onto a resting proxy carries it out after
//! the step (`incise_sim`), so these overlaps last only where a cut made them; and they never
//! let the proxy sink into the tissue. A cutting tool's proxy in its own cut is also stopped
//! where the cut ends: its cutting shape may not move into material it has not cut
//! ([`Obstacles::uncut`]).
//!
//! **Cost.** Each triangle's clearance at the step's start bounds its distance at any pose that
//! moves no point of the shape further than that: only the triangles a pose comes near are
//! tested.
//!
//! **The search.** Along the straight path between two poses, the allowed poses are tested at
//! steps no longer than half the shape's thinnest dimension (no point of the shape moves more
//! than that between two tests, so no triangle is jumped over), and between the last allowed and
//! the first refused one the contact is found by bisection, to [`RESOLUTION`].
//!
//! **Sliding.** Once stopped, the rest of the device's displacement is projected onto the
//! directions that the constraints met so far allow (their outward normals, at most three), and
//! the proxy moves on along it, up to three times. With friction `μ`, the proxy slides only by
//! what the tangential offset exceeds `μ` times the depth of the device behind the constraint:
//! the friction cone of the coupling force.

use super::gap::{Reach, gap_at_least, surely_at_least, triangle_gap};
use crate::geometry::{norm, sub};
use crate::pose::Pose;
use crate::shape::Shape;
use incise_math::Vec3;
use incise_math::mat3::dot;

/// How much deeper than at the step's start a triangle may reach into a moving proxy (m): the
/// tolerance of the contact search.
pub const PENETRATION_TOLERANCE: f64 = 1e-6;

/// The length to which a contact along a path is located (m).
pub const RESOLUTION: f64 = 2.5e-7;

/// Most tests along one straight path: a 5 cm jump of a 1 mm blade needs 100.
const MAX_SAMPLES: usize = 512;

/// Most halvings of one bisection: enough to locate a contact to [`RESOLUTION`] on a path of
/// `2^60 RESOLUTION`.
const MAX_HALVINGS: u32 = 60;

/// A triangle of the tissue's surface near the proxy: its surface's triangle id, its vertices
/// and their deformed positions (grid frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Facet {
    /// The triangle's id in its surface.
    pub id: u32,
    /// Its vertices' ids, counter-clockwise seen from outside.
    pub vertices: [u32; 3],
    /// Their deformed positions (m, grid frame).
    pub corners: [Vec3; 3],
}

/// Whether a cutting shape moved from the first pose to the second would be in uncut material.
pub type UncutTest<'a> = dyn Fn(&Pose, &Pose) -> bool + 'a;

/// What a proxy may not enter in one step: the surface's triangles near its path, whether a
/// point lies inside the tissue's volume, and for a cutting tool the material it has not cut.
pub struct Obstacles<'a> {
    /// The triangles that may meet the shape anywhere along the step's path.
    pub facets: &'a [Facet],
    /// Whether a point (grid frame) lies inside the tissue's volume.
    pub inside: &'a dyn Fn(Vec3) -> bool,
    /// For a tool that cuts: whether its cutting shape, moved from the step's start pose to a
    /// pose, would be in material it has not cut (voxels it did not hold, links its blade has
    /// not severed). A proxy in its own cut overlaps the cut's walls, which do not stop it;
    /// this does, where the cut ends.
    pub uncut: Option<&'a UncutTest<'a>>,
}

/// Where the proxy went in a step.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// Its new pose.
    pub pose: Pose,
    /// Whether the tissue stopped it short of the device's pose.
    pub blocked: bool,
    /// The outward normals (grid frame, away from the tissue) of what stopped it, at most three.
    pub normals: Vec<Vec3>,
}

/// The farthest any point of `shape`'s bounding box moves between poses `a` and `b` (m).
#[must_use]
pub fn travel(shape: &Shape, a: &Pose, b: &Pose) -> f64 {
    let (lo, hi) = shape.bounds();
    (0..8)
        .map(|corner| {
            let q: Vec3 = std::array::from_fn(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
            norm(sub(b.grid_from_tool(q), a.grid_from_tool(q)))
        })
        .fold(0.0, f64::max)
}

/// The tests of one step against the obstacles, with each triangle's allowed depth.
struct Rules<'a> {
    shape: &'a Shape,
    /// The step's start (`None`: a proxy placed afresh).
    from: Option<Pose>,
    reach: Reach,
    obstacles: &'a Obstacles<'a>,
    /// The least signed distance each facet may have (m).
    floors: Vec<f64>,
    /// A lower bound of each facet's signed distance from the shape at the step's start (m):
    /// a pose that moves no point of the shape further than a facet's clearance above its
    /// floor needs no test of that facet.
    clearances: Vec<f64>,
    /// How far the shape's points lie from its frame's origin at most (m): a turn by `θ`
    /// moves none further than `θ` times this.
    extent: f64,
    /// Whether the shape's centre may be inside the volume (it was at the start).
    may_be_inside: bool,
}

impl<'a> Rules<'a> {
    /// The rules of a step that starts at `from`; `None`: a proxy placed afresh, which may touch
    /// nothing.
    fn new(shape: &'a Shape, from: Option<&Pose>, obstacles: &'a Obstacles<'a>) -> Self {
        let reach = Reach::of(shape);
        let (floors, clearances) = obstacles
            .facets
            .iter()
            .map(|f| {
                let Some(pose) = from else { return (floor(0.0), f64::NEG_INFINITY) };
                let t = f.corners.map(|p| pose.tool_from_grid(p));
                let bound = lower_bound(shape, &t, &reach);
                if bound >= 0.0 {
                    (floor(0.0), bound)
                } else {
                    let gap = triangle_gap(shape, &t).distance;
                    (floor(gap), gap)
                }
            })
            .unzip();
        let (lo, hi) = shape.bounds();
        let extent = (0..8)
            .map(|c| {
                let corner: Vec3 =
                    std::array::from_fn(|k| if c >> k & 1 == 0 { lo[k] } else { hi[k] });
                norm(corner)
            })
            .fold(0.0, f64::max);
        let may_be_inside = from.is_some_and(|pose| (obstacles.inside)(centre(shape, pose)));
        Self {
            shape,
            from: from.copied(),
            reach,
            obstacles,
            floors,
            clearances,
            extent,
            may_be_inside,
        }
    }

    /// Whether the proxy may be at `pose`.
    fn allows(&self, pose: &Pose) -> bool {
        // The cheapest tests first: the triangles near the shape, most of them passed on
        // their clearance alone, then the volume and the material not cut.
        let moved = self.from.as_ref().map_or(f64::INFINITY, |from| self.moved(from, pose));
        let clear = self.obstacles.facets.iter().zip(&self.floors).zip(&self.clearances).all(
            |((f, &floor), &clear)| {
                if clear - moved >= floor {
                    return true;
                }
                let t = f.corners.map(|p| pose.tool_from_grid(p));
                surely_at_least(self.shape, &t, floor, &self.reach)
                    || gap_at_least(self.shape, &t, floor)
            },
        );
        if !clear {
            return false;
        }
        if !self.may_be_inside && (self.obstacles.inside)(centre(self.shape, pose)) {
            return false;
        }
        !matches!((self.obstacles.uncut, &self.from), (Some(uncut), Some(from)) if uncut(from, pose))
    }

    /// How far any point of the shape moves from `from` to `pose` at most (m): the origin's
    /// displacement and the turn's angle times the shape's extent.
    fn moved(&self, from: &Pose, pose: &Pose) -> f64 {
        let (a, b) = (from.rotation(), pose.rotation());
        let cos = (0..4).map(|k| a[k] * b[k]).sum::<f64>().abs().min(1.0);
        norm(sub(pose.position(), from.position())) + 2.0 * cos.acos() * self.extent
    }

    /// The outward normals (grid frame) of the facets that refuse `pose`, the most refused
    /// first (of a flat patch, the triangle under the shape's middle before its neighbours,
    /// whose nearest points are shared edges and corners, tilted), or, when only the volume
    /// refuses it, the way back to `from`.
    fn refusals(&self, pose: &Pose, from: &Pose) -> Vec<Vec3> {
        let mut refused: Vec<(f64, Vec3)> = Vec::new();
        for (f, &floor) in self.obstacles.facets.iter().zip(&self.floors) {
            let t = f.corners.map(|p| pose.tool_from_grid(p));
            if surely_at_least(self.shape, &t, floor, &self.reach) {
                continue;
            }
            let g = triangle_gap(self.shape, &t);
            if g.distance < floor {
                refused.push((g.distance - floor, pose.rotate(g.normal).map(|c| -c)));
            }
        }
        refused.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut normals: Vec<Vec3> = refused.into_iter().map(|r| r.1).collect();
        if normals.is_empty() {
            let back = sub(from.position(), pose.position());
            let len = norm(back);
            if len > 0.0 {
                normals.push(back.map(|c| c / len));
            }
        }
        normals
    }

    /// How far along the path from `a` to `b` the proxy may go (a fraction in [0, 1]), and the
    /// first pose refused beyond it, if any.
    fn furthest(&self, a: &Pose, b: &Pose) -> (f64, Option<Pose>) {
        let length = travel(self.shape, a, b);
        if length <= 0.0 {
            return (1.0, None);
        }
        // In contact and pressed further in (the common case while a tool is held against
        // tissue): refused at once, without sampling the path.
        let first = (RESOLUTION / length).min(1.0);
        if !self.allows(&a.lerp(b, first)) {
            return (0.0, Some(a.lerp(b, first)));
        }
        let step = 0.5 * self.shape.thinnest();
        let samples = ((length / step).ceil() as usize).clamp(1, MAX_SAMPLES);
        let mut lo = first;
        for k in 1..=samples {
            let t = (k as f64 / samples as f64).max(first);
            if self.allows(&a.lerp(b, t)) {
                lo = t;
                continue;
            }
            let mut hi = t;
            // Bounded as well: on a path longer than the fractions' rounding can resolve
            // (a proxy carried off by tissue that diverged), halving stops at adjacent numbers.
            let mut halvings = 0;
            while (hi - lo) * length > RESOLUTION && halvings < MAX_HALVINGS {
                halvings += 1;
                let mid = 0.5 * (lo + hi);
                if self.allows(&a.lerp(b, mid)) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return (lo, Some(a.lerp(b, hi)));
        }
        (1.0, None)
    }
}

/// The least signed distance a triangle at `gap` from the proxy at a step's start may have during
/// the step: a triangle in contact (or clear) may reach [`PENETRATION_TOLERANCE`] into the
/// proxy, measured from the contact, not from where the last step left it, so that a proxy
/// held against tissue does not creep in by a tolerance a step; one that overlaps it more
/// already may not reach deeper (module doc).
fn floor(gap: f64) -> f64 {
    if gap >= -PENETRATION_TOLERANCE { -PENETRATION_TOLERANCE } else { gap - PENETRATION_TOLERANCE }
}

/// A lower bound of the signed distance between `shape` and the triangle `t` (tool frame), from
/// its bounding ball and one distance evaluation at the triangle's centroid (as
/// [`surely_at_least`] tests it).
fn lower_bound(shape: &Shape, t: &[Vec3; 3], reach: &Reach) -> f64 {
    let c: Vec3 = std::array::from_fn(|k| (t[0][k] + t[1][k] + t[2][k]) / 3.0);
    let r = t.iter().map(|&p| norm(sub(p, c))).fold(0.0, f64::max);
    let ball = norm(sub(c, reach.centre)) - reach.radius - r;
    if ball > 0.0 { ball } else { ball.max(shape.signed_distance(c) - r) }
}

/// The shape's centre (its bounding box's) at `pose`, grid frame.
fn centre(shape: &Shape, pose: &Pose) -> Vec3 {
    let (lo, hi) = shape.bounds();
    pose.grid_from_tool(std::array::from_fn(|k| 0.5 * (lo[k] + hi[k])))
}

/// Where a proxy may be placed when its tool first appears at `device`: there, if the shape
/// touches no tissue there; `None` otherwise (it waits for the device to leave the tissue).
#[must_use]
pub fn place(shape: &Shape, device: &Pose, obstacles: &Obstacles) -> Option<Pose> {
    Rules::new(shape, None, obstacles).allows(device).then_some(*device)
}

/// The proxy's motion from `from` toward `device` (module doc), with friction coefficient
/// `friction`.
#[must_use]
pub fn advance(
    shape: &Shape,
    from: &Pose,
    device: &Pose,
    friction: f64,
    obstacles: &Obstacles,
) -> Motion {
    let rules = Rules::new(shape, Some(from), obstacles);
    let mut motion = Motion { pose: *from, blocked: false, normals: Vec::new() };
    let mut target = *device;
    for _ in 0..4 {
        let (t, refused) = rules.furthest(&motion.pose, &target);
        motion.pose = if t >= 1.0 { target } else { motion.pose.lerp(&target, t) };
        let Some(refused) = refused else { break };
        motion.blocked = true;
        let met = rules.refusals(&refused, &motion.pose);
        for &n in &met {
            if motion.normals.len() < 3 && motion.normals.iter().all(|m| dot(m, &n) < 0.999) {
                motion.normals.push(n);
            }
        }
        // The search stops where the contact reaches the tolerance; backed off by half of it,
        // the proxy slides on (and starts the next step) with the other half to spare for
        // rounding, instead of being refused by the last bit of a tangential move.
        let away = met.first().copied().unwrap_or([0.0; 3]);
        let lifted = motion.pose.with_position(std::array::from_fn(|k| {
            motion.pose.position()[k] + 0.5 * PENETRATION_TOLERANCE * away[k]
        }));
        if rules.allows(&lifted) {
            motion.pose = lifted;
        }
        let rest = sub(device.position(), motion.pose.position());
        let mut along = slide(rest, &motion.normals);
        if friction > 0.0 {
            let pressed = norm(sub(rest, along));
            let length = norm(along);
            if length > 0.0 {
                let keep = (1.0 - friction * pressed / length).max(0.0);
                along = along.map(|c| c * keep);
            }
        }
        let next =
            device.with_position(std::array::from_fn(|k| motion.pose.position()[k] + along[k]));
        if travel(shape, &motion.pose, &next) <= RESOLUTION {
            break;
        }
        target = next;
    }
    motion
}

/// The nearest displacement to `r` that moves away from none of `normals`' planes: `u` with
/// `u · n ≥ 0` for each (the projection onto their cone, at most three planes).
#[must_use]
pub fn slide(r: Vec3, normals: &[Vec3]) -> Vec3 {
    let feasible = |u: &Vec3| normals.iter().all(|n| dot(u, n) >= -1e-12 * norm(r));
    if feasible(&r) {
        return r;
    }
    let mut best: Option<Vec3> = None;
    let mut keep = |u: Vec3| {
        if feasible(&u) && best.is_none_or(|b| norm(sub(r, u)) < norm(sub(r, b))) {
            best = Some(u);
        }
    };
    for n in normals {
        let along = dot(&r, n);
        if along < 0.0 {
            keep(std::array::from_fn(|k| r[k] - along * n[k]));
        }
    }
    for (i, a) in normals.iter().enumerate() {
        for b in &normals[i + 1..] {
            let line = incise_math::mat3::cross(a, b);
            let len = norm(line);
            if len > 1e-9 {
                let d = line.map(|c| c / len);
                let s = dot(&r, &d);
                keep(d.map(|c| c * s));
            }
        }
    }
    best.unwrap_or([0.0; 3])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::Primitive;

    /// A flat floor at z = 0 of triangles `cell` m across, spanning ±2 cm; the volume below.
    fn floor(cell: f64) -> Vec<Facet> {
        let n = (0.04 / cell).round() as i32;
        let mut facets = Vec::new();
        let p = |i: i32, j: i32| [-0.02 + f64::from(i) * cell, -0.02 + f64::from(j) * cell, 0.0];
        for i in 0..n {
            for j in 0..n {
                let (a, b, c, d) = (p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                let id = facets.len() as u32;
                facets.push(Facet { id, vertices: [0, 1, 2], corners: [a, b, c] });
                facets.push(Facet { id: id + 1, vertices: [0, 2, 3], corners: [a, c, d] });
            }
        }
        facets
    }

    fn below(p: Vec3) -> bool {
        p[2] < 0.0 && p[0].abs() < 0.02 && p[1].abs() < 0.02
    }

    fn ball(radius: f64) -> Shape {
        Shape::new(Primitive::Sphere { radius }, [0.0; 3]).unwrap()
    }

    #[test]
    fn a_ball_smaller_than_the_triangles_stops_on_the_floor_and_slides_along_it() {
        let facets = floor(0.01);
        let obstacles = Obstacles { facets: &facets, inside: &below, uncut: None };
        let shape = ball(0.0005);
        let from = Pose::at([0.003, 0.001, 0.002]);
        // Straight down, 1 cm past the floor.
        let m = advance(&shape, &from, &Pose::at([0.003, 0.001, -0.01]), 0.0, &obstacles);
        assert!(m.blocked);
        let z = m.pose.position()[2];
        let stopped = |z: f64| (0.0005 - PENETRATION_TOLERANCE..=0.0005).contains(&z);
        assert!(stopped(z), "stopped at z = {z}");
        assert!((m.normals[0][2] - 1.0).abs() < 1e-9, "{:?}", m.normals);
        // Down and sideways: it slides to above the device, still on the floor.
        let m = advance(&shape, &from, &Pose::at([0.009, -0.004, -0.01]), 0.0, &obstacles);
        let p = m.pose.position();
        assert!((p[0] - 0.009).abs() < 1e-6 && (p[1] + 0.004).abs() < 1e-6, "{p:?}");
        assert!(stopped(p[2]), "{p:?}");
        // Friction 0.5 with the device 1 cm below and 1 cm aside: the tangential offset may not
        // exceed half the depth, so it slides 5 mm of the 10.
        let from = Pose::at([0.0, 0.0, 0.0005]);
        let m = advance(&shape, &from, &Pose::at([0.01, 0.0, -0.0095]), 0.5, &obstacles);
        let p = m.pose.position();
        assert!((p[0] - 0.005).abs() < 1e-6, "{p:?}");
    }

    #[test]
    fn a_jump_through_a_thin_sheet_is_stopped_at_the_sheet() {
        let facets = floor(0.005);
        let nothing = |_: Vec3| false;
        let obstacles = Obstacles { facets: &facets, inside: &nothing, uncut: None };
        let shape =
            Shape::new(Primitive::Cuboid { half_extents: [0.005, 0.005, 0.0005] }, [0.0; 3])
                .unwrap();
        let m = advance(
            &shape,
            &Pose::at([0.0, 0.0, 0.025]),
            &Pose::at([0.0, 0.0, -0.025]),
            0.0,
            &obstacles,
        );
        let z = m.pose.position()[2];
        assert!(
            (0.0005 - PENETRATION_TOLERANCE - RESOLUTION..=0.0005).contains(&z),
            "stopped at z = {z}"
        );
    }

    #[test]
    fn a_proxy_is_placed_only_where_it_touches_nothing() {
        let facets = floor(0.01);
        let obstacles = Obstacles { facets: &facets, inside: &below, uncut: None };
        let shape = ball(0.001);
        assert!(place(&shape, &Pose::at([0.0, 0.0, 0.002]), &obstacles).is_some());
        assert!(place(&shape, &Pose::at([0.0, 0.0, 0.0005]), &obstacles).is_none());
        // Wholly inside, touching no triangle: the volume refuses it.
        assert!(place(&shape, &Pose::at([0.0, 0.0, -0.01]), &obstacles).is_none());
    }

    #[test]
    #[allow(clippy::float_cmp, reason = "projections onto axis planes are exact")]
    fn sliding_keeps_away_from_every_plane_met() {
        let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(slide([-1.0, 2.0, 3.0], &[x]), [0.0, 2.0, 3.0]);
        assert_eq!(slide([-1.0, -2.0, 3.0], &[x, y]), [0.0, 0.0, 3.0]);
        assert_eq!(slide([-1.0, -2.0, 3.0], &[x, y, [0.0, 0.0, -1.0]]), [0.0; 3]);
        assert_eq!(slide([1.0, 2.0, 3.0], &[x, y]), [1.0, 2.0, 3.0]);
    }
}
