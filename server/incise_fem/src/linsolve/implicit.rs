//! The linear system of an implicit step and the solver that keeps its state between steps.
//!
//! Backward Euler solves `(a·M + b·K + h²·K_own + h·C) Δv = rhs` every step, with `a = 1 + hα`,
//! `b = hβ + h²` and `rhs = h (node + Σ f(x) + s·K v − h·K_own v − C (v − w))`, `s = −(β + h)`:
//! `K` the fields that take the Rayleigh damping, `K_own` and `C` those with damping of their own
//! ([`ForceField::rayleigh_damped`]) ([`StepRhs`]: the one definition of the
//! right-hand side; the lockstep CG forms its element terms in its first pass, the other solvers
//! through [`StepRhs::assemble`]). [`SystemSolver`] owns what a solver carries from one step to
//! the next: block-Jacobi blocks and the lockstep workspace, a Cholesky factor with its renewal
//! cycle, the direct factor and what it was built for.

use super::cg::{CgReport, CgSettings, block_jacobi, solve_against};
use super::cholesky::{Precision, SystemFactor};
use super::jacobi::{field_preconditioner, preconditioner, preconditioner_into};
use super::lockstep_cg;
use crate::constraint::FixedNodes;
use crate::forcefield::ForceField;
use crate::forcefield::hex::{Formulation, HexForceField};
use crate::model::{HexModel, Mass};
use crate::ode::LinearSolver;
use incise_math::Vec3;
use incise_math::mat3::Mat3;

/// The cost of refactorising, in CG iterations with the factor as preconditioner: a numeric
/// factorisation costs a few dozen triangular solves on the block scenes, a ratio that hardly
/// moves with size (bigger supernodes run the factorisation faster), and an iteration adds the
/// operator product to its solve. A count, not a clock, so the choice is the same on every
/// run and frames stay bit-identical.
pub const REFRESH_COST: usize = 30;

/// How long (simulated seconds) block-Jacobi blocks serve before they are rebuilt with the
/// current rotations. Any symmetric positive definite blocks precondition correctly (CG stops at
/// the same tolerance); stale ones only cost iterations, and over 8 ms the rotations hardly move:
/// with 1 ms steps, blocks rebuilt every eighth step cost no more iterations than blocks rebuilt
/// every step, and save the rebuilding (an element loop, a scatter and an inversion per node;
/// `docs/notebook/code-comment-figures.md`). At 10 ms they are rebuilt every step.
const JACOBI_MAX_AGE: f64 = 8e-3;

/// An implicit step's right-hand side, `h (node + Σ f(x) + s·K v)`.
pub(crate) struct StepRhs<'a> {
    /// Positions the fields were updated at.
    pub x: &'a [Vec3],
    /// Velocities.
    pub v: &'a [Vec3],
    /// The node terms: external forces and mass damping.
    pub node: &'a [Vec3],
    /// The time step.
    pub h: f64,
    /// The stiffness term's factor, `−(β + h)`, for the fields that take the Rayleigh damping
    /// (`−h` for the others).
    pub s: f64,
    /// CG stops at `‖r‖ ≤ tolerance · max(‖b‖, reference)` (see [`solve_against`]).
    pub reference: f64,
}

impl StepRhs<'_> {
    /// The right-hand side into `out`, the fields' terms added to the node terms.
    pub(crate) fn assemble(&self, fields: &[&mut dyn ForceField], out: &mut Vec<Vec3>) {
        out.clear();
        out.extend_from_slice(self.node);
        for field in fields {
            let s = if field.rayleigh_damped() { self.s } else { -self.h };
            field.add_forces_and_stiffness_times(self.x, s, self.v, out);
            field.add_damping_forces(self.v, out);
        }
        for r in out.iter_mut() {
            for k in 0..3 {
                r[k] *= self.h;
            }
        }
    }
}

