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
use incise_tool::proxy::Facet;

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

    /// Every triangle slot, live or free.
    #[must_use]
    pub fn triangle_slots(&self) -> &[incise_surface::Triangle] {
        match self {
            Self::Voxels { surface, .. } => surface.triangles(),
            Self::Tetrahedra { surface, .. } => surface.triangles(),
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
            Self::Voxels { mapping, .. } => {
                // Scattered to grid-node order, where the embeddings point.
                mapping.deformed(&self.stable_nodes(x, model), out);
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

    /// The surface group (tissue group) of vertex `v` (0 on a tetrahedral surface).
    #[must_use]
    pub fn vertex_group(&self, v: u32) -> u16 {
        match self {
            Self::Voxels { surface, .. } => {
                surface.vertices().get(v as usize).map_or(0, |x| x.group)
            }
            Self::Tetrahedra { .. } => 0,
        }
    }

    /// The rest position of every vertex slot: the voxel surface's own, or `mesh_rest` (the
    /// tetrahedral mesh's rest positions) for a tetrahedral surface.
    #[must_use]
    pub fn rest_positions(&self, mesh_rest: &[Vec3]) -> Vec<Vec3> {
        match self {
            Self::Voxels { surface, .. } => surface.rest_positions(),
            Self::Tetrahedra { .. } => mesh_rest.to_vec(),
        }
    }

    /// The live triangles of each surface group (tissue group; one group on a tetrahedral
    /// surface), in slot order.
    #[must_use]
    pub fn triangles_by_group(&self) -> Vec<Vec<[u32; 3]>> {
        let mut groups: Vec<Vec<[u32; 3]>> = Vec::new();
        for t in self.triangle_slots().iter().filter(|t| t.alive) {
            let g = usize::from(t.group);
            if groups.len() <= g {
                groups.resize_with(g + 1, Vec::new);
            }
            groups[g].push(t.v);
        }
        groups
    }

    /// Every triangle slot as a device keeps it: its vertex slots and its group (`None` for a
    /// free slot).
    #[must_use]
    pub fn group_slots(&self) -> Vec<([u32; 3], Option<u16>)> {
        self.triangle_slots().iter().map(|t| (t.v, t.alive.then_some(t.group))).collect()
    }

    /// Every vertex slot's embedding in the numbering a device keeps across cuts (grid node
    /// ids for a voxel surface, whose model numbering a cut changes; mesh vertices for a
    /// tetrahedral one; dead slots weigh nothing), and how many such nodes there are.
    #[must_use]
    pub fn stable_embeddings(&self) -> (Vec<EmbeddedPoint>, usize) {
        match self {
            Self::Voxels { surface, mapping, model_of_grid, .. } => {
                let slots = surface.vertices();
                let points = (0..slots.len())
                    .map(|v| {
                        let mut point = EmbeddedPoint { nodes: [0; 8], weights: [0.0; 8] };
                        if slots[v].alive {
                            let e = mapping.embedding(v as u32);
                            for k in 0..8 {
                                if e.weights[k] != 0.0 {
                                    point.nodes[k] = e.nodes[k];
                                    point.weights[k] = e.weights[k];
                                }
                            }
                        }
                        point
                    })
                    .collect();
                (points, model_of_grid.len())
            }
            Self::Tetrahedra { surface, .. } => {
                let count = surface.vertex_count();
                ((0..count as u32).map(EmbeddedPoint::node).collect(), count)
            }
        }
    }

    /// Node positions `x` (model order) in the numbering of [`Self::stable_embeddings`].
    ///
    /// # Panics
    /// On a voxel surface without the hexahedral `model` it belongs to.
    #[must_use]
    pub fn stable_nodes(&self, x: &[Vec3], model: Option<&HexModel>) -> Vec<Vec3> {
        match self {
            Self::Voxels { model_of_grid, .. } => {
                let model = model.expect("a voxel surface belongs to a hexahedral model");
                let mut scattered = vec![[0.0; 3]; model_of_grid.len()];
                for (p, &g) in x.iter().zip(&model.grid_node) {
                    scattered[g as usize] = *p;
                }
                scattered
            }
            Self::Tetrahedra { .. } => x.to_vec(),
        }
    }

    /// The live triangles that may meet the box `(lo, hi)`, with their corners at `positions`
    /// (deformed, by vertex slot), appended to `out` in triangle-id order.
    ///
    /// A voxel surface finds them from its vertices: those within a few voxels of the box
    /// (three edges of the largest voxel: a triangle spans at most two voxel edges at rest, and
    /// tissue stretched beyond half as much again is torn long before) name their owner voxels,
    /// whose cubes hold every triangle around them. A tetrahedral surface is small enough to be
    /// scanned.
    pub fn facets_near(&self, positions: &[Vec3], (lo, hi): (Vec3, Vec3), out: &mut Vec<Facet>) {
        let start = out.len();
        let meets = |t: &[Vec3; 3]| {
            (0..3).all(|k| {
                let (a, b) = t.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    (a.min(p[k]), b.max(p[k]))
                });
                b >= lo[k] && a <= hi[k]
            })
        };
        let mut push = |id: u32, t: &incise_surface::Triangle| {
            let corners = t.v.map(|v| positions[v as usize]);
            if meets(&corners) {
                out.push(Facet { id, vertices: t.v, corners });
            }
        };
        match self {
            Self::Voxels { surface, live, .. } => {
                let reach = 3.0 * surface.spacing().into_iter().fold(0.0, f64::max);
                let near =
                    |p: &Vec3| (0..3).all(|k| p[k] >= lo[k] - reach && p[k] <= hi[k] + reach);
                let vertices = surface.vertices();
                // Several vertices share an owner voxel, and neighbouring voxels share cubes:
                // the cubes are marked on a map of the box around the owners' (a cube's
                // corners are the voxels `(i..=i+1, …)`), so each is taken once, in the order
                // of its index, and a triangle lies in one cube only.
                let owners: Vec<[i64; 3]> = live
                    .iter()
                    .filter(|&&v| near(&positions[v as usize]))
                    .map(|&v| surface.voxel_coords(vertices[v as usize].voxel))
                    .collect();
                let Some(first) = owners.first() else { return };
                // `Surface::cubes_around`: an owner's cubes lie in `x − 1 ..= x`.
                let (mut from, mut to) = (first.map(|c| c - 1), *first);
                for x in &owners {
                    for k in 0..3 {
                        from[k] = from[k].min(x[k] - 1);
                        to[k] = to[k].max(x[k]);
                    }
                }
                let size: [usize; 3] = std::array::from_fn(|k| (to[k] - from[k] + 1) as usize);
                let at = |c: [i64; 3]| {
                    let o: [usize; 3] = std::array::from_fn(|k| (c[k] - from[k]) as usize);
                    o[0] + size[0] * (o[1] + size[1] * o[2])
                };
                let mut marked = vec![false; size.iter().product()];
                for &x in &owners {
                    for c in Surface::cubes_around(x) {
                        marked[at(c)] = true;
                    }
                }
                let triangles = surface.triangles();
                for (index, _) in marked.iter().enumerate().filter(|(_, m)| **m) {
                    let c = [
                        from[0] + (index % size[0]) as i64,
                        from[1] + (index / size[0] % size[1]) as i64,
                        from[2] + (index / (size[0] * size[1])) as i64,
                    ];
                    for id in surface.cube_triangles(surface.cube_index(c)) {
                        push(id, &triangles[id as usize]);
                    }
                }
                out[start..].sort_unstable_by_key(|f| f.id);
            }
            Self::Tetrahedra { surface, .. } => {
                for (id, t) in surface.live_triangles() {
                    push(id, t);
                }
            }
        }
        debug_assert!(out[start..].windows(2).all(|w| w[0].id < w[1].id));
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
                mapping.update_by_grid_node(surface, grid, &changed, &surface_changes);
                fill_model_of_grid(map, grid, model);
                patch_live(live, &surface_changes);
                debug_assert_eq!(*live, live_of(surface));
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

/// The sorted live vertices `live` after the surface changed by `changes` (both lists sorted),
/// without a pass over every vertex slot (which cost more than the rest of a small cut's
/// re-meshing).
fn patch_live(live: &mut Vec<u32>, changes: &SurfaceChanges) {
    let (removed, added) = (&changes.vertices_removed, &changes.vertices_added);
    if 32 * (removed.len() + added.len()) > live.len() {
        // Many changes (a long stroke in one edit): one merge pass is cheaper than many runs.
        *live = merged(live, removed, added);
    } else {
        patch_runs(live, removed, added);
    }
}

/// `live` without `removed` and with `added` (all sorted), in one pass.
fn merged(live: &[u32], removed: &[u32], added: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(live.len() + added.len());
    let mut gone = removed.iter().peekable();
    let mut new = added.iter().copied().peekable();
    for &v in live {
        while gone.next_if(|&&r| r < v).is_some() {}
        if gone.next_if_eq(&&v).is_none() {
            while let Some(a) = new.next_if(|&a| a < v) {
                out.push(a);
            }
            out.push(v);
        }
    }
    out.extend(new);
    out
}

/// `live` without `removed` and with `added` (all sorted), moving the runs between them whole.
fn patch_runs(live: &mut Vec<u32>, removed: &[u32], added: &[u32]) {
    if let Some(&first) = removed.first() {
        let mut write = live.partition_point(|&v| v < first);
        let mut read = write;
        for &r in removed {
            let at = read + live[read..].partition_point(|&v| v < r);
            live.copy_within(read..at, write);
            write += at - read;
            read = if live.get(at) == Some(&r) { at + 1 } else { at };
        }
        live.copy_within(read.., write);
        write += live.len() - read;
        live.truncate(write);
    }
    // Merged from the back: each old run moves once, to its final place.
    let mut unplaced = live.len();
    live.resize(unplaced + added.len(), 0);
    let mut end = live.len();
    for &a in added.iter().rev() {
        let at = live[..unplaced].partition_point(|&v| v < a);
        let run = unplaced - at;
        live.copy_within(at..unplaced, end - run);
        end -= run + 1;
        live[end] = a;
        unplaced = at;
    }
}

/// Model index of each grid node id.
fn model_of_grid(grid: &BranchedGrid, model: &HexModel) -> Vec<u32> {
    let mut map = Vec::new();
    fill_model_of_grid(&mut map, grid, model);
    map
}

/// [`model_of_grid`] into `map`'s buffer.
fn fill_model_of_grid(map: &mut Vec<u32>, grid: &BranchedGrid, model: &HexModel) {
    map.clear();
    map.resize(grid.top().node_capacity(), u32::MAX);
    for (i, &g) in model.grid_node.iter().enumerate() {
        map[g as usize] = i as u32;
    }
}

/// The vertices of a tetrahedral surface's live triangles, sorted.
fn boundary_vertices(surface: &TetSurface) -> Vec<u32> {
    let mut v: Vec<u32> = surface.live_triangles().flat_map(|(_, t)| t.v).collect();
    v.sort_unstable();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_facets_near_a_box_are_the_live_triangles_meeting_it_in_id_order() {
        let text = "name = \"organ\"\n[volume]\nprocedural = \"organ\"\n\
                    size_m = [0.12, 0.09, 0.08]\nvoxels = [24, 18, 16]\n[[materials]]\n\
                    label = 1\nyoungs_modulus = 3000.0\npoisson_ratio = 0.45\ndensity = 1000.0\n\
                    [[materials]]\nlabel = 2\nyoungs_modulus = 9000.0\npoisson_ratio = 0.45\n\
                    density = 1000.0\n[integrator]\nkind = \"implicit-euler\"\ndt = 0.001\n";
        let config = crate::SceneConfig::from_toml(text, "organ.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        let mut table = incise_grid::MaterialTable::new();
        for m in &config.materials {
            table.insert(m.label, m.material());
        }
        let grid = BranchedGrid::build(&volume, &table, 1).unwrap();
        let model = HexModel::from_grid_of_kind(&grid, incise_fem::ElementKind::Condensed);
        let surface = OrganSurface::voxels(&grid, &model, &SurfaceOptions::default(), 2);
        // Deformed by a smooth field moving points up to a voxel (5 mm voxels here), as tissue
        // under a tool is.
        let positions: Vec<Vec3> = surface
            .rest_positions(&[])
            .iter()
            .map(|p| [p[0] + 0.004 * (80.0 * p[1]).sin(), p[1], p[2] + 0.003 * (60.0 * p[0]).cos()])
            .collect();
        let OrganSurface::Voxels { surface: triangles, .. } = &surface else { unreachable!() };
        let mut boxes = 0;
        for i in 0..40 {
            let c: Vec3 = std::array::from_fn(|k| 0.06 + 0.05 * ((i * 3 + k * 7) as f64).sin());
            let half = 0.0005 + 0.01 * (i % 5) as f64;
            let region = (c.map(|x| x - half), c.map(|x| x + half));
            let mut found = Vec::new();
            surface.facets_near(&positions, region, &mut found);
            let want: Vec<u32> = triangles
                .live_triangles()
                .filter(|(_, t)| {
                    let p = t.v.map(|v| positions[v as usize]);
                    (0..3).all(|k| {
                        p.iter().any(|q| q[k] >= region.0[k])
                            && p.iter().any(|q| q[k] <= region.1[k])
                    })
                })
                .map(|(id, _)| id)
                .collect();
            assert_eq!(found.iter().map(|f| f.id).collect::<Vec<_>>(), want, "box {region:?}");
            boxes += usize::from(!want.is_empty());
        }
        assert!(boxes >= 10, "only {boxes} boxes met the surface");
    }

    #[test]
    fn the_live_list_is_patched_into_a_fresh_one() {
        let changes = |removed: &[u32], added: &[u32]| SurfaceChanges {
            vertices_removed: removed.to_vec(),
            vertices_added: added.to_vec(),
            ..SurfaceChanges::default()
        };
        for (live, c, want) in [
            (vec![1, 3, 5, 7], changes(&[3, 7], &[0, 4, 9]), vec![0, 1, 4, 5, 9]),
            (vec![1, 3, 5, 7], changes(&[], &[]), vec![1, 3, 5, 7]),
            (vec![1, 3, 5, 7], changes(&[1, 3, 5, 7], &[]), vec![]),
            (vec![], changes(&[], &[2, 6]), vec![2, 6]),
            (vec![2, 4, 6], changes(&[4], &[5]), vec![2, 5, 6]),
            (vec![2, 4, 6], changes(&[6], &[7, 8]), vec![2, 4, 7, 8]),
            (vec![2, 4, 6], changes(&[2], &[0, 1, 3]), vec![0, 1, 3, 4, 6]),
            (vec![2, 4, 6], changes(&[2, 6], &[]), vec![4]),
            (vec![2, 4, 6], changes(&[], &[8]), vec![2, 4, 6, 8]),
            ((0..100).collect(), changes(&[0, 50, 99], &[100, 101]), {
                (1..50).chain(51..99).chain(100..102).collect()
            }),
        ] {
            let (removed, added) = (&c.vertices_removed, &c.vertices_added);
            let mut runs = live.clone();
            patch_runs(&mut runs, removed, added);
            assert_eq!(runs, want, "{live:?} with {c:?}");
            assert_eq!(merged(&live, removed, added), want, "{live:?} with {c:?}");
            let mut patched = live.clone();
            patch_live(&mut patched, &c);
            assert_eq!(patched, want, "{live:?} with {c:?}");
        }
    }
}
