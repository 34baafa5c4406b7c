//! The sparse Cholesky factor of `a·M + b·K` in nested-dissection order, with our own supernodal
//! substitutions: it solves the system, in `f32` it is a close preconditioner, and the two halves
//! of the dissection give the same bits on one thread and on two.

use incise_fem::linsolve::cholesky::{Precision, SystemFactor};
use incise_fem::{Executor, FixedNodes, Formulation, HexForceField, HexModel, Idle};
use incise_math::Vec3;

mod common;
use common::{SIZE, block};

/// A deformed state, so the rotations are not all identity.
fn twisted(model: &HexModel) -> HexForceField {
    let mut ff = HexForceField::new(model, Formulation::Corotational);
    let x: Vec<Vec3> = model
        .rest
        .iter()
        .map(|p| {
            let t = 0.8 * (SIZE[2] - p[2]) / SIZE[2];
            let (s, c) = t.sin_cos();
            [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]
        })
        .collect();
    ff.update_rotations(model, &x);
    ff
}

/// `‖(a·M + b·K) z − r‖ / ‖r‖` over the free nodes.
fn residual(
    model: &HexModel,
    ff: &HexForceField,
    fixed: &FixedNodes,
    a: f64,
    b: f64,
    r: &[Vec3],
    z: &[Vec3],
) -> f64 {
    let mut az: Vec<Vec3> =
        (0..model.node_count()).map(|i| z[i].map(|c| a * model.lumped_mass[i] * c)).collect();
    ff.add_stiffness_times(model, b, z, &mut az);
    let (mut num, mut den) = (0.0, 0.0);
    for i in (0..model.node_count()).filter(|&i| !fixed.is_fixed(i)) {
        for k in 0..3 {
            num += (az[i][k] - r[i][k]).powi(2);
            den += r[i][k].powi(2);
        }
    }
    (num / den).sqrt()
}

fn load(n: usize) -> Vec<Vec3> {
    (0..n).map(|i| [((i * 37) % 11) as f64 - 5.0, ((i * 13) % 7) as f64 - 3.0, 1.0]).collect()
}

#[test]
fn the_factor_solves_the_system_and_the_single_precision_one_is_close() {
    let (model, fixed) = block([9, 6, 5]);
    let ff = twisted(&model);
    let (a, b) = (1.02, 2e-4);
    let r = load(model.node_count());
    let mut z = vec![[0.0; 3]; model.node_count()];
    let mut exact = SystemFactor::new(&model, &fixed).unwrap();
    exact.factorize(&model, &ff, a, b).unwrap();
    exact.solve(&r, &mut z);
    let double = residual(&model, &ff, &fixed, a, b, &r, &z);
    let mut single = SystemFactor::with_precision(&model, &fixed, Precision::Single).unwrap();
    single.factorize(&model, &ff, a, b).unwrap();
    single.solve(&r, &mut z);
    let float = residual(&model, &ff, &fixed, a, b, &r, &z);
    println!("relative residual: f64 factor {double:.2e}, f32 factor {float:.2e}");
    // f64: rounding times a modest condition number. f32: 6e-8 rounding per entry times the same
    // condition number; CG only needs a preconditioner this close.
    assert!(double < 1e-10, "f64 residual {double:e}");
    assert!(float < 1e-4, "f32 residual {float:e}");
    assert!(
        z.iter().enumerate().all(|(i, v)| !fixed.is_fixed(i) || v.iter().all(|c| c.to_bits() == 0))
    );
}

#[test]
fn the_halves_of_the_dissection_give_the_same_bits_on_one_and_two_threads() {
    // 22 × 15 × 12 (scene B3): a factor of over a million entries, solved in two halves.
    let (model, fixed) = block([22, 15, 12]);
    let ff = twisted(&model);
    let (a, b) = (1.02, 2e-4);
    let r = load(model.node_count());
    let solve = |threads: usize| {
        let mut factor = SystemFactor::with_precision(&model, &fixed, Precision::Single)
            .unwrap()
            .with_executor(Executor::new(threads, Idle::DEFAULT_SPIN));
        factor.factorize(&model, &ff, a, b).unwrap();
        assert!(factor.runs_in_halves(), "the top dissection splits the supernodes");
        assert!(factor.factor_entries() > 1_000_000);
        let mut z = vec![[0.0; 3]; model.node_count()];
        factor.solve(&r, &mut z);
        (z, factor.factor_entries())
    };
    let ((one, entries), (two, _)) = (solve(1), solve(2));
    assert!(
        one.iter().flatten().zip(two.iter().flatten()).all(|(p, q)| p.to_bits() == q.to_bits())
    );
    let float = residual(&model, &ff, &fixed, a, b, &r, &one);
    println!("B3 f32 factor: {entries} entries, relative residual {float:.2e}");
    assert!(float < 1e-4, "f32 residual {float:e}");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
    /// On random branched grids (holes, fragments, superimposed nodes, levels 0–2; a third of
    /// them big enough for a supernodal factor split in halves) the
    /// nested-dissection factor still solves the system: the order is a valid elimination order
    /// whatever the node layout.
    #[test]
    fn the_factor_solves_random_branched_grids(
        dims in proptest::array::uniform3(3usize..12),
        level in 0u32..3,
        seed in proptest::prelude::any::<u64>(),
    ) {
        use incise_grid::procedural::from_fn;
        use incise_grid::{BranchedGrid, Material, MaterialTable};
        // Voxel indices arrive as f64 voxel coordinates.
        let occupied = |x: f64, y: f64, z: f64| {
            let (x, y, z) = (x as u64, y as u64, z as u64);
            let h = (x * 73_856_093) ^ (y * 19_349_663) ^ (z * 83_492_791) ^ seed;
            u16::from(h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 62 != 0)
        };
        let v = from_fn(dims, [0.01; 3], occupied);
        let table = MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0));
        let Ok(grid) = BranchedGrid::build(&v, &table, level) else { return Ok(()) };
        let model = HexModel::from_grid(&grid);
        if model.node_count() == 0 {
            return Ok(());
        }
        let top = model.rest.iter().map(|p| p[2]).fold(f64::MIN, f64::max);
        let fixed = FixedNodes::plane(&model.rest, 2, top, 1e-9);
        let ff = twisted(&model);
        let (a, b) = (1.0, 1e-3);
        let r = load(model.node_count());
        let mut z = vec![[0.0; 3]; model.node_count()];
        let mut factor = SystemFactor::new(&model, &fixed).unwrap();
        factor.factorize(&model, &ff, a, b).unwrap();
        factor.solve(&r, &mut z);
        let res = residual(&model, &ff, &fixed, a, b, &r, &z);
        proptest::prop_assert!(res < 1e-9, "residual {res:e} on {dims:?} level {level}");
    }
}
