//! Mechanics on the Dynamic Branched Grid (Jeřábková 2010, §2; Nesme 2006 for non-uniform
//! elements): corotational and linear hexahedral force fields using each element's condensed
//! stiffness, lumped masses, fixed nodes by projection, a block-sparse system matrix, a
//! preconditioned conjugate-gradient solver, and the static, linearised backward-Euler and explicit
//! integrators.
//!
//! All physics is `f64` and deterministic: element loops may run on two threads, but every
//! element writes its own contribution and the sums over elements run in element order, so results
//! are bit-identical whatever the thread count.

pub mod bicgstab;
pub mod cg;
pub mod cholesky;
pub mod constraints;
pub mod hex_force;
pub mod integrate;
mod kernel;
mod lockstep_cg;
pub mod model;
pub mod ordering;
mod parallel;
mod supernodal;
pub mod tangent;
mod team;
pub mod tet;
mod walsh;

pub use constraints::FixedNodes;
pub use hex_force::{Formulation, HexForceField};
pub use model::HexModel;
pub use parallel::set_thread_override;
