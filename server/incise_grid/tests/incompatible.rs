//! Incompatible-mode elements (`incise_grid::incompatible`) against known answers: a coarse cell
//! bent purely reproduces the exact bending energy (the trilinear condensed cell does not: it
//! locks), rigid motions cost nothing, every constant strain gives the condensed element's forces
//! (the patch test, partly filled cells included), and no element is stiffer than the condensed
//! one or of negative energy.

use incise_grid::hex8::{Mat24, corner, rigid_modes};
use incise_grid::incompatible::incompatible_stiffness;
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, LabelVolume, Material, MaterialTable};

const YOUNGS: f64 = 3e3;
const POISSON: f64 = 0.45;

fn grid(volume: &LabelVolume, level: u32) -> BranchedGrid {
    let table = MaterialTable::uniform(&[1], Material::new(YOUNGS, POISSON, 1000.0));
    BranchedGrid::build(volume, &table, level).unwrap()
}

fn energy(k: &Mat24, u: &[f64; 24]) -> f64 {
    let ku = k.mul_vec(u);
    ku.iter().zip(u).map(|(a, b)| a * b).sum::<f64>() / 2.0
}

/// Corner positions of a cell of edge lengths `size`, from its centre.
fn corners(size: [f64; 3]) -> [[f64; 3]; 8] {
    std::array::from_fn(|c| std::array::from_fn(|a| (corner(c)[a] as f64 - 0.5) * size[a]))
}

#[test]
fn a_cell_bent_purely_stores_the_exact_energy() {
    // One level-2 cell of 4 × 4 × 4 voxels of 1 × 1.5 × 2 mm.
    let volume = from_fn([4, 4, 4], [1e-3, 1.5e-3, 2e-3], |_, _, _| 1);
    let grid = grid(&volume, 2);
    let (id, _) = grid.top().elements().next().unwrap();
    let size = grid.element_size();
    let enriched = incompatible_stiffness(&grid);
    let k = enriched[id as usize].as_ref().unwrap();
    let condensed = &grid.matrices(id).unwrap().stiffness;
    // Pure bending about y with curvature κ: σ_xx = E κ z and no other stress, from
    // u = (κxz, −νκyz, −κ(x² + ν(z² − y²))/2); energy ½ E κ² ∫ z² dV.
    let kappa = 2.0;
    let u: [f64; 24] = {
        let p = corners(size);
        std::array::from_fn(|i| {
            let [x, y, z] = p[i / 3];
            match i % 3 {
                0 => kappa * x * z,
                1 => -POISSON * kappa * y * z,
                _ => -kappa * (x * x + POISSON * (z * z - y * y)) / 2.0,
            }
        })
    };
    let exact = 0.5 * YOUNGS * kappa * kappa * size[0] * size[1] * size[2].powi(3) / 12.0;
    let (ei, ec) = (energy(k, &u), energy(condensed, &u));
    println!(
        "pure bending: exact {exact:.6e} J, incompatible modes {ei:.6e}, condensed {ec:.6e} ({:.2}×)",
        ec / exact
    );
    assert!((ei - exact).abs() <= 1e-10 * exact, "incompatible modes: {ei:e} against {exact:e}");
    assert!(
        ec > 1.5 * exact,
        "the trilinear cell should lock in bending: {ec:e} against {exact:e}"
    );
}

/// A 16 × 12 × 16 block of 1 mm voxels with a hole along y and a sloped face: partly filled
/// cells at every level.
fn holed_block() -> LabelVolume {
    from_fn([16, 12, 16], [1e-3; 3], |x, _, z| {
        let hole = (x + 0.5 - 6.0).powi(2) + (z + 0.5 - 9.0).powi(2) < 8.0;
        u16::from(!hole && x + 0.5 < 15.0 - 0.4 * z)
    })
}

#[test]
fn rigid_motions_and_constant_strains_match_the_condensed_element_and_nothing_is_stiffer() {
    let volume = holed_block();
    for level in 1..=3 {
        let grid = grid(&volume, level);
        let enriched = incompatible_stiffness(&grid);
        let size = grid.element_size();
        let mut softer = 0;
        let mut count = 0;
        for (id, _) in grid.top().elements() {
            let k = enriched[id as usize].as_ref().unwrap();
            let condensed = &grid.matrices(id).unwrap().stiffness;
            let scale = condensed.frobenius();
            for mode in rigid_modes(size) {
                let f = k.mul_vec(&mode);
                let len = mode.iter().map(|x| x * x).sum::<f64>().sqrt();
                let norm = f.iter().map(|x| x * x).sum::<f64>().sqrt();
                assert!(
                    norm <= 1e-11 * scale * len,
                    "level {level}, element {id}: |K r| = {norm:e}"
                );
            }
            // Constant strains: u = G x for the nine unit matrices G.
            let p = corners(size);
            for g in 0..9 {
                let u: [f64; 24] =
                    std::array::from_fn(|i| if i % 3 == g / 3 { p[i / 3][g % 3] } else { 0.0 });
                let (fi, fc) = (k.mul_vec(&u), condensed.mul_vec(&u));
                let diff = fi.iter().zip(&fc).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
                let norm = fc.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
                assert!(
                    diff <= 1e-9 * norm,
                    "level {level}, element {id}, strain {g}: patch test off by {:e}",
                    diff / norm
                );
            }
            // Energy bounds on the corner displacements of a few bent fields.
            for (j, kappa) in [1.0, -0.5, 2.0].iter().enumerate() {
                let u: [f64; 24] = std::array::from_fn(|i| {
                    let [x, y, z] = p[i / 3];
                    let a = (i % 3 + j) % 3;
                    kappa * [x * y, y * z, z * x][a] + 0.1 * [x, y, z][(a + 1) % 3]
                });
                let (ei, ec) = (energy(k, &u), energy(condensed, &u));
                let tol = 1e-11 * scale * 24.0;
                assert!(
                    ei >= -tol && ei <= ec + tol,
                    "level {level}, element {id}: {ei:e} against {ec:e}"
                );
                softer += usize::from(ei < ec * (1.0 - 1e-6));
                count += 1;
            }
        }
        println!("level {level}: {softer} of {count} bent fields softer than condensed");
        assert!(softer * 2 > count, "level {level}: the bubbles do nothing");
    }
}
