//! The embedding of the surface in the top-level elements (paper 1, §3, Fig. 9): it reproduces
//! the rest positions, its force mapping is the exact transpose of its position mapping, and after
//! a cut only the vertices of changed elements are embedded again.

mod common;

use common::{H, Rng, check_surface, cluster, grid_of, voxel};
use incise_grid::procedural::sphere;
use incise_grid::{BranchedGrid, GridEdit};
use incise_math::Vec3;
use incise_surface::{Surface, SurfaceMapping, SurfaceOptions, changed_elements};

/// The caller's numbering of the grid's nodes, as `HexModel` numbers them: the live nodes in id
/// order, compactly. A cut that adds or removes a node shifts the index of every node after it,
/// touched by the cut or not.
fn numbering(grid: &BranchedGrid) -> impl Fn(u32) -> u32 + use<> {
    let mut rank = vec![u32::MAX; grid.top().node_capacity()];
    for (i, (id, _)) in grid.top().nodes().enumerate() {
        rank[id as usize] = i as u32;
    }
    move |n| rank[n as usize]
}

/// Node positions at rest in the caller's numbering.
fn rest_nodes(grid: &BranchedGrid) -> Vec<Vec3> {
    let index = numbering(grid);
    let mut x = vec![[0.0; 3]; grid.top().node_count()];
    for (id, _) in grid.top().nodes() {
        x[index(id) as usize] = grid.node_rest_position(id).unwrap();
    }
    x
}

/// Largest distance between the live vertices' `positions` and `want`, over the largest `|want|`.
fn relative_gap(s: &Surface, positions: &[Vec3], want: &[Vec3]) -> f64 {
    let mut gap = 0.0f64;
    let mut size = 0.0f64;
    for (i, v) in s.vertices().iter().enumerate() {
        if v.alive {
            for a in 0..3 {
                gap = gap.max((positions[i][a] - want[i][a]).abs());
                size = size.max(want[i][a].abs());
            }
        }
    }
    gap / size
}

