//! Time integration and static equilibrium for the hexahedral model.
//!
//! - [`static_solve`]: Newton iterations to `f_int(x) + f_ext = 0` (one for the linear model);
//!   the reference answers come from it. The corotational Jacobian is complete, `R K Rᵀ` plus
//!   the rotation's own derivative ([`crate::tangent`]), so each step is a Bi-CGSTAB solve; the
//!   load is cut into increments only when a full Newton run fails.
//! - [`BackwardEuler`]: linearised implicit Euler (Baraff & Witkin 1998), one solve per step:
//!   `(M + hC + h²K) Δv = h (f(x₀) − C v₀ + f_ext − h K v₀)`, `C = αM + βK` (Rayleigh),
//!   `v₁ = v₀ + Δv`, `x₁ = x₀ + h v₁`; CG warm-started from the previous step's `Δv`.
//! - [`explicit_step`]: symplectic Euler with lumped mass, stable below [`stable_dt`].
//!
//! Masses are lumped (the condensed consistent mass rows summed per node).

use crate::bicgstab;
use crate::cg::{CgReport, CgSettings, block_jacobi, invert_block, solve, solve_against};
use crate::cholesky::{Precision, SystemFactor};
use crate::constraints::FixedNodes;
use crate::hex_force::{Formulation, HexForceField};
use crate::model::HexModel;
use crate::parallel::{join_if, update_elements, update_runs};
use crate::tangent::RotationTangent;
use incise_math::Vec3;

/// External loads: gravity (m/s²) on every node's lumped mass, plus per-node forces (N).
#[derive(Clone, Debug, PartialEq)]
pub struct Loads {
    /// Gravitational acceleration.
    pub gravity: Vec3,
    /// Extra force on each node (empty = none).
    pub nodal: Vec<Vec3>,
}

impl Loads {
    /// Gravity only.
    #[must_use]
    pub fn gravity(g: Vec3) -> Self {
        Self { gravity: g, nodal: Vec::new() }
    }

    /// Spreads `force` (N) evenly over the nodes of `rest` within `radius` of `centre`, added
    /// to the per-node forces (a tool pushing or pulling on a patch: a single-node force would
    /// depend on the mesh). Returns how many nodes share it (0: none lies that close, and
    /// nothing is added).
    pub fn add_patch(&mut self, rest: &[Vec3], centre: Vec3, radius: f64, force: Vec3) -> usize {
        let patch: Vec<usize> = (0..rest.len())
            .filter(|&n| {
                (0..3).map(|a| (rest[n][a] - centre[a]).powi(2)).sum::<f64>().sqrt() <= radius
            })
            .collect();
        if patch.is_empty() {
            return 0;
        }
        self.nodal.resize(rest.len(), [0.0; 3]);
        let share = 1.0 / patch.len() as f64;
        for &n in &patch {
            for a in 0..3 {
                self.nodal[n][a] += force[a] * share;
            }
        }
        patch.len()
    }

    /// `f += external forces`.
    pub fn add_to(&self, model: &HexModel, f: &mut [Vec3]) {
        for (n, fi) in f.iter_mut().enumerate() {
            self.add_at(model, n, fi);
        }
    }

    /// `f += the external force on node n`.
    #[inline]
    fn add_at(&self, model: &HexModel, n: usize, f: &mut Vec3) {
        let m = model.lumped_mass[n];
        for k in 0..3 {
            f[k] += m * self.gravity[k];
        }
        if let Some(extra) = self.nodal.get(n) {
            for k in 0..3 {
                f[k] += extra[k];
            }
        }
    }
}

/// Rayleigh damping `C = αM + βK`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rayleigh {
    /// Mass-proportional coefficient α (1/s).
    pub alpha: f64,
    /// Stiffness-proportional coefficient β (s).
    pub beta: f64,
}

