//! Jeřábková 2010 §2.1–2.2 (eq. 5): incremental updates after voxel removal and link severing must
//! equal a rebuild from scratch (graphs equal up to renumbering; K and M to 1e-12 relative, the
//! rounding margin justified in `condensation.rs`; subtraction is used only while fewer voxels
//! are removed than remain, which bounds cancellation), and report what changed.

mod common;

use common::{Rng, materials, random_edit, random_volume, reference_level, without_children};
use incise_grid::canonical::{canonical_levels, compare_grids};
use incise_grid::procedural::from_fn;
use incise_grid::{Block, BranchedGrid, GridEdit, Material, MaterialTable};
use proptest::prelude::*;

fn check_changes(grid: &BranchedGrid, changes: &incise_grid::GridChanges) -> Result<(), String> {
    let top = grid.top();
    for &(id, origin) in &changes.top.elements_added {
        if top.element(id).is_none() {
            return Err(format!("added element {id} is not alive"));
        }
        if let Some(o) = origin
            && top.element(o).is_none()
        {
            return Err(format!(
                "element {id} split from {o}, which should survive as the largest piece"
            ));
        }
    }
    for &id in &changes.top.elements_removed {
        if top.element(id).is_some() && !changes.top.elements_added.iter().any(|&(a, _)| a == id) {
            return Err(format!("removed element {id} is still alive"));
        }
    }
    for &(id, _) in &changes.top.nodes_added {
        if top.node(id).is_none() {
            return Err(format!("added node {id} is not alive"));
        }
    }
    for (id, e) in top.elements() {
        if grid.matrices(id).is_none() {
            return Err(format!("live element {id} has no matrices"));
        }
        if e.nodes.iter().any(|&n| top.node(n).is_none()) {
            return Err(format!("element {id} refers to a dead node: {:?}", e.nodes));
        }
        check_offsets(grid, id)?;
    }
    Ok(())
}

/// `element_voxel_offsets_into` (a box scan for an element alone in its cell, a walk for the
/// pieces of a split one) names the element's voxels, each at its coordinates less its cell's
/// lowest corner.
fn check_offsets(grid: &BranchedGrid, id: u32) -> Result<(), String> {
    let d = grid.fine().dims();
    let per = 1u32 << grid.top_level();
    let cell = grid.top().cell_coords(grid.top().element(id).expect("live").cell);
    let mut walked = grid.element_voxels(id);
    let mut offsets = Vec::new();
    grid.element_voxel_offsets_into(id, &mut offsets);
    for &(v, o) in &offsets {
        let c = [v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])];
        let want: [u32; 3] = std::array::from_fn(|a| c[a] - cell[a] * per);
        if o != want {
            return Err(format!("element {id}: voxel {v} at offset {o:?}, not {want:?}"));
        }
    }
    let mut scanned: Vec<u32> = offsets.iter().map(|&(v, _)| v).collect();
    walked.sort_unstable();
    scanned.sort_unstable();
    if walked != scanned {
        return Err(format!("element {id}: offsets name {scanned:?}, the element owns {walked:?}"));
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(96)))]

    #[test]
    fn incremental_equals_rebuild(
        dims in prop::array::uniform3(1usize..13),
        density in 0.3f64..1.0,
        mats in prop::sample::select(vec![1u16, 2]),
        level in 0u32..=3,
        seed in any::<u64>(),
        steps in prop::collection::vec((0usize..12, 0usize..12), 1..5),
    ) {
        let v = random_volume(dims, density, mats, seed);
        let mut grid = BranchedGrid::build(&v, &materials(mats), level).unwrap();
        let mut rng = Rng(seed ^ 0x9e37_79b9_7f4a_7c15 | 1);
        for (i, &(removals, severs)) in steps.iter().enumerate() {
            let edit = random_edit(&grid, &mut rng, removals, severs);
            let changes = grid.apply(&edit).unwrap();
            if let Err(e) = check_changes(&grid, &changes) {
                prop_assert!(false, "step {}: {}", i, e);
            }
            let rebuilt = grid.rebuild();
            if let Err(e) = compare_grids(&grid, &rebuilt, 1e-12) {
                prop_assert!(false, "step {} ({:?}): incremental differs from rebuild: {}", i, edit, e);
            }
            let top = canonical_levels(&grid).pop().unwrap();
            if let Some(d) = without_children(top).first_difference(&reference_level(&grid, level)) {
                prop_assert!(false, "step {}: top level differs from the brute-force reference: {}", i, d);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(96)))]

    /// Walking an element's descendants and skipping the blocks outside a box of voxels, or
    /// taking a block inside it whole, lists exactly the element's voxels in the box, in the
    /// order `element_voxels_into` lists them; after cuts too.
    #[test]
    fn voxels_by_block_are_the_element_voxels_in_the_box(
        dims in prop::array::uniform3(1usize..13),
        density in 0.3f64..1.0,
        level in 0u32..=3,
        seed in any::<u64>(),
        lo in prop::array::uniform3(0u32..12),
        span in prop::array::uniform3(0u32..8),
        cuts in 0usize..6,
    ) {
        let v = random_volume(dims, density, 2, seed);
        let mut grid = BranchedGrid::build(&v, &materials(2), level).unwrap();
        let mut rng = Rng(seed ^ 0x5851_f42d_4c95_7f2d | 1);
        if cuts > 0 {
            let edit = random_edit(&grid, &mut rng, cuts, cuts);
            grid.apply(&edit).unwrap();
        }
        let hi: [u32; 3] = std::array::from_fn(|k| lo[k] + span[k]);
        let d = grid.fine().dims();
        let inside = |c: [u32; 3]| (0..3).all(|k| c[k] >= lo[k] && c[k] <= hi[k]);
        let ids: Vec<u32> = grid.top().elements().map(|(id, _)| id).collect();
        for id in ids {
            let mut all = Vec::new();
            grid.element_voxels_into(id, &mut all);
            let want: Vec<u32> = all
                .into_iter()
                .filter(|&v| inside([v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])]))
                .collect();
            let mut got = Vec::new();
            grid.element_voxels_where(
                id,
                &mut |first: [u32; 3], size: u32| {
                    let last: [u32; 3] = std::array::from_fn(|k| first[k] + size - 1);
                    if (0..3).any(|k| last[k] < lo[k] || first[k] > hi[k]) {
                        Block::Skip
                    } else if inside(first) && inside(last) {
                        Block::All
                    } else {
                        Block::Some
                    }
                },
                &mut got,
            );
            // A finest block answered `Some` lists its voxels whole, for the caller to test one
            // by one (as `each_near` tests their centres): filtered here the same way.
            got.retain(|&v| inside([v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])]));
            prop_assert_eq!(got, want, "element {}", id);
        }
    }
}

