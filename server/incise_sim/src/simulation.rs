//! The simulation loop of one scene: the branched grid at the configured level, the hexahedral
//! model and force field, fixed nodes, loads and the integrator, advanced one step per call.

use crate::calibration::{Calibration, calibrate};
use crate::config::{FixedSpec, IntegratorKind, ModelKind, SceneConfig, SceneError, VolumeSpec};
use incise_fem::cg::CgSettings;
use incise_fem::integrate::{
    BackwardEuler, Loads, Rayleigh, State, explicit_step, stable_dt, static_solve,
};
use incise_fem::{FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::{
    BranchedGrid, EditError, GridChanges, GridEdit, LabelFilter, LabelVolume, MaterialTable,
};
use incise_math::Vec3;
use std::time::Instant;

/// Per-step counters (timings are measurements, not part of the deterministic state).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageCounters {
    /// Wall time of the whole step (ns).
    pub step_ns: u64,
    /// Linear-solver iterations (CG) in the step.
    pub solver_iterations: usize,
    /// Final relative residual of the step's solve.
    pub solver_residual: f64,
}

/// The result of one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Step number, from 1.
    pub index: u64,
    /// Simulated time at the end of the step (s).
    pub time: f64,
    /// Node positions (m, grid frame), in model node order.
    pub positions: Vec<Vec3>,
    /// FNV-1a hash of the positions' and velocities' bits: equal hashes, bit-identical state.
    pub state_hash: u64,
    /// Counters.
    pub counters: StageCounters,
}

enum Integrator {
    Implicit(Box<BackwardEuler>),
    Explicit { dt: f64, alpha: f64 },
    Static { tolerance: f64 },
}

/// A running scene.
pub struct Simulation {
    config: SceneConfig,
    calibration: Option<Calibration>,
    grid: BranchedGrid,
    model: HexModel,
    force_field: HexForceField,
    fixed: FixedNodes,
    loads: Loads,
    state: State,
    integrator: Integrator,
    index: u64,
}

