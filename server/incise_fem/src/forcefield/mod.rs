//! Force fields: what computes internal forces and their Jacobian. [`hex`] holds the linear and
//! corotational hexahedra of the branched grid, [`tet`] paper 2's tensor-mass tetrahedra.

pub mod hex;
pub mod tet;
