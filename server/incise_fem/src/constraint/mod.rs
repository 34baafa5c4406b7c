//! Constraints: fixed nodes, applied by projecting their entries out of every vector a solver
//! forms.

mod fixed;

pub use fixed::FixedNodes;
