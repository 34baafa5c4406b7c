//! Linear solvers for the systems the integrators form: preconditioned CG ([`cg`]) and its
//! two-thread lockstep form for the implicit step, Bi-CGSTAB for Newton's nonsymmetric tangent,
//! block-Jacobi preconditioning, and sparse Cholesky ([`cholesky`]: faer's numeric factorisation
//! with our nested-dissection order and supernodal substitutions, in `f64`, or in `f32` as a
//! preconditioner).

pub(crate) mod bicgstab;
pub mod cg;
pub mod cholesky;
pub(crate) mod implicit;
pub mod jacobi;
pub(crate) mod lockstep_cg;
pub mod multigrid;
pub(crate) mod ordering;
mod supernodal;

pub use cg::{CgReport, CgSettings};
pub use cholesky::{FactorError, Precision, SystemFactor};
