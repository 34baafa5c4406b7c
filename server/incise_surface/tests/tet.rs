//! The tensor-mass family's surface: the boundary of a tetrahedral mesh, refreshed as tetrahedra
//! are cut out, stays the topology's boundary and a closed manifold.

mod common;

use common::{H, Rng};
use incise_grid::procedural::sphere;
use incise_mesh::TetTopology;
use incise_mesh::generate::{cylinder, from_volume};
use incise_mesh::topology::{check_closed, check_manifold};
use incise_surface::{SurfaceMapping, TetSurface};

/// Triangles rotated so the smallest vertex comes first (orientation kept), sorted.
fn canonical(tris: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut out: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            let f = (0..3).min_by_key(|&i| t[i]).unwrap();
            std::array::from_fn(|i| t[(f + i) % 3])
        })
        .collect();
    out.sort_unstable();
    out
}

#[test]
fn the_boundary_follows_cuts_and_stays_a_closed_manifold() {
    for mesh in [cylinder(1e-2, 3e-2, 6, 4), from_volume(&sphere(10, H), 1).unwrap()] {
        let mut topo = TetTopology::new(&mesh);
        let mut s = TetSurface::new(&topo);
        assert_eq!(s.vertex_count(), mesh.vertices().len());
        assert_eq!(canonical(&s.triangle_list()), canonical(&topo.boundary()));
        let mut rng = Rng::new(5);
        for _ in 0..12 {
            let t = rng.below(topo.tets().len() as u32) as usize;
            let before = s.triangle_count();
            topo.cut(t);
            let changes = s.refresh(&topo);
            let tris = s.triangle_list();
            assert_eq!(canonical(&tris), canonical(&topo.boundary()));
            assert_eq!(
                s.triangle_count(),
                before + changes.triangles_added.len() - changes.triangles_removed.len()
            );
            assert!(changes.vertices_added.is_empty() && changes.vertices_removed.is_empty());
            if topo.live_count() > 0 {
                check_closed(&tris).unwrap();
                check_manifold(&tris).unwrap();
            }
        }
        // Refreshing without a change changes nothing.
        assert!(s.refresh(&topo).is_empty());
        // The mesh's vertices are the nodes: the identity mapping carries them.
        let m = SurfaceMapping::identity(s.vertex_count());
        let mut out = Vec::new();
        m.deformed(mesh.vertices(), &mut out);
        assert_eq!(out, mesh.vertices());
    }
}
