//! The implicit step's block-Jacobi CG (the same iteration as [`crate::linsolve::cg::solve`]) run by a
//! [`crate::exec::team`] of two threads in lockstep, for the lumped-mass system `(a·M + b·K) x = rhs`.
//!
//! The nodes and the elements are each cut into two fixed parts. The first element pass forms the
//! step's right-hand side and `A x₀` together ([`Rhs`]). Per iteration:
//! 1. each element part sums its rotated stiffness products `b·R K Rᵀ p` into its own node
//!    vector, in element order;
//! 2. each node part forms `Ap` (its mass term, then the element parts' sums in part order) and
//!    its share of `p·Ap`;
//! 3. each node part updates its `x`, `r` and `z` (the preconditioner is per node) and forms its
//!    shares of `r·z` and `r·r`;
//! 4. every thread updates its own whole copy of `p` from `z` (a few microseconds done twice,
//!    instead of a barrier and a shared vector every element would read through).
//!
//! Between the steps the threads meet at a barrier; the dot products are the parts' partial sums
//! added in part order. Nothing depends on which thread did a part, so one thread and two give the
//! same bits.

use crate::constraint::FixedNodes;
use crate::exec::team::{self, PARTS};
use crate::forcefield::hex::HexForceField;
use crate::linsolve::cg::{CgReport, CgSettings, dot};
use crate::linsolve::implicit::StepRhs as Rhs;
use crate::model::HexModel;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, mul_vec};
use std::ops::Range;
use std::sync::{Mutex, MutexGuard, RwLock};

/// Below this many elements the second thread is not worth waking: scene B1, just above it,
/// gains from it a little, a block half its size loses a little
/// (`docs/notebook/code-comment-figures.md`).
const TEAM_MIN: usize = 128;

/// A node part's vectors (`z` is shared separately: every thread reads all of it).
#[derive(Default)]
struct NodePart {
    x: Vec<Vec3>,
    r: Vec<Vec3>,
    ap: Vec<Vec3>,
    b: Vec<Vec3>,
}

/// The system `(a·M_lumped + b·K(rotations)) x = rhs` with its block-Jacobi preconditioner.
pub(crate) struct System<'a> {
    pub model: &'a HexModel,
    pub ff: &'a HexForceField,
    pub fixed: &'a FixedNodes,
    pub a: f64,
    pub b: f64,
    /// Inverse diagonal blocks, per node.
    pub pre: &'a [Mat3],
}

/// The solve's vectors, kept between solves: allocating them per step (about 1.4 MB on scene
/// B3) made the allocator return and re-fault pages every step.
#[derive(Default)]
pub(crate) struct Workspace {
    parts: [Mutex<NodePart>; PARTS],
    z: [RwLock<Vec<Vec3>>; PARTS],
    sums: [RwLock<Vec<Vec3>>; PARTS],
    forces: [RwLock<Vec<Vec3>>; PARTS],
    /// Each thread's copy of the search direction.
    directions: [Mutex<Vec<Vec3>>; PARTS],
}

/// `v` resized to `len` (its contents are overwritten before they are read).
fn sized(v: &mut Vec<Vec3>, len: usize) {
    v.resize(len, [0.0; 3]);
}

