//! The surface of the tensor-mass family: the boundary faces of a tetrahedral mesh, whose vertices
//! are the mesh's own (so [`crate::SurfaceMapping::identity`] maps it). After tetrahedra are
//! removed, [`TetSurface::refresh`] compares the topology's boundary with the triangles it holds
//! and reports the difference in the same [`SurfaceChanges`] as the voxel surface.

use crate::extract::Triangle;
use crate::remesh::SurfaceChanges;
use incise_mesh::TetTopology;
use incise_mesh::topology::FACES;
use std::collections::{BTreeMap, BTreeSet};

/// Boundary triangles of a [`TetTopology`] in slots with a free list.
#[derive(Clone, Debug)]
pub struct TetSurface {
    vertex_count: usize,
    triangles: Vec<Triangle>,
    free: BTreeSet<u32>,
    live: usize,
    /// Slot of each boundary triangle, by the topology's triangle id.
    by_face: BTreeMap<u32, u32>,
}

/// The boundary of `topology` by triangle id, each oriented outwards from its live tetrahedron.
fn boundary_faces(topology: &TetTopology) -> BTreeMap<u32, [u32; 3]> {
    let mut out = BTreeMap::new();
    for (t, v) in topology.tets().iter().enumerate() {
        if !topology.is_alive(t) {
            continue;
        }
        for (f, face) in FACES.iter().enumerate() {
            let id = topology.tet_triangles(t)[f];
            if topology.triangle_degree(id as usize) == 1 {
                out.insert(id, face.map(|i| v[i]));
            }
        }
    }
    out
}

impl TetSurface {
    /// The boundary surface of `topology`'s live tetrahedra.
    #[must_use]
    pub fn new(topology: &TetTopology) -> Self {
        let mut s = Self {
            vertex_count: topology.vertex_count(),
            triangles: Vec::new(),
            free: BTreeSet::new(),
            live: 0,
            by_face: BTreeMap::new(),
        };
        s.refresh(topology);
        s
    }

    /// Brings the triangles up to date after tetrahedra were removed from `topology`: faces that
    /// left the boundary are freed, faces that joined it (or turned to face the other way) are
    /// added. The vertex lists stay empty: the vertices are the mesh's and never change.
    pub fn refresh(&mut self, topology: &TetTopology) -> SurfaceChanges {
        let now = boundary_faces(topology);
        let mut changes = SurfaceChanges::default();
        let gone: Vec<(u32, u32)> = self
            .by_face
            .iter()
            .filter(|&(face, &slot)| now.get(face) != Some(&self.triangles[slot as usize].v))
            .map(|(&face, &slot)| (face, slot))
            .collect();
        for (face, slot) in gone {
            self.by_face.remove(&face);
            self.triangles[slot as usize].alive = false;
            self.live -= 1;
            changes.triangles_removed.push(slot);
        }
        for (&face, &v) in &now {
            if self.by_face.contains_key(&face) {
                continue;
            }
            let tri = Triangle { v, cube: face, group: 0, alive: true };
            let slot = if let Some(s) = self.free.pop_first() {
                self.triangles[s as usize] = tri;
                s
            } else {
                self.triangles.push(tri);
                (self.triangles.len() - 1) as u32
            };
            self.by_face.insert(face, slot);
            self.live += 1;
            changes.triangles_added.push(slot);
        }
        self.free.extend(changes.triangles_removed.iter().copied());
        changes.triangles_removed.sort_unstable();
        changes.triangles_added.sort_unstable();
        changes
    }

    /// Vertices (the mesh's, all of them).
    #[must_use]
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// Live triangles.
    #[must_use]
    pub fn triangle_count(&self) -> usize {
        self.live
    }

    /// Triangle slots (free ones have `alive == false`; `cube` holds the topology's triangle id).
    #[must_use]
    pub fn triangles(&self) -> &[Triangle] {
        &self.triangles
    }

    /// Live triangles with their ids, in id order.
    pub fn live_triangles(&self) -> impl Iterator<Item = (u32, &Triangle)> {
        self.triangles.iter().enumerate().filter(|(_, t)| t.alive).map(|(i, t)| (i as u32, t))
    }

    /// The vertex ids of the live triangles, in id order.
    #[must_use]
    pub fn triangle_list(&self) -> Vec<[u32; 3]> {
        self.live_triangles().map(|(_, t)| t.v).collect()
    }
}
