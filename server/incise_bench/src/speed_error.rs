//! `incise-bench speed-error`: speed against error on docs/benchmarks.md scenes B (hanging block),
//! B2-moving (the block under a travelling pull), C (cantilever) and on the liver, for each model,
//! integrator and dt ∈ {1 ms, 10 ms}. The scenes are the files in `deploy/scenes/`
//! (`--scene-dir`), built by `incise_sim::Simulation` as a server would build them.
//!
//! Error is measured, not assumed: each row runs its own integrator, solver and tolerance from
//! rest until its compared quantity settles (`--settle-seconds` simulated seconds at most), and
//! its error is that settled value against the reference: Euler–Bernoulli for C; for B, static
//! corotational solves on a 33×22×18 and a 44×30×24 mesh extrapolated to h → 0 (Richardson), the
//! error signed; and for both livers the finest model affordable, the 109,201-voxel liver at
//! level 0 solved statically with the same model (each Newton step preconditioned by the liver's
//! own levels as a multigrid), compared on the same points ([`organ`]). A solver that stopped
//! short would show in that value, and a run that never settles reports no error. The static
//! answer of the row's own mesh and model is reported beside it (`error_static`). A row is stable when its run stays finite and bounded. B2-moving never
//! settles: its rows are whole timed runs, compared as trajectories ([`moving`]).
//!
//! Speed is steps per second of the integrator alone, median/min/max over `--repeats` runs, on
//! the report's executor and, for implicit rows, again on one thread. A hexahedral row's runs
//! follow `--warmup-steps` untimed steps and last about `--run-seconds` (`--steps` to
//! `--max-steps` steps), shaped like the peers' scripts; a tensor-mass row times `--steps` steps
//! from rest.

use crate::timing::measure;
use anyhow::{Context, bail};
use incise_fem::linsolve::cg::CgSettings;
use incise_fem::linsolve::multigrid::{LevelSpec, Multigrid};
use incise_fem::model::{Loads, State};
use incise_fem::ode::{
    BackwardEuler, LinearSolver, Rayleigh, explicit_step, stable_dt, static_solve_multigrid,
    static_solve_with,
};
use incise_fem::{ElementKind, Executor, FixedNodes, Formulation, HexForceField, HexModel, Idle};
use incise_math::Vec3;
use incise_sim::config::{DEFAULT_CG_TOLERANCE, ExecSpec, Level, Model, VolumeSpec};
use incise_sim::{SceneConfig, Simulation};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod moving;
pub mod multigrid;
mod organ;
mod press;
pub mod reference;

/// Arguments of `incise-bench speed-error`.
#[derive(clap::Args, Debug)]
pub struct SpeedErrorArgs {
    /// Scenes to run: `all`, or a comma-separated list of `b1`, `b2`, `b3`, `b2-moving`, `c`,
    /// `liver`, `liver-press`. `liver-press` is the 13,648-voxel liver (`--liver-levels`,
    /// `--elements`) hanging at rest and pushed upwards at its lowest point by a tool (2 N, rising
    /// over 0.25 s, released at 1 s): each row runs 2 s from its own static equilibrium, all of
    /// it timed, and its `trajectory_error` is the contact point's RMS distance from the same
    /// liver at level 0 (dt = 0.5 ms, CG to 1e-9; about a minute per model) over that
    /// reference's peak displacement; `all` leaves it out. `b2-moving` is B2 with its pull travelling along the bottom edge (there and back
    /// every 100 ms): each row simulates 2 s from rest, all of it timed, and its
    /// `trajectory_error` is the pulled corner's RMS distance from the same model at dt = 0.1 ms
    /// (CG to 1e-12), over that reference's peak displacement (docs/benchmarks.md). Those two
    /// references, 20,000 steps each, take most of its run (about 50 s each in release on a busy
    /// 2-core machine).
    #[arg(long, default_value = "all")]
    scene: String,
    /// Skip meshes with more elements than this (quick runs).
    #[arg(long)]
    max_elements: Option<usize>,
    /// Timed steps per run, at least: a fast row runs more, so that one run lasts about
    /// `--run-seconds` (as the peers' scripts choose their step counts).
    #[arg(long, default_value_t = 50)]
    steps: usize,
    /// Wall time one timed run aims at (s); its step count is chosen from a short trial.
    #[arg(long, default_value_t = 0.25)]
    run_seconds: f64,
    /// Most steps in one timed run (the peers' scripts cap theirs at 2,000 too).
    #[arg(long, default_value_t = 2000)]
    max_steps: usize,
    /// Untimed steps before the timed runs of a row (the peers' scripts warm up too).
    #[arg(long, default_value_t = 20)]
    warmup_steps: usize,
    /// Timed runs per row (median, min and max are reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Simulated seconds every run lasts at least (it must stay finite and bounded throughout).
    #[arg(long, default_value_t = 0.3)]
    stable_seconds: f64,
    /// Simulated seconds a run may take to settle before its row is reported unsettled (no
    /// error): the compared quantity is settled when it moved less than 1e-5 of itself over each
    /// of the last two 0.1 s windows.
    #[arg(long, default_value_t = 20.0)]
    settle_seconds: f64,
    /// Folder of the scene files (b1.toml, b2.toml, b3.toml, c_*.toml, liver_*.toml).
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Cells per axis of scene B's coarse reference (a static corotational solve of b3.toml's
    /// block): 1.5 times as fine as B3 by default (1.7–3.3 s in release on an idle 2-core
    /// machine).
    #[arg(long, value_delimiter = ',', default_value = "33,22,18")]
    reference_cells: Vec<usize>,
    /// Cells per axis of scene B's fine reference: with the coarse one, the pulled corner is
    /// extrapolated to h → 0 (Richardson, error ∝ h² for trilinear hexahedra, h the largest cell
    /// edge) and scene B's rows are measured against that. The default 44,30,24 (105,000
    /// unknowns) takes a few times as long as the coarse solve: seconds to tens of seconds in
    /// release on two cores.
    #[arg(long, value_delimiter = ',', default_value = "44,30,24")]
    richardson_cells: Vec<usize>,
    /// Skip the fine reference (quick runs): scene B's rows are measured against the coarse one.
    #[arg(long)]
    no_richardson: bool,
    /// Simulated seconds of each b2-moving run and its reference (2 s by the protocol; shorter
    /// only to keep tests quick: the figures are then not the benchmark's).
    #[arg(long, default_value_t = 2.0, hide = true)]
    moving_seconds: f64,
    /// Simulated seconds of each liver-press run and its reference (2 s by the protocol; shorter
    /// only to keep tests quick).
    #[arg(long, default_value_t = 2.0, hide = true)]
    press_seconds: f64,
    /// Levels of the 13,648-voxel liver to run.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    liver_levels: Vec<u32>,
    /// Levels of the 109,201-voxel liver to run (level 2 holds about 3,000 elements; its rows
    /// take several minutes).
    #[arg(long = "liver-109k-levels", value_delimiter = ',', default_value = "3")]
    liver_109k_levels: Vec<u32>,
    /// Hexahedral models to run, comma-separated: `corotational`, `linear`. The liver's
    /// reference is solved for these only (the corotational one takes most of its time).
    #[arg(long, value_delimiter = ',', default_value = "corotational,linear")]
    models: Vec<String>,
    /// Element kinds of the liver's coarse levels, comma-separated: `condensed` (the Galerkin
    /// product of the voxels, Jeřábková 2010 eq. 1–4), `composite` (the points of a cell that no
    /// other element uses relaxed to least energy, `incise_grid::composite`) and `incompatible`
    /// (nine internal bubble modes condensed out, `incise_grid::incompatible`).
    #[arg(long, value_delimiter = ',', default_value = "condensed,composite,incompatible")]
    elements: Vec<String>,
    /// Accepted for older command lines: the 109,201-voxel liver's level 0 is now always solved,
    /// as the liver's reference.
    #[arg(long, hide = true)]
    fine_references: bool,
    /// Also print the fastest stable configuration whose error (its absolute value) is at most
    /// this (e.g. 0.05).
    #[arg(long)]
    max_error: Option<f64>,
    /// End with one line holding one JSON object `{"rows":[…],"references":{…},"threads":{…}}`.
    /// A row's `error` is signed for scene B (`(u − u*)/|u*|`) and the absolute relative error
    /// elsewhere, `error_abs` its absolute value; `error_signed` holds the signed fractions by
    /// quantity (`corner` for B, `tip_deflection` for C, `centre_of_mass`, `max` and `rms` for
    /// the liver, whose `error` is the larger magnitude of the first two);
    /// `steps_per_s_one_thread` is the implicit rows' speed on one thread (null on explicit
    /// rows); `trajectory_error` is b2-moving's error (null on other rows). `references.B`
    /// holds scene B's coarse, fine and extrapolated answers and the extrapolation's estimated
    /// error; `references.B1` … the value the rows are measured against; `references.liver` the
    /// liver's reference measures and the 13,648-voxel liver's level 0 against them.
    #[arg(long)]
    json: bool,
    /// Write the rows as CSV to this file.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
    /// Draw speed against error (log-log) to this PNG.
    #[arg(long, value_name = "PATH")]
    png: Option<PathBuf>,
    /// The table `deploy/peers/bench_mujoco.py S1 S2 S3 nocant` printed, saved to a file (run it
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
    /// Its absolute error.
    error: f64,
}

