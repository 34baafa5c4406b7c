//! Scene liver-press: the 13,648-voxel liver hanging under gravity, pressed by a tool. Each row
//! starts from its own model's static equilibrium; a tool then pushes the organ's lowest point
//! upwards with a force that rises smoothly to [`FORCE_N`] over [`RAMP`], holds until
//! [`RELEASE`], falls back over another [`RAMP`], and the organ swings free to the end of the run
//! (2 s). The tool's tip is a ball of radius [`TIP_RADIUS`] centred on the organ's lowest
//! voxel: its force is spread evenly over the voxels whose centres lie in it (a point force would
//! indent the voxels under it without bound as they get finer, and the reference would measure
//! that), and the contact point's displacement is the mean of those voxels' centres'. Every model
//! reads that mean through its elements' trilinear field ([`super::organ::Sampler`]) and takes
//! the force as the transpose, the nodal loads that do the same work.
//!
//! The reference is the finest model whose 2 s of dynamics are affordable here: the same liver at
//! level 0 with the row's model, stepped at [`REFERENCE_DT`] with CG to [`REFERENCE_TOLERANCE`]
//! (about a minute per model on a 2-core machine; the 109,201-voxel liver's level 0 would take
//! an hour or more: an operator product alone costs 15 ms there, and an implicit step several).
//! A row's `trajectory_error` is the RMS over its steps of the distance between its contact
//! point's displacement and the reference's at the same time, over the reference's largest
//! displacement; `error_signed.peak` is its largest displacement's signed error.

use super::organ::Sampler;
use super::{Case, Liver, Preconditioner, Row, Scheme, SpeedErrorArgs, stepper};
use anyhow::Context;
use incise_fem::model::{Loads, State};
use incise_fem::ode::{LinearSolver, stable_dt};
use incise_fem::{Executor, Formulation, HexForceField};
use incise_math::Vec3;
use std::collections::BTreeMap;
use std::time::Instant;

/// The rows' scene name.
pub(super) const SCENE: &str = "liver-13k-press";
/// The tool's largest force (N), upwards.
const FORCE_N: f64 = 2.0;
/// How long the force takes to rise, and to fall (s).
const RAMP: f64 = 0.25;
/// When the force starts to fall (s).
const RELEASE: f64 = 1.0;
/// The tool tip's radius (m).
const TIP_RADIUS: f64 = 0.015;
/// The reference's step (s): half the 1 ms rows' step.
pub(super) const REFERENCE_DT: f64 = 5e-4;
/// The reference's CG tolerance, far below the rows' (the scene's 1e-6).
const REFERENCE_TOLERANCE: f64 = 1e-9;

/// The tool's force at time `t` as a fraction of [`FORCE_N`]: smooth (half cosine) rise and fall.
fn profile(t: f64) -> f64 {
    let rise = |s: f64| 0.5 - 0.5 * (std::f64::consts::PI * s.clamp(0.0, 1.0)).cos();
    if t < RELEASE { rise(t / RAMP) } else { 1.0 - rise((t - RELEASE) / RAMP) }
}

/// Where the tool touches: per voxel under the tip, its corners at level 0 (their mean is the
/// voxel's centre).
pub(super) struct Contact {
    voxels: Vec<Vec<u32>>,
}

impl Contact {
    /// The voxels of `level0` (the liver's level-0 case) whose centres lie within [`TIP_RADIUS`]
    /// of the lowest voxel's (least z, then least index).
    fn under_tip(level0: &Case) -> Self {
        let rest = &level0.model.rest;
        let centre = |nodes: &[u32; 8]| -> Vec3 {
            std::array::from_fn(|a| nodes.iter().map(|&n| rest[n as usize][a]).sum::<f64>() / 8.0)
        };
        let elements = &level0.model.elements;
        let lowest = elements
            .iter()
            .map(|e| centre(&e.nodes))
            .min_by(|a, b| a[2].total_cmp(&b[2]))
            .expect("a liver has voxels");
        let voxels = elements
            .iter()
            .filter(|e| {
                let c = centre(&e.nodes);
                (0..3).map(|a| (c[a] - lowest[a]).powi(2)).sum::<f64>() <= TIP_RADIUS.powi(2)
            })
            .map(|e| e.nodes.to_vec())
            .collect();
        Self { voxels }
    }
}

