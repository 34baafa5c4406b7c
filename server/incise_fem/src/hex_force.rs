//! Hexahedral force fields on the branched grid, each element with its own condensed stiffness
//! (partially filled and superimposed elements included; Nesme 2006 via Jeřábková 2010 §2.2).
//!
//! - [`Formulation::Linear`]: `f = −K (x − x₀)`; rotations produce spurious forces.
//! - [`Formulation::Corotational`]: the element rotation `R` is extracted from the deformation
//!   gradient at the element centre, `F = Σₐ xₐ ⊗ ∇Nₐ(centre)`, by the inversion-safe method of
//!   `incise_math::rotation` (warm-started from the previous call); forces are
//!   `f = −R K (Rᵀx − x₀)` and the stiffness used by implicit solves is `R K Rᵀ` per element.

use crate::kernel::{symmetric_product, symmetric_product_pair};
use crate::model::HexModel;
use crate::parallel::{fill_element_pairs, fill_elements, map_elements};
use incise_grid::hex8::corner;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, mul_transpose_vec, mul_vec};
use incise_math::rotation::{Quat, nearest_rotation};
use std::sync::Arc;

/// How element rotations are treated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Formulation {
    /// Small-strain linear elasticity.
    Linear,
    /// Linear elasticity in each element's rotated frame.
    Corotational,
}

/// Iterations allowed to refine an element rotation from its warm start.
const ROTATION_ITERATIONS: usize = 100;

/// Per-element rotations and the shape-function gradients at the element centre.
#[derive(Clone, Debug)]
pub struct HexForceField {
    formulation: Formulation,
    rotations: Vec<Quat>,
    matrices: Vec<Mat3>,
    centre_gradient: [Vec3; 8],
}

impl HexForceField {
    /// A force field for `model`, all rotations at identity.
    #[must_use]
    pub fn new(model: &HexModel, formulation: Formulation) -> Self {
        let s = model.element_size;
        let centre_gradient = std::array::from_fn(|c| {
            let b = corner(c);
            std::array::from_fn(|a| if b[a] == 1 { 0.25 / s[a] } else { -0.25 / s[a] })
        });
        let n = model.elements.len();
        Self {
            formulation,
            rotations: vec![Quat::IDENTITY; n],
            matrices: vec![incise_math::mat3::IDENTITY; n],
            centre_gradient,
        }
    }

    /// The force field for `new_model` after a topology change, keeping each surviving element's
    /// rotation (matched by grid element id) and giving a split-off element the rotation of the
    /// element it came from (`origin(grid_id)`, a grid id of the old model).
    #[must_use]
    pub fn remapped(
        &self,
        old_model: &HexModel,
        new_model: &HexModel,
        origin: impl Fn(u32) -> Option<u32>,
    ) -> Self {
        let mut by_grid: Vec<(u32, usize)> =
            old_model.elements.iter().enumerate().map(|(i, e)| (e.grid_id, i)).collect();
        by_grid.sort_unstable();
        let find =
            |g: u32| by_grid.binary_search_by_key(&g, |&(id, _)| id).ok().map(|k| by_grid[k].1);
        let mut out = Self::new(new_model, self.formulation);
        for (i, e) in new_model.elements.iter().enumerate() {
            let old = match origin(e.grid_id) {
                Some(o) => find(o),
                None => find(e.grid_id),
            };
            if let Some(j) = old {
                out.rotations[i] = self.rotations[j];
                out.matrices[i] = self.matrices[j];
            }
        }
        out
    }

    /// The formulation.
    #[must_use]
    pub fn formulation(&self) -> Formulation {
        self.formulation
    }

    /// Rotation of element `e` (identity for the linear formulation).
    #[must_use]
    pub fn rotation(&self, e: usize) -> &Mat3 {
        &self.matrices[e]
    }

    /// Re-extracts every element's rotation from positions `x` (no-op when linear).
    pub fn update_rotations(&mut self, model: &HexModel, x: &[Vec3]) {
        if self.formulation == Formulation::Linear {
            return;
        }
        let grad = self.centre_gradient;
        let previous = &self.rotations;
        // Each element's matrix is formed in the parallel loop with its rotation.
        let mut updated = vec![(Quat::IDENTITY, incise_math::mat3::IDENTITY); previous.len()];
        fill_elements(&mut updated, |e| {
            let el = &model.elements[e];
            let mut f = [[0.0; 3]; 3];
            for (c, &n) in el.nodes.iter().enumerate() {
                let p = x[n as usize];
                for r in 0..3 {
                    for k in 0..3 {
                        f[r][k] += p[r] * grad[c][k];
                    }
                }
            }
            let mut q = previous[e];
            nearest_rotation(&f, &mut q, ROTATION_ITERATIONS);
            (q, q.to_matrix())
        });
        (self.rotations, self.matrices) = updated.into_iter().unzip();
    }

