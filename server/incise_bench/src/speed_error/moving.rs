//! Scene B2-moving (docs/benchmarks.md): B2 with its pull travelling along the bottom edge, so the
//! block never settles. Each row is a `Simulation` of its own, driven through
//! `StepInputs::node_forces`, simulated from rest and timed over the whole run; its error is the
//! pulled corner's trajectory against the same model at a tenth of the smallest row's step.
//!
//! The scene is built in code from `b2.toml` with its `[[loads]]` cleared rather than from a
//! scene file of its own: the moving load cannot be written in a scene file, so such a file would
//! hold everything but the load, a copy of b2.toml that could drift from it. The pull's force and
//! radius are b2.toml's own, so the two scenes differ only in where the patch is.

use super::{Row, Scheme, SpeedErrorArgs, scheme_names};
use anyhow::{Context, bail};
use incise_fem::ode::{LinearSolver, stable_dt};
use incise_fem::{Executor, Formulation, HexForceField, Idle};
use incise_math::Vec3;
use incise_sim::config::{ImplicitSolver, Integrator, Model, VolumeSpec};
use incise_sim::{SceneConfig, Simulation, StepInputs};
use std::time::Instant;

/// The scene's name in rows and references.
pub(super) const SCENE: &str = "B2-moving";
/// The reference's step (s): a tenth of the 1 ms rows' step, and every row's step time is a
/// multiple of it, so each row step has a reference sample at the same time.
const REFERENCE_DT: f64 = 1e-4;
/// The reference's CG tolerance: far below any row's, so its own solver error does not count.
const REFERENCE_TOLERANCE: f64 = 1e-12;
/// The patch's round trip (s): 50 ms out along the edge, 50 ms back.
const PERIOD: f64 = 0.1;
/// Steps of the rows (s).
const DTS: [f64; 2] = [1e-3, 1e-2];

/// The scene as read from b2.toml, without its patch load, and what the moving load needs.
pub(super) struct Scene {
    config: SceneConfig,
    volume: incise_grid::LabelVolume,
    file: String,
    /// The pull's total force (N) and radius (m): b2.toml's load.
    force: Vec3,
    radius: f64,
    /// The block's size (m): the patch travels along x at `y = size[1]`, `z = 0`.
    size: [f64; 3],
    /// Node rest positions (the same for every model and integrator of the scene).
    rest: Vec<Vec3>,
    /// The pulled corner's node, nearest (size x, size y, 0).
    corner: usize,
    elements: usize,
    dofs: usize,
    /// The mesh's explicit stable step (s), from the rest stiffness as the other scenes'.
    explicit_limit: f64,
}

/// One model's reference run.
pub(super) struct Reference {
    pub model: &'static str,
    /// The corner's displacement after every reference step `k` (time `k · REFERENCE_DT`), and
    /// at rest (`k = 0`).
    corner: Vec<Vec3>,
    /// The largest `|corner displacement|` over the run (m).
    pub peak: f64,
    /// Wall time of the reference run (s).
    pub seconds: f64,
}

/// What the footer and the JSON say about the scene.
pub(super) struct Summary {
    pub references: Vec<Reference>,
    pub alpha: f64,
    pub beta: f64,
    pub simulated_seconds: f64,
    pub explicit_limit: f64,
}

impl Scene {
    /// Reads `b2.toml` from the scene folder and clears its loads.
    pub(super) fn read(args: &SpeedErrorArgs) -> anyhow::Result<Self> {
        let path = args.scene_dir.join("b2.toml");
        let scene = incise_scene::read_scene(&path)
            .with_context(|| format!("reading scene {} (see --scene-dir)", path.display()))?;
        let mut config = scene.config;
        let incise_scene::SceneGeometry::Volume(volume) = scene.geometry else {
            bail!("{}: scene B2-moving needs b2.toml's block, not a mesh", path.display());
        };
        let [load] = &config.loads[..] else {
            bail!("{}: scene B2-moving moves b2.toml's one patch load", path.display());
        };
        let (force, radius, fixed_centre) = (load.force, load.radius, load.centre);
        config.loads.clear();
        let Some(&VolumeSpec::Block { size_m, .. }) = config.volume() else {
            bail!("{}: not a procedural block", path.display())
        };
        let file = path.display().to_string();
        let sim = Simulation::new(&config, &volume, &file)?;
        let model = sim.model().context("b2.toml is a hexahedral scene")?;
        let rest = model.rest.clone();
        let dist = |n: usize| (0..3).map(|a| (rest[n][a] - fixed_centre[a]).powi(2)).sum::<f64>();
        let corner = (0..rest.len()).min_by(|&a, &b| dist(a).total_cmp(&dist(b))).expect("nodes");
        let explicit_limit =
            stable_dt(model, &HexForceField::new(model, Formulation::Linear), sim.fixed());
        Ok(Self {
            explicit_limit,
            elements: model.elements.len(),
            dofs: model.dof_count(),
            config,
            volume,
            file,
            force,
            radius,
            size: size_m,
            rest,
            corner,
        })
    }

