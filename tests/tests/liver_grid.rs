//! The real liver CT (`tests/data/liver.inr.gz`, see `tests/data/README.md`) through the whole
//! pipeline: read, filter, crop, stride, build the branched grid, cut it.
//!
//! Counts are pinned: a change in any of them is a change in the grid's topology on real data and
//! must be explained in the commit that changes them.

use incise_grid::canonical::compare_grids;
use incise_grid::{BranchedGrid, GridEdit, LabelFilter, LabelVolume, MaterialTable};
use incise_tests::fixture;

fn liver(stride: [usize; 3]) -> LabelVolume {
    let raw = incise_io::read_volume(&fixture("liver.inr.gz")).expect("fixture reads");
    raw.filtered(&LabelFilter::abdominal_ct())
        .crop_and_stride(stride)
        .expect("fixture has a foreground")
}

/// (level, elements, superimposed, nodes) for levels 0..=3.
fn check_counts(
    stride: [usize; 3],
    voxels: usize,
    dims: [usize; 3],
    expected: [(u32, usize, usize, usize); 4],
) {
    let v = liver(stride);
    assert_eq!(v.dims(), dims);
    assert_eq!(v.foreground_count(), voxels);
    let grid = BranchedGrid::build(&v, &MaterialTable::abdominal_ct(), 3).unwrap();
    let got: Vec<(u32, usize, usize, usize)> =
        grid.summary().iter().map(|s| (s.level, s.elements, s.superimposed, s.nodes)).collect();
    println!("liver at stride {stride:?}: {voxels} voxels");
    println!("level  elements  superimposed  nodes");
    for (l, e, s, n) in &got {
        println!("{l:>5} {e:>9} {s:>13} {n:>6}");
    }
    assert_eq!(got, expected.to_vec());
}

#[test]
fn liver_at_stride_8_8_4() {
    check_counts(
        [8, 8, 4],
        13_648,
        [42, 35, 34],
        [(0, 13_648, 0, 16_728), (1, 2_113, 6, 2_982), (2, 377, 24, 652), (3, 82, 16, 180)],
    );
}

#[test]
fn liver_at_stride_4_4_2() {
    check_counts(
        [4, 4, 2],
        109_201,
        [84, 70, 68],
        [
            (0, 109_201, 0, 121_556),
            (1, 15_217, 12, 18_471),
            (2, 2_304, 36, 3_189),
            (3, 403, 35, 682),
        ],
    );
}

#[test]
fn liver_cut_updates_equal_a_rebuild() {
    // A blade 1 voxel thick down the middle plane from the top, then a separation cut beside it.
    let v = liver([8, 8, 4]);
    let mut grid = BranchedGrid::build(&v, &MaterialTable::abdominal_ct(), 3).unwrap();
    let d = grid.fine().dims();
    let x = d[0] / 2;
    let mut remove = Vec::new();
    let mut sever = Vec::new();
    for z in d[2] / 3..d[2] {
        for y in 0..d[1] {
            let vox = x + d[0] * (y + d[1] * z);
            if grid.fine().material(vox).is_some() {
                remove.push(vox);
                sever.push((vox + 3, vox + 4));
            }
        }
    }
    let elements_before = grid.top().element_count();
    let changes = grid.apply(&GridEdit { remove_voxels: remove, sever_links: vec![] }).unwrap();
    assert!(changes.voxels_removed > 100, "the blade removes voxels ({})", changes.voxels_removed);
    let labels = grid.fine_labels();
    assert_eq!(
        labels.iter().filter(|&&l| l != 0).count(),
        v.foreground_count() - changes.voxels_removed
    );
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
    let changes = grid.apply(&GridEdit { remove_voxels: vec![], sever_links: sever }).unwrap();
    assert!(changes.links_severed > 100);
    compare_grids(&grid, &grid.rebuild(), 1e-12).unwrap();
    assert!(
        grid.top().element_count() > elements_before,
        "cutting the organ in two branches its elements"
    );
}
