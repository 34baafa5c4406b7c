//! The tensor-mass tetrahedral family (Picinbono, Delingette & Ayache 2001, "paper 2"): the
//! conventional element-by-element St Venant-Kirchhoff model that serves as the reference
//! ([`element`]), the tensor-mass storage of the same model on vertices, edges, triangles and
//! tetrahedra (eq. 7–10), from which a tetrahedron is removed by subtracting exactly what it added
//! ([`TensorMassForceField`]), and the incompressibility penalty (§4, [`incompressible`]). The meshes
//! themselves are `incise_mesh`'s.

mod elasticity;
pub mod element;
pub mod incompressible;
mod tensor_mass;

pub use elasticity::TetElasticity;
pub use element::{Elasticity, Lame, TetMaterial, TetModel};
pub use incompressible::Incompressibility;
pub use tensor_mass::TensorMassForceField;
