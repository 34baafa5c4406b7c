//! The organ's surface as the tools see it: the marching-cubes surface of the fine voxels
//! embedded in the hexahedra, or the boundary of the tensor-mass tetrahedra.
//!
//! The voxel surface's embeddings name grid nodes, not model nodes: a cut renumbers the model's
//! nodes (they are numbered in grid-node order, compactly), while a surviving grid node keeps
//! its id, so only the vertices of elements the cut changed need embedding again. Positions are
//! scattered to grid-node order once per frame to evaluate them.

use incise_fem::HexModel;
use incise_fem::forcefield::springs::EmbeddedPoint;
use incise_grid::{BranchedGrid, GridChanges};
use incise_math::Vec3;
use incise_mesh::TetTopology;
use incise_surface::{Surface, SurfaceChanges, SurfaceMapping, SurfaceOptions, TetSurface};

/// The surface of a scene's organ.
pub enum OrganSurface {
    /// Marching cubes on the grid's fine voxels, embedded in its top-level elements.
    Voxels {
        /// The triangles and vertices.
        surface: Box<Surface>,
        /// Each vertex's embedding, by grid node id.
        mapping: SurfaceMapping,
        /// Model node index of each grid node id (`u32::MAX`: no such node).
        model_of_grid: Vec<u32>,
        /// The live vertices, sorted.
        live: Vec<u32>,
    },
    /// The boundary of the live tetrahedra; its vertices are the mesh's.
    Tetrahedra {
        /// The boundary triangles.
        surface: TetSurface,
        /// The vertices on the boundary, sorted.
        boundary: Vec<u32>,
    },
}

impl OrganSurface {
    /// The voxel surface of `grid` (whose model is `model`), its rest positions smoothed by
    /// `smoothing` Taubin steps.
    #[must_use]
    pub fn voxels(
        grid: &BranchedGrid,
        model: &HexModel,
        options: &SurfaceOptions,
        smoothing: u32,
    ) -> Self {
        let mut surface = Surface::extract(grid.fine(), grid.spacing(), options);
        if smoothing > 0 {
            let rest = surface.smoothed_rest(smoothing as usize, 0.5);
            surface.set_rest(&rest);
        }
        let mapping = SurfaceMapping::embed(&surface, grid, &|g| g);
        let live = live_of(&surface);
        let surface = Box::new(surface);
        Self::Voxels { surface, mapping, model_of_grid: model_of_grid(grid, model), live }
    }

    /// The boundary surface of `topology`.
    #[must_use]
    pub fn tetrahedra(topology: &TetTopology) -> Self {
        let surface = TetSurface::new(topology);
        let boundary = boundary_vertices(&surface);
        Self::Tetrahedra { surface, boundary }
    }

    /// Live triangles.
    #[must_use]
    pub fn triangle_count(&self) -> usize {
        match self {
            Self::Voxels { surface, .. } => surface.triangle_count(),
            Self::Tetrahedra { surface, .. } => surface.triangle_count(),
        }
    }

    /// The live triangles as vertex triples (vertex ids index [`Self::deform`]'s output).
    #[must_use]
    pub fn triangle_list(&self) -> Vec<[u32; 3]> {
        match self {
            Self::Voxels { surface, .. } => surface.triangle_list(),
            Self::Tetrahedra { surface, .. } => surface.triangle_list(),
        }
    }

    /// The live vertices, in id order.
    #[must_use]
    pub fn live_vertices(&self) -> &[u32] {
        match self {
            Self::Voxels { live, .. } => live,
            Self::Tetrahedra { boundary, .. } => boundary,
        }
    }

    /// Whether vertex `v` exists.
    #[must_use]
    pub fn is_live(&self, v: u32) -> bool {
        self.live_vertices().binary_search(&v).is_ok()
    }

