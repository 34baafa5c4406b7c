//! The simulation loop of one scene, advanced one step per call: either the branched grid at the
//! configured level with the hexahedral model, force field and integrator, or (with
//! `model.kind = "tensor-mass"`) the tetrahedralised volume with paper 2's tensor-mass model and
//! its explicit integrator. Fixed regions and loads apply to either.

use crate::calibration::{Calibration, calibrate};
use crate::config::{
    IntegratorKind, ModelKind, SceneConfig, SceneError, TensorMassSpec, VolumeSpec,
};
use crate::regions::{
    empty_region_hold, fixed_at, fixed_nodes, missing_label_holds, patch_forces, patch_loads,
    spread_patches,
};
use incise_fem::forcefield::tet::element::Fibre;
use incise_fem::forcefield::tet::incompressible::Incompressibility;
use incise_fem::forcefield::tet::{Lame, TensorMassForceField, TetMaterial, TetModel};
use incise_fem::linsolve::cg::CgSettings;
use incise_fem::model::{Loads, State};
use incise_fem::ode::central_difference::CentralDifference;
use incise_fem::ode::{BackwardEuler, Rayleigh, explicit_step, stable_dt, static_solve_with};
use incise_fem::{Executor, FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::{
    BranchedGrid, EditError, GridChanges, GridEdit, LabelFilter, LabelVolume, MaterialTable,
};
use incise_math::Vec3;
use incise_mesh::{TetMesh, TetTopology};
use std::time::Instant;

/// Per-step counters (timings are measurements, not part of the deterministic state).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageCounters {
    /// Wall time of the whole step (ns).
    pub step_ns: u64,
    /// Implicit hexahedral scenes: the step's stages (ns): extracting the element rotations,
    /// forming the right-hand side and solving, updating the state. Zero for the other
    /// integrators.
    pub rotations_ns: u64,
    /// See `rotations_ns`.
    pub solve_ns: u64,
    /// See `rotations_ns`.
    pub update_ns: u64,
    /// Linear-solver iterations (CG) in the step.
    pub solver_iterations: usize,
    /// Final residual of the step's solve, relative to the larger of its right-hand side and
    /// `h‖f_ext‖` (see `incise_fem::linsolve::cg::solve_against`); a static step's, relative to the load.
    pub solver_residual: f64,
    /// Explicit hexahedral scenes: explicit steps taken for this frame; more than 1 once a cut
    /// has lowered the mesh's stable step below the scene's `dt`. Zero for other integrators.
    pub substeps: usize,
    /// Tensor-mass scenes: vertices using non-linear elasticity (all for SVK, none for linear,
    /// those past the threshold with adaptive non-linearity).
    pub nonlinear_vertices: usize,
}

/// What drives one step from outside the scene (a haptic tool's contact, a script, a test):
/// forces that act during this step only, on top of the scene's gravity and patch loads.
/// `StepInputs::default()` drives nothing.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepInputs {
    /// `(node, force)`: a force (N, grid frame) on a model node (a hexahedral node, or a
    /// tensor-mass vertex), in the model's node order as of this step (a cut renumbers them).
    /// Several forces on one node add up; a force on a fixed node is held by the fixture.
    pub node_forces: Vec<(usize, Vec3)>,
}

/// Inputs [`Simulation::step`] refused; the step was not taken and the state is unchanged.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum InputError {
    /// A force on a node the model does not have.
    #[error("node_forces[{entry}]: node {node} does not exist (the model has {nodes} nodes)")]
    NoSuchNode {
        /// Index into `node_forces`.
        entry: usize,
        /// The node named.
        node: usize,
        /// Nodes in the model.
        nodes: usize,
    },
    /// A force with a NaN or infinite component.
    #[error("node_forces[{entry}]: the force {force:?} N on node {node} is not finite")]
    NotFinite {
        /// Index into `node_forces`.
        entry: usize,
        /// The node named.
        node: usize,
        /// The force given.
        force: Vec3,
    },
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
    /// `stable_dt`: the mesh's explicit stability limit (s), re-estimated after every cut;
    /// `substeps`: explicit steps per frame, `⌈dt / stable_dt⌉` (1 until a cut lowers the limit
    /// below the scene's `dt`: cut cells hold less mass, and their corners can vibrate faster).
    Explicit {
        dt: f64,
        alpha: f64,
        stable_dt: f64,
        substeps: usize,
    },
    /// `cholesky`: each Newton step's CG preconditioned by a factorisation of the stiffness
    /// (`integrator.solver = "cholesky"` or `"cholesky-cg"`), else block-Jacobi.
    Static {
        tolerance: f64,
        cholesky: bool,
    },
}

