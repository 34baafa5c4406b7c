//! Jeřábková 2010 §2.2: direct condensation against the recursive scheme, against the coarse
//! hexahedron computed directly, and the physical invariants every condensed element must keep.
//!
//! Tolerances: all compared quantities are sums of the same exact-in-exact-arithmetic terms in a
//! different order, so they differ by rounding only: ~1e-16 per addition times at most a few
//! thousand additions. 1e-12 relative leaves two orders of magnitude of margin and still catches
//! any missing or doubled voxel (which changes K by ≥ 1/8^L ≥ 2.4e-4 relative).

mod common;

use common::{materials, random_volume};
use incise_grid::hex8::{hex_mass, hex_stiffness, rigid_modes};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, Material, MaterialTable};
use proptest::prelude::*;

fn max_direct_vs_recursive(grid: &BranchedGrid) -> f64 {
    let rec = grid.condense_recursive();
    let mut worst = 0.0f64;
    for (id, _) in grid.top().elements() {
        let d = grid.matrices(id).expect("matrices of a live element");
        let r = rec[id as usize].as_ref().expect("recursive matrices");
        let dk = d.stiffness.frobenius_diff(&r.stiffness) / r.stiffness.frobenius();
        let dm = incise_grid::hex8::mat8_frobenius_diff(&d.mass, &r.mass)
            / incise_grid::hex8::mat8_frobenius(&r.mass);
        worst = worst.max(dk).max(dm);
    }
    worst
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(48)))]

    #[test]
    fn direct_equals_recursive(
        dims in prop::array::uniform3(1usize..14),
        density in 0.2f64..1.0,
        mats in prop::sample::select(vec![1u16, 3]),
        level in 1u32..=3,
        seed in any::<u64>(),
    ) {
        let v = random_volume(dims, density, mats, seed);
        let grid = BranchedGrid::build(&v, &materials(mats), level).unwrap();
        let worst = max_direct_vs_recursive(&grid);
        prop_assert!(worst <= 1e-12, "direct vs recursive differ by {worst:e}");
    }
}

#[test]
fn direct_equals_recursive_at_level_4() {
    // Level 4 (4096 voxels per cell) separately: its product table is the expensive one.
    for (seed, mats, density) in [(1u64, 1u16, 0.97), (2, 3, 0.97), (3, 1, 0.6), (4, 3, 0.85)] {
        let v = random_volume([19, 17, 18], density, mats, seed);
        let grid = BranchedGrid::build(&v, &materials(mats), 4).unwrap();
        let worst = max_direct_vs_recursive(&grid);
        assert!(
            worst <= 1e-12,
            "seed {seed}, {mats} materials: direct vs recursive differ by {worst:e}"
        );
    }
}

#[test]
fn full_cell_equals_the_coarse_hexahedron() {
    let h = [1e-3, 1.5e-3, 2e-3];
    let m = Material::new(3e3, 0.45, 1000.0);
    for level in 1..=4u32 {
        let n = 1usize << level;
        let v = from_fn([n; 3], h, |_, _, _| 1);
        let grid = BranchedGrid::build(&v, &MaterialTable::uniform(&[1], m), level).unwrap();
        assert_eq!(grid.top().element_count(), 1);
        let (k, mass, steps) = grid.condense_direct_with_steps(0);
        assert_eq!(steps, 1, "a full cell is one condensation step (eq. 2)");
        let size = grid.element_size();
        let kd = hex_stiffness(size, m.youngs_modulus, m.poisson_ratio);
        let md = hex_mass(size, m.density);
        let dk = k.frobenius_diff(&kd) / kd.frobenius();
        let dm = incise_grid::hex8::mat8_frobenius_diff(&mass, &md)
            / incise_grid::hex8::mat8_frobenius(&md);
        assert!(dk <= 1e-12 && dm <= 1e-12, "level {level}: K differs by {dk:e}, M by {dm:e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(common::cases(32)))]

    #[test]
    fn condensed_elements_keep_rigid_modes_and_mass(
        dims in prop::array::uniform3(1usize..14),
        density in 0.2f64..1.0,
        mats in prop::sample::select(vec![1u16, 3]),
        level in 0u32..=3,
        seed in any::<u64>(),
    ) {
        let v = random_volume(dims, density, mats, seed);
        let table = materials(mats);
        let grid = BranchedGrid::build(&v, &table, level).unwrap();
        let modes = rigid_modes(grid.element_size());
        let voxel_volume: f64 = grid.spacing().iter().product();
        for (id, _) in grid.top().elements() {
            let mats_e = grid.matrices(id).unwrap();
            let kf = mats_e.stiffness.frobenius();
            for (i, r) in modes.iter().enumerate() {
                let f = mats_e.stiffness.mul_vec(r);
                let fr = f.iter().map(|x| x * x).sum::<f64>().sqrt();
                let rn = r.iter().map(|x| x * x).sum::<f64>().sqrt();
                prop_assert!(fr <= 1e-12 * kf * rn, "element {id}: rigid mode {i} gives force {fr:e} (scale {:e})", kf * rn);
            }
            // Σ m_ab = ρV: H·1 = 1 carries each voxel's mass unchanged to the coarse nodes.
            let expected: f64 = grid
                .element_voxels(id)
                .iter()
                .map(|&v| grid.materials().nth(usize::from(grid.fine().material(v).unwrap())).unwrap().1.density * voxel_volume)
                .sum();
            let total: f64 = mats_e.mass.iter().sum();
            prop_assert!((total - expected).abs() <= 1e-13 * expected, "element {id}: mass {total:e} vs ρV {expected:e}");
            let lumped: f64 = mats_e.lumped_mass.iter().sum();
            prop_assert!((lumped - expected).abs() <= 1e-13 * expected);
        }
    }
}
