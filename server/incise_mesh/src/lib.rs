//! Tetrahedral meshes, as geometry: the checked mesh ([`TetMesh`]: every tetrahedron positively
//! oriented, non-degenerate, in range, its faces shared by at most two), its topology
//! ([`TetTopology`]: vertices, edges, triangles, tetrahedra, neighbours, and the boundary surface
//! kept current as tetrahedra are removed, Picinbono 2001 §3.2), and meshes generated from a label
//! volume at any grid level or as paper 2's cylinder ([`generate`]).
//!
//! No mechanics here: the tensor-mass force field of `incise_fem` is built on these meshes, and
//! the readers of `incise_io` produce them, so file formats need not depend on mechanics.
//!
//! - `mesh`: [`TetMesh`], [`TetMeshError`], [`signed_volume`]
//! - `topology`: [`TetTopology`], the face and edge tables
//! - [`generate`]: lattices split into six tetrahedra per cell (Kuhn), and the cylinder

pub mod generate;
mod mesh;
pub mod topology;

pub use mesh::{TetMesh, TetMeshError, signed_volume};
pub use topology::TetTopology;
