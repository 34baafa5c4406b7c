//! The tensor-mass tetrahedral family (Picinbono, Delingette & Ayache 2001, "paper 2"):
//! tetrahedral meshes and their topology, the conventional element-by-element St Venant-Kirchhoff
//! model that serves as the reference, and the tensor-mass storage of the same model on vertices,
//! edges, triangles and tetrahedra (eq. 7–10), from which a tetrahedron is removed by subtracting
//! exactly what it added.

pub mod element;
pub mod explicit;
pub mod generate;
pub mod incompressible;
pub mod mesh;
pub mod relax;
pub mod tensor_mass;
pub mod topology;

pub use element::{Elasticity, Lame, TetMaterial, TetModel};
pub use mesh::{TetMesh, TetMeshError};
pub use tensor_mass::TensorMassForceField;
pub use topology::TetTopology;