fn block(dims: [usize; 3]) -> BranchedGrid {
    let v = from_fn(dims, [1e-3; 3], |_, _, _| 1);
    BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::liver()), 2).unwrap()
}

fn voxel(grid: &BranchedGrid, x: u32, y: u32, z: u32) -> u32 {
    let d = grid.fine().dims();
    x + d[0] * (y + d[1] * z)
}

#[test]
fn no_topological_change_updates_matrices_only() {
    let mut grid = block([8, 4, 4]);
    let before = grid.top().element_count();
    let changes = grid
        .apply(&GridEdit { remove_voxels: vec![voxel(&grid, 1, 1, 1)], sever_links: vec![] })
        .unwrap();
    assert_eq!(grid.top().element_count(), before);
    assert!(changes.top.elements_added.is_empty() && changes.top.elements_removed.is_empty());
    assert!(changes.top.nodes_added.is_empty() && changes.top.nodes_removed.is_empty());
    assert_eq!(changes.matrices_updated.len(), 1);
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
}

#[test]
fn cell_split_creates_a_superimposed_element() {
    // Remove the voxel plane x = 1 inside the first level-2 cell (x 0..4): x = 0 is cut off.
    let mut grid = block([8, 4, 4]);
    let plane: Vec<u32> = (0..4)
        .flat_map(|z| (0..4).map(move |y| (y, z)))
        .map(|(y, z)| voxel(&grid, 1, y, z))
        .collect();
    let changes = grid.apply(&GridEdit { remove_voxels: plane, sever_links: vec![] }).unwrap();
    assert_eq!(grid.top().element_count(), 3, "x = 0 slice, x 2..4 and the second cell");
    assert_eq!(changes.top.elements_added.len(), 1);
    let (new, origin) = changes.top.elements_added[0];
    assert!(origin.is_some(), "the new piece names the element it split from");
    assert_eq!(
        grid.top().element(new).unwrap().voxel_count,
        16,
        "the smaller piece is the new one"
    );
    assert_eq!(grid.top().superimposed_count(), 2);
    assert_eq!(
        changes.top.nodes_added.len(),
        8,
        "the cut-off slice connects to nothing: all 8 corners are its own"
    );
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
}

#[test]
fn cell_disconnect_unshares_nodes() {
    // Sever every link across x = 4 between the two level-2 cells of an 8×4×4 block.
    let mut grid = block([8, 4, 4]);
    let links: Vec<(u32, u32)> = (0..4)
        .flat_map(|z| (0..4).map(move |y| (y, z)))
        .map(|(y, z)| (voxel(&grid, 3, y, z), voxel(&grid, 4, y, z)))
        .collect();
    let nodes_before = grid.top().node_count();
    let changes = grid.apply(&GridEdit { remove_voxels: vec![], sever_links: links }).unwrap();
    assert_eq!(changes.links_severed, 16);
    assert_eq!(grid.top().element_count(), 2);
    assert!(
        grid.top().elements().all(|(_, e)| e.neighbors.is_empty()),
        "the two elements are no longer connected"
    );
    assert_eq!(
        grid.top().node_count(),
        nodes_before + 4,
        "the shared face's 4 nodes are duplicated"
    );
    assert!(
        changes.top.nodes_added.iter().all(|&(_, o)| o.is_some()),
        "new nodes name the node they split from"
    );
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
}

#[test]
fn cell_removal_drops_the_element() {
    let mut grid = block([8, 4, 4]);
    let all: Vec<u32> = (0..4)
        .flat_map(|z| (0..4).flat_map(move |y| (0..4).map(move |x| (x, y, z))))
        .map(|(x, y, z)| voxel(&grid, x, y, z))
        .collect();
    let changes = grid.apply(&GridEdit { remove_voxels: all, sever_links: vec![] }).unwrap();
    assert_eq!(changes.top.elements_removed.len(), 1);
    assert_eq!(grid.top().element_count(), 1);
    assert_eq!(changes.top.nodes_removed.len(), 4, "the far face's corners go with the element");
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
}

#[test]
fn bad_edits_are_errors_and_change_nothing() {
    let mut grid = block([8, 4, 4]);
    let before = canonical_levels(&grid);
    let err =
        grid.apply(&GridEdit { remove_voxels: vec![0, 1000], sever_links: vec![] }).unwrap_err();
    assert!(err.to_string().contains("1000"), "{err}");
    let err =
        grid.apply(&GridEdit { remove_voxels: vec![], sever_links: vec![(0, 2)] }).unwrap_err();
    assert!(err.to_string().contains("do not share a face"), "{err}");
    assert_eq!(canonical_levels(&grid), before);
}
