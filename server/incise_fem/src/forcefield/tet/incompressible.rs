//! The incompressibility penalty of paper 2 §4: each vertex of a tetrahedron is pushed along the
//! normal of its opposite face with a magnitude growing as the square of the relative volume
//! change, `F_p ∝ ((V − V₀)/V₀)² N_p`, outwards when the tetrahedron is compressed and inwards when
//! it is stretched ("a pressure increase inside the tetrahedron").
//!
//! Written as `F_p = −κ sign(V − V₀) ((V − V₀)/V₀)² ∂V/∂x_p` (`∂V/∂x_p` is a third of the opposite
//! face's area vector, pointing at `p`), it is the force of the energy `κ V₀ |V/V₀ − 1|³ / 3`, so it
//! is conservative and the explicit integrator's energy stays bounded. `κ` (Pa) sets its strength.

use super::element::TetModel;
use incise_math::Vec3;
use incise_math::mat3::{cross, dot as dot3};

/// `∂V/∂x_p` for the four vertices of the tetrahedron `p`.
#[must_use]
// Plain array expressions, not `array::from_fn` or `map` closures: whether those are inlined
// depends on how the crate falls into codegen units, and this runs per tetrahedron per step.
#[inline]
pub fn volume_gradient(p: &[Vec3; 4]) -> [Vec3; 4] {
    let d =
        |a: usize, b: usize| -> Vec3 { [p[b][0] - p[a][0], p[b][1] - p[a][1], p[b][2] - p[a][2]] };
    let sixth = |v: Vec3| -> Vec3 { [v[0] / 6.0, v[1] / 6.0, v[2] / 6.0] };
    let g1 = sixth(cross(&d(0, 2), &d(0, 3)));
    let g2 = sixth(cross(&d(0, 3), &d(0, 1)));
    let g3 = sixth(cross(&d(0, 1), &d(0, 2)));
    let g0 = [-g1[0] - g2[0] - g3[0], -g1[1] - g2[1] - g3[1], -g1[2] - g2[2] - g3[2]];
    [g0, g1, g2, g3]
}

/// The penalty with strength `kappa` (Pa) on every live tetrahedron.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Incompressibility {
    /// Strength κ (Pa).
    pub kappa: f64,
}

impl Incompressibility {
    /// `f += penalty forces` over the tetrahedra `live(t)` accepts.
    pub fn add_forces(
        &self,
        model: &TetModel,
        live: impl Fn(usize) -> bool,
        x: &[Vec3],
        f: &mut [Vec3],
    ) {
        for t in (0..model.tets.len()).filter(|&t| live(t)) {
            let p = model.tets[t].map(|n| x[n as usize]);
            let delta = model.current_volume(t, x) / model.volume[t] - 1.0;
            let scale = -self.kappa * delta * delta.abs();
            for (g, &n) in volume_gradient(&p).iter().zip(&model.tets[t]) {
                for k in 0..3 {
                    f[n as usize][k] += scale * g[k];
                }
            }
        }
    }

    /// `out += scale · K p` with the Gauss–Newton part of the penalty's Jacobian,
    /// `K = Σ (2κ|δ|/V₀) ∇V ∇Vᵀ` (`δ = V/V₀ − 1`): symmetric positive semi-definite, zero at
    /// rest, and what keeps a compressed tetrahedron from collapsing within one implicit step. The
    /// part left out, `κ δ|δ| ∇²V`, is small where the penalty is (`δ²` against `|δ|`).
    pub fn add_stiffness_times(
        &self,
        model: &TetModel,
        live: impl Fn(usize) -> bool,
        x: &[Vec3],
        scale: f64,
        p: &[Vec3],
        out: &mut [Vec3],
    ) {
        self.each_stiffness_term(model, live, x, |nodes, weight, g| {
            let gp: f64 = g.iter().zip(&nodes).map(|(gi, &n)| dot3(gi, &p[n])).sum();
            for (gi, &n) in g.iter().zip(&nodes) {
                for k in 0..3 {
                    out[n][k] += scale * weight * gp * gi[k];
                }
            }
        });
    }

    /// `blocks[n] += K_nn` of [`Self::add_stiffness_times`]'s Jacobian.
    pub fn add_diagonal_blocks(
        &self,
        model: &TetModel,
        live: impl Fn(usize) -> bool,
        x: &[Vec3],
        blocks: &mut [incise_math::mat3::Mat3],
    ) {
        self.each_stiffness_term(model, live, x, |nodes, weight, g| {
            for (gi, &n) in g.iter().zip(&nodes) {
                for i in 0..3 {
                    for j in 0..3 {
                        blocks[n][i][j] += weight * gi[i] * gi[j];
                    }
                }
            }
        });
    }

    /// `term(nodes, 2κ|δ|/V₀, ∇V)` for each live tetrahedron whose volume changed: the
    /// Gauss–Newton Jacobian is `Σ term · ∇V ∇Vᵀ`.
    fn each_stiffness_term(
        self,
        model: &TetModel,
        live: impl Fn(usize) -> bool,
        x: &[Vec3],
        mut term: impl FnMut([usize; 4], f64, [Vec3; 4]),
    ) {
        for t in (0..model.tets.len()).filter(|&t| live(t)) {
            let nodes = model.tets[t].map(|n| n as usize);
            let delta = model.current_volume(t, x) / model.volume[t] - 1.0;
            let weight = 2.0 * self.kappa * delta.abs() / model.volume[t];
            if weight != 0.0 {
                term(nodes, weight, volume_gradient(&nodes.map(|n| x[n])));
            }
        }
    }

    /// The penalty's energy `Σ κ V₀ |V/V₀ − 1|³ / 3` (J).
    #[must_use]
    pub fn energy(&self, model: &TetModel, live: impl Fn(usize) -> bool, x: &[Vec3]) -> f64 {
        (0..model.tets.len())
            .filter(|&t| live(t))
            .map(|t| {
                let delta = (model.current_volume(t, x) / model.volume[t] - 1.0).abs();
                self.kappa * model.volume[t] * delta * delta * delta / 3.0
            })
            .sum()
    }
}
