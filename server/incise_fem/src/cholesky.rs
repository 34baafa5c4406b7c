//! Sparse Cholesky factorisation (faer) of the implicit system `a·M + b·K`, on the free degrees
//! of freedom, used as a direct solver or as the preconditioner of CG.
//!
//! The sparsity pattern (lower triangle, scalar CSC) and the symbolic factorisation are built once
//! per topology; each refresh only scatters the element blocks `R K Rᵀ` through a precomputed map
//! and runs the numeric factorisation.

use crate::constraints::FixedNodes;
use crate::hex_force::HexForceField;
use crate::model::HexModel;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{MatMut, Side};
use incise_math::Vec3;
use incise_math::mat3::{mul, transpose};

const NONE: u32 = u32::MAX;

/// A factorisable `a·M + b·K` on the free nodes of one model.
pub struct SystemFactor {
    /// Free-node index of each node (`NONE` when fixed).
    free: Vec<u32>,
    dofs: usize,
    symbolic_matrix: SymbolicSparseColMat<u32>,
    symbolic: SymbolicLlt<u32>,
    /// Per element, per (row dof, col dof) of its 24×24 block: position in the values, or `NONE`.
    entry: Vec<u32>,
    /// Position of each free dof's diagonal entry.
    diagonal: Vec<u32>,
    values: Vec<f64>,
    factor: Option<Llt<u32, f64>>,
}

/// Why a factorisation failed.
#[derive(Debug, thiserror::Error)]
#[error("sparse Cholesky failed: {0}")]
pub struct FactorError(String);

impl SystemFactor {
    /// The pattern and symbolic factorisation for `model` with `fixed` nodes removed.
    ///
    /// # Panics
    /// Never for a consistent model (every element entry is in the pattern built from it).
    pub fn new(model: &HexModel, fixed: &FixedNodes) -> Result<Self, FactorError> {
        let n = model.node_count();
        let mut free = vec![NONE; n];
        let mut count = 0u32;
        for (i, f) in free.iter_mut().enumerate() {
            if !fixed.is_fixed(i) {
                *f = count;
                count += 1;
            }
        }
        let dofs = 3 * count as usize;
        // Node adjacency through elements, then the scalar lower-triangle pattern per column.
        let mut adjacent: Vec<Vec<u32>> = vec![Vec::new(); count as usize];
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
        let symbolic = SymbolicLlt::try_new(symbolic_matrix.as_ref(), Side::Lower)
            .map_err(|e| FactorError(format!("{e:?}")))?;
        Ok(Self {
            free,
            dofs,
            symbolic_matrix,
            symbolic,
            entry,
            diagonal,
            values: vec![0.0; nnz],
            factor: None,
        })
    }

    /// Factorises `a·M + b·K(R)` with the lumped mass and the force field's current rotations.
    pub fn factorize(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        a: f64,
        b: f64,
    ) -> Result<(), FactorError> {
        self.values.fill(0.0);
        for (n, &f) in self.free.iter().enumerate() {
            if f != NONE {
                for p in 0..3 {
                    self.values[self.diagonal[3 * f as usize + p] as usize] +=
                        a * model.lumped_mass[n];
                }
            }
        }
        for (ei, e) in model.elements.iter().enumerate() {
            let r = ff.rotation(ei);
            let rt = transpose(r);
            let map = &self.entry[ei * 576..(ei + 1) * 576];
            for ci in 0..8 {
                for cj in 0..8 {
                    let k: [[f64; 3]; 3] = std::array::from_fn(|p| {
                        std::array::from_fn(|q| e.stiffness.get(3 * ci + p, 3 * cj + q))
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
        // A view over the stored pattern and values: nothing is copied per refresh.
        let matrix = SparseColMatRef::new(self.symbolic_matrix.as_ref(), &self.values);
        let llt = Llt::try_new_with_symbolic(self.symbolic.clone(), matrix, Side::Lower)
            .map_err(|e| FactorError(format!("{e:?}")))?;
        self.factor = Some(llt);
        Ok(())
    }

    /// `z = (a·M + b·K)⁻¹ r` on the free nodes (fixed nodes get 0). Requires a factorisation.
    ///
    /// # Panics
    /// If [`SystemFactor::factorize`] has not succeeded yet.
    pub fn solve(&self, r: &[Vec3], z: &mut [Vec3]) {
        let llt = self.factor.as_ref().expect("factorize before solve");
        let mut rhs = vec![0.0; self.dofs];
        for (n, &f) in self.free.iter().enumerate() {
            if f != NONE {
                rhs[3 * f as usize..3 * f as usize + 3].copy_from_slice(&r[n]);
            }
        }
        llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut rhs, self.dofs, 1));
        for (n, &f) in self.free.iter().enumerate() {
            z[n] = if f == NONE {
                [0.0; 3]
            } else {
                [rhs[3 * f as usize], rhs[3 * f as usize + 1], rhs[3 * f as usize + 2]]
            };
        }
    }

    /// Non-zeros of the lower triangle.
    #[must_use]
    pub fn nonzeros(&self) -> usize {
        self.values.len()
    }
}
