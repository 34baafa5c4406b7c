//! How far a triangle of the tissue's surface is from a tool shape: the least signed distance
//! of the shape over the triangle, and where it is least.
//!
//! A proxy is stopped by the triangles, not only by their corners, so a shape smaller than a
//! triangle, pressed on its middle, meets it. For a ball and a capsule the least distance is
//! exact (the closest point of the triangle to the centre, or to the axis segment). For a box, a
//! blade and a mesh it is found by branch and bound on the signed distance, which is 1-Lipschitz:
//! over a sub-triangle of centroid `c` and circumradius `R` it is at least `φ(c) − R`, so
//! sub-triangles that cannot hold a smaller value are dropped, and the rest are split in four,
//! most promising first, within a fixed number of evaluations. Where the bound cannot prune (a
//! face lying flush on the triangle) the distance is nearly the same everywhere and the best
//! sample found is as good as the minimum.

use crate::geometry::{
    at_bary, closest_on_triangle, closest_segment_triangle, norm, sub, triangle_normal, unit,
};
use crate::shape::{Primitive, Shape};
use incise_math::Vec3;
use incise_math::mat3::dot;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// The least signed distance of a shape over a triangle (tool frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gap {
    /// The least signed distance (m): the gap between the two, or minus the depth by which the
    /// triangle reaches into the shape.
    pub distance: f64,
    /// Barycentric coordinates of the triangle's point where it is least.
    pub bary: [f64; 3],
    /// The shape's outward normal at that point (tool frame): the way the shape pushes it.
    pub normal: Vec3,
}

/// Signed distances evaluated per triangle at most, for the shapes found by branch and bound.
const MAX_EVALUATIONS: usize = 64;

/// How much below the best sample a sub-triangle's bound must be to be split (m).
const RESOLUTION: f64 = 1e-7;

/// The least signed distance of `shape` over triangle `t` (tool frame).
#[must_use]
pub fn triangle_gap(shape: &Shape, t: &[Vec3; 3]) -> Gap {
    let o = shape.offset();
    match shape.primitive() {
        Some(Primitive::Sphere { radius }) => {
            let c = closest_on_triangle(o, *t);
            from_axis(t, c.bary, sub(c.point, o), radius)
        }
        Some(Primitive::Capsule { radius, length }) => {
            let top = [o[0], o[1], o[2] + length];
            let (s, bary, _) = closest_segment_triangle(o, top, t);
            let axis: Vec3 = std::array::from_fn(|k| o[k] + s * (top[k] - o[k]));
            from_axis(t, bary, sub(at_bary(t, bary), axis), radius)
        }
        _ => branch_and_bound(shape, t),
    }
}

/// Whether the least signed distance of `shape` over triangle `t` is surely at least `bound`,
/// from one evaluation at the triangle's centroid: `φ(c) − R ≥ bound`. False says nothing.
#[must_use]
pub fn surely_at_least(shape: &Shape, t: &[Vec3; 3], bound: f64, reach: &Reach) -> bool {
    // The shape lies within its bounding box, so its distance is at least the box's, which is
    // at least how far a point lies beyond any one of the box's face planes: a triangle wholly
    // beyond one (one lying flush on a face included) is as far as its nearest corner there.
    let (lo, hi) = (reach.lo, reach.hi);
    for k in 0..3 {
        let (least, most) = t
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p[k]), b.max(p[k])));
        if least - hi[k] >= bound || lo[k] - most >= bound {
            return true;
        }
    }
    let c = at_bary(t, [1.0 / 3.0; 3]);
    let r = t.iter().map(|&p| norm(sub(p, c))).fold(0.0, f64::max);
    // The shape lies within its bounding ball: nothing further needs its distance.
    if norm(sub(c, reach.centre)) - reach.radius - r >= bound {
        return true;
    }
    shape.signed_distance(c) - r >= bound
}

/// A shape's bounding ball and box in the tool frame: first tests that need no distance
/// evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// Its centre (tool frame).
    pub centre: Vec3,
    /// Its radius (m).
    pub radius: f64,
    /// The shape's bounding box in the tool frame (m).
    pub lo: Vec3,
    /// Its upper corner (m).
    pub hi: Vec3,
}

impl Reach {
    /// The ball around `shape`'s bounding box.
    #[must_use]
    pub fn of(shape: &Shape) -> Self {
        let (lo, hi) = shape.bounds();
        let centre = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
        Self { centre, radius: 0.5 * norm(sub(hi, lo)), lo, hi }
    }
}

