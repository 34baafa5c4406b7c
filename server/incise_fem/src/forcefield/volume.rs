//! The penalty of an intersection volume: the force field of volume contact (Faure et al. 2008,
//! as paper 1 §3 uses it for organ on organ and for a cut's flaps on each other).
//!
//! Where two surfaces (or two layers of one surface) overlap, the overlap's volume `V` and its
//! gradient `gᵢ = ∂V/∂pᵢ` with respect to every surface vertex are measured from layered depth
//! images (`incise_tool::volume_contact`). The penalty is a pressure `k_p` per metre of
//! penetration over the overlap's area, with the depth taken as `V / A`:
//!
//! ```text
//! A = ½ Σᵢ |gᵢ|,    E = ½ (k_p / A) V²,    fᵢ = −(k_p / A) V gᵢ
//! ```
//!
//! `A` is the area of the contact: two slabs overlapping by `d` over an area `a` have `V = a d`
//! and `Σ |gᵢ| = 2a` (each side's vertices together move `V` by `a` per metre), so each side is
//! pushed with `k_p a d`, a Winkler foundation of stiffness `k_p` (N/m³). The direction is the
//! gradient's: the force on a thin sheet of overlap acts across it, however wide the sheet, not
//! along its width (where rays see long intervals but moving the surface changes little).
//!
//! The vertices are embedded in the model (`pᵢ = Σₐ wᵢₐ xₐ`), so the gradient is carried to the
//! nodes, `Gₐ = Σᵢ wᵢₐ gᵢ`, and the volume linearised at the positions it was measured at,
//! `V(x) ≈ V₀ + Σₐ Gₐ · (xₐ − x₀ₐ)`. The field is then linear in `x`, with the rank-one
//! Jacobian `K = (k_p / A) G Gᵀ` (exactly its energy's Hessian): the implicit step sees the
//! stiffness of the whole contact, including that all its nodes push together, which a spring
//! per vertex would not. The product costs two passes over the region's nodes.
//!
//! The linearisation holds for the step it was measured for: the next step measures again, so
//! a volume the step's motion would make negative pulls back only within that step's solve.
//!
//! Damping: the integrator's Rayleigh term `β K` applies ([`ForceField::rayleigh_damped`]).
//! For this field it damps `G · v`, the rate at which the overlap grows, which a rigid motion of
//! both sides together does not change: it damps the bodies' approach, not their common motion.

use super::{ForceField, TopologyChange};
use crate::exec::Executor;
use crate::forcefield::springs::EmbeddedPoint;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, dot};

/// One connected overlap, linearised where it was measured.
#[derive(Clone, Debug, PartialEq)]
pub struct OverlapRegion {
    /// `(node, Gₐ)`: the volume's gradient with respect to each node it depends on (m²), by
    /// ascending node.
    gradient: Vec<(u32, Vec3)>,
    /// The nodes' positions where the volume was measured (m), in `gradient`'s order.
    at: Vec<Vec3>,
    /// The volume measured there (m³).
    volume: f64,
    /// `k_p / A` (N/m⁵).
    stiffness: f64,
}

impl OverlapRegion {
    /// The overlap of volume `volume` whose gradient with respect to embedded surface points is
    /// `vertex_gradients` (m²), under a penalty of `pressure` (N/m³) per metre of depth, measured
    /// at node positions `x`. `None` when it has no volume or no area.
    #[must_use]
    pub fn new(
        volume: f64,
        vertex_gradients: impl IntoIterator<Item = (EmbeddedPoint, Vec3)>,
        pressure: f64,
        x: &[Vec3],
    ) -> Option<Self> {
        Self::against(volume, vertex_gradients, [], pressure, x)
    }

    /// As [`OverlapRegion::new`], for an overlap with a body whose vertices the step does not
    /// move (a tool posed from outside): `fixed_gradients` are the volume's gradient with
    /// respect to its vertices, which count toward the contact's area (each side of the
    /// overlap holds half its `Σ |gᵢ|`) but move no node.
    #[must_use]
    pub fn against(
        volume: f64,
        vertex_gradients: impl IntoIterator<Item = (EmbeddedPoint, Vec3)>,
        fixed_gradients: impl IntoIterator<Item = Vec3>,
        pressure: f64,
        x: &[Vec3],
    ) -> Option<Self> {
        let mut by_node: Vec<(u32, Vec3)> = Vec::new();
        let mut area: f64 = fixed_gradients.into_iter().map(|g| 0.5 * dot(&g, &g).sqrt()).sum();
        for (point, g) in vertex_gradients {
            area += 0.5 * dot(&g, &g).sqrt();
            for (&n, &w) in point.nodes.iter().zip(&point.weights) {
                if w != 0.0 {
                    by_node.push((n, g.map(|c| w * c)));
                }
            }
        }
        if !(volume > 0.0 && area > 0.0 && pressure.is_finite()) {
            return None;
        }
        by_node.sort_by_key(|&(n, _)| n);
        let mut gradient: Vec<(u32, Vec3)> = Vec::with_capacity(by_node.len());
        for (n, g) in by_node {
            match gradient.last_mut() {
                Some((last, sum)) if *last == n => {
                    for k in 0..3 {
                        sum[k] += g[k];
                    }
                }
                _ => gradient.push((n, g)),
            }
        }
        let at = gradient.iter().map(|&(n, _)| x[n as usize]).collect();
        Some(Self { gradient, at, volume, stiffness: pressure / area })
    }