/// A model's reading of the contact point and its nodal load.
struct Probe {
    /// The contact point's displacement is `Σ w (x − rest)` over these `(node, w)`: the
    /// sampler's reading composed into weights once, so that reading it costs a few products
    /// per step and the timed runs time the integrator.
    weights: Vec<(usize, f64)>,
    /// The tool's largest force as nodal loads on the model: the same weights times the force.
    load: Vec<Vec3>,
}

impl Probe {
    fn new(liver: &Liver, case: &Case, contact: &Contact) -> anyhow::Result<Self> {
        let (grid, _) = liver.level(case.level)?;
        let sampler = Sampler::new(liver.level(0)?, (grid, &case.model), contact.voxels.clone())?;
        let unit = sampler.mean_load([1.0, 0.0, 0.0], case.model.node_count());
        let weights: Vec<(usize, f64)> =
            unit.iter().enumerate().filter(|(_, f)| f[0] != 0.0).map(|(n, f)| (n, f[0])).collect();
        let load = unit.iter().map(|f| [0.0, 0.0, FORCE_N * f[0]]).collect();
        Ok(Self { weights, load })
    }

    fn displacement(&self, rest: &[Vec3], x: &[Vec3]) -> Vec3 {
        let mut u = [0.0; 3];
        for &(n, w) in &self.weights {
            for a in 0..3 {
                u[a] += w * (x[n][a] - rest[n][a]);
            }
        }
        u
    }
}

/// One run: the contact point's displacement from the start after every step (and at the
/// start), whether it stayed within its bounds (see `Bounds`), and its wall time.
struct Trajectory {
    u: Vec<Vec3>,
    bounded: bool,
    seconds: f64,
}

/// Runs `case` with `formulation` and `scheme` at `dt` for `seconds` from `start` (its static
/// equilibrium), under gravity and the tool.
#[allow(clippy::too_many_arguments, reason = "one run's whole set-up")]
fn run(
    case: &Case,
    probe: &Probe,
    formulation: Formulation,
    scheme: Scheme,
    dt: f64,
    seconds: f64,
    start: &[Vec3],
    exec: &Executor,
) -> Trajectory {
    let mut step = stepper(case, formulation, scheme, dt, exec);
    let mut state = State { x: start.to_vec(), v: vec![[0.0; 3]; start.len()] };
    let origin = probe.displacement(&case.model.rest, start);
    let at = |x: &[Vec3]| -> Vec3 {
        let u = probe.displacement(&case.model.rest, x);
        std::array::from_fn(|a| u[a] - origin[a])
    };
    let steps = (seconds / dt).round() as usize;
    let mut u = Vec::with_capacity(steps + 1);
    u.push([0.0; 3]);
    let mut loads = Loads { gravity: case.loads.gravity, nodal: case.loads.nodal.clone() };
    let bounds = super::Bounds::of(case);
    let started = Instant::now();
    let mut bounded = true;
    for k in 1..=steps {
        // Implicit Euler balances the forces at the step's end, symplectic Euler at its start.
        let t = match scheme {
            Scheme::Explicit => (k - 1) as f64 * dt,
            Scheme::Implicit(_) => k as f64 * dt,
        };
        let s = profile(t);
        loads.nodal.clear();
        loads.nodal.extend(
            probe
                .load
                .iter()
                .zip(case.loads.nodal.iter().chain(std::iter::repeat(&[0.0; 3])))
                .map(|(f, g)| std::array::from_fn(|a| g[a] + s * f[a])),
        );
        step(&mut state, &loads);
        if !bounds.hold(case, &state.x) {
            bounded = false;
            break;
        }
        u.push(at(&state.x));
    }
    Trajectory { u, bounded, seconds: started.elapsed().as_secs_f64() }
}