/// Positions and velocities of every node.
#[derive(Clone, Debug, PartialEq)]
pub struct State {
    /// Positions (m).
    pub x: Vec<Vec3>,
    /// Velocities (m/s).
    pub v: Vec<Vec3>,
}

impl State {
    /// At rest in the rest configuration.
    #[must_use]
    pub fn at_rest(model: &HexModel) -> Self {
        Self { x: model.rest.clone(), v: vec![[0.0; 3]; model.node_count()] }
    }
}

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

fn norm(v: &[Vec3]) -> f64 {
    v.iter().map(|x| x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sum::<f64>().sqrt()
}

/// Block-Jacobi preconditioner of `a·M + b·K`.
pub(crate) fn preconditioner(
    model: &HexModel,
    ff: &HexForceField,
    mass: &[f64],
    a: f64,
    b: f64,
) -> Vec<incise_math::mat3::Mat3> {
    let mut blocks = Vec::new();
    preconditioner_into(model, ff, mass, (a, b), &mut blocks, &mut Vec::new());
    blocks
}

/// [`preconditioner`] into `blocks`, with `scratch` for the element sums (buffers kept between
/// rebuilds).
fn preconditioner_into(
    model: &HexModel,
    ff: &HexForceField,
    mass: &[f64],
    (a, b): (f64, f64),
    blocks: &mut Vec<incise_math::mat3::Mat3>,
    scratch: &mut Vec<incise_math::mat3::Mat3>,
) {
    ff.diagonal_blocks_into(model, blocks, scratch);
    update_elements(blocks, |n, k| {
        let mut blk = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                blk[i][j] = b * k[i][j];
            }
            blk[i][i] += a * mass[n];
        }
        *k = invert_block(&blk);
    });
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
    let mut factor = if cholesky { SystemFactor::new(model, fixed).ok() } else { None };
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
        let report = if let Some(f) = factor.as_ref() {
            linear_solve(&|r, z| f.solve(r, z), &mut dx)
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

/// How the implicit system is solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolver {
    /// CG with a block-Jacobi (3×3 per node) preconditioner.
    JacobiCg,
    /// CG preconditioned by a sparse Cholesky factorisation of the system, refactored (with the
    /// current rotations) when that lowers the average cost per step (see [`REFRESH_COST`]), and
    /// always when a solve needs more than `refresh_iterations` iterations.
    CholeskyCg {
        /// Iterations above which the factorisation is refreshed for the next step.
        refresh_iterations: usize,
    },
    /// Sparse Cholesky of the current system every step (exact solve, no iteration).
    Cholesky,
}

/// The cost of refactorising, in CG iterations with the factor as preconditioner. Measured here:
/// a numeric factorisation takes 40–50 triangular solves on B1, B2, B3 and a 33×22×18 block (the
/// ratio hardly moves with size: bigger supernodes run the factorisation faster), and an iteration
/// adds the operator product to its solve. A count, not a clock, so the choice is the same on every
/// run and frames stay bit-identical.
pub const REFRESH_COST: usize = 30;

/// The highest order of the starting guess's extrapolation (cubic).
const MAX_ORDER: usize = 3;

/// Velocity changes kept: the cubic's four, and one more to judge the cubic's last prediction.
const HISTORY: usize = MAX_ORDER + 2;

/// Weights of the polynomial of order `k` through the `k + 1` most recent values (one step
/// apart), evaluated one step ahead.
const WEIGHTS: [&[f64]; MAX_ORDER + 1] =
    [&[1.0], &[2.0, -1.0], &[3.0, -3.0, 1.0], &[4.0, -6.0, 4.0, -1.0]];