/// The hexahedral mechanics of a scene.
struct HexBody {
    grid: BranchedGrid,
    model: HexModel,
    force_field: HexForceField,
    loads: Loads,
    integrator: Integrator,
}

/// The tensor-mass mechanics of a scene (`model.kind = "tensor-mass"`).
pub struct TetBody {
    /// The tetrahedralised volume (6 tetrahedra per grid cell).
    pub mesh: TetMesh,
    /// Rest data per tetrahedron.
    pub model: TetModel,
    /// Live tetrahedra and the boundary.
    pub topology: TetTopology,
    /// The stiffness tensors.
    pub force_field: TensorMassForceField,
    /// The incompressibility penalty, when configured.
    pub penalty: Option<Incompressibility>,
    /// The largest stable explicit step of the mesh and material (s); with the explicit
    /// integrator the scene's dt is at most this.
    pub stable_dt: f64,
    /// Grid cell (at the scene's level) of each group of 6 tetrahedra.
    cells: Vec<[usize; 3]>,
    /// Voxels per axis of the (filtered, strided) volume.
    voxel_dims: [usize; 3],
    /// Gravity on the lumped masses plus the patch loads, as per-vertex forces.
    loads: Loads,
    integrator: TetIntegrator,
}

/// How a tensor-mass scene steps.
enum TetIntegrator {
    /// Paper 2's central differences.
    Explicit(CentralDifference),
    /// Linearised backward Euler through the same force-field interface as the hexahedra.
    Implicit(Box<BackwardEuler>),
}

enum Body {
    Hex(Box<HexBody>),
    Tet(Box<TetBody>),
}

/// A running scene.
pub struct Simulation {
    config: SceneConfig,
    calibration: Option<Calibration>,
    body: Body,
    fixed: FixedNodes,
    state: State,
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

impl Simulation {
    /// Builds the scene on `volume` (from [`SceneConfig::procedural_volume`] or a file). Only what
    /// the scene uses is built: the grid at its level, the model, the chosen integrator. It runs
    /// on an executor of its own with the default settings, which the environment variables
    /// `INCISE_THREADS` and `INCISE_LINGER_US` may override ([`Executor::configured`]).
    pub fn new(config: &SceneConfig, volume: &LabelVolume, file: &str) -> Result<Self, SceneError> {
        Self::with_executor(config, volume, file, &Executor::configured(None, None))
    }

