//! What a tool's inner shape cuts (Jeřábková 2010, §3, Fig. 9): a flood from the cells the
//! shape reaches at the surface, inwards through the material while the cells' deformed centres
//! stay inside it, and the test of whether a blade's mid-plane swept across a link.
//!
//! The flood starts at the voxels (or tetrahedra) under the surface points the shape contains:
//! only material connected to where the shape entered is cut, so a blade that reaches two lobes
//! through a gap cuts each only where it touches it. Cells are visited in a deterministic
//! order and returned sorted.

use crate::pose::Pose;
use crate::shape::{Primitive, Shape};
use incise_math::Vec3;
use std::collections::BTreeSet;

/// The cells reachable from `seeds` through `neighbours` whose `inside` holds (seeds
/// included only if inside), sorted. `neighbours(c, out)` appends the cells linked to `c`.
pub fn flood(
    seeds: impl IntoIterator<Item = u32>,
    mut inside: impl FnMut(u32) -> bool,
    mut neighbours: impl FnMut(u32, &mut Vec<u32>),
) -> Vec<u32> {
    let mut seen: BTreeSet<u32> = BTreeSet::new();
    let mut queue: Vec<u32> = Vec::new();
    for s in seeds {
        if seen.insert(s) {
            queue.push(s);
        }
    }
    let mut found = Vec::new();
    let mut next = Vec::new();
    let mut head = 0;
    while head < queue.len() {
        let c = queue[head];
        head += 1;
        if !inside(c) {
            continue;
        }
        found.push(c);
        next.clear();
        neighbours(c, &mut next);
        for &n in &next {
            if seen.insert(n) {
                queue.push(n);
            }
        }
    }
    found.sort_unstable();
    found
}

/// A blade's separating surface between two frames: its mid-plane rectangle at sub-poses from
/// `from` to `to`, close enough that a link shorter than `link` cannot pass between two of them.
#[derive(Clone, Debug)]
pub struct SweptBlade {
    /// The blade's half length (x) and height (z) in the tool frame, and its offset.
    half_length: f64,
    height: f64,
    offset: Vec3,
    poses: Vec<Pose>,
}

/// Most sub-poses of a swept blade.
const MAX_BLADE_SAMPLES: usize = 256;

