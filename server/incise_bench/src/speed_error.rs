//! `incise-bench speed-error`: speed against error on BENCHMARKS.md scenes B (hanging block) and
//! C (cantilever) and on the liver, for each model, integrator and dt ∈ {1 ms, 10 ms}.
//!
//! Error is measured, not assumed: a row's error is the static answer of its own mesh and model
//! (which its dynamics settle on, tested in `incise_fem`) against the reference — Euler–Bernoulli
//! for C, a static corotational solve on a mesh twice as fine as B3 for B — and a row is stable
//! when a run of `--stable-seconds` simulated seconds stays finite and bounded. Speed is steps per
//! second of the integrator alone, median/min/max over `--repeats` runs.

use crate::timing::measure;
use anyhow::{Context, bail};
use incise_fem::cg::CgSettings;
use incise_fem::integrate::{
    BackwardEuler, LinearSolver, Loads, Rayleigh, State, explicit_step, stable_dt,
    static_solve_with,
};
use incise_fem::{FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, Material, MaterialTable};
use incise_math::Vec3;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `incise-bench speed-error`.
#[derive(clap::Args, Debug)]
pub struct SpeedErrorArgs {
    /// Scenes to run: `all`, or a comma-separated list of `b1`, `b2`, `b3`, `c`, `liver`.
    #[arg(long, default_value = "all")]
    scene: String,
    /// Skip meshes with more elements than this (quick runs).
    #[arg(long)]
    max_elements: Option<usize>,
    /// Timed steps per run.
    #[arg(long, default_value_t = 50)]
    steps: usize,
    /// Timed runs per row (median, min and max are reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Simulated seconds of the stability check.
    #[arg(long, default_value_t = 0.3)]
    stable_seconds: f64,
    /// Also print the fastest stable configuration whose error is at most this (e.g. 0.05).
    #[arg(long)]
    max_error: Option<f64>,
    /// End with one line holding one JSON object `{"rows":[…]}`.
    #[arg(long)]
    json: bool,
    /// Write the rows as CSV to this file.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
    /// Draw speed against error (log-log) to this PNG.
    #[arg(long, value_name = "PATH")]
    png: Option<PathBuf>,
    /// The table `../shared/peers/bench_mujoco.py S1 S2 S3 nocant` printed, saved to a file (run it
    /// right before or after, on the same machine): its rows get their error against the same
    /// reference, go on the plot, and are compared with our fastest stable row at equal or lower
    /// error and the same dt. `deploy/peers/bench_newton.py`'s table (Newton's semi-implicit
    /// integrator) is read the same way; give `--peers` once per file, or one file holding both.
    #[arg(long, value_name = "PATH")]
    peers: Vec<PathBuf>,
}

/// A peer's point against ours at equal error.
#[derive(Clone, Debug, Serialize)]
struct PeerComparison {
    peer: String,
    scene: String,
    dt: f64,
    steps_per_s: f64,
    /// The peer's error against the scene's reference (`None` when it blew up, or its scene was
    /// not in this run).
    error: Option<f64>,
    /// Whether the peer stayed stable at this dt.
    stable: bool,
    /// Our fastest stable row at the same dt with an error at most the peer's.
    ours: Option<OursAtEqualError>,
    /// Our steps/s over the peer's.
    ratio: Option<f64>,
}

/// The row of ours a peer is compared with.
#[derive(Clone, Debug, Serialize)]
struct OursAtEqualError {
    scene: String,
    resolution: String,
    model: &'static str,
    integrator: &'static str,
    solver: &'static str,
    steps_per_s: f64,
    error: f64,
}

/// One configuration's figures.
#[derive(Clone, Debug, Serialize)]
struct Row {
    scene: String,
    model: &'static str,
    integrator: &'static str,
    solver: &'static str,
    resolution: String,
    level: u32,
    elements: usize,
    dofs: usize,
    dt: f64,
    steps_per_s: f64,
    steps_per_s_min: f64,
    steps_per_s_max: f64,
    error: Option<f64>,
    stable: bool,
}