    /// The volume measured (m³).
    #[must_use]
    pub fn volume(&self) -> f64 {
        self.volume
    }

    /// `k_p / A` (N/m⁵): the contact's area is `pressure / stiffness`.
    #[must_use]
    pub fn stiffness(&self) -> f64 {
        self.stiffness
    }

    /// The nodes and the volume's gradient with respect to each (m²).
    #[must_use]
    pub fn gradient(&self) -> &[(u32, Vec3)] {
        &self.gradient
    }

    /// `G · p` over the region's nodes.
    fn dot(&self, p: &[Vec3]) -> f64 {
        self.gradient.iter().map(|&(n, g)| dot(&g, &p[n as usize])).sum()
    }

    /// The linearised volume at node positions `x`.
    #[must_use]
    pub fn volume_at(&self, x: &[Vec3]) -> f64 {
        self.volume
            + self
                .gradient
                .iter()
                .zip(&self.at)
                .map(|(&(n, g), x0)| {
                    let d: Vec3 = std::array::from_fn(|k| x[n as usize][k] - x0[k]);
                    dot(&g, &d)
                })
                .sum::<f64>()
    }

    /// `out[a] += s · Gₐ`.
    fn spread(&self, s: f64, out: &mut [Vec3]) {
        for &(n, g) in &self.gradient {
            let o = &mut out[n as usize];
            for k in 0..3 {
                o[k] += s * g[k];
            }
        }
    }
}

/// The penalty of every overlap of a step, as a [`ForceField`]. Its loops run in region order on
/// the calling thread, so its sums are the same on any executor.
#[derive(Clone, Debug)]
pub struct VolumePenalty {
    regions: Vec<OverlapRegion>,
    exec: Executor,
}

impl VolumePenalty {
    /// A field of `regions`; `exec` is the executor of the fields it is stepped with.
    #[must_use]
    pub fn new(regions: Vec<OverlapRegion>, exec: Executor) -> Self {
        Self { regions, exec }
    }

    /// The regions.
    #[must_use]
    pub fn regions(&self) -> &[OverlapRegion] {
        &self.regions
    }

    /// The total overlap volume measured (m³).
    #[must_use]
    pub fn volume(&self) -> f64 {
        self.regions.iter().map(OverlapRegion::volume).sum()
    }
}

impl ForceField for VolumePenalty {
    fn update(&mut self, _x: &[Vec3]) {}

    fn add_forces(&self, x: &[Vec3], f: &mut [Vec3]) {
        for r in &self.regions {
            r.spread(-r.stiffness * r.volume_at(x), f);
        }
    }

    fn add_stiffness_times(&self, _x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        for r in &self.regions {
            r.spread(scale * r.stiffness * r.dot(p), out);
        }
    }

    fn energy(&self, x: &[Vec3]) -> f64 {
        self.regions.iter().map(|r| 0.5 * r.stiffness * r.volume_at(x).powi(2)).sum()
    }

    fn add_diagonal_blocks(&self, _x: &[Vec3], blocks: &mut [Mat3]) {
        for r in &self.regions {
            for &(n, g) in &r.gradient {
                let b = &mut blocks[n as usize];
                for (row, gr) in b.iter_mut().zip(g) {
                    for (c, gc) in row.iter_mut().zip(g) {
                        *c += r.stiffness * gr * gc;
                    }
                }
            }
        }
    }

    fn executor(&self) -> &Executor {
        &self.exec
    }

