//! Steps the hanging block of scene B (gravity and the corner pull) for profiling (`perf record`), printing the time per step
//! and the CG iterations: `cargo run --release -p incise_fem --example profile_block -- 22,15,12 implicit 0.01 50`.
//! Schemes: `implicit` (Jacobi-CG), `cholesky-cg` (`REFRESH=n` caps the iterations before a
//! refactorisation), `cholesky`, `explicit`, `static` (the static solve, block-Jacobi and with
//! the factor), and `solve-only` (times one factorisation and the
//! triangular solves; `SINGLE=1` keeps the factor in `f32`). `ROT=1` also times 1,000 rotation
//! updates, each after a small turn of the whole block.

use incise_fem::linsolve::cg::CgSettings;
use incise_fem::model::{Loads, State};
use incise_fem::ode::{BackwardEuler, LinearSolver, Rayleigh, explicit_step};
use incise_fem::{FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, Material, MaterialTable};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cells: Vec<usize> = args
        .get(1)
        .map_or("22,15,12", String::as_str)
        .split(',')
        .map(|s| s.parse().expect("cells like 22,15,12"))
        .collect();
    let scheme = args.get(2).map_or("implicit", String::as_str).to_owned();
    let dt: f64 = args.get(3).map_or(0.001, |s| s.parse().expect("dt"));
    let steps: usize = args.get(4).map_or(50, |s| s.parse().expect("steps"));
    let size = [0.15, 0.10, 0.08];
    let spacing = std::array::from_fn(|a| size[a] / cells[a] as f64);
    let v = from_fn([cells[0], cells[1], cells[2]], spacing, |_, _, _| 1);
    let grid =
        BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0)), 0)
            .expect("block grid");
    let model = HexModel::from_grid(&grid);
    let fixed = FixedNodes::plane(&model.rest, 2, size[2], 1e-9);
    // Scene B's loads: gravity and a 0.5 N pull along (1, 1, −1)/√3 spread over the nodes within
    // 22 mm of the corner (0.15, 0.10, 0).
    let mut loads = Loads::gravity([0.0, 0.0, -9.81]);
    let pull = 0.5 / 3f64.sqrt();
    loads.add_patch(&model.rest, [size[0], size[1], 0.0], 0.022, [pull, pull, -pull]);
    let mut ff = HexForceField::new(&model, Formulation::Corotational);
    let damping = Rayleigh { alpha: 2.0, beta: 0.01 };
    let solver = match scheme.as_str() {
        "cholesky-cg" => LinearSolver::CholeskyCg {
            refresh_iterations: std::env::var("REFRESH").map_or(8, |v| v.parse().expect("REFRESH")),
        },
        "cholesky" => LinearSolver::Cholesky,
        _ => LinearSolver::JacobiCg,
    };
    let mut be = BackwardEuler::with_solver(
        dt,
        damping,
        CgSettings { tolerance: 1e-6, max_iterations: 2000 },
        solver,
    );
    if scheme == "static" {
        // The static solve (scene B's reference at 33,22,18), block-Jacobi and with the factor.
        for cholesky in [false, true] {
            let mut ff = HexForceField::new(&model, Formulation::Corotational);
            let mut x = model.rest.clone();
            let start = std::time::Instant::now();
            let report = incise_fem::ode::static_solve_with(
                &model, &mut ff, &fixed, &loads, &mut x, 1e-8, 50, cholesky,
            );
            println!(
                "static, cholesky {cholesky}: {report:?} in {:.2} s",
                start.elapsed().as_secs_f64()
            );
        }
        return;
    }
    if scheme == "solve-only" {
        let precision = if std::env::var("SINGLE").is_ok() {
            incise_fem::linsolve::cholesky::Precision::Single
        } else {
            incise_fem::linsolve::cholesky::Precision::Double
        };
        let mut f =
            incise_fem::linsolve::cholesky::SystemFactor::with_precision(&model, &fixed, precision)
                .expect("pattern");
        let start = std::time::Instant::now();
        f.factorize(&model, &ff, 1.0, dt * dt).expect("factor");
        println!(
            "factor: {} entries, {:.3e} work, {:.1} ms",
            f.factor_entries(),
            f.factor_work(),
            1e3 * start.elapsed().as_secs_f64()
        );
        let r = vec![[1.0, 2.0, 3.0]; model.node_count()];
        let mut z = r.clone();
        let start = std::time::Instant::now();
        for _ in 0..steps {
            f.solve(&r, &mut z);
        }
        println!(
            "{} dofs, {} nonzeros in the matrix: {:.1} µs per solve",
            model.dof_count(),
            f.nonzeros(),
            1e6 * start.elapsed().as_secs_f64() / steps as f64
        );
        return;
    }
    let mut state = State::at_rest(&model);
    let start = std::time::Instant::now();
    let mut iterations = 0;
    let mut stages = [0u64; 3];
    for _ in 0..steps {
        if scheme == "explicit" {
            explicit_step(&model, &mut ff, &fixed, &loads, damping.alpha, dt, &mut state);
        } else {
            iterations += be.step(&model, &mut ff, &fixed, &loads, &mut state).iterations;
            let t = be.stage_times;
            for (s, v) in stages.iter_mut().zip([t.rotations_ns, t.solve_ns, t.update_ns]) {
                *s += v;
            }
        }
    }
    let s = start.elapsed().as_secs_f64();
    if std::env::var("ROT").is_ok() {
        let mut x = state.x.clone();
        let t = std::time::Instant::now();
        for i in 0..1000 {
            let a = 1e-5 * (i as f64).sin();
            for p in &mut x {
                p[0] += a * p[1];
                p[1] -= a * p[0];
            }
            ff.update_rotations(&model, &x);
        }
        println!(
            "update_rotations with a small turn each call: {:.1} µs",
            t.elapsed().as_secs_f64() * 1e3
        );
    }

    println!(
        "{} elements, {scheme}, dt {dt}: {:.3} ms/step, {:.1} steps/s, {:.1} CG iterations/step, {} factorisations",
        model.elements.len(),
        1e3 * s / steps as f64,
        steps as f64 / s,
        iterations as f64 / steps as f64,
        be.factorizations()
    );
    if scheme != "explicit" {
        let per = |ns: u64| ns as f64 * 1e-3 / steps as f64;
        println!(
            "stages per step: rotations {:.1} µs, right-hand side and solve {:.1} µs, update {:.1} µs",
            per(stages[0]),
            per(stages[1]),
            per(stages[2])
        );
    }
}