    pub(super) fn elements(&self) -> usize {
        self.elements
    }

    /// The patch's centre at time `t`: a triangle wave along the bottom edge, from x = 0 to the
    /// block's end and back every `PERIOD`.
    fn centre(&self, t: f64) -> Vec3 {
        let phase = (t / PERIOD).fract();
        let s = if phase < 0.5 { 2.0 * phase } else { 2.0 * (1.0 - phase) };
        [s * self.size[0], self.size[1], 0.0]
    }

    /// The forces of the `steps` steps of `dt`, each evaluated at its step's end time (when
    /// implicit Euler evaluates its forces), computed before any run so that the timed loop holds
    /// the simulation's steps only.
    fn inputs(&self, dt: f64, steps: usize) -> Vec<StepInputs> {
        (1..=steps)
            .map(|k| {
                let c = self.centre(k as f64 * dt);
                let patch: Vec<usize> = (0..self.rest.len())
                    .filter(|&n| {
                        (0..3).map(|a| (self.rest[n][a] - c[a]).powi(2)).sum::<f64>().sqrt()
                            <= self.radius
                    })
                    .collect();
                let share = 1.0 / patch.len().max(1) as f64;
                let f = self.force.map(|c| c * share);
                StepInputs {
                    node_forces: patch.into_iter().map(|n| (n, f)).collect(),
                    ..StepInputs::default()
                }
            })
            .collect()
    }

    /// The scene with `model`, `scheme`, `dt` and `tolerance` (b2.toml's damping; the explicit
    /// integrator takes its α only, as the b2 rows' explicit runs do).
    fn config(&self, model: Formulation, scheme: Scheme, dt: f64, tolerance: f64) -> SceneConfig {
        let mut config = self.config.clone();
        let damping = self.damping();
        let Model::Hexahedra(hex) = &mut config.model else {
            unreachable!("read() accepts b2.toml's block only")
        };
        hex.formulation = model;
        hex.integrator = match scheme {
            Scheme::Implicit(solver) => Integrator::ImplicitEuler {
                dt,
                solver: match solver {
                    LinearSolver::JacobiCg => ImplicitSolver::JacobiCg { cg_tolerance: tolerance },
                    LinearSolver::CholeskyCg { .. } => {
                        ImplicitSolver::CholeskyCg { cg_tolerance: tolerance }
                    }
                    LinearSolver::Cholesky => ImplicitSolver::Cholesky,
                },
                mass: incise_fem::ode::MassMatrix::Lumped,
                damping,
            },
            Scheme::Explicit => Integrator::Explicit { dt, rayleigh_alpha: damping.alpha },
        };
        config
    }

    /// b2.toml's damping.
    fn damping(&self) -> incise_fem::ode::Rayleigh {
        match &self.config.model {
            Model::Hexahedra(hex) => hex.integrator.damping(),
            Model::TensorMass(_) => unreachable!("read() accepts b2.toml's block only"),
        }
    }

    /// b2.toml's CG tolerance.
    fn tolerance(&self) -> f64 {
        match &self.config.model {
            Model::Hexahedra(hex) => hex.integrator.cg_tolerance(),
            Model::TensorMass(_) => None,
        }
        .unwrap_or(incise_sim::config::DEFAULT_CG_TOLERANCE)
    }

    /// Runs `config` from rest through `inputs` on `exec`: the wall time of all the steps (the
    /// build is not timed) and the corner's displacement after each, or `None` when the run blew
    /// up (a value not finite, or the corner further from rest than the block is long).
    fn run(
        &self,
        config: &SceneConfig,
        inputs: &[StepInputs],
        exec: &Executor,
    ) -> anyhow::Result<Option<(f64, Vec<Vec3>)>> {
        let mut sim = Simulation::with_executor(config, &self.volume, &self.file, exec)?;
        let rest = self.rest[self.corner];
        let mut corner = Vec::with_capacity(inputs.len());
        let start = Instant::now();
        for input in inputs {
            let frame = sim.step(input)?;
            let x = frame.positions[self.corner];
            corner.push(std::array::from_fn(|a| x[a] - rest[a]));
        }
        let seconds = start.elapsed().as_secs_f64();
        let bound = self.size.iter().copied().fold(0.0, f64::max);
        let stable = sim.state().x.iter().flatten().all(|c| c.is_finite())
            && corner.iter().all(|u: &Vec3| norm(*u) < bound);
        Ok(stable.then_some((seconds, corner)))
    }