    /// [`Self::new`] on the given executor: every element loop and solve of this simulation runs
    /// on its threads, and nothing else is shared with another simulation unless it is given a
    /// clone of the same executor.
    pub fn with_executor(
        config: &SceneConfig,
        volume: &LabelVolume,
        file: &str,
        exec: &Executor,
    ) -> Result<Self, SceneError> {
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
        // A config built in code skips the file's checks of what the mechanics ignores.
        if config.integrator == IntegratorKind::Explicit && config.rayleigh_beta != 0.0 {
            return Err(build(format!(
                "integrator.rayleigh_beta = {} does not apply to the explicit integrator (only rayleigh_alpha does)",
                config.rayleigh_beta
            )));
        }
        if let Some(m) = config
            .materials
            .iter()
            .find(|m| m.material.rayleigh_mass != 0.0 || m.material.rayleigh_stiffness != 0.0)
        {
            return Err(build(format!(
                "label {}: per-material damping is not supported; set integrator.rayleigh_alpha and rayleigh_beta",
                m.label
            )));
        }
        let mut table = MaterialTable::new();
        for m in &config.materials {
            table.insert(m.label, m.material);
        }
        let mut config = config.clone();
        let calibration = match config.auto_level {
            Some(auto) => {
                let c = calibrate(&config, &volume, &table, auto, exec)
                    .map_err(|e| build(format!("model.kind = \"auto\": {e}")))?;
                config.level = c.chosen;
                Some(c)
            }
            None => None,
        };
        let config = &config;
        if let (ModelKind::TensorMass, Some(spec)) = (config.model, config.tensor_mass) {
            let (body, fixed) =
                tet_body(config, &spec, &volume, &table, exec.clone()).map_err(build)?;
            let state =
                State { x: body.model.rest.clone(), v: vec![[0.0; 3]; body.model.vertex_count()] };
            return Ok(Self {
                config: config.clone(),
                calibration,
                body: Body::Tet(Box::new(body)),
                fixed,
                state,
                index: 0,
            });
        }
        let grid =
            BranchedGrid::build(&volume, &table, config.level).map_err(|e| build(e.to_string()))?;
        let model = HexModel::from_grid(&grid);
        let formulation = match config.model {
            ModelKind::Linear => Formulation::Linear,
            ModelKind::Corotational | ModelKind::TensorMass => Formulation::Corotational,
        };
        let force_field = HexForceField::new(&model, formulation).with_executor(exec.clone());
        if let Some(message) = missing_label_holds(config, |l| grid.fine_labels().contains(&l))
            .or_else(|| empty_region_hold(config, &model.rest, grid.element_size()))
        {
            return Err(build(message));
        }
        let fixed = fixed_nodes(config, &grid, &model);
        let loads = patch_loads(config, &model).map_err(build)?;
        let damping = Rayleigh { alpha: config.rayleigh_alpha, beta: config.rayleigh_beta };
        let integrator = match config.integrator {
            IntegratorKind::ImplicitEuler => {
                let mut be = BackwardEuler::with_solver(
                    config.dt,
                    damping,
                    CgSettings {
                        tolerance: config.cg_tolerance,
                        max_iterations: 10 * model.dof_count().max(100),
                    },
                    config.solver,
                );
                be.mass = config.mass;
                Integrator::Implicit(Box::new(be))
            }
            IntegratorKind::Explicit => {
                let limit = stable_dt(&model, &force_field, &fixed);
                if config.dt > limit {
                    return Err(build(format!(
                        "integrator.dt = {} s is above the explicit stability limit {limit:.3e} s of this mesh; use a smaller dt or the implicit integrator",
                        config.dt
                    )));
                }
                Integrator::Explicit {
                    dt: config.dt,
                    alpha: config.rayleigh_alpha,
                    stable_dt: limit,
                    substeps: 1,
                }
            }
            IntegratorKind::Static => Integrator::Static {
                tolerance: config.cg_tolerance,
                cholesky: config.solver != incise_fem::ode::LinearSolver::JacobiCg,
            },
        };
        let state = State::at_rest(&model);
        Ok(Self {
            config: config.clone(),
            calibration,
            body: Body::Hex(Box::new(HexBody { grid, model, force_field, loads, integrator })),
            fixed,
            state,
            index: 0,
        })
    }

