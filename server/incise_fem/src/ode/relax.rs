//! Static equilibrium of the tensor-mass model by dynamic relaxation with kinetic damping: the
//! explicit integrator runs undamped and every time the kinetic energy passes a peak all
//! velocities are zeroed, so the motion loses its energy at the potential's lowest point along
//! its path (Cundall's method). It needs only forces (no tangent stiffness, which for St
//! Venant-Kirchhoff under compression is indefinite) and converges for every mode at the rate of
//! the slowest, which suits the large-deformation references of paper 2's Table 1.

use crate::constraint::FixedNodes;
use crate::forcefield::tet::TensorMassForceField;
use crate::forcefield::tet::element::TetModel;
use crate::forcefield::tet::incompressible::Incompressibility;
use crate::ode::CentralDifference;
use incise_math::Vec3;
use incise_mesh::TetTopology;

/// Vertices moved to prescribed positions (they are held there, like fixed ones).
#[derive(Clone, Debug, PartialEq)]
pub struct Prescribed {
    /// Vertex and its target position (m).
    pub targets: Vec<(usize, Vec3)>,
    /// Steps over which the vertices move from rest to their targets.
    pub ramp_steps: usize,
}

/// When to stop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelaxSettings {
    /// Stop when the largest force on a free vertex is below this fraction of the largest force
    /// on a held one (the reaction).
    pub tolerance: f64,
    /// Give up after this many steps.
    pub max_steps: usize,
}

/// What a relaxation did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelaxReport {
    /// Steps run (in the last attempt).
    pub steps: usize,
    /// The step used (s): the one asked for, halved after each attempt that blew up.
    pub dt: f64,
    /// Final residual (see [`RelaxSettings::tolerance`]).
    pub residual: f64,
    /// Whether the tolerance was reached.
    pub converged: bool,
}

/// Attempts with a halved step after a blow-up: the stable step is estimated from the rest
/// stiffness, and the incompressibility penalty or strongly stretched SVK can be stiffer.
const ATTEMPTS: usize = 5;

/// A static problem: the model, its supports and what moves or pulls it.
#[derive(Clone, Copy)]
pub struct Statics<'a> {
    /// Rest data.
    pub model: &'a TetModel,
    /// Live tetrahedra.
    pub topology: &'a TetTopology,
    /// The stiffness.
    pub force_field: &'a TensorMassForceField,
    /// The incompressibility penalty, if any.
    pub penalty: Option<&'a Incompressibility>,
    /// Held vertices, the prescribed ones included.
    pub fixed: &'a FixedNodes,
    /// Vertices moved to targets.
    pub prescribed: &'a Prescribed,
    /// External forces (N per vertex; empty = none).
    pub external: &'a [Vec3],
}

/// Relaxes `x` (start: rest positions) to the equilibrium of `problem`. When the motion blows up
/// (non-finite positions), it starts again from `x` with half the step. Pass about half the
/// stable step: at the stability limit the kinetic-energy peaks are blurred and the relaxation
/// can stall (measured on scene B1's linear tetrahedra: no convergence in 400,000 steps at the
/// limit, 1,050 steps at half of it).
///
/// # Panics
/// If the step `dt` is above the stable one.
pub fn relax(
    problem: &Statics<'_>,
    dt: f64,
    x: &mut [Vec3],
    settings: RelaxSettings,
) -> RelaxReport {
    let start = x.to_vec();
    let mut dt = dt;
    for _ in 0..ATTEMPTS {
        x.copy_from_slice(&start);
        let report = attempt(problem, dt, x, settings);
        if x.iter().flatten().all(|c| c.is_finite()) {
            return report;
        }
        dt *= 0.5;
    }
    RelaxReport { steps: 0, dt, residual: f64::INFINITY, converged: false }
}

fn attempt(problem: &Statics<'_>, dt: f64, x: &mut [Vec3], settings: RelaxSettings) -> RelaxReport {
    let Statics { model, topology: topo, force_field: ff, penalty, fixed, prescribed, external } =
        *problem;
    let mut cd = CentralDifference::new(model, ff, fixed, x, dt, 0.0)
        .expect("relaxation runs at or below the stable step");
    let n = x.len();
    let mut kinetic_before = 0.0;
    let mut residual = f64::INFINITY;
    for step in 1..=settings.max_steps {
        let s = (step as f64 / prescribed.ramp_steps.max(1) as f64).min(1.0);
        for &(v, target) in &prescribed.targets {
            let rest = model.rest[v];
            x[v] = std::array::from_fn(|k| rest[k] + s * (target[k] - rest[k]));
        }
        cd.step(model, topo, ff, penalty, fixed, external, x);
        if step % 50 == 0 && !x.iter().flatten().all(|c| c.is_finite()) {
            return RelaxReport { steps: step, dt, residual: f64::INFINITY, converged: false };
        }
        let v = cd.velocities(x);
        let kinetic: f64 = v
            .iter()
            .zip(&model.lumped_mass)
            .map(|(v, m)| m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
            .sum();
        if kinetic < kinetic_before {
            cd.stop(x);
            kinetic_before = 0.0;
        } else {
            kinetic_before = kinetic;
        }
        if s >= 1.0 && step % 50 == 0 {
            let mut f = if external.is_empty() { vec![[0.0; 3]; n] } else { external.to_vec() };
            ff.add_forces(model, x, &mut f);
            if let Some(p) = penalty {
                p.add_forces(model, |t| topo.is_alive(t), x, &mut f);
            }
            residual = fixed.residual_ratio(&f);
            if residual <= settings.tolerance {
                return RelaxReport { steps: step, dt, residual, converged: true };
            }
        }
    }
    RelaxReport { steps: settings.max_steps, dt, residual, converged: false }
}
