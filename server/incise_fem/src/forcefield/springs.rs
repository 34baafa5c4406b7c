//! Springs on embedded points: the force field of a tool's push on the tissue and of a grasp.
//!
//! A surface vertex is not a node: it is embedded in an element, `p(x) = Σₐ wₐ xₐ` (trilinear
//! weights in a hexahedron, or a single weight 1 on a tetrahedral vertex). A spring pulls it
//! toward a target `t` with a symmetric positive semi-definite 3×3 stiffness `S`:
//!
//! ```text
//! f_p = −S (p(x) − t),    fₐ = wₐ f_p,    E = ½ (p − t)ᵀ S (p − t),    K_ab = wₐ w_b S
//! ```
//!
//! A tool's push through a surface point its proxy touches is the spring `S = k n nᵀ` whose
//! target lies along the contact normal by the depth it pushes (the proxy's surface linearised
//! at the contact: its tangent plane), so the force is `k · depth` along the normal and the
//! stiffness the implicit step needs is exact for that plane. A grasp is `S = k I` toward the point's anchor in the
//! jaws. Both are linear in `x`, so [`ForceField::update`] has nothing to do, and the step's
//! matrix gains `h² wₐ w_b S`: a stiff contact is integrated implicitly, like the tissue, which
//! is what keeps it stable at dt = 10 ms.
//!
//! A spring may also damp its point's motion relative to its target's, `f_p = −C (ṗ − w)` with
//! `C` symmetric positive semi-definite (`c n nᵀ` for a contact) and `w` the target's velocity
//! (the tool's, where the point touches it). The target moves with the tool, so the damping must
//! too: the integrator's Rayleigh damping `β K`, which damps against the world, does not apply to
//! these springs ([`ForceField::rayleigh_damped`] is false). Damping a spring against the world
//! would hold the tissue back from a moving tool: at β = 0.01 s and h = 1 ms, one step closes only
//! `h / (h + β)` = 1/11 of a spring's gap, and a tool jumping 5 cm leaves a membrane behind.

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

    /// `blocks[a] += wₐ² m`: the diagonal blocks of `m` acting on the point, seen from its nodes.
    fn add_diagonal_blocks(&self, m: &Mat3, blocks: &mut [Mat3]) {
        for (&n, &w) in self.nodes.iter().zip(&self.weights) {
            if w != 0.0 {
                let b = &mut blocks[n as usize];
                for r in 0..3 {
                    for c in 0..3 {
                        b[r][c] += w * w * m[r][c];
                    }
                }
            }
        }
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
    /// `C` (N·s/m), symmetric positive semi-definite: the damping of the point's motion relative
    /// to `velocity`.
    pub damping: Mat3,
    /// The target's velocity (m/s): the velocity the damping drives the point toward.
    pub velocity: Vec3,
}

impl EmbeddedSpring {
    /// A spring without damping.
    #[must_use]
    pub fn new(point: EmbeddedPoint, stiffness: Mat3, target: Vec3) -> Self {
        Self { point, stiffness, target, damping: [[0.0; 3]; 3], velocity: [0.0; 3] }
    }

    /// The same spring damping its point's motion relative to `velocity` with `damping`.
    #[must_use]
    pub fn damped(self, damping: Mat3, velocity: Vec3) -> Self {
        Self { damping, velocity, ..self }
    }

    /// Whether it damps at all.
    fn has_damping(&self) -> bool {
        self.damping.iter().flatten().any(|&c| c != 0.0)
    }