    /// The regions follow their nodes to the new numbering; a node that did not survive leaves
    /// its region (its share of the gradient is gone with its material).
    fn topology_changed(&mut self, change: &TopologyChange<'_>) {
        for r in &mut self.regions {
            let mut kept_gradient = Vec::with_capacity(r.gradient.len());
            let mut kept_at = Vec::with_capacity(r.at.len());
            for (&(n, g), &x0) in r.gradient.iter().zip(&r.at) {
                if let Some(new) = change.new_of_old.get(n as usize).copied().flatten() {
                    kept_gradient.push((new, g));
                    kept_at.push(x0);
                }
            }
            r.gradient = kept_gradient;
            r.at = kept_at;
        }
        self.regions.retain(|r| !r.gradient.is_empty());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(x: &[Vec3]) -> VolumePenalty {
        let a = EmbeddedPoint {
            nodes: [0, 1, 2, 3, 0, 0, 0, 0],
            weights: [0.1, 0.2, 0.3, 0.4, 0.0, 0.0, 0.0, 0.0],
        };
        let b = EmbeddedPoint {
            nodes: [2, 4, 0, 0, 0, 0, 0, 0],
            weights: [0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        };
        let one = OverlapRegion::new(
            2e-6,
            [(a, [1e-4, 0.0, 2e-4]), (b, [0.0, -3e-4, -1e-4]), (EmbeddedPoint::node(4), [0.0; 3])],
            5e5,
            x,
        )
        .unwrap();
        let two =
            OverlapRegion::new(1e-6, [(EmbeddedPoint::node(1), [0.0, 0.0, 4e-4])], 1e6, x).unwrap();
        VolumePenalty::new(vec![one, two], Executor::single_thread())
    }

    fn positions(seed: f64) -> Vec<Vec3> {
        (0..5)
            .map(|i| std::array::from_fn(|k| 0.01 * (seed * (i * 3 + k + 1) as f64).sin()))
            .collect()
    }

    #[test]
    fn the_area_is_half_the_gradients_length_and_shared_nodes_sum() {
        let x = positions(0.7);
        let f = field(&x);
        let one = &f.regions()[0];
        let area = 0.5 * (5f64.sqrt() * 1e-4 + 10f64.sqrt() * 1e-4);
        assert!((one.stiffness() - 5e5 / area).abs() <= 1e-9 * one.stiffness());
        // Node 2 gets 0.3 of a's gradient and 0.5 of b's.
        let g2 = one.gradient().iter().find(|&&(n, _)| n == 2).unwrap().1;
        let want = [0.3e-4, -1.5e-4, 0.6e-4 - 0.5e-4];
        assert!((0..3).all(|k| (g2[k] - want[k]).abs() < 1e-18), "{g2:?}");
        // A region with no volume or no area is none.
        assert!(OverlapRegion::new(0.0, [(EmbeddedPoint::node(0), [1.0; 3])], 1.0, &x).is_none());
        assert!(OverlapRegion::new(1.0, [(EmbeddedPoint::node(0), [0.0; 3])], 1.0, &x).is_none());
    }

    #[test]
    fn at_the_measured_positions_the_force_is_the_penalty_of_the_measured_volume() {
        let x = positions(0.7);
        let field = field(&x);
        let mut f = vec![[0.0; 3]; 5];
        field.add_forces(&x, &mut f);
        // Node 1: 0.2 of a's gradient in region one, all of region two's.
        let one = &field.regions()[0];
        let two = &field.regions()[1];
        let want: Vec3 = std::array::from_fn(|k| {
            -one.stiffness() * 2e-6 * 0.2 * [1e-4, 0.0, 2e-4][k]
                - two.stiffness() * 1e-6 * [0.0, 0.0, 4e-4][k]
        });
        assert!((0..3).all(|k| (f[1][k] - want[k]).abs() <= 1e-12 * (1.0 + want[k].abs())));
        let e = 0.5 * one.stiffness() * 4e-12 + 0.5 * two.stiffness() * 1e-12;
        assert!((field.energy(&x) - e).abs() <= 1e-12 * e);
    }

    #[test]
    fn forces_are_minus_the_energy_gradient_and_the_product_is_their_derivative() {
        // The energy is quadratic: central differences are exact up to rounding. Away from the
        // positions it was linearised at, so that the volume's change enters.
        let field = field(&positions(0.7));
        let (x, p) = (positions(0.9), positions(1.3));
        crate::forcefield::checks::forces_and_product(&field, &x, &p, (1e-6, 1e-12), (1e-6, 1e-12));
    }

    #[test]
    fn diagonal_blocks_are_the_products_diagonal() {
        let x = positions(0.2);
        crate::forcefield::checks::diagonal_blocks(&field(&x), &x, (1e-9, 1e-9));
    }

    #[test]
    fn a_cut_drops_the_nodes_it_removed() {
        let x = positions(0.7);
        let mut field = field(&x);
        let new_of_old = [Some(0), None, Some(1), Some(2), Some(3)];
        field.topology_changed(&TopologyChange { new_of_old: &new_of_old });
        // Region two was node 1 alone: gone. Region one keeps nodes 0, 2, 3, 4 as 0, 1, 2, 3.
        assert_eq!(field.regions().len(), 1);
        let nodes: Vec<u32> = field.regions()[0].gradient().iter().map(|&(n, _)| n).collect();
        assert_eq!(nodes, [0, 1, 2, 3]);
    }
}