/// A scene to measure: its model, supports, loads, the quantity compared and its reference.
struct Case {
    scene: String,
    resolution: String,
    level: u32,
    model: HexModel,
    fixed: FixedNodes,
    loads: Loads,
    /// Nodes whose mean displacement along `axis` (or norm, when `None`) is the compared quantity.
    probe: Vec<usize>,
    axis: Option<usize>,
    reference: Option<f64>,
    /// The implicit solvers measured on this scene (each gets its own rows).
    solvers: Vec<LinearSolver>,
    /// Block scenes: the cells per axis, from which the tensor-mass rows build their tetrahedra.
    block_cells: Option<[usize; 3]>,
}

const BLOCK: Vec3 = [0.15, 0.10, 0.08];

fn block_case(name: &str, cells: [usize; 3]) -> Case {
    let spacing = std::array::from_fn(|a| BLOCK[a] / cells[a] as f64);
    let v = from_fn(cells, spacing, |_, _, _| 1);
    let grid =
        BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0)), 0)
            .expect("block grid");
    let model = HexModel::from_grid(&grid);
    let fixed = FixedNodes::plane(&model.rest, 2, BLOCK[2], 1e-9);
    let corner = [BLOCK[0], BLOCK[1], 0.0];
    let dist =
        |n: usize| (0..3).map(|a| (model.rest[n][a] - corner[a]).powi(2)).sum::<f64>().sqrt();
    let mut loads = Loads::gravity([0.0, 0.0, -9.81]);
    let pull = 0.5 / 3f64.sqrt();
    loads.add_patch(&model.rest, corner, 0.022, [pull, pull, -pull]);
    let probe =
        vec![(0..model.node_count()).min_by(|&a, &b| dist(a).total_cmp(&dist(b))).expect("nodes")];
    Case {
        scene: name.into(),
        resolution: format!("{}x{}x{}", cells[0], cells[1], cells[2]),
        level: 0,
        model,
        fixed,
        loads,
        probe,
        axis: None,
        reference: None,
        // Both: Jacobi-CG is the faster when the mass dominates (dt = 1 ms), the Cholesky
        // preconditioner when the stiffness does (dt = 10 ms), until its fill grows too large.
        solvers: vec![LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }],
        block_cells: Some(cells),
    }
}

fn cantilever_case(n: usize) -> Case {
    let (l, w) = (0.1, 0.01);
    let v = from_fn(
        [n, n / 10, n / 10],
        [l / n as f64, w / (n / 10) as f64, w / (n / 10) as f64],
        |_, _, _| 1,
    );
    let grid =
        BranchedGrid::build(&v, &MaterialTable::uniform(&[1], Material::new(1e6, 0.3, 1000.0)), 0)
            .expect("beam grid");
    let model = HexModel::from_grid(&grid);
    let fixed = FixedNodes::plane(&model.rest, 0, 0.0, 1e-12);
    let probe = (0..model.node_count()).filter(|&k| (model.rest[k][0] - l).abs() < 1e-12).collect();
    let eb = 1000.0 * 9.81 * w * w * l.powi(4) / (8.0 * 1e6 * w * w.powi(3) / 12.0);
    Case {
        scene: "C".into(),
        resolution: format!("{n}x{}x{}", n / 10, n / 10),
        level: 0,
        model,
        fixed,
        loads: Loads::gravity([0.0, 0.0, -9.81]),
        probe,
        axis: Some(2),
        reference: Some(eb),
        // A slender beam is ill-conditioned for Jacobi but factorises with little fill.
        solvers: vec![LinearSolver::CholeskyCg { refresh_iterations: 8 }],
        block_cells: None,
    }
}

fn liver_case(name: &str, stride: [usize; 3]) -> anyhow::Result<Case> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/liver.inr.gz");
    let raw = incise_io::read_volume(std::path::Path::new(path))?;
    // Striding leaves a few isolated voxels that would fall free: keep the organ itself.
    let v = raw
        .filtered(&incise_grid::LabelFilter::abdominal_ct())
        .crop_and_stride(stride)?
        .largest_component();
    let grid = BranchedGrid::build(&v, &MaterialTable::abdominal_ct(), 3)?;
    let model = HexModel::from_grid(&grid);
    // Held by its top: every node within one element of the highest node plane.
    let top = model.rest.iter().map(|p| p[2]).fold(0.0, f64::max);
    let fixed =
        FixedNodes::by_position(&model.rest, |p| p[2] >= top - model.element_size[2] - 1e-9);
    Ok(Case {
        scene: name.into(),
        resolution: format!("stride {},{},{}", stride[0], stride[1], stride[2]),
        level: 3,
        model,
        fixed,
        loads: Loads::gravity([0.0, 0.0, -9.81]),
        probe: Vec::new(),
        axis: None,
        reference: None,
        solvers: vec![LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }],
        block_cells: None,
    })
}