    /// Displacement of element `e` in its rotated frame, `Rᵀx − x₀`, as a 24-vector.
    #[inline]
    fn local_displacement(&self, model: &HexModel, e: usize, x: &[Vec3]) -> [f64; 24] {
        let el = &model.elements[e];
        let r = &self.matrices[e];
        let mut u = [0.0; 24];
        for (c, &n) in el.nodes.iter().enumerate() {
            let (p, p0) = (x[n as usize], model.rest[n as usize]);
            let q =
                if self.formulation == Formulation::Linear { p } else { mul_transpose_vec(r, &p) };
            u[3 * c] = q[0] - p0[0];
            u[3 * c + 1] = q[1] - p0[1];
            u[3 * c + 2] = q[2] - p0[2];
        }
        u
    }

    /// Element `e`'s vector `p` in its rotated frame, `Rᵀp`, as a 24-vector.
    #[inline]
    fn local_vector(&self, model: &HexModel, e: usize, p: &[Vec3]) -> [f64; 24] {
        let el = &model.elements[e];
        let r = &self.matrices[e];
        let mut local = [0.0; 24];
        for (c, &n) in el.nodes.iter().enumerate() {
            let v = p[n as usize];
            let q =
                if self.formulation == Formulation::Linear { v } else { mul_transpose_vec(r, &v) };
            local[3 * c..3 * c + 3].copy_from_slice(&q);
        }
        local
    }

    /// `scale · R g` per corner: an element product back in the global frame.
    #[inline]
    fn global_corners(&self, e: usize, scale: f64, g: &[f64; 24]) -> [Vec3; 8] {
        let r = &self.matrices[e];
        std::array::from_fn(|c| {
            let gc = [scale * g[3 * c], scale * g[3 * c + 1], scale * g[3 * c + 2]];
            if self.formulation == Formulation::Linear { gc } else { mul_vec(r, &gc) }
        })
    }

    /// `out += Σₑ scale · R Kₑ local(e)`: the element loop shared by every product.
    fn add_products(
        &self,
        model: &HexModel,
        scale: f64,
        local: impl Fn(usize) -> [f64; 24] + Sync,
        out: &mut [Vec3],
    ) {
        with_scratch(model.elements.len(), |per_element| {
            fill_element_pairs(per_element, |e, slots| {
                self.products_from(model, scale, &local, e, slots);
            });
            scatter(&model.elements, per_element, out);
        });
    }

    /// `slots[i] = scale · R Kₑ local(e)` per corner for elements `e = first + i`. Neighbouring
    /// elements with the same stiffness (every full cell of a material) are multiplied as a pair,
    /// loading the matrix once; the result does not depend on the pairing.
    fn products_from(
        &self,
        model: &HexModel,
        scale: f64,
        local: &impl Fn(usize) -> [f64; 24],
        first: usize,
        slots: &mut [[Vec3; 8]],
    ) {
        for (k, pair) in slots.chunks_mut(2).enumerate() {
            let e = first + 2 * k;
            let shared = &model.elements[e].stiffness;
            if let [a, b] = pair
                && Arc::ptr_eq(shared, &model.elements[e + 1].stiffness)
            {
                let (g, h) = symmetric_product_pair(shared, &local(e), &local(e + 1));
                *a = self.global_corners(e, scale, &g);
                *b = self.global_corners(e + 1, scale, &h);
            } else {
                for (i, slot) in pair.iter_mut().enumerate() {
                    let k = &model.elements[e + i].stiffness;
                    *slot = self.global_corners(e + i, scale, &symmetric_product(k, &local(e + i)));
                }
            }
        }
    }

    /// `out += scale · R Kₑ Rᵀ p` for the elements in `elements` (starting at an even index), in
    /// element order: one part of a stiffness product whose parts are summed elsewhere.
    pub(crate) fn add_stiffness_products_of(
        &self,
        model: &HexModel,
        scale: f64,
        p: &[Vec3],
        elements: std::ops::Range<usize>,
        out: &mut [Vec3],
    ) {
        let local = |e| self.local_vector(model, e, p);
        let mut slots = [[[0.0; 3]; 8]; 2];
        for first in elements.clone().step_by(2) {
            let len = (elements.end - first).min(2);
            self.products_from(model, scale, &local, first, &mut slots[..len]);
            scatter(&model.elements[first..], &slots[..len], out);
        }
    }

    /// For the elements in `elements`, in element order: `forces += −R K ((Rᵀx − x₀) − s·Rᵀv)`
    /// (the elastic forces and the stiffness term of an implicit step's right-hand side) and
    /// `products += b · R K Rᵀ p`, both products of an element taken in one pass over its matrix.
    #[allow(clippy::too_many_arguments)] // one element pass, its inputs and its two outputs
    pub(crate) fn add_step_products(
        &self,
        model: &HexModel,
        (x, s, v): (&[Vec3], f64, &[Vec3]),
        (b, p): (f64, &[Vec3]),
        elements: std::ops::Range<usize>,
        forces: &mut [Vec3],
        products: &mut [Vec3],
    ) {
        for e in elements {
            let u = self.local_displacement(model, e, x);
            let w = self.local_vector(model, e, v);
            let q = self.local_vector(model, e, p);
            let u: [f64; 24] = std::array::from_fn(|i| u[i] - s * w[i]);
            let (g, k) = symmetric_product_pair(&model.elements[e].stiffness, &u, &q);
            let el = std::slice::from_ref(&model.elements[e]);
            scatter(el, &[self.global_corners(e, -1.0, &g)], forces);
            scatter(el, &[self.global_corners(e, b, &k)], products);
        }
    }

