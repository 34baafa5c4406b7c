//! The surface embedded in the deformable elements (paper 1, §3 and Fig. 9): each vertex follows
//! the top-level element that owns its owner voxel, by the trilinear weights of its rest position
//! in that element's cell. The same weights map vertex forces (collision response) back to the
//! nodes as the transpose, so the virtual work of the two agrees exactly.
//!
//! A vertex whose weights fall slightly outside `[0, 1]` (smoothed, or on a voxel face at the
//! cell's border) is extrapolated from its element, which is what keeps it on the element's side
//! of a cut: the element, not the nearest cell, decides.

use crate::extract::{Surface, SurfaceVertex};
use crate::remesh::SurfaceChanges;
use incise_grid::{BranchedGrid, GridChanges, hex8};
use incise_math::Vec3;

/// How one vertex follows the nodes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Embedding {
    /// Node indices in the caller's numbering (unused slots repeat a used node with weight 0).
    pub nodes: [u32; 8],
    /// Weights, summing to 1 for a live vertex.
    pub weights: [f64; 8],
}

/// Every vertex slot's embedding.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceMapping {
    embeddings: Vec<Embedding>,
    /// The top-level grid node ids behind each embedding's `nodes`, so that the caller's indices
    /// can be looked up again when its numbering moves.
    grid_nodes: Vec<[u32; 8]>,
    live: Vec<bool>,
    /// The top-level cell each live vertex's element fills (`u32::MAX`: none), and the live
    /// vertices of each cell, sorted: a cut finds the vertices of the elements it changed from
    /// their cells instead of walking the elements' voxels (512 per element at level 3, each a
    /// look-up in the surface's vertex map). A vertex's voxel, so its cell, never changes.
    cell: Vec<u32>,
    cell_vertices: Vec<Vec<u32>>,
}

