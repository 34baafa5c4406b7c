//! Linearised backward Euler (Baraff & Witkin 1998), one solve per step:
//! `(M + hC + h²K) Δv = h (f(x₀) − C v₀ + f_ext − h K v₀)`, `C = αM + βK` (Rayleigh),
//! `v₁ = v₀ + Δv`, `x₁ = x₀ + h v₁`; CG warm-started from the previous steps' `Δv`
//! extrapolated (`warm_start`).

use crate::constraint::FixedNodes;
use crate::exec::Executor;
use crate::forcefield::ForceField;
use crate::forcefield::hex::HexForceField;
use crate::linsolve::cg::{CgReport, CgSettings};
use crate::linsolve::implicit::{StepRhs, StepSystem, SystemSolver};
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
    /// current rotations) when that lowers the average cost per step (see [`crate::ode::REFRESH_COST`]), and
    /// always when a solve needs more than `refresh_iterations` iterations.
    CholeskyCg {
        /// Iterations above which the factorisation is refreshed for the next step.
        refresh_iterations: usize,
    },
    /// Sparse Cholesky of the current system every step (exact solve, no iteration).
    Cholesky,
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

/// Linearised backward Euler with its linear solver (which keeps its own state between steps:
/// factor, refresh cycle, Jacobi blocks, workspaces) and the warm start.
pub struct BackwardEuler {
    /// Time step (s).
    pub dt: f64,
    /// Rayleigh damping.
    pub damping: Rayleigh,
    /// Linear-solve settings (CG variants).
    pub cg: CgSettings,
    /// The mass matrix of the system and of the mass damping (gravity is the same either way:
    /// the consistent mass's rows sum to the lumped one).
    pub mass: MassMatrix,
    solver: SystemSolver,
    /// The last steps' velocity changes, the most recent first (at most [`HISTORY`]): CG's
    /// starting guess is their extrapolation ([`starting_guess`]).
    history: Vec<Vec<Vec3>>,
    /// The step's node terms, its assembled right-hand side and the next starting guess, kept
    /// between steps (a step allocates nothing once they have their size).
    node: Vec<Vec3>,
    assembled: Vec<Vec3>,
    spare: Vec<Vec3>,
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
            mass: MassMatrix::Lumped,
            solver: SystemSolver::new(solver),
            history: Vec::new(),
            node: Vec::new(),
            assembled: Vec::new(),
            spare: Vec::new(),
            stage_times: StageTimes::default(),
        }
    }

    /// The linear solver's kind.
    #[must_use]
    pub fn solver(&self) -> LinearSolver {
        self.solver.kind()
    }

    /// Factorisations computed so far (a counter for reports).
    #[must_use]
    pub fn factorizations(&self) -> usize {
        self.solver.factorizations()
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
        // Extrapolation starts again from the remapped step.
        let old = std::mem::take(&mut self.history).into_iter().next().unwrap_or_default();
        let same_nodes = old.len() == old_of_new.len()
            && old_of_new.iter().enumerate().all(|(i, &o)| o == Some(i));
        self.history = vec![
            old_of_new
                .iter()
                .map(|o| o.and_then(|j| old.get(j).copied()).unwrap_or([0.0; 3]))
                .collect(),
        ];
        self.solver.topology_changed(same_nodes);
    }

    /// The last steps' velocity changes, the most recent first: the next solve's warm start.
    #[must_use]
    pub fn warm_start(&self) -> &[Vec<Vec3>] {
        &self.history
    }

    /// Sets the warm start (restoring a snapshot of the state) and drops what the linear solver
    /// keeps ([`Self::drop_kept`]).
    ///
    /// # Errors
    /// With more than the integrator keeps, or vectors of other lengths than `nodes`.
    pub fn set_warm_start(&mut self, history: Vec<Vec<Vec3>>, nodes: usize) -> Result<(), String> {
        if history.len() > HISTORY {
            return Err(format!("{} warm-start steps; at most {HISTORY} are kept", history.len()));
        }
        if let Some(bad) = history.iter().find(|h| h.len() != nodes) {
            return Err(format!("a warm-start step of {} nodes for {nodes}", bad.len()));
        }
        self.history = history;
        self.solver.reset();
        Ok(())
    }

    /// Drops what the linear solver keeps between steps (block-Jacobi blocks, a factor and its
    /// renewal cycle), keeping the warm start: the next step builds them from the state alone.
    /// What it keeps depends on the rotations of the step that built it, which a snapshot of
    /// the state does not hold; a simulation drops it at each keyframe so that a replay
    /// restored there steps as the session did.
    pub fn drop_kept(&mut self) {
        self.solver.reset();
    }

    /// Forgets the warm start and the factorisation (after the topology changed).
    pub fn reset_warm_start(&mut self) {
        self.history.clear();
        self.solver.reset();
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
        let consistent = self.mass == MassMatrix::Consistent && mass.has_consistent();
        // The node terms of rhs = h (f_ext − αM v + Σ f(x) − (β + h) K v); the solver adds the
        // fields' terms (see `StepRhs`).
        let mut node = std::mem::take(&mut self.node);
        node.clear();
        node.resize(n, [0.0; 3]);
        if consistent {
            loads.add_to(mass, &mut node);
            mass.add_consistent_times(-alpha, &state.v, &mut node);
        } else {
            exec.update_elements(&mut node, |i, r| {
                loads.add_at(lumped, i, r);
                let m = lumped[i];
                for k in 0..3 {
                    r[k] -= alpha * m * state.v[i][k];
                }
            });
        }
        let a = 1.0 + h * alpha;
        let b = h * beta + h * h;
        // CG's residual is measured against the larger of the right-hand side and h‖f_ext‖,
        // what the right-hand side is when the loads are out of balance: at rest the right-hand
        // side is the rounding noise of f_int + f_ext ≈ 0, and solving to 1e-6 of that noise took
        // ever more iterations as a body settled. It
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
        let rhs = StepRhs { x: &state.x, v: &state.v, node: &node, h, s: -(beta + h), reference };
        let system = StepSystem { mass, consistent, fields, x: &state.x, fixed, a, b, h };
        let report = self.solver.solve(&system, &rhs, &mut dv, self.cg, &mut self.assembled);
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
        self.node = node;
        let ns = |d: std::time::Duration| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        self.stage_times = StageTimes {
            rotations_ns: ns(rotated - started),
            solve_ns: ns(solved - rotated),
            update_ns: ns(solved.elapsed()),
        };
        report
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