/// The matrix `a·M + b·K + h²·K_own + h·C` of a step (see the module's doc).
pub(crate) struct StepSystem<'a, 'f> {
    pub mass: &'a dyn Mass,
    /// Whether `M` is the consistent mass (else lumped).
    pub consistent: bool,
    pub fields: &'a [&'f mut dyn ForceField],
    /// Positions the fields were updated at.
    pub x: &'a [Vec3],
    pub fixed: &'a FixedNodes,
    pub a: f64,
    pub b: f64,
    /// The time step, for the age of kept preconditioners.
    pub h: f64,
}

impl StepSystem<'_, '_> {
    /// The hexahedra of the fields where they are one hexahedral elasticity.
    fn hexahedra(&self) -> Option<(&HexModel, &HexForceField)> {
        match self.fields {
            [only] => only.hexahedra(),
            _ => None,
        }
    }

    /// `out = (a·M + b·K) p`.
    fn apply(&self, p: &[Vec3], out: &mut [Vec3]) {
        if self.consistent {
            out.fill([0.0; 3]);
            self.mass.add_consistent_times(self.a, p, out);
        } else {
            for ((o, q), &m) in out.iter_mut().zip(p).zip(self.mass.lumped()) {
                let m = self.a * m;
                *o = [m * q[0], m * q[1], m * q[2]];
            }
        }
        for field in self.fields {
            let b = if field.rayleigh_damped() { self.b } else { self.h * self.h };
            field.add_stiffness_times(self.x, b, p, out);
            field.add_damping_times(self.h, p, out);
        }
    }
}

/// Block-Jacobi blocks and what they were built for.
struct JacobiBlocks {
    /// Steps solved with them.
    used: usize,
    /// The system's `(a, b)`.
    key: (f64, f64),
    /// Inverse diagonal blocks, per node.
    blocks: Vec<Mat3>,
    /// Room for the next rebuild's element sums.
    scratch: Vec<Mat3>,
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

/// A sparse Cholesky factor of `a·M + b·K`, kept between steps.
#[derive(Default)]
struct KeptFactor {
    factor: Option<SystemFactor>,
    /// A refactorisation is due before the next solve.
    refresh: bool,
    /// The factor was built for the model before a topology change that kept every node: good
    /// as a preconditioner, but its element map is the old model's, so a refresh rebuilds it.
    pattern_stale: bool,
    /// Factorisations computed so far.
    count: usize,
}

impl KeptFactor {
    /// Builds the symbolic factorisation once, and refactorises when a refresh is due.
    fn ensure(
        &mut self,
        (model, ff): (&HexModel, &HexForceField),
        system: &StepSystem,
        precision: Precision,
    ) -> bool {
        if self.refresh && self.pattern_stale {
            self.factor = None;
        }
        if self.factor.is_none() {
            self.pattern_stale = false;
            self.factor = Some(
                SystemFactor::with_precision(model, system.fixed, precision)
                    .expect("the system pattern is valid")
                    .with_executor(ff.executor().clone()),
            );
            self.refresh = true;
        }
        if !self.refresh {
            return false;
        }
        let factor = self.factor.as_mut().expect("created above");
        let (a, b) = (system.a, system.b);
        if factor.factorize_with(model, ff, a, b, system.consistent).is_err() {
            // Rounding to f32 can lose definiteness on a very stiff system: fall back to f64.
            factor.set_precision(Precision::Double);
            factor
                .factorize_with(model, ff, a, b, system.consistent)
                .expect("a·M + b·K is positive definite on the free nodes");
        }
        self.count += 1;
        self.refresh = false;
        true
    }