    /// `f += elastic forces at positions x` (call [`HexForceField::update_rotations`] first).
    pub fn add_forces(&self, model: &HexModel, x: &[Vec3], f: &mut [Vec3]) {
        self.add_products(model, -1.0, |e| self.local_displacement(model, e, x), f);
    }

    /// `out += scale · K(x) p`, with `K` the (rotated) stiffness, element by element.
    pub fn add_stiffness_times(&self, model: &HexModel, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.add_products(model, scale, |e| self.local_vector(model, e, p), out);
    }

    /// `out += f(x) + scale · K(x) p` in one element loop (the right-hand side of an implicit
    /// step): `−R K ((Rᵀx − x₀) − scale · Rᵀp)` per element.
    pub fn add_forces_and_stiffness_times(
        &self,
        model: &HexModel,
        x: &[Vec3],
        scale: f64,
        p: &[Vec3],
        out: &mut [Vec3],
    ) {
        self.add_products(
            model,
            -1.0,
            |e| {
                let u = self.local_displacement(model, e, x);
                let q = self.local_vector(model, e, p);
                std::array::from_fn(|i| u[i] - scale * q[i])
            },
            out,
        );
    }

    /// The 3×3 diagonal blocks of the (rotated) stiffness, per node: `R K_cc Rᵀ` summed (in
    /// element order).
    #[must_use]
    pub fn diagonal_blocks(&self, model: &HexModel) -> Vec<Mat3> {
        let rotated = self.formulation == Formulation::Corotational;
        let per_element: Vec<[Mat3; 8]> = map_elements(model.elements.len(), |e| {
            let el = &model.elements[e];
            let r = &self.matrices[e];
            std::array::from_fn(|c| {
                let k: Mat3 = std::array::from_fn(|i| {
                    std::array::from_fn(|j| el.stiffness.get(3 * c + i, 3 * c + j))
                });
                if rotated { rotate_symmetric(r, &k) } else { k }
            })
        });
        let mut out = vec![[[0.0; 3]; 3]; model.node_count()];
        for (el, blocks) in model.elements.iter().zip(&per_element) {
            for (&n, k) in el.nodes.iter().zip(blocks) {
                let d = &mut out[n as usize];
                for i in 0..3 {
                    for j in 0..3 {
                        d[i][j] += k[i][j];
                    }
                }
            }
        }
        out
    }

    /// Elastic energy `½ Σₑ uₑᵀ Kₑ uₑ` (J), with `u` in each element's rotated frame.
    #[must_use]
    pub fn energy(&self, model: &HexModel, x: &[Vec3]) -> f64 {
        let per_element = map_elements(model.elements.len(), |e| {
            let u = self.local_displacement(model, e, x);
            let g = symmetric_product(&model.elements[e].stiffness, &u);
            0.5 * u.iter().zip(g.iter()).map(|(a, b)| a * b).sum::<f64>()
        });
        per_element.iter().sum()
    }
}

/// `R K Rᵀ` for a symmetric `K`: the upper triangle computed, the lower mirrored (exactly
/// symmetric, 45 multiplications instead of 54).
fn rotate_symmetric(r: &Mat3, k: &Mat3) -> Mat3 {
    let t: Mat3 = std::array::from_fn(|i| {
        std::array::from_fn(|j| r[i][0] * k[0][j] + r[i][1] * k[1][j] + r[i][2] * k[2][j])
    });
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in i..3 {
            let v = t[i][0] * r[j][0] + t[i][1] * r[j][1] + t[i][2] * r[j][2];
            out[i][j] = v;
            out[j][i] = v;
        }
    }
    out
}

thread_local! {
    /// Per-element results of the element loops, kept between calls: a fresh buffer per call
    /// (0.8 MB on scene B3) cost page faults and cross-core TLB flushes on every CG iteration.
    static SCRATCH: std::cell::RefCell<Vec<[Vec3; 8]>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` on a buffer of `n` per-element corner vectors borrowed from this thread's scratch.
fn with_scratch<R>(n: usize, f: impl FnOnce(&mut [[Vec3; 8]]) -> R) -> R {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut buf) => {
            buf.resize(n, [[0.0; 3]; 8]);
            f(&mut buf[..n])
        }
        // Re-entered (a callback inside an element loop): a one-off buffer.
        Err(_) => f(&mut vec![[[0.0; 3]; 8]; n]),
    })
}

/// Adds per-element corner vectors into node vectors, in element order (deterministic):
/// `per_element[i]` belongs to `elements[i]`.
fn scatter(elements: &[crate::model::HexElement], per_element: &[[Vec3; 8]], out: &mut [Vec3]) {
    for (el, fs) in elements.iter().zip(per_element) {
        for (c, &n) in el.nodes.iter().enumerate() {
            let o = &mut out[n as usize];
            o[0] += fs[c][0];
            o[1] += fs[c][1];
            o[2] += fs[c][2];
        }
    }
}