fn fnv(state: &State) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in state.x.iter().chain(state.v.iter()) {
        for c in v {
            for b in c.to_bits().to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
    h
}

impl SceneConfig {
    /// The scene's volume when it is procedural (`None` for a file, which the caller reads).
    #[must_use]
    pub fn procedural_volume(&self) -> Option<LabelVolume> {
        match &self.volume {
            VolumeSpec::Block { size_m, voxels } => {
                let spacing = std::array::from_fn(|a| size_m[a] / voxels[a] as f64);
                Some(incise_grid::procedural::from_fn(*voxels, spacing, |_, _, _| {
                    incise_grid::procedural::TISSUE
                }))
            }
            VolumeSpec::File { .. } => None,
        }
    }
}

/// The nodes of the scene's fixed regions.
pub(crate) fn fixed_nodes(
    config: &SceneConfig,
    grid: &BranchedGrid,
    model: &HexModel,
) -> FixedNodes {
    let tolerance = 1e-9 * grid.element_size().iter().copied().fold(0.0, f64::max);
    let mut fixed = FixedNodes::none(model.node_count());
    for f in &config.fixed {
        let region = match f {
            FixedSpec::Plane { axis, value } => {
                FixedNodes::plane(&model.rest, *axis, *value, tolerance)
            }
            FixedSpec::Box { min, max } => FixedNodes::aabb(&model.rest, *min, *max),
        };
        fixed = fixed.union(&region);
    }
    fixed
}

/// Gravity plus the scene's patch loads spread over the model's nodes.
pub(crate) fn patch_loads(config: &SceneConfig, model: &HexModel) -> Result<Loads, String> {
    let mut nodal = vec![[0.0; 3]; model.node_count()];
    for (k, load) in config.loads.iter().enumerate() {
        let patch: Vec<usize> = (0..model.node_count())
            .filter(|&n| {
                (0..3).map(|a| (model.rest[n][a] - load.centre[a]).powi(2)).sum::<f64>().sqrt()
                    <= load.radius
            })
            .collect();
        if patch.is_empty() {
            return Err(format!(
                "loads[{k}]: no node lies within {} m of {:?}",
                load.radius, load.centre
            ));
        }
        let share = 1.0 / patch.len() as f64;
        for n in patch {
            for a in 0..3 {
                nodal[n][a] += load.force[a] * share;
            }
        }
    }
    Ok(Loads { gravity: config.gravity, nodal })
}

impl Simulation {
    /// Builds the scene on `volume` (from [`SceneConfig::procedural_volume`] or a file). Only what
    /// the scene uses is built: the grid at its level, the model, the chosen integrator.
    pub fn new(config: &SceneConfig, volume: &LabelVolume, file: &str) -> Result<Self, SceneError> {
        let build = |message: String| SceneError::Build { file: file.to_owned(), message };
        let volume = match &config.volume {
            VolumeSpec::File { stride, labels, .. } => {
                let mut filter = LabelFilter::abdominal_ct();
                if !labels.is_empty() {
                    filter = filter.keep(labels);
                }
                volume
                    .filtered(&filter)
                    .crop_and_stride(*stride)
                    .map_err(|e| build(e.to_string()))?
            }
            VolumeSpec::Block { .. } => volume.clone(),
        };
        let mut table = MaterialTable::new();
        for m in &config.materials {
            table.insert(m.label, m.material);
        }
        let mut config = config.clone();
        let calibration = match config.auto_level {
            Some(auto) => {
                let c = calibrate(&config, &volume, &table, auto)
                    .map_err(|e| build(format!("model.kind = \"auto\": {e}")))?;
                config.level = c.chosen;
                Some(c)
            }
            None => None,
        };
        let config = &config;
        let grid =
            BranchedGrid::build(&volume, &table, config.level).map_err(|e| build(e.to_string()))?;
        let model = HexModel::from_grid(&grid);
        let formulation = match config.model {
            ModelKind::Linear => Formulation::Linear,
            ModelKind::Corotational => Formulation::Corotational,
        };
        let force_field = HexForceField::new(&model, formulation);
        let fixed = fixed_nodes(config, &grid, &model);
        let loads = patch_loads(config, &model).map_err(build)?;
        let damping = Rayleigh { alpha: config.rayleigh_alpha, beta: config.rayleigh_beta };
        let integrator = match config.integrator {
            IntegratorKind::ImplicitEuler => {
                Integrator::Implicit(Box::new(BackwardEuler::with_solver(
                    config.dt,
                    damping,
                    CgSettings {
                        tolerance: config.cg_tolerance,
                        max_iterations: 10 * model.dof_count().max(100),
                    },
                    config.solver,
                )))
            }
            IntegratorKind::Explicit => {
                let limit = stable_dt(&model, &force_field, &fixed);
                if config.dt > limit {
                    return Err(build(format!(
                        "integrator.dt = {} s is above the explicit stability limit {limit:.3e} s of this mesh; use a smaller dt or the implicit integrator",
                        config.dt
                    )));
                }
                Integrator::Explicit { dt: config.dt, alpha: config.rayleigh_alpha }
            }
            IntegratorKind::Static => Integrator::Static { tolerance: config.cg_tolerance },
        };
        let state = State::at_rest(&model);
        Ok(Self {
            config: config.clone(),
            calibration,
            grid,
            model,
            force_field,
            fixed,
            loads,
            state,
            integrator,
            index: 0,
        })
    }

    /// Advances one step.
    pub fn step(&mut self) -> Frame {
        let start = Instant::now();
        let mut counters = StageCounters::default();
        match &mut self.integrator {
            Integrator::Implicit(be) => {
                let r = be.step(
                    &self.model,
                    &mut self.force_field,
                    &self.fixed,
                    &self.loads,
                    &mut self.state,
                );
                counters.solver_iterations = r.iterations;
                counters.solver_residual = r.relative_residual;
            }
            Integrator::Explicit { dt, alpha } => {
                explicit_step(
                    &self.model,
                    &mut self.force_field,
                    &self.fixed,
                    &self.loads,
                    *alpha,
                    *dt,
                    &mut self.state,
                );
            }
            Integrator::Static { tolerance } => {
                let r = static_solve(
                    &self.model,
                    &mut self.force_field,
                    &self.fixed,
                    &self.loads,
                    &mut self.state.x,
                    *tolerance,
                    50,
                );
                counters.solver_iterations = r.cg_iterations;
                counters.solver_residual = r.relative_residual;
            }
        }
        self.index += 1;
        counters.step_ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        Frame {
            index: self.index,
            time: self.index as f64 * self.config.dt,
            positions: self.state.x.clone(),
            state_hash: fnv(&self.state),
            counters,
        }
    }

    /// Cuts the grid (voxel removal or link severing) and carries the simulation across the
    /// topology change: surviving nodes keep position and velocity; a node split off another takes
    /// that node's; any other new node takes its element's mean displacement and velocity.
    /// Surviving and split-off elements keep their rotation. Fixed regions and patch loads are
    /// re-applied to the new nodes.
    pub fn cut(&mut self, edit: &GridEdit) -> Result<GridChanges, EditError> {
        let changes = self.grid.apply(edit)?;
        if changes == GridChanges::default() {
            return Ok(changes);
        }
        let model = HexModel::from_grid(&self.grid);
        let old = &self.model;
        // Grid node id → index in the old model (ids beyond the old ones are new nodes).
        let mut old_index =
            vec![u32::MAX; old.grid_node.iter().map(|&g| g as usize + 1).max().unwrap_or(0)];
        for (i, &g) in old.grid_node.iter().enumerate() {
            old_index[g as usize] = i as u32;
        }
        let added: std::collections::BTreeMap<u32, Option<u32>> =
            changes.top.nodes_added.iter().copied().collect();
        let n = model.node_count();
        let mut state = State { x: model.rest.clone(), v: vec![[0.0; 3]; n] };
        let mut known = vec![false; n];
        for (i, &g) in model.grid_node.iter().enumerate() {
            let source = match added.get(&g) {
                Some(origin) => *origin,
                None => Some(g),
            };
            if let Some(j) =
                source.and_then(|s| old_index.get(s as usize).copied()).filter(|&j| j != u32::MAX)
            {
                state.x[i] = self.state.x[j as usize];
                state.v[i] = self.state.v[j as usize];
                known[i] = true;
            }
        }
        for e in &model.elements {
            let have: Vec<usize> =
                e.nodes.iter().map(|&k| k as usize).filter(|&k| known[k]).collect();
            if have.is_empty() {
                continue;
            }
            let mut du = [0.0; 3];
            let mut v = [0.0; 3];
            for &k in &have {
                for a in 0..3 {
                    du[a] += (state.x[k][a] - model.rest[k][a]) / have.len() as f64;
                    v[a] += state.v[k][a] / have.len() as f64;
                }
            }
            for &k in &e.nodes {
                let k = k as usize;
                if !known[k] {
                    state.x[k] = std::array::from_fn(|a| model.rest[k][a] + du[a]);
                    state.v[k] = v;
                    known[k] = true;
                }
            }
        }
        let origin_of: std::collections::BTreeMap<u32, u32> =
            changes.top.elements_added.iter().filter_map(|&(id, o)| o.map(|o| (id, o))).collect();
        self.force_field = self.force_field.remapped(old, &model, |g| origin_of.get(&g).copied());
        self.fixed = fixed_nodes(&self.config, &self.grid, &model);
        for (i, s) in state.v.iter_mut().enumerate() {
            if self.fixed.is_fixed(i) {
                *s = [0.0; 3];
            }
        }
        // A patch that lost all its nodes simply stops pulling.
        self.loads = patch_loads(&self.config, &model)
            .unwrap_or(Loads { gravity: self.config.gravity, nodal: Vec::new() });
        if let Integrator::Implicit(be) = &mut self.integrator {
            be.reset_warm_start();
        }
        self.model = model;
        self.state = state;
        Ok(changes)
    }

    /// The scene's configuration (with `model.kind = "auto"`, `level` is the level chosen).
    #[must_use]
    pub fn config(&self) -> &SceneConfig {
        &self.config
    }

    /// With `model.kind = "auto"`: the per-level error estimates and the level chosen.
    #[must_use]
    pub fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }

    /// The grid.
    #[must_use]
    pub fn grid(&self) -> &BranchedGrid {
        &self.grid
    }

    /// The mechanical model.
    #[must_use]
    pub fn model(&self) -> &HexModel {
        &self.model
    }

    /// The current state.
    #[must_use]
    pub fn state(&self) -> &State {
        &self.state
    }

    /// The fixed nodes.
    #[must_use]
    pub fn fixed(&self) -> &FixedNodes {
        &self.fixed
    }
}