    fn forget(&mut self) {
        self.factor = None;
        self.refresh = true;
        self.pattern_stale = false;
    }
}

/// The linear solver of an implicit step and the state it keeps between steps.
pub(crate) struct SystemSolver(Kept);

/// What each kind of solver keeps.
enum Kept {
    /// Block-Jacobi CG: on two threads in lockstep for one hexahedral elasticity with the lumped
    /// mass, through the fields' products otherwise.
    JacobiCg { blocks: Option<JacobiBlocks>, lockstep: lockstep_cg::Workspace },
    /// CG preconditioned by an `f32` Cholesky factor, refreshed by the renewal rule.
    CholeskyCg { refresh_iterations: usize, kept: KeptFactor, cycle: Cycle },
    /// The exact `f64` factor.
    Cholesky { kept: KeptFactor, factored_for: Option<(f64, f64, bool)> },
}

impl SystemSolver {
    /// A solver of kind `kind` with no state yet.
    pub(crate) fn new(kind: LinearSolver) -> Self {
        let fresh = || KeptFactor { refresh: true, ..KeptFactor::default() };
        Self(match kind {
            LinearSolver::JacobiCg => {
                Kept::JacobiCg { blocks: None, lockstep: lockstep_cg::Workspace::default() }
            }
            LinearSolver::CholeskyCg { refresh_iterations } => {
                Kept::CholeskyCg { refresh_iterations, kept: fresh(), cycle: Cycle::default() }
            }
            LinearSolver::Cholesky => Kept::Cholesky { kept: fresh(), factored_for: None },
        })
    }

    /// The kind.
    pub(crate) fn kind(&self) -> LinearSolver {
        match &self.0 {
            Kept::JacobiCg { .. } => LinearSolver::JacobiCg,
            Kept::CholeskyCg { refresh_iterations, .. } => {
                LinearSolver::CholeskyCg { refresh_iterations: *refresh_iterations }
            }
            Kept::Cholesky { .. } => LinearSolver::Cholesky,
        }
    }

    /// Factorisations computed so far.
    pub(crate) fn factorizations(&self) -> usize {
        match &self.0 {
            Kept::JacobiCg { .. } => 0,
            Kept::CholeskyCg { kept, .. } | Kept::Cholesky { kept, .. } => kept.count,
        }
    }

    /// After a topology change: `same_nodes` when every node kept its index. CG preconditioned
    /// by a factor keeps the old one then (still symmetric positive definite and close; the
    /// renewal rule refactorises when the extra iterations cost more than a factorisation); the
    /// direct solver, which must be exact, always starts again, as do the Jacobi blocks.
    pub(crate) fn topology_changed(&mut self, same_nodes: bool) {
        match &mut self.0 {
            Kept::JacobiCg { blocks, .. } => *blocks = None,
            Kept::CholeskyCg { kept, .. } if same_nodes => {
                kept.pattern_stale = kept.factor.is_some();
            }
            Kept::CholeskyCg { kept, .. } | Kept::Cholesky { kept, .. } => {
                kept.factor = None;
                kept.refresh = true;
            }
        }
    }

    /// Forgets everything kept.
    pub(crate) fn reset(&mut self) {
        match &mut self.0 {
            Kept::JacobiCg { blocks, .. } => *blocks = None,
            Kept::CholeskyCg { kept, .. } | Kept::Cholesky { kept, .. } => kept.forget(),
        }
    }

