//! Static equilibrium by Newton's method, `f_int(x) + f_ext = 0`: the reference answers come
//! from it. The corotational Jacobian is complete, `R K Rᵀ` plus the rotation's own derivative
//! (`crate::forcefield::hex::tangent`), so each step is a Bi-CGSTAB solve; the load is cut into
//! increments only when a full Newton run fails.

use crate::constraint::FixedNodes;
use crate::forcefield::hex::tangent::RotationTangent;
use crate::forcefield::hex::{Formulation, HexForceField};
use crate::linsolve::bicgstab;
use crate::linsolve::cg::{CgSettings, block_jacobi, solve};
use crate::linsolve::cholesky::SystemFactor;
use crate::linsolve::jacobi::preconditioner;
use crate::linsolve::multigrid::Multigrid;
use crate::model::{HexModel, Loads};
use incise_math::Vec3;

/// Outcome of a static solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StaticReport {
    /// Newton iterations run.
    pub newton_iterations: usize,
    /// CG iterations summed over them.
    pub cg_iterations: usize,
    /// Final `‖f_int + f_ext‖ / ‖f_ext‖` on the free nodes.
    pub relative_residual: f64,
    /// Whether `tolerance` was reached.
    pub converged: bool,
}

pub(crate) fn norm(v: &[Vec3]) -> f64 {
    v.iter().map(|x| x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sum::<f64>().sqrt()
}

/// Newton iterations to static equilibrium from `x` (fixed nodes keep their positions in `x`).
/// Stops when the residual force is below `tolerance` times the external force.
///
/// The whole load is tried first. A Newton step whose residual blows up (10⁴ times the best so
/// far), or eight steps without a new best, send the solve back to the last equilibrium it
/// reached with half the remaining load increment; after a success the increment doubles. So
/// a soft body that folds far from rest is still solved, and a stiff one takes plain Newton.
/// `max_newton` counts every Newton step, on every increment.
pub fn static_solve(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    x: &mut [Vec3],
    tolerance: f64,
    max_newton: usize,
) -> StaticReport {
    static_solve_with(model, ff, fixed, loads, x, tolerance, max_newton, false)
}

/// [`static_solve`] with, when `cholesky` is set, each Newton step's CG preconditioned by a
/// sparse Cholesky factorisation of the current stiffness (a few iterations instead of thousands
/// on large bulky meshes; the factorisation costs memory and time up front).
///
/// A stiffness the factorisation finds singular on the free nodes (a piece no hold supports)
/// switches the solve to block-Jacobi CG from that Newton step on, instead of aborting; such a
/// problem under a load has no equilibrium, and the report then says `converged: false`.
#[allow(clippy::too_many_arguments)] // the static problem is these seven things; a struct adds nothing
pub fn static_solve_with(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    x: &mut [Vec3],
    tolerance: f64,
    max_newton: usize,
    cholesky: bool,
) -> StaticReport {
    let factor = if cholesky {
        SystemFactor::new(model, fixed).ok().map(|f| f.with_executor(ff.executor().clone()))
    } else {
        None
    };
    newton(model, ff, fixed, loads, x, (tolerance, max_newton), factor, None)
}

/// [`static_solve`] with each Newton step's linear solve preconditioned by `multigrid`, a
/// hierarchy over `model` (its finest level) for `a = 0, b = 1`, whose rotations are taken at
/// every Newton step's positions. Its iterations hardly grow with the mesh, where block-Jacobi's
/// do; it needs neither Cholesky's memory nor its factorisation (on the 109,201-voxel liver's
/// linear static solve, 5.6 s against 179 s and block-Jacobi's 58 s on two threads). A
/// hierarchy whose coarsest level cannot be factorised at some step leaves that step to
/// block-Jacobi.
#[allow(clippy::too_many_arguments)] // static_solve's seven and the hierarchy
pub fn static_solve_multigrid(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    x: &mut [Vec3],
    tolerance: f64,
    max_newton: usize,
    multigrid: &mut Multigrid,
) -> StaticReport {
    newton(model, ff, fixed, loads, x, (tolerance, max_newton), None, Some(multigrid))
}

/// The Newton iterations behind [`static_solve_with`] and [`static_solve_multigrid`]: each step
/// preconditioned by `factor` when there is one, else by `multigrid` when there is one, else by
/// block-Jacobi.
#[allow(clippy::too_many_arguments)]
fn newton(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    x: &mut [Vec3],
    (tolerance, max_newton): (f64, usize),
    mut factor: Option<SystemFactor>,
    mut multigrid: Option<&mut Multigrid>,
) -> StaticReport {
    let n = model.node_count();
    let mut f_ext = vec![[0.0; 3]; n];
    loads.add_to(model, &mut f_ext);
    fixed.project(&mut f_ext);
    let scale = norm(&f_ext).max(f64::MIN_POSITIVE);
    let corotational = ff.formulation() == Formulation::Corotational;
    // `f_int(x) + λ f_ext` with `ff`'s rotations taken at `x`, relative to the whole load.
    let residual_at = |ff: &mut HexForceField, x: &[Vec3], load: f64, r: &mut [Vec3]| {
        ff.update_rotations(model, x);
        for (ri, fi) in r.iter_mut().zip(&f_ext) {
            *ri = fi.map(|f| load * f);
        }
        ff.add_forces(model, x, r);
        fixed.project(r);
        norm(r) / scale
    };
    // Load continuation: the whole load first; when Newton fails on the way (a step that blows
    // up, or no progress for a while) the solve returns to the last equilibrium reached and
    // tries half the increment. `reached` is that load fraction and its state.
    let mut load = 1.0;
    let mut reached = (0.0, x.to_vec());
    let mut r = vec![[0.0; 3]; n];
    let mut rel = residual_at(ff, x, load, &mut r);
    let mut best = rel;
    let mut since_best = 0;
    let mut cg_total = 0;
    let mut dx = vec![[0.0; 3]; n];
    for it in 0..max_newton {
        // An intermediate load only has to be reached closely enough to start the next from.
        let target = if load < 1.0 { tolerance.max(PATH_TOLERANCE * load) } else { tolerance };
        if rel <= target {
            if load >= 1.0 {
                return StaticReport {
                    newton_iterations: it,
                    cg_iterations: cg_total,
                    relative_residual: rel,
                    converged: true,
                };
            }
            let increment = load - reached.0;
            reached = (load, x.to_vec());
            load = (load + 2.0 * increment).min(1.0);
            rel = residual_at(ff, x, load, &mut r);
            (best, since_best) = (rel, 0);
            continue;
        }
        dx.fill([0.0; 3]);
        let ffr = &*ff;
        // The rotation's derivative completes the corotational Jacobian (see `tangent`):
        // Newton converges quadratically with it, and without it it diverged on the liver.
        let tangent = RotationTangent::at(model, ffr, x);
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            out.fill([0.0; 3]);
            ffr.add_stiffness_times(model, 1.0, p, out);
            tangent.add_times(model, ffr, 1.0, p, out);
        };
        // Inexact Newton (Eisenstat–Walker) for the corotational model with block-Jacobi
        // preconditioning: far from the answer a linear solve to 1e-2 of the residual gains as
        // much as an exact one; near it, one to a tenth of what is left to reach `tolerance`.
        // The answer's tolerance is unchanged, and the iterations of all the steps together are
        // about those of one exact solve instead of one per step (a 104,000-unknown block:
        // 54 s instead of 141 s). Never stricter than a tenth of the tolerance (with no
        // external load `rel` is measured against nothing and would ask for the impossible).
        let exact = (0.1 * tolerance / rel).max(0.1 * tolerance);
        let forcing = match ff.formulation() {
            // One step is exact for the linear model: solve it to the tolerance. With a factor
            // the iteration converges in a few steps: fewer Newton steps, each solved exactly,
            // cost less.
            Formulation::Corotational if factor.is_none() => exact.max(rel.min(1e-2)).min(0.1),
            _ => exact,
        };
        let settings =
            CgSettings { tolerance: forcing.max(1e-14), max_iterations: 20 * model.dof_count() };
        // A factor of `R K Rᵀ` plus the symmetric part of the rotation term (or of `R K Rᵀ`
        // alone where that sum is indefinite), fresh every Newton step: Bi-CGSTAB then needs a
        // few products.
        if factor.as_mut().is_some_and(|f| {
            f.factorize_tangent(model, ffr, &tangent).is_err()
                && f.factorize(model, ffr, 0.0, 1.0).is_err()
        }) {
            factor = None;
        }
        // The full tangent is not symmetric: Bi-CGSTAB, preconditioned as CG would be.
        let linear_solve = |precondition: &dyn Fn(&[Vec3], &mut [Vec3]), dx: &mut [Vec3]| {
            if corotational {
                bicgstab::solve(apply, precondition, fixed, &r, dx, settings)
            } else {
                solve(apply, precondition, fixed, &r, dx, settings)
            }
        };
        let hierarchy =
            multigrid.as_deref_mut().and_then(|mg| mg.update(x).is_ok().then_some(&*mg));
        let report = if let Some(f) = factor.as_ref() {
            linear_solve(&|r, z| f.solve(r, z), &mut dx)
        } else if let Some(mg) = hierarchy {
            linear_solve(&|r, z| mg.precondition(r, z), &mut dx)
        } else {
            let pre = preconditioner(model, ffr, &model.lumped_mass, 0.0, 1.0);
            linear_solve(&block_jacobi(&pre), &mut dx)
        };
        cg_total += report.iterations;
        for (xi, d) in x.iter_mut().zip(&dx) {
            for k in 0..3 {
                xi[k] += d[k];
            }
        }
        rel = residual_at(ff, x, load, &mut r);
        // Full steps: the residual may rise on the way (a cantilever's first step from rest
        // raises it 585 times, then Newton converges quadratically), so only a step that blows
        // up, or a run of steps without a new best, counts as failure.
        if rel < best {
            (best, since_best) = (rel, 0);
        } else {
            since_best += 1;
        }
        if corotational
            && (!rel.is_finite() || rel > WATCHDOG_GROWTH * best || since_best >= WATCHDOG_STEPS)
        {
            x.copy_from_slice(&reached.1);
            load = reached.0 + 0.5 * (load - reached.0);
            rel = residual_at(ff, x, load, &mut r);
            (best, since_best) = (rel, 0);
        }
    }
    StaticReport {
        newton_iterations: max_newton,
        cg_iterations: cg_total,
        relative_residual: if load < 1.0 { residual_at(ff, x, 1.0, &mut r) } else { rel },
        converged: false,
    }
}

/// A Newton step whose residual exceeds the best one at its load by this factor has failed.
const WATCHDOG_GROWTH: f64 = 1e4;

/// Newton steps in a row without a new best residual after which the load is cut.
const WATCHDOG_STEPS: usize = 8;

/// How closely (relative to the load reached) an intermediate load's equilibrium is solved.
const PATH_TOLERANCE: f64 = 1e-4;
