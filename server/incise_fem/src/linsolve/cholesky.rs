//! Sparse Cholesky factorisation (faer) of the implicit system `a·M + b·K`, on the free degrees
//! of freedom, used as a direct solver or as the preconditioner of CG.
//!
//! The sparsity pattern (lower triangle, scalar CSC) and the symbolic factorisation are built once
//! per topology, in a geometric nested-dissection order of the nodes (`linsolve::ordering`); each
//! refresh only scatters the element blocks `R K Rᵀ` through a precomputed map and runs the
//! numeric factorisation.
//!
//! As a CG preconditioner the factor may be kept in `f32` ([`Precision::Single`]): the triangular
//! solves read every entry of the factor once per CG iteration and are bound by memory, so half the
//! bytes is nearly half the time. CG itself, its residual and its stopping test stay in `f64`, so
//! the solution meets the same tolerance; only the preconditioner is less exact.

use crate::constraint::FixedNodes;
use crate::forcefield::hex::HexForceField;
use crate::forcefield::hex::tangent::RotationTangent;
use crate::linsolve::supernodal::{Scalar, Supernodes};
use crate::model::HexModel;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side, Spec};
use incise_math::Vec3;
use incise_math::mat3::{mul, transpose};

const NONE: u32 = u32::MAX;

/// The floating-point type the factor is stored and applied in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Precision {
    /// `f64`: an exact direct solve.
    Double,
    /// `f32`: a preconditioner only (about 1e-7 relative rounding per entry).
    Single,
}

/// The numeric factor in one of the two precisions.
enum Factor {
    None,
    Double(Vec<f64>),
    Single(Vec<f32>),
}

/// A factorisable `a·M + b·K` on the free nodes of one model.
pub struct SystemFactor {
    /// Position of each node in the elimination order (`NONE` when fixed).
    free: Vec<u32>,
    dofs: usize,
    precision: Precision,
    symbolic_matrix: SymbolicSparseColMat<u32>,
    symbolic: SymbolicCholesky<u32>,
    /// Per element, per (row dof, col dof) of its 24×24 block: position in the values, or `NONE`.
    entry: Vec<u32>,
    /// Position of each free dof's diagonal entry.
    diagonal: Vec<u32>,
    values: Vec<f64>,
    factor: Factor,
    /// The supernode layout for our own substitutions (`None` for a simplicial factor).
    supernodes: Option<Supernodes>,
    /// The threads the substitutions' two halves run on.
    exec: crate::exec::Executor,
}

/// Why a factorisation failed.
#[derive(Debug, thiserror::Error)]
#[error("sparse Cholesky failed: {0}")]
pub struct FactorError(String);

impl SystemFactor {
    /// The pattern and symbolic factorisation for `model` with `fixed` nodes removed, in `f64`.
    ///
    /// # Errors
    /// If faer cannot build the symbolic factorisation (out of memory).
    pub fn new(model: &HexModel, fixed: &FixedNodes) -> Result<Self, FactorError> {
        Self::with_precision(model, fixed, Precision::Double)
    }