    /// The reference of `model`: implicit Euler at `REFERENCE_DT`, CG preconditioned by the
    /// exact factor to `REFERENCE_TOLERANCE`, for `seconds` of simulated time.
    fn reference(
        &self,
        model: Formulation,
        name: &'static str,
        seconds: f64,
        exec: &Executor,
    ) -> anyhow::Result<Reference> {
        let steps = (seconds / REFERENCE_DT).round() as usize;
        let scheme = Scheme::Implicit(LinearSolver::CholeskyCg { refresh_iterations: 8 });
        let config = self.config(model, scheme, REFERENCE_DT, REFERENCE_TOLERANCE);
        let start = Instant::now();
        let Some((_, trajectory)) = self.run(&config, &self.inputs(REFERENCE_DT, steps), exec)?
        else {
            bail!("the {SCENE} reference ({name}, dt = {REFERENCE_DT} s) blew up");
        };
        let corner: Vec<Vec3> = std::iter::once([0.0; 3]).chain(trajectory).collect();
        let peak = corner.iter().map(|&u| norm(u)).fold(0.0, f64::max);
        Ok(Reference { model: name, corner, peak, seconds: start.elapsed().as_secs_f64() })
    }
}

fn norm(u: Vec3) -> f64 {
    (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
}

/// The RMS over a row's steps of its corner's distance to the reference's at the same time,
/// over the reference corner's peak displacement.
fn trajectory_error(row: &[Vec3], dt: f64, reference: &Reference) -> f64 {
    let stride = (dt / REFERENCE_DT).round() as usize;
    let sum: f64 = row
        .iter()
        .enumerate()
        .map(|(k, u)| {
            let r = reference.corner[(k + 1) * stride];
            norm(std::array::from_fn(|a| u[a] - r[a])).powi(2)
        })
        .sum();
    (sum / row.len().max(1) as f64).sqrt() / reference.peak
}

/// Median, min and max of `rates`.
fn spread(mut rates: Vec<f64>) -> (f64, f64, f64) {
    rates.sort_by(f64::total_cmp);
    (rates[rates.len() / 2], rates[0], rates[rates.len() - 1])
}

/// The scene's rows: corotational and linear hexahedra, implicit Euler at 1 ms and 10 ms with
/// each solver scene B measures (and the exact factor for the linear model), and explicit at
/// 1 ms when the mesh's stable step allows it. Each row is `--repeats` whole runs from rest on
/// `exec` (median, min, max), and its implicit runs again on one thread; its trajectory error
/// comes from its first run (the runs are bit-identical).
pub(super) fn rows(
    scene: &Scene,
    args: &SpeedErrorArgs,
    exec: &Executor,
    bar: &indicatif::ProgressBar,
) -> anyhow::Result<(Vec<Row>, Summary)> {
    let seconds = args.moving_seconds;
    if !(seconds > 0.0 && (seconds / DTS[1]).fract().abs() < 1e-9) {
        bail!("--moving-seconds must be a positive multiple of {} s", DTS[1]);
    }
    let one = Executor::new(1, Idle::DEFAULT_SPIN);
    let mut references = Vec::new();
    let mut rows = Vec::new();
    for (kind, name) in
        [(Formulation::Corotational, "corotational-hex"), (Formulation::Linear, "linear-hex")]
    {
        bar.set_message(format!("{SCENE} {name} reference (dt = {REFERENCE_DT} s)"));
        let reference = scene.reference(kind, name, seconds, exec)?;
        eprintln!(
            "reference for {SCENE} {name}: peak corner displacement {:.4} mm ({:.1} s)",
            reference.peak * 1e3,
            reference.seconds
        );
        let solvers = [LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }];
        let direct = (kind == Formulation::Linear).then_some(LinearSolver::Cholesky);
        let schemes = solvers.into_iter().chain(direct).map(Scheme::Implicit);
        let runs = schemes.flat_map(|s| DTS.map(|dt| (s, dt))).chain([(Scheme::Explicit, DTS[0])]);
        for (scheme, dt) in runs {
            let (integrator, solver) = scheme_names(scheme);
            bar.set_message(format!("{SCENE} {name} {integrator} {solver} {dt} s"));
            let steps = (seconds / dt).round() as usize;
            let inputs = scene.inputs(dt, steps);
            let config = scene.config(kind, scheme, dt, scene.tolerance());
            let timed = |exec: &Executor| -> anyhow::Result<Option<(Vec<f64>, Vec<Vec3>)>> {
                let mut rates = Vec::new();
                let mut first = None;
                for _ in 0..args.repeats.max(1) {
                    let Some((wall, corner)) = scene.run(&config, &inputs, exec)? else {
                        return Ok(None);
                    };
                    rates.push(steps as f64 / wall);
                    first.get_or_insert(corner);
                }
                Ok(first.map(|c| (rates, c)))
            };
            let outcome = match scheme {
                // Above the mesh's stable step the scene refuses to build: not stable.
                Scheme::Explicit if dt > scene.explicit_limit => None,
                _ => timed(exec)?,
            };
            let one_thread = match (scheme, &outcome) {
                (Scheme::Implicit(_), Some(_)) => timed(&one)?.map(|(rates, _)| spread(rates).0),
                _ => None,
            };
            let stable = outcome.is_some();
            let (rates, trajectory) = outcome.unwrap_or((vec![0.0], Vec::new()));
            let (median, min, max) = spread(rates);
            rows.push(Row {
                scene: SCENE.into(),
                model: name,
                element: "condensed",
                integrator,
                solver,
                resolution: "11x8x6".into(),
                level: scene.config.level().unwrap_or(0),
                elements: scene.elements,
                dofs: scene.dofs,
                dt,
                steps_per_s: median,
                steps_per_s_min: min,
                steps_per_s_max: max,
                steps_per_s_one_thread: one_thread,
                error: None,
                error_abs: None,
                error_signed: None,
                error_level0: None,
                error_static: None,
                trajectory_error: stable.then(|| trajectory_error(&trajectory, dt, &reference)),
                settled: false,
                stable,
            });
        }
        references.push(reference);
    }
    let summary = Summary {
        references,
        alpha: scene.damping().alpha,
        beta: scene.damping().beta,
        simulated_seconds: seconds,
        explicit_limit: scene.explicit_limit,
    };
    Ok((rows, summary))
}