/// CG's starting guess from the last steps' velocity changes (`history`, the most recent first):
/// the polynomial of the order that would have predicted the most recent one best from those
/// before it, extrapolated one step (zero with no history; linear before there is a choice).
/// A smooth motion's acceleration changes slowly, and at 1 ms from rest the cubic wins: CG
/// iterations per step on B2 / B3 fall from 6.5 / 11.6 (linear) to 3.1 / 5.7. At 10 ms, where the
/// motion is not smooth on the step's scale, a lower order wins. The choice uses vector sums
/// only (no operator product), is made the same way every run, and changes where CG starts, not
/// where it stops.
fn starting_guess(history: &[Vec<Vec3>], guess: &mut [Vec3]) {
    let n = guess.len();
    let Some((latest, older)) = history.split_first() else {
        guess.fill([0.0; 3]);
        return;
    };
    let judged = older.len().min(MAX_ORDER + 1);
    let order = if judged < 2 {
        usize::from(judged == 1)
    } else {
        // Two fixed halves of the entries (on two threads where allowed), their sums added:
        // the same bits on one thread.
        let entries = 3 * n;
        let half = entries / 2;
        let zeros = if judged <= MAX_ORDER { vec![0.0; entries] } else { Vec::new() };
        let olders: [&[f64]; MAX_ORDER + 1] =
            std::array::from_fn(|j| older.get(j).map_or(&zeros[..], |v| v.as_flattened()));
        let latest = latest.as_flattened();
        let (first, second) = join_if(
            n >= crate::parallel::PARALLEL_MIN,
            || misses(&latest[..half], &olders.map(|o| &o[..half])),
            || misses(&latest[half..], &olders.map(|o| &o[half..])),
        );
        let miss: [f64; MAX_ORDER + 1] = std::array::from_fn(|j| first[j] + second[j]);
        (0..judged).min_by(|&a, &b| miss[a].total_cmp(&miss[b])).unwrap_or(0)
    };
    let order = order.min(history.len() - 1);
    update_runs(guess.as_flattened_mut(), |start, run| {
        // The order's weights are at most as many as the history's entries.
        let values: [&[f64]; HISTORY] = std::array::from_fn(|j| {
            history.get(j).map_or(&[][..], |h| &h.as_flattened()[start..start + run.len()])
        });
        for (g, i) in run.iter_mut().zip(0..) {
            *g = WEIGHTS[order].iter().zip(&values).fold(0.0, |acc, (w, v)| acc + w * v[i]);
        }
    });
}

/// How far each order's prediction of `latest` from `older` (the values before it, most recent
/// first) misses, summed over the entries: order k's prediction is order k − 1's plus the k-th
/// backward difference. Four lanes of partial sums, added in lane order at the end: a loop the
/// compiler vectorises.
fn misses(latest: &[f64], older: &[&[f64]; MAX_ORDER + 1]) -> [f64; MAX_ORDER + 1] {
    let mut lanes = [[0.0f64; 4]; MAX_ORDER + 1];
    for (i, &value) in latest.iter().enumerate() {
        let d: [f64; MAX_ORDER + 1] = std::array::from_fn(|j| older[j][i]);
        let differences =
            [d[0], d[0] - d[1], d[0] - 2.0 * d[1] + d[2], d[0] - 3.0 * d[1] + 3.0 * d[2] - d[3]];
        let mut error = value;
        for (lane, delta) in lanes.iter_mut().zip(differences) {
            error -= delta;
            lane[i % 4] += error * error;
        }
    }
    lanes.map(|l| ((l[0] + l[1]) + l[2]) + l[3])
}

/// How long (simulated seconds) block-Jacobi blocks serve before they are rebuilt with the
/// current rotations. Any symmetric positive definite blocks precondition correctly (CG stops at
/// the same tolerance); stale ones only cost iterations, and over 8 ms the rotations hardly move:
/// at 1 ms, B2 and B3 take the same iterations per step (2.7, 4.9) with blocks rebuilt every
/// step or every 8th, and run 23 % faster (building the blocks is an element loop, a scatter and
/// an inversion per node). At 10 ms they are rebuilt every step, as before.
const JACOBI_MAX_AGE: f64 = 8e-3;

