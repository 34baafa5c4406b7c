//! Local re-meshing (paper 1, §3: "The update of the level set surface is performed locally")
//! equals a full extraction of the edited volume, and the surface stays a closed manifold through
//! voxel removals and severed links; the embedding updated after each edit equals a fresh one.

mod common;

use common::{
    Rng, block, check_surface, cluster, cut, grid_of, matches_full, neighbour, touched, voxel,
};
use incise_grid::GridEdit;
use incise_grid::procedural::sphere;
use incise_surface::{Surface, SurfaceMapping, SurfaceOptions, changed_elements};
use proptest::prelude::*;

fn check_all(s: &Surface, grid: &incise_grid::BranchedGrid, o: &SurfaceOptions) {
    check_surface(s).unwrap();
    matches_full(s, grid, o).unwrap();
}

#[test]
fn extraction_of_a_block_and_a_sphere_is_closed_and_manifold() {
    for (v, level) in [(block([6, 5, 4], None), 1), (sphere(12, common::H), 2)] {
        let grid = grid_of(&v, 1, level);
        let s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
        check_surface(&s).unwrap();
        assert_eq!(s.components(), 1);
        assert!(s.triangle_count() > 50);
    }
}

#[test]
fn removing_voxels_re_meshes_like_a_full_extraction() {
    let o = SurfaceOptions::default();
    for (v, level) in [(block([8, 8, 8], None), 2), (sphere(12, common::H), 1)] {
        let mut grid = grid_of(&v, 1, level);
        let d = grid.fine().dims();
        let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
        // A single voxel at the surface, one inside, a tunnel through, and a blob.
        let centre = voxel(d, d[0] / 2, d[1] / 2, d[2] / 2);
        let edits = [
            vec![voxel(d, d[0] / 2, d[1] / 2, 0)],
            vec![centre],
            (0..d[2]).map(|z| voxel(d, 2, 3, z)).collect(),
            cluster(d, centre + 1, 30, &mut Rng::new(7)),
        ];
        for (i, remove_voxels) in edits.into_iter().enumerate() {
            let edit = GridEdit { remove_voxels, sever_links: vec![] };
            let before = s.triangle_count();
            let changes = cut(&mut grid, &mut s, &edit);
            check_all(&s, &grid, &o);
            assert_eq!(
                s.triangle_count(),
                before + changes.triangles_added.len() - changes.triangles_removed.len()
            );
            if i == 1 {
                assert_eq!(s.components(), 2, "the inner cavity is a surface of its own");
            }
        }
    }
}

#[test]
fn severing_links_re_meshes_like_a_full_extraction() {
    let o = SurfaceOptions::default();
    for (v, level) in [(block([8, 8, 8], None), 1), (sphere(12, common::H), 2)] {
        let mut grid = grid_of(&v, 1, level);
        let d = grid.fine().dims();
        let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
        let before = s.canonical_triangles();
        // One link inside the solid: a zero-volume bubble.
        let a = voxel(d, 4, 4, 4);
        let edit = GridEdit { remove_voxels: vec![], sever_links: vec![(a, a + 1)] };
        let changes = cut(&mut grid, &mut s, &edit);
        check_all(&s, &grid, &o);
        assert!(!changes.triangles_added.is_empty());
        // A crack one link wide from the surface inwards, then a wide one from the other side.
        let strip: Vec<(u32, u32)> =
            (0..5).map(|z| (voxel(d, 2, 3, z), voxel(d, 2, 3, z) + d[0])).collect();
        cut(&mut grid, &mut s, &GridEdit { remove_voxels: vec![], sever_links: strip });
        check_all(&s, &grid, &o);
        let sheet: Vec<(u32, u32)> = (0..d[0])
            .flat_map(|x| (4..d[2]).map(move |z| (x, z)))
            .map(|(x, z)| (voxel(d, x, 5, z), voxel(d, x, 6, z)))
            .collect();
        cut(&mut grid, &mut s, &GridEdit { remove_voxels: vec![], sever_links: sheet });
        check_all(&s, &grid, &o);
        assert_ne!(s.canonical_triangles(), before);
    }
}

