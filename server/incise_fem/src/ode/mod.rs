//! Integrators: how the state moves from one step to the next.
//!
//! - [`BackwardEuler`]: linearised implicit Euler, one linear solve per step;
//! - [`explicit_step`]: symplectic Euler for hexahedra, stable below [`stable_dt`];
//! - [`CentralDifference`]: paper 2's explicit scheme for tensor-mass tetrahedra;
//! - [`static_solve`]: Newton to static equilibrium (the references);
//! - [`relax`]: dynamic relaxation of tetrahedra to equilibrium.

mod backward_euler;
pub mod central_difference;
mod explicit;
mod rayleigh;
pub mod relax;
pub(crate) mod static_newton;
pub(crate) mod warm_start;

pub use crate::linsolve::implicit::REFRESH_COST;
pub use backward_euler::{BackwardEuler, LinearSolver, MassMatrix, StageTimes};
pub use central_difference::{CentralDifference, StepTooLarge};
pub use explicit::{explicit_step, explicit_step_fields, stable_dt};
pub use rayleigh::Rayleigh;
pub use static_newton::{StaticReport, static_solve, static_solve_multigrid, static_solve_with};