    /// Solves `system · dv = rhs` from the starting guess in `dv`. `assembled` is room for the
    /// right-hand side where the solver does not form it itself. A factor is only built for one
    /// hexahedral elasticity (it needs the elements' matrices); for any other fields the
    /// factor-based kinds solve by block-Jacobi CG through the fields' products.
    pub(crate) fn solve(
        &mut self,
        system: &StepSystem,
        rhs: &StepRhs,
        dv: &mut [Vec3],
        settings: CgSettings,
        assembled: &mut Vec<Vec3>,
    ) -> CgReport {
        let apply = |p: &[Vec3], out: &mut [Vec3]| system.apply(p, out);
        let fixed = system.fixed;
        let hexahedra = system.hexahedra();
        let (a, b) = (system.a, system.b);
        match (&mut self.0, hexahedra) {
            (Kept::JacobiCg { blocks, lockstep }, Some((model, ff))) if !system.consistent => {
                // The lockstep solve forms the right-hand side's element terms in its first
                // element pass, together with `A x₀`.
                let n = model.node_count();
                let stale = blocks.as_ref().is_none_or(|j| {
                    j.used as f64 * system.h >= JACOBI_MAX_AGE - 1e-12
                        || j.key != (a, b)
                        || j.blocks.len() != n
                });
                if stale {
                    let mut j = blocks.take().unwrap_or(JacobiBlocks {
                        used: 0,
                        key: (a, b),
                        blocks: Vec::new(),
                        scratch: Vec::new(),
                    });
                    let lumped = system.mass.lumped();
                    preconditioner_into(model, ff, lumped, (a, b), &mut j.blocks, &mut j.scratch);
                    (j.used, j.key) = (0, (a, b));
                    *blocks = Some(j);
                }
                let jacobi = blocks.as_mut().expect("built above");
                jacobi.used += 1;
                let pre = &jacobi.blocks;
                let sys = lockstep_cg::System { model, ff, fixed, a, b, pre };
                lockstep_cg::solve(&sys, rhs, dv, settings, lockstep)
            }
            (Kept::CholeskyCg { refresh_iterations, kept, cycle }, Some(hex)) => {
                rhs.assemble(system.fields, assembled);
                // A node fixed or freed by the edit leaves the old factor without a pivot for it.
                if kept.pattern_stale && !kept.factor.as_ref().is_some_and(|f| f.serves(fixed)) {
                    kept.factor = None;
                }
                // A preconditioner only needs to be close: single precision halves the bytes
                // every triangular solve reads.
                if kept.ensure(hex, system, Precision::Single) {
                    *cycle = Cycle::default();
                }
                let factor = kept.factor.as_ref().expect("factorised above");
                let report = solve_against(
                    apply,
                    |r, z| factor.solve(r, z),
                    fixed,
                    assembled,
                    dv,
                    settings,
                    rhs.reference,
                );
                cycle.record(report.iterations);
                kept.refresh =
                    report.iterations > *refresh_iterations || cycle.refresh_pays(REFRESH_COST);
                report
            }
            (Kept::Cholesky { kept, factored_for }, Some(hex)) => {
                rhs.assemble(system.fields, assembled);
                // The linear model's matrix only changes with the step, the damping, the mass
                // matrix or the topology (which resets the factor): one factorisation serves
                // every step.
                let key = Some((a, b, system.consistent));
                kept.refresh |=
                    hex.1.formulation() == Formulation::Corotational || *factored_for != key;
                *factored_for = key;
                kept.ensure(hex, system, Precision::Double);
                fixed.project(assembled);
                kept.factor.as_ref().expect("factorised above").solve(assembled, dv);
                CgReport { iterations: 1, relative_residual: 0.0, converged: true }
            }
            // Block-Jacobi CG through the fields' products: for any fields but one hexahedral
            // elasticity, and for that one with the consistent mass.
            _ => {
                rhs.assemble(system.fields, assembled);
                let mass = mass_diagonal(system);
                let pre = match hexahedra {
                    Some((model, ff)) => preconditioner(model, ff, &mass, a, b),
                    None => field_preconditioner(system.fields, rhs.x, &mass, a, b, system.h),
                };
                solve_against(
                    apply,
                    block_jacobi(&pre),
                    fixed,
                    assembled,
                    dv,
                    settings,
                    rhs.reference,
                )
            }
        }
    }
}

/// The diagonal of the system's mass matrix.
fn mass_diagonal<'a>(system: &StepSystem<'a, '_>) -> std::borrow::Cow<'a, [f64]> {
    if system.consistent {
        system.mass.consistent_diagonal().into()
    } else {
        system.mass.lumped().into()
    }
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
