//! The rotation's own derivative in the corotational force's Jacobian, for static Newton.
//!
//! The corotational force of an element is `f = −R K (Rᵀx − x₀)` with `R` the rotation of the
//! deformation gradient `F = Σₐ xₐ ⊗ gₐ` (`gₐ = ∇Nₐ` where the rotation is taken). Implicit
//! steps use `R K Rᵀ` as its stiffness, which is exact at a rotated rest state but leaves out
//! `∂R/∂x`: under load that omission is of the size of the force itself, and Newton on a
//! heavily loaded organ converges slowly or not at all with it. This module adds the missing
//! part.
//!
//! Differentiating `R` where `RᵀF = S` is symmetric (the polar rotation, and the fixed point of
//! the inversion-safe extraction): with `δR = R [ω]×`, `RᵀδF − δFᵀR = [ω]×S + S[ω]× =
//! [(tr S · I − S) ω]×`, and `RᵀδF − δFᵀR` is the cross-product matrix of `Σₐ gₐ × (Rᵀδxₐ)`, so
//!
//! `ω = (tr S · I − S)⁻¹ Σₐ [gₐ]× Rᵀδxₐ = G Rᵀδx`.
//!
//! With `u = Rᵀx − x₀`, `δf = −R K Rᵀ δx + R (Q − K P) ω`, where block `a` of `Q` is
//! `[(K u)ₐ]×` and of `P` is `[(Rᵀx)ₐ]×`. The stiffness `−∂f/∂x` is therefore
//! `R (K + (K P − Q) G) Rᵀ`: `R K Rᵀ` plus a rank-3 term per element, not symmetric in general
//! (the corotational force is not the gradient of an energy), so the Newton step that uses it
//! needs a nonsymmetric solver (`linsolve::bicgstab`).

use crate::forcefield::hex::{Formulation, HexForceField};
use crate::model::HexModel;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, cross, mul_transpose_vec, mul_vec};

/// One element's rank-3 term in the element's frame: `C = K P − Q` (24×3), and
/// `(tr S · I − S)⁻¹`, which with the shape-function gradients gives `G` (kept apart: `G`
/// itself is 72 numbers per element instead of 9 to stream through every product).
#[derive(Clone, Debug)]
struct Term {
    c: [[f64; 3]; 24],
    m_inv: Mat3,
}

/// The `∂R/∂x` part of every element's corotational stiffness at one configuration.
#[derive(Debug, Default)]
pub struct RotationTangent {
    /// `None` for an element whose rotation is not differentiable there (`tr S · I − S`
    /// singular: two principal stretches of opposite sign and equal size, the fold of an
    /// inversion), which then keeps `R K Rᵀ`.
    terms: Vec<Option<Term>>,
    /// Each element's product, computed on the element threads and summed in element order.
    scratch: std::cell::RefCell<Vec<[f64; 24]>>,
}

/// `[v]×`, the matrix of `w ↦ v × w`.
fn cross_matrix(v: &Vec3) -> Mat3 {
    [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]
}

/// The inverse of a symmetric 3×3 matrix, or `None` when it is singular relative to its size.
fn inverse(m: &Mat3) -> Option<Mat3> {
    let cof: Mat3 = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let (r0, r1) = ((j + 1) % 3, (j + 2) % 3);
            let (c0, c1) = ((i + 1) % 3, (i + 2) % 3);
            m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
        })
    });
    let det = m[0][0] * cof[0][0] + m[0][1] * cof[1][0] + m[0][2] * cof[2][0];
    let size = m.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    (det.abs() > 1e-10 * size * size * size).then(|| cof.map(|row| row.map(|c| c / det)))
}

impl RotationTangent {
    /// The term at positions `x`, with `ff`'s rotations already taken there
    /// ([`HexForceField::update_rotations`]). Empty for the linear formulation.
    #[must_use]
    pub fn at(model: &HexModel, ff: &HexForceField, x: &[Vec3]) -> Self {
        if ff.formulation() == Formulation::Linear {
            return Self::default();
        }
        let terms =
            ff.executor().map_elements(model.elements.len(), |e| Self::term(model, ff, x, e));
        Self { terms, scratch: std::cell::RefCell::default() }
    }