impl Summary {
    /// The footer's lines.
    pub(super) fn print(&self, scene: &Scene, repeats: usize) {
        let f = norm(scene.force);
        println!(
            "{SCENE}: b2.toml's block, material, gravity and fixed top face; Rayleigh damping alpha = {} /s, beta = {} s on the implicit rows (as on the b2 rows), alpha only on the explicit ones; instead of the corner patch, {f:.3} N along ({:.3}, {:.3}, {:.3}) shared evenly by the nodes within {} mm of a centre moving along (x, {}, 0) from x = 0 to {} m and back, {} ms each way, evaluated at each step's end",
            self.alpha,
            self.beta,
            scene.force[0] / f,
            scene.force[1] / f,
            scene.force[2] / f,
            scene.radius * 1e3,
            scene.size[1],
            scene.size[0],
            PERIOD * 500.0,
        );
        println!(
            "{SCENE} timing: {} s simulated from rest, all of it timed (steps / wall time; the scene's build untimed), {repeats} runs (median, min, max)",
            self.simulated_seconds
        );
        let peaks: Vec<String> = self
            .references
            .iter()
            .map(|r| format!("{} {:.3} mm ({:.1} s)", r.model, r.peak * 1e3, r.seconds))
            .collect();
        println!(
            "{SCENE} trajectory_error: RMS over the row's steps of the distance between its pulled corner (node at {:?}) and the reference's at the same time, over the reference corner's peak displacement; reference: the same model and mesh, implicit Euler at dt = {} ms, cholesky-cg to a CG tolerance of {:e}, run once per model: peak {}",
            scene.rest[scene.corner],
            REFERENCE_DT * 1e3,
            REFERENCE_TOLERANCE,
            peaks.join(", ")
        );
        println!(
            "{SCENE}: explicit stable dt {:.3e} s (an explicit row runs only at or below it); the explicit rows lack beta's stiffness damping, which the reference has, so their trajectory_error measures that difference too",
            self.explicit_limit
        );
    }

    /// The scene's entry under the JSON's `references`.
    pub(super) fn json(&self) -> serde_json::Value {
        let mut peak = serde_json::Map::new();
        let mut wall = serde_json::Map::new();
        for r in &self.references {
            peak.insert(r.model.into(), r.peak.into());
            wall.insert(r.model.into(), r.seconds.into());
        }
        serde_json::json!({
            "integrator": "implicit-euler",
            "solver": "cholesky-cg",
            "dt": REFERENCE_DT,
            "cg_tolerance": REFERENCE_TOLERANCE,
            "simulated_seconds": self.simulated_seconds,
            "peak_displacement": peak,
            "seconds": wall,
        })
    }
}