/// The gap of a ball of `radius` about an axis point, whose offset to the triangle's closest
/// point is `d`.
fn from_axis(t: &[Vec3; 3], bary: [f64; 3], d: Vec3, radius: f64) -> Gap {
    let len = norm(d);
    // The axis touches the triangle: the shape pushes it the way it faces away from the shape's
    // inside, against its own outward normal.
    let normal = if len > 1e-12 { d.map(|c| c / len) } else { triangle_normal(t).map(|c| -c) };
    Gap { distance: len - radius, bary, normal }
}

/// A sub-triangle waiting to be split, by the lower bound of the distance over it; its corners
/// are indices into the search's vertices, so that the queue moves little.
struct Queued {
    bound: f64,
    corners: [u16; 3],
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.bound.total_cmp(&other.bound) == Ordering::Equal
    }
}
impl Eq for Queued {}
impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Queued {
    /// The smallest bound first (a max-heap of reversed bounds).
    fn cmp(&self, other: &Self) -> Ordering {
        other.bound.total_cmp(&self.bound)
    }
}

/// Best-first branch and bound on the signed distance (module doc).
struct Search<'a> {
    shape: &'a Shape,
    t: &'a [Vec3; 3],
    evaluations: usize,
    /// The least distance sampled and where.
    best: (f64, [f64; 3]),
    heap: BinaryHeap<Queued>,
    /// The sub-triangles' corners: barycentric coordinates in the whole triangle, and the
    /// points they give.
    vertices: Vec<([f64; 3], Vec3)>,
}

impl Search<'_> {
    /// Adds the vertex at barycentric point `b`.
    fn vertex(&mut self, b: [f64; 3]) -> u16 {
        self.vertices.push((b, at_bary(self.t, b)));
        u16::try_from(self.vertices.len() - 1).expect("a search has few vertices")
    }

    /// The distance at barycentric point `b`, which is `p`, kept if it is the least so far by
    /// more than the resolution (so that on a triangle lying flush on a face the point first
    /// sampled, its centroid, stays: the middle of the touch, not a corner).
    fn sample(&mut self, b: [f64; 3], p: Vec3) -> f64 {
        self.evaluations += 1;
        let d = self.shape.signed_distance(p);
        if d < self.best.0 - RESOLUTION {
            self.best = (d, b);
        }
        d
    }

    /// Samples a sub-triangle's centroid and queues it if it may hold a smaller distance.
    fn consider(&mut self, corners: [u16; 3]) {
        let [a, b, c] = corners.map(|i| self.vertices[usize::from(i)]);
        let centroid: [f64; 3] = std::array::from_fn(|k| (a.0[k] + b.0[k] + c.0[k]) / 3.0);
        let p = at_bary(self.t, centroid);
        let r = [a.1, b.1, c.1].iter().map(|&q| norm(sub(q, p))).fold(0.0, f64::max);
        let bound = self.sample(centroid, p) - r;
        if bound < self.best.0 - RESOLUTION {
            self.heap.push(Queued { bound, corners });
        }
    }
}

/// Whether [`triangle_gap`]`(shape, t).distance >= floor`, the same answer found with fewer
/// evaluations where it is decided early: the least sample only falls, and no sample falls
/// below the least bound still queued.
#[must_use]
pub fn gap_at_least(shape: &Shape, t: &[Vec3; 3], floor: f64) -> bool {
    match shape.primitive() {
        Some(Primitive::Sphere { .. } | Primitive::Capsule { .. }) => {
            triangle_gap(shape, t).distance >= floor
        }
        _ => search(shape, t, Some(floor)).best.0 >= floor,
    }
}