/// The top-level elements whose vertices need new embeddings after `changes`, sorted: those
/// added (split pieces, which take over vertices of the element they split from) and those with a
/// corner node that changed. An element that only lost voxels or neighbours keeps its cell and its
/// nodes, and a removal never moves a voxel to another surviving element, so the vertices it
/// still owns keep their weights and nodes (re-embedding them was most of a small cut's mapping
/// update).
#[must_use]
pub fn changed_elements(changes: &GridChanges) -> Vec<u32> {
    let top = &changes.top;
    let mut out: Vec<u32> = top
        .elements_added
        .iter()
        .map(|&(id, _)| id)
        .chain(top.elements_renoded.iter().copied())
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

impl SurfaceMapping {
    /// Embeds every live vertex of `surface` in `grid`'s top level. `node_index` turns a
    /// top-level grid node id into the caller's node index (the simulation numbers its nodes
    /// differently).
    ///
    /// # Panics
    /// If a live vertex's owner voxel is empty in `grid` (the surface was not re-meshed after an
    /// edit).
    #[must_use]
    pub fn embed(surface: &Surface, grid: &BranchedGrid, node_index: &dyn Fn(u32) -> u32) -> Self {
        let vertices = surface.vertices();
        let n = vertices.len();
        let mut m = Self {
            embeddings: with_room_of(n, Embedding::default()),
            grid_nodes: with_room_of(n, [0; 8]),
            live: with_room_of(n, false),
            cell: with_room_of(n, u32::MAX),
            cell_vertices: vec![Vec::new(); cell_count(grid)],
        };
        for (live, v) in m.live.iter_mut().zip(vertices) {
            *live = v.alive;
        }
        for (i, v) in vertices.iter().enumerate() {
            if v.alive {
                let cell;
                (m.embeddings[i], m.grid_nodes[i], cell) = embed_vertex(v, grid, node_index);
                m.cell[i] = cell;
                // Slots in id order: each list comes out sorted.
                m.cell_vertices[cell as usize].push(i as u32);
            }
        }
        m
    }

    /// A mapping where vertex `i` is node `i` (surfaces whose vertices are the mesh's own, as for
    /// the tensor-mass family's [`crate::TetSurface`]).
    #[must_use]
    pub fn identity(vertex_count: usize) -> Self {
        let embeddings = (0..vertex_count as u32)
            .map(|i| {
                let mut weights = [0.0; 8];
                weights[0] = 1.0;
                Embedding { nodes: [i; 8], weights }
            })
            .collect();
        Self {
            embeddings,
            grid_nodes: (0..vertex_count as u32).map(|i| [i; 8]).collect(),
            live: vec![true; vertex_count],
            cell: vec![u32::MAX; vertex_count],
            cell_vertices: Vec::new(),
        }
    }

    /// After a grid change: re-embeds only the vertices whose owner voxel is now in an element
    /// listed in `changed_elements` (added, changed and shrunk elements; see
    /// [`changed_elements`]), and the vertices added by the surface change; frees the slots of
    /// removed vertices. Returns how many were re-embedded.
    ///
    /// The other vertices keep their weights and grid nodes, but their node indices are looked up
    /// again through `node_index`: a cut may renumber nodes it did not touch (a model that numbers
    /// its live nodes compactly shifts every node after one that was added or removed).
    ///
    /// # Panics
    /// As [`SurfaceMapping::embed`].
    pub fn update(
        &mut self,
        surface: &Surface,
        grid: &BranchedGrid,
        changed_elements: &[u32],
        surface_changes: &SurfaceChanges,
        node_index: &dyn Fn(u32) -> u32,
    ) -> usize {
        self.update_with(surface, grid, changed_elements, surface_changes, Some(node_index))
    }

    /// [`SurfaceMapping::update`] for a mapping whose node indices are the top-level grid node
    /// ids themselves (embedded with `&|g| g`): a grid node keeps its id across a cut, so the
    /// vertices that are not re-embedded are not visited at all.
    ///
    /// # Panics
    /// As [`SurfaceMapping::embed`].
    pub fn update_by_grid_node(
        &mut self,
        surface: &Surface,
        grid: &BranchedGrid,
        changed_elements: &[u32],
        surface_changes: &SurfaceChanges,
    ) -> usize {
        self.update_with(surface, grid, changed_elements, surface_changes, None)
    }

    /// [`SurfaceMapping::update`]; `node_index` `None` for grid node ids.
    fn update_with(
        &mut self,
        surface: &Surface,
        grid: &BranchedGrid,
        changed_elements: &[u32],
        surface_changes: &SurfaceChanges,
        node_index: Option<&dyn Fn(u32) -> u32>,
    ) -> usize {
        let vertices = surface.vertices();
        self.embeddings.resize(vertices.len(), Embedding::default());
        self.grid_nodes.resize(vertices.len(), [0; 8]);
        self.live.resize(vertices.len(), false);
        self.cell.resize(vertices.len(), u32::MAX);
        if self.cell_vertices.len() != cell_count(grid) {
            self.index_cells(surface, grid);
        }
        for &v in &surface_changes.vertices_removed {
            self.embeddings[v as usize] = Embedding::default();
            self.live[v as usize] = false;
            self.leave_cell(v);
        }
        if let Some(node_index) = node_index {
            for (e, (g, &live)) in
                self.embeddings.iter_mut().zip(self.grid_nodes.iter().zip(&self.live))
            {
                if live {
                    e.nodes = g.map(node_index);
                }
            }
        }
        let sorted;
        let changed_elements = if changed_elements.is_sorted() {
            changed_elements
        } else {
            sorted = {
                let mut c = changed_elements.to_vec();
                c.sort_unstable();
                c
            };
            &sorted
        };
        let mut todo: Vec<u32> = surface_changes.vertices_added.clone();
        let top = grid.top();
        let mut cells: Vec<u32> =
            changed_elements.iter().filter_map(|&e| top.element(e)).map(|e| e.cell).collect();
        cells.sort_unstable();
        cells.dedup();
        for cell in cells {
            let in_cell = &self.cell_vertices[cell as usize];
            if let [only] = top.cell_elements(cell) {
                // Every voxel of the cell holding material is the one element's.
                if changed_elements.binary_search(only).is_ok() {
                    todo.extend_from_slice(in_cell);
                }
            } else {
                todo.extend(in_cell.iter().copied().filter(|&v| {
                    grid.voxel_element(vertices[v as usize].voxel)
                        .is_some_and(|e| changed_elements.binary_search(&e).is_ok())
                }));
            }
        }
        todo.sort_unstable();
        todo.dedup();
        todo.retain(|&v| vertices[v as usize].alive);
        let identity = |g: u32| g;
        let node_index = node_index.unwrap_or(&identity);
        for &v in &todo {
            let i = v as usize;
            let cell;
            (self.embeddings[i], self.grid_nodes[i], cell) =
                embed_vertex(&vertices[i], grid, node_index);
            self.live[i] = true;
            if self.cell[i] != cell {
                self.leave_cell(v);
                self.cell[i] = cell;
                let list = &mut self.cell_vertices[cell as usize];
                let at = list.partition_point(|&w| w < v);
                list.insert(at, v);
            }
        }
        todo.len()
    }

    /// Files every live vertex under its cell (a mapping made by [`SurfaceMapping::identity`],
    /// or one from another grid, has no cells yet).
    fn index_cells(&mut self, surface: &Surface, grid: &BranchedGrid) {
        self.cell_vertices = vec![Vec::new(); cell_count(grid)];
        self.cell.fill(u32::MAX);
        for (i, v) in surface.vertices().iter().enumerate() {
            if self.live[i]
                && let Some(e) = grid.voxel_element(v.voxel).and_then(|e| grid.top().element(e))
            {
                self.cell[i] = e.cell;
                self.cell_vertices[e.cell as usize].push(i as u32);
            }
        }
    }

    /// Takes vertex `v` off its cell's list.
    fn leave_cell(&mut self, v: u32) {
        let cell = std::mem::replace(&mut self.cell[v as usize], u32::MAX);
        if let Some(list) = self.cell_vertices.get_mut(cell as usize)
            && let Ok(at) = list.binary_search(&v)
        {
            list.remove(at);
        }
    }

    /// The embedding of vertex slot `vertex`.
    #[must_use]
    pub fn embedding(&self, vertex: u32) -> &Embedding {
        &self.embeddings[vertex as usize]
    }

    /// Number of vertex slots.
    #[must_use]
    pub fn len(&self) -> usize {
        self.embeddings.len()
    }

    /// True when there are no vertex slots.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.embeddings.is_empty()
    }

    /// Deformed positions of every vertex slot from node positions `x` (free slots get zero).
    pub fn deformed(&self, x: &[Vec3], out: &mut Vec<Vec3>) {
        out.clear();
        out.extend(self.embeddings.iter().zip(&self.live).map(|(e, &live)| {
            let mut p = [0.0; 3];
            if live {
                for (&n, &w) in e.nodes.iter().zip(&e.weights) {
                    let q = x[n as usize];
                    for a in 0..3 {
                        p[a] += w * q[a];
                    }
                }
            }
            p
        }));
    }

    /// The transpose of [`SurfaceMapping::deformed`]: adds each `(vertex, force)` to the nodes
    /// with the vertex's weights.
    pub fn add_forces(&self, vertex_forces: &[(u32, Vec3)], node_forces: &mut [Vec3]) {
        for &(v, f) in vertex_forces {
            let e = &self.embeddings[v as usize];
            for (&n, &w) in e.nodes.iter().zip(&e.weights) {
                let out = &mut node_forces[n as usize];
                for a in 0..3 {
                    out[a] += w * f[a];
                }
            }
        }
    }
}

