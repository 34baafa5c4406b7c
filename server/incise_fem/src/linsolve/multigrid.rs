//! Geometric multigrid on the branched grid's levels: a preconditioner for CG on a fine model
//! (after Dick, Georgii, Westermann 2011, whose hexahedral multigrid for cutting duplicates coarse
//! cells per connected piece exactly as the branched grid does).
//!
//! Each level is the model of the same label volume at one grid level. A node of level `l` takes
//! the trilinear field of the corners of the level-`l + 1` element that owns its voxels
//! (prolongation `P`); a coarse element is one connected piece of its cell, so pieces the fine
//! level holds apart stay apart on every coarser level. The coarse operators are the coarse
//! models' own matrices: condensation (Jeřábková 2010 eq. 1–4) is the Galerkin product of the
//! voxels' stiffness with the same trilinear interpolation, so `K_{l+1} = Pᵀ K_l P` to rounding
//! on a grid without branched cells (`tests/multigrid.rs`). Where the grid duplicates a node
//! for pieces that meet there, a fine node follows one of the pieces and the two can differ; the
//! cycle stays symmetric and positive either way, only its convergence could suffer.
//!
//! The V-cycle: `sweeps` damped block-Jacobi sweeps, the residual restricted (`Pᵀ`), the next
//! level's correction prolonged and added, `sweeps` more sweeps; the coarsest level is solved by
//! sparse Cholesky. Pre- and post-smoothing are the same symmetric sweeps, so the cycle is a
//! symmetric positive definite preconditioner, as CG requires.

use super::cholesky::{FactorError, SystemFactor};
use super::jacobi::preconditioner_into;
use crate::constraint::FixedNodes;
use crate::exec::Executor;
use crate::forcefield::hex::{Formulation, HexForceField};
use crate::model::HexModel;
use incise_grid::BranchedGrid;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, mul_vec};
use std::cell::RefCell;

/// Power iterations that estimate the largest eigenvalue of `D⁻¹ A` on a level.
const POWER_ITERATIONS: usize = 12;

/// The estimate is raised by this much: power iteration approaches the largest eigenvalue from
/// below, and a smoother damped for too small a one amplifies the modes above it.
const ESTIMATE_MARGIN: f64 = 1.1;

/// Trilinear interpolation from a coarse level's nodes onto a finer one's: up to eight
/// (coarse node, weight) pairs per fine node.
#[derive(Clone, Debug)]
pub struct Prolongation {
    /// Per fine node, its coarse nodes and weights (zero weights dropped).
    rows: Vec<Vec<(u32, f64)>>,
    /// Number of coarse nodes.
    coarse_nodes: usize,
}

impl Prolongation {
    /// The interpolation from `coarse` (the model of `coarse_grid`) onto `fine` (of `fine_grid`,
    /// built from the same volume at a finer level): each fine node follows the coarse element
    /// that owns the voxels of the first fine element using it.
    ///
    /// # Errors
    /// When a fine element's voxel has no coarse element (the grids were built from different
    /// volumes).
    pub fn new(
        fine_grid: &BranchedGrid,
        fine: &HexModel,
        coarse_grid: &BranchedGrid,
        coarse: &HexModel,
    ) -> Result<Self, String> {
        let mut coarse_of_grid = vec![u32::MAX; coarse_grid.top().element_capacity()];
        for (i, e) in coarse.elements.iter().enumerate() {
            coarse_of_grid[e.grid_id as usize] = i as u32;
        }
        let size = coarse.element_size;
        let mut rows: Vec<Option<Vec<(u32, f64)>>> = vec![None; fine.node_count()];
        for e in &fine.elements {
            if e.nodes.iter().all(|&n| rows[n as usize].is_some()) {
                continue;
            }
            let voxel = fine_grid
                .top()
                .element(e.grid_id)
                .map(|g| g.min_voxel)
                .ok_or_else(|| format!("fine element {} is not in its grid", e.grid_id))?;
            let owner = coarse_grid
                .voxel_element(voxel)
                .map(|g| coarse_of_grid[g as usize])
                .filter(|&c| c != u32::MAX)
                .ok_or_else(|| format!("voxel {voxel} has no element at the coarse level"))?;
            let corners = coarse.elements[owner as usize].nodes;
            let origin = coarse.rest[corners[0] as usize];
            for &n in &e.nodes {
                let row = &mut rows[n as usize];
                if row.is_some() {
                    continue;
                }
                let p = fine.rest[n as usize];
                let s: [f64; 3] = std::array::from_fn(|a| (p[a] - origin[a]) / size[a]);
                let mut weights = Vec::with_capacity(8);
                for (c, &node) in corners.iter().enumerate() {
                    let w: f64 =
                        (0..3).map(|a| if (c >> a) & 1 == 1 { s[a] } else { 1.0 - s[a] }).product();
                    if w.abs() > 1e-12 {
                        weights.push((node, w));
                    }
                }
                *row = Some(weights);
            }
        }
        let rows = rows.into_iter().map(Option::unwrap_or_default).collect();
        Ok(Self { rows, coarse_nodes: coarse.node_count() })
    }

