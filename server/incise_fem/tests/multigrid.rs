//! The branched grid's levels as a multigrid preconditioner: the prolongation reproduces linear
//! fields, the V-cycle is symmetric and positive, and CG with it reaches the sparse Cholesky
//! answer in iterations that do not grow as the voxels are refined, while block-Jacobi's do.

use incise_fem::linsolve::SystemFactor;
use incise_fem::linsolve::cg::{self, CgSettings, block_jacobi};
use incise_fem::linsolve::jacobi::preconditioner;
use incise_fem::linsolve::multigrid::{LevelSpec, Multigrid, Prolongation};
use incise_fem::model::Loads;
use incise_fem::{Executor, FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::procedural::{TISSUE, TUMOUR, ellipsoid_with_inclusion};
use incise_grid::{BranchedGrid, Material, MaterialTable};
use incise_math::Vec3;

/// An ellipsoid 0.1 m across in `n` voxels per axis with a stiffer, nearly incompressible
/// inclusion, at levels 0..=`top`, held near its bottom.
fn hierarchy_of(n: usize, top: u32) -> Vec<(BranchedGrid, HexModel, FixedNodes)> {
    let v = ellipsoid_with_inclusion(n, 0.1 / n as f64);
    let mut table = MaterialTable::new();
    table.insert(TISSUE, Material::new(3e3, 0.45, 1000.0));
    table.insert(TUMOUR, Material::new(3e4, 0.49, 1000.0));
    (0..=top)
        .map(|level| {
            let grid = BranchedGrid::build(&v, &table, level).unwrap();
            let model = HexModel::from_grid(&grid);
            let fixed = FixedNodes::by_position(&model.rest, |p| p[2] < 0.02);
            (grid, model, fixed)
        })
        .collect()
}

fn hierarchy() -> Vec<(BranchedGrid, HexModel, FixedNodes)> {
    hierarchy_of(20, 3)
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p[0] * q[0] + p[1] * q[1] + p[2] * q[2]).sum()
}

