//! Hexahedral force fields on the branched grid, each element with its own condensed stiffness
//! (partially filled and superimposed elements included; Nesme 2006 via Jeřábková 2010 §2.2).
//!
//! - [`Formulation::Linear`]: `f = −K (x − x₀)`; rotations produce spurious forces.
//! - [`Formulation::Corotational`]: the element rotation `R` is extracted from the deformation
//!   gradient at the centre of mass of the element's material, `F = Σₐ xₐ ⊗ ∇Nₐ(ξ̄)` (the
//!   cell's centre for a full cell), by the inversion-safe method of
//!   `incise_math::rotation` (warm-started from the previous call); forces are
//!   `f = −R K (Rᵀx − x₀)` and the stiffness used by implicit steps is `R K Rᵀ` per element
//!   (static Newton adds the rotation's derivative, `crate::forcefield::hex::tangent`).

use crate::exec::Executor;
use crate::forcefield::hex::kernel::{
    Local, Wide, component_major, gather, product, product_pair, scatter_add, to_global, to_local,
    vectorized,
};
use crate::forcefield::hex::walsh::Walsh;
use crate::model::{HexModel, Renumbering};
use incise_grid::hex8::{Mat24, corner};
use incise_math::Vec3;
use incise_math::lanes::{Lane, Lane4};
use incise_math::mat3::Mat3;
use incise_math::rotation::{Quat, nearest, nearest4};
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

/// Per-element rotations, the element matrices in the element passes' layout, and the
/// shape-function gradients the rotations are taken at.
#[derive(Clone, Debug)]
pub struct HexForceField {
    formulation: Formulation,
    frames: Vec<Frame>,
    /// Each element's stiffness, component-major ([`component_major`]); elements that share a
    /// matrix in the model share it here too.
    stiffness: Vec<Arc<Mat24>>,
    /// The same stiffness in the Walsh–Hadamard basis where it is a full cell's
    /// ([`Walsh::of`]): the element passes multiply by that instead.
    walsh: Vec<Option<Arc<Walsh>>>,
    centre_gradient: [Vec3; 8],
    /// Elements whose material's centre of mass is off the cell's centre (partly filled and
    /// superimposed ones): the shape-function gradients there, which their rotation is taken
    /// at instead ([`material_gradient`]).
    off_centre: Vec<Option<Arc<[Vec3; 8]>>>,
    /// The threads its element loops run on.
    exec: Executor,
}

/// The shape-function gradients of a box of edge lengths `s` at the centre of mass of the
/// material its consistent mass block `m` holds. Trilinear shape functions reproduce linear
/// fields, so that centre is `Σ_c m_c ξ_c / Σ_c m_c` with `m_c` the row sums of `m`: exact,
/// without the voxels. `None` at the cell's centre (a full cell), where the shared centre
/// gradients serve.
///
/// Why: the deformation gradient at the cell's centre weighs all eight corners alike, so in a
/// cell whose material sits in one corner the far corners, tied to almost nothing, steer the
/// rotation. With the rotation held fixed through a step (linearised backward Euler), such a
/// corner's motion rotates its own restoring force: on the liver at level 3 corners of 1e-7 kg
/// swung metres away at hundreds of m/s and the organ never came to rest. At the material's
/// centre the far corners' weight is the product of small coordinates.
fn material_gradient(m: &[f64; 64], s: Vec3) -> Option<[Vec3; 8]> {
    let corner_mass: [f64; 8] = std::array::from_fn(|c| m[8 * c..8 * c + 8].iter().sum());
    let total: f64 = corner_mass.iter().sum();
    if total <= 0.0 {
        return None;
    }
    let xi: Vec3 = std::array::from_fn(|a| {
        corner_mass
            .iter()
            .enumerate()
            .filter(|(c, _)| corner(*c)[a] == 1)
            .map(|(_, m)| m)
            .sum::<f64>()
            / total
    });
    if xi.iter().all(|&x| (x - 0.5).abs() <= 1e-12) {
        return None;
    }
    Some(gradient_at(xi, s))
}

