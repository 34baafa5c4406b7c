//! Hexahedral force fields on the branched grid: [`HexForceField`] (linear or corotational, each
//! element with its own condensed stiffness), the complete corotational tangent for Newton
//! ([`tangent`]), and the element passes' kernels (component-major element vectors, AVX2 chosen
//! at run time) and Walsh–Hadamard products of full cells.

mod elasticity;
mod hexahedron_fem;
pub(crate) mod kernel;
pub mod tangent;
pub(crate) mod walsh;

pub use elasticity::HexElasticity;
pub use hexahedron_fem::{Formulation, HexForceField};
pub use tangent::RotationTangent;