/// Block-Jacobi blocks and what they were built for.
struct JacobiBlocks {
    /// Steps solved with them.
    used: usize,
    /// The system's `(a, b)`.
    key: (f64, f64),
    /// Inverse diagonal blocks, per node.
    blocks: Vec<incise_math::mat3::Mat3>,
    /// Room for the next rebuild's element sums.
    scratch: Vec<incise_math::mat3::Mat3>,
}

/// Which mass matrix an implicit step uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MassMatrix {
    /// The condensed consistent rows summed per node: diagonal, and what explicit integration
    /// needs. Its vibration frequencies come out low.
    #[default]
    Lumped,
    /// The condensed consistent mass `Mₑ ⊗ I₃` per element. Its frequencies come out high; it
    /// costs an element loop more per CG iteration.
    Consistent,
}

/// Wall time of the stages of the last implicit step (ns): measurements, not state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageTimes {
    /// Extracting the element rotations.
    pub rotations_ns: u64,
    /// Forming the right-hand side and solving the linear system (with its element passes).
    pub solve_ns: u64,
    /// Updating velocities and positions and the solver's history.
    pub update_ns: u64,
}

/// Linearised backward Euler with its solver state (CG warm start, factorisation).
pub struct BackwardEuler {
    /// Time step (s).
    pub dt: f64,
    /// Rayleigh damping.
    pub damping: Rayleigh,
    /// Linear-solve settings (CG variants).
    pub cg: CgSettings,
    /// The linear solver.
    pub solver: LinearSolver,
    /// The mass matrix of the system and of the mass damping (gravity is the same either way:
    /// the consistent mass's rows sum to the lumped one).
    pub mass: MassMatrix,
    /// The last steps' velocity changes, the most recent first (at most [`HISTORY`]): CG's
    /// starting guess is their extrapolation ([`starting_guess`]).
    history: Vec<Vec<Vec3>>,
    factor: Option<SystemFactor>,
    refresh: bool,
    /// Steps and CG iterations since the last refactorisation (a running count: a server that
    /// never needs a refresh must not grow a list).
    since_refresh: Cycle,
    /// The `(a, b)` and mass matrix of the direct solver's factor `a·M + b·K`.
    factored_for: Option<(f64, f64, MassMatrix)>,
    /// The block-Jacobi blocks of the lockstep solve, kept between steps (see
    /// [`JACOBI_MAX_AGE`]).
    jacobi: Option<JacobiBlocks>,
    /// The lockstep solve's vectors, and the step's right-hand side and next starting guess,
    /// kept between steps (a step allocates nothing once they have their size).
    lockstep: crate::lockstep_cg::Workspace,
    rhs: Vec<Vec3>,
    spare: Vec<Vec3>,
    /// The factor was built for the model before a topology change that kept every node: good
    /// as a preconditioner, but its element map is the old model's, so a refresh rebuilds it.
    pattern_stale: bool,
    /// Factorisations computed so far (a counter for reports).
    pub factorizations: usize,
    /// The last step's stage times.
    pub stage_times: StageTimes,
}

impl BackwardEuler {
    /// An integrator with step `dt` solving with block-Jacobi CG.
    #[must_use]
    pub fn new(dt: f64, damping: Rayleigh, cg: CgSettings) -> Self {
        Self::with_solver(dt, damping, cg, LinearSolver::JacobiCg)
    }

    /// An integrator with step `dt` and the given linear solver.
    #[must_use]
    pub fn with_solver(dt: f64, damping: Rayleigh, cg: CgSettings, solver: LinearSolver) -> Self {
        Self {
            dt,
            damping,
            cg,
            solver,
            mass: MassMatrix::Lumped,
            history: Vec::new(),
            factor: None,
            refresh: true,
            since_refresh: Cycle::default(),
            factored_for: None,
            jacobi: None,
            lockstep: crate::lockstep_cg::Workspace::default(),
            rhs: Vec::new(),
            spare: Vec::new(),
            pattern_stale: false,
            factorizations: 0,
            stage_times: StageTimes::default(),
        }
    }