    /// Advances one step, driven by `inputs`; refuses them (and takes no step) if a force is
    /// not finite or names a node the model does not have.
    pub fn step(&mut self, inputs: &StepInputs) -> Result<Frame, InputError> {
        let start = Instant::now();
        let nodes = self.state.x.len();
        for (entry, &(node, force)) in inputs.node_forces.iter().enumerate() {
            if node >= nodes {
                return Err(InputError::NoSuchNode { entry, node, nodes });
            }
            if !force.iter().all(|c| c.is_finite()) {
                return Err(InputError::NotFinite { entry, node, force });
            }
        }
        // The scene's own nodal loads plus this step's forces (none: the scene's, not copied).
        let with_inputs = |scene: &[Vec3]| -> Option<Vec<Vec3>> {
            if inputs.node_forces.is_empty() {
                return None;
            }
            let mut f = if scene.is_empty() { vec![[0.0; 3]; nodes] } else { scene.to_vec() };
            for &(node, force) in &inputs.node_forces {
                for k in 0..3 {
                    f[node][k] += force[k];
                }
            }
            Some(f)
        };
        let mut counters = StageCounters::default();
        let hex = match &mut self.body {
            Body::Hex(hex) => hex,
            Body::Tet(tet) => {
                let TetBody { model, topology, force_field, penalty, loads, integrator, .. } =
                    &mut **tet;
                let external = with_inputs(&loads.nodal);
                match integrator {
                    TetIntegrator::Explicit(cd) => {
                        if force_field.elasticity()
                            == incise_fem::forcefield::tet::Elasticity::StVenantKirchhoff
                        {
                            force_field.update_adaptive(model, topology, &self.state.x);
                        }
                        cd.step(
                            model,
                            topology,
                            force_field,
                            penalty.as_ref(),
                            &self.fixed,
                            external.as_deref().unwrap_or(&loads.nodal),
                            &mut self.state.x,
                        );
                        self.state.v = cd.velocities(&self.state.x);
                    }
                    TetIntegrator::Implicit(be) => {
                        let driven = external.map(|nodal| Loads { gravity: [0.0; 3], nodal });
                        let mut elastic = force_field.bind(model, topology, penalty.as_ref());
                        let r = be.step_fields(
                            model,
                            &mut [&mut elastic],
                            &self.fixed,
                            driven.as_ref().unwrap_or(loads),
                            &mut self.state,
                        );
                        counters.solver_iterations = r.iterations;
                        counters.solver_residual = r.relative_residual;
                    }
                }
                counters.nonlinear_vertices = force_field.nonlinear_count();
                return Ok(self.finish(start, counters));
            }
        };
        let driven =
            with_inputs(&hex.loads.nodal).map(|nodal| Loads { gravity: hex.loads.gravity, nodal });
        let loads = driven.as_ref().unwrap_or(&hex.loads);
        match &mut hex.integrator {
            Integrator::Implicit(be) => {
                let r =
                    be.step(&hex.model, &mut hex.force_field, &self.fixed, loads, &mut self.state);
                counters.solver_iterations = r.iterations;
                counters.solver_residual = r.relative_residual;
                let t = be.stage_times;
                (counters.rotations_ns, counters.solve_ns, counters.update_ns) =
                    (t.rotations_ns, t.solve_ns, t.update_ns);
            }
            Integrator::Explicit { dt, alpha, substeps, .. } => {
                for _ in 0..*substeps {
                    explicit_step(
                        &hex.model,
                        &mut hex.force_field,
                        &self.fixed,
                        loads,
                        *alpha,
                        *dt / *substeps as f64,
                        &mut self.state,
                    );
                }
                counters.substeps = *substeps;
            }
            Integrator::Static { tolerance, cholesky } => {
                let r = static_solve_with(
                    &hex.model,
                    &mut hex.force_field,
                    &self.fixed,
                    loads,
                    &mut self.state.x,
                    *tolerance,
                    50,
                    *cholesky,
                );
                counters.solver_iterations = r.cg_iterations;
                counters.solver_residual = r.relative_residual;
            }
        }
        Ok(self.finish(start, counters))
    }

