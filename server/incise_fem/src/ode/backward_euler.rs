//! Linearised backward Euler (Baraff & Witkin 1998), one solve per step:
//! `(M + hC + h²K) Δv = h (f(x₀) − C v₀ + f_ext − h K v₀)`, `C = αM + βK` (Rayleigh),
//! `v₁ = v₀ + Δv`, `x₁ = x₀ + h v₁`; CG warm-started from the previous steps' `Δv`
//! extrapolated (`warm_start`).

use crate::constraint::FixedNodes;
use crate::exec::Executor;
use crate::forcefield::ForceField;
use crate::forcefield::hex::{Formulation, HexForceField};
use crate::linsolve::cg::{CgReport, CgSettings, block_jacobi, solve_against};
use crate::linsolve::cholesky::{Precision, SystemFactor};
use crate::linsolve::jacobi::{field_preconditioner, preconditioner, preconditioner_into};
use crate::model::{HexModel, Loads, Mass, State};
use crate::ode::Rayleigh;
use crate::ode::warm_start::{HISTORY, starting_guess};
use incise_math::Vec3;

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
    lockstep: crate::linsolve::lockstep_cg::Workspace,
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
            lockstep: crate::linsolve::lockstep_cg::Workspace::default(),
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

    /// Advances `state` by one step of the hexahedral model `model` with its field `ff` alone:
    /// [`Self::step_fields`] with that one field.
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
        self.step_fields(model, &mut [&mut ff.bind(model)], fixed, loads, state)
    }

    /// Advances `state` by one step under the forces of `fields` (their sum: the tissue, and
    /// whatever else acts on the same nodes), with `mass` and the external `loads`.
    ///
    /// The solver is [`Self::solver`]. Where the fields are one hexahedral elasticity
    /// ([`ForceField::hexahedra`]) the solves run element by element on it (block-Jacobi CG on
    /// two threads in lockstep, sparse Cholesky); for any other set of fields the system is
    /// solved by block-Jacobi CG through the fields' products, whatever solver is set (a sparse
    /// factor needs the elements' matrices, which only the hexahedra give).
    ///
    /// # Panics
    /// With a Cholesky solver, if the system is not positive definite on the free nodes (a free
    /// node without mass), which a model built from a grid never has.
    pub fn step_fields(
        &mut self,
        mass: &dyn Mass,
        fields: &mut [&mut dyn ForceField],
        fixed: &FixedNodes,
        loads: &Loads,
        state: &mut State,
    ) -> CgReport {
        let lumped = mass.lumped();
        let n = lumped.len();
        let h = self.dt;
        let Rayleigh { alpha, beta } = self.damping;
        let started = std::time::Instant::now();
        for field in fields.iter_mut() {
            field.update(&state.x);
        }
        let fields: &[&mut dyn ForceField] = fields;
        let rotated = std::time::Instant::now();
        let exec = fields.first().map_or_else(Executor::single_thread, |f| f.executor().clone());
        let hexahedra = match fields {
            [only] => only.hexahedra(),
            _ => None,
        };
        let solver = if hexahedra.is_some() { self.solver } else { LinearSolver::JacobiCg };
        // rhs = h (f_int + f_ext − αM v − (β + h) K v). The lockstep solve forms the element
        // terms itself, in its first pass; the others get them here.
        let lockstep = hexahedra.is_some()
            && solver == LinearSolver::JacobiCg
            && self.mass == MassMatrix::Lumped;
        let consistent = self.mass == MassMatrix::Consistent && mass.has_consistent();
        let mut rhs = std::mem::take(&mut self.rhs);
        rhs.clear();
        rhs.resize(n, [0.0; 3]);
        if consistent {
            loads.add_to(mass, &mut rhs);
            mass.add_consistent_times(-alpha, &state.v, &mut rhs);
        } else {
            exec.update_elements(&mut rhs, |i, r| {
                loads.add_at(lumped, i, r);
                let m = lumped[i];
                for k in 0..3 {
                    r[k] -= alpha * m * state.v[i][k];
                }
            });
        }
        if !lockstep {
            for field in fields {
                field.add_forces_and_stiffness_times(&state.x, -(beta + h), &state.v, &mut rhs);
            }
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
        let reference = h * load_scale(lumped, loads, fixed);
        // CG starts from the last steps' velocity changes extrapolated (a smooth motion's
        // acceleration changes slowly): on B3 at 1 ms the cubic saves half the iterations, to the
        // same tolerance.
        self.history.retain(|d| d.len() == n);
        let mut dv = std::mem::take(&mut self.spare);
        dv.resize(n, [0.0; 3]);
        starting_guess(&exec, &self.history, &mut dv);
        let x = &state.x;
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            if consistent {
                out.fill([0.0; 3]);
                mass.add_consistent_times(a, p, out);
            } else {
                for (i, o) in out.iter_mut().enumerate() {
                    let m = a * lumped[i];
                    *o = [m * p[i][0], m * p[i][1], m * p[i][2]];
                }
            }
            for field in fields {
                field.add_stiffness_times(x, b, p, out);
            }
        };
        let report = match (solver, hexahedra) {
            (LinearSolver::JacobiCg, Some((model, ff))) if lockstep => {
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
                    preconditioner_into(model, ff, lumped, (a, b), &mut j.blocks, &mut j.scratch);
                    (j.used, j.key) = (0, (a, b));
                    self.jacobi = Some(j);
                }
                let jacobi = self.jacobi.as_mut().expect("built above");
                jacobi.used += 1;
                let pre = &jacobi.blocks;
                let system = crate::linsolve::lockstep_cg::System { model, ff, fixed, a, b, pre };
                let rhs = crate::linsolve::lockstep_cg::Rhs {
                    x: &state.x,
                    v: &state.v,
                    node: &rhs,
                    h,
                    s: -(beta + h),
                    reference,
                };
                crate::linsolve::lockstep_cg::solve(
                    &system,
                    &rhs,
                    &mut dv,
                    self.cg,
                    &mut self.lockstep,
                )
            }
            (LinearSolver::JacobiCg, _) => {
                let diagonal;
                let mass_diagonal = if consistent {
                    diagonal = mass.consistent_diagonal();
                    &diagonal
                } else {
                    lumped
                };
                let pre = match hexahedra {
                    Some((model, ff)) => preconditioner(model, ff, mass_diagonal, a, b),
                    None => field_preconditioner(fields, x, mass_diagonal, a, b),
                };
                solve_against(apply, block_jacobi(&pre), fixed, &rhs, &mut dv, self.cg, reference)
            }
            (LinearSolver::CholeskyCg { refresh_iterations }, Some((model, ff))) => {
                // A node fixed or freed by the edit leaves the old factor without a pivot for it.
                if self.pattern_stale && !self.factor.as_ref().is_some_and(|f| f.serves(fixed)) {
                    self.factor = None;
                }
                self.ensure_factor(model, ff, fixed, a, b);
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
            (LinearSolver::Cholesky, Some((model, ff))) => {
                // The linear model's matrix only changes with the step, the damping, the mass
                // matrix or the topology (which resets the factor): one factorisation serves
                // every step.
                let key = Some((a, b, self.mass));
                self.refresh |=
                    ff.formulation() == Formulation::Corotational || self.factored_for != key;
                self.factored_for = key;
                self.ensure_factor(model, ff, fixed, a, b);
                let mut rr = rhs.clone();
                fixed.project(&mut rr);
                self.factor.as_ref().expect("factorised above").solve(&rr, &mut dv);
                CgReport { iterations: 1, relative_residual: 0.0, converged: true }
            }
            (LinearSolver::CholeskyCg { .. } | LinearSolver::Cholesky, None) => {
                unreachable!("a factor is only asked of hexahedra")
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
                    .expect("the system pattern is valid")
                    .with_executor(ff.executor().clone()),
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
fn load_scale(lumped: &[f64], loads: &Loads, fixed: &FixedNodes) -> f64 {
    let mut sum = 0.0;
    for i in 0..lumped.len() {
        if fixed.is_fixed(i) {
            continue;
        }
        let mut f = [0.0; 3];
        loads.add_at(lumped, i, &mut f);
        sum += f[0] * f[0] + f[1] * f[1] + f[2] * f[2];
    }
    sum.sqrt()
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