    /// Carries the warm start across a topology change: new node `i` starts from the last step's
    /// velocity change of old node `old_of_new[i]` (zero when it has none).
    ///
    /// When every node kept its index (an edit that changed elements' matrices but no node, as
    /// most cuts at a coarse level do), CG keeps the old factor as its preconditioner: it is still
    /// symmetric positive definite and close, CG still meets its tolerance on the new system, and
    /// the renewal rule refactorises when the extra iterations cost more than a factorisation.
    /// Otherwise (and always for the direct solver, which must be exact) the factor is dropped
    /// and rebuilt for the new sparsity pattern.
    pub fn remap_warm_start(&mut self, old_of_new: &[Option<usize>]) {
        // Extrapolation starts again from the remapped step, and the Jacobi blocks from the new
        // elements.
        self.jacobi = None;
        let old = std::mem::take(&mut self.history).into_iter().next().unwrap_or_default();
        let same_nodes = old.len() == old_of_new.len()
            && old_of_new.iter().enumerate().all(|(i, &o)| o == Some(i));
        self.history = vec![
            old_of_new
                .iter()
                .map(|o| o.and_then(|j| old.get(j).copied()).unwrap_or([0.0; 3]))
                .collect(),
        ];
        if same_nodes && matches!(self.solver, LinearSolver::CholeskyCg { .. }) {
            self.pattern_stale = self.factor.is_some();
        } else {
            self.factor = None;
            self.refresh = true;
        }
    }

    /// Forgets the warm start and the factorisation (after the topology changed).
    pub fn reset_warm_start(&mut self) {
        self.history.clear();
        self.jacobi = None;
        self.factor = None;
        self.refresh = true;
        self.pattern_stale = false;
    }