#[test]
fn the_prolongation_reproduces_linear_fields() {
    let levels = hierarchy();
    for pair in levels.windows(2) {
        let [(fg, fine, _), (cg, coarse, _)] = pair else { unreachable!() };
        let p = Prolongation::new(fg, fine, cg, coarse).unwrap();
        // A linear field sampled at the coarse nodes comes back exactly at the fine ones.
        let field = |x: &Vec3| [0.3 * x[0] - x[2], 2.0 * x[1] + 0.1, x[0] + x[1] + x[2]];
        let on_coarse: Vec<Vec3> = coarse.rest.iter().map(field).collect();
        let mut on_fine = vec![[0.0; 3]; fine.node_count()];
        p.add_prolonged(&on_coarse, &mut on_fine);
        let worst = fine
            .rest
            .iter()
            .zip(&on_fine)
            .map(|(x, u)| (0..3).map(|k| (field(x)[k] - u[k]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        assert!(worst < 1e-12, "level {}: {worst:e}", fg.top_level());
        // Restriction is its transpose: ⟨P c, f⟩ = ⟨c, Pᵀ f⟩.
        let f: Vec<Vec3> = (0..fine.node_count()).map(|i| [i as f64 % 3.0, 1.0, -0.5]).collect();
        let mut r = vec![[0.0; 3]; coarse.node_count()];
        p.restrict(&f, &mut r);
        let (lhs, rhs) = (dot(&on_fine, &f), dot(&on_coarse, &r));
        assert!((lhs - rhs).abs() <= 1e-12 * lhs.abs(), "{lhs} {rhs}");
    }
}

#[test]
fn the_coarse_stiffness_is_the_galerkin_product_of_the_fine_one() {
    // Condensation is the Galerkin product with the same trilinear interpolation: on a body
    // without branched cells, Pᵀ K_l P = K_{l+1} up to rounding.
    let levels = hierarchy();
    for pair in levels.windows(2) {
        let [(fg, fine, _), (cg, coarse, _)] = pair else { unreachable!() };
        let p = Prolongation::new(fg, fine, cg, coarse).unwrap();
        let (kf, kc) = (
            HexForceField::new(fine, Formulation::Linear),
            HexForceField::new(coarse, Formulation::Linear),
        );
        let v: Vec<Vec3> = (0..coarse.node_count())
            .map(|i| std::array::from_fn(|k| (((i * 5 + k * 11) % 13) as f64) - 6.0))
            .collect();
        let mut pv = vec![[0.0; 3]; fine.node_count()];
        p.add_prolonged(&v, &mut pv);
        let mut kpv = vec![[0.0; 3]; fine.node_count()];
        kf.add_stiffness_times(fine, 1.0, &pv, &mut kpv);
        let mut galerkin = vec![[0.0; 3]; coarse.node_count()];
        p.restrict(&kpv, &mut galerkin);
        let mut direct = vec![[0.0; 3]; coarse.node_count()];
        kc.add_stiffness_times(coarse, 1.0, &v, &mut direct);
        let diff: Vec<Vec3> = galerkin
            .iter()
            .zip(&direct)
            .map(|(a, b)| std::array::from_fn(|k| a[k] - b[k]))
            .collect();
        let rel = (dot(&diff, &diff) / dot(&direct, &direct)).sqrt();
        println!("level {}: |Pᵀ K P v − K_c v| / |K_c v| = {rel:.1e}", cg.top_level());
        assert!(rel < 1e-10, "level {}: {rel:e}", cg.top_level());
    }
}

/// CG iterations to 1e-10 with block-Jacobi and with the multigrid on `levels`, after checking
/// that the multigrid is symmetric and positive and that its answer is Cholesky's.
fn iterations(levels: &[(BranchedGrid, HexModel, FixedNodes)]) -> (usize, usize) {
    let (_, model, fixed) = &levels[0];
    let field = HexForceField::new(model, Formulation::Linear);
    let mut b = vec![[0.0; 3]; model.node_count()];
    Loads::gravity([0.0, 0.0, -9.81]).add_to(model, &mut b);
    let apply = |p: &[Vec3], out: &mut [Vec3]| {
        out.fill([0.0; 3]);
        field.add_stiffness_times(model, 1.0, p, out);
    };
    let settings = CgSettings { tolerance: 1e-10, max_iterations: 100_000 };

    let mut factor = SystemFactor::new(model, fixed).unwrap();
    factor.factorize(model, &field, 0.0, 1.0).unwrap();
    let mut exact = vec![[0.0; 3]; model.node_count()];
    cg::solve(apply, |r, z| factor.solve(r, z), fixed, &b, &mut exact, settings);

    let blocks = preconditioner(model, &field, &model.lumped_mass, 0.0, 1.0);
    let mut u = vec![[0.0; 3]; model.node_count()];
    let jacobi = cg::solve(apply, block_jacobi(&blocks), fixed, &b, &mut u, settings);

    let specs = levels
        .iter()
        .map(|(grid, model, fixed)| LevelSpec { grid, model: model.clone(), fixed: fixed.clone() })
        .collect();
    let mg = Multigrid::new(specs, Formulation::Linear, 0.0, 1.0, 2, &Executor::default()).unwrap();

    // Symmetric and positive: CG's requirements of a preconditioner.
    let n = model.node_count();
    let probe = |s: usize| -> Vec<Vec3> {
        let mut v: Vec<Vec3> = (0..n)
            .map(|i| std::array::from_fn(|k| (((i * 13 + k * 7 + s * 5) % 17) as f64) - 8.0))
            .collect();
        fixed.project(&mut v);
        v
    };
    let (r1, r2) = (probe(1), probe(2));
    let (mut z1, mut z2) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
    mg.precondition(&r1, &mut z1);
    mg.precondition(&r2, &mut z2);
    let (a, b12) = (dot(&r2, &z1), dot(&r1, &z2));
    assert!((a - b12).abs() <= 1e-9 * dot(&r1, &z1).abs(), "not symmetric: {a} {b12}");
    assert!(dot(&r1, &z1) > 0.0 && dot(&r2, &z2) > 0.0);

    let mut v = vec![[0.0; 3]; n];
    let multigrid = cg::solve(apply, |r, z| mg.precondition(r, z), fixed, &b, &mut v, settings);
    let norm = dot(&exact, &exact).sqrt();
    let error = |x: &[Vec3]| {
        let d: Vec<Vec3> =
            x.iter().zip(&exact).map(|(p, q)| std::array::from_fn(|k| p[k] - q[k])).collect();
        dot(&d, &d).sqrt() / norm
    };
    println!(
        "levels (nodes, elements) {:?}: block-Jacobi {} iterations (error {:.1e}), multigrid {} (error {:.1e})",
        mg.sizes(),
        jacobi.iterations,
        error(&u),
        multigrid.iterations,
        error(&v)
    );
    assert!(jacobi.converged && error(&u) < 1e-7, "{jacobi:?}");
    assert!(multigrid.converged && error(&v) < 1e-7, "{multigrid:?}");
    (jacobi.iterations, multigrid.iterations)
}

#[test]
fn multigrid_iterations_do_not_grow_as_the_voxels_are_refined() {
    // The same body in voxels half as large, with one more level: the coarsest cells are the
    // same size. Block-Jacobi's iterations grow like 1/h (about twice); a multigrid's should
    // stay about the same.
    let (jacobi_coarse, mg_coarse) = iterations(&hierarchy_of(12, 2));
    let (jacobi_fine, mg_fine) = iterations(&hierarchy_of(24, 3));
    assert!(2 * jacobi_fine > 3 * jacobi_coarse, "{jacobi_coarse} → {jacobi_fine}");
    assert!(4 * mg_fine < 5 * mg_coarse, "{mg_coarse} → {mg_fine}");
    assert!(mg_fine * 4 < jacobi_fine, "{mg_fine} against {jacobi_fine}");
}

#[test]
fn corotational_levels_follow_the_fine_rotations() {
    // The body turned 60° about x: the fine operator is R K Rᵀ per element. A hierarchy whose
    // rotations are taken at the turned positions preconditions it as well as the unturned
    // one does the body at rest; one left at rest does far worse.
    let levels = hierarchy();
    let (_, model, fixed) = &levels[0];
    let (c, s) = (60f64.to_radians().cos(), 60f64.to_radians().sin());
    let x: Vec<Vec3> =
        model.rest.iter().map(|p| [p[0], c * p[1] - s * p[2], s * p[1] + c * p[2]]).collect();
    let mut field = HexForceField::new(model, Formulation::Corotational);
    let mut b = vec![[0.0; 3]; model.node_count()];
    Loads::gravity([0.0, 0.0, -9.81]).add_to(model, &mut b);
    let settings = CgSettings { tolerance: 1e-10, max_iterations: 100_000 };
    let specs = || -> Vec<LevelSpec<'_>> {
        levels
            .iter()
            .map(|(grid, model, fixed)| LevelSpec {
                grid,
                model: model.clone(),
                fixed: fixed.clone(),
            })
            .collect()
    };
    let mut solve_at = |positions: &[Vec3], mg: &Multigrid| {
        field.update_rotations(model, positions);
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            out.fill([0.0; 3]);
            field.add_stiffness_times(model, 1.0, p, out);
        };
        let mut u = vec![[0.0; 3]; model.node_count()];
        let report = cg::solve(apply, |r, z| mg.precondition(r, z), fixed, &b, &mut u, settings);
        assert!(report.converged, "{report:?}");
        report.iterations
    };
    let at_rest =
        Multigrid::new(specs(), Formulation::Corotational, 0.0, 1.0, 2, &Executor::default())
            .unwrap();
    let rest_iterations = solve_at(&model.rest.clone(), &at_rest);
    let stale_iterations = solve_at(&x, &at_rest);
    let mut turned =
        Multigrid::new(specs(), Formulation::Corotational, 0.0, 1.0, 2, &Executor::default())
            .unwrap();
    turned.update(&x).unwrap();
    let turned_iterations = solve_at(&x, &turned);
    println!(
        "iterations: at rest {rest_iterations}, turned with rest rotations {stale_iterations}, turned with its own {turned_iterations}"
    );
    assert!(4 * turned_iterations <= 5 * rest_iterations, "{turned_iterations} {rest_iterations}");
    assert!(2 * turned_iterations < stale_iterations, "{turned_iterations} {stale_iterations}");
}

#[test]
fn static_newton_with_the_multigrid_reaches_the_same_equilibrium() {
    use incise_fem::ode::{static_solve_multigrid, static_solve_with};
    let levels = hierarchy();
    let (_, model, fixed) = &levels[0];
    // Soft enough to turn its elements visibly under its weight.
    let loads = Loads::gravity([0.0, 0.0, -30.0]);
    let solve_jacobi = || {
        let mut ff = HexForceField::new(model, Formulation::Corotational);
        let mut x = model.rest.clone();
        let report = static_solve_with(model, &mut ff, fixed, &loads, &mut x, 1e-9, 50, false);
        (x, report)
    };
    let (reference, jacobi) = solve_jacobi();
    let specs = levels
        .iter()
        .map(|(grid, model, fixed)| LevelSpec { grid, model: model.clone(), fixed: fixed.clone() })
        .collect();
    let mut mg =
        Multigrid::new(specs, Formulation::Corotational, 0.0, 1.0, 2, &Executor::default())
            .unwrap();
    let mut ff = HexForceField::new(model, Formulation::Corotational);
    let mut x = model.rest.clone();
    let report = static_solve_multigrid(model, &mut ff, fixed, &loads, &mut x, 1e-9, 50, &mut mg);
    println!("block-Jacobi {jacobi:?}\nmultigrid {report:?}");
    assert!(jacobi.converged && report.converged, "{jacobi:?} {report:?}");
    let sag = model.centre_of_mass_shift(&reference)[2];
    let difference = model.centre_of_mass_shift(&x)[2] - sag;
    assert!(sag < -1e-3, "{sag}");
    assert!(difference.abs() < 1e-6 * sag.abs(), "{difference} of {sag}");
    assert!(4 * report.cg_iterations < jacobi.cg_iterations, "{report:?} {jacobi:?}");
}