/// One configuration's figures.
#[derive(Clone, Debug, Serialize)]
struct Row {
    scene: String,
    model: &'static str,
    /// How the hexahedra's stiffness was made from the voxels: `condensed`, `composite`,
    /// `incompatible` (`tetrahedra` for the tensor-mass rows).
    element: &'static str,
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
    /// Implicit rows: the median steps/s of the same runs on a one-thread executor.
    steps_per_s_one_thread: Option<f64>,
    /// The settled value of the row's own run against the reference (`None` without a
    /// reference, or when the run did not settle or was unstable): `(u − r)/|r|` for scene B,
    /// `|u − r|/|r|` for the others.
    error: Option<f64>,
    /// `|error|`: what `--max-error` and the peer comparisons use.
    error_abs: Option<f64>,
    /// The signed fractions `(u − r)/|r|` by quantity (see `--json`).
    error_signed: Option<BTreeMap<&'static str, f64>>,
    /// Liver rows: the centre of mass's error against the same liver's level 0 (static, same
    /// model), the discretisation error of the coarse levels that `model = "auto"` calibrates.
    error_level0: Option<f64>,
    /// The static answer of the row's mesh and model against the reference (signed as `error`).
    error_static: Option<f64>,
    /// Scene B2-moving: the pulled corner's RMS distance from the reference trajectory over its
    /// peak displacement.
    trajectory_error: Option<f64>,
    /// Whether the row's run settled within `--settle-seconds`.
    settled: bool,
    stable: bool,
}

impl Row {
    /// The row of `case` with `formulation` and `scheme` at `dt`, its figures still empty.
    fn of(case: &Case, formulation: Formulation, scheme: Scheme, dt: f64) -> Self {
        let (integrator, solver) = scheme_names(scheme);
        Self {
            scene: case.scene.clone(),
            model: row_model(formulation),
            element: case.element,
            integrator,
            solver,
            resolution: case.resolution.clone(),
            level: case.level,
            elements: case.model.elements.len(),
            dofs: case.model.dof_count(),
            dt,
            steps_per_s: 0.0,
            steps_per_s_min: 0.0,
            steps_per_s_max: 0.0,
            steps_per_s_one_thread: None,
            error: None,
            error_abs: None,
            error_signed: None,
            error_level0: None,
            error_static: None,
            trajectory_error: None,
            settled: false,
            stable: false,
        }
    }
}

/// What a case compares with its reference.
#[derive(Clone, Debug)]
enum Probe {
    /// The mean displacement of these nodes: along `axis`, downwards positive, or its norm.
    Nodes { nodes: Vec<usize>, axis: Option<usize> },
    /// The norm of the centre of mass's displacement (condensed lumped masses): under gravity
    /// the global stiffness, the measure `model = "auto"` calibrates with.
    CentreOfMass,
}

/// A scene to measure: its model, supports, loads, the quantity compared and its reference.
struct Case {
    scene: String,
    resolution: String,
    level: u32,
    /// `condensed`, `composite` or `incompatible` (see [`Row::element`]).
    element: &'static str,
    model: HexModel,
    fixed: FixedNodes,
    loads: Loads,
    /// The scene file's Rayleigh damping and CG tolerance.
    damping: Rayleigh,
    tolerance: f64,
    probe: Probe,
    /// The probe's name in `error_signed`.
    quantity: &'static str,
    reference: Option<f64>,
    /// Liver cases: the rows' error against the liver's reference ([`organ`]); `reference` is
    /// then the same liver's level 0 (`error_level0`).
    organ: Option<Organ>,
    /// The model the reference is valid for (`None`: every model's rows are measured against
    /// it, as the physical answer).
    reference_model: Option<Formulation>,
    /// With `reference_model` linear: the corotational rows' own reference, when there is one.
    corotational_reference: Option<f64>,
    /// Whether the rows' errors keep their sign (scene B: too stiff or too soft matters once the
    /// reference is an extrapolation rather than a finer mesh).
    signed: bool,
    /// The implicit solvers measured on this scene (each gets its own rows).
    solvers: Vec<LinearSolver>,
    /// Block scenes: the block's size and cells per axis, from which the tensor-mass rows build
    /// their tetrahedra.
    block: Option<([f64; 3], [usize; 3])>,
}

/// How a liver case is measured against the liver's reference.
struct Organ {
    sampler: organ::Sampler,
    reference: Arc<organ::OrganReference>,
}

/// Reads `file` from the scene folder and builds it with `Simulation::new`, at `level` and with
/// `voxels` per axis (a procedural block) when given instead of the file's own; also returns the
/// volume as read.
fn load_scene(
    scene_dir: &Path,
    file: &str,
    level: Option<u32>,
    voxels: Option<[usize; 3]>,
) -> anyhow::Result<(SceneConfig, Simulation, incise_grid::LabelVolume)> {
    let path = scene_dir.join(file);
    let incise_scene::Scene { mut config, geometry, .. } = incise_scene::read_scene(&path)
        .with_context(|| format!("reading scene {} (see --scene-dir)", path.display()))?;
    let Some(mut volume) = geometry.volume().cloned() else {
        bail!("scene {}: the report measures scenes on a label volume", path.display());
    };
    if let Some(level) = level {
        at_level(&mut config, level);
    }
    if let (Some(cells), Some(VolumeSpec::Block { voxels, .. })) = (voxels, config.volume_mut()) {
        *voxels = cells;
        volume = config.procedural_volume().expect("a block scene");
    }
    let simulation = Simulation::new(&config, &volume, &path.display().to_string())?;
    Ok((config, simulation, volume))
}

/// `config` with its hexahedra on grid `level`.
fn at_level(config: &mut SceneConfig, level: u32) {
    if let Model::Hexahedra(hex) = &mut config.model {
        hex.level = Level::Fixed(level);
    }
}

/// A case from a built scene.
fn case_of(
    name: &str,
    resolution: String,
    config: &SceneConfig,
    simulation: &Simulation,
    probe: Probe,
    solvers: Vec<LinearSolver>,
) -> anyhow::Result<Case> {
    let (Some(model), Some(loads), Model::Hexahedra(hex)) =
        (simulation.model(), simulation.loads(), &config.model)
    else {
        bail!("scene {name}: the report measures hexahedral scenes");
    };
    let block = match hex.volume {
        VolumeSpec::Block { size_m, voxels } => Some((size_m, voxels)),
        VolumeSpec::File { .. } | VolumeSpec::Organ { .. } => None,
    };
    Ok(Case {
        scene: name.into(),
        resolution,
        level: simulation.config().level().context("a hexahedral scene runs on a level")?,
        element: "condensed",
        model: model.clone(),
        fixed: simulation.fixed().clone(),
        loads: loads.clone(),
        damping: hex.integrator.damping(),
        tolerance: hex.integrator.cg_tolerance().unwrap_or(DEFAULT_CG_TOLERANCE),
        probe,
        quantity: "",
        reference: None,
        organ: None,
        reference_model: None,
        corotational_reference: None,
        signed: false,
        solvers,
        block,
    })
}

/// Scene B (`b1.toml` …), or with `voxels` the same block at another resolution: the probe is
/// the node nearest the centre of the pulled patch.
fn block_case(
    args: &SpeedErrorArgs,
    name: &str,
    file: &str,
    voxels: Option<[usize; 3]>,
) -> anyhow::Result<Case> {
    let (config, simulation, _) = load_scene(&args.scene_dir, file, None, voxels)?;
    let Some(patch) = config.loads.first() else { bail!("{file}: scene B pulls a patch") };
    let rest = &simulation.model().expect("a hexahedral scene").rest;
    let dist = |n: usize| (0..3).map(|a| (rest[n][a] - patch.centre[a]).powi(2)).sum::<f64>();
    let nearest = (0..rest.len()).min_by(|&a, &b| dist(a).total_cmp(&dist(b))).expect("nodes");
    let Some(VolumeSpec::Block { voxels, .. }) = config.volume() else {
        bail!("{file}: not a block")
    };
    // Both: Jacobi-CG is the faster when the mass dominates (dt = 1 ms), the Cholesky
    // preconditioner when the stiffness does (dt = 10 ms), until its fill grows too large.
    let mut case = case_of(
        name,
        format!("{}x{}x{}", voxels[0], voxels[1], voxels[2]),
        &config,
        &simulation,
        Probe::Nodes { nodes: vec![nearest], axis: None },
        vec![LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }],
    )?;
    case.signed = true;
    case.quantity = "corner";
    Ok(case)
}