    /// Advances `state` by one step.
    ///
    /// # Panics
    /// With a Cholesky solver, if the system is not positive definite on the free nodes (a free
    /// node without mass), which a model built from a grid never has.
    pub fn step(
        &mut self,
        model: &HexModel,
        ff: &mut HexForceField,
        fixed: &FixedNodes,
        loads: &Loads,
        state: &mut State,
    ) -> CgReport {
        let n = model.node_count();
        let h = self.dt;
        let Rayleigh { alpha, beta } = self.damping;
        let started = std::time::Instant::now();
        ff.update_rotations(model, &state.x);
        let rotated = std::time::Instant::now();
        // rhs = h (f_int + f_ext − αM v − (β + h) K v). The lockstep solve forms the element
        // terms itself, in its first pass; the others get them here.
        let lockstep = self.solver == LinearSolver::JacobiCg && self.mass == MassMatrix::Lumped;
        let mut rhs = std::mem::take(&mut self.rhs);
        rhs.clear();
        rhs.resize(n, [0.0; 3]);
        match self.mass {
            MassMatrix::Lumped => update_elements(&mut rhs, |i, r| {
                loads.add_at(model, i, r);
                let m = model.lumped_mass[i];
                for k in 0..3 {
                    r[k] -= alpha * m * state.v[i][k];
                }
            }),
            MassMatrix::Consistent => {
                loads.add_to(model, &mut rhs);
                model.add_consistent_mass_times(-alpha, &state.v, &mut rhs);
            }
        }
        if !lockstep {
            ff.add_forces_and_stiffness_times(model, &state.x, -(beta + h), &state.v, &mut rhs);
            for r in &mut rhs {
                for k in 0..3 {
                    r[k] *= h;
                }
            }
        }
        let a = 1.0 + h * alpha;
        let b = h * beta + h * h;
        // CG's residual is measured against the larger of the right-hand side and h‖f_ext‖,
        // what the right-hand side is when the loads are out of balance: at rest the right-hand
        // side is the rounding noise of f_int + f_ext ≈ 0, and solving to 1e-6 of that noise took
        // B1 (block-Jacobi CG, 1 ms) from 1.6 to 7 iterations a step, rising as it settled. It
        // loosens the solves of a moving body too, where the right-hand side is smaller than
        // h‖f_ext‖: B1's trajectory stays within 1e-5 of an exactly solved one (tested). The
        // step's force balance is then exact to the tolerance of the loads, as the static
        // solver's is.
        let reference = h * load_scale(model, loads, fixed);
        // CG starts from the last steps' velocity changes extrapolated (a smooth motion's
        // acceleration changes slowly): on B3 at 1 ms the cubic saves half the iterations, to the
        // same tolerance.
        self.history.retain(|d| d.len() == n);
        let mut dv = std::mem::take(&mut self.spare);
        dv.resize(n, [0.0; 3]);
        starting_guess(&self.history, &mut dv);
        let ffr = &*ff;
        let consistent = self.mass == MassMatrix::Consistent;
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            if consistent {
                out.fill([0.0; 3]);
                model.add_consistent_mass_times(a, p, out);
            } else {
                for (i, o) in out.iter_mut().enumerate() {
                    let m = a * model.lumped_mass[i];
                    *o = [m * p[i][0], m * p[i][1], m * p[i][2]];
                }
            }
            ffr.add_stiffness_times(model, b, p, out);
        };
        let report = match self.solver {
            LinearSolver::JacobiCg if lockstep => {
                let stale = self.jacobi.as_ref().is_none_or(|j| {
                    j.used as f64 * h >= JACOBI_MAX_AGE - 1e-12
                        || j.key != (a, b)
                        || j.blocks.len() != n
                });
                if stale {
                    let mut j = self.jacobi.take().unwrap_or(JacobiBlocks {
                        used: 0,
                        key: (a, b),
                        blocks: Vec::new(),
                        scratch: Vec::new(),
                    });
                    let mass = &model.lumped_mass;
                    preconditioner_into(model, ffr, mass, (a, b), &mut j.blocks, &mut j.scratch);
                    (j.used, j.key) = (0, (a, b));
                    self.jacobi = Some(j);
                }
                let jacobi = self.jacobi.as_mut().expect("built above");
                jacobi.used += 1;
                let pre = &jacobi.blocks;
                let system = crate::lockstep_cg::System { model, ff: ffr, fixed, a, b, pre };
                let rhs = crate::lockstep_cg::Rhs {
                    x: &state.x,
                    v: &state.v,
                    node: &rhs,
                    h,
                    s: -(beta + h),
                    reference,
                };
                crate::lockstep_cg::solve(&system, &rhs, &mut dv, self.cg, &mut self.lockstep)
            }
            LinearSolver::JacobiCg => {
                let diagonal;
                let mass = if consistent {
                    diagonal = model.consistent_mass_diagonal();
                    &diagonal
                } else {
                    &model.lumped_mass
                };
                let pre = preconditioner(model, ffr, mass, a, b);
                solve_against(apply, block_jacobi(&pre), fixed, &rhs, &mut dv, self.cg, reference)
            }
            LinearSolver::CholeskyCg { refresh_iterations } => {
                // A node fixed or freed by the edit leaves the old factor without a pivot for it.
                if self.pattern_stale && !self.factor.as_ref().is_some_and(|f| f.serves(fixed)) {
                    self.factor = None;
                }
                self.ensure_factor(model, ffr, fixed, a, b);
                let factor = self.factor.as_ref().expect("factorised above");
                let report = solve_against(
                    apply,
                    |r, z| factor.solve(r, z),
                    fixed,
                    &rhs,
                    &mut dv,
                    self.cg,
                    reference,
                );
                self.since_refresh.record(report.iterations);
                self.refresh = report.iterations > refresh_iterations
                    || self.since_refresh.refresh_pays(REFRESH_COST);
                report
            }
            LinearSolver::Cholesky => {
                // The linear model's matrix only changes with the step, the damping, the mass
                // matrix or the topology (which resets the factor): one factorisation serves
                // every step.
                let key = Some((a, b, self.mass));
                self.refresh |=
                    ffr.formulation() == Formulation::Corotational || self.factored_for != key;
                self.factored_for = key;
                self.ensure_factor(model, ffr, fixed, a, b);
                let mut rr = rhs.clone();
                fixed.project(&mut rr);
                self.factor.as_ref().expect("factorised above").solve(&rr, &mut dv);
                CgReport { iterations: 1, relative_residual: 0.0, converged: true }
            }
        };
        let solved = std::time::Instant::now();
        for i in 0..n {
            if fixed.is_fixed(i) {
                state.v[i] = [0.0; 3];
                continue;
            }
            for k in 0..3 {
                state.v[i][k] += dv[i][k];
                state.x[i][k] += h * state.v[i][k];
            }
        }
        if self.history.len() >= HISTORY {
            self.spare = self.history.pop().expect("a full history");
        }
        self.history.truncate(HISTORY - 1);
        self.history.insert(0, dv);
        self.rhs = rhs;
        let ns = |d: std::time::Duration| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        self.stage_times = StageTimes {
            rotations_ns: ns(rotated - started),
            solve_ns: ns(solved - rotated),
            update_ns: ns(solved.elapsed()),
        };
        report
    }
}