    /// `C (ṗ − w)` at node velocities `v`: minus the damping force on the point.
    #[must_use]
    pub fn damping_force(&self, v: &[Vec3]) -> Vec3 {
        if !self.has_damping() {
            return [0.0; 3];
        }
        let pv = self.point.position(v);
        mul_vec(&self.damping, &std::array::from_fn(|k| pv[k] - self.velocity[k]))
    }

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
            s.point.add_diagonal_blocks(&s.stiffness, blocks);
        }
    }

    fn rayleigh_damped(&self) -> bool {
        false
    }

    fn add_damping_forces(&self, v: &[Vec3], f: &mut [Vec3]) {
        for s in self.springs.iter().filter(|s| s.has_damping()) {
            s.point.spread(s.damping_force(v).map(|c| -c), f);
        }
    }

    fn add_damping_times(&self, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        for s in self.springs.iter().filter(|s| s.has_damping()) {
            let r = mul_vec(&s.damping, &s.point.position(p));
            s.point.spread(r.map(|c| scale * c), out);
        }
    }

    fn add_damping_diagonal_blocks(&self, blocks: &mut [Mat3]) {
        for s in self.springs.iter().filter(|s| s.has_damping()) {
            s.point.add_diagonal_blocks(&s.damping, blocks);
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
                EmbeddedSpring::new(a, contact, [0.1, 0.2, 0.3])
                    .damped(contact.map(|r| r.map(|c| 0.01 * c)), [0.5, -0.2, 0.1]),
                EmbeddedSpring::new(EmbeddedPoint::node(4), grasp, [1.0; 3]),
            ],
            Executor::single_thread(),
        )
    }

    fn positions(seed: f64) -> Vec<Vec3> {
        (0..5).map(|i| std::array::from_fn(|k| (seed * (i * 3 + k + 1) as f64).sin())).collect()
    }

    #[test]
    fn forces_are_minus_the_energy_gradient_and_the_product_is_their_derivative() {
        // Central differences of a quadratic are exact up to rounding: 1e-7 relative.
        let (x, p) = (positions(0.7), positions(1.3));
        crate::forcefield::checks::forces_and_product(
            &springs(),
            &x,
            &p,
            (1e-7, 1e-7),
            (1e-6, 1e-6),
        );
    }

    #[test]
    fn diagonal_blocks_are_the_products_diagonal() {
        crate::forcefield::checks::diagonal_blocks(&springs(), &positions(0.2), (0.0, 1e-12));
    }

    #[test]
    fn the_damping_forces_are_linear_in_the_relative_velocity_and_match_their_product() {
        let field = springs();
        assert!(!field.rayleigh_damped());
        let v = positions(0.4);
        let mut f = vec![[0.0; 3]; 5];
        field.add_damping_forces(&v, &mut f);
        // −C (ṗ − w) on the damped spring's point, spread by its weights.
        let s = &field.springs()[0];
        let pv = s.point.position(&v);
        let rel: Vec3 = std::array::from_fn(|k| pv[k] - s.velocity[k]);
        let fp = mul_vec(&s.damping, &rel);
        for (a, &w) in s.point.weights.iter().enumerate().take(4) {
            for k in 0..3 {
                assert!((f[a][k] + w * fp[k]).abs() < 1e-15, "{a},{k}");
            }
        }
        assert!(f[4].iter().all(|&c| c == 0.0), "the grasp spring has no damping");
        // The product is the forces' derivative in v, exactly (they are affine in v).
        let p = positions(1.9);
        let mut cp = vec![[0.0; 3]; 5];
        field.add_damping_times(3.0, &p, &mut cp);
        let vp: Vec<Vec3> =
            v.iter().zip(&p).map(|(a, b)| std::array::from_fn(|k| a[k] + b[k])).collect();
        let mut fv = vec![[0.0; 3]; 5];
        field.add_damping_forces(&vp, &mut fv);
        let mut blocks = vec![[[0.0; 3]; 3]; 5];
        field.add_damping_diagonal_blocks(&mut blocks);
        for i in 0..5 {
            for k in 0..3 {
                assert!((3.0 * (f[i][k] - fv[i][k]) - cp[i][k]).abs() < 1e-12, "{i},{k}");
            }
            let mut e = vec![[0.0; 3]; 5];
            e[i][0] = 1.0;
            let mut out = vec![[0.0; 3]; 5];
            field.add_damping_times(1.0, &e, &mut out);
            for r in 0..3 {
                assert!((out[i][r] - blocks[i][r][0]).abs() < 1e-15);
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