impl SweptBlade {
    /// The swept mid-plane of `blade` (a [`Primitive::Blade`]; `None` for any other shape) from
    /// `from` to `to`, sampled every `link` / 2 of travel.
    #[must_use]
    pub fn new(blade: &Shape, from: &Pose, to: &Pose, link: f64) -> Option<Self> {
        let Some(Primitive::Blade { length, height, .. }) = blade.primitive() else { return None };
        let (lo, hi) = blade.bounds();
        let mut travel: f64 = 0.0;
        for corner in 0..8 {
            let q: Vec3 = std::array::from_fn(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
            let (a, b) = (from.grid_from_tool(q), to.grid_from_tool(q));
            travel = travel.max((0..3).map(|k| (b[k] - a[k]).powi(2)).sum::<f64>().sqrt());
        }
        let samples = ((travel / (0.5 * link)).ceil() as usize).clamp(1, MAX_BLADE_SAMPLES);
        let poses = (0..=samples).map(|i| from.lerp(to, i as f64 / samples as f64)).collect();
        let offset = blade.bounds().0;
        Some(Self {
            half_length: 0.5 * length,
            height,
            offset: [offset[0] + 0.5 * length, offset[1] + 0.5 * (hi[1] - lo[1]), offset[2]],
            poses,
        })
    }

    /// Whether the segment from `a` to `b` (grid frame) crosses the mid-plane at any sub-pose.
    #[must_use]
    pub fn crosses(&self, a: Vec3, b: Vec3) -> bool {
        self.poses.iter().any(|pose| {
            let local = |p: Vec3| {
                let q = pose.tool_from_grid(p);
                [q[0] - self.offset[0], q[1] - self.offset[1], q[2] - self.offset[2]]
            };
            let (qa, qb) = (local(a), local(b));
            if (qa[1] > 0.0) == (qb[1] > 0.0) {
                return false;
            }
            let t = qa[1] / (qa[1] - qb[1]);
            let x = qa[0] + t * (qb[0] - qa[0]);
            let z = qa[2] + t * (qb[2] - qa[2]);
            x.abs() <= self.half_length && (0.0..=self.height).contains(&z)
        })
    }

    /// The grid-frame bounding box of the swept mid-plane.
    #[must_use]
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for pose in &self.poses {
            for corner in 0..4 {
                let x = if corner & 1 == 0 { -self.half_length } else { self.half_length };
                let z = if corner & 2 == 0 { 0.0 } else { self.height };
                let q = [self.offset[0] + x, self.offset[1], self.offset[2] + z];
                let p = pose.grid_from_tool(q);
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
        (lo, hi)
    }

    /// The smallest distance (m) from `p` to the mid-plane rectangle over the sub-poses: the
    /// flood of candidate links stays within reach of it.
    #[must_use]
    pub fn distance(&self, p: Vec3) -> f64 {
        self.poses
            .iter()
            .map(|pose| {
                let q = pose.tool_from_grid(p);
                let d = [
                    ((q[0] - self.offset[0]).abs() - self.half_length).max(0.0),
                    (q[1] - self.offset[1]).abs(),
                    ((q[2] - self.offset[2] - 0.5 * self.height).abs() - 0.5 * self.height)
                        .max(0.0),
                ];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flood_stays_in_the_connected_inside() {
        // A row of cells 0..20, inside where 3 ≤ c ≤ 8 or 12 ≤ c ≤ 15; seeded at 5 only.
        let inside = |c: u32| (3..=8).contains(&c) || (12..=15).contains(&c);
        let line = |c: u32, out: &mut Vec<u32>| {
            out.extend(c.checked_sub(1));
            if c < 19 {
                out.push(c + 1);
            }
        };
        assert_eq!(flood([5], inside, line), vec![3, 4, 5, 6, 7, 8]);
        assert_eq!(flood([5, 14, 0], inside, line), vec![3, 4, 5, 6, 7, 8, 12, 13, 14, 15]);
        assert!(flood([10], inside, line).is_empty());
    }

    #[test]
    fn a_swept_blade_crosses_the_links_it_passed_through() {
        let blade = Shape::new(
            Primitive::Blade { length: 0.01, height: 0.005, thickness: 0.0005 },
            [0.0; 3],
        )
        .unwrap();
        // The blade, edge down, moves 2 cm along +y: links along y within its span are crossed.
        let from = Pose::at([0.0, -0.01, 0.0]);
        let to = Pose::at([0.0, 0.01, 0.0]);
        let swept = SweptBlade::new(&blade, &from, &to, 0.001).unwrap();
        assert!(swept.crosses([0.0, 0.0, 0.002], [0.0, 0.001, 0.002]));
        assert!(swept.crosses([0.004, 0.0095, 0.001], [0.004, 0.0105, 0.001]));
        // Beyond its length, below its edge, beyond its travel: not crossed.
        assert!(!swept.crosses([0.006, 0.0, 0.002], [0.006, 0.001, 0.002]));
        assert!(!swept.crosses([0.0, 0.0, -0.001], [0.0, 0.001, -0.001]));
        assert!(!swept.crosses([0.0, 0.0105, 0.002], [0.0, 0.0115, 0.002]));
        // A link along x never crosses a plane normal to y.
        assert!(!swept.crosses([0.0, 0.0, 0.002], [0.001, 0.0, 0.002]));
        assert!(swept.distance([0.0, 0.0, 0.002]) < 1e-12);
        assert!((swept.distance([0.0, 0.0, -0.003]) - 0.003).abs() < 1e-12);
        assert!(
            SweptBlade::new(
                &Shape::new(Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap(),
                &from,
                &to,
                0.001
            )
            .is_none()
        );
    }
}