/// The branch and bound over triangle `t`; with a `floor`, stopped once the least distance is
/// known to be below it or not.
fn search<'a>(shape: &'a Shape, t: &'a [Vec3; 3], floor: Option<f64>) -> Search<'a> {
    let mut search = Search {
        shape,
        t,
        evaluations: 0,
        best: (f64::INFINITY, [1.0, 0.0, 0.0]),
        // Each split evaluates seven points, adds three vertices and queues at most four
        // sub-triangles for the one it takes, so the queue holds fewer than half as many as
        // there are evaluations, and the vertices as many: one allocation each instead of a
        // doubling at each growth.
        heap: BinaryHeap::with_capacity(MAX_EVALUATIONS / 2),
        vertices: Vec::with_capacity(MAX_EVALUATIONS / 2),
    };
    let root = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|b| search.vertex(b));
    search.consider(root);
    for i in root {
        let (b, p) = search.vertices[usize::from(i)];
        search.sample(b, p);
    }
    while let Some(Queued { bound, corners: [a, b, c] }) = search.heap.pop() {
        if bound >= search.best.0 - RESOLUTION || search.evaluations >= MAX_EVALUATIONS {
            break;
        }
        if floor.is_some_and(|f| search.best.0 < f || bound >= f) {
            break;
        }
        let mid = |search: &mut Search, p: u16, q: u16| -> u16 {
            let (p, q) = (search.vertices[usize::from(p)].0, search.vertices[usize::from(q)].0);
            let m = search.vertex(std::array::from_fn(|k| 0.5 * (p[k] + q[k])));
            let (b, point) = search.vertices[usize::from(m)];
            search.sample(b, point);
            m
        };
        let (ab, bc, ca) = (mid(&mut search, a, b), mid(&mut search, b, c), mid(&mut search, c, a));
        for child in [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]] {
            search.consider(child);
        }
    }
    search
}

fn branch_and_bound(shape: &Shape, t: &[Vec3; 3]) -> Gap {
    let (distance, bary) = search(shape, t, None).best;
    let normal = shape.distance(at_bary(t, bary)).1;
    // A shape's distance always has a unit gradient; a degenerate one falls back to pushing the
    // triangle along its own outward normal.
    let normal = if dot(&normal, &normal) > 0.0 { unit(normal) } else { triangle_normal(t) };
    Gap { distance, bary, normal }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A triangle in the plane z = `z` around the z axis, 10 mm across.
    fn flat(z: f64) -> [Vec3; 3] {
        [[-0.01, -0.01, z], [0.01, -0.01, z], [0.0, 0.01, z]]
    }

    #[test]
    fn a_small_ball_over_a_large_triangle_meets_its_middle() {
        let ball = Shape::new(Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap();
        let g = triangle_gap(&ball, &flat(-0.0015));
        assert!((g.distance - 0.0005).abs() < 1e-15, "{}", g.distance);
        assert!((g.normal[2] + 1.0).abs() < 1e-15);
        let g = triangle_gap(&ball, &flat(-0.0004));
        assert!((g.distance + 0.0006).abs() < 1e-15, "pressed 0.6 mm in: {}", g.distance);
    }

    #[test]
    fn a_capsule_lying_across_a_triangle_is_as_close_as_its_axis() {
        let capsule =
            Shape::new(Primitive::Capsule { radius: 0.001, length: 0.02 }, [0.0; 3]).unwrap();
        // The capsule along z; a vertical triangle 1.5 mm from its axis along x.
        let t = [[0.0015, -0.01, 0.005], [0.0015, 0.01, 0.005], [0.0015, 0.0, 0.015]];
        let g = triangle_gap(&capsule, &t);
        assert!((g.distance - 0.0005).abs() < 1e-15, "{}", g.distance);
        assert!((g.normal[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn branch_and_bound_finds_how_deep_a_triangle_reaches_into_a_box_and_a_blade() {
        // A 4 mm cube about the origin and a large triangle through it at z = −0.5 mm: the
        // triangle's points inside lie at most 1.5 mm from the cube's faces.
        let cube = Shape::new(Primitive::Cuboid { half_extents: [0.002; 3] }, [0.0; 3]).unwrap();
        let t = flat(-0.0005);
        let g = triangle_gap(&cube, &t);
        assert!((g.distance + 0.0015).abs() < 1e-6, "{}", g.distance);
        let far = triangle_gap(&cube, &flat(-0.0031));
        assert!((far.distance - 0.0011).abs() < 1e-6, "{}", far.distance);
        assert!((far.normal[2] + 1.0).abs() < 1e-9);
        // A blade's edge (1 mm thick) pressed 0.2 mm into a triangle lying across it.
        let blade = Shape::new(
            Primitive::Blade { length: 0.012, height: 0.01, thickness: 0.001 },
            [0.0; 3],
        )
        .unwrap();
        let g = triangle_gap(&blade, &flat(0.0002));
        assert!((g.distance + 0.0002).abs() < 1e-6, "{}", g.distance);
    }

    #[test]
    fn a_triangle_far_from_the_shape_is_surely_clear() {
        let ball = Shape::new(Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap();
        let reach = Reach::of(&ball);
        assert!(surely_at_least(&ball, &flat(-0.05), 0.0, &reach));
        assert!(!surely_at_least(&ball, &flat(-0.0005), 0.0, &reach));
    }
}