    /// `fine += P coarse`.
    pub fn add_prolonged(&self, coarse: &[Vec3], fine: &mut [Vec3]) {
        for (f, row) in fine.iter_mut().zip(&self.rows) {
            for &(c, w) in row {
                let v = coarse[c as usize];
                for k in 0..3 {
                    f[k] += w * v[k];
                }
            }
        }
    }

    /// `coarse = Pᵀ fine`.
    pub fn restrict(&self, fine: &[Vec3], coarse: &mut [Vec3]) {
        coarse.fill([0.0; 3]);
        for (f, row) in fine.iter().zip(&self.rows) {
            for &(c, w) in row {
                let v = &mut coarse[c as usize];
                for k in 0..3 {
                    v[k] += w * f[k];
                }
            }
        }
    }

    /// The coarse positions that interpolate `fine` best in the weighted mean
    /// `x_c = D⁻¹ Pᵀ x`, `D = diag(Pᵀ 1)` (rest positions where no fine node follows a coarse
    /// node): what the coarse level's rotations are taken at.
    fn coarse_positions(&self, fine: &[Vec3], rest: &[Vec3]) -> Vec<Vec3> {
        let mut sum = vec![[0.0; 3]; self.coarse_nodes];
        let mut weight = vec![0.0; self.coarse_nodes];
        for (f, row) in fine.iter().zip(&self.rows) {
            for &(c, w) in row {
                weight[c as usize] += w;
                for k in 0..3 {
                    sum[c as usize][k] += w * f[k];
                }
            }
        }
        sum.iter()
            .zip(&weight)
            .zip(rest)
            .map(|((s, &w), r)| if w > 0.0 { s.map(|v| v / w) } else { *r })
            .collect()
    }
}

/// One level of the hierarchy.
struct Level {
    model: HexModel,
    field: HexForceField,
    fixed: FixedNodes,
    /// Inverse diagonal blocks of `a·M + b·K` at this level.
    inverse: Vec<Mat3>,
    /// The smoother's damping `ω = 4 / (3 Λ)`, `Λ` the estimated largest eigenvalue of `D⁻¹ A`
    /// raised by [`ESTIMATE_MARGIN`]: a sweep multiplies a mode of eigenvalue `μ` by `1 − ωμ`,
    /// so every mode in `[Λ/2, Λ]` shrinks at least threefold and none up to `1.5 Λ` grows.
    weight: f64,
    /// From the next coarser level onto this one (`None` on the coarsest).
    from_coarser: Option<Prolongation>,
}

/// Work vectors per level: residual, correction, operator product.
#[derive(Default)]
struct Scratch {
    r: Vec<Vec3>,
    z: Vec<Vec3>,
    a: Vec<Vec3>,
}

/// The multigrid preconditioner for `a·M + b·K` (lumped `M`) on the finest level's model.
pub struct Multigrid {
    /// Finest first.
    levels: Vec<Level>,
    coarsest: SystemFactor,
    a: f64,
    b: f64,
    sweeps: usize,
    scratch: RefCell<Vec<Scratch>>,
}

