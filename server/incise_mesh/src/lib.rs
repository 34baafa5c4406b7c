//! Meshes, as geometry. Tetrahedral meshes: the checked mesh ([`TetMesh`]: every tetrahedron
//! positively oriented, non-degenerate, in range, its faces shared by at most two), its topology
//! ([`TetTopology`]: vertices, edges, triangles, tetrahedra, neighbours, and the boundary surface
//! kept current as tetrahedra are removed, Picinbono 2001 §3.2), and meshes generated from a label
//! volume at any grid level or as paper 2's cylinder ([`generate`]). Closed triangle meshes too
//! ([`TriMesh`]): the surfaces that give a surgical tool its shape, checked to bound a solid
//! (every edge in exactly two triangles, wound consistently) and oriented with normals outwards.
//!
//! No mechanics here: the tensor-mass force field of `incise_fem` is built on these meshes, and
//! the readers of `incise_io` produce them, so file formats need not depend on mechanics.
//!
//! - `mesh`: [`TetMesh`], [`TetMeshError`], [`signed_volume`]
//! - `topology`: [`TetTopology`], the face and edge tables
//! - [`generate`]: lattices split into six tetrahedra per cell (Kuhn), and the cylinder
//! - `tri_mesh`: [`TriMesh`], [`TriMeshError`]

pub mod generate;
mod mesh;
pub mod topology;
mod tri_mesh;

pub use mesh::{TetMesh, TetMeshError, signed_volume};
pub use topology::TetTopology;
pub use tri_mesh::{TriMesh, TriMeshError};