#[test]
fn nodes_at_rest_give_the_rest_surface() {
    for level in 0..=3 {
        let grid = grid_of(&sphere(14, H), 1, level);
        let mut s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
        let x = rest_nodes(&grid);
        let mut out = Vec::new();
        let m = SurfaceMapping::embed(&s, &grid, &numbering(&grid));
        m.deformed(&x, &mut out);
        // Trilinear interpolation reproduces linear functions, positions among them: only
        // rounding separates the two, a few ulps of the coordinates.
        let gap = relative_gap(&s, &out, &s.rest_positions());
        assert!(gap < 1e-12, "level {level}: {gap:e}");
        for (i, v) in s.vertices().iter().enumerate() {
            let w = m.embedding(i as u32).weights;
            assert!(!v.alive || (w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
        // Smoothed vertices may leave their element's cell (weights outside [0, 1]); the
        // extrapolation still reproduces them.
        let smooth = s.smoothed_rest(5, 0.5);
        s.set_rest(&smooth);
        let m = SurfaceMapping::embed(&s, &grid, &numbering(&grid));
        m.deformed(&x, &mut out);
        let gap = relative_gap(&s, &out, &smooth);
        assert!(gap < 1e-12, "level {level}, smoothed: {gap:e}");
    }
}

#[test]
fn force_mapping_is_the_transpose_of_position_mapping() {
    let grid = grid_of(&sphere(14, H), 1, 2);
    let s = Surface::extract(grid.fine(), grid.spacing(), &SurfaceOptions::default());
    let m = SurfaceMapping::embed(&s, &grid, &numbering(&grid));
    let x0 = rest_nodes(&grid);
    let mut rng = Rng::new(11);
    for _ in 0..5 {
        let u: Vec<Vec3> =
            x0.iter().map(|_| std::array::from_fn(|_| 1e-4 * rng.signed())).collect();
        let x: Vec<Vec3> =
            x0.iter().zip(&u).map(|(p, d)| std::array::from_fn(|a| p[a] + d[a])).collect();
        let forces: Vec<(u32, Vec3)> = s
            .vertices()
            .iter()
            .enumerate()
            .filter(|(_, v)| v.alive)
            .map(|(i, _)| (i as u32, std::array::from_fn(|_| rng.signed())))
            .collect();
        let (mut deformed, mut rest) = (Vec::new(), Vec::new());
        m.deformed(&x, &mut deformed);
        m.deformed(&x0, &mut rest);
        let surface_work: f64 = forces
            .iter()
            .map(|&(v, f)| {
                (0..3).map(|a| f[a] * (deformed[v as usize][a] - rest[v as usize][a])).sum::<f64>()
            })
            .sum();
        let mut node_forces = vec![[0.0; 3]; x0.len()];
        m.add_forces(&forces, &mut node_forces);
        let node_work: f64 =
            node_forces.iter().zip(&u).map(|(f, d)| (0..3).map(|a| f[a] * d[a]).sum::<f64>()).sum();
        // Both are the same bilinear form fᵀ W u summed in two orders: they differ by rounding of
        // a sum of ~10⁴ terms, and of the cancellation in deformed − rest.
        let rel = (surface_work - node_work).abs() / node_work.abs();
        assert!(rel < 1e-12, "virtual work {surface_work:e} against {node_work:e} ({rel:e})");
    }
}

#[test]
fn a_cut_re_embeds_only_the_vertices_of_changed_elements() {
    let o = SurfaceOptions::default();
    let mut grid = grid_of(&sphere(16, H), 1, 2);
    let mut s = Surface::extract(grid.fine(), grid.spacing(), &o);
    let mut m = SurfaceMapping::embed(&s, &grid, &numbering(&grid));
    // The same vertices numbered by grid node id, as the simulation embeds them.
    let mut by_id = SurfaceMapping::embed(&s, &grid, &|g| g);
    let d = grid.fine().dims();
    let bottom: Vec<u32> = (0..d[0] * d[1] * 4).collect();
    let edits = [
        // The bottom layer of level-2 cells goes, and with it the lowest node ids: every other
        // node's compact index shifts. Then a small bite at the surface, and a slit severing the
        // upper part nearly in two.
        GridEdit { remove_voxels: bottom, sever_links: vec![] },
        GridEdit {
            remove_voxels: cluster(d, voxel(d, 8, 8, 15), 25, &mut Rng::new(3)),
            sever_links: vec![],
        },
        GridEdit {
            remove_voxels: vec![],
            sever_links: (0..d[0])
                .flat_map(|x| (0..d[1]).map(move |y| (x, y)))
                .filter(|&(_, y)| y > 2)
                .map(|(x, y)| (voxel(d, x, y, 9), voxel(d, x, y, 10)))
                .collect(),
        },
    ];
    for edit in edits {
        let grid_changes = grid.apply(&edit).unwrap();
        let changes = s.remesh(grid.fine(), &common::touched(&edit));
        check_surface(&s).unwrap();
        let index = numbering(&grid);
        let count = m.update(&s, &grid, &changed_elements(&grid_changes), &changes, &index);
        println!("re-embedded {count} of {} vertices", s.vertex_count());
        assert!(count > 0 && count < s.vertex_count(), "{count} of {}", s.vertex_count());
        let by_id_count =
            by_id.update_by_grid_node(&s, &grid, &changed_elements(&grid_changes), &changes);
        assert_eq!(by_id_count, count);
        let fresh = SurfaceMapping::embed(&s, &grid, &index);
        let fresh_by_id = SurfaceMapping::embed(&s, &grid, &|g| g);
        for (i, v) in s.vertices().iter().enumerate() {
            if v.alive {
                assert_eq!(m.embedding(i as u32), fresh.embedding(i as u32), "vertex {i}");
                assert_eq!(
                    by_id.embedding(i as u32),
                    fresh_by_id.embedding(i as u32),
                    "vertex {i}"
                );
            }
        }
        // The vertices re-embedded are those of the changed elements' voxels and the new ones.
        let mut want: Vec<u32> = changes.vertices_added.clone();
        for e in changed_elements(&grid_changes) {
            for voxel in grid.element_voxels(e) {
                want.extend(s.vertices_of_voxel(voxel));
            }
        }
        want.sort_unstable();
        want.dedup();
        want.retain(|&v| s.vertices()[v as usize].alive);
        assert_eq!(count, want.len());
        let (mut a, mut b) = (Vec::new(), Vec::new());
        m.deformed(&rest_nodes(&grid), &mut a);
        fresh.deformed(&rest_nodes(&grid), &mut b);
        assert_eq!(a, b);
    }
}

#[test]
fn identity_maps_vertices_to_nodes() {
    let m = SurfaceMapping::identity(3);
    let x = vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]];
    let mut out = Vec::new();
    m.deformed(&x, &mut out);
    assert_eq!(out, x);
    let mut f = vec![[0.0; 3]; 3];
    m.add_forces(&[(1, [1.0, -1.0, 0.5]), (1, [1.0, 0.0, 0.0])], &mut f);
    assert_eq!(f, vec![[0.0; 3], [2.0, -1.0, 0.5], [0.0; 3]]);
}