    fn term(model: &HexModel, ff: &HexForceField, x: &[Vec3], e: usize) -> Option<Term> {
        let element = &model.elements[e];
        let r = ff.rotation(e);
        let grad = ff.rotation_gradient(e);
        let local: [Vec3; 8] =
            std::array::from_fn(|a| mul_transpose_vec(r, &x[element.nodes[a] as usize]));
        // S = Rᵀ F, symmetrised (it is symmetric where the extraction converged).
        let mut s = [[0.0; 3]; 3];
        for (y, g) in local.iter().zip(grad) {
            for i in 0..3 {
                for j in 0..3 {
                    s[i][j] += y[i] * g[j];
                }
            }
        }
        let trace = s[0][0] + s[1][1] + s[2][2];
        let m: Mat3 = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let sym = 0.5 * (s[i][j] + s[j][i]);
                if i == j { trace - sym } else { -sym }
            })
        });
        let m_inv = inverse(&m)?;
        let k = &element.stiffness;
        let rest = |a: usize| model.rest[element.nodes[a] as usize];
        let u: [f64; 24] = std::array::from_fn(|i| local[i / 3][i % 3] - rest(i / 3)[i % 3]);
        let ku: [f64; 24] = std::array::from_fn(|i| (0..24).map(|j| k.get(i, j) * u[j]).sum());
        // P's block a is [yₐ]×; (K P) column c: Σ_b K[:, b] [y_b]×[:, c].
        let p: [Mat3; 8] = std::array::from_fn(|a| cross_matrix(&local[a]));
        let mut c = [[0.0; 3]; 24];
        for (i, row) in c.iter_mut().enumerate() {
            for (col, out) in row.iter_mut().enumerate() {
                *out = (0..24).map(|j| k.get(i, j) * p[j / 3][j % 3][col]).sum();
            }
            let q = cross_matrix(&[ku[3 * (i / 3)], ku[3 * (i / 3) + 1], ku[3 * (i / 3) + 2]]);
            for col in 0..3 {
                row[col] -= q[i % 3][col];
            }
        }
        Some(Term { c, m_inv })
    }

    /// `G`'s columns for corner `a`: `(tr S · I − S)⁻¹ [gₐ]×`.
    fn g_block(m_inv: &Mat3, ga: &Vec3) -> Mat3 {
        incise_math::mat3::mul(m_inv, &cross_matrix(ga))
    }

    /// The symmetric part of element `e`'s term `(K P − Q) G` in its frame (24×24), or `None`
    /// where it has none; `ff` is the force field the term was taken with.
    #[must_use]
    pub fn symmetric_block(&self, ff: &HexForceField, e: usize) -> Option<[[f64; 24]; 24]> {
        let term = self.terms.get(e)?.as_ref()?;
        let grad = ff.rotation_gradient(e);
        let g: [Mat3; 8] = std::array::from_fn(|a| Self::g_block(&term.m_inv, &grad[a]));
        let full: [[f64; 24]; 24] = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| term.c[i][k] * g[j / 3][k][j % 3]).sum())
        });
        Some(std::array::from_fn(|i| std::array::from_fn(|j| 0.5 * (full[i][j] + full[j][i]))))
    }

    /// `out += scale · R (K P − Q) G Rᵀ p` summed over the elements: added to
    /// [`HexForceField::add_stiffness_times`] it gives the full corotational stiffness.
    pub fn add_times(
        &self,
        model: &HexModel,
        ff: &HexForceField,
        scale: f64,
        p: &[Vec3],
        out: &mut [Vec3],
    ) {
        let mut scratch = self.scratch.borrow_mut();
        scratch.resize(self.terms.len(), [0.0; 24]);
        let terms = &self.terms;
        ff.executor().update_elements(&mut scratch, |e, local| {
            let Some(term) = &terms[e] else { return };
            let nodes = &model.elements[e].nodes;
            let r = ff.rotation(e);
            let grad = ff.rotation_gradient(e);
            // ω = (tr S · I − S)⁻¹ Σₐ gₐ × Rᵀpₐ
            let mut w = [0.0; 3];
            for (ga, &n) in grad.iter().zip(nodes) {
                let y = mul_transpose_vec(r, &p[n as usize]);
                let c = cross(ga, &y);
                for k in 0..3 {
                    w[k] += c[k];
                }
            }
            let omega = mul_vec(&term.m_inv, &w);
            for a in 0..8 {
                let z: Vec3 = std::array::from_fn(|k| {
                    let row = &term.c[3 * a + k];
                    scale * (row[0] * omega[0] + row[1] * omega[1] + row[2] * omega[2])
                });
                local[3 * a..3 * a + 3].copy_from_slice(&mul_vec(r, &z));
            }
        });
        for ((element, term), local) in model.elements.iter().zip(terms).zip(scratch.iter()) {
            if term.is_some() {
                for (a, &n) in element.nodes.iter().enumerate() {
                    let o = &mut out[n as usize];
                    for k in 0..3 {
                        o[k] += local[3 * a + k];
                    }
                }
            }
        }
    }
}