impl BackwardEuler {
    /// Builds the symbolic factorisation once, and refactorises when a refresh is due.
    fn ensure_factor(
        &mut self,
        model: &HexModel,
        ff: &HexForceField,
        fixed: &FixedNodes,
        a: f64,
        b: f64,
    ) {
        // A preconditioner only needs to be close: single precision halves the bytes every
        // triangular solve reads. The direct solver needs the exact factor.
        let precision = match self.solver {
            LinearSolver::CholeskyCg { .. } => Precision::Single,
            _ => Precision::Double,
        };
        if self.refresh && self.pattern_stale {
            self.factor = None;
        }
        if self.factor.is_none() {
            self.pattern_stale = false;
            self.factor = Some(
                SystemFactor::with_precision(model, fixed, precision)
                    .expect("the system pattern is valid"),
            );
            self.refresh = true;
        }
        if self.refresh {
            let factor = self.factor.as_mut().expect("created above");
            let consistent = self.mass == MassMatrix::Consistent;
            if factor.factorize_with(model, ff, a, b, consistent).is_err() {
                // Rounding to f32 can lose definiteness on a very stiff system: fall back to f64.
                factor.set_precision(Precision::Double);
                factor
                    .factorize_with(model, ff, a, b, consistent)
                    .expect("a·M + b·K is positive definite on the free nodes");
            }
            self.factorizations += 1;
            self.refresh = false;
            self.since_refresh = Cycle::default();
        }
    }
}

/// The steps since the last factorisation: how many, their CG iterations in all, and the last
/// step's.
#[derive(Clone, Copy, Debug, Default)]
struct Cycle {
    steps: usize,
    iterations: usize,
    last: usize,
}

impl Cycle {
    fn record(&mut self, iterations: usize) {
        self.steps += 1;
        self.iterations += iterations;
        self.last = iterations;
    }

    /// Whether to refactorise now, a factorisation costing `cost` iterations. The iteration
    /// counts grow as the rotations drift from the factorised ones; the average cost per step of a
    /// cycle, `(cost + Σ iterations) / steps`, is least when the cycle ends as soon as the last
    /// step's count exceeds that average (the renewal rule for a growing running cost).
    fn refresh_pays(&self, cost: usize) -> bool {
        self.steps > 0 && self.last * self.steps > cost + self.iterations
    }
}

/// The external forces' norm on the free nodes (gravity on the lumped masses and the nodal
/// loads), summed in node order.
fn load_scale(model: &HexModel, loads: &Loads, fixed: &FixedNodes) -> f64 {
    let mut sum = 0.0;
    for i in 0..model.node_count() {
        if fixed.is_fixed(i) {
            continue;
        }
        let mut f = [0.0; 3];
        loads.add_at(model, i, &mut f);
        sum += f[0] * f[0] + f[1] * f[1] + f[2] * f[2];
    }
    sum.sqrt()
}