    /// The pattern and symbolic factorisation, with the factor kept in `precision`.
    ///
    /// # Errors
    /// If faer cannot build the symbolic factorisation (out of memory).
    ///
    /// # Panics
    /// Never for a consistent model (every element entry is in the pattern built from it).
    pub fn with_precision(
        model: &HexModel,
        fixed: &FixedNodes,
        precision: Precision,
    ) -> Result<Self, FactorError> {
        let n = model.node_count();
        let mut free_nodes = Vec::new();
        for i in 0..n {
            if !fixed.is_fixed(i) {
                free_nodes.push(i);
            }
        }
        let mut local = vec![NONE; n];
        for (k, &i) in free_nodes.iter().enumerate() {
            local[i] = k as u32;
        }
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); free_nodes.len()];
        for e in &model.elements {
            for &a in &e.nodes {
                for &b in &e.nodes {
                    let (la, lb) = (local[a as usize], local[b as usize]);
                    if la != NONE && lb != NONE && la != lb {
                        neighbours[la as usize].push(lb);
                    }
                }
            }
        }
        let positions: Vec<Vec3> = free_nodes.iter().map(|&i| model.rest[i]).collect();
        let dissection = crate::linsolve::ordering::nested_dissection(&positions, &neighbours);
        let mut free = vec![NONE; n];
        for (k, &l) in dissection.order.iter().enumerate() {
            free[free_nodes[l as usize]] = k as u32;
        }
        let count = free_nodes.len();
        let dofs = 3 * count;
        // Node adjacency through elements, then the scalar lower-triangle pattern per column.
        let mut adjacent: Vec<Vec<u32>> = vec![Vec::new(); count];
        for e in &model.elements {
            for &a in &e.nodes {
                for &b in &e.nodes {
                    let (fa, fb) = (free[a as usize], free[b as usize]);
                    if fa != NONE && fb != NONE && fa >= fb {
                        adjacent[fb as usize].push(fa);
                    }
                }
            }
        }
        let mut col_ptr: Vec<u32> = Vec::with_capacity(dofs + 1);
        let mut row_idx: Vec<u32> = Vec::new();
        col_ptr.push(0);
        for (col_node, rows) in adjacent.iter_mut().enumerate() {
            rows.sort_unstable();
            rows.dedup();
            for q in 0..3u32 {
                let col = 3 * col_node as u32 + q;
                for &r in rows.iter() {
                    for p in 0..3u32 {
                        let row = 3 * r + p;
                        if row >= col {
                            row_idx.push(row);
                        }
                    }
                }
                col_ptr.push(row_idx.len() as u32);
            }
        }
        let position = |row: u32, col: u32| -> u32 {
            let (lo, hi) = (col_ptr[col as usize] as usize, col_ptr[col as usize + 1] as usize);
            lo as u32 + row_idx[lo..hi].binary_search(&row).expect("entry in pattern") as u32
        };
        let mut entry = Vec::with_capacity(model.elements.len() * 576);
        for e in &model.elements {
            for ci in 0..8 {
                for p in 0..3u32 {
                    for cj in 0..8 {
                        for q in 0..3u32 {
                            let (fi, fj) = (free[e.nodes[ci] as usize], free[e.nodes[cj] as usize]);
                            let pos = if fi == NONE || fj == NONE {
                                NONE
                            } else {
                                let (row, col) = (3 * fi + p, 3 * fj + q);
                                if row >= col { position(row, col) } else { NONE }
                            };
                            entry.push(pos);
                        }
                    }
                }
            }
        }
        let diagonal = (0..dofs as u32).map(|d| position(d, d)).collect();
        let nnz = row_idx.len();
        let symbolic_matrix = SymbolicSparseColMat::new_checked(dofs, dofs, col_ptr, None, row_idx);
        // The dofs are numbered in elimination order already; faer's `Identity` ordering would
        // skip its conversion of the lower-triangle input, so the identity is passed as a
        // custom permutation.
        let identity: Vec<u32> = (0..dofs as u32).collect();
        let perm = faer::perm::PermRef::new_checked(&identity, &identity, dofs);
        let symbolic = factorize_symbolic_cholesky(
            symbolic_matrix.as_ref(),
            Side::Lower,
            SymmetricOrdering::Custom(perm),
            faer::sparse::linalg::cholesky::CholeskySymbolicParams::default(),
        )
        .map_err(|e| FactorError(format!("{e:?}")))?;
        let supernodes = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => {
                Some(Supernodes::new(s, dissection.halves.map(|h| h.map(|n| 3 * n))))
            }
            SymbolicCholeskyRaw::Simplicial(_) => None,
        };
        Ok(Self {
            supernodes,
            free,
            dofs,
            precision,
            symbolic_matrix,
            symbolic,
            entry,
            diagonal,
            values: vec![0.0; nnz],
            factor: Factor::None,
            exec: crate::exec::Executor::default(),
        })
    }

    /// The same factor running its substitutions on `exec` (the simulation's executor).
    #[must_use]
    pub fn with_executor(mut self, exec: crate::exec::Executor) -> Self {
        self.exec = exec;
        self
    }

    /// Factorises `a·M + b·K(R)` with the lumped mass and the force field's current rotations.
    ///
    /// # Errors
    /// If the matrix is not numerically positive definite in this precision.
    pub fn factorize(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        a: f64,
        b: f64,
    ) -> Result<(), FactorError> {
        self.factorize_with(model, ff, a, b, false)
    }

    /// [`SystemFactor::factorize`] with the condensed consistent mass when `consistent`.
    ///
    /// # Errors
    /// If the matrix is not numerically positive definite in this precision.
    pub fn factorize_with(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        a: f64,
        b: f64,
        consistent: bool,
    ) -> Result<(), FactorError> {
        self.assemble_and_factorize(model, ff, a, b, consistent, None)
    }

    /// The factor of `K + sym(T)`, `T` the rotation-derivative part of the corotational
    /// Jacobian at the rotations of `ff` ([`RotationTangent`]): a preconditioner for static
    /// Newton's nonsymmetric systems close enough that Bi-CGSTAB needs a few products.
    ///
    /// # Errors
    /// If that matrix is not numerically positive definite (far from equilibrium the rotation
    /// term can make it indefinite; factor `K` alone then).
    pub fn factorize_tangent(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        tangent: &RotationTangent,
    ) -> Result<(), FactorError> {
        self.assemble_and_factorize(model, ff, 0.0, 1.0, false, Some(tangent))
    }

    fn assemble_and_factorize(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        a: f64,
        b: f64,
        consistent: bool,
        tangent: Option<&RotationTangent>,
    ) -> Result<(), FactorError> {
        self.values.fill(0.0);
        if !consistent {
            for (n, &f) in self.free.iter().enumerate() {
                if f != NONE {
                    for p in 0..3 {
                        self.values[self.diagonal[3 * f as usize + p] as usize] +=
                            a * model.lumped_mass[n];
                    }
                }
            }
        }
        for (ei, e) in model.elements.iter().enumerate() {
            let r = ff.rotation(ei);
            let rt = transpose(r);
            let map = &self.entry[ei * 576..(ei + 1) * 576];
            if consistent {
                for ci in 0..8 {
                    for cj in 0..8 {
                        let m = a * e.mass[8 * ci + cj];
                        for p in 0..3 {
                            let pos = map[(3 * ci + p) * 24 + 3 * cj + p];
                            if pos != NONE {
                                self.values[pos as usize] += m;
                            }
                        }
                    }
                }
            }
            let extra = tangent.and_then(|t| t.symmetric_block(ff, ei));
            for ci in 0..8 {
                for cj in 0..8 {
                    let k: [[f64; 3]; 3] = std::array::from_fn(|p| {
                        std::array::from_fn(|q| {
                            let (i, j) = (3 * ci + p, 3 * cj + q);
                            e.stiffness.get(i, j) + extra.as_ref().map_or(0.0, |x| x[i][j])
                        })
                    });
                    let rk = mul(&mul(r, &k), &rt);
                    for p in 0..3 {
                        for q in 0..3 {
                            let pos = map[(3 * ci + p) * 24 + 3 * cj + q];
                            if pos != NONE {
                                self.values[pos as usize] += b * rk[p][q];
                            }
                        }
                    }
                }
            }
        }
        self.factor = match self.precision {
            Precision::Double => Factor::Double(self.factorize_values(&self.values)?),
            Precision::Single => Factor::Single(
                self.factorize_values(&self.values.iter().map(|&v| v as f32).collect::<Vec<_>>())?,
            ),
        };
        Ok(())
    }

    /// The numeric factor of the assembled `values` (in the symbolic pattern).
    fn factorize_values<T: faer::traits::RealField + Copy>(
        &self,
        values: &[T],
    ) -> Result<Vec<T>, FactorError> {
        let matrix = SparseColMatRef::new(self.symbolic_matrix.as_ref(), values);
        let mut l_values = vec![T::from_f64_impl(0.0); self.symbolic.len_val()];
        let mut buffer = MemBuffer::new(
            self.symbolic.factorize_numeric_llt_scratch::<T>(Par::Seq, Spec::default()),
        );
        self.symbolic
            .factorize_numeric_llt(
                &mut l_values,
                matrix,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut buffer),
                Spec::default(),
            )
            .map_err(|e| FactorError(format!("{e:?}")))?;
        Ok(l_values)
    }

    /// `z = (a·M + b·K)⁻¹ r` on the free nodes (fixed nodes get 0), through the factor in its
    /// precision.
    ///
    /// # Panics
    /// If [`SystemFactor::factorize`] has not succeeded yet.
    pub fn solve(&self, r: &[Vec3], z: &mut [Vec3]) {
        match &self.factor {
            Factor::None => panic!("factorize before solve"),
            Factor::Double(l) => self.solve_in(l, r, z, |v| v, |v| v),
            Factor::Single(l) => self.solve_in(l, r, z, |v| v as f32, f64::from),
        }
    }

    fn solve_in<T: faer::traits::RealField + Scalar>(
        &self,
        l_values: &[T],
        r: &[Vec3],
        z: &mut [Vec3],
        narrow: impl Fn(f64) -> T,
        widen: impl Fn(T) -> f64,
    ) {
        let mut rhs = vec![narrow(0.0); self.dofs];
        for (n, &f) in self.free.iter().enumerate() {
            if f != NONE {
                for p in 0..3 {
                    rhs[3 * f as usize + p] = narrow(r[n][p]);
                }
            }
        }
        if let Some(supernodes) = &self.supernodes {
            supernodes.solve(&self.exec, l_values, &mut rhs);
        } else {
            let mut buffer = MemBuffer::new(self.symbolic.solve_in_place_scratch::<T>(1, Par::Seq));
            LltRef::new(&self.symbolic, l_values).solve_in_place_with_conj(
                Conj::No,
                MatMut::from_column_major_slice_mut(&mut rhs, self.dofs, 1),
                Par::Seq,
                MemStack::new(&mut buffer),
            );
        }
        for (n, &f) in self.free.iter().enumerate() {
            z[n] = if f == NONE {
                [0.0; 3]
            } else {
                let at = 3 * f as usize;
                [widen(rhs[at]), widen(rhs[at + 1]), widen(rhs[at + 2])]
            };
        }
    }

    /// Whether this factor was built for exactly these fixed nodes (same node count, same set).
    #[must_use]
    pub fn serves(&self, fixed: &FixedNodes) -> bool {
        self.free.len() == fixed.node_count()
            && self.free.iter().enumerate().all(|(n, &f)| (f == NONE) == fixed.is_fixed(n))
    }

    /// Changes the precision of the next factorisation.
    pub fn set_precision(&mut self, precision: Precision) {
        self.precision = precision;
        self.factor = Factor::None;
    }

    /// Multiply-adds of one numeric factorisation (0 for a simplicial factor, which faer only
    /// picks when it is cheap).
    #[must_use]
    pub fn factor_work(&self) -> f64 {
        self.supernodes.as_ref().map_or(0.0, Supernodes::factor_work)
    }

    /// Whether the substitutions run the top dissection's two halves apart (on two threads when
    /// the factor is big).
    #[must_use]
    pub fn runs_in_halves(&self) -> bool {
        self.supernodes.as_ref().is_some_and(Supernodes::has_halves)
    }

    /// Entries of the lower triangle of the factor.
    #[must_use]
    pub fn factor_entries(&self) -> usize {
        self.symbolic.len_val()
    }

    /// Non-zeros of the lower triangle.
    #[must_use]
    pub fn nonzeros(&self) -> usize {
        self.values.len()
    }
}