/// The compared quantity of `case` at positions `x`.
fn measured(case: &Case, x: &[Vec3]) -> f64 {
    let d = |n: usize| -> f64 {
        let u: Vec3 = std::array::from_fn(|a| x[n][a] - case.model.rest[n][a]);
        match case.axis {
            Some(a) => -u[a],
            None => (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt(),
        }
    };
    case.probe.iter().map(|&n| d(n)).sum::<f64>() / case.probe.len().max(1) as f64
}

fn static_answer(case: &Case, formulation: Formulation) -> f64 {
    let mut ff = HexForceField::new(&case.model, formulation);
    let mut x = case.model.rest.clone();
    static_solve_with(&case.model, &mut ff, &case.fixed, &case.loads, &mut x, 1e-9, 50, true);
    measured(case, &x)
}

#[derive(Clone, Copy)]
enum Scheme {
    Implicit(LinearSolver),
    Explicit,
}

fn scheme_names(s: Scheme) -> (&'static str, &'static str) {
    match s {
        Scheme::Implicit(LinearSolver::JacobiCg) => ("implicit-euler", "jacobi-cg"),
        Scheme::Implicit(LinearSolver::CholeskyCg { .. }) => ("implicit-euler", "cholesky-cg"),
        Scheme::Implicit(LinearSolver::Cholesky) => ("implicit-euler", "cholesky"),
        Scheme::Explicit => ("explicit", "-"),
    }
}

/// A stepping closure for `case` with `scheme` at `dt`, and the state it advances.
fn stepper(
    case: &Case,
    formulation: Formulation,
    scheme: Scheme,
    dt: f64,
) -> impl FnMut(&mut State) + '_ {
    let mut ff = HexForceField::new(&case.model, formulation);
    let damping = Rayleigh { alpha: 2.0, beta: 0.01 };
    let mut be = match scheme {
        Scheme::Implicit(solver) => Some(BackwardEuler::with_solver(
            dt,
            damping,
            CgSettings { tolerance: 1e-6, max_iterations: 2000 },
            solver,
        )),
        Scheme::Explicit => None,
    };
    move |state: &mut State| match &mut be {
        Some(be) => {
            be.step(&case.model, &mut ff, &case.fixed, &case.loads, state);
        }
        None => {
            explicit_step(&case.model, &mut ff, &case.fixed, &case.loads, damping.alpha, dt, state);
        }
    }
}

/// Stable: every value finite and the material's motion bounded — the mass-weighted mean
/// displacement stays below the scene's size (nodes of nearly empty elements carry almost no
/// material and may swing far without meaning anything).
fn stable(case: &Case, formulation: Formulation, scheme: Scheme, dt: f64, seconds: f64) -> bool {
    let mut step = stepper(case, formulation, scheme, dt);
    let mut state = State::at_rest(&case.model);
    let size = case.model.rest.iter().flat_map(|p| p.iter()).fold(0.0f64, |m, &c| m.max(c.abs()));
    let mass = case.model.total_mass();
    for _ in 0..(seconds / dt).ceil() as usize {
        step(&mut state);
        if state.x.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
            return false;
        }
        let mean: f64 = state
            .x
            .iter()
            .zip(&case.model.rest)
            .zip(&case.model.lumped_mass)
            .map(|((p, q), m)| m * (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt())
            .sum::<f64>()
            / mass;
        if mean > size {
            return false;
        }
    }
    true
}

