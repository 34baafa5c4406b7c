//! Mechanics on the Dynamic Branched Grid (Jeřábková 2010, §2; Nesme 2006 for non-uniform
//! elements) and on tensor-mass tetrahedra (Picinbono 2001), laid out by concern in the
//! vocabulary of SOFA:
//!
//! - [`model`]: the hexahedral model of a grid's top level (topology, condensed matrices, lumped
//!   and consistent masses), external loads and the mechanical state;
//! - [`constraint`]: fixed nodes, applied by projection;
//! - [`forcefield`]: the force fields: linear and corotational hexahedra ([`forcefield::hex`],
//!   with the rotation's derivative for Newton, the element kernels and the Walsh–Hadamard
//!   products) and paper 2's tensor-mass tetrahedra ([`forcefield::tet`]);
//! - [`ode`]: the integrators: linearised backward Euler, explicit symplectic Euler and central
//!   differences, static Newton, dynamic relaxation, the stable step, the implicit step's warm
//!   start;
//! - [`linsolve`]: the linear solvers: CG, the two-thread lockstep CG, Bi-CGSTAB, block Jacobi,
//!   sparse Cholesky (nested-dissection order, supernodal substitutions);
//! - [`exec`]: the executor every loop runs on (threads, spinning or sleeping workers).
//!
//! Tetrahedral meshes and their topology are geometry and live in `incise_mesh`.
//!
//! All physics is `f64` and deterministic: element loops may run on two threads, but every
//! element writes its own contribution and the sums over elements run in element order, so results
//! are bit-identical whatever the thread count.

pub mod constraint;
pub mod exec;
pub mod forcefield;
pub mod linsolve;
pub mod model;
pub mod ode;

pub use constraint::FixedNodes;
pub use exec::{Executor, Idle};
pub use forcefield::hex::{Formulation, HexForceField};
pub use model::{ElementKind, HexModel, Loads, State};
