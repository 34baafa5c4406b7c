//! Explicit integration: symplectic Euler with lumped mass for any force fields, stable below
//! [`stable_dt`] for the hexahedral model.

use crate::constraint::FixedNodes;
use crate::forcefield::ForceField;
use crate::forcefield::hex::HexForceField;
use crate::model::{HexModel, Loads, Mass, State};
use crate::ode::static_newton::norm;
use incise_math::Vec3;

/// One symplectic-Euler step of the hexahedral model `model` with its field `ff` alone:
/// [`explicit_step_fields`] with that one field.
pub fn explicit_step(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    alpha: f64,
    dt: f64,
    state: &mut State,
) {
    explicit_step_fields(model, &mut [&mut ff.bind(model)], fixed, loads, alpha, dt, state);
}

/// One symplectic-Euler step under the forces of `fields` with lumped mass and
/// mass-proportional damping α: `v += h M⁻¹ (f − αMv)`, `x += h v`.
pub fn explicit_step_fields(
    mass: &dyn Mass,
    fields: &mut [&mut dyn ForceField],
    fixed: &FixedNodes,
    loads: &Loads,
    alpha: f64,
    dt: f64,
    state: &mut State,
) {
    let lumped = mass.lumped();
    let n = lumped.len();
    let mut f = vec![[0.0; 3]; n];
    loads.add_to(mass, &mut f);
    for field in fields.iter_mut() {
        field.update(&state.x);
        field.add_forces(&state.x, &mut f);
        field.add_damping_forces(&state.v, &mut f);
    }
    for i in 0..n {
        if fixed.is_fixed(i) || lumped[i] <= 0.0 {
            state.v[i] = [0.0; 3];
            continue;
        }
        let inv = 1.0 / lumped[i];
        for k in 0..3 {
            state.v[i][k] += dt * (f[i][k] * inv - alpha * state.v[i][k]);
            state.x[i][k] += dt * state.v[i][k];
        }
    }
}

/// Largest stable explicit step `2 / √λ_max(M⁻¹K)`, `λ_max` by power iteration (rest stiffness).
#[must_use]
pub fn stable_dt(model: &HexModel, ff: &HexForceField, fixed: &FixedNodes) -> f64 {
    let n = model.node_count();
    let mut v: Vec<Vec3> = (0..n)
        .map(|i| [1.0 + (i % 7) as f64, 1.0 + (i % 5) as f64, 1.0 + (i % 3) as f64])
        .collect();
    fixed.project(&mut v);
    let mut lambda = 0.0;
    for _ in 0..200 {
        let nv = norm(&v);
        if nv == 0.0 {
            return f64::INFINITY;
        }
        for x in &mut v {
            *x = [x[0] / nv, x[1] / nv, x[2] / nv];
        }
        let mut kv = vec![[0.0; 3]; n];
        ff.add_stiffness_times(model, 1.0, &v, &mut kv);
        for (i, x) in kv.iter_mut().enumerate() {
            let m = model.lumped_mass[i];
            let inv = if m > 0.0 { 1.0 / m } else { 0.0 };
            *x = [x[0] * inv, x[1] * inv, x[2] * inv];
        }
        fixed.project(&mut kv);
        lambda = norm(&kv);
        v = kv;
    }
    2.0 / lambda.sqrt()
}
