//! Composite coarse elements (`incise_grid::composite`) against what they must satisfy whatever
//! the voxels: no energy in rigid motions; never stiffer than the Galerkin (condensed) element,
//! never of negative energy; and, in a cell whose points are all shared with neighbours (nothing
//! free but the inner points), the same forces as the Galerkin element for every linear field, the
//! fields a homogeneous cell's inner points already balance (the patch test).

use incise_grid::composite::composite_stiffness;
use incise_grid::hex8::{Mat24, corner, rigid_modes};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, LabelVolume, Material, MaterialTable};

fn grid(volume: &LabelVolume, level: u32) -> BranchedGrid {
    let table = MaterialTable::uniform(&[1, 2], Material::new(3e3, 0.45, 1000.0));
    BranchedGrid::build(volume, &table, level).unwrap()
}

/// A 24 × 16 × 24 block of 2 mm voxels with two holes along y and a second, stiffer material in
/// one corner: thin walls, superimposed elements and material borders at every level.
fn holed_block() -> LabelVolume {
    from_fn([24, 16, 24], [2e-3; 3], |x, y, z| {
        let hole = [(7.0, 8.0), (16.0, 15.0)]
            .iter()
            .any(|&(cx, cz)| (x + 0.5 - cx).powi(2) + (z + 0.5 - cz).powi(2) < 10.0);
        if hole {
            0
        } else if x > 17.0 && y > 9.0 {
            2
        } else {
            1
        }
    })
}

fn energy(k: &Mat24, u: &[f64; 24]) -> f64 {
    let ku = k.mul_vec(u);
    ku.iter().zip(u).map(|(a, b)| a * b).sum()
}

/// A fixed sequence of pseudo-random vectors in [−1, 1]²⁴ (xorshift: no dependency, same every
/// run).
fn vectors(count: usize) -> Vec<[f64; 24]> {
    let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
    (0..count)
        .map(|_| {
            std::array::from_fn(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 52) as f64 - 1.0
            })
        })
        .collect()
}

#[test]
fn rigid_motions_cost_nothing_and_no_element_is_stiffer_than_the_condensed_one() {
    let volume = holed_block();
    let probes = vectors(64);
    for level in 1..=3 {
        let grid = grid(&volume, level);
        let composite = composite_stiffness(&grid);
        let size = grid.element_size();
        let mut checked = 0;
        let mut softer = 0;
        for (id, _) in grid.top().elements() {
            let k = composite[id as usize].as_ref().expect("live element");
            let galerkin = &grid.matrices(id).unwrap().stiffness;
            let scale = galerkin.frobenius();
            for mode in rigid_modes(size) {
                let f = k.mul_vec(&mode);
                let norm = f.iter().map(|x| x * x).sum::<f64>().sqrt();
                let len = mode.iter().map(|x| x * x).sum::<f64>().sqrt();
                // Rounding of a few hundred products of entries of size `scale`.
                assert!(
                    norm <= 1e-11 * scale * len,
                    "level {level}, element {id}: |K r| = {norm:e}"
                );
            }
            for u in &probes {
                let (ec, eg) = (energy(k, u), energy(galerkin, u));
                let tol = 1e-11 * scale * 24.0;
                assert!(ec >= -tol, "level {level}, element {id}: negative energy {ec:e}");
                assert!(ec <= eg + tol, "level {level}, element {id}: {ec:e} > Galerkin {eg:e}");
                softer += usize::from(ec < eg * (1.0 - 1e-6));
            }
            checked += 1;
        }
        println!(
            "level {level}: {checked} elements, {softer} of {} probes softer than Galerkin",
            checked * probes.len()
        );
        // The relaxation must do something: most cells hold points it frees.
        assert!(
            softer * 2 > checked * probes.len(),
            "level {level}: the composite is the Galerkin element"
        );
    }
}

#[test]
fn an_inner_homogeneous_cell_passes_the_patch_test() {
    for level in 1..=2u32 {
        let n = 3 * (1usize << level);
        let volume = from_fn([n, n, n], [1e-3, 1.5e-3, 2e-3], |_, _, _| 1);
        let grid = grid(&volume, level);
        let composite = composite_stiffness(&grid);
        let size = grid.element_size();
        // The middle cell of 3 × 3 × 3: every point on its faces is shared.
        let (id, _) = grid
            .top()
            .elements()
            .find(|(_, e)| grid.top().cell_coords(e.cell) == [1, 1, 1])
            .expect("the middle cell");
        let k = composite[id as usize].as_ref().unwrap();
        let galerkin = &grid.matrices(id).unwrap().stiffness;
        let mut worst: f64 = 0.0;
        for g in 0..9 {
            // u = G x with G the unit matrix g (row g / 3, column g % 3).
            let u: [f64; 24] = std::array::from_fn(|i| {
                let (c, a) = (i / 3, i % 3);
                let x = corner(c)[g % 3] as f64 * size[g % 3];
                if a == g / 3 { x } else { 0.0 }
            });
            let (fc, fg) = (k.mul_vec(&u), galerkin.mul_vec(&u));
            let diff = fc.iter().zip(&fg).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
            let norm = fg.iter().map(|x| x * x).sum::<f64>().sqrt();
            worst = worst.max(diff / norm);
        }
        println!("level {level}: linear fields, largest relative force difference {worst:e}");
        assert!(worst <= 1e-10, "level {level}: the patch test fails by {worst:e}");
        // The fields that are not linear do relax: moving one corner alone costs less.
        let one_corner: [f64; 24] = std::array::from_fn(|i| f64::from(i == 0));
        let (ec, eg) = (energy(k, &one_corner), energy(galerkin, &one_corner));
        println!(
            "level {level}: one corner moved, energy {:.4} of the Galerkin element's",
            ec / eg
        );
        assert!(ec < eg * (1.0 - 1e-3), "level {level}: no relaxation ({ec:e} against {eg:e})");
    }
}