    fn finish(&mut self, start: Instant, mut counters: StageCounters) -> Frame {
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
    /// Surviving and split-off elements keep their rotation; elements the edit did not touch keep
    /// their matrices ([`HexModel::updated`]); the implicit solver's warm start follows the nodes.
    /// Fixed regions and patch loads are re-applied to the new nodes.
    ///
    /// In a tensor-mass scene there is no grid: the tetrahedra of every cell holding a removed
    /// voxel are removed (their stiffness subtracted, paper 2 §3.2), severed links are not
    /// supported there, and the change list returned is empty (see [`Simulation::tet`]).
    pub fn cut(&mut self, edit: &GridEdit) -> Result<GridChanges, EditError> {
        let hex = match &mut self.body {
            Body::Hex(hex) => hex,
            Body::Tet(tet) => {
                remove_voxel_cells(tet, &self.config, edit)?;
                return Ok(GridChanges::default());
            }
        };
        let changes = hex.grid.apply(edit)?;
        if changes == GridChanges::default() {
            return Ok(changes);
        }
        let model = hex.model.updated(&hex.grid, &changes);
        let old = &hex.model;
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
        let mut old_of_new: Vec<Option<usize>> = vec![None; n];
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
                old_of_new[i] = Some(j as usize);
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
        hex.force_field = hex.force_field.remapped(old, &model, |g| origin_of.get(&g).copied());
        self.fixed = fixed_nodes(&self.config, &hex.grid, &model);
        for (i, s) in state.v.iter_mut().enumerate() {
            if self.fixed.is_fixed(i) {
                *s = [0.0; 3];
            }
        }
        // A patch that lost all its nodes simply stops pulling; the others keep pulling.
        let (nodal, _) = spread_patches(&self.config, &model.rest);
        hex.loads = Loads { gravity: self.config.gravity, nodal };
        match &mut hex.integrator {
            Integrator::Implicit(be) => be.remap_warm_start(&old_of_new),
            // Cut cells hold less mass and the cut mesh's limit may fall below dt: rather than
            // blow up (or refuse the cut), each frame then takes as many smaller steps as it
            // needs. The estimate is a power iteration, paid once per cut; the explicit
            // integrator is for comparisons and CFL studies, interactive cutting runs implicit.
            Integrator::Explicit { dt, stable_dt: limit, substeps, .. } => {
                *limit = stable_dt(&model, &hex.force_field, &self.fixed);
                *substeps = (*dt / *limit).ceil().max(1.0) as usize;
            }
            Integrator::Static { .. } => {}
        }
        hex.model = model;
        self.state = state;
        Ok(changes)
    }

    /// The scene's configuration (with `model.kind = "auto"`, `level` is the level chosen).
    #[must_use]
    pub fn config(&self) -> &SceneConfig {
        &self.config
    }

    /// With an explicit integrator: the mesh's stable step (s), estimated from the rest
    /// stiffness (after a cut, of the cut mesh). A frame takes `⌈dt / limit⌉` explicit steps
    /// (`StageCounters::substeps`). `None` for the implicit and static integrators.
    #[must_use]
    pub fn explicit_stable_dt(&self) -> Option<f64> {
        match &self.body {
            Body::Hex(hex) => match &hex.integrator {
                Integrator::Explicit { stable_dt: limit, .. } => Some(*limit),
                _ => None,
            },
            Body::Tet(tet) => match tet.integrator {
                TetIntegrator::Explicit(_) => Some(tet.stable_dt),
                TetIntegrator::Implicit(_) => None,
            },
        }
    }

    /// With `model.kind = "auto"`: the per-level error estimates and the level chosen.
    #[must_use]
    pub fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }

    /// The grid (`None` in a tensor-mass scene).
    #[must_use]
    pub fn grid(&self) -> Option<&BranchedGrid> {
        match &self.body {
            Body::Hex(hex) => Some(&hex.grid),
            Body::Tet(_) => None,
        }
    }

    /// The hexahedral model (`None` in a tensor-mass scene).
    #[must_use]
    pub fn model(&self) -> Option<&HexModel> {
        match &self.body {
            Body::Hex(hex) => Some(&hex.model),
            Body::Tet(_) => None,
        }
    }

    /// The hexahedral model's loads: gravity and the patch loads spread over its nodes (`None`
    /// in a tensor-mass scene).
    #[must_use]
    pub fn loads(&self) -> Option<&Loads> {
        match &self.body {
            Body::Hex(hex) => Some(&hex.loads),
            Body::Tet(_) => None,
        }
    }

    /// The tensor-mass mechanics (`None` in a hexahedral scene).
    #[must_use]
    pub fn tet(&self) -> Option<&TetBody> {
        match &self.body {
            Body::Tet(tet) => Some(tet),
            Body::Hex(_) => None,
        }
    }