/// What a level of the hierarchy is built from: its grid, its model, and the nodes held fixed
/// on it.
pub struct LevelSpec<'a> {
    /// The grid of the level (its top level is the model's).
    pub grid: &'a BranchedGrid,
    /// The model of that grid.
    pub model: HexModel,
    /// The supports, as they fall on this level's nodes.
    pub fixed: FixedNodes,
}

impl Multigrid {
    /// The hierarchy over `levels` (finest first, each grid one level coarser than the one
    /// before), preconditioning `a·M + b·K` with `sweeps` smoothing sweeps before and after each
    /// coarse correction, every level's loops on `exec` (the fine problem's executor: one pool
    /// of threads, not one per level). The rotations start at rest; see [`Multigrid::update`].
    ///
    /// # Errors
    /// When the levels do not nest (see [`Prolongation::new`]) or the coarsest level's matrix
    /// cannot be factorised (no support).
    pub fn new(
        levels: Vec<LevelSpec<'_>>,
        formulation: Formulation,
        a: f64,
        b: f64,
        sweeps: usize,
        exec: &Executor,
    ) -> Result<Self, String> {
        let prolongations = (0..levels.len())
            .map(|i| {
                levels
                    .get(i + 1)
                    .map(|c| Prolongation::new(levels[i].grid, &levels[i].model, c.grid, &c.model))
            })
            .map(Option::transpose)
            .collect::<Result<Vec<_>, _>>()?;
        let built: Vec<Level> = levels
            .into_iter()
            .zip(prolongations)
            .map(|(spec, from_coarser)| Level {
                field: HexForceField::new(&spec.model, formulation).with_executor(exec.clone()),
                model: spec.model,
                fixed: spec.fixed,
                inverse: Vec::new(),
                weight: 0.0,
                from_coarser,
            })
            .collect();
        let Some(last) = built.last() else {
            return Err("a multigrid needs at least one level".into());
        };
        let coarsest = SystemFactor::new(&last.model, &last.fixed)
            .map_err(|e: FactorError| e.to_string())?
            .with_executor(exec.clone());
        let scratch = built
            .iter()
            .map(|l| {
                let n = l.model.node_count();
                Scratch { r: vec![[0.0; 3]; n], z: vec![[0.0; 3]; n], a: vec![[0.0; 3]; n] }
            })
            .collect();
        let mut mg = Self { levels: built, coarsest, a, b, sweeps, scratch: RefCell::new(scratch) };
        mg.refresh().map_err(|e| e.to_string())?;
        Ok(mg)
    }

    /// Takes every level's rotations at the fine positions `x` (coarser levels at the weighted
    /// mean of the nodes that follow theirs) and rebuilds the smoothers and the coarsest factor.
    ///
    /// # Errors
    /// When the coarsest level's matrix is not positive definite.
    pub fn update(&mut self, x: &[Vec3]) -> Result<(), FactorError> {
        let mut positions = x.to_vec();
        for i in 0..self.levels.len() {
            let level = &mut self.levels[i];
            level.field.update_rotations(&level.model, &positions);
            if let Some(p) = &self.levels[i].from_coarser {
                let coarse_rest = &self.levels[i + 1].model.rest;
                positions = p.coarse_positions(&positions, coarse_rest);
            }
        }
        self.refresh()
    }

    /// Rebuilds the smoothers' blocks and the coarsest factor from the current rotations.
    fn refresh(&mut self) -> Result<(), FactorError> {
        let (a, b) = (self.a, self.b);
        let mut sums = Vec::new();
        for level in &mut self.levels {
            let Level { model, field, inverse, .. } = level;
            preconditioner_into(model, field, &model.lumped_mass, (a, b), inverse, &mut sums);
        }
        for i in 0..self.levels.len() {
            let lambda = self.largest_eigenvalue(i);
            self.levels[i].weight = 4.0 / (3.0 * ESTIMATE_MARGIN * lambda);
        }
        let last = self.levels.last().expect("at least one level");
        self.coarsest.factorize(&last.model, &last.field, a, b)
    }

