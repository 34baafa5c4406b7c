//! Where the work runs: the [`Executor`] a simulation is given (thread count, spinning or
//! sleeping workers, its own pool) and the two-thread team of the lockstep solve.

pub(crate) mod executor;
pub(crate) mod team;

pub(crate) use executor::PARALLEL_MIN;
pub use executor::{Executor, Idle};
