//! `incise-bench multigrid`: the branched grid's levels as a multigrid preconditioner
//! (`incise_fem::linsolve::multigrid`) against block-Jacobi CG and sparse Cholesky, on the liver
//! hanging from its hold under gravity at its finest levels.
//!
//! Each system is solved from zero to `‖r‖ ≤ 1e-8 ‖b‖` with the linear stiffness (the rotations
//! at rest): the static one `K u = f` and the implicit step's `(M + h² K) Δv = h f` at
//! h = 1 ms and 10 ms. Every solver runs on one executor (the machine's cores, at most two;
//! `INCISE_THREADS` sets it). The fine level's operator product (one element loop) is timed too:
//! no preconditioner makes an iteration cheaper than that.

use super::{hierarchy_of, liver_levels, supported_volume};
use anyhow::{Context, bail};
use incise_fem::linsolve::SystemFactor;
use incise_fem::linsolve::cg::{self, CgSettings, block_jacobi};
use incise_fem::linsolve::jacobi::preconditioner;
use incise_fem::{Formulation, HexForceField};
use incise_math::Vec3;
use incise_sim::config::ExecSpec;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `incise-bench multigrid`.
#[derive(clap::Args, Debug)]
pub struct MultigridArgs {
    /// Folder of the scene files (`liver_13k.toml`, `liver_109k.toml`).
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Scenes to run, comma-separated: `liver_13k`, `liver_109k` (364,668 unknowns at level 0;
    /// its Cholesky factor takes a few GB).
    #[arg(long, value_delimiter = ',', default_value = "liver_13k")]
    scenes: Vec<String>,
    /// The finest level solved (the multigrid's first level).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// The multigrid's coarsest levels to try, comma-separated (each above `--level`).
    #[arg(long, value_delimiter = ',', default_value = "2,3")]
    coarsest: Vec<u32>,
    /// Smoothing sweeps before and after each coarse correction.
    #[arg(long, default_value_t = 2)]
    sweeps: usize,
    /// End with one line holding one JSON object `{"rows":[…]}`.
    #[arg(long)]
    json: bool,
}

/// One solve.
#[derive(Debug, Serialize)]
struct Row {
    scene: String,
    level: u32,
    dofs: usize,
    /// `static`, `implicit-1ms`, `implicit-10ms`.
    system: String,
    /// `jacobi-cg`, `cholesky`, `multigrid-L<coarsest>`.
    solver: String,
    iterations: usize,
    /// Building the preconditioner (factorisation, hierarchy) (ms).
    setup_ms: f64,
    /// The CG solve (ms).
    solve_ms: f64,
    /// `|u − u_cholesky| / |u_cholesky|`.
    difference: f64,
}

/// Runs the comparison.
pub fn run(args: &MultigridArgs) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    let exec = incise_scene::environment::exec_from_environment(ExecSpec::default())?.executor();
    for scene in &args.scenes {
        if !["liver_13k", "liver_109k"].contains(&scene.as_str()) {
            bail!("--scenes: unknown scene {scene:?}; expected liver_13k or liver_109k");
        }
        if let Some(&c) = args.coarsest.iter().find(|&&c| c <= args.level) {
            bail!("--coarsest {c} is not above --level {}", args.level);
        }
        let supported = supported_volume(&args.scene_dir, &format!("{scene}.toml"))?;
        let top = args.coarsest.iter().copied().max().unwrap_or(args.level);
        eprintln!("{scene}: building levels {} to {top} …", args.level);
        let sims = liver_levels(&supported, args.level, top)?;
        let fine = &sims[0];
        let model = fine.model().context("a hexahedral scene")?;
        let fixed = fine.fixed();
        let field = HexForceField::new(model, Formulation::Linear).with_executor(exec.clone());
        let mut gravity = vec![[0.0; 3]; model.node_count()];
        fine.loads().context("a hexahedral scene")?.add_to(model, &mut gravity);

        // The floor: one fine operator product.
        let mut out = vec![[0.0; 3]; model.node_count()];
        let t = Instant::now();
        let products = 20;
        for _ in 0..products {
            out.fill([0.0; 3]);
            field.add_stiffness_times(model, 1.0, &gravity, &mut out);
        }
        let product_ms = t.elapsed().as_secs_f64() * 1e3 / f64::from(products);
        println!(
            "{scene} level {}: {} unknowns; one operator product {product_ms:.3} ms ({} threads, as every solver below)",
            args.level,
            model.dof_count(),
            exec.threads()
        );

        for (system, a, h) in
            [("static", 0.0, 1.0), ("implicit-1ms", 1.0, 1e-3), ("implicit-10ms", 1.0, 1e-2)]
        {
            let b_scale = if a == 0.0 { 1.0 } else { h };
            let rhs: Vec<Vec3> = gravity.iter().map(|g| g.map(|v| b_scale * v)).collect();
            let stiffness = if a == 0.0 { 1.0 } else { h * h };
            let apply = |p: &[Vec3], out: &mut [Vec3]| {
                for ((o, q), &m) in out.iter_mut().zip(p).zip(&model.lumped_mass) {
                    *o = q.map(|v| a * m * v);
                }
                field.add_stiffness_times(model, stiffness, p, out);
            };
            let settings = CgSettings { tolerance: 1e-8, max_iterations: 100_000 };
            let mut record = |solver: String, iterations, setup_ms, solve_ms, difference| {
                let row = Row {
                    scene: scene.clone(),
                    level: args.level,
                    dofs: model.dof_count(),
                    system: system.into(),
                    solver,
                    iterations,
                    setup_ms,
                    solve_ms,
                    difference,
                };
                println!(
                    "  {:<14} {:<14} {:>6} iterations  setup {:>9.1} ms  solve {:>9.1} ms  |Δu|/|u| {:.1e}",
                    row.system,
                    row.solver,
                    row.iterations,
                    row.setup_ms,
                    row.solve_ms,
                    row.difference
                );
                rows.push(row);
            };

            // Sparse Cholesky: the answer the others are compared with.
            let t = Instant::now();
            let mut factor = SystemFactor::new(model, fixed)?.with_executor(exec.clone());
            factor.factorize(model, &field, a, stiffness)?;
            let setup = t.elapsed().as_secs_f64() * 1e3;
            let mut exact = vec![[0.0; 3]; model.node_count()];
            let t = Instant::now();
            let report =
                cg::solve(apply, |r, z| factor.solve(r, z), fixed, &rhs, &mut exact, settings);
            let solve = t.elapsed().as_secs_f64() * 1e3;
            record("cholesky".into(), report.iterations, setup, solve, 0.0);
            drop(factor);
            let difference = |u: &[Vec3]| {
                let d: f64 = u
                    .iter()
                    .zip(&exact)
                    .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).powi(2)))
                    .sum();
                let n: f64 = exact.iter().flat_map(|q| q.iter().map(|v| v * v)).sum();
                (d / n).sqrt()
            };

            let t = Instant::now();
            let blocks = preconditioner(model, &field, &model.lumped_mass, a, stiffness);
            let setup = t.elapsed().as_secs_f64() * 1e3;
            let mut u = vec![[0.0; 3]; model.node_count()];
            let t = Instant::now();
            let report = cg::solve(apply, block_jacobi(&blocks), fixed, &rhs, &mut u, settings);
            let solve = t.elapsed().as_secs_f64() * 1e3;
            record("jacobi-cg".into(), report.iterations, setup, solve, difference(&u));

            for &coarsest in &args.coarsest {
                let t = Instant::now();
                let levels = &sims[..=(coarsest - args.level) as usize];
                let mg =
                    hierarchy_of(levels, Formulation::Linear, (a, stiffness), args.sweeps, &exec)?;
                let setup = t.elapsed().as_secs_f64() * 1e3;
                let mut u = vec![[0.0; 3]; model.node_count()];
                let t = Instant::now();
                let report =
                    cg::solve(apply, |r, z| mg.precondition(r, z), fixed, &rhs, &mut u, settings);
                let solve = t.elapsed().as_secs_f64() * 1e3;
                record(
                    format!("multigrid-L{coarsest}"),
                    report.iterations,
                    setup,
                    solve,
                    difference(&u),
                );
            }
        }
    }
    if args.json {
        println!("{}", serde_json::json!({ "rows": rows }));
    }
    Ok(())
}