/// `n` copies of `fill`, with room for a few cuts' new vertices (growing a full vector would
/// copy every slot on one cut).
fn with_room_of<T: Clone>(n: usize, fill: T) -> Vec<T> {
    let mut v = Vec::with_capacity(n + n / 8 + 64);
    v.resize(n, fill);
    v
}

/// Cells of `grid`'s top level.
fn cell_count(grid: &BranchedGrid) -> usize {
    grid.top().cell_dims().iter().map(|&d| d as usize).product()
}

/// The embedding of one live vertex, with the grid node ids behind it and its element's cell.
fn embed_vertex(
    v: &SurfaceVertex,
    grid: &BranchedGrid,
    node_index: &dyn Fn(u32) -> u32,
) -> (Embedding, [u32; 8], u32) {
    let id = grid
        .voxel_element(v.voxel)
        .unwrap_or_else(|| panic!("voxel {} owns a surface vertex but is empty", v.voxel));
    let top = grid.top();
    let e = top.element(id).expect("the owner of a voxel is a live element");
    let cell = top.cell_coords(e.cell);
    let size = grid.element_size();
    let xi: Vec3 = std::array::from_fn(|a| v.rest[a] / size[a] - f64::from(cell[a]));
    let embedding = Embedding {
        nodes: e.nodes.map(node_index),
        weights: std::array::from_fn(|n| hex8::shape(n, xi)),
    };
    (embedding, e.nodes, e.cell)
}
