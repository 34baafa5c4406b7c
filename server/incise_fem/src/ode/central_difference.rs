//! Explicit central-difference integration of the tensor-mass model with lumped masses and
//! mass-proportional damping (paper 2 eq. 11–13): per vertex
//!
//! `(m/Δt² + γ/2Δt) x⁺ = F + 2m/Δt² x − (m/Δt² − γ/2Δt) x⁻`, `γ = α m`.
//!
//! (The paper writes the damping term with the opposite sign convention for γ; here a positive α
//! damps.) The scheme is stable for `Δt ≤ 2/ω_max`, `ω_max² = λ_max(M⁻¹K)`; [`stable_dt`]
//! estimates it from the rest stiffness and [`CentralDifference::new`] refuses a larger step.

use crate::constraint::FixedNodes;
use crate::forcefield::ForceField;
use crate::forcefield::tet::TensorMassForceField;
use crate::forcefield::tet::element::TetModel;
use crate::forcefield::tet::incompressible::Incompressibility;
use crate::model::Mass;
use incise_math::Vec3;
use incise_mesh::TetTopology;

/// Power iterations for `λ_max(M⁻¹K)`.
const POWER_ITERATIONS: usize = 100;

/// The step allowed is this fraction of `2 / √λ`: the power iteration approaches `λ_max` from
/// below, and strains of tens of percent stiffen St Venant-Kirchhoff (its tangent stiffness grows
/// with the stretch) beyond the rest stiffness the estimate uses. Measured on a cylinder released
/// from a 10 % stretch and bend: linear and SVK with the incompressibility penalty keep their
/// energy bounded over 10⁴ steps at 0.5; bare SVK (no penalty) lets compressed tetrahedra collapse,
/// stiffen and blow up at 0.5 (after 2,702 steps) but not at 0.35.
const SAFETY: f64 = 0.5;

/// The stable step (s): a safety factor (0.5) times the limit `2/ω_max` of the rest (linear)
/// stiffness of `ff` with lumped masses.
#[must_use]
pub fn stable_dt(model: &TetModel, ff: &TensorMassForceField, fixed: &FixedNodes) -> f64 {
    let n = model.vertex_count();
    let mut v: Vec<Vec3> = (0..n)
        .map(|i| [1.0 + (i % 7) as f64, 1.0 - (i % 5) as f64, 1.0 + (i % 3) as f64])
        .collect();
    let mut lambda = 0.0;
    for _ in 0..POWER_ITERATIONS {
        fixed.project(&mut v);
        let norm = v.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            return f64::INFINITY;
        }
        for x in v.iter_mut().flatten() {
            *x /= norm;
        }
        let mut kv = vec![[0.0; 3]; n];
        ff.add_rest_stiffness_times(&v, &mut kv);
        for (x, &m) in kv.iter_mut().zip(&model.lumped_mass) {
            let inv = if m > 0.0 { 1.0 / m } else { 0.0 };
            *x = x.map(|c| c * inv);
        }
        fixed.project(&mut kv);
        lambda = kv.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
        v = kv;
    }
    SAFETY * 2.0 / lambda.sqrt()
}

/// A step above the stable one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "time step {dt} s is above the stable explicit step {stable:.3e} s for this mesh and material \
     (central differences need dt ≤ 2/ω_max); use dt ≤ {stable:.3e} s, a coarser mesh or an implicit model"
)]
pub struct StepTooLarge {
    /// The step asked for (s).
    pub dt: f64,
    /// The stable step (s).
    pub stable: f64,
}

/// Central-difference state: the previous positions.
#[derive(Clone, Debug)]
pub struct CentralDifference {
    dt: f64,
    alpha: f64,
    previous: Vec<Vec3>,
    /// The stable step estimated at construction (s).
    pub stable_dt: f64,
}

impl CentralDifference {
    /// The positions at the previous step, which the next step differences against.
    #[must_use]
    pub fn previous(&self) -> &[Vec3] {
        &self.previous
    }