/// Runs the report.
pub fn run(args: &SpeedErrorArgs) -> anyhow::Result<()> {
    let wanted: Vec<String> = if args.scene == "all" {
        ["b1", "b2", "b3", "c", "liver"].map(String::from).to_vec()
    } else {
        args.scene.split(',').map(|s| s.trim().to_lowercase()).collect()
    };
    let mut cases: Vec<Case> = Vec::new();
    for w in &wanted {
        match w.as_str() {
            "b1" => cases.push(block_case("B1", [7, 5, 4])),
            "b2" => cases.push(block_case("B2", [11, 8, 6])),
            "b3" => cases.push(block_case("B3", [22, 15, 12])),
            "c" => cases.extend([10, 20, 40, 80].map(cantilever_case)),
            "liver" => {
                cases.push(liver_case("liver-13k", [8, 8, 4])?);
                cases.push(liver_case("liver-109k", [4, 4, 2])?);
            }
            other => bail!("unknown scene '{other}': expected all, b1, b2, b3, c or liver"),
        }
    }
    if let Some(limit) = args.max_elements {
        cases.retain(|c| c.model.elements.len() <= limit);
    }
    if cases.is_empty() {
        bail!("no scene left to run (check --scene and --max-elements)");
    }
    if cases.iter().any(|c| c.scene.starts_with('B')) {
        eprintln!(
            "reference for scene B: static corotational solve on 33x22x18 hexahedra (1.5x B3) …"
        );
        let fine = block_case("B-ref", [33, 22, 18]);
        let reference = static_answer(&fine, Formulation::Corotational);
        eprintln!("  pulled-corner displacement {:.4} mm", reference * 1e3);
        for c in cases.iter_mut().filter(|c| c.scene.starts_with('B')) {
            c.reference = Some(reference);
        }
    }
    let bar = crate::progress::stages(cases.len() as u64);
    // Read before the long measurement, so a bad file fails at once.
    let peer_points: Option<Vec<crate::peers::PeerPoint>> = if args.peers.is_empty() {
        None
    } else {
        let mut points = Vec::new();
        for path in &args.peers {
            points.extend(crate::peers::read_peers(path)?);
        }
        Some(points)
    };
    let mut rows = Vec::new();
    let mut explicit_limits = Vec::new();
    for case in &cases {
        bar.set_message(format!("{} {}", case.scene, case.resolution));
        let explicit_limit = stable_dt(
            &case.model,
            &HexForceField::new(&case.model, Formulation::Linear),
            &case.fixed,
        );
        explicit_limits.push((case.scene.clone(), case.resolution.clone(), explicit_limit));
        for formulation in [Formulation::Corotational, Formulation::Linear] {
            let error = case.reference.map(|r| (static_answer(case, formulation) - r).abs() / r);
            // The linear model's matrix is constant: one exact factorisation serves every step,
            // so the direct solver is measured for it too.
            let direct = (formulation == Formulation::Linear && case.block_cells.is_some())
                .then_some(Scheme::Implicit(LinearSolver::Cholesky));
            let schemes = case
                .solvers
                .iter()
                .map(|&s| Scheme::Implicit(s))
                .chain(direct)
                .chain([Scheme::Explicit]);
            for scheme in schemes {
                for dt in [1e-3, 1e-2] {
                    let ok = match scheme {
                        Scheme::Explicit if dt > explicit_limit => false,
                        _ => stable(case, formulation, scheme, dt, args.stable_seconds),
                    };
                    let (timing, ()) = if ok {
                        let mut step = stepper(case, formulation, scheme, dt);
                        let mut state = State::at_rest(&case.model);
                        measure(
                            args.repeats,
                            || (),
                            |()| {
                                for _ in 0..args.steps {
                                    step(&mut state);
                                }
                            },
                        )
                    } else {
                        (
                            crate::timing::Timing {
                                median_ms: f64::INFINITY,
                                min_ms: f64::INFINITY,
                                max_ms: f64::INFINITY,
                                repeats: 0,
                            },
                            (),
                        )
                    };
                    let rate = |ms: f64| {
                        if ms.is_finite() { args.steps as f64 / (ms * 1e-3) } else { 0.0 }
                    };
                    let (integrator, solver) = scheme_names(scheme);
                    rows.push(Row {
                        scene: case.scene.clone(),
                        model: if formulation == Formulation::Linear {
                            "linear-hex"
                        } else {
                            "corotational-hex"
                        },
                        integrator,
                        solver,
                        resolution: case.resolution.clone(),
                        level: case.level,
                        elements: case.model.elements.len(),
                        dofs: case.model.dof_count(),
                        dt,
                        steps_per_s: rate(timing.median_ms),
                        steps_per_s_min: rate(timing.max_ms),
                        steps_per_s_max: rate(timing.min_ms),
                        error,
                        stable: ok,
                    });
                }
            }
        }
        if let Some(cells) = case.block_cells {
            bar.set_message(format!("{} {} tensor-mass", case.scene, case.resolution));
            rows.extend(tensor_mass_rows(case, cells, args));
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    print_table(&rows);
    println!();
    println!(
        "explicit stable dt per mesh (rest stiffness; an explicit row runs only at or below it):"
    );
    for (scene, resolution, limit) in &explicit_limits {
        println!("  {scene:<11} {resolution:<14} {limit:.3e} s");
    }
    if let Some(limit) = args.max_error {
        match rows
            .iter()
            .filter(|r| r.stable && r.error.is_some_and(|e| e <= limit))
            .max_by(|a, b| a.steps_per_s.total_cmp(&b.steps_per_s))
        {
            Some(r) => println!(
                "fastest stable configuration within {:.1} % error: {} {} {} {} {} dt = {} s: {:.0} steps/s, error {:.2} %",
                limit * 100.0,
                r.scene,
                r.resolution,
                r.model,
                r.integrator,
                r.solver,
                r.dt,
                r.steps_per_s,
                r.error.unwrap_or(f64::NAN) * 100.0
            ),
            None => println!("no stable configuration is within {:.1} % error", limit * 100.0),
        }
    }
    let comparisons =
        peer_points.map(|points| compare_with_peers(&points, &rows, &cases)).unwrap_or_default();
    if !comparisons.is_empty() {
        print_comparisons(&comparisons);
    }
    if let Some(path) = &args.csv {
        write_csv(path, &rows).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.png {
        let peers: Vec<(String, f64, f64)> = comparisons
            .iter()
            .filter_map(|c| {
                let label = format!("{} {} {} ms", c.peer, c.scene, c.dt * 1e3);
                Some((label, c.steps_per_s, c.error?))
            })
            .collect();
        crate::plot::speed_error_png(
            path,
            &rows
                .iter()
                .map(|r| (r.model, r.scene.as_str(), r.steps_per_s, r.error, r.stable))
                .collect::<Vec<_>>(),
            (!args.peers.is_empty()).then_some(peers.as_slice()),
        )
        .with_context(|| format!("drawing {}", path.display()))?;
    }
    if args.json {
        if args.peers.is_empty() {
            println!("{}", serde_json::json!({ "rows": rows }));
        } else {
            println!("{}", serde_json::json!({ "rows": rows, "peers": comparisons }));
        }
    }
    Ok(())
}

/// Each peer point's error against its scene's reference, and our fastest stable row at the same
/// dt whose error is at most the peer's (any model, integrator and resolution of scene B: equal
/// error, not equal element count).
fn compare_with_peers(
    points: &[crate::peers::PeerPoint],
    rows: &[Row],
    cases: &[Case],
) -> Vec<PeerComparison> {
    points
        .iter()
        .map(|p| {
            let reference = cases.iter().find(|c| c.scene == p.scene).and_then(|c| c.reference);
            let error = p.displacement.zip(reference).map(|(u, r)| (u - r).abs() / r);
            let ours = error.and_then(|limit| {
                rows.iter()
                    .filter(|r| {
                        r.stable
                            && r.scene.starts_with('B')
                            && (r.dt - p.dt).abs() < 1e-12
                            && r.error.is_some_and(|e| e <= limit)
                    })
                    .max_by(|a, b| a.steps_per_s.total_cmp(&b.steps_per_s))
                    .map(|r| OursAtEqualError {
                        scene: r.scene.clone(),
                        resolution: r.resolution.clone(),
                        model: r.model,
                        integrator: r.integrator,
                        solver: r.solver,
                        steps_per_s: r.steps_per_s,
                        error: r.error.unwrap_or(f64::NAN),
                    })
            });
            let ratio = ours.as_ref().map(|o| o.steps_per_s / p.steps_per_s);
            PeerComparison {
                peer: p.peer.clone(),
                scene: p.scene.clone(),
                dt: p.dt,
                steps_per_s: p.steps_per_s,
                error,
                stable: p.displacement.is_some(),
                ours,
                ratio,
            }
        })
        .collect()
}

fn print_comparisons(comparisons: &[PeerComparison]) {
    println!();
    println!(
        "At equal error: each peer row against our fastest stable row at the same dt with an error at most the peer's"
    );
    println!(
        "{:<32} {:<5} {:>6} {:>9} {:>10} | {:<40} {:>10} {:>8} {:>8}",
        "peer", "scene", "dt ms", "error", "steps/s", "ours", "steps/s", "error", "ratio"
    );
    for c in comparisons {
        let error = match c.error {
            Some(e) => format!("{:.2} %", 100.0 * e),
            None if !c.stable => "blew up".to_owned(),
            None => "not run".to_owned(),
        };
        let (ours, rate, ours_error) = c.ours.as_ref().map_or(
            ("none at this error".to_owned(), String::new(), String::new()),
            |o| {
                (
                    format!("{} {} {} {}", o.scene, o.model, o.integrator, o.solver),
                    format!("{:.1}", o.steps_per_s),
                    format!("{:.2} %", 100.0 * o.error),
                )
            },
        );
        let ratio = c.ratio.map_or(String::new(), |r| format!("{r:.2}×"));
        println!(
            "{:<32} {:<5} {:>6} {:>9} {:>10.1} | {:<40} {:>10} {:>8} {:>8}",
            c.peer,
            c.scene,
            c.dt * 1e3,
            error,
            c.steps_per_s,
            ours,
            rate,
            ours_error,
            ratio
        );
    }
}

/// Paper 2's tensor-mass model (linear and St Venant-Kirchhoff, explicit central differences) on
/// scene B's block split into 6 tetrahedra per cell, at 1 ms, 10 ms and the mesh's own stable
/// step. Its error is its static answer (dynamic relaxation) against the same reference.
fn tensor_mass_rows(case: &Case, cells: [usize; 3], args: &SpeedErrorArgs) -> Vec<Row> {
    use incise_fem::tet::explicit::{CentralDifference, stable_dt as tet_stable_dt};
    use incise_fem::tet::relax::{Prescribed, RelaxSettings, Statics, relax};
    use incise_fem::tet::{
        Elasticity, Lame, TensorMassForceField, TetMaterial, TetModel, TetTopology,
    };
    let spacing: Vec3 = std::array::from_fn(|a| BLOCK[a] / cells[a] as f64);
    let mesh = incise_fem::tet::generate::lattice_to_tets(
        cells,
        |_, _, _| Some(1),
        |i, j, k| [i as f64 * spacing[0], j as f64 * spacing[1], k as f64 * spacing[2]],
    )
    .expect("a block tetrahedralises");
    let model = TetModel::new(&mesh, |_| {
        TetMaterial::isotropic(Lame::from_young_poisson(3e3, 0.45), 1000.0)
    });
    let topo = TetTopology::new(&mesh);
    let fixed = FixedNodes::plane(&model.rest, 2, BLOCK[2], 1e-9);
    // The same loads as the hexahedral rows: gravity and 0.5 N spread near the corner.
    let corner = [BLOCK[0], BLOCK[1], 0.0];
    let dist =
        |n: usize| (0..3).map(|a| (model.rest[n][a] - corner[a]).powi(2)).sum::<f64>().sqrt();
    let patch: Vec<usize> = (0..model.vertex_count()).filter(|&n| dist(n) <= 0.022).collect();
    let share = 0.5 / 3f64.sqrt() / patch.len() as f64;
    let mut external: Vec<Vec3> = model.lumped_mass.iter().map(|m| [0.0, 0.0, -9.81 * m]).collect();
    for &n in &patch {
        external[n][0] += share;
        external[n][1] += share;
        external[n][2] -= share;
    }
    let probe =
        (0..model.vertex_count()).min_by(|&a, &b| dist(a).total_cmp(&dist(b))).expect("vertices");
    let mut rows = Vec::new();
    for (name, kind) in [
        ("tensor-mass-svk", Elasticity::StVenantKirchhoff),
        ("tensor-mass-linear", Elasticity::Linear),
    ] {
        let ff = TensorMassForceField::new(&model, &topo, kind);
        let limit = tet_stable_dt(&model, &ff, &fixed);
        let mut x = model.rest.clone();
        let problem = Statics {
            model: &model,
            topology: &topo,
            force_field: &ff,
            penalty: None,
            fixed: &fixed,
            prescribed: &Prescribed { targets: Vec::new(), ramp_steps: 1 },
            external: &external,
        };
        let settled = relax(
            &problem,
            0.5 * limit,
            &mut x,
            RelaxSettings { tolerance: 1e-5, max_steps: 400_000 },
        );
        let answer =
            (0..3).map(|a| (x[probe][a] - model.rest[probe][a]).powi(2)).sum::<f64>().sqrt();
        let error = case.reference.filter(|_| settled.converged).map(|r| (answer - r).abs() / r);
        for dt in [1e-3, 1e-2, limit] {
            let run = |steps: usize| -> (bool, f64) {
                let Ok(mut cd) = CentralDifference::new(&model, &ff, &fixed, &model.rest, dt, 2.0)
                else {
                    return (false, 0.0);
                };
                let mut x = model.rest.clone();
                let start = std::time::Instant::now();
                for _ in 0..steps {
                    cd.step(&model, &topo, &ff, None, &fixed, &external, &mut x);
                }
                let secs = start.elapsed().as_secs_f64();
                (x.iter().flatten().all(|c| c.is_finite()), steps as f64 / secs)
            };
            let (ok, _) = run((args.stable_seconds / dt).ceil() as usize);
            let rates: Vec<f64> = if ok {
                let mut r: Vec<f64> = (0..args.repeats.max(1)).map(|_| run(args.steps).1).collect();
                r.sort_by(f64::total_cmp);
                r
            } else {
                vec![0.0]
            };
            rows.push(Row {
                scene: case.scene.clone(),
                model: name,
                integrator: "explicit",
                solver: "-",
                resolution: case.resolution.clone(),
                level: 0,
                elements: mesh.tets().len(),
                dofs: 3 * model.vertex_count(),
                dt,
                steps_per_s: rates[rates.len() / 2],
                steps_per_s_min: rates[0],
                steps_per_s_max: rates[rates.len() - 1],
                error,
                stable: ok,
            });
        }
    }
    rows
}

fn print_table(rows: &[Row]) {
    println!(
        "{:<11} {:<18} {:<15} {:<12} {:<14} {:>5} {:>8} {:>7} {:>8} {:>10} {:>10} {:>10} {:>9} {:>6}",
        "scene",
        "model",
        "integrator",
        "solver",
        "resolution",
        "level",
        "elements",
        "dofs",
        "dt",
        "steps/s",
        "min",
        "max",
        "error",
        "stable"
    );
    for r in rows {
        println!(
            "{:<11} {:<18} {:<15} {:<12} {:<14} {:>5} {:>8} {:>7} {:>8} {:>10.1} {:>10.1} {:>10.1} {:>9} {:>6}",
            r.scene,
            r.model,
            r.integrator,
            r.solver,
            r.resolution,
            r.level,
            r.elements,
            r.dofs,
            format!("{:.3}", r.dt * 1e3) + " ms",
            r.steps_per_s,
            r.steps_per_s_min,
            r.steps_per_s_max,
            r.error.map_or("-".to_string(), |e| format!("{:.2} %", e * 100.0)),
            if r.stable { "yes" } else { "no" }
        );
    }
}

fn write_csv(path: &std::path::Path, rows: &[Row]) -> std::io::Result<()> {
    let mut f = std::fs::File::create(path)?;
    writeln!(
        f,
        "scene,model,integrator,solver,resolution,level,elements,dofs,dt,steps_per_s,steps_per_s_min,steps_per_s_max,error,stable"
    )?;
    for r in rows {
        writeln!(
            f,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.scene,
            r.model,
            r.integrator,
            r.solver,
            r.resolution,
            r.level,
            r.elements,
            r.dofs,
            r.dt,
            r.steps_per_s,
            r.steps_per_s_min,
            r.steps_per_s_max,
            r.error.map_or(String::new(), |e| e.to_string()),
            r.stable
        )?;
    }
    Ok(())
}
