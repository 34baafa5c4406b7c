//! The organ's surface, for rendering and collision: a polygonal level set of the fine voxels
//! embedded in the deformable elements, re-meshed locally as the organ is cut (Jeřábková 2010,
//! paper 1, §3 "Surface Model and Cutting", Fig. 8 and 9).
//!
//! - `contour`: the surface inside one marching cube whose corners are
//!   voxel centres, from the corners' inside flags and the severed state of its edges alone, so
//!   that neighbouring cubes agree (crack-free), severed links open the surface, and the inside is
//!   6-connected like the grid's voxels. Vertices sit at voxel face centres, no interpolation.
//! - `extract`: [`Surface`], its vertices and triangles in slot vectors with free lists, named by
//!   [`VertexKey`]s and cube indices (cube index = voxel index, Fig. 8), one closed surface per
//!   label group ([`SurfaceOptions`]).
//! - `remesh`: [`Surface::remesh`], the local update after voxels are removed or links severed,
//!   reporting [`SurfaceChanges`].
//! - `smooth`: [`Surface::smoothed_rest`], Taubin smoothing that keeps the embedding valid.
//! - `mapping`: [`SurfaceMapping`], each vertex's trilinear [`Embedding`] in the top-level element
//!   that owns its voxel, the deformed positions and the transposed force mapping; re-embedding
//!   after a grid change touches only what changed.
//! - `tet`: [`TetSurface`], the same interface over the boundary of a tetrahedral mesh (the
//!   tensor-mass family), mapped by [`SurfaceMapping::identity`].
//!
//! Everything is deterministic: ids are handed out in cube order, lowest free slot first.

mod contour;
mod extract;
mod mapping;
mod remesh;
mod smooth;
mod tet;

pub use extract::{
    CanonicalTriangle, CubeTriangles, Surface, SurfaceOptions, SurfaceVertex, Triangle, VertexKey,
};
pub use mapping::{Embedding, SurfaceMapping, changed_elements};
pub use remesh::SurfaceChanges;
pub use tet::TetSurface;