    /// Sets the positions at the previous step (restoring a snapshot of the state).
    ///
    /// # Errors
    /// When their count is not the current one's (the vertex count).
    pub fn set_previous(&mut self, previous: &[Vec3]) -> Result<(), String> {
        if previous.len() != self.previous.len() {
            return Err(format!(
                "{} previous positions for {} vertices",
                previous.len(),
                self.previous.len()
            ));
        }
        self.previous.copy_from_slice(previous);
        Ok(())
    }
    /// An integrator at rest in `x` with step `dt` and mass damping `alpha` (1/s).
    pub fn new(
        model: &TetModel,
        ff: &TensorMassForceField,
        fixed: &FixedNodes,
        x: &[Vec3],
        dt: f64,
        alpha: f64,
    ) -> Result<Self, StepTooLarge> {
        let stable = stable_dt(model, ff, fixed);
        if !(dt > 0.0 && dt <= stable) {
            return Err(StepTooLarge { dt, stable });
        }
        Ok(Self { dt, alpha, previous: x.to_vec(), stable_dt: stable })
    }

    /// The step (s).
    #[must_use]
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Sets every velocity to zero (the previous positions to `x`).
    pub fn stop(&mut self, x: &[Vec3]) {
        self.previous.copy_from_slice(x);
    }

    /// Velocities `(x − x⁻)/Δt` (m/s).
    #[must_use]
    pub fn velocities(&self, x: &[Vec3]) -> Vec<Vec3> {
        x.iter()
            .zip(&self.previous)
            .map(|(a, b)| std::array::from_fn(|k| (a[k] - b[k]) / self.dt))
            .collect()
    }

    /// Advances `x` by one step under the elastic forces of `ff` as it stands (no adaptive
    /// update), the optional penalty, and `external` forces (N per vertex; empty = none). Fixed
    /// vertices stay where they are.
    #[allow(clippy::too_many_arguments)] // the explicit step is these things; a struct adds nothing
    pub fn step(
        &mut self,
        model: &TetModel,
        topo: &TetTopology,
        ff: &TensorMassForceField,
        penalty: Option<&Incompressibility>,
        fixed: &FixedNodes,
        external: &[Vec3],
        x: &mut [Vec3],
    ) {
        let mut f = forces_from(external, x.len());
        ff.add_forces(model, x, &mut f);
        if let Some(p) = penalty {
            p.add_forces(model, |t| topo.is_alive(t), x, &mut f);
        }
        self.advance(&model.lumped_mass, &f, fixed, x);
    }

    /// Advances `x` by one step under the forces of `fields` (each updated at `x` first) and
    /// `external` forces (N per vertex; empty = none), with `mass`'s lumped masses. Fixed
    /// vertices stay where they are.
    pub fn step_fields(
        &mut self,
        mass: &dyn Mass,
        fields: &mut [&mut dyn ForceField],
        fixed: &FixedNodes,
        external: &[Vec3],
        x: &mut [Vec3],
    ) {
        let mut f = forces_from(external, x.len());
        for field in fields.iter_mut() {
            field.update(x);
            field.add_forces(x, &mut f);
        }
        // A field with damping of its own (a tool's springs) damps the velocity of the last step.
        if fields.iter().any(|field| !field.rayleigh_damped()) {
            let v = self.velocities(x);
            for field in fields.iter() {
                field.add_damping_forces(&v, &mut f);
            }
        }
        self.advance(mass.lumped(), &f, fixed, x);
    }

    /// The central-difference update of `x` under forces `f`.
    fn advance(&mut self, lumped: &[f64], f: &[Vec3], fixed: &FixedNodes, x: &mut [Vec3]) {
        let (h, h2) = (self.dt, self.dt * self.dt);
        for i in 0..x.len() {
            let m = lumped[i];
            if fixed.is_fixed(i) || m <= 0.0 {
                self.previous[i] = x[i];
                continue;
            }
            let g = 0.5 * self.alpha * m / h;
            let a = m / h2 + g;
            for k in 0..3 {
                let next =
                    (f[i][k] + 2.0 * m / h2 * x[i][k] - (m / h2 - g) * self.previous[i][k]) / a;
                self.previous[i][k] = x[i][k];
                x[i][k] = next;
            }
        }
    }
}

/// The external forces as the start of a force vector of `n` vertices.
fn forces_from(external: &[Vec3], n: usize) -> Vec<Vec3> {
    if external.is_empty() { vec![[0.0; 3]; n] } else { external.to_vec() }
}
