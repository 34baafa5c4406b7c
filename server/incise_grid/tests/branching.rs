//! Jeřábková 2010 §2.1 (Fig. 3, 5): the branched topology against an independent brute-force
//! construction, the U-tube whose arms share coarse cells, and the level-0 voxel graph.

mod common;

use common::{materials, random_volume, reference_level, without_children};
use incise_grid::canonical::canonical_levels;
use incise_grid::procedural::{UTube, u_tube};
use incise_grid::{BranchedGrid, Material, MaterialTable};
use proptest::prelude::*;
use std::collections::BTreeSet;

fn check_against_reference(grid: &BranchedGrid) -> Result<(), String> {
    for c in canonical_levels(grid) {
        let r = reference_level(grid, c.level);
        if let Some(d) = without_children(c).first_difference(&r) {
            return Err(d);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(64)))]

    #[test]
    fn levels_equal_the_brute_force_construction(
        dims in prop::array::uniform3(1usize..11),
        density in 0.2f64..1.0,
        level in 0u32..=3,
        seed in any::<u64>(),
    ) {
        let v = random_volume(dims, density, 1, seed);
        let grid = BranchedGrid::build(&v, &materials(1), level).unwrap();
        if let Err(d) = check_against_reference(&grid) {
            prop_assert!(false, "{}", d);
        }
    }
}

fn tube_grid(level: u32) -> BranchedGrid {
    let v = u_tube(UTube::DEFAULT, 1e-3);
    BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::liver()), level).unwrap()
}

#[test]
fn u_tube_arms_branch_where_they_share_cells() {
    let shape = UTube::DEFAULT;
    for level in 1..=3u32 {
        let grid = tube_grid(level);
        let top = grid.top();
        let dims = grid.fine().dims();
        // The arm an element belongs to, if all its voxels lie in one arm above the base.
        let arm_of = |id: u32| -> Option<usize> {
            let mut arms = BTreeSet::new();
            for v in grid.element_voxels(id) {
                let (x, z) = (v % dims[0], v / (dims[0] * dims[1]));
                if (z as usize) < shape.base_height {
                    return None;
                }
                arms.insert(shape.arm_of(x as usize)?);
            }
            (arms.len() == 1).then(|| *arms.first().unwrap())
        };
        let shares_cells = (0..top.cell_dims().iter().product::<u32>()).any(|c| {
            let arms: BTreeSet<usize> =
                top.cell_elements(c).iter().filter_map(|&e| arm_of(e)).collect();
            arms.len() == 2
        });
        let mut nodes = [BTreeSet::new(), BTreeSet::new()];
        for (id, e) in top.elements() {
            if let Some(a) = arm_of(id) {
                nodes[a].extend(e.nodes.iter().copied());
            }
        }
        let shared: Vec<u32> = nodes[0].intersection(&nodes[1]).copied().collect();
        // Where the arms meet the base they share the nodes of the base's top face, and only there.
        let base_plane = (shape.base_height as u32).div_ceil(1 << level);
        for &n in &shared {
            let p = top.point_coords(top.node(n).unwrap().point);
            assert!(
                p[2] <= base_plane,
                "level {level}: node {n} at {p:?} is shared by both arms above the base"
            );
        }
        if level >= 2 {
            assert!(shares_cells, "level {level}: the arms should share cells");
            assert!(
                top.superimposed_count() >= 2,
                "level {level}: cells holding both arms need superimposed elements"
            );
        } else {
            assert!(
                !shares_cells && top.superimposed_count() == 0,
                "level 1 cells never hold both arms"
            );
        }
    }
}

#[test]
fn level_zero_is_the_voxel_graph() {
    let grid = tube_grid(0);
    let v = u_tube(UTube::DEFAULT, 1e-3);
    let top = grid.top();
    assert_eq!(top.element_count(), v.foreground_count());
    // Elements are voxels: each owns exactly itself, and its neighbours are its face neighbours.
    for (_, e) in top.elements() {
        assert_eq!((e.voxel_count, e.children.as_slice()), (1, &[e.min_voxel][..]));
        let mut expected: Vec<u32> = common::fine_neighbors(&grid, e.min_voxel);
        expected.sort_unstable();
        let mut got: Vec<u32> =
            e.neighbors.iter().map(|&n| top.element(n).unwrap().min_voxel).collect();
        got.sort_unstable();
        assert_eq!(got, expected);
    }
    // A solid U-tube has no edge-only contacts, so every corner point is one node:
    // 13×5×17 points minus the 12×5 points strictly inside the gap above the base.
    assert_eq!(top.node_count(), 13 * 5 * 17 - 12 * 5);
    // The level-0 summary of a coarse grid uses the same routine and agrees.
    assert_eq!(tube_grid(2).summary()[0].nodes, top.node_count());
    check_against_reference(&grid).unwrap();
}

#[test]
fn numbering_is_deterministic() {
    let v = random_volume([13, 9, 11], 0.7, 3, 42);
    let a = BranchedGrid::build(&v, &materials(3), 2).unwrap();
    let b = BranchedGrid::build(&v, &materials(3), 2).unwrap();
    for (la, lb) in a.levels().iter().zip(b.levels()) {
        assert!(la.elements().eq(lb.elements()), "element numbering differs between two builds");
        assert!(la.nodes().eq(lb.nodes()), "node numbering differs between two builds");
    }
    for (id, _) in a.top().elements() {
        assert_eq!(a.matrices(id), b.matrices(id), "matrices are not bit-identical");
    }
}

#[test]
fn bad_grids_are_errors_that_say_why() {
    let v = u_tube(UTube::DEFAULT, 1e-3);
    let err = BranchedGrid::build(&v, &MaterialTable::new(), 2).unwrap_err();
    assert!(err.to_string().contains("label 1"), "{err}");
    let err =
        BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::liver()), 9).unwrap_err();
    assert!(err.to_string().contains("level 9"), "{err}");
    let bad = MaterialTable::uniform(&[1], Material::new(1e3, 0.7, 1000.0));
    let err = BranchedGrid::build(&v, &bad, 2).unwrap_err();
    assert!(err.to_string().contains("Poisson"), "{err}");
    let empty = incise_grid::procedural::from_fn([4, 4, 4], [1e-3; 3], |_, _, _| 0);
    let err = BranchedGrid::build(&empty, &MaterialTable::uniform(&[1], Material::liver()), 1)
        .unwrap_err();
    assert!(err.to_string().contains("no foreground"), "{err}");
}

#[test]
fn voxel_element_names_the_element_that_owns_the_voxel() {
    for level in 0..=3u32 {
        let mut grid = tube_grid(level);
        // Cut the left arm off its base, so owners move to split pieces.
        let d = grid.fine().dims();
        let z = UTube::DEFAULT.base_height as u32;
        let cut: Vec<u32> =
            (0..d[1]).flat_map(|y| (0..5).map(move |x| x + d[0] * (y + d[1] * z))).collect();
        grid.apply(&incise_grid::GridEdit { remove_voxels: cut, sever_links: vec![] }).unwrap();
        let mut owner = vec![None; d.iter().product::<u32>() as usize];
        for (id, _) in grid.top().elements() {
            for v in grid.element_voxels(id) {
                owner[v as usize] = Some(id);
            }
        }
        for (v, o) in owner.iter().enumerate() {
            assert_eq!(grid.voxel_element(v as u32), *o, "level {level}, voxel {v}");
        }
        assert_eq!(grid.voxel_element(owner.len() as u32), None, "out of range");
    }
}