fn norm(u: &Vec3) -> f64 {
    (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
}

/// The reference trajectory for one model, and what the footer says about it.
pub(super) struct Reference {
    model: Formulation,
    u: Vec<Vec3>,
    peak: f64,
    seconds: f64,
}

/// The reference runs and the rows of the press scene.
pub(super) fn rows(
    small: &Liver,
    cases: &[&Case],
    formulations: &[Formulation],
    args: &SpeedErrorArgs,
    exec: &Executor,
) -> anyhow::Result<(Vec<Row>, Vec<Reference>)> {
    let mut level0 = small.case(0, "condensed")?;
    let contact = Contact::under_tip(&level0);
    eprintln!("{SCENE}: the tool's tip covers {} voxels", contact.voxels.len());
    level0.tolerance = REFERENCE_TOLERANCE;
    let seconds = args.press_seconds;
    let mut references = Vec::new();
    for &formulation in formulations {
        eprintln!(
            "reference for {SCENE}: {} level 0 of {}, {seconds} s at dt = {} ms …",
            super::model_name(formulation),
            small.file,
            REFERENCE_DT * 1e3
        );
        let started = Instant::now();
        let start = small
            .static_level0(&level0, formulation)?
            .context("the liver's static equilibrium at level 0 did not converge")?;
        let probe = Probe::new(small, &level0, &contact)?;
        let t = run(
            &level0,
            &probe,
            formulation,
            Scheme::Implicit(LinearSolver::JacobiCg),
            REFERENCE_DT,
            seconds,
            &start,
            exec,
        );
        anyhow::ensure!(t.bounded, "the {SCENE} reference blew up");
        let peak = t.u.iter().map(norm).fold(0.0, f64::max);
        let elapsed = started.elapsed().as_secs_f64();
        eprintln!("  peak {:.4} mm ({elapsed:.1} s)", peak * 1e3);
        references.push(Reference { model: formulation, u: t.u, peak, seconds: elapsed });
    }
    let mut rows = Vec::new();
    for case in cases {
        let probe = Probe::new(small, case, &contact)?;
        // As the settled rows: explicit steps only at or below the mesh's stable step at rest.
        let explicit_limit = stable_dt(
            &case.model,
            &HexForceField::new(&case.model, Formulation::Linear).with_executor(exec.clone()),
            &case.fixed,
        );
        for reference in &references {
            let formulation = reference.model;
            let Some(start) =
                super::static_positions(case, formulation, &mut Preconditioner::Cholesky)
            else {
                eprintln!(
                    "{SCENE}: no static equilibrium at level {}; its rows are left out",
                    case.level
                );
                continue;
            };
            let schemes =
                case.solvers.iter().map(|&s| Scheme::Implicit(s)).chain([Scheme::Explicit]);
            for scheme in schemes {
                for dt in [1e-3, 1e-2] {
                    let stride = (dt / REFERENCE_DT).round() as usize;
                    if matches!(scheme, Scheme::Explicit) && dt > explicit_limit {
                        rows.push(Row {
                            scene: SCENE.into(),
                            ..Row::of(case, formulation, scheme, dt)
                        });
                        continue;
                    }
                    let t = run(case, &probe, formulation, scheme, dt, seconds, &start, exec);
                    let stable = t.bounded;
                    let (trajectory_error, peak_error) = if stable {
                        let sum: f64 =
                            t.u.iter()
                                .enumerate()
                                .map(|(k, u)| {
                                    let r = reference.u[(k * stride).min(reference.u.len() - 1)];
                                    (0..3).map(|a| (u[a] - r[a]).powi(2)).sum::<f64>()
                                })
                                .sum();
                        let rms = (sum / t.u.len() as f64).sqrt() / reference.peak;
                        let peak = t.u.iter().map(norm).fold(0.0, f64::max);
                        (Some(rms), Some((peak - reference.peak) / reference.peak))
                    } else {
                        (None, None)
                    };
                    let rate = if stable { (t.u.len() - 1) as f64 / t.seconds } else { 0.0 };
                    rows.push(Row {
                        scene: SCENE.into(),
                        steps_per_s: rate,
                        steps_per_s_min: rate,
                        steps_per_s_max: rate,
                        error_signed: peak_error.map(|e| BTreeMap::from([("peak", e)])),
                        trajectory_error,
                        stable,
                        ..Row::of(case, formulation, scheme, dt)
                    });
                }
            }
        }
    }
    Ok((rows, references))
}

impl Reference {
    pub(super) fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "model": super::row_model(self.model),
            "dt": REFERENCE_DT,
            "cg_tolerance": REFERENCE_TOLERANCE,
            "peak_displacement": self.peak,
            "seconds": self.seconds,
        })
    }

    pub(super) fn print(&self) {
        println!(
            "{SCENE}'s reference ({}): the 13,648-voxel liver at level 0, dt = {} ms, CG to {:e}; the tool's contact point moves at most {:.3} mm ({:.0} s)",
            super::row_model(self.model),
            REFERENCE_DT * 1e3,
            REFERENCE_TOLERANCE,
            self.peak * 1e3,
            self.seconds
        );
    }
}
