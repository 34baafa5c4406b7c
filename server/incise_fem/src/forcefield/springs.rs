//! Springs on embedded points: the force field of a tool's penalty contact and of a grasp.
//!
//! A surface vertex is not a node: it is embedded in an element, `p(x) = Σₐ wₐ xₐ` (trilinear
//! weights in a hexahedron, or a single weight 1 on a tetrahedral vertex). A spring pulls it
//! toward a target `t` with a symmetric positive semi-definite 3×3 stiffness `S`:
//!
//! ```text
//! f_p = −S (p(x) − t),    fₐ = wₐ f_p,    E = ½ (p − t)ᵀ S (p − t),    K_ab = wₐ w_b S
//! ```
//!
//! A penalty contact against a tool's outer shape is the spring `S = k n nᵀ` whose target is the
//! point's projection onto the shape's surface (the shape linearised at the contact point: its
//! tangent plane), so the force is `k · depth` along the normal and the stiffness the implicit
//! step needs is exact for that plane. A grasp is `S = k I` toward the point's anchor in the
//! jaws. Both are linear in `x`, so [`ForceField::update`] has nothing to do, and the step's
//! matrix `a M + b K` gains `b wₐ w_b S`: a stiff contact is integrated implicitly, like the
//! tissue, which is what keeps it stable at dt = 10 ms.

use super::{ForceField, TopologyChange};
use crate::exec::Executor;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, mul_vec};

/// A point embedded in the model: `p(x) = Σₐ weights[a] · x[nodes[a]]`; slots with weight 0 are
/// unused (their node index is never read).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmbeddedPoint {
    /// Model node indices.
    pub nodes: [u32; 8],
    /// The weight of each node; they sum to 1 for a point inside its element.
    pub weights: [f64; 8],
}

impl EmbeddedPoint {
    /// A point that is the model node `node` itself (a tetrahedral mesh's vertex).
    #[must_use]
    pub fn node(node: u32) -> Self {
        let mut weights = [0.0; 8];
        weights[0] = 1.0;
        Self { nodes: [node; 8], weights }
    }

    /// Its position for node positions `x`.
    #[must_use]
    pub fn position(&self, x: &[Vec3]) -> Vec3 {
        let mut p = [0.0; 3];
        for (&n, &w) in self.nodes.iter().zip(&self.weights) {
            if w != 0.0 {
                let q = x[n as usize];
                for k in 0..3 {
                    p[k] += w * q[k];
                }
            }
        }
        p
    }

    /// Adds the point force `f` to the nodes, `fₐ += wₐ f` (the transpose of [`Self::position`]).
    pub fn spread(&self, f: Vec3, out: &mut [Vec3]) {
        for (&n, &w) in self.nodes.iter().zip(&self.weights) {
            if w != 0.0 {
                let o = &mut out[n as usize];
                for k in 0..3 {
                    o[k] += w * f[k];
                }
            }
        }
    }
}

/// One spring: `f = −stiffness · (p(x) − target)` on an embedded point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmbeddedSpring {
    /// Where it acts.
    pub point: EmbeddedPoint,
    /// `S` (N/m), symmetric positive semi-definite.
    pub stiffness: Mat3,
    /// Where it pulls the point (m).
    pub target: Vec3,
}

impl EmbeddedSpring {
    /// `S (p(x) − t)`: minus the force on the point.
    fn stretch_force(&self, x: &[Vec3]) -> Vec3 {
        let p = self.point.position(x);
        mul_vec(&self.stiffness, &std::array::from_fn(|k| p[k] - self.target[k]))
    }
}

/// Springs on embedded points, as a [`ForceField`]. Its loops are short (a contact touches tens
/// to thousands of points) and run in spring order on the calling thread, so its sums are the
/// same on any executor.
#[derive(Clone, Debug)]
pub struct EmbeddedSprings {
    springs: Vec<EmbeddedSpring>,
    exec: Executor,
}

impl EmbeddedSprings {
    /// A field of `springs`; `exec` is the executor of the fields it is stepped with.
    #[must_use]
    pub fn new(springs: Vec<EmbeddedSpring>, exec: Executor) -> Self {
        Self { springs, exec }
    }

    /// The springs.
    #[must_use]
    pub fn springs(&self) -> &[EmbeddedSpring] {
        &self.springs
    }

    /// The force each spring puts on its point at `x` (N), in spring order.
    pub fn point_forces<'a>(&'a self, x: &'a [Vec3]) -> impl Iterator<Item = Vec3> + 'a {
        self.springs.iter().map(move |s| s.stretch_force(x).map(|c| -c))
    }
}

impl ForceField for EmbeddedSprings {
    fn update(&mut self, _x: &[Vec3]) {}

    fn add_forces(&self, x: &[Vec3], f: &mut [Vec3]) {
        for s in &self.springs {
            let r = s.stretch_force(x);
            s.point.spread(r.map(|c| -c), f);
        }
    }

    fn add_stiffness_times(&self, _x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        for s in &self.springs {
            let r = mul_vec(&s.stiffness, &s.point.position(p));
            s.point.spread(r.map(|c| scale * c), out);
        }
    }

    fn energy(&self, x: &[Vec3]) -> f64 {
        self.springs
            .iter()
            .map(|s| {
                let p = s.point.position(x);
                let d: Vec3 = std::array::from_fn(|k| p[k] - s.target[k]);
                let r = mul_vec(&s.stiffness, &d);
                0.5 * (0..3).map(|k| d[k] * r[k]).sum::<f64>()
            })
            .sum()
    }