/// Solves the system with right-hand side `rhs` for `x`, starting from `x` (warm start); the
/// same stopping rule and iteration as [`crate::linsolve::cg::solve`].
pub(crate) fn solve(
    sys: &System,
    rhs: &Rhs,
    x: &mut [Vec3],
    settings: CgSettings,
    work: &mut Workspace,
) -> CgReport {
    let model = sys.model;
    let n = model.node_count();
    let nodes = team::split(0..n, 1);
    let elements = team::split(0..model.elements.len(), 2);
    project(sys.fixed, 0, x);
    let spans: [Range<usize>; PARTS] = std::array::from_fn(|q| {
        let touched = model.elements[elements[q].clone()].iter().flat_map(|e| e.nodes);
        touched
            .fold(None, |span: Option<Range<usize>>, n| {
                let n = n as usize;
                Some(span.map_or(n..n + 1, |s| s.start.min(n)..s.end.max(n + 1)))
            })
            .unwrap_or(0..0)
    });
    for q in 0..PARTS {
        let part = work.parts[q].get_mut().expect("no thread panicked");
        let range = nodes[q].clone();
        part.x.clear();
        part.x.extend_from_slice(&x[range.clone()]);
        for v in [&mut part.r, &mut part.ap, &mut part.b] {
            sized(v, range.len());
        }
        sized(work.z[q].get_mut().expect("no thread panicked"), range.len());
        // The element sums are cleared inside their span before every pass; outside it they
        // must be zero (a kept buffer may hold another model's sums there).
        for sums in [&mut work.sums[q], &mut work.forces[q]] {
            let sums = sums.get_mut().expect("no thread panicked");
            sized(sums, n);
            sums[..spans[q].start].fill([0.0; 3]);
            sums[spans[q].end..].fill([0.0; 3]);
        }
        let direction = work.directions[q].get_mut().expect("no thread panicked");
        direction.clear();
        direction.extend_from_slice(x);
    }
    let shared = Shared {
        sys,
        nodes: &nodes,
        elements: &elements,
        parts: &work.parts,
        z: &work.z,
        sums: &work.sums,
        forces: &work.forces,
        spans: &spans,
    };
    let directions = &work.directions;
    let report = team::run(sys.ff.executor(), model.elements.len() >= TEAM_MIN, |m| {
        // Rank 0 of a one-thread team does both parts with the first copy.
        let mut p = directions[m.rank()].lock().expect("no thread panicked");
        shared.iterate(m, rhs, &mut p, settings)
    });
    for (q, part) in work.parts.iter_mut().enumerate() {
        let part = part.get_mut().expect("no thread panicked");
        x[nodes[q].clone()].copy_from_slice(&part.x);
    }
    report
}

/// What both threads of the team see.
struct Shared<'a> {
    sys: &'a System<'a>,
    nodes: &'a [Range<usize>; PARTS],
    elements: &'a [Range<usize>; PARTS],
    parts: &'a [Mutex<NodePart>; PARTS],
    /// The preconditioned residual, by node part.
    z: &'a [RwLock<Vec<Vec3>>; PARTS],
    /// Each element part's stiffness product summed per node (zero outside its span).
    sums: &'a [RwLock<Vec<Vec3>>; PARTS],
    /// Each element part's elastic forces summed per node (the right-hand side's element terms).
    forces: &'a [RwLock<Vec<Vec3>>; PARTS],
    /// The nodes each element part touches.
    spans: &'a [Range<usize>; PARTS],
}

