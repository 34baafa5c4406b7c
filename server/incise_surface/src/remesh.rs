//! Local re-meshing after a cut (paper 1, §3): each removed voxel, and each end of a severed link,
//! is a corner of 8 cubes, and only those cubes can change. They are meshed again from the edited
//! fine level; a cube whose triangles come out the same keeps them (ids included), the others
//! drop theirs and add the new ones. Vertices are named by key, so a new triangle reuses the id of
//! any vertex whose key still exists (neighbouring cubes share it), and a vertex no triangle uses
//! any more is freed. Ids freed by a call are not handed out again in the same call, so the
//! removed and added lists of one [`SurfaceChanges`] never share an id.

use crate::extract::{CubeScratch, NO_TRIANGLE, Surface, VertexKey};
use incise_grid::topology::FineLevel;
use std::cmp::Reverse;

/// What one [`Surface::remesh`] changed, as sorted slot ids.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SurfaceChanges {
    /// Triangles freed.
    pub triangles_removed: Vec<u32>,
    /// Triangles created.
    pub triangles_added: Vec<u32>,
    /// Vertices freed (no triangle uses them any more).
    pub vertices_removed: Vec<u32>,
    /// Vertices created (they need an embedding).
    pub vertices_added: Vec<u32>,
}

impl SurfaceChanges {
    /// True when nothing changed.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.triangles_removed.is_empty()
            && self.triangles_added.is_empty()
            && self.vertices_removed.is_empty()
            && self.vertices_added.is_empty()
    }
}

impl Surface {
    /// Re-meshes the cubes having any of `voxels` as a corner (removed voxels, and both ends of
    /// severed links), after the fine level has been edited. Returns what changed.
    ///
    /// # Panics
    /// If `fine` has other dimensions than the level the surface was extracted from, or a voxel
    /// is out of range.
    pub fn remesh(&mut self, fine: &FineLevel, voxels: &[u32]) -> SurfaceChanges {
        assert_eq!(fine.dims(), self.dims(), "the surface belongs to a fine level of these dims");
        let count: u32 = self.dims().iter().product();
        let mut cubes: Vec<u32> = Vec::with_capacity(8 * voxels.len());
        for &v in voxels {
            assert!(v < count, "voxel {v} out of range ({count} voxels)");
            cubes.extend(self.cubes_of_voxel(v));
        }
        cubes.sort_unstable();
        cubes.dedup();

        let mut scratch = CubeScratch::default();
        let mut fresh: Vec<(u32, u16, [VertexKey; 3])> = Vec::new();
        let mut stale: Vec<u32> = Vec::new();
        for &cube in &cubes {
            self.cube_keys(fine, cube, &mut scratch);
            let mut old = self.cube_triangles(cube);
            let same = scratch.out.iter().all(|(group, keys)| {
                old.next().is_some_and(|t| {
                    let tri = &self.triangles[t as usize];
                    tri.group == *group
                        && (0..3).all(|i| self.vertices[tri.v[i] as usize].key() == keys[i])
                })
            }) && old.next().is_none();
            if !same {
                stale.push(cube);
                fresh.extend(scratch.out.iter().map(|&(g, k)| (cube, g, k)));
            }
        }

        let mut changes = SurfaceChanges::default();
        let mut unused: Vec<u32> = Vec::new();
        for cube in stale {
            let mut next = std::mem::replace(&mut self.cube_first[cube as usize], NO_TRIANGLE);
            while next != NO_TRIANGLE {
                let t = next;
                next = self.cube_next[t as usize];
                let tri = &mut self.triangles[t as usize];
                tri.alive = false;
                for &v in &tri.v {
                    self.uses[v as usize] -= 1;
                    if self.uses[v as usize] == 0 {
                        unused.push(v);
                    }
                }
                self.live_triangles -= 1;
                changes.triangles_removed.push(t);
            }
        }
        for (cube, group, keys) in fresh {
            let id = self.add_triangle(cube, group, keys, &mut changes.vertices_added);
            changes.triangles_added.push(id);
        }
        self.free_triangles.extend(changes.triangles_removed.iter().map(|&t| Reverse(t)));
        unused.sort_unstable();
        unused.dedup();
        for v in unused {
            if self.uses[v as usize] == 0 {
                self.unlink_vertex(v);
                self.vertices[v as usize].alive = false;
                self.live_vertices -= 1;
                changes.vertices_removed.push(v);
            }
        }
        self.free_vertices.extend(changes.vertices_removed.iter().map(|&v| Reverse(v)));
        changes.triangles_removed.sort_unstable();
        changes.triangles_added.sort_unstable();
        changes.vertices_added.sort_unstable();
        changes
    }
}