/// The trilinear shape functions' gradients at local point `xi` of a box of edge lengths `s`
/// (at the centre, `±0.25 / s` exactly).
fn gradient_at(xi: Vec3, s: Vec3) -> [Vec3; 8] {
    std::array::from_fn(|c| {
        let b = corner(c);
        let factor = |a: usize| if b[a] == 1 { xi[a] } else { 1.0 - xi[a] };
        std::array::from_fn(|a| {
            let sign = if b[a] == 1 { 1.0 } else { -1.0 };
            sign * factor((a + 1) % 3) * factor((a + 2) % 3) / s[a]
        })
    })
}

/// Permuted stiffness matrices (and their Walsh forms) by the model matrix they were made from.
type Shared = std::collections::HashMap<*const Mat24, (Arc<Mat24>, Option<Arc<Walsh>>)>;

/// An element's rotation, as the quaternion the next extraction starts from and as a matrix.
#[derive(Clone, Copy, Debug)]
struct Frame {
    q: Quat,
    r: Mat3,
}

impl Frame {
    const IDENTITY: Self = Self { q: Quat::IDENTITY, r: incise_math::mat3::IDENTITY };
}

/// What an element pass multiplies by the stiffness: a vector in each element's frame.
#[derive(Clone, Copy)]
enum Input<'a> {
    /// `Rᵀp`.
    Vector(&'a [Vec3]),
    /// The displacement `Rᵀ(x − s·v) − x₀` (no `s·v` term when `moved` is `None`).
    Displacement { x: &'a [Vec3], moved: Option<(f64, &'a [Vec3])> },
}

impl HexForceField {
    /// A force field for `model`, all rotations at identity, on an executor of its own (see
    /// [`Self::with_executor`]).
    #[must_use]
    pub fn new(model: &HexModel, formulation: Formulation) -> Self {
        Self::with_known(model, formulation, Shared::new(), Executor::default())
    }

    /// The same field running its loops on `exec` (the simulation's executor, shared with its
    /// solvers).
    #[must_use]
    pub fn with_executor(mut self, exec: Executor) -> Self {
        self.exec = exec;
        self
    }

    /// The executor its loops run on; the integrators and solvers working on this field use it
    /// too.
    #[must_use]
    pub fn executor(&self) -> &Executor {
        &self.exec
    }