impl Shared<'_> {
    fn part(&self, q: usize) -> MutexGuard<'_, NodePart> {
        self.parts[q].lock().expect("no thread panicked")
    }

    /// The CG iteration, run by every member of the team; `p` is this thread's copy of the
    /// search direction, first the (projected) starting point.
    fn iterate(
        &self,
        m: &team::Member,
        rhs: &Rhs,
        p: &mut [Vec3],
        settings: CgSettings,
    ) -> CgReport {
        // b and A x.
        self.apply_step(m, p, rhs);
        let [bb] = m.sum(|q| {
            let part = self.part(q);
            [dot(&part.b, &part.b)]
        });
        let b_norm = bb.sqrt();
        if b_norm == 0.0 {
            for q in m.parts() {
                self.part(q).x.fill([0.0; 3]);
            }
            return CgReport { iterations: 0, relative_residual: 0.0, converged: true };
        }
        // r = b − A x, z = P r, p = z.
        let [mut rz, rr] = m.sum(|q| {
            let mut guard = self.part(q);
            let part = &mut *guard;
            for ((r, b), a) in part.r.iter_mut().zip(&part.b).zip(&part.ap) {
                *r = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            }
            self.precondition(q, part)
        });
        for (q, range) in self.nodes.iter().enumerate() {
            p[range.clone()].copy_from_slice(&self.z[q].read().expect("no thread panicked"));
        }
        let scale = b_norm.max(rhs.reference);
        let mut rel = rr.sqrt() / scale;
        let mut it = 0;
        while rel > settings.tolerance && it < settings.max_iterations {
            self.apply(m, p);
            let [pap] = m.sum(|q| [dot(&p[self.nodes[q].clone()], &self.part(q).ap)]);
            if pap <= 0.0 {
                break;
            }
            let alpha = rz / pap;
            let [rz_new, rr] = m.sum(|q| {
                let mut guard = self.part(q);
                let part = &mut *guard;
                let pq = &p[self.nodes[q].clone()];
                for (((x, r), pi), a) in part.x.iter_mut().zip(&mut part.r).zip(pq).zip(&part.ap) {
                    for k in 0..3 {
                        x[k] += alpha * pi[k];
                        r[k] -= alpha * a[k];
                    }
                }
                self.precondition(q, part)
            });
            let beta = rz_new / rz;
            rz = rz_new;
            for (q, range) in self.nodes.iter().enumerate() {
                let z = self.z[q].read().expect("no thread panicked");
                for (pi, zi) in p[range.clone()].iter_mut().zip(z.iter()) {
                    for k in 0..3 {
                        pi[k] = zi[k] + beta * pi[k];
                    }
                }
            }
            rel = rr.sqrt() / scale;
            it += 1;
        }
        CgReport { iterations: it, relative_residual: rel, converged: rel <= settings.tolerance }
    }

    /// `ap = A p` (fixed nodes projected out) for this member's node parts. Each element part
    /// sums its products into its own node vector, in element order; a node's value is then its
    /// mass term plus the parts' sums in part order.
    fn apply(&self, m: &team::Member, p: &[Vec3]) {
        let sys = self.sys;
        for q in m.parts() {
            let mut sum = self.sums[q].write().expect("no thread panicked");
            sum[self.spans[q].clone()].fill([0.0; 3]);
            sys.ff.add_stiffness_products_of(
                sys.model,
                sys.b,
                p,
                self.elements[q].clone(),
                &mut sum,
            );
        }
        m.barrier();
        self.node_products(m, p);
    }

    /// `ap = a·M p + Σ parts' sums` (fixed nodes projected out) for this member's node parts,
    /// once every element part's sum is complete.
    fn node_products(&self, m: &team::Member, p: &[Vec3]) {
        let sys = self.sys;
        let sums: [_; PARTS] =
            std::array::from_fn(|q| self.sums[q].read().expect("no thread panicked"));
        for q in m.parts() {
            let mut part = self.part(q);
            let range = self.nodes[q].clone();
            let (s0, s1) = (&sums[0][range.clone()], &sums[1][range.clone()]);
            let (mass, pq) = (&sys.model.lumped_mass[range.clone()], &p[range.clone()]);
            for (i, o) in part.ap.iter_mut().enumerate() {
                let m = sys.a * mass[i];
                *o = std::array::from_fn(|k| (m * pq[i][k] + s0[i][k]) + s1[i][k]);
            }
            project(sys.fixed, range.start, &mut part.ap);
        }
    }

    /// [`Shared::apply`] for the first product of an implicit step, which also forms the
    /// right-hand side `b = h (node + f(x) − s·K v)` in the same element pass.
    fn apply_step(&self, m: &team::Member, p: &[Vec3], rhs: &Rhs) {
        let sys = self.sys;
        let Rhs { x, v, node, h, s, .. } = *rhs;
        for q in m.parts() {
            let mut sum = self.sums[q].write().expect("no thread panicked");
            let mut force = self.forces[q].write().expect("no thread panicked");
            sum[self.spans[q].clone()].fill([0.0; 3]);
            force[self.spans[q].clone()].fill([0.0; 3]);
            sys.ff.add_step_products(
                sys.model,
                (x, s, v),
                (sys.b, p),
                self.elements[q].clone(),
                &mut force,
                &mut sum,
            );
        }
        m.barrier();
        let forces: [_; PARTS] =
            std::array::from_fn(|q| self.forces[q].read().expect("no thread panicked"));
        for q in m.parts() {
            let range = self.nodes[q].clone();
            let mut part = self.part(q);
            let (f0, f1) = (&forces[0][range.clone()], &forces[1][range.clone()]);
            for (i, b) in part.b.iter_mut().enumerate() {
                let n = &node[range.start + i];
                *b = std::array::from_fn(|k| h * ((n[k] + f0[i][k]) + f1[i][k]));
            }
            project(sys.fixed, range.start, &mut part.b);
        }
        self.node_products(m, p);
    }

    /// `z = P r` on node part `q`, fixed nodes projected out; returns this part's `r·z` and
    /// `r·r`.
    fn precondition(&self, q: usize, part: &NodePart) -> [f64; 2] {
        let start = self.nodes[q].start;
        let blocks = &self.sys.pre[self.nodes[q].clone()];
        let mut z = self.z[q].write().expect("no thread panicked");
        for ((zi, r), block) in z.iter_mut().zip(&part.r).zip(blocks) {
            *zi = mul_vec(block, r);
        }
        project(self.sys.fixed, start, &mut z);
        [dot(&part.r, &z), dot(&part.r, &part.r)]
    }
}