    /// The current state (node or vertex positions and velocities).
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

/// Builds the tensor-mass mechanics of a scene and its fixed vertices.
fn tet_body(
    config: &SceneConfig,
    spec: &TensorMassSpec,
    volume: &LabelVolume,
    table: &MaterialTable,
    exec: Executor,
) -> Result<(TetBody, FixedNodes), String> {
    let (mesh, cells) = incise_mesh::generate::from_volume_with_cells(volume, config.level)
        .map_err(|e| format!("tetrahedralising the volume at level {}: {e}", config.level))?;
    let material = |region: u32| -> TetMaterial {
        let m = u16::try_from(region)
            .ok()
            .and_then(|l| table.get(l).copied())
            .unwrap_or_else(incise_grid::Material::liver);
        let lame = Lame::from_young_poisson(m.youngs_modulus, m.poisson_ratio);
        TetMaterial {
            lame,
            density: m.density,
            fibre: spec.fibre.map(|(direction, ratio)| Fibre {
                direction,
                lame_along: Lame { lambda: ratio * lame.lambda, mu: ratio * lame.mu },
            }),
        }
    };
    let model = TetModel::new(&mesh, material);
    let topology = TetTopology::new(&mesh);
    let mut force_field =
        TensorMassForceField::new(&model, &topology, spec.elasticity).with_executor(exec);
    if let Some(threshold) = spec.adaptive_threshold {
        force_field.enable_adaptive(&model, threshold, 0.2);
    }
    let step = f64::from(1u32 << config.level);
    let size: Vec3 = std::array::from_fn(|a| step * volume.spacing()[a]);
    if let Some(message) = missing_label_holds(config, |l| volume.labels().contains(&l))
        .or_else(|| empty_region_hold(config, &model.rest, size))
    {
        return Err(message);
    }
    // A cell's tetrahedra are held when the cell holds a voxel with the label.
    let fixed = fixed_at(config, &model.rest, size, |label| {
        let step = 1usize << config.level;
        let dims = volume.dims();
        let labels = volume.labels();
        let holds = |c: &[usize; 3]| {
            (c[2] * step..((c[2] + 1) * step).min(dims[2])).any(|z| {
                (c[1] * step..((c[1] + 1) * step).min(dims[1])).any(|y| {
                    (c[0] * step..((c[0] + 1) * step).min(dims[0]))
                        .any(|x| labels[x + dims[0] * (y + dims[1] * z)] == label)
                })
            })
        };
        cells
            .iter()
            .enumerate()
            .filter(|(_, c)| holds(c))
            .flat_map(|(g, _)| (6 * g..6 * g + 6).flat_map(|t| mesh.tets()[t]))
            .map(|v| v as usize)
            .collect()
    });
    let mut external = patch_forces(config, &model.rest)?;
    for (f, m) in external.iter_mut().zip(&model.lumped_mass) {
        for a in 0..3 {
            f[a] += m * config.gravity[a];
        }
    }
    let stable_dt = incise_fem::ode::central_difference::stable_dt(&model, &force_field, &fixed);
    let integrator = match config.integrator {
        IntegratorKind::ImplicitEuler => TetIntegrator::Implicit(Box::new(BackwardEuler::new(
            config.dt,
            Rayleigh { alpha: config.rayleigh_alpha, beta: config.rayleigh_beta },
            CgSettings {
                tolerance: config.cg_tolerance,
                max_iterations: 10 * (3 * model.vertex_count()).max(100),
            },
        ))),
        IntegratorKind::Explicit | IntegratorKind::Static => TetIntegrator::Explicit(
            CentralDifference::new(
                &model,
                &force_field,
                &fixed,
                &model.rest,
                config.dt,
                config.rayleigh_alpha,
            )
            .map_err(|e| format!("integrator.dt: {e}"))?,
        ),
    };
    Ok((
        TetBody {
            mesh,
            model,
            topology,
            penalty: spec.incompressibility.map(|kappa| Incompressibility { kappa }),
            force_field,
            stable_dt,
            cells,
            voxel_dims: volume.dims(),
            loads: Loads { gravity: [0.0; 3], nodal: external },
            integrator,
        },
        fixed,
    ))
}

/// Removes the tetrahedra of every cell holding one of `edit`'s removed voxels.
fn remove_voxel_cells(
    tet: &mut TetBody,
    config: &SceneConfig,
    edit: &GridEdit,
) -> Result<(), EditError> {
    let dims = tet.voxel_dims;
    let count = dims.iter().product::<usize>();
    let step = 1usize << config.level;
    let mut doomed: Vec<[usize; 3]> = Vec::with_capacity(edit.remove_voxels.len());
    for &v in &edit.remove_voxels {
        if v as usize >= count {
            return Err(EditError::VoxelOutOfRange { voxel: v, count });
        }
        let v = v as usize;
        let p = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
        doomed.push(std::array::from_fn(|a| p[a] / step));
    }
    doomed.sort_unstable();
    doomed.dedup();
    for k in 0..tet.cells.len() {
        if doomed.binary_search(&tet.cells[k]).is_ok() {
            for t in 6 * k..6 * k + 6 {
                tet.force_field.remove_tet(&tet.model, &mut tet.topology, t);
            }
        }
    }
    Ok(())
}