/// Scene C at `n` cells along the beam: the probe is the tip face's mean deflection, the
/// reference Euler–Bernoulli's `q L⁴ / (8 E I)` from the file's size, material and gravity.
fn cantilever_case(args: &SpeedErrorArgs, n: usize) -> anyhow::Result<Case> {
    let file = format!("c_{n}x{}x{}.toml", n / 10, n / 10);
    let (config, simulation, _) = load_scene(&args.scene_dir, &file, None, None)?;
    let Some(&VolumeSpec::Block { size_m: [l, w, h], .. }) = config.volume() else {
        bail!("{file}: scene C is a procedural block")
    };
    let Some(material) = config.materials.first().map(incise_sim::config::MaterialSpec::material)
    else {
        bail!("{file}: no material")
    };
    let rest = &simulation.model().expect("a hexahedral scene").rest;
    let tip = (0..rest.len()).filter(|&k| (rest[k][0] - l).abs() < 1e-9 * l).collect();
    let q = material.density * config.gravity[2].abs() * w * h;
    let inertia = w * h.powi(3) / 12.0;
    let mut case = case_of(
        "C",
        format!("{n}x{}x{}", n / 10, n / 10),
        &config,
        &simulation,
        Probe::Nodes { nodes: tip, axis: Some(2) },
        // A slender beam is ill-conditioned for Jacobi but factorises with little fill: both are
        // measured, so the report shows which wins here.
        vec![LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }],
    )?;
    case.reference = Some(q * l.powi(4) / (8.0 * material.youngs_modulus * inertia));
    case.quantity = "tip_deflection";
    Ok(case)
}

/// The element kind `--elements` names, as the rows spell it.
fn element_kind(name: &str) -> Option<&'static str> {
    ElementKind::from_name(name).map(ElementKind::name)
}

/// A liver case from its built scene (a level of a [`Liver`]), probed by its centre of mass,
/// with elements of kind `element` (see [`element_kind`]). The scene holds only the tissue
/// connected to its hold ([`supported_volume`]'s result): a fragment striding cut loose would
/// have no static answer and would fall for ever.
fn liver_case_from(
    name: &str,
    simulation: &Simulation,
    stride: [usize; 3],
    element: &'static str,
) -> anyhow::Result<Case> {
    let mut case = case_of(
        name,
        format!("stride {},{},{}", stride[0], stride[1], stride[2]),
        simulation.config(),
        simulation,
        Probe::CentreOfMass,
        vec![LinearSolver::JacobiCg, LinearSolver::CholeskyCg { refresh_iterations: 8 }],
    )?;
    let kind = ElementKind::from_name(element).context("a known element kind")?;
    if kind != ElementKind::Condensed {
        let grid = simulation.grid().context("a hexahedral scene has a grid")?;
        case.model = HexModel::from_grid_of_kind(grid, kind);
    }
    case.element = element;
    case.quantity = "centre_of_mass";
    Ok(case)
}

/// The coarsest level of the multigrid that solves a liver's level 0.
const MULTIGRID_COARSEST: u32 = 3;

/// A supported liver (see [`supported_volume`]) built at levels 0 to 3 or coarser: its rows'
/// models, and the levels of the multigrid that solves its level 0 statically.
struct Liver {
    /// The rows' scene name (`liver-13k`, `liver-109k`).
    scene: &'static str,
    file: &'static str,
    supported: (SceneConfig, incise_grid::LabelVolume, [usize; 3]),
    levels: Vec<Simulation>,
}

impl Liver {
    /// Reads `file` and builds its levels 0 to `coarsest` (at least 3).
    fn read(
        scene_dir: &Path,
        scene: &'static str,
        file: &'static str,
        coarsest: u32,
    ) -> anyhow::Result<Self> {
        let supported = supported_volume(scene_dir, file)?;
        let levels = liver_levels(&supported, 0, coarsest.max(MULTIGRID_COARSEST))?;
        Ok(Self { scene, file, supported, levels })
    }

    /// The case at `level` with elements of kind `element`.
    fn case(&self, level: u32, element: &'static str) -> anyhow::Result<Case> {
        liver_case_from(self.scene, &self.levels[level as usize], self.supported.2, element)
    }

    /// The grid and model of `level`.
    fn level(&self, level: u32) -> anyhow::Result<(&incise_grid::BranchedGrid, &HexModel)> {
        let s = &self.levels[level as usize];
        Ok((s.grid().context("a liver has a grid")?, s.model().context("a liver has a model")?))
    }

    /// The static positions of `level0` (this liver's level-0 case) with `formulation`, each
    /// Newton step preconditioned by the liver's own levels as a multigrid (the 109,201-voxel
    /// liver's solves take seconds instead of minutes: `incise-bench multigrid`); `None` when
    /// Newton did not converge.
    fn static_level0(
        &self,
        level0: &Case,
        formulation: Formulation,
    ) -> anyhow::Result<Option<Vec<Vec3>>> {
        let levels = &self.levels[..=MULTIGRID_COARSEST as usize];
        let mut mg = hierarchy_of(levels, formulation, (0.0, 1.0), 2, &Executor::default())?;
        Ok(static_positions(level0, formulation, &mut Preconditioner::Multigrid(&mut mg)))
    }
}

/// The scenes of a supported liver (see [`supported_volume`]) at levels `finest` to `coarsest`:
/// a multigrid's levels (see [`hierarchy_of`]).
fn liver_levels(
    supported: &(SceneConfig, incise_grid::LabelVolume, [usize; 3]),
    finest: u32,
    coarsest: u32,
) -> anyhow::Result<Vec<Simulation>> {
    let (config, volume, _) = supported;
    (finest..=coarsest)
        .map(|level| {
            let mut config = config.clone();
            at_level(&mut config, level);
            Ok(Simulation::new(&config, volume, &config.name)?)
        })
        .collect()
}