#[test]
fn re_meshing_an_unchanged_volume_changes_nothing() {
    let grid = grid_of(&sphere(10, common::H), 1, 1);
    let mut s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
    let all: Vec<u32> = (0..grid.fine().dims().iter().product()).collect();
    let changes = s.remesh(grid.fine(), &all);
    assert!(changes.is_empty(), "{changes:?}");
}

#[test]
fn vertex_ids_of_surviving_keys_are_kept() {
    let mut grid = grid_of(&block([6, 6, 6], None), 1, 1);
    let o = SurfaceOptions::default();
    let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
    let keys: Vec<_> = s.vertices().iter().map(incise_surface::SurfaceVertex::key).collect();
    let d = grid.fine().dims();
    let changes = cut(
        &mut grid,
        &mut s,
        &GridEdit {
            remove_voxels: vec![voxel(d, 2, 2, 5), voxel(d, 3, 2, 5)],
            sever_links: vec![],
        },
    );
    for (id, key) in keys.iter().enumerate() {
        if let Some(now) = s.vertex_id(*key) {
            assert_eq!(now, id as u32, "{key:?} kept its id");
        } else {
            assert!(changes.vertices_removed.contains(&(id as u32)));
        }
    }
    for t in &changes.triangles_added {
        assert!(!changes.triangles_removed.contains(t), "ids are not reused within one call");
    }
}

/// One random edit: a cluster of removed voxels, or links severed from a cluster's voxels.
fn random_edit(d: [u32; 3], sever: bool, centre: u32, size: usize, seed: u64) -> GridEdit {
    let mut rng = Rng::new(seed);
    let voxels = cluster(d, centre, size, &mut rng);
    if !sever {
        return GridEdit { remove_voxels: voxels, sever_links: vec![] };
    }
    let links =
        voxels.iter().filter_map(|&v| neighbour(d, v, 2 * rng.below(3)).map(|n| (v, n))).collect();
    GridEdit { remove_voxels: vec![], sever_links: links }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// Random cut sequences on an 8³ block (one material, or two with a surface each): after
    /// every edit the surface is a closed manifold and equals the full re-extraction, and its
    /// embedding, updated only for the elements `changed_elements` names, equals a fresh one.
    #[test]
    fn random_cuts_keep_a_closed_manifold_equal_to_a_full_extraction(
        level in 1u32..=2,
        two_materials in any::<bool>(),
        edits in prop::collection::vec((any::<bool>(), 0u32..512, 1usize..=30, any::<u64>()), 1..=20),
    ) {
        let (v, labels, o) = if two_materials {
            (block([8; 3], Some(3)), 2, SurfaceOptions::per_material(2))
        } else {
            (block([8; 3], None), 1, SurfaceOptions::default())
        };
        let mut grid = grid_of(&v, labels, level);
        let d = grid.fine().dims();
        let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
        let mut mapping = SurfaceMapping::embed(&s, &grid, &|g| g);
        for (i, &(sever, centre, size, seed)) in edits.iter().enumerate() {
            let edit = random_edit(d, sever, centre, size, seed);
            let grid_changes = grid.apply(&edit).unwrap();
            let changes = s.remesh(grid.fine(), &touched(&edit));
            mapping.update_by_grid_node(&s, &grid, &changed_elements(&grid_changes), &changes);
            let fresh = SurfaceMapping::embed(&s, &grid, &|g| g);
            for (v, vertex) in s.vertices().iter().enumerate() {
                let v = v as u32;
                prop_assert!(
                    !vertex.alive || mapping.embedding(v) == fresh.embedding(v),
                    "edit {}: vertex {} embedded as {:?}, freshly as {:?}",
                    i, v, mapping.embedding(v), fresh.embedding(v)
                );
            }
            if let Err(e) = check_surface(&s) {
                prop_assert!(false, "edit {}: {}", i, e);
            }
            if let Err(e) = matches_full(&s, &grid, &o) {
                prop_assert!(false, "edit {}: {}", i, e);
            }
        }
    }
}