mod common;

use common::{Rng, materials, random_edit, random_volume};
use incise_grid::composite::CompositeLevels;
use proptest::prelude::*;

/// The first element whose stiffness differs between `a` and `b` in any bit (or lives in one
/// only), if any.
fn first_difference(a: &[Option<Mat24>], b: &[Option<Mat24>]) -> Option<usize> {
    (0..a.len().max(b.len())).find(|&id| match (a.get(id), b.get(id)) {
        (Some(Some(a)), Some(Some(b))) => {
            a.0.iter().zip(&b.0).any(|(x, y)| x.to_bits() != y.to_bits())
        }
        (Some(None) | None, Some(None) | None) => false,
        _ => true,
    })
}

/// Edits `steps` (removals, severings) at random into a random block and checks after each that
/// the levels updated near the edit give every element the stiffness a computation from scratch
/// gives, bit for bit: the cells left alone did not depend on the edit. With `track`, every
/// level's nodes are kept current, as a simulation of composite elements keeps them: the node
/// numbering then differs from the one computed from scratch, which must not matter.
fn check_local_update(
    volume: &LabelVolume,
    mats: u16,
    level: u32,
    seed: u64,
    track: bool,
    steps: &[(usize, usize)],
) -> Result<(), TestCaseError> {
    let mut plain = BranchedGrid::build(volume, &materials(mats), level).unwrap();
    let mut grid = plain.clone();
    if track {
        grid.track_all_nodes();
    }
    let (mut levels, _) = CompositeLevels::new(&grid);
    let mut rng = Rng(seed ^ 0x2545_f491_4f6c_dd1d | 1);
    for (i, &(removals, severs)) in steps.iter().enumerate() {
        let edit = random_edit(&grid, &mut rng, removals, severs);
        let changes = grid.apply(&edit).unwrap();
        plain.apply(&edit).unwrap();
        let made = levels.update(&grid, &changes.dirty_voxels);
        let local = levels.stiffness(&grid);
        let scratch = composite_stiffness(&plain);
        prop_assert_eq!(local.len(), scratch.len());
        if let Some(id) = first_difference(&local, &scratch) {
            prop_assert!(
                false,
                "step {}: element {} differs from the computation from scratch",
                i,
                id
            );
        }
        for (id, k) in &made {
            let b = scratch[*id as usize].as_ref().unwrap();
            prop_assert!(k.0.iter().zip(&b.0).all(|(x, y)| x.to_bits() == y.to_bits()));
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(48)))]

    /// After random voxel removals and link severings, the levels updated near the edit give
    /// every element the stiffness a computation from scratch gives, bit for bit. Half the cases
    /// keep every level's nodes current.
    #[test]
    fn a_local_update_equals_a_computation_from_scratch(
        dims in prop::array::uniform3(2usize..14),
        density in 0.4f64..1.0,
        mats in prop::sample::select(vec![1u16, 2]),
        level in 1u32..=3,
        seed in any::<u64>(),
        steps in prop::collection::vec((0usize..10, 0usize..10), 1..4),
    ) {
        let v = random_volume(dims, density, mats, seed);
        check_local_update(&v, mats, level, seed, seed % 2 == 0, &steps)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(12)))]

    /// The same on blocks where a few edits leave most cells of levels 2 and 3 far from them (6
    /// to 10 cells per axis at level 2), every level's nodes kept current: the counts and lists
    /// an update brings up to date from the cells near the edit alone.
    #[test]
    fn a_local_update_on_a_large_block_equals_a_computation_from_scratch(
        dims in prop::array::uniform3(24usize..40),
        density in 0.35f64..0.8,
        level in 2u32..=3,
        seed in any::<u64>(),
        steps in prop::collection::vec((0usize..6, 0usize..6), 1..4),
    ) {
        let v = random_volume(dims, density, 2, seed);
        check_local_update(&v, 2, level, seed, true, &steps)?;
    }
}

/// A grid that starts keeping every level's nodes between two updates numbers them afresh: the
/// levels count their users afresh then, instead of bringing the last counts up to date.
#[test]
fn tracking_nodes_from_the_middle_of_a_run_changes_nothing() {
    let v = random_volume([30, 26, 22], 0.5, 2, 7);
    let mut plain = BranchedGrid::build(&v, &materials(2), 2).unwrap();
    let mut grid = plain.clone();
    let (mut levels, _) = CompositeLevels::new(&grid);
    let mut rng = Rng(11);
    for step in 0..4 {
        let edit = random_edit(&grid, &mut rng, 4, 4);
        let changes = grid.apply(&edit).unwrap();
        plain.apply(&edit).unwrap();
        if step == 1 {
            grid.track_all_nodes();
        }
        levels.update(&grid, &changes.dirty_voxels);
        let scratch = composite_stiffness(&plain);
        let id = first_difference(&levels.stiffness(&grid), &scratch);
        assert!(
            id.is_none(),
            "step {step}: element {id:?} differs from the computation from scratch"
        );
    }
}