    /// [`Self::new`] reusing the permuted matrices in `known` (by the model matrix they came
    /// from) and computing only the others.
    fn with_known(
        model: &HexModel,
        formulation: Formulation,
        mut known: Shared,
        exec: Executor,
    ) -> Self {
        let s = model.element_size;
        let centre_gradient = gradient_at([0.5; 3], s);
        // One permuted copy per shared matrix, so the pairs of the element passes still find
        // their neighbours' matrix the same.
        let (stiffness, walsh) = model
            .elements
            .iter()
            .map(|el| {
                let (k, w) = known.entry(Arc::as_ptr(&el.stiffness)).or_insert_with(|| {
                    let k = component_major(&el.stiffness);
                    let w = Walsh::of(&k).map(Arc::new);
                    (Arc::new(k), w)
                });
                (Arc::clone(k), w.clone())
            })
            .unzip();
        let off_centre =
            model.elements.iter().map(|el| material_gradient(&el.mass, s).map(Arc::new)).collect();
        Self {
            formulation,
            frames: vec![Frame::IDENTITY; model.elements.len()],
            stiffness,
            walsh,
            centre_gradient,
            off_centre,
            exec,
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
        // Elements the edit left alone keep their model matrix (the same `Arc`, see
        // `HexModel::updated`), so their permuted copies carry over; only the re-condensed ones
        // are permuted again. The old model is alive here, so no new matrix can reuse the
        // address of an old one.
        let known: Shared = old_model
            .elements
            .iter()
            .enumerate()
            .map(|(j, el)| {
                (
                    Arc::as_ptr(&el.stiffness),
                    (Arc::clone(&self.stiffness[j]), self.walsh[j].clone()),
                )
            })
            .collect();
        let mut out = Self::with_known(new_model, self.formulation, known, self.exec.clone());
        for (i, e) in new_model.elements.iter().enumerate() {
            let old = match origin(e.grid_id) {
                Some(o) => find(o),
                None => find(e.grid_id),
            };
            if let Some(j) = old {
                out.frames[i] = self.frames[j];
            }
        }
        out
    }

    /// [`HexForceField::remapped`] in place, for `model` brought through an edit by
    /// [`HexModel::update`] (`renumbering`, what it returned): the elements that kept their
    /// matrices keep their permuted matrices, rotation and rotation gradients; only those with
    /// new matrices are prepared again, a new element starting from the rotation of the element
    /// it split from (`origin(grid_id)`, a grid id before the edit) or else of the element that
    /// had its id.
    ///
    /// # Panics
    /// If `renumbering` is not what [`HexModel::update`] returned for `model` and this field's
    /// model.
    pub fn remap(
        &mut self,
        model: &HexModel,
        renumbering: &Renumbering,
        origin: impl Fn(u32) -> Option<u32>,
    ) {
        let s = model.element_size;
        let mut known = Shared::new();
        let mut prepared = |el: &crate::model::HexElement| {
            let (k, w) = known.entry(Arc::as_ptr(&el.stiffness)).or_insert_with(|| {
                let k = component_major(&el.stiffness);
                let w = Walsh::of(&k).map(Arc::new);
                (Arc::new(k), w)
            });
            (Arc::clone(k), w.clone(), material_gradient(&el.mass, s).map(Arc::new))
        };
        let kept_all = renumbering.element_before.len() == self.frames.len()
            && renumbering.element_before.iter().enumerate().all(|(i, &b)| b == Some(i as u32));
        if kept_all {
            // No element added or removed: none has an origin, and each keeps its rotation.
            for &i in &renumbering.new_matrices {
                let i = i as usize;
                (self.stiffness[i], self.walsh[i], self.off_centre[i]) =
                    prepared(&model.elements[i]);
            }
            return;
        }
        // The kept elements' data moves over (in order: their old indices rise), not cloned:
        // a reference count touched per element cost more than preparing the new ones.
        let n = model.elements.len();
        let frames = std::mem::replace(&mut self.frames, Vec::with_capacity(n));
        let mut old = std::mem::replace(&mut self.stiffness, Vec::with_capacity(n))
            .into_iter()
            .zip(std::mem::replace(&mut self.walsh, Vec::with_capacity(n)))
            .zip(std::mem::replace(&mut self.off_centre, Vec::with_capacity(n)))
            .enumerate();
        let mut fresh = renumbering.new_matrices.iter().copied().peekable();
        for (i, el) in model.elements.iter().enumerate() {
            let again = fresh.next_if_eq(&(i as u32)).is_some();
            match renumbering.element_before[i] {
                Some(j) if !again => {
                    let j = j as usize;
                    let ((k, w), g) = old
                        .find_map(|(at, data)| (at == j).then_some(data))
                        .expect("kept elements keep their order");
                    self.frames.push(frames[j]);
                    self.stiffness.push(k);
                    self.walsh.push(w);
                    self.off_centre.push(g);
                }
                _ => {
                    let before = origin(el.grid_id).map_or_else(
                        || renumbering.element_before_by_grid_id(el.grid_id),
                        |o| renumbering.element_before_by_grid_id(o),
                    );
                    self.frames.push(before.map_or(Frame::IDENTITY, |j| frames[j]));
                    let (k, w, g) = prepared(el);
                    self.stiffness.push(k);
                    self.walsh.push(w);
                    self.off_centre.push(g);
                }
            }
        }
    }

    /// The formulation.
    #[must_use]
    pub fn formulation(&self) -> Formulation {
        self.formulation
    }

    /// Rotation of element `e` (identity for the linear formulation).
    #[must_use]
    pub fn rotation(&self, e: usize) -> &Mat3 {
        &self.frames[e].r
    }

    /// Every element's rotation as the next extraction starts from it: the quaternion
    /// `(w, x, y, z)` and the matrix (a snapshot of the state; [`Self::set_rotations`]).
    #[must_use]
    pub fn rotations(&self) -> Vec<([f64; 4], Mat3)> {
        self.frames.iter().map(|f| ([f.q.w, f.q.v[0], f.q.v[1], f.q.v[2]], f.r)).collect()
    }

    /// Sets every element's rotation as [`Self::rotations`] gave them.
    ///
    /// # Errors
    /// With a count other than the element count.
    pub fn set_rotations(&mut self, rotations: &[([f64; 4], Mat3)]) -> Result<(), String> {
        if rotations.len() != self.frames.len() {
            return Err(format!(
                "{} rotations for {} elements",
                rotations.len(),
                self.frames.len()
            ));
        }
        for (f, &([w, x, y, z], r)) in self.frames.iter_mut().zip(rotations) {
            *f = Frame { q: Quat { w, v: [x, y, z] }, r };
        }
        Ok(())
    }

    /// The shape-function gradients element `e`'s rotation is taken at (`F = Σₐ xₐ ⊗ ∇Nₐ`).
    pub(crate) fn rotation_gradient(&self, e: usize) -> &[Vec3; 8] {
        self.off_centre[e].as_deref().unwrap_or(&self.centre_gradient)
    }

    /// Re-extracts every element's rotation from positions `x` (no-op when linear).
    pub fn update_rotations(&mut self, model: &HexModel, x: &[Vec3]) {
        if self.formulation == Formulation::Linear {
            return;
        }
        let centre = self.centre_gradient;
        let off_centre = &self.off_centre;
        let grad_of = |e: usize| off_centre[e].as_deref().unwrap_or(&centre);
        let gradient = |e: usize| {
            let grad = grad_of(e);
            let mut f = [[0.0; 3]; 3];
            for (c, &n) in model.elements[e].nodes.iter().enumerate() {
                let p = x[n as usize];
                for r in 0..3 {
                    for k in 0..3 {
                        f[r][k] += p[r] * grad[c][k];
                    }
                }
            }
            f
        };
        // Four elements at a time on vector lanes where there are any (`nearest4`: the same
        // bits as one by one).
        self.exec.update_runs(&mut self.frames, |start, run| {
            vectorized(
                #[inline(always)]
                |wide| {
                    let mut quads = run.chunks_exact_mut(4);
                    let mut done = 0;
                    if let Some(like) = wide.lanes() {
                        for frames in &mut quads {
                            let first = start + done;
                            // The four gradients on the lanes, summed as `gradient` sums them.
                            // Plain loops, not `array::from_fn`, `map` or `all`: whether such
                            // closures are inlined depends on how the crate falls into codegen
                            // units, and this pass is hot.
                            let mut f = [[like.constant(0.0); 3]; 3];
                            let mut grads: [&[Vec3; 8]; 4] = [&centre; 4];
                            let mut centred = true;
                            for i in 0..4 {
                                grads[i] = grad_of(first + i);
                                centred &= off_centre[first + i].is_none();
                            }
                            for c in 0..8 {
                                let mut nodes = [0usize; 4];
                                for i in 0..4 {
                                    nodes[i] = model.elements[first + i].nodes[c] as usize;
                                }
                                for r in 0..3 {
                                    let mut pv = [0.0; 4];
                                    for i in 0..4 {
                                        pv[i] = x[nodes[i]][r];
                                    }
                                    let p = Lane4::from_lanes(like, pv);
                                    for k in 0..3 {
                                        let g = if centred {
                                            like.constant(centre[c][k])
                                        } else {
                                            let mut gv = [0.0; 4];
                                            for i in 0..4 {
                                                gv[i] = grads[i][c][k];
                                            }
                                            Lane4::from_lanes(like, gv)
                                        };
                                        f[r][k] = f[r][k] + p * g;
                                    }
                                }
                            }
                            let mut q = [Quat::IDENTITY; 4];
                            for i in 0..4 {
                                q[i] = frames[i].q;
                            }
                            let refined = nearest4(&f, &mut q, ROTATION_ITERATIONS);
                            for ((frame, q), refined) in frames.iter_mut().zip(q).zip(refined) {
                                *frame = Frame { q, r: refined.matrix };
                            }
                            done += 4;
                        }
                    }
                    for (i, frame) in run[done..].iter_mut().enumerate() {
                        let f = gradient(start + done + i);
                        frame.r = nearest(&f, &mut frame.q, ROTATION_ITERATIONS).matrix;
                    }
                },
            );
        });
    }

    /// Element `e`'s input in its frame, component-major.
    #[allow(clippy::inline_always)] // inlined into the vectorised element passes
    #[inline(always)]
    fn local(&self, wide: Wide, model: &HexModel, e: usize, input: Input) -> Local {
        let nodes = &model.elements[e].nodes;
        let r = &self.frames[e].r;
        match input {
            Input::Vector(p) => to_local(wide, r, &gather(nodes, p)),
            Input::Displacement { x, moved } => {
                let mut g = gather(nodes, x);
                if let Some((s, v)) = moved {
                    let w = gather(nodes, v);
                    for (gi, wi) in g.iter_mut().zip(w) {
                        *gi = (-s).mul_add(wi, *gi);
                    }
                }
                let rest = gather(nodes, &model.rest);
                let mut u = to_local(wide, r, &g);
                for (ui, ri) in u.iter_mut().zip(rest) {
                    *ui -= ri;
                }
                u
            }
        }
    }

    /// `slots[i] = scale · R Kₑ local(e)` for elements `e = first + i` (one or two). Neighbours
    /// with the same stiffness (every full cell of a material) are multiplied as a pair, loading
    /// the matrix once; the result does not depend on the pairing.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn products_from(
        &self,
        wide: Wide,
        model: &HexModel,
        scale: f64,
        input: Input,
        first: usize,
        slots: &mut [Local],
    ) {
        let k = &self.stiffness[first];
        if let [a, b] = slots
            && self.walsh[first].is_none()
            && Arc::ptr_eq(k, &self.stiffness[first + 1])
        {
            let (g, h) = product_pair(
                k,
                &self.local(wide, model, first, input),
                &self.local(wide, model, first + 1, input),
            );
            *a = to_global(wide, &self.frames[first].r, scale, &g);
            *b = to_global(wide, &self.frames[first + 1].r, scale, &h);
        } else {
            for (i, slot) in slots.iter_mut().enumerate() {
                let e = first + i;
                let g = self.product(wide, e, &self.local(wide, model, e, input));
                *slot = to_global(wide, &self.frames[e].r, scale, &g);
            }
        }
    }