/// One symplectic-Euler step with lumped mass and mass-proportional damping α:
/// `v += h M⁻¹ (f − αMv)`, `x += h v`.
pub fn explicit_step(
    model: &HexModel,
    ff: &mut HexForceField,
    fixed: &FixedNodes,
    loads: &Loads,
    alpha: f64,
    dt: f64,
    state: &mut State,
) {
    let n = model.node_count();
    ff.update_rotations(model, &state.x);
    let mut f = vec![[0.0; 3]; n];
    loads.add_to(model, &mut f);
    ff.add_forces(model, &state.x, &mut f);
    for i in 0..n {
        if fixed.is_fixed(i) || model.lumped_mass[i] <= 0.0 {
            state.v[i] = [0.0; 3];
            continue;
        }
        let inv = 1.0 / model.lumped_mass[i];
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

#[cfg(test)]
mod renewal_tests {
    use super::Cycle;

    #[test]
    fn a_steady_count_never_refreshes_and_a_growing_one_refreshes_when_it_passes_the_average() {
        let mut steady = Cycle::default();
        for _ in 0..100_000 {
            steady.record(2);
            assert!(!steady.refresh_pays(30));
        }
        // Counts 2, 3, 4, …: after n steps the average is (30 + Σ) / n, and the count n + 1 first
        // exceeds it at n = 9 (n = 8: 9 · 8 = 72 ≤ 30 + 44; n = 9: 10 · 9 = 90 > 30 + 54).
        let mut growing = Cycle::default();
        let first = (1..100)
            .find(|&n| {
                growing.record(n + 1);
                growing.refresh_pays(30)
            })
            .unwrap();
        assert_eq!(first, 9);
    }
}

#[cfg(test)]
mod guess_tests {
    use super::*;

    /// [`starting_guess`] for `n` nodes.
    fn guessed(history: &[Vec<Vec3>], n: usize) -> Vec<Vec3> {
        let mut guess = vec![[f64::NAN; 3]; n];
        starting_guess(history, &mut guess);
        guess
    }

    /// Histories (most recent first) of a two-node field sampled at steps `t = 0, -1, -2, …`.
    fn history(f: impl Fn(f64) -> f64, len: usize) -> Vec<Vec<Vec3>> {
        (0..len)
            .map(|j| {
                let t = -(j as f64);
                vec![[f(t), 2.0 * f(t), -f(t)], [0.5 * f(t), 0.0, f(t)]]
            })
            .collect()
    }

    #[test]
    fn a_cubic_motion_is_predicted_exactly() {
        let f = |t: f64| 0.3 + 0.2 * t - 0.05 * t * t + 0.01 * t * t * t;
        let guess = guessed(&history(f, HISTORY), 2);
        let want = history(|t| f(t + 1.0), 1);
        for (g, w) in guess.iter().zip(&want[0]) {
            for k in 0..3 {
                assert!((g[k] - w[k]).abs() < 1e-12, "{guess:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn an_oscillation_on_the_step_scale_falls_back_to_the_last_value() {
        // +1, −1, +1, … : every extrapolation of higher order overshoots further.
        let f = |t: f64| if (t as i64) % 2 == 0 { 1.0 } else { -1.0 };
        let h = history(f, HISTORY);
        assert_eq!(guessed(&h, 2), h[0]);
    }

    #[test]
    fn short_histories_use_what_there_is() {
        let f = |t: f64| 1.0 + t;
        assert_eq!(guessed(&[], 2), vec![[0.0; 3]; 2]);
        assert_eq!(guessed(&history(f, 1), 2), history(f, 1)[0]);
        // Two values: linear, before any order could be judged.
        assert_eq!(guessed(&history(f, 2), 2), history(|t| f(t + 1.0), 1)[0]);
    }
}