    /// The deformed position of every vertex slot for node positions `x` (model order); dead
    /// slots hold anything.
    ///
    /// # Panics
    /// On a voxel surface without the hexahedral `model` it belongs to.
    pub fn deform(&self, x: &[Vec3], model: Option<&HexModel>, out: &mut Vec<Vec3>) {
        match self {
            Self::Voxels { mapping, model_of_grid, .. } => {
                let model = model.expect("a voxel surface belongs to a hexahedral model");
                // Scattered to grid-node order, where the embeddings point.
                let mut scattered = vec![[0.0; 3]; model_of_grid.len()];
                for (p, &g) in x.iter().zip(&model.grid_node) {
                    scattered[g as usize] = *p;
                }
                mapping.deformed(&scattered, out);
            }
            Self::Tetrahedra { .. } => {
                out.clear();
                out.extend_from_slice(x);
            }
        }
    }

    /// Vertex `v`'s embedding in model node indices.
    #[must_use]
    pub fn embedding(&self, v: u32) -> EmbeddedPoint {
        match self {
            Self::Voxels { mapping, model_of_grid, .. } => {
                let e = mapping.embedding(v);
                let mut point = EmbeddedPoint { nodes: [0; 8], weights: [0.0; 8] };
                for k in 0..8 {
                    if e.weights[k] != 0.0 {
                        point.nodes[k] = model_of_grid[e.nodes[k] as usize];
                        point.weights[k] = e.weights[k];
                    }
                }
                point
            }
            Self::Tetrahedra { .. } => EmbeddedPoint::node(v),
        }
    }

    /// The voxel that owns vertex `v` (`None` on a tetrahedral surface).
    #[must_use]
    pub fn owner_voxel(&self, v: u32) -> Option<u32> {
        match self {
            Self::Voxels { surface, .. } => surface.vertices().get(v as usize).map(|x| x.voxel),
            Self::Tetrahedra { .. } => None,
        }
    }

    /// Brings the voxel surface up to date after a grid edit that touched `voxels` (removed
    /// voxels, and both ends of severed links) and changed the grid by `changes`; `model` is the
    /// model of the edited grid.
    pub fn after_grid_edit(
        &mut self,
        grid: &BranchedGrid,
        model: &HexModel,
        voxels: &[u32],
        changes: &GridChanges,
    ) -> SurfaceChanges {
        match self {
            Self::Voxels { surface, mapping, model_of_grid: map, live } => {
                let surface_changes = surface.remesh(grid.fine(), voxels);
                let changed = incise_surface::changed_elements(changes);
                mapping.update(surface, grid, &changed, &surface_changes, &|g| g);
                *map = model_of_grid(grid, model);
                *live = live_of(surface);
                surface_changes
            }
            Self::Tetrahedra { .. } => SurfaceChanges::default(),
        }
    }

    /// Brings the tetrahedral surface up to date after tetrahedra were removed.
    pub fn after_tet_removal(&mut self, topology: &TetTopology) -> SurfaceChanges {
        match self {
            Self::Tetrahedra { surface, boundary } => {
                let changes = surface.refresh(topology);
                *boundary = boundary_vertices(surface);
                changes
            }
            Self::Voxels { .. } => SurfaceChanges::default(),
        }
    }
}

/// The live vertices of `surface`, sorted.
fn live_of(surface: &Surface) -> Vec<u32> {
    surface.vertices().iter().enumerate().filter(|(_, v)| v.alive).map(|(i, _)| i as u32).collect()
}

/// Model index of each grid node id.
fn model_of_grid(grid: &BranchedGrid, model: &HexModel) -> Vec<u32> {
    let mut map = vec![u32::MAX; grid.top().node_capacity()];
    for (i, &g) in model.grid_node.iter().enumerate() {
        map[g as usize] = i as u32;
    }
    map
}

/// The vertices of a tetrahedral surface's live triangles, sorted.
fn boundary_vertices(surface: &TetSurface) -> Vec<u32> {
    let mut v: Vec<u32> = surface.live_triangles().flat_map(|(_, t)| t.v).collect();
    v.sort_unstable();
    v.dedup();
    v
}