/// Zeroes the entries of fixed nodes in `v`, whose first entry is node `start`.
fn project(fixed: &FixedNodes, start: usize, v: &mut [Vec3]) {
    for (i, vi) in v.iter_mut().enumerate() {
        if fixed.is_fixed(start + i) {
            *vi = [0.0; 3];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forcefield::hex::Formulation;
    use crate::linsolve::cg::block_jacobi;
    use incise_grid::procedural::from_fn;
    use incise_grid::{BranchedGrid, Material, MaterialTable};

    /// On a twisted block (every element rotated differently) the lockstep solve, forming an
    /// implicit step's right-hand side itself, and the serial [`crate::linsolve::cg::solve`] given that
    /// right-hand side assembled reach the same solution, with the same iteration count: the
    /// same iteration, only its sums grouped by part. Tolerance: both stop at ‖r‖ ≤ 1e-10 ‖b‖, so
    /// their solutions differ by about that times the condition number (< 1e3 here).
    #[test]
    fn agrees_with_the_serial_solver() {
        let cells = [9, 7, 5];
        // A notch (an empty column) makes some elements partly filled, with their own matrices.
        let v = from_fn(cells, [0.01; 3], |x, y, _| u16::from((x - 4.5).abs() > 1.0 || y > 3.0));
        let table = MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0));
        let model = HexModel::from_grid(&BranchedGrid::build(&v, &table, 0).unwrap());
        assert!(model.elements.len() >= TEAM_MIN);
        let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-9);
        let x: Vec<Vec3> = model
            .rest
            .iter()
            .map(|p| {
                let t = 3.0 * p[2];
                [p[0] * t.cos() - p[1] * t.sin(), p[0] * t.sin() + p[1] * t.cos(), p[2] * 1.1]
            })
            .collect();
        let mut ff = HexForceField::new(&model, Formulation::Corotational);
        ff.update_rotations(&model, &x);
        let (a, b) = (1.002, 1.1e-5);
        let pre = crate::linsolve::jacobi::preconditioner(&model, &ff, &model.lumped_mass, a, b);
        // A step's right-hand side: positions `x`, some velocities and node terms. The serial
        // solver gets it assembled as the integrator did before; the lockstep one forms it.
        let wave = |i: usize, scale: f64| -> Vec3 {
            let s = i as f64;
            [(0.3 * s).sin(), (0.7 * s).cos(), (1.1 * s).sin()].map(|c| c * scale)
        };
        let v: Vec<Vec3> = (0..model.node_count()).map(|i| wave(i, 1e-3)).collect();
        let node: Vec<Vec3> = (0..model.node_count()).map(|i| wave(i + 7, 1e-4)).collect();
        let (h, s) = (1e-3, -(0.01 + 1e-3));
        let mut rhs = node.clone();
        ff.add_forces_and_stiffness_times(&model, &x, s, &v, &mut rhs);
        for r in &mut rhs {
            *r = r.map(|c| h * c);
        }
        let settings = CgSettings { tolerance: 1e-10, max_iterations: 1000 };
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            for (i, o) in out.iter_mut().enumerate() {
                let m = a * model.lumped_mass[i];
                *o = p[i].map(|c| m * c);
            }
            ff.add_stiffness_times(&model, b, p, out);
        };
        let mut serial = vec![[0.0; 3]; model.node_count()];
        let rs = crate::linsolve::cg::solve(
            apply,
            block_jacobi(&pre),
            &fixed,
            &rhs,
            &mut serial,
            settings,
        );
        let sys = System { model: &model, ff: &ff, fixed: &fixed, a, b, pre: &pre };
        let mut lockstep = vec![[0.0; 3]; model.node_count()];
        let step = Rhs { x: &x, v: &v, node: &node, h, s, reference: 0.0 };
        let rl = solve(&sys, &step, &mut lockstep, settings, &mut Workspace::default());
        assert!(rs.converged && rl.converged, "{rs:?} {rl:?}");
        assert!(rs.iterations.abs_diff(rl.iterations) <= 1, "{rs:?} {rl:?}");
        let norm = |v: &[Vec3]| v.iter().flatten().map(|c| c * c).sum::<f64>().sqrt();
        let diff: Vec<Vec3> = serial
            .iter()
            .zip(&lockstep)
            .map(|(s, l)| std::array::from_fn(|k| s[k] - l[k]))
            .collect();
        let rel = norm(&diff) / norm(&serial);
        assert!(rel < 1e-7, "relative difference {rel:e}");
        for n in (0..model.node_count()).filter(|&n| fixed.is_fixed(n)) {
            assert!(lockstep[n].iter().all(|c| *c == 0.0), "fixed node {n} moved");
        }
    }

    /// A workspace kept from a solve on another model (other sizes, other element spans) gives
    /// the bits a fresh one gives.
    #[test]
    fn a_kept_workspace_gives_a_fresh_ones_bits() {
        let table = MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0));
        let solve_on = |cells: [usize; 3], work: &mut Workspace| {
            let v = from_fn(cells, [0.01; 3], |x, y, _| u16::from(x > 1.5 || y > 2.5));
            let model = HexModel::from_grid(&BranchedGrid::build(&v, &table, 0).unwrap());
            let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-9);
            let x: Vec<Vec3> = model.rest.iter().map(|p| [p[0], p[1], p[2] * 1.05]).collect();
            let mut ff = HexForceField::new(&model, Formulation::Corotational);
            ff.update_rotations(&model, &x);
            let (a, b) = (1.002, 1.1e-5);
            let pre =
                crate::linsolve::jacobi::preconditioner(&model, &ff, &model.lumped_mass, a, b);
            let n = model.node_count();
            let v = vec![[1e-3, 0.0, -2e-3]; n];
            let node = vec![[0.0, 0.0, -1e-3]; n];
            let sys = System { model: &model, ff: &ff, fixed: &fixed, a, b, pre: &pre };
            let step =
                Rhs { x: &x, v: &v, node: &node, h: 1e-3, s: -(0.01 + 1e-3), reference: 0.0 };
            let mut dv = vec![[0.0; 3]; n];
            let settings = CgSettings { tolerance: 1e-10, max_iterations: 1000 };
            solve(&sys, &step, &mut dv, settings, work);
            dv
        };
        let mut kept = Workspace::default();
        solve_on([12, 9, 6], &mut kept);
        let reused = solve_on([9, 7, 5], &mut kept);
        let fresh = solve_on([9, 7, 5], &mut Workspace::default());
        let bits = |v: &[Vec3]| v.iter().flatten().map(|c| c.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&reused), bits(&fresh));
    }
}