    /// `Kₑ v` (element frame, component-major): through the Walsh–Hadamard basis for a full cell,
    /// the dense product otherwise.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn product(&self, wide: Wide, e: usize, v: &Local) -> Local {
        match &self.walsh[e] {
            Some(walsh) => walsh.apply(wide, v),
            None => product(&self.stiffness[e], v),
        }
    }

    /// `out += Σₑ scale · R Kₑ local(e)`: the element loop shared by every product.
    fn add_products(&self, model: &HexModel, scale: f64, input: Input, out: &mut [Vec3]) {
        with_scratch(model.elements.len(), |per_element| {
            self.exec.update_runs(per_element, |start, run| {
                vectorized(
                    #[inline(always)]
                    |wide| {
                        for (k, slots) in run.chunks_mut(2).enumerate() {
                            self.products_from(wide, model, scale, input, start + 2 * k, slots);
                        }
                    },
                );
            });
            for (el, g) in model.elements.iter().zip(per_element.iter()) {
                scatter_add(&el.nodes, g, out);
            }
        });
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
        vectorized(
            #[inline(always)]
            |wide| {
                let mut slots = [[0.0; 24]; 2];
                for first in elements.clone().step_by(2) {
                    let len = (elements.end - first).min(2);
                    self.products_from(
                        wide,
                        model,
                        scale,
                        Input::Vector(p),
                        first,
                        &mut slots[..len],
                    );
                    for (i, g) in slots[..len].iter().enumerate() {
                        scatter_add(&model.elements[first + i].nodes, g, out);
                    }
                }
            },
        );
    }

    /// For the elements in `elements`, in element order: `forces += −R K (Rᵀ(x − s·v) − x₀)`
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
        vectorized(
            #[inline(always)]
            |wide| {
                for e in elements {
                    let u =
                        self.local(wide, model, e, Input::Displacement { x, moved: Some((s, v)) });
                    let q = self.local(wide, model, e, Input::Vector(p));
                    let (g, k) = match &self.walsh[e] {
                        Some(walsh) => (walsh.apply(wide, &u), walsh.apply(wide, &q)),
                        None => product_pair(&self.stiffness[e], &u, &q),
                    };
                    let (nodes, r) = (&model.elements[e].nodes, &self.frames[e].r);
                    scatter_add(nodes, &to_global(wide, r, -1.0, &g), forces);
                    scatter_add(nodes, &to_global(wide, r, b, &k), products);
                }
            },
        );
    }

    /// `f += elastic forces at positions x` (call [`HexForceField::update_rotations`] first).
    pub fn add_forces(&self, model: &HexModel, x: &[Vec3], f: &mut [Vec3]) {
        self.add_products(model, -1.0, Input::Displacement { x, moved: None }, f);
    }

    /// `out += scale · K(x) p`, with `K` the (rotated) stiffness, element by element.
    pub fn add_stiffness_times(&self, model: &HexModel, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.add_products(model, scale, Input::Vector(p), out);
    }

    /// `out += f(x) + scale · K(x) p` in one element loop (the right-hand side of an implicit
    /// step): `−R K (Rᵀ(x − scale · p) − x₀)` per element.
    pub fn add_forces_and_stiffness_times(
        &self,
        model: &HexModel,
        x: &[Vec3],
        scale: f64,
        p: &[Vec3],
        out: &mut [Vec3],
    ) {
        self.add_products(model, -1.0, Input::Displacement { x, moved: Some((scale, p)) }, out);
    }

    /// The 3×3 diagonal blocks of the (rotated) stiffness, per node: `R K_cc Rᵀ` summed (in
    /// element order).
    #[must_use]
    pub fn diagonal_blocks(&self, model: &HexModel) -> Vec<Mat3> {
        let mut out = Vec::new();
        self.diagonal_blocks_into(model, &mut out, &mut Vec::new());
        out
    }

    /// [`HexForceField::diagonal_blocks`] into `out`, with `scratch` for the second half's sums:
    /// buffers kept between calls (fresh ones cost page faults on every rebuild).
    pub(crate) fn diagonal_blocks_into(
        &self,
        model: &HexModel,
        out: &mut Vec<Mat3>,
        scratch: &mut Vec<Mat3>,
    ) {
        let rotated = self.formulation == Formulation::Corotational;
        let n = model.node_count();
        // Two fixed halves of the elements, each summed into its own blocks in element order,
        // then added: the same bits on one thread or two.
        let half = |elements: std::ops::Range<usize>, out: &mut [Mat3]| {
            for e in elements {
                let el = &model.elements[e];
                for (c, &node) in el.nodes.iter().enumerate() {
                    let k: Mat3 = std::array::from_fn(|i| {
                        std::array::from_fn(|j| el.stiffness.get(3 * c + i, 3 * c + j))
                    });
                    let k = if rotated { rotate_symmetric(&self.frames[e].r, &k) } else { k };
                    let d = &mut out[node as usize];
                    for i in 0..3 {
                        for j in 0..3 {
                            d[i][j] += k[i][j];
                        }
                    }
                }
            }
        };
        let count = model.elements.len();
        for buffer in [&mut *out, &mut *scratch] {
            buffer.clear();
            buffer.resize(n, [[0.0; 3]; 3]);
        }
        self.exec.join_if(
            count >= crate::exec::PARALLEL_MIN,
            || half(0..count / 2, out),
            || half(count / 2..count, scratch),
        );
        self.exec.update_elements(out, |node, d| {
            let s = &scratch[node];
            for i in 0..3 {
                for j in 0..3 {
                    d[i][j] += s[i][j];
                }
            }
        });
    }

    /// Elastic energy `½ Σₑ uₑᵀ Kₑ uₑ` (J), with `u` in each element's rotated frame.
    #[must_use]
    pub fn energy(&self, model: &HexModel, x: &[Vec3]) -> f64 {
        let per_element = self.exec.map_elements(model.elements.len(), |e| {
            vectorized(
                #[inline(always)]
                |wide| {
                    let u = self.local(wide, model, e, Input::Displacement { x, moved: None });
                    let g = self.product(wide, e, &u);
                    0.5 * u.iter().zip(g.iter()).map(|(a, b)| a * b).sum::<f64>()
                },
            )
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
    static SCRATCH: std::cell::RefCell<Vec<Local>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` on a buffer of `n` per-element corner vectors borrowed from this thread's scratch.
fn with_scratch<R>(n: usize, f: impl FnOnce(&mut [Local]) -> R) -> R {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut buf) => {
            buf.resize(n, [0.0; 24]);
            f(&mut buf[..n])
        }
        // Re-entered (a callback inside an element loop): a one-off buffer.
        Err(_) => f(&mut vec![[0.0; 24]; n]),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use incise_grid::procedural::{TISSUE, TUMOUR, ellipsoid_with_inclusion};
    use incise_grid::{BranchedGrid, Material, MaterialTable};

    /// Level 2 of an ellipsoid with a stiffer inclusion: full, partly filled and superimposed
    /// cells.
    fn ellipsoid_grid() -> BranchedGrid {
        let mut table = MaterialTable::new();
        table.insert(TISSUE, Material::new(3e3, 0.45, 1000.0));
        table.insert(TUMOUR, Material::new(3e4, 0.45, 1000.0));
        BranchedGrid::build(&ellipsoid_with_inclusion(20, 2e-3), &table, 2).unwrap()
    }

    fn ellipsoid_model() -> HexModel {
        HexModel::from_grid(&ellipsoid_grid())
    }

    #[test]
    fn a_cut_field_equals_a_new_one_and_reuses_what_the_cut_left_alone() {
        let mut grid = ellipsoid_grid();
        let model = HexModel::from_grid(&grid);
        let ff = HexForceField::new(&model, Formulation::Corotational);
        let dims = grid.fine().dims();
        // A slab of voxels through the middle: re-condenses the cells it crosses, splits some.
        let x = dims[0] / 2;
        let remove: Vec<u32> = (0..dims[2])
            .flat_map(|z| (0..dims[1]).map(move |y| (x, y, z)))
            .map(|(x, y, z)| x + dims[0] * (y + dims[1] * z))
            .collect();
        let changes = grid
            .apply(&incise_grid::GridEdit { remove_voxels: remove, sever_links: vec![] })
            .unwrap();
        let cut = model.updated(&grid, &changes);
        let remapped = ff.remapped(&model, &cut, |_| None);
        let fresh = HexForceField::new(&cut, Formulation::Corotational);
        let bits = |k: &Mat24| k.0.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let (mut reused, mut made) = (0, 0);
        for (i, el) in cut.elements.iter().enumerate() {
            assert_eq!(bits(&remapped.stiffness[i]), bits(&fresh.stiffness[i]), "element {i}");
            assert_eq!(
                remapped.walsh[i].is_some(),
                fresh.walsh[i].is_some(),
                "element {i}: Walsh form"
            );
            let old = model.elements.iter().position(|o| Arc::ptr_eq(&o.stiffness, &el.stiffness));
            match old {
                Some(j) => {
                    assert!(Arc::ptr_eq(&remapped.stiffness[i], &ff.stiffness[j]), "element {i}");
                    if let (Some(a), Some(b)) = (&remapped.walsh[i], &ff.walsh[j]) {
                        assert!(Arc::ptr_eq(a, b), "element {i}: Walsh form not reused");
                    }
                    reused += 1;
                }
                None => made += 1,
            }
        }
        assert!(reused > 0 && made > 0, "{reused} reused, {made} permuted again");
    }

    #[test]
    fn a_partly_filled_cell_turns_about_its_material() {
        let model = ellipsoid_model();
        let ff = HexForceField::new(&model, Formulation::Corotational);
        let partial = ff.off_centre.iter().filter(|g| g.is_some()).count();
        assert!(partial > 0 && partial < model.elements.len(), "{partial} off-centre elements");
        // The gradients still reproduce a linear field exactly: Σ_c x_c ⊗ ∇N_c = F for x = F X.
        let f = [[1.1, 0.2, -0.1], [0.05, 0.9, 0.3], [-0.2, 0.1, 1.2]];
        let s = model.element_size;
        for g in ff.off_centre.iter().flatten() {
            let mut got = [[0.0; 3]; 3];
            for (c, gc) in g.iter().enumerate() {
                let b = corner(c);
                let p: Vec3 = std::array::from_fn(|a| if b[a] == 1 { s[a] } else { 0.0 });
                for r in 0..3 {
                    let x = (0..3).map(|k| f[r][k] * p[k]).sum::<f64>();
                    for k in 0..3 {
                        got[r][k] += x * gc[k];
                    }
                }
            }
            for r in 0..3 {
                for k in 0..3 {
                    assert!((got[r][k] - f[r][k]).abs() < 1e-12, "{got:?} against {f:?}");
                }
            }
        }
    }

    #[test]
    fn lanes_and_one_by_one_give_the_same_rotations() {
        let model = ellipsoid_model();
        let mut ff = HexForceField::new(&model, Formulation::Corotational);
        // A bend and a twist, so that every element turns by its own amount.
        let x: Vec<Vec3> = model
            .rest
            .iter()
            .map(|p| {
                let t = 8.0 * p[2];
                let (sin, cos) = t.sin_cos();
                [cos * p[0] - sin * p[1], sin * p[0] + cos * p[1] + 0.3 * p[0] * p[0], p[2]]
            })
            .collect();
        ff.update_rotations(&model, &x);
        let centre = ff.centre_gradient;
        for (e, element) in model.elements.iter().enumerate() {
            let grad = ff.off_centre[e].as_deref().unwrap_or(&centre);
            let mut f = [[0.0; 3]; 3];
            for (c, &n) in element.nodes.iter().enumerate() {
                for r in 0..3 {
                    for k in 0..3 {
                        f[r][k] += x[n as usize][r] * grad[c][k];
                    }
                }
            }
            let mut q = Quat::IDENTITY;
            let r = nearest(&f, &mut q, ROTATION_ITERATIONS).matrix;
            assert_eq!(
                ff.rotation(e).map(|row| row.map(f64::to_bits)),
                r.map(|row| row.map(f64::to_bits)),
                "element {e}"
            );
        }
    }
}