/// The multigrid over `levels` (finest first) for `a·M + b·K` with `sweeps` smoothing sweeps.
fn hierarchy_of(
    levels: &[Simulation],
    formulation: Formulation,
    (a, b): (f64, f64),
    sweeps: usize,
    exec: &Executor,
) -> anyhow::Result<Multigrid> {
    let specs = levels
        .iter()
        .map(|s| -> anyhow::Result<LevelSpec<'_>> {
            Ok(LevelSpec {
                grid: s.grid().context("a hexahedral scene has a grid")?,
                model: s.model().context("a hexahedral scene has a model")?.clone(),
                fixed: s.fixed().clone(),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Multigrid::new(specs, formulation, a, b, sweeps, exec).map_err(anyhow::Error::msg)
}

/// The scene `file`, and its filtered, strided volume with only the voxels connected (through
/// shared nodes at level 0) to a held node, with the scene's stride; the scene's volume is
/// rewritten to take that volume as it is.
fn supported_volume(
    scene_dir: &Path,
    file: &str,
) -> anyhow::Result<(SceneConfig, incise_grid::LabelVolume, [usize; 3])> {
    let (mut config, simulation, raw) = load_scene(scene_dir, file, Some(0), None)?;
    let (Some(grid), Some(model)) = (simulation.grid(), simulation.model()) else {
        bail!("{file}: the report measures hexahedral scenes")
    };
    let Some(VolumeSpec::File { path, stride, labels }) = config.volume().cloned() else {
        bail!("{file}: not a file volume")
    };
    let strided = raw.filtered(&labels).crop_and_stride(stride)?;
    let mut of_node: Vec<Vec<usize>> = vec![Vec::new(); model.node_count()];
    for (e, element) in model.elements.iter().enumerate() {
        for &n in &element.nodes {
            of_node[n as usize].push(e);
        }
    }
    let fixed = simulation.fixed();
    let mut kept = vec![false; model.elements.len()];
    let mut stack: Vec<usize> = (0..model.elements.len())
        .filter(|&e| model.elements[e].nodes.iter().any(|&n| fixed.is_fixed(n as usize)))
        .collect();
    for &e in &stack {
        kept[e] = true;
    }
    while let Some(e) = stack.pop() {
        for &n in &model.elements[e].nodes {
            for &f in &of_node[n as usize] {
                if !kept[f] {
                    kept[f] = true;
                    stack.push(f);
                }
            }
        }
    }
    let mut labels = vec![0u16; strided.labels().len()];
    for (element, _) in model.elements.iter().zip(&kept).filter(|(_, k)| **k) {
        for v in grid.element_voxels(element.grid_id) {
            labels[v as usize] = strided.labels()[v as usize];
        }
    }
    let dropped = strided.foreground_count() - labels.iter().filter(|&&l| l != 0).count();
    let supported = incise_grid::LabelVolume::new(strided.dims(), strided.spacing(), labels)?
        .with_placement(strided.origin(), strided.direction())?;
    // The scene's regions are in the grid frame, which starts at the foreground's corner: the
    // kept voxels must still span the same box.
    if supported.foreground_bounds() != strided.foreground_bounds() {
        bail!("{file}: the tissue connected to the hold does not span the volume's box");
    }
    if dropped > 0 {
        eprintln!("{file}: {dropped} voxels not connected to the hold left out");
    }
    // The volume is already filtered and strided.
    if let Some(volume) = config.volume_mut() {
        *volume =
            VolumeSpec::File { path, stride: [1; 3], labels: incise_grid::LabelFilter::all() };
    }
    Ok((config, supported, stride))
}

/// The compared quantity of `case` at positions `x`.
fn measured(case: &Case, x: &[Vec3]) -> f64 {
    let rest = &case.model.rest;
    match &case.probe {
        Probe::Nodes { nodes, axis } => {
            let d = |n: usize| -> f64 {
                let u: Vec3 = std::array::from_fn(|a| x[n][a] - rest[n][a]);
                match axis {
                    Some(a) => -u[*a],
                    None => (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt(),
                }
            };
            nodes.iter().map(|&n| d(n)).sum::<f64>() / nodes.len().max(1) as f64
        }
        Probe::CentreOfMass => {
            let u = case.model.centre_of_mass_shift(x);
            (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
        }
    }
}

/// The static answer of `case`'s mesh with `formulation` (`None` when Newton did not converge),
/// each Newton step solved by CG preconditioned with a sparse Cholesky factor (`cholesky`) or
/// with block Jacobi (on a large bulky mesh the factor's fill costs minutes, CG seconds). When
/// Newton from rest does not converge (a large, soft deformation), the load is applied in ten
/// increments, each solve starting from the last.
fn static_answer(case: &Case, formulation: Formulation, cholesky: bool) -> Option<f64> {
    let mut with = if cholesky { Preconditioner::Cholesky } else { Preconditioner::BlockJacobi };
    static_positions(case, formulation, &mut with).map(|x| measured(case, &x))
}

/// How a static solve's Newton steps are preconditioned.
enum Preconditioner<'a> {
    BlockJacobi,
    Cholesky,
    /// A hierarchy whose finest level is the case's model.
    Multigrid(&'a mut Multigrid),
}

/// The node positions of [`static_answer`]'s solve (`None` when Newton did not converge).
fn static_positions(
    case: &Case,
    formulation: Formulation,
    with: &mut Preconditioner<'_>,
) -> Option<Vec<Vec3>> {
    let mut ff = HexForceField::new(&case.model, formulation);
    if let Preconditioner::Multigrid(mg) = with {
        // One pool of threads for the field and the hierarchy.
        ff = ff.with_executor(mg.executor().clone());
    }
    let (model, fixed) = (&case.model, &case.fixed);
    for increments in [1u32, 10] {
        let mut x = model.rest.clone();
        let mut converged = true;
        for k in 1..=increments {
            let s = f64::from(k) / f64::from(increments);
            let loads = Loads {
                gravity: case.loads.gravity.map(|g| s * g),
                nodal: case.loads.nodal.iter().map(|f| f.map(|c| s * c)).collect(),
            };
            // 1e-8: the probe to 7 digits or so; with an exact factor Newton's residual stalls
            // a little above 1e-9 on scene B (rounding), and 50 refactorisations cost minutes.
            let report = if let Preconditioner::Multigrid(mg) = with {
                static_solve_multigrid(model, &mut ff, fixed, &loads, &mut x, 1e-8, 50, mg)
            } else {
                let cholesky = matches!(with, Preconditioner::Cholesky);
                static_solve_with(model, &mut ff, fixed, &loads, &mut x, 1e-8, 50, cholesky)
            };
            converged &= report.converged;
            if !converged {
                break;
            }
        }
        if converged {
            return Some(x);
        }
    }
    None
}

/// A reference case's static answer (block-Jacobi CG: the reference meshes are the large ones),
/// printed as `quantity` with the time since `start`.
fn reference_of(
    fine: &Case,
    formulation: Formulation,
    quantity: &str,
    start: std::time::Instant,
) -> anyhow::Result<f64> {
    let Some(reference) = static_answer(fine, formulation, false) else {
        bail!("the static solve of the reference for {} did not converge", fine.scene);
    };
    eprintln!("  {quantity} {:.4} mm ({:.1} s)", reference * 1e3, start.elapsed().as_secs_f64());
    Ok(reference)
}

/// The model's name in the rows.
fn row_model(formulation: Formulation) -> &'static str {
    match formulation {
        Formulation::Linear => "linear-hex",
        Formulation::Corotational => "corotational-hex",
    }
}

/// The model's name in messages.
fn model_name(formulation: Formulation) -> &'static str {
    match formulation {
        Formulation::Linear => "linear",
        Formulation::Corotational => "corotational",
    }
}

/// Gives the liver cases their references, and returns them as JSON: the liver's reference is
/// the 109,201-voxel liver's level 0 (`large`), solved statically with each of `formulations`,
/// read on the points [`organ`] describes; each case is also measured against its own liver's
/// level 0 (`error_level0`), so `small`'s level 0 is solved too when it has cases.
fn set_liver_references(
    cases: &mut [Case],
    small: &Liver,
    large: &Liver,
    formulations: &[Formulation],
) -> anyhow::Result<serde_json::Value> {
    let coarse0 = small.case(0, "condensed")?;
    let fine0 = large.case(0, "condensed")?;
    let matching =
        reference::Matching::new(&coarse0, &small.supported.1, &fine0, &large.supported.1)?;
    let points = |liver: &Liver| {
        if liver.scene == small.scene {
            matching.coarse_points(&coarse0.model)
        } else {
            matching.fine_points()
        }
    };
    let fine_sampler = organ::Sampler::new(large.level(0)?, large.level(0)?, points(large))?;
    let coarse_sampler = organ::Sampler::new(small.level(0)?, small.level(0)?, points(small))?;
    let with_small = cases.iter().any(|c| c.scene == small.scene);
    let mut reference = organ::OrganReference {
        points: points(large).len(),
        unmatched: matching.unmatched(),
        linear: None,
        corotational: None,
    };
    // Per liver and model: the centre of mass's displacement at level 0.
    let mut level0: Vec<(&str, Formulation, f64)> = Vec::new();
    let mut small_errors = serde_json::Map::new();
    for &formulation in formulations {
        let name = model_name(formulation);
        eprintln!(
            "reference for the liver: static {name} solve of {} at level 0 ({} nodes) …",
            large.file,
            fine0.model.node_count()
        );
        let start = std::time::Instant::now();
        let Some(x) = large.static_level0(&fine0, formulation)? else {
            eprintln!("  the static solve did not converge: the {name} liver rows have no error");
            continue;
        };
        let measures = fine_sampler.measures(&fine0.model.rest, &x);
        eprintln!(
            "  centre of mass {:.4} mm, largest {:.4} mm, RMS {:.4} mm ({:.1} s)",
            measures.centre_of_mass * 1e3,
            measures.max * 1e3,
            measures.rms * 1e3,
            start.elapsed().as_secs_f64()
        );
        level0.push((large.scene, formulation, measured(&fine0, &x)));
        match formulation {
            Formulation::Linear => reference.linear = Some(measures),
            Formulation::Corotational => reference.corotational = Some(measures),
        }
        if with_small {
            eprintln!("  and of {} at level 0 …", small.file);
            if let Some(x) = small.static_level0(&coarse0, formulation)? {
                level0.push((small.scene, formulation, measured(&coarse0, &x)));
                let error =
                    coarse_sampler.measures(&coarse0.model.rest, &x).signed_error(&measures);
                small_errors.insert(name.into(), serde_json::to_value(error)?);
            }
        }
    }
    let reference = Arc::new(reference);
    let json = serde_json::json!({
        "model": format!("{} at level 0, static", large.file),
        "measures": &*reference,
        format!("{} level 0", small.scene): small_errors,
    });
    for case in cases.iter_mut() {
        let liver = match &case.scene {
            s if s == small.scene => small,
            s if s == large.scene => large,
            _ => continue,
        };
        let (grid, _) = liver.level(case.level)?;
        let sampler = organ::Sampler::new(liver.level(0)?, (grid, &case.model), points(liver))?;
        case.organ = Some(Organ { sampler, reference: Arc::clone(&reference) });
        let at_level0 = |f: Formulation| {
            level0.iter().find(|(s, m, _)| *s == liver.scene && *m == f).map(|l| l.2)
        };
        case.reference = at_level0(Formulation::Linear);
        case.reference_model = Some(Formulation::Linear);
        case.corotational_reference = at_level0(Formulation::Corotational);
    }
    Ok(json)
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

/// A stepping closure for `case` with `scheme` at `dt` on `exec`: it advances a state under the
/// loads it is given.
fn stepper<'a>(
    case: &'a Case,
    formulation: Formulation,
    scheme: Scheme,
    dt: f64,
    exec: &Executor,
) -> impl FnMut(&mut State, &Loads) + 'a {
    let mut ff = HexForceField::new(&case.model, formulation).with_executor(exec.clone());
    let damping = case.damping;
    let mut be = match scheme {
        Scheme::Implicit(solver) => Some(BackwardEuler::with_solver(
            dt,
            damping,
            CgSettings { tolerance: case.tolerance, max_iterations: 2000 },
            solver,
        )),
        Scheme::Explicit => None,
    };
    move |state: &mut State, loads: &Loads| match &mut be {
        Some(be) => {
            be.step(&case.model, &mut ff, &case.fixed, loads, state);
        }
        None => {
            explicit_step(&case.model, &mut ff, &case.fixed, loads, damping.alpha, dt, state);
        }
    }
}

/// A row's errors (see [`Row`]).
#[derive(Default)]
struct Errors {
    error: Option<f64>,
    signed: Option<BTreeMap<&'static str, f64>>,
    level0: Option<f64>,
}

/// The errors of `case` with `formulation` at positions `x`, whose compared quantity is `value`,
/// against `reference` (the case's reference for this model).
fn errors(
    case: &Case,
    formulation: Formulation,
    reference: Option<f64>,
    value: f64,
    x: &[Vec3],
) -> Errors {
    let relative = |r: f64| (value - r) / r.abs();
    let Some(organ) = &case.organ else {
        let signed = reference.map(relative);
        return Errors {
            error: signed.map(|e| if case.signed { e } else { e.abs() }),
            signed: signed.map(|e| BTreeMap::from([(case.quantity, e)])),
            level0: None,
        };
    };
    let measures = match formulation {
        Formulation::Linear => organ.reference.linear,
        Formulation::Corotational => organ.reference.corotational,
    };
    let signed = measures.map(|r| organ.sampler.measures(&case.model.rest, x).signed_error(&r));
    Errors {
        error: signed.map(|e| e.worst()),
        signed: signed.map(|e| {
            BTreeMap::from([("centre_of_mass", e.centre_of_mass), ("max", e.max), ("rms", e.rms)])
        }),
        level0: reference.map(|r| relative(r).abs()),
    }
}

/// Takes `--warmup-steps` untimed steps, then a short trial, and returns the step count of one
/// timed run: enough to last about `--run-seconds`, at least `--steps`, at most `--max-steps`.
/// The peers' scripts (`deploy/peers/scenes.py`: `pick_steps`, `time_runs`) also warm up and
/// choose their step counts under the same 2,000-step cap, so neither side's figure carries
/// first-step costs (allocation, page faults, the first solves' empty history) the other does
/// not, and fast rows on both sides time the same stretch of simulated time.
fn warm_up(args: &SpeedErrorArgs, mut step: impl FnMut()) -> usize {
    for _ in 0..args.warmup_steps {
        step();
    }
    let trial = 10;
    let start = std::time::Instant::now();
    for _ in 0..trial {
        step();
    }
    let per_step = start.elapsed().as_secs_f64() / trial as f64;
    let wanted = (args.run_seconds / per_step.max(1e-9)).ceil().min(1e9) as usize;
    wanted.min(args.max_steps).max(args.steps)
}

/// Times `case` with `scheme` at `dt` on `exec` by the protocol ([`warm_up`], then `--repeats`
/// runs from the same state on): steps/s median, min and max.
fn timed_rates(
    case: &Case,
    formulation: Formulation,
    scheme: Scheme,
    dt: f64,
    args: &SpeedErrorArgs,
    exec: &Executor,
) -> (f64, f64, f64) {
    let mut step = stepper(case, formulation, scheme, dt, exec);
    let mut state = State::at_rest(&case.model);
    let steps = warm_up(args, || step(&mut state, &case.loads));
    let (timing, ()) = measure(
        args.repeats,
        || (),
        |()| {
            for _ in 0..steps {
                step(&mut state, &case.loads);
            }
        },
    );
    let rate = |ms: f64| steps as f64 / (ms * 1e-3);
    (rate(timing.median_ms), rate(timing.max_ms), rate(timing.min_ms))
}

/// What a row's own run from rest found.
struct Run {
    /// Every value stayed finite and the material's motion bounded.
    stable: bool,
    /// The compared quantity settled (see `--settle-seconds`).
    settled: bool,
    /// The compared quantity at the end of the run.
    value: f64,
    /// The positions at the end of the run (empty when unstable).
    x: Vec<Vec3>,
}

/// Runs `case` from rest for at least `--stable-seconds`, then until the compared quantity
/// settles or `--settle-seconds` pass. Stable: every value finite and the material's motion
/// bounded, the mass-weighted mean displacement below the scene's size (nodes of nearly empty
/// elements carry almost no material and may swing far without meaning anything).
fn run_until_settled(
    case: &Case,
    formulation: Formulation,
    scheme: Scheme,
    dt: f64,
    args: &SpeedErrorArgs,
    exec: &Executor,
) -> Run {
    const SETTLED: f64 = 1e-5;
    let mut step = stepper(case, formulation, scheme, dt, exec);
    let mut state = State::at_rest(&case.model);
    let bounds = Bounds::of(case);
    let window = (0.1 / dt).round().max(1.0) as usize;
    let min_steps = (args.stable_seconds / dt).ceil() as usize;
    let max_steps = min_steps.max((args.settle_seconds / dt).ceil() as usize);
    let mut windows: Vec<f64> = Vec::new();
    let unstable = || Run { stable: false, settled: false, value: f64::NAN, x: Vec::new() };
    for k in 1..=max_steps {
        step(&mut state, &case.loads);
        if !bounds.hold(case, &state.x) {
            return unstable();
        }
        if k % window == 0 {
            windows.push(measured(case, &state.x));
            if let [.., a, b, c] = windows[..]
                && k >= min_steps
                && (c - b).abs() <= SETTLED * c.abs()
                && (b - a).abs() <= SETTLED * c.abs()
            {
                return Run { stable: true, settled: true, value: c, x: state.x };
            }
        }
    }
    let value = measured(case, &state.x);
    Run { stable: true, settled: false, value, x: state.x }
}

/// What a run of a case must stay within to count as stable: finite, and its material's
/// mass-weighted mean displacement below the scene's size (nodes of nearly empty elements carry
/// almost no material and may swing far without meaning anything).
struct Bounds {
    size: f64,
    mass: f64,
}

impl Bounds {
    fn of(case: &Case) -> Self {
        let rest = &case.model.rest;
        let size = rest.iter().flat_map(|p| p.iter()).fold(0.0f64, |m, &c| m.max(c.abs()));
        Self { size, mass: case.model.total_mass() }
    }

    /// Whether positions `x` of `case` are within the bounds.
    fn hold(&self, case: &Case, x: &[Vec3]) -> bool {
        if x.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
            return false;
        }
        let mean: f64 = x
            .iter()
            .zip(&case.model.rest)
            .zip(&case.model.lumped_mass)
            .map(|((p, q), m)| m * (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt())
            .sum::<f64>()
            / self.mass;
        mean <= self.size
    }
}

/// The order of the pulled corner's discretisation error in the cell size for trilinear
/// hexahedra, which Richardson extrapolation assumes.
const RICHARDSON_ORDER: f64 = 2.0;

/// Scene B's reference: the static corotational answer at `--reference-cells`, and unless
/// `--no-richardson` at `--richardson-cells` and their extrapolation to h → 0.
struct BlockReference {
    coarse_cells: [usize; 3],
    coarse: f64,
    coarse_seconds: f64,
    fine: Option<FineReference>,
}

/// The finer static solve and the extrapolation it allows.
struct FineReference {
    cells: [usize; 3],
    value: f64,
    seconds: f64,
    /// `h_coarse / h_fine`, h the largest cell edge.
    ratio: f64,
    /// `u* = u_fine + (u_fine − u_coarse)/(ratio^p − 1)`.
    extrapolated: f64,
}

impl BlockReference {
    /// What scene B's rows are measured against.
    fn value(&self) -> f64 {
        self.fine.as_ref().map_or(self.coarse, |f| f.extrapolated)
    }

    /// The extrapolation's own error estimate, `|u* − u_fine|`.
    fn estimated_error(&self) -> Option<f64> {
        self.fine.as_ref().map(|f| (f.extrapolated - f.value).abs())
    }

    fn json(&self) -> serde_json::Value {
        let fine = self.fine.as_ref();
        serde_json::json!({
            "coarse_cells": self.coarse_cells,
            "coarse": self.coarse,
            "fine_cells": fine.map(|f| f.cells),
            "fine": fine.map(|f| f.value),
            "h_ratio": fine.map(|f| f.ratio),
            "order": RICHARDSON_ORDER,
            "extrapolated": fine.map(|f| f.extrapolated),
            "estimated_error": self.estimated_error(),
            "used": self.value(),
        })
    }

    fn print(&self) {
        let cells = |c: [usize; 3]| format!("{}x{}x{}", c[0], c[1], c[2]);
        match &self.fine {
            Some(f) => {
                println!(
                    "scene B's reference: the pulled corner of static corotational solves, {:.4} mm at {} cells ({:.1} s) and {:.4} mm at {} ({:.1} s), extrapolated to {:.4} mm assuming error ∝ h^{RICHARDSON_ORDER} (h the largest cell edge, ratio {:.4}), estimated error |u* − u_fine| = {:.4} mm ({:.2} %)",
                    self.coarse * 1e3,
                    cells(self.coarse_cells),
                    self.coarse_seconds,
                    f.value * 1e3,
                    cells(f.cells),
                    f.seconds,
                    f.extrapolated * 1e3,
                    f.ratio,
                    (f.extrapolated - f.value).abs() * 1e3,
                    100.0 * (f.extrapolated - f.value).abs() / f.extrapolated.abs()
                );
                // The shares of the load move between nodes as the mesh changes (the patch is a
                // radius in metres), so the corner does not converge smoothly in h: the
                // extrapolation's estimate is an order of magnitude, not a bound.
                println!(
                    "scene B errors are signed, (u − u*)/|u*| (negative: the row's corner moved less than the extrapolated answer); the extrapolation assumes the two meshes are in the asymptotic range, which the load's per-node shares (changing with the mesh) only roughly allow"
                );
            }
            None => println!(
                "scene B's reference: the pulled corner of a static corotational solve at {} cells, {:.4} mm ({:.1} s), not extrapolated (--no-richardson); scene B errors are signed, (u − r)/|r|",
                cells(self.coarse_cells),
                self.coarse * 1e3,
                self.coarse_seconds
            ),
        }
    }
}

/// Cells per axis from a flag's list.
fn three(flag: &str, cells: &[usize]) -> anyhow::Result<[usize; 3]> {
    match cells {
        &[x, y, z] if x > 0 && y > 0 && z > 0 => Ok([x, y, z]),
        _ => bail!("{flag} takes three positive counts, e.g. 33,22,18"),
    }
}

/// The static corotational answer at `cells`, and the largest cell edge (m).
fn block_static(args: &SpeedErrorArgs, cells: [usize; 3]) -> anyhow::Result<(f64, f64, f64)> {
    let label = format!("{}x{}x{}", cells[0], cells[1], cells[2]);
    eprintln!("reference for scene B: static corotational solve of b3.toml on {label} hexahedra …");
    let start = std::time::Instant::now();
    let fine = block_case(args, "B-ref", "b3.toml", Some(cells))?;
    let value =
        reference_of(&fine, Formulation::Corotational, "pulled-corner displacement", start)?;
    let (size, _) = fine.block.expect("a block");
    let h = (0..3).map(|a| size[a] / cells[a] as f64).fold(0.0, f64::max);
    Ok((value, h, start.elapsed().as_secs_f64()))
}

/// Scene B's reference (see [`BlockReference`]).
fn block_reference(args: &SpeedErrorArgs) -> anyhow::Result<BlockReference> {
    let coarse_cells = three("--reference-cells", &args.reference_cells)?;
    let fine_cells = if args.no_richardson {
        None
    } else {
        let cells = three("--richardson-cells", &args.richardson_cells)?;
        if (0..3).any(|a| cells[a] <= coarse_cells[a]) {
            bail!(
                "--richardson-cells {cells:?} must be finer than --reference-cells {coarse_cells:?} on every axis (or give --no-richardson)"
            );
        }
        Some(cells)
    };
    let (coarse, h_coarse, coarse_seconds) = block_static(args, coarse_cells)?;
    let fine = match fine_cells {
        Some(cells) => {
            let (value, h_fine, seconds) = block_static(args, cells)?;
            let ratio = h_coarse / h_fine;
            let extrapolated = value + (value - coarse) / (ratio.powf(RICHARDSON_ORDER) - 1.0);
            eprintln!(
                "  extrapolated (Richardson, p = {RICHARDSON_ORDER}) {:.4} mm",
                extrapolated * 1e3
            );
            Some(FineReference { cells, value, seconds, ratio, extrapolated })
        }
        None => None,
    };
    Ok(BlockReference { coarse_cells, coarse, coarse_seconds, fine })
}

/// Scenes B1, B2, B3 (not B2-moving, which has no static reference).
fn is_scene_b(scene: &str) -> bool {
    matches!(scene, "B1" | "B2" | "B3")
}

/// Runs the report.
pub fn run(args: &SpeedErrorArgs) -> anyhow::Result<()> {
    let wanted: Vec<String> = if args.scene == "all" {
        ["b1", "b2", "b3", "b2-moving", "c", "liver"].map(String::from).to_vec()
    } else {
        args.scene.split(',').map(|s| s.trim().to_lowercase()).collect()
    };
    let mut formulations = Vec::new();
    for m in &args.models {
        formulations.push(match m.as_str() {
            "corotational" => Formulation::Corotational,
            "linear" => Formulation::Linear,
            other => bail!("--models: unknown model {other:?}; expected corotational or linear"),
        });
    }
    if let Some(bad) = args.elements.iter().find(|e| element_kind(e).is_none()) {
        bail!(
            "--elements: unknown element kind {bad:?}; expected condensed, composite or incompatible"
        );
    }
    // Read before the scenes and references are built, so a bad file fails at once.
    let peer_points: Option<Vec<crate::peers::PeerPoint>> = if args.peers.is_empty() {
        None
    } else {
        let mut points = Vec::new();
        for path in &args.peers {
            points.extend(crate::peers::read_peers(path)?);
        }
        Some(points)
    };
    let mut cases: Vec<Case> = Vec::new();
    let mut moving_scene = None;
    let (mut liver_wanted, mut press_wanted) = (false, false);
    for w in &wanted {
        match w.as_str() {
            "b1" => cases.push(block_case(args, "B1", "b1.toml", None)?),
            "b2" => cases.push(block_case(args, "B2", "b2.toml", None)?),
            "b3" => cases.push(block_case(args, "B3", "b3.toml", None)?),
            "b2-moving" => moving_scene = Some(moving::Scene::read(args)?),
            "c" => {
                for n in [10, 20, 40, 80] {
                    cases.push(cantilever_case(args, n)?);
                }
            }
            "liver" => liver_wanted = true,
            "liver-press" => press_wanted = true,
            other => {
                bail!(
                    "unknown scene '{other}': expected all, b1, b2, b3, b2-moving, c, liver or liver-press"
                )
            }
        }
    }
    let coarsest = |levels: &[u32]| levels.iter().copied().max().unwrap_or(0);
    let small = if liver_wanted || press_wanted {
        eprintln!("building the livers' levels …");
        Some(Liver::read(
            &args.scene_dir,
            "liver-13k",
            "liver_13k.toml",
            coarsest(&args.liver_levels),
        )?)
    } else {
        None
    };
    let large = if liver_wanted {
        Some(Liver::read(
            &args.scene_dir,
            "liver-109k",
            "liver_109k.toml",
            coarsest(&args.liver_109k_levels),
        )?)
    } else {
        None
    };
    let elements: Vec<&'static str> =
        args.elements.iter().filter_map(|e| element_kind(e)).collect();
    let liver_cases = |liver: &Liver, levels: &[u32]| -> anyhow::Result<Vec<Case>> {
        let mut out = Vec::new();
        for &level in levels {
            for &element in &elements {
                // Level 0's elements are voxels: nothing inside them to relax.
                if level == 0 && element != "condensed" {
                    continue;
                }
                out.push(liver.case(level, element)?);
            }
        }
        Ok(out)
    };
    if let (Some(small), Some(large)) = (&small, &large) {
        cases.extend(liver_cases(small, &args.liver_levels)?);
        cases.extend(liver_cases(large, &args.liver_109k_levels)?);
    }
    let mut press_cases = match (&small, press_wanted) {
        (Some(small), true) => liver_cases(small, &args.liver_levels)?,
        _ => Vec::new(),
    };
    if let Some(limit) = args.max_elements {
        cases.retain(|c| c.model.elements.len() <= limit);
        press_cases.retain(|c| c.model.elements.len() <= limit);
        moving_scene = moving_scene.filter(|m| m.elements() <= limit);
    }
    if cases.is_empty() && moving_scene.is_none() && press_cases.is_empty() {
        bail!("no scene left to run (check --scene and --max-elements)");
    }
    let block_reference = if cases.iter().any(|c| is_scene_b(&c.scene)) {
        let reference = block_reference(args)?;
        for c in cases.iter_mut().filter(|c| is_scene_b(&c.scene)) {
            c.reference = Some(reference.value());
        }
        Some(reference)
    } else {
        None
    };
    let liver_reference = match (&small, &large) {
        (Some(small), Some(large)) if cases.iter().any(|c| c.scene.starts_with("liver")) => {
            Some(set_liver_references(&mut cases, small, large, &formulations)?)
        }
        _ => None,
    };
    // The large liver's levels are in its cases now; the rest is not needed any more.
    drop(large);
    // One executor for every row, so that INCISE_THREADS applies to the whole report; the
    // one-thread column runs the same rows again on an executor of one thread.
    let exec = incise_scene::environment::exec_from_environment(ExecSpec::default())?.executor();
    let one = Executor::new(1, Idle::DEFAULT_SPIN);
    let bar = crate::progress::stages(
        cases.len() as u64 + u64::from(moving_scene.is_some()) + u64::from(!press_cases.is_empty()),
    );
    let mut rows = Vec::new();
    let mut explicit_limits = Vec::new();
    for case in &cases {
        bar.set_message(format!("{} {}", case.scene, case.resolution));
        let explicit_limit = stable_dt(
            &case.model,
            &HexForceField::new(&case.model, Formulation::Linear).with_executor(exec.clone()),
            &case.fixed,
        );
        let mesh = format!("{} level {} {}", case.resolution, case.level, case.element);
        explicit_limits.push((case.scene.clone(), mesh, explicit_limit));
        for &formulation in &formulations {
            let reference = match case.reference_model {
                None => case.reference,
                Some(m) if m == formulation => case.reference,
                Some(_) if formulation == Formulation::Corotational => case.corotational_reference,
                Some(_) => None,
            };
            let errors_of = |value: f64, x: &[Vec3]| errors(case, formulation, reference, value, x);
            let error_static = static_positions(case, formulation, &mut Preconditioner::Cholesky)
                .and_then(|x| errors_of(measured(case, &x), &x).error);
            // The linear model's matrix is constant: one exact factorisation serves every step,
            // so the direct solver is measured for it too.
            let direct = (formulation == Formulation::Linear && is_scene_b(&case.scene))
                .then_some(Scheme::Implicit(LinearSolver::Cholesky));
            let schemes = case
                .solvers
                .iter()
                .map(|&s| Scheme::Implicit(s))
                .chain(direct)
                .chain([Scheme::Explicit]);
            for scheme in schemes {
                for dt in [1e-3, 1e-2] {
                    let outcome = match scheme {
                        Scheme::Explicit if dt > explicit_limit => {
                            Run { stable: false, settled: false, value: f64::NAN, x: Vec::new() }
                        }
                        _ => run_until_settled(case, formulation, scheme, dt, args, &exec),
                    };
                    let ok = outcome.stable;
                    let (median, min, max) = if ok {
                        timed_rates(case, formulation, scheme, dt, args, &exec)
                    } else {
                        (0.0, 0.0, 0.0)
                    };
                    let one_thread = match scheme {
                        Scheme::Implicit(_) if ok => {
                            Some(timed_rates(case, formulation, scheme, dt, args, &one).0)
                        }
                        _ => None,
                    };
                    let Errors { error, signed, level0 } = if outcome.settled {
                        errors_of(outcome.value, &outcome.x)
                    } else {
                        Errors::default()
                    };
                    rows.push(Row {
                        steps_per_s: median,
                        steps_per_s_min: min,
                        steps_per_s_max: max,
                        steps_per_s_one_thread: one_thread,
                        error,
                        error_abs: error.map(f64::abs),
                        error_signed: signed,
                        error_level0: level0,
                        error_static,
                        settled: outcome.settled,
                        stable: ok,
                        ..Row::of(case, formulation, scheme, dt)
                    });
                }
            }
        }
        if let Some((size, cells)) = case.block.filter(|_| is_scene_b(&case.scene)) {
            bar.set_message(format!("{} {} tensor-mass", case.scene, case.resolution));
            rows.extend(tensor_mass_rows(case, size, cells, args));
        }
        bar.inc(1);
    }
    let moving = match &moving_scene {
        Some(scene) => {
            let (moving_rows, summary) = moving::rows(scene, args, &exec, &bar)?;
            rows.extend(moving_rows);
            bar.inc(1);
            Some((scene, summary))
        }
        None => None,
    };
    let press = match (&small, press_cases.is_empty()) {
        (Some(small), false) => {
            bar.set_message(press::SCENE);
            let cases: Vec<&Case> = press_cases.iter().collect();
            let (press_rows, references) = press::rows(small, &cases, &formulations, args, &exec)?;
            rows.extend(press_rows);
            bar.inc(1);
            references
        }
        _ => Vec::new(),
    };
    bar.finish_and_clear();
    print_table(&rows);
    if !cases.is_empty() {
        println!(
            "timing: hexahedral rows take {} untimed steps, then {} runs of {}-{} steps lasting about {} s each (median, min, max), from the same state on; tensor-mass rows time {} steps from rest",
            args.warmup_steps,
            args.repeats,
            args.steps,
            args.max_steps,
            args.run_seconds,
            args.steps
        );
    }
    println!(
        "threads: steps/s, min and max on {} thread(s) (the machine's cores, at most 2, unless INCISE_THREADS says otherwise; meshes under 1,500 elements keep most loops on one), 1T steps/s on {} (implicit rows, the same protocol)",
        exec.threads(),
        one.threads()
    );
    if let Some(reference) = &block_reference {
        reference.print();
    }
    if let Some(liver) = &liver_reference {
        print_liver_reference(liver);
    }
    for reference in &press {
        reference.print();
    }
    if let Some((scene, summary)) = &moving {
        summary.print(scene, args.repeats.max(1));
    }
    if !explicit_limits.is_empty() {
        println!();
        println!(
            "explicit stable dt per mesh (rest stiffness; an explicit row runs only at or below it):"
        );
        for (scene, resolution, limit) in &explicit_limits {
            println!("  {scene:<11} {resolution:<36} {limit:.3e} s");
        }
    }
    if let Some(limit) = args.max_error {
        match rows
            .iter()
            .filter(|r| r.stable && r.error_abs.is_some_and(|e| e <= limit))
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
                .map(|r| crate::plot::Point {
                    model: r.model,
                    element: r.element,
                    scene: &r.scene,
                    steps_per_s: r.steps_per_s,
                    error: r.error_abs,
                    stable: r.stable,
                })
                .collect::<Vec<_>>(),
            (!args.peers.is_empty()).then_some(peers.as_slice()),
        )
        .with_context(|| format!("drawing {}", path.display()))?;
    }
    if args.json {
        let mut references = serde_json::Map::new();
        for c in &cases {
            // A liver's own level 0: its rows' `error_level0`.
            let key =
                if c.organ.is_some() { format!("{} level 0", c.scene) } else { c.scene.clone() };
            if let Some(r) = c.reference {
                references.insert(key.clone(), r.into());
            }
            // A scene whose rows have a reference per model: the corotational one beside it.
            if let Some(r) = c.corotational_reference {
                references.insert(format!("{key} corotational"), r.into());
            }
        }
        if let Some(liver) = liver_reference {
            references.insert("liver".into(), liver);
        }
        if !press.is_empty() {
            let runs: Vec<serde_json::Value> = press.iter().map(press::Reference::json).collect();
            references.insert(press::SCENE.into(), runs.into());
        }
        if let Some(reference) = &block_reference {
            references.insert("B".into(), reference.json());
        }
        if let Some((_, summary)) = &moving {
            references.insert(moving::SCENE.into(), summary.json());
        }
        let threads = serde_json::json!({
            "steps_per_s": exec.threads(),
            "steps_per_s_one_thread": one.threads(),
        });
        let mut out =
            serde_json::json!({ "rows": rows, "references": references, "threads": threads });
        if !args.peers.is_empty() {
            out["peers"] = serde_json::to_value(&comparisons)?;
        }
        println!("{out}");
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
            let error = p.displacement.zip(reference).map(|(u, r)| (u - r).abs() / r.abs());
            let ours = error.and_then(|limit| {
                rows.iter()
                    .filter(|r| {
                        r.stable
                            && is_scene_b(&r.scene)
                            && (r.dt - p.dt).abs() < 1e-12
                            && r.error_abs.is_some_and(|e| e <= limit)
                    })
                    .max_by(|a, b| a.steps_per_s.total_cmp(&b.steps_per_s))
                    .map(|r| OursAtEqualError {
                        scene: r.scene.clone(),
                        resolution: r.resolution.clone(),
                        model: r.model,
                        integrator: r.integrator,
                        solver: r.solver,
                        steps_per_s: r.steps_per_s,
                        error: r.error_abs.unwrap_or(f64::NAN),
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
/// step. Its error is its static answer (dynamic relaxation: the same explicit integrator run to
/// rest, at half the stable step) against the same reference.
fn tensor_mass_rows(
    case: &Case,
    size: [f64; 3],
    cells: [usize; 3],
    args: &SpeedErrorArgs,
) -> Vec<Row> {
    use incise_fem::forcefield::tet::{
        Elasticity, Lame, TensorMassForceField, TetMaterial, TetModel,
    };
    use incise_fem::ode::central_difference::{CentralDifference, stable_dt as tet_stable_dt};
    use incise_fem::ode::relax::{Prescribed, RelaxSettings, Statics, relax};
    use incise_mesh::TetTopology;
    let spacing: Vec3 = std::array::from_fn(|a| size[a] / cells[a] as f64);
    let mesh = incise_mesh::generate::lattice_to_tets(
        cells,
        |_, _, _| Some(1),
        |i, j, k| [i as f64 * spacing[0], j as f64 * spacing[1], k as f64 * spacing[2]],
    )
    .expect("a block tetrahedralises");
    let model = TetModel::new(&mesh, |_| {
        TetMaterial::isotropic(Lame::from_young_poisson(3e3, 0.45), 1000.0)
    });
    let topo = TetTopology::new(&mesh);
    let fixed = FixedNodes::plane(&model.rest, 2, size[2], 1e-9);
    // The same loads as the hexahedral rows: gravity and 0.5 N spread near the corner.
    let corner = [size[0], size[1], 0.0];
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
        let signed = case.reference.filter(|_| settled.converged).map(|r| (answer - r) / r.abs());
        let error = signed.map(|e| if case.signed { e } else { e.abs() });
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
                element: "tetrahedra",
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
                steps_per_s_one_thread: None,
                // Dynamic relaxation is this integrator run to rest (at half its stable step).
                error: error.filter(|_| ok),
                error_abs: error.filter(|_| ok).map(f64::abs),
                error_signed: signed.filter(|_| ok).map(|e| BTreeMap::from([(case.quantity, e)])),
                error_level0: None,
                error_static: error,
                trajectory_error: None,
                settled: ok && settled.converged,
                stable: ok,
            });
        }
        // Settling an implicit tensor-mass mesh from rest costs hundreds of CG iterations a step
        // (the products are not yet optimised): B3's 23,760 tetrahedra would take most of the
        // report's time, so its implicit rows are left out.
        if mesh.tets().len() <= IMPLICIT_TET_MAX {
            rows.extend(implicit_tensor_mass_rows(
                (case, args),
                (name, kind, error),
                (&model, &topo, &fixed),
                (&external, probe),
            ));
        }
    }
    rows
}

/// The largest tensor-mass mesh (tetrahedra) the report steps implicitly.
const IMPLICIT_TET_MAX: usize = 5_000;

/// Implicit Euler on the tensor-mass block through the same `ForceField` interface as the
/// hexahedra, at 1 ms and 10 ms with the hexahedral rows' damping (α = 2 /s, β = 0.01 s):
/// timed like the explicit tensor-mass rows (`--steps` steps from rest), on the report's threads
/// and on one, its error from its own run settled at rest (the probe moved less than 1e-5 of
/// itself over two 0.1 s windows, within `--settle-seconds`); `error_static` is the relaxed
/// static answer's.
fn implicit_tensor_mass_rows(
    (case, args): (&Case, &SpeedErrorArgs),
    (name, kind, error_static): (
        &'static str,
        incise_fem::forcefield::tet::Elasticity,
        Option<f64>,
    ),
    (model, topo, fixed): (
        &incise_fem::forcefield::tet::TetModel,
        &incise_mesh::TetTopology,
        &FixedNodes,
    ),
    (external, probe): (&[Vec3], usize),
) -> Vec<Row> {
    use incise_fem::forcefield::tet::TensorMassForceField;
    let loads = Loads { gravity: [0.0; 3], nodal: external.to_vec() };
    let damping = Rayleigh { alpha: 2.0, beta: 0.01 };
    let settings = CgSettings { tolerance: 1e-6, max_iterations: 30 * model.vertex_count() };
    let mut fields = [
        TensorMassForceField::new(model, topo, kind),
        TensorMassForceField::new(model, topo, kind).with_executor(Executor::single_thread()),
    ];
    let displacement = |x: &[Vec3]| {
        (0..3).map(|a| (x[probe][a] - model.rest[probe][a]).powi(2)).sum::<f64>().sqrt()
    };
    let mut rows = Vec::new();
    for dt in [1e-3, 1e-2] {
        let mut run = |steps: usize, settle: bool, threads: usize| -> (bool, f64, Option<f64>) {
            let ff = &mut fields[usize::from(threads == 1)];
            let mut be = BackwardEuler::new(dt, damping, settings);
            let mut state =
                State { x: model.rest.clone(), v: vec![[0.0; 3]; model.vertex_count()] };
            let window = (0.1 / dt).round().max(1.0) as usize;
            let mut marks = Vec::new();
            let start = std::time::Instant::now();
            let limit = if settle { (args.settle_seconds / dt).ceil() as usize } else { steps };
            for k in 1..=limit {
                let mut elastic = ff.bind(model, topo, None);
                be.step_fields(model, &mut [&mut elastic], fixed, &loads, &mut state);
                if settle && k % window == 0 {
                    marks.push(displacement(&state.x));
                    if let [.., a, b, c] = marks[..]
                        && (b - a).abs() <= 1e-5 * c.abs()
                        && (c - b).abs() <= 1e-5 * c.abs()
                    {
                        break;
                    }
                }
            }
            let secs = start.elapsed().as_secs_f64();
            let finite = state.x.iter().flatten().all(|c| c.is_finite());
            let settled = settle
                && marks.len() >= 3
                && marks[marks.len() - 3..]
                    .windows(2)
                    .all(|w| (w[1] - w[0]).abs() <= 1e-5 * w[1].abs());
            (finite, steps as f64 / secs, settled.then(|| displacement(&state.x)))
        };
        let (ok, _, answer) = run(0, true, 2);
        let mut rates = |threads| -> Vec<f64> {
            if !ok {
                return vec![0.0];
            }
            let mut r: Vec<f64> =
                (0..args.repeats.max(1)).map(|_| run(args.steps, false, threads).1).collect();
            r.sort_by(f64::total_cmp);
            r
        };
        let (rates, one) = (rates(2), rates(1));
        let signed = case.reference.zip(answer).map(|(r, u)| (u - r) / r.abs());
        let error = signed.map(|e| if case.signed { e } else { e.abs() });
        rows.push(Row {
            scene: case.scene.clone(),
            element: "tetrahedra",
            model: name,
            integrator: "implicit-euler",
            solver: "jacobi-cg",
            resolution: case.resolution.clone(),
            level: 0,
            elements: model.tets.len(),
            dofs: 3 * model.vertex_count(),
            dt,
            steps_per_s: rates[rates.len() / 2],
            steps_per_s_min: rates[0],
            steps_per_s_max: rates[rates.len() - 1],
            steps_per_s_one_thread: ok.then(|| one[one.len() / 2]),
            error,
            error_abs: error.map(f64::abs),
            error_signed: signed.map(|e| BTreeMap::from([(case.quantity, e)])),
            error_level0: None,
            error_static,
            trajectory_error: None,
            settled: answer.is_some(),
            stable: ok,
        });
    }
    rows
}

/// The liver's reference and what its rows' errors mean.
fn print_liver_reference(liver: &serde_json::Value) {
    let mm = |v: &serde_json::Value, key: &str| v[key].as_f64().unwrap_or(f64::NAN) * 1e3;
    let measures = &liver["measures"];
    println!(
        "the liver's reference: {} ({} points: the 13,648-voxel liver's voxel centres, {} without a fine node left out)",
        liver["model"].as_str().unwrap_or_default(),
        measures["points"],
        measures["unmatched"]
    );
    for name in ["corotational", "linear"] {
        let m = &measures[name];
        if m.is_object() {
            println!(
                "  {name}: centre of mass {:.3} mm, largest {:.3} mm, RMS {:.3} mm",
                mm(m, "centre_of_mass"),
                mm(m, "max"),
                mm(m, "rms")
            );
        }
    }
    if let Some(level0) = liver["liver-13k level 0"].as_object() {
        for (name, e) in level0 {
            println!(
                "  the 13,648-voxel liver's level 0 ({name}) against it: centre of mass {:+.2} %, largest {:+.2} %, RMS {:+.2} %",
                mm(e, "centre_of_mass") / 10.0,
                mm(e, "max") / 10.0,
                mm(e, "rms") / 10.0
            );
        }
    }
    println!(
        "liver rows: error = the larger magnitude of the centre of mass's and the largest displacement's signed errors against it (each in error_signed); L0 err = the centre of mass against the same liver's own level 0 (what model = \"auto\" calibrates)"
    );
}

fn print_table(rows: &[Row]) {
    println!(
        "{:<11} {:<18} {:<10} {:<15} {:<12} {:<14} {:>5} {:>8} {:>7} {:>8} {:>10} {:>10} {:>10} {:>10} {:>9} {:>9} {:>6} {:>9}",
        "scene",
        "model",
        "element",
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
        "1T steps/s",
        "error",
        "traj err",
        "stable",
        "L0 err"
    );
    let percent =
        |e: Option<f64>| e.map_or_else(|| "-".to_string(), |e| format!("{:.2} %", e * 100.0));
    for r in rows {
        let error = match r.error {
            // Scene B's errors are signed: the sign says too stiff or too soft.
            Some(e) if is_scene_b(&r.scene) => format!("{:+.2} %", e * 100.0),
            Some(e) => format!("{:.2} %", e * 100.0),
            // The moving and pressed scenes' rows are trajectories: they never settle.
            None if r.stable
                && !r.settled
                && r.scene != moving::SCENE
                && r.scene != press::SCENE =>
            {
                "unsettled".to_string()
            }
            None => "-".to_string(),
        };
        println!(
            "{:<11} {:<18} {:<10} {:<15} {:<12} {:<14} {:>5} {:>8} {:>7} {:>8} {:>10.1} {:>10.1} {:>10.1} {:>10} {:>9} {:>9} {:>6} {:>9}",
            r.scene,
            r.model,
            r.element,
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
            r.steps_per_s_one_thread.map_or_else(|| "-".to_string(), |s| format!("{s:.1}")),
            error,
            percent(r.trajectory_error),
            if r.stable { "yes" } else { "no" },
            percent(r.error_level0)
        );
    }
}

fn write_csv(path: &std::path::Path, rows: &[Row]) -> std::io::Result<()> {
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    let mut f = std::fs::File::create(path)?;
    // New columns go at the end, so that scripts reading the older ones by position still work.
    writeln!(
        f,
        "scene,model,integrator,solver,resolution,level,elements,dofs,dt,steps_per_s,steps_per_s_min,steps_per_s_max,error,stable,error_static,settled,error_abs,trajectory_error,steps_per_s_one_thread,element,error_signed,error_level0"
    )?;
    // `quantity=fraction` pairs joined by `;`, so the column stays one CSV field.
    let signed = |m: &Option<BTreeMap<&'static str, f64>>| {
        m.as_ref().map_or(String::new(), |m| {
            m.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(";")
        })
    };
    for r in rows {
        writeln!(
            f,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
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
            opt(r.error),
            r.stable,
            opt(r.error_static),
            r.settled,
            opt(r.error_abs),
            opt(r.trajectory_error),
            opt(r.steps_per_s_one_thread),
            r.element,
            signed(&r.error_signed),
            opt(r.error_level0),
        )?;
    }
    Ok(())
}