    fn add_diagonal_blocks(&self, _x: &[Vec3], blocks: &mut [Mat3]) {
        for s in &self.springs {
            for (&n, &w) in s.point.nodes.iter().zip(&s.point.weights) {
                if w != 0.0 {
                    let b = &mut blocks[n as usize];
                    for r in 0..3 {
                        for c in 0..3 {
                            b[r][c] += w * w * s.stiffness[r][c];
                        }
                    }
                }
            }
        }
    }

    fn executor(&self) -> &Executor {
        &self.exec
    }

    /// The springs follow their nodes to the new numbering. A node that did not survive loses its
    /// weight, and the remaining weights are scaled back to their old sum, so the point stays on
    /// the piece of material that still holds it; a spring left with no node is dropped. A cut
    /// within a step therefore keeps the contact found before it, instead of dropping it for the
    /// step.
    fn topology_changed(&mut self, change: &TopologyChange<'_>) {
        self.springs.retain_mut(|s| {
            let before: f64 = s.point.weights.iter().sum();
            let mut after = 0.0;
            for (n, w) in s.point.nodes.iter_mut().zip(s.point.weights.iter_mut()) {
                if *w == 0.0 {
                    continue;
                }
                match change.new_of_old.get(*n as usize).copied().flatten() {
                    Some(new) => {
                        *n = new;
                        after += *w;
                    }
                    None => *w = 0.0,
                }
            }
            if after == 0.0 {
                return false;
            }
            let scale = before / after;
            for w in &mut s.point.weights {
                *w *= scale;
            }
            true
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn springs() -> EmbeddedSprings {
        let n = [0.6, 0.0, 0.8];
        let contact: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| 300.0 * n[r] * n[c]));
        let grasp: Mat3 =
            std::array::from_fn(|r| std::array::from_fn(|c| f64::from(r == c) * 50.0));
        let a = EmbeddedPoint {
            nodes: [0, 1, 2, 3, 0, 0, 0, 0],
            weights: [0.1, 0.2, 0.3, 0.4, 0.0, 0.0, 0.0, 0.0],
        };
        EmbeddedSprings::new(
            vec![
                EmbeddedSpring { point: a, stiffness: contact, target: [0.1, 0.2, 0.3] },
                EmbeddedSpring {
                    point: EmbeddedPoint::node(4),
                    stiffness: grasp,
                    target: [1.0; 3],
                },
            ],
            Executor::single_thread(),
        )
    }

    fn positions(seed: f64) -> Vec<Vec3> {
        (0..5).map(|i| std::array::from_fn(|k| (seed * (i * 3 + k + 1) as f64).sin())).collect()
    }

    #[test]
    fn forces_are_minus_the_energy_gradient_and_the_product_is_their_derivative() {
        let field = springs();
        let x = positions(0.7);
        let mut f = vec![[0.0; 3]; 5];
        field.add_forces(&x, &mut f);
        // Central differences of a quadratic are exact up to rounding: 1e-7 relative.
        let h = 1e-6;
        for i in 0..5 {
            for k in 0..3 {
                let mut xp = x.clone();
                let mut xm = x.clone();
                xp[i][k] += h;
                xm[i][k] -= h;
                let grad = (field.energy(&xp) - field.energy(&xm)) / (2.0 * h);
                assert!((grad + f[i][k]).abs() <= 1e-7 * (1.0 + f[i][k].abs()), "{i},{k}");
            }
        }
        let p = positions(1.3);
        let mut kp = vec![[0.0; 3]; 5];
        field.add_stiffness_times(&x, 2.0, &p, &mut kp);
        let xp: Vec<Vec3> =
            x.iter().zip(&p).map(|(a, b)| std::array::from_fn(|k| a[k] + h * b[k])).collect();
        let mut fp = vec![[0.0; 3]; 5];
        field.add_forces(&xp, &mut fp);
        for i in 0..5 {
            for k in 0..3 {
                let df = (fp[i][k] - f[i][k]) / h;
                assert!((2.0 * -df - kp[i][k]).abs() <= 1e-6 * (1.0 + kp[i][k].abs()));
            }
        }
    }

    #[test]
    fn diagonal_blocks_are_the_products_diagonal() {
        let field = springs();
        let x = positions(0.2);
        let mut blocks = vec![[[0.0; 3]; 3]; 5];
        field.add_diagonal_blocks(&x, &mut blocks);
        for i in 0..5 {
            for c in 0..3 {
                let mut e = vec![[0.0; 3]; 5];
                e[i][c] = 1.0;
                let mut out = vec![[0.0; 3]; 5];
                field.add_stiffness_times(&x, 1.0, &e, &mut out);
                for r in 0..3 {
                    assert!((out[i][r] - blocks[i][r][c]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn a_topology_change_renumbers_nodes_and_drops_what_lost_its_nodes() {
        let mut field = springs();
        // Node 1 vanishes, the others move up by one; node 4 (the grasp's) vanishes.
        let new_of_old = [Some(1), None, Some(3), Some(4), None];
        field.topology_changed(&TopologyChange { new_of_old: &new_of_old });
        assert_eq!(field.springs().len(), 1);
        let point = field.springs()[0].point;
        assert_eq!(&point.nodes[..4], &[1, 1, 3, 4]);
        let w = point.weights;
        assert!(w[1] == 0.0, "the vanished node keeps no weight");
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((w[0] / w[2] - 1.0 / 3.0).abs() < 1e-15);
    }
}