    /// The largest eigenvalue of `D⁻¹ A` on level `i`'s free nodes, by power iteration from a
    /// fixed start (deterministic).
    fn largest_eigenvalue(&self, i: usize) -> f64 {
        let level = &self.levels[i];
        let n = level.model.node_count();
        let mut v: Vec<Vec3> =
            (0..n).map(|k| std::array::from_fn(|a| ((k * 7 + a * 3) % 11) as f64 - 5.0)).collect();
        level.fixed.project(&mut v);
        let mut av = vec![[0.0; 3]; n];
        let mut lambda = 1.0;
        for _ in 0..POWER_ITERATIONS {
            let norm = super::cg::dot(&v, &v).sqrt();
            if norm == 0.0 {
                break;
            }
            self.apply(i, &v, &mut av);
            for (k, (a, x)) in av.iter().zip(v.iter_mut()).enumerate() {
                *x = mul_vec(&level.inverse[k], a).map(|c| c / norm);
            }
            level.fixed.project(&mut v);
            lambda = super::cg::dot(&v, &v).sqrt();
        }
        lambda
    }

    /// The executor every level's loops run on.
    #[must_use]
    pub fn executor(&self) -> &Executor {
        self.levels[0].field.executor()
    }

    /// Levels, finest first: (nodes, elements) of each.
    #[must_use]
    pub fn sizes(&self) -> Vec<(usize, usize)> {
        self.levels.iter().map(|l| (l.model.node_count(), l.model.elements.len())).collect()
    }

    /// `out = (a·M + b·K) p` on level `i`.
    fn apply(&self, i: usize, p: &[Vec3], out: &mut [Vec3]) {
        let level = &self.levels[i];
        for ((o, q), &m) in out.iter_mut().zip(p).zip(&level.model.lumped_mass) {
            *o = q.map(|v| self.a * m * v);
        }
        level.field.add_stiffness_times(&level.model, self.b, p, out);
    }

    /// `z ≈ (a·M + b·K)⁻¹ r` on the finest level: one V-cycle (fixed nodes get 0).
    pub fn precondition(&self, r: &[Vec3], z: &mut [Vec3]) {
        let mut scratch = self.scratch.borrow_mut();
        scratch[0].r.copy_from_slice(r);
        self.cycle(0, &mut scratch);
        z.copy_from_slice(&scratch[0].z);
    }

    /// One V-cycle from level `i` on `scratch[0].r` into `scratch[0].z` (`scratch` starts at
    /// level `i`).
    fn cycle(&self, i: usize, scratch: &mut [Scratch]) {
        let level = &self.levels[i];
        let (here, below) = scratch.split_first_mut().expect("a scratch per level");
        let Some(prolong) = &level.from_coarser else {
            self.coarsest.solve(&here.r, &mut here.z);
            return;
        };
        let s = here;
        level.fixed.project(&mut s.r);
        s.z.fill([0.0; 3]);
        for sweep in 0..self.sweeps {
            // From z = 0 the first sweep's product is zero: it is left out.
            self.smooth(i, s, sweep == 0);
        }
        // The residual after pre-smoothing, restricted.
        self.apply(i, &s.z, &mut s.a);
        for (a, r) in s.a.iter_mut().zip(&s.r) {
            *a = std::array::from_fn(|k| r[k] - a[k]);
        }
        level.fixed.project(&mut s.a);
        prolong.restrict(&s.a, &mut below[0].r);
        self.cycle(i + 1, below);
        prolong.add_prolonged(&below[0].z, &mut s.z);
        level.fixed.project(&mut s.z);
        for _ in 0..self.sweeps {
            self.smooth(i, s, false);
        }
    }

    /// One damped block-Jacobi sweep: `z += ω D⁻¹ (r − A z)`; with `at_zero` (`z` is zero) the
    /// product is not taken.
    fn smooth(&self, i: usize, s: &mut Scratch, at_zero: bool) {
        let level = &self.levels[i];
        if at_zero {
            s.a.fill([0.0; 3]);
        } else {
            self.apply(i, &s.z, &mut s.a);
        }
        for (n, ((z, r), a)) in s.z.iter_mut().zip(&s.r).zip(&s.a).enumerate() {
            if level.fixed.is_fixed(n) {
                *z = [0.0; 3];
                continue;
            }
            let d = mul_vec(&level.inverse[n], &std::array::from_fn(|k| r[k] - a[k]));
            for k in 0..3 {
                z[k] += level.weight * d[k];
            }
        }
    }
}
