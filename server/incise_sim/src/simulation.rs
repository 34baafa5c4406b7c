//! The simulation loop of one scene, advanced one step per call: either the branched grid at the
//! configured level with the hexahedral model, force field and integrator, or (with
//! `model.kind = "tensor-mass"`) the tetrahedralised volume or a mesh read from a file with paper
//! 2's tensor-mass model and its integrator. Fixed regions and loads apply to either.

use crate::calibration::{Calibration, calibrate};
use crate::config::{
    DEFAULT_CG_TOLERANCE, ElementKind, HexSpec, Integrator, LengthUnit, Level, Model, SceneConfig,
    SceneError, StaticSolver, TensorMassSpec, TetIntegrator, TetSource, ToolContact,
    VolumeContactSpec, VolumeSpec,
};
use crate::regions::{
    empty_region_hold, fixed_at, fixed_nodes, missing_label_holds, patch_forces, patch_loads,
    spread_patches,
};
use incise_fem::forcefield::ForceField;
use incise_fem::forcefield::tet::element::Fibre;
use incise_fem::forcefield::tet::incompressible::Incompressibility;
use incise_fem::forcefield::tet::{Lame, TensorMassForceField, TetMaterial, TetModel};
use incise_fem::linsolve::cg::CgSettings;
use incise_fem::model::{Loads, State};
use incise_fem::ode::central_difference::CentralDifference;
use incise_fem::ode::{BackwardEuler, explicit_step_fields, stable_dt, static_solve_with};
use incise_fem::{Executor, FixedNodes, HexForceField, HexModel};
use incise_grid::{BranchedGrid, EditError, GridChanges, GridEdit, LabelVolume, MaterialTable};
use incise_math::Vec3;
use incise_mesh::{TetMesh, TetTopology};
use std::time::Instant;

mod keyframe;
mod surgery;

pub use keyframe::{KEYFRAME_INTERVAL_S, Keyframe, KeyframeError, ToolState};

use surgery::Surgery;
pub use surgery::{CutEvent, OrganSurface, SurfaceGeometry, SurgicalFrame, ToolFrame, ToolInput};

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
    /// Wall time (ns) of the integrator's step, whatever the integrator: what the frame
    /// benchmark reports as the solve.
    pub mechanics_ns: u64,
    /// Scenes with tools, the frame's stages (ns): finding the contacts and grasps.
    pub contact_ns: u64,
    /// Finding what the tools cut.
    pub cut_ns: u64,
    /// Updating the grid, the model and the solver state for a cut (or removing tetrahedra).
    pub grid_ns: u64,
    /// Deforming the surface (its vertices' positions and velocities from the nodes').
    pub surface_ns: u64,
    /// Re-meshing and re-embedding the surface after a cut (or refreshing a tetrahedral
    /// boundary).
    pub remesh_ns: u64,
    /// Springs the tools put on the surface (contact and grasp).
    pub contact_points: usize,
    /// Voxels a cut removed this step.
    pub voxels_removed: usize,
    /// Links a cut severed this step.
    pub links_severed: usize,
    /// Tetrahedra a cut removed this step.
    pub tets_removed: usize,
    /// Scenes with `[volume_contact]`: finding the overlaps (layered depth images) and making
    /// their penalty (ns).
    pub volume_contact_ns: u64,
    /// Connected overlaps pushed apart this step.
    pub overlap_regions: usize,
    /// Their total volume at the step's start (m³).
    pub overlap_volume: f64,
    /// With [`Simulation::check_gpu`] on a scene whose volume contact runs on a GPU: the
    /// largest difference between a device pass's overlap volume and the same pass on the CPU,
    /// relative to the larger (0 otherwise).
    pub gpu_cpu_volume_diff: f64,
    /// With [`Simulation::check_gpu`] on a scene whose volume contact runs on a GPU: voxels
    /// near a cutting shape that the device and the CPU disagree on (held or not) this step.
    pub gpu_cpu_cut_mismatches: usize,
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
    /// Poses for the scene's tools this step (a tool given none keeps its scripted or last
    /// pose). A pose is checked when it is built ([`incise_tool::ToolPose::new`]: finite, unit
    /// quaternion); a tool index the scene lacks, a pose that is not finite (one built unchecked,
    /// by `Pose::at` or `Pose::moved`, from a NaN or infinite number), or a gripper angle that is
    /// not finite and ≥ 0, is refused here.
    pub tools: Vec<ToolInput>,
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
    /// A pose for a tool the scene does not have.
    #[error("tools[{entry}]: tool {tool} does not exist (the scene has {tools} tools)")]
    NoSuchTool {
        /// Index into `tools`.
        entry: usize,
        /// The tool named.
        tool: usize,
        /// Tools in the scene.
        tools: usize,
    },
    /// A cut the tools made was refused by the grid (an internal error: the tools only name
    /// voxels and links the grid has).
    #[error("the tools' cut: {0}")]
    Cut(#[from] CutError),
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
    /// The tools' part: their forces and linearisations, the cuts, the surface's changes.
    pub surgical: SurgicalFrame,
}

/// What a scene is built on: a label volume as read (the scene's label filter and stride are
/// applied when it is built) or a tetrahedral mesh as read (in the unit of `volume.unit`).
#[derive(Clone, Copy, Debug)]
pub enum Geometry<'a> {
    /// For a hexahedral scene, or a tensor-mass scene generated from a volume.
    Volume(&'a LabelVolume),
    /// For a tensor-mass scene read from a mesh file (`volume.mesh`).
    Mesh(&'a TetMesh),
}

impl<'a> From<&'a LabelVolume> for Geometry<'a> {
    fn from(volume: &'a LabelVolume) -> Self {
        Self::Volume(volume)
    }
}

impl<'a> From<&'a TetMesh> for Geometry<'a> {
    fn from(mesh: &'a TetMesh) -> Self {
        Self::Mesh(mesh)
    }
}

/// A cut [`Simulation::cut`] or [`Simulation::remove_tets`] refused; nothing was removed.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum CutError {
    /// The edit names a voxel or link the volume does not have.
    #[error(transparent)]
    Edit(#[from] EditError),
    /// Voxels were named in a scene whose tetrahedra were read from a mesh file.
    #[error(
        "the scene's tetrahedra were read from a mesh file and are no voxels' cells; remove them by index (`Simulation::remove_tets`)"
    )]
    NoVoxels,
    /// Tetrahedra were named in a hexahedral scene.
    #[error(
        "the scene is hexahedral: it has no tetrahedra to remove; cut its grid (`Simulation::cut`)"
    )]
    NotTetrahedra,
    /// A tetrahedron the mesh does not have.
    #[error("tetrahedron {tet} does not exist (the mesh has {count})")]
    NoSuchTet {
        /// The index given.
        tet: usize,
        /// Tetrahedra in the mesh (live or removed).
        count: usize,
    },
}

enum HexStepper {
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
    stepper: HexStepper,
}

/// The tensor-mass mechanics of a scene (`model.kind = "tensor-mass"`).
pub struct TetBody {
    /// The tetrahedra: 6 per grid cell of the volume, or as read from the mesh file (in metres).
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
    /// The volume's cells the tetrahedra were generated from (`None` for a mesh file).
    cells: Option<VoxelCells>,
    /// Gravity on the lumped masses plus the patch loads, as per-vertex forces.
    loads: Loads,
    stepper: TetStepper,
}

/// The cells of a generated mesh: how a cut by voxels finds its tetrahedra.
struct VoxelCells {
    /// Grid cell (at `level`) of each group of 6 tetrahedra.
    cells: Vec<[usize; 3]>,
    /// The grid level of the cells.
    level: u32,
    /// The volume (filtered, strided) they were generated from.
    volume: LabelVolume,
}

/// How a tensor-mass scene steps.
enum TetStepper {
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
    /// The tools and the surface they act on (scenes with `[[tools]]`).
    surgery: Option<Box<Surgery>>,
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

impl Simulation {
    /// Builds the scene on its geometry as read: the label volume (from
    /// [`SceneConfig::procedural_volume`] or a file, before the scene's label filter and stride)
    /// or the tetrahedral mesh of `volume.mesh` (in the file's unit). Only what the scene uses is
    /// built: the grid at its level or the tetrahedra, the model, the chosen integrator. It runs
    /// on an executor of its own with the scene's `[exec]` settings ([`Executor::configured`]).
    pub fn new<'a>(
        config: &SceneConfig,
        geometry: impl Into<Geometry<'a>>,
        file: &str,
    ) -> Result<Self, SceneError> {
        Self::with_executor(config, geometry, file, &config.exec.executor())
    }

    /// [`Self::new`] on the given executor (the scene's `[exec]` keys are then not used): every
    /// element loop and solve of this simulation runs on its threads, and nothing else is shared
    /// with another simulation unless it is given a clone of the same executor.
    pub fn with_executor<'a>(
        config: &SceneConfig,
        geometry: impl Into<Geometry<'a>>,
        file: &str,
        exec: &Executor,
    ) -> Result<Self, SceneError> {
        let build = |message: String| SceneError::Build { file: file.to_owned(), message };
        let geometry = geometry.into();
        let mut table = MaterialTable::new();
        for m in &config.materials {
            table.insert(m.label, m.material());
        }
        let mut config = config.clone();
        let mut calibration = None;
        let (body, fixed) = match (&config.model, geometry) {
            (Model::Hexahedra(hex), Geometry::Volume(raw)) => {
                let volume = prepared(&hex.volume, raw).map_err(build)?;
                let (level, element) = match hex.level {
                    Level::Fixed(level) => (level, hex.element),
                    Level::Auto(auto) => {
                        // The calibration reads only the scene's holds and loads.
                        let c = calibrate(&config, &volume, &table, auto, hex.element, exec)
                            .map_err(|e| build(format!("model.kind = \"auto\": {e}")))?;
                        let chosen = (c.chosen, c.chosen_element);
                        calibration = Some(c);
                        chosen
                    }
                };
                let (body, fixed) =
                    hex_body(&config, hex, (level, element), &volume, &table, exec.clone())
                        .map_err(build)?;
                (Body::Hex(Box::new(body)), fixed)
            }
            (Model::TensorMass(spec), geometry) => {
                let (mesh, cells) = match (&spec.source, geometry) {
                    (TetSource::Volume { volume, level }, Geometry::Volume(raw)) => {
                        let volume = prepared(volume, raw).map_err(build)?;
                        let (mesh, cells) =
                            incise_mesh::generate::from_volume_with_cells(&volume, *level)
                                .map_err(|e| {
                                    build(format!(
                                        "tetrahedralising the volume at level {level}: {e}"
                                    ))
                                })?;
                        (mesh, Some(VoxelCells { cells, level: *level, volume }))
                    }
                    (TetSource::Mesh(spec), Geometry::Mesh(mesh)) => {
                        (in_metres(mesh, spec.unit).map_err(build)?, None)
                    }
                    (TetSource::Volume { .. }, Geometry::Mesh(_)) => {
                        return Err(build(
                            "the scene generates its tetrahedra from a label volume, and was given a mesh".into(),
                        ));
                    }
                    (TetSource::Mesh(m), Geometry::Volume(_)) => {
                        return Err(build(format!(
                            "the scene reads its tetrahedra from the mesh file {}, and was given a label volume",
                            m.path
                        )));
                    }
                };
                let (body, fixed) =
                    tet_body(&config, spec, mesh, cells, &table, exec.clone()).map_err(build)?;
                (Body::Tet(Box::new(body)), fixed)
            }
            (Model::Hexahedra(_), Geometry::Mesh(_)) => {
                return Err(build(
                    "hexahedra are built on a label volume, and the scene was given a mesh".into(),
                ));
            }
        };
        // The configuration a simulation reports is the one it runs: at the level chosen.
        if let (Some(c), Model::Hexahedra(hex)) = (&calibration, &mut config.model) {
            hex.level = Level::Fixed(c.chosen);
            hex.element = c.chosen_element;
        }
        let state = match &body {
            Body::Hex(hex) => State::at_rest(&hex.model),
            Body::Tet(tet) => {
                State { x: tet.model.rest.clone(), v: vec![[0.0; 3]; tet.model.vertex_count()] }
            }
        };
        let surgery = if config.tools.is_empty() && config.volume_contact.is_none() {
            None
        } else {
            let surface = match &body {
                Body::Hex(hex) => {
                    if matches!(hex.stepper, HexStepper::Static { .. }) {
                        return Err(build(
                            "[[tools]]: a static scene has no time for a tool to move in; use \
                             integrator.kind = \"implicit-euler\" or \"explicit\""
                                .into(),
                        ));
                    }
                    OrganSurface::voxels(
                        &hex.grid,
                        &hex.model,
                        &surgery::surface_options(&config, &hex.grid),
                        config.surface.smoothing,
                    )
                }
                Body::Tet(tet) => OrganSurface::tetrahedra(&tet.topology),
            };
            // A tool that pushes by volume needs the contact even where the tissues do not.
            let tool_meshes = config.tools.iter().any(|t| t.contact == ToolContact::Volume);
            let spec = config.volume_contact.clone().or_else(|| {
                tool_meshes.then(|| VolumeContactSpec {
                    pressure: VolumeContactSpec::DEFAULT_PRESSURE,
                    resolution: VolumeContactSpec::DEFAULT_RESOLUTION,
                    pairs: Vec::new(),
                    self_contact: false,
                })
            });
            let volume = match &spec {
                Some(spec) => Some(volume_contact(spec, &body, &surface).map_err(build)?),
                None => None,
            };
            let defaults = tool_defaults(&config, &body);
            let mut surgery = Surgery::new(&config.tools, surface, &defaults).map_err(build)?;
            if let Some(volume) = volume {
                surgery.set_volume_contact(volume);
            }
            Some(Box::new(surgery))
        };
        let mut sim = Self { config, calibration, body, fixed, state, index: 0, surgery };
        sim.separate_tissues().map_err(build)?;
        Ok(sim)
    }

    /// The GPU volume contact runs on (its adapter's name), if it runs on one.
    #[must_use]
    pub fn gpu(&self) -> Option<String> {
        self.surgery.as_ref()?.volume_contact()?.device_name()
    }

    /// Runs volume contact's per-frame passes (the surface's deformation, the layered depth
    /// images) on `device` from the next step on: what a scene's `gpu` key asks for, which the
    /// crates that build scenes for users act on (`incise_scene::attach_gpu`), so that this crate
    /// stays free of any GPU library. Returns false, and drops the device, in a scene without
    /// volume contact.
    pub fn set_contact_device(
        &mut self,
        device: Box<dyn incise_tool::volume_contact::ContactDevice>,
    ) -> bool {
        match self.surgery.as_mut().and_then(|s| s.volume_contact_mut()) {
            Some(v) => {
                v.set_device(device);
                true
            }
            None => false,
        }
    }

    /// Runs each of volume contact's GPU passes on the CPU too, and reports the largest
    /// difference in [`StageCounters::gpu_cpu_volume_diff`], and the cut search's voxels the
    /// two disagree on in [`StageCounters::gpu_cpu_cut_mismatches`] (a benchmark's check; it
    /// costs the CPU pass).
    pub fn check_gpu(&mut self, check: bool) {
        if let Some(v) = self.surgery.as_mut().and_then(|s| s.volume_contact_mut()) {
            v.set_check(check);
        }
    }

    /// Severs the links between the voxels of the tissues `[volume_contact] pairs` names, so
    /// that each is a body of its own (the branched grid duplicates the cells they share).
    fn separate_tissues(&mut self) -> Result<(), String> {
        let Some(spec) = &self.config.volume_contact else { return Ok(()) };
        let Some(grid) = self.grid() else { return Ok(()) };
        if spec.pairs.is_empty() {
            return Ok(());
        }
        let labels: Vec<u16> = grid.materials().map(|(label, _)| label).collect();
        let fine = grid.fine();
        let d = fine.dims().map(|n| n as usize);
        let label = |v: usize| fine.material(v as u32).map(|m| labels[usize::from(m)]);
        let paired = |a: u16, b: u16| spec.pairs.contains(&[a.min(b), a.max(b)]);
        let mut links = Vec::new();
        for v in 0..d[0] * d[1] * d[2] {
            let Some(a) = label(v) else { continue };
            let at = [v % d[0], v / d[0] % d[1], v / (d[0] * d[1])];
            for (axis, step) in [1, d[0], d[0] * d[1]].into_iter().enumerate() {
                if at[axis] + 1 < d[axis]
                    && let Some(b) = label(v + step)
                    && paired(a, b)
                {
                    links.push((v as u32, (v + step) as u32));
                }
            }
        }
        if links.is_empty() {
            return Ok(());
        }
        self.cut(&GridEdit { remove_voxels: Vec::new(), sever_links: links })
            .map_err(|e| format!("separating the tissues of volume_contact.pairs: {e}"))?;
        if let Some(volume) = self.surgery.as_mut().and_then(|s| s.volume_contact_mut()) {
            volume.forget_cuts();
        }
        Ok(())
    }

    /// Advances one step, driven by `inputs`; refuses them (and takes no step) if a force is
    /// not finite or names a node the model does not have, or a tool input names a tool the
    /// scene does not have or has a bad gripper angle.
    ///
    /// With tools posed, the step is the surgical frame: contact, grasping and cutting (the
    /// grid, model, solver state and surface updated locally), then the mechanics with the
    /// tools' springs beside the tissue, then each tool's force and linearisation
    /// ([`Frame::surgical`]).
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
        self.check_tools(inputs)?;
        let mut counters = StageCounters::default();
        let mut surgical = SurgicalFrame::default();
        let mut springs = self.prepare_tools(inputs, &mut counters, &mut surgical)?;
        let mut volume = self.prepare_volume_contact(&mut counters);
        let mut extra: Vec<&mut dyn ForceField> = Vec::new();
        if let Some(s) = springs.as_mut() {
            extra.push(&mut s.field);
        }
        if let Some(v) = volume.as_mut() {
            extra.push(v);
        }
        let t = Instant::now();
        self.advance(inputs, extra, &mut counters);
        counters.mechanics_ns = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
        if let Some(springs) = &springs {
            self.finish_tools(springs, &mut surgical);
        }
        if let Some(volume) = &volume {
            self.finish_volume_tools(volume, &mut surgical);
        }
        Ok(self.finish(start, counters, surgical))
    }

    /// The mechanics of one step: the integrator under the scene's loads, `inputs`' node forces
    /// and the fields beside the tissue (the tools' springs, the volume contact).
    fn advance(
        &mut self,
        inputs: &StepInputs,
        mut extra: Vec<&mut dyn ForceField>,
        counters: &mut StageCounters,
    ) {
        let nodes = self.state.x.len();
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
        let hex = match &mut self.body {
            Body::Hex(hex) => hex,
            Body::Tet(tet) => {
                let TetBody { model, topology, force_field, penalty, loads, stepper, .. } =
                    &mut **tet;
                let external = with_inputs(&loads.nodal);
                let mut elastic = force_field.bind(model, topology, penalty.as_ref());
                let mut fields: Vec<&mut dyn ForceField> = vec![&mut elastic];
                for t in &mut extra {
                    fields.push(&mut **t);
                }
                match stepper {
                    TetStepper::Explicit(cd) => {
                        cd.step_fields(
                            model,
                            &mut fields,
                            &self.fixed,
                            external.as_deref().unwrap_or(&loads.nodal),
                            &mut self.state.x,
                        );
                        self.state.v = cd.velocities(&self.state.x);
                    }
                    TetStepper::Implicit(be) => {
                        let driven = external.map(|nodal| Loads { gravity: [0.0; 3], nodal });
                        let r = be.step_fields(
                            model,
                            &mut fields,
                            &self.fixed,
                            driven.as_ref().unwrap_or(loads),
                            &mut self.state,
                        );
                        counters.solver_iterations = r.iterations;
                        counters.solver_residual = r.relative_residual;
                    }
                }
                counters.nonlinear_vertices = force_field.nonlinear_count();
                return;
            }
        };
        let driven =
            with_inputs(&hex.loads.nodal).map(|nodal| Loads { gravity: hex.loads.gravity, nodal });
        let loads = driven.as_ref().unwrap_or(&hex.loads);
        match (&mut hex.stepper, extra.is_empty()) {
            (HexStepper::Implicit(be), true) => {
                let r =
                    be.step(&hex.model, &mut hex.force_field, &self.fixed, loads, &mut self.state);
                counters.solver_iterations = r.iterations;
                counters.solver_residual = r.relative_residual;
                let t = be.stage_times;
                (counters.rotations_ns, counters.solve_ns, counters.update_ns) =
                    (t.rotations_ns, t.solve_ns, t.update_ns);
            }
            // With tools or volume contact their fields join the tissue: the system is solved
            // through the fields' products (block-Jacobi CG), whose preconditioner includes the
            // contact's blocks.
            (HexStepper::Implicit(be), false) => {
                let mut elastic = hex.force_field.bind(&hex.model);
                let mut fields: Vec<&mut dyn ForceField> = vec![&mut elastic];
                for t in &mut extra {
                    fields.push(&mut **t);
                }
                let r =
                    be.step_fields(&hex.model, &mut fields, &self.fixed, loads, &mut self.state);
                counters.solver_iterations = r.iterations;
                counters.solver_residual = r.relative_residual;
            }
            (HexStepper::Explicit { dt, alpha, substeps, .. }, _) => {
                for _ in 0..*substeps {
                    let mut elastic = hex.force_field.bind(&hex.model);
                    let mut fields: Vec<&mut dyn ForceField> = vec![&mut elastic];
                    for t in &mut extra {
                        fields.push(&mut **t);
                    }
                    explicit_step_fields(
                        &hex.model,
                        &mut fields,
                        &self.fixed,
                        loads,
                        *alpha,
                        *dt / *substeps as f64,
                        &mut self.state,
                    );
                }
                counters.substeps = *substeps;
            }
            (HexStepper::Static { tolerance, cholesky }, _) => {
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
    }

    fn finish(
        &mut self,
        start: Instant,
        mut counters: StageCounters,
        surgical: SurgicalFrame,
    ) -> Frame {
        self.index += 1;
        if self.is_keyframe(self.index) {
            self.settle_for_keyframe();
        }
        counters.step_ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        Frame {
            index: self.index,
            time: self.index as f64 * self.config.dt(),
            positions: self.state.x.clone(),
            state_hash: fnv(&self.state),
            counters,
            surgical,
        }
    }

    /// Cuts the grid (voxel removal or link severing) and carries the simulation across the
    /// topology change: surviving nodes keep position and velocity; a node split off another takes
    /// that node's; any other new node takes its element's mean displacement and velocity.
    /// Surviving and split-off elements keep their rotation; elements the edit did not touch keep
    /// their matrices ([`HexModel::update`]); the implicit solver's warm start follows the nodes.
    /// Fixed regions and patch loads are re-applied to the new nodes.
    ///
    /// In a tensor-mass scene there is no grid: the tetrahedra of every cell holding a removed
    /// voxel are removed (their stiffness subtracted, paper 2 §3.2), severed links are not
    /// supported there, and the change list returned is empty (see [`Simulation::tet`]). A mesh
    /// read from a file has no voxels: naming any is [`CutError::NoVoxels`] (see
    /// [`Simulation::remove_tets`]).
    ///
    /// The organ's surface, where there is one, is re-meshed and re-embedded locally.
    pub fn cut(&mut self, edit: &GridEdit) -> Result<GridChanges, CutError> {
        let changes = self.cut_grid(edit)?;
        if changes != GridChanges::default() || self.tet().is_some() {
            self.surface_after_cut(Some(edit), Some(&changes));
        }
        Ok(changes)
    }

    /// [`Self::cut`] without the surface.
    fn cut_grid(&mut self, edit: &GridEdit) -> Result<GridChanges, CutError> {
        let hex = match &mut self.body {
            Body::Hex(hex) => hex,
            Body::Tet(tet) => {
                remove_voxel_cells(tet, edit)?;
                return Ok(GridChanges::default());
            }
        };
        let changes = hex.grid.apply(edit)?;
        if changes == GridChanges::default() {
            return Ok(changes);
        }
        // In place: a cut touches a few elements, and copying the model, state and field cost
        // more than updating what it touched.
        let renumbering = hex.model.update(&hex.grid, &changes);
        let model = &hex.model;
        let old_of_new = self.state.carry(model, &renumbering, &changes);
        let added = &changes.top.elements_added;
        hex.force_field.remap(model, &renumbering, |g| {
            added.iter().find(|&&(id, _)| id == g).and_then(|&(_, origin)| origin)
        });
        self.fixed = fixed_nodes(&self.config, &hex.grid, model);
        for (i, s) in self.state.v.iter_mut().enumerate() {
            if self.fixed.is_fixed(i) {
                *s = [0.0; 3];
            }
        }
        // A patch that lost all its nodes simply stops pulling; the others keep pulling.
        let (nodal, _) = spread_patches(&self.config, &model.rest);
        hex.loads = Loads { gravity: self.config.gravity, nodal };
        match &mut hex.stepper {
            HexStepper::Implicit(be) => be.remap_warm_start(&old_of_new),
            // Cut cells hold less mass and the cut mesh's limit may fall below dt: rather than
            // blow up (or refuse the cut), each frame then takes as many smaller steps as it
            // needs. The estimate is a power iteration, paid once per cut; the explicit
            // integrator is for comparisons and CFL studies, interactive cutting runs implicit.
            HexStepper::Explicit { dt, stable_dt: limit, substeps, .. } => {
                *limit = stable_dt(model, &hex.force_field, &self.fixed);
                *substeps = (*dt / *limit).ceil().max(1.0) as usize;
            }
            HexStepper::Static { .. } => {}
        }
        Ok(changes)
    }

    /// Removes tetrahedra of a tensor-mass scene by index in [`TetBody::mesh`], each with any
    /// tetrahedra that would then hang on by an edge or a vertex, and subtracts their stiffness
    /// (paper 2 §3.2); the vertices stay, so the state and the node numbering do not change.
    /// Returns every tetrahedron removed, in order of removal (none for one already removed).
    /// An index beyond the mesh is refused before anything is removed.
    /// The boundary surface, where there is one, follows.
    pub fn remove_tets(&mut self, tets: &[usize]) -> Result<Vec<usize>, CutError> {
        let removed = self.remove_tets_only(tets)?;
        if !removed.is_empty() {
            self.surface_after_cut(None, None);
        }
        Ok(removed)
    }

    /// [`Self::remove_tets`] without the surface.
    fn remove_tets_only(&mut self, tets: &[usize]) -> Result<Vec<usize>, CutError> {
        let Body::Tet(tet) = &mut self.body else { return Err(CutError::NotTetrahedra) };
        let count = tet.mesh.tets().len();
        if let Some(&bad) = tets.iter().find(|&&t| t >= count) {
            return Err(CutError::NoSuchTet { tet: bad, count });
        }
        let mut removed = Vec::new();
        for &t in tets {
            removed.extend(tet.force_field.remove_tet(&tet.model, &mut tet.topology, t));
        }
        Ok(removed)
    }

    /// The last frame stepped (or restored from a keyframe); 0 before the first step.
    #[must_use]
    pub fn frame_index(&self) -> u64 {
        self.index
    }

    /// The scene's configuration (with `model.kind = "auto"`, the level is the level chosen).
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
            Body::Hex(hex) => match &hex.stepper {
                HexStepper::Explicit { stable_dt: limit, .. } => Some(*limit),
                _ => None,
            },
            Body::Tet(tet) => match tet.stepper {
                TetStepper::Explicit(_) => Some(tet.stable_dt),
                TetStepper::Implicit(_) => None,
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

/// A label volume as the scene uses it: a file's through the scene's label filter, cropped to
/// the foreground and strided; a procedural block's as built.
fn prepared(spec: &VolumeSpec, raw: &LabelVolume) -> Result<LabelVolume, String> {
    match spec {
        VolumeSpec::File { stride, labels, .. } => {
            raw.filtered(labels).crop_and_stride(*stride).map_err(|e| e.to_string())
        }
        VolumeSpec::Block { .. } | VolumeSpec::Organ { .. } => Ok(raw.clone()),
    }
}

/// `mesh`, its coordinates given in `unit`, in metres.
fn in_metres(mesh: &TetMesh, unit: LengthUnit) -> Result<TetMesh, String> {
    if unit == LengthUnit::Metre {
        return Ok(mesh.clone());
    }
    let per_metre = unit.per_metre();
    let vertices = mesh.vertices().iter().map(|p| p.map(|c| c / per_metre)).collect();
    TetMesh::new(vertices, mesh.tets().to_vec(), mesh.regions().to_vec())
        .map_err(|e| format!("the mesh in metres: {e}"))
}

/// Builds the hexahedral mechanics of a scene at grid `level` with elements of kind `element`,
/// and its fixed nodes.
fn hex_body(
    config: &SceneConfig,
    hex: &HexSpec,
    (level, element): (u32, ElementKind),
    volume: &LabelVolume,
    table: &MaterialTable,
    exec: Executor,
) -> Result<(HexBody, FixedNodes), String> {
    let mut grid = BranchedGrid::build(volume, table, level).map_err(|e| e.to_string())?;
    if element == ElementKind::Composite {
        // A cut then makes composite cells again from the levels' nodes near it.
        grid.track_all_nodes();
    }
    let model = HexModel::from_grid_of_kind(&grid, element);
    let force_field = HexForceField::new(&model, hex.formulation).with_executor(exec);
    if let Some(message) = missing_label_holds(config, |l| grid.fine_labels().contains(&l))
        .or_else(|| empty_region_hold(config, &model.rest, grid.element_size()))
    {
        return Err(message);
    }
    let fixed = fixed_nodes(config, &grid, &model);
    let loads = patch_loads(config, &model)?;
    let stepper = match hex.integrator {
        Integrator::ImplicitEuler { dt, solver, mass, damping } => {
            let mut be = BackwardEuler::with_solver(
                dt,
                damping,
                CgSettings {
                    // The exact solve runs no CG; the tolerance is only carried.
                    tolerance: solver.cg_tolerance().unwrap_or(DEFAULT_CG_TOLERANCE),
                    max_iterations: 10 * model.dof_count().max(100),
                },
                solver.linear_solver(),
            );
            be.mass = mass;
            HexStepper::Implicit(Box::new(be))
        }
        Integrator::Explicit { dt, rayleigh_alpha } => {
            let limit = stable_dt(&model, &force_field, &fixed);
            if dt > limit {
                return Err(format!(
                    "integrator.dt = {dt} s is above the explicit stability limit {limit:.3e} s of this mesh; use a smaller dt or the implicit integrator"
                ));
            }
            HexStepper::Explicit { dt, alpha: rayleigh_alpha, stable_dt: limit, substeps: 1 }
        }
        Integrator::Static { tolerance, solver, .. } => {
            HexStepper::Static { tolerance, cholesky: solver == StaticSolver::CholeskyCg }
        }
    };
    Ok((HexBody { grid, model, force_field, loads, stepper }, fixed))
}

/// Builds the tensor-mass mechanics of a scene and its fixed vertices, on `mesh` (in metres),
/// generated from the volume's cells (`cells`) or read from a file.
fn tet_body(
    config: &SceneConfig,
    spec: &TensorMassSpec,
    mesh: TetMesh,
    cells: Option<VoxelCells>,
    table: &MaterialTable,
    exec: Executor,
) -> Result<(TetBody, FixedNodes), String> {
    let mut regions: Vec<u32> = mesh.regions().to_vec();
    regions.sort_unstable();
    regions.dedup();
    if let Some(&region) =
        regions.iter().find(|&&r| u16::try_from(r).ok().and_then(|l| table.get(l)).is_none())
    {
        let count = mesh.regions().iter().filter(|&&r| r == region).count();
        return Err(format!(
            "region {region} ({count} tetrahedra) has no `[[materials]]` entry with that label"
        ));
    }
    let material = |region: u32| -> TetMaterial {
        let m = u16::try_from(region)
            .ok()
            .and_then(|l| table.get(l).copied())
            .expect("every region has a material (checked above)");
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
    // The tolerance of plane holds: a cell's size, or a file mesh's extent.
    let size: Vec3 = match &cells {
        Some(c) => {
            let step = f64::from(1u32 << c.level);
            std::array::from_fn(|a| step * c.volume.spacing()[a])
        }
        None => std::array::from_fn(|a| {
            let (lo, hi) =
                model.rest.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[a]), hi.max(p[a]))
                });
            hi - lo
        }),
    };
    let present = |l: u16| match &cells {
        Some(c) => c.volume.labels().contains(&l),
        None => mesh.regions().contains(&u32::from(l)),
    };
    if let Some(message) = missing_label_holds(config, present)
        .or_else(|| empty_region_hold(config, &model.rest, size))
    {
        return Err(message);
    }
    let fixed = fixed_at(config, &model.rest, size, |label| match &cells {
        // A cell's tetrahedra are held when the cell holds a voxel with the label.
        Some(c) => {
            let step = 1usize << c.level;
            let dims = c.volume.dims();
            let labels = c.volume.labels();
            let holds = |cell: &[usize; 3]| {
                (cell[2] * step..((cell[2] + 1) * step).min(dims[2])).any(|z| {
                    (cell[1] * step..((cell[1] + 1) * step).min(dims[1])).any(|y| {
                        (cell[0] * step..((cell[0] + 1) * step).min(dims[0]))
                            .any(|x| labels[x + dims[0] * (y + dims[1] * z)] == label)
                    })
                })
            };
            c.cells
                .iter()
                .enumerate()
                .filter(|(_, cell)| holds(cell))
                .flat_map(|(g, _)| (6 * g..6 * g + 6).flat_map(|t| mesh.tets()[t]))
                .map(|v| v as usize)
                .collect()
        }
        None => mesh
            .tets()
            .iter()
            .zip(mesh.regions())
            .filter(|&(_, &r)| r == u32::from(label))
            .flat_map(|(t, _)| *t)
            .map(|v| v as usize)
            .collect(),
    });
    let mut external = patch_forces(config, &model.rest)?;
    for (f, m) in external.iter_mut().zip(&model.lumped_mass) {
        for a in 0..3 {
            f[a] += m * config.gravity[a];
        }
    }
    let stable_dt = incise_fem::ode::central_difference::stable_dt(&model, &force_field, &fixed);
    let stepper = match spec.integrator {
        TetIntegrator::ImplicitEuler { dt, cg_tolerance, damping } => {
            TetStepper::Implicit(Box::new(BackwardEuler::new(
                dt,
                damping,
                CgSettings {
                    tolerance: cg_tolerance,
                    max_iterations: 10 * (3 * model.vertex_count()).max(100),
                },
            )))
        }
        TetIntegrator::Explicit { dt, rayleigh_alpha } => TetStepper::Explicit(
            CentralDifference::new(&model, &force_field, &fixed, &model.rest, dt, rayleigh_alpha)
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
            loads: Loads { gravity: [0.0; 3], nodal: external },
            stepper,
        },
        fixed,
    ))
}

/// Removes the tetrahedra of every cell holding one of `edit`'s removed voxels.
fn remove_voxel_cells(tet: &mut TetBody, edit: &GridEdit) -> Result<(), CutError> {
    let Some(cells) = &tet.cells else { return Err(CutError::NoVoxels) };
    let dims = cells.volume.dims();
    let count = dims.iter().product::<usize>();
    let step = 1usize << cells.level;
    let mut doomed: Vec<[usize; 3]> = Vec::with_capacity(edit.remove_voxels.len());
    for &v in &edit.remove_voxels {
        if v as usize >= count {
            return Err(EditError::VoxelOutOfRange { voxel: v, count }.into());
        }
        let v = v as usize;
        let p = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
        doomed.push(std::array::from_fn(|a| p[a] / step));
    }
    doomed.sort_unstable();
    doomed.dedup();
    for k in 0..cells.cells.len() {
        if doomed.binary_search(&cells.cells[k]).is_ok() {
            for t in 6 * k..6 * k + 6 {
                tet.force_field.remove_tet(&tet.model, &mut tet.topology, t);
            }
        }
    }
    Ok(())
}

/// The volume contact of `spec` on `body`'s `surface`.
fn volume_contact(
    spec: &crate::config::VolumeContactSpec,
    body: &Body,
    surface: &OrganSurface,
) -> Result<surgery::VolumeContact, String> {
    match body {
        Body::Hex(hex) => {
            let labels: Vec<u16> = hex.grid.materials().map(|(label, _)| label).collect();
            let group = |label: u16| labels.iter().position(|&l| l == label).map(|m| m as u16);
            surgery::VolumeContact::new(spec, surface, &surface.rest_positions(&[]), group)
        }
        Body::Tet(tet) => surgery::VolumeContact::new(
            spec,
            surface,
            &surface.rest_positions(&tet.model.rest),
            |_| None,
        ),
    }
}

/// What the tools' defaults depend on ([`surgery::ToolDefaults`]): the implicit step, the mean
/// node mass, and with an explicit integrator a coupling stiffness its step keeps stable on the
/// lightest node: `m / 8h²`, a thirty-second of a lone spring's limit `4m / h²`, since the
/// node's elasticity takes most of that limit already (a scene's step is chosen near its mesh's
/// own) and the overlap penalty (held to the same limit) some more.
fn tool_defaults(config: &SceneConfig, body: &Body) -> surgery::ToolDefaults {
    let lumped = match body {
        Body::Hex(hex) => incise_fem::model::Mass::lumped(&hex.model),
        Body::Tet(tet) => incise_fem::model::Mass::lumped(&tet.model),
    };
    let node_mass = lumped.iter().sum::<f64>() / lumped.len().max(1) as f64;
    let lightest = lumped.iter().copied().filter(|&m| m > 0.0).fold(f64::INFINITY, f64::min);
    let explicit_step = match body {
        Body::Hex(hex) => match hex.stepper {
            HexStepper::Explicit { dt, stable_dt, .. } => Some(dt.min(stable_dt)),
            _ => None,
        },
        Body::Tet(tet) => matches!(tet.stepper, TetStepper::Explicit(_)).then(|| config.dt()),
    };
    surgery::ToolDefaults {
        implicit_dt: implicit_step(config),
        node_mass,
        explicit_limit: explicit_step.map(|h| lightest / (8.0 * h * h)),
        voxel: match body {
            Body::Hex(hex) => Some(hex.grid.spacing().into_iter().fold(0.0, f64::max)),
            Body::Tet(_) => None,
        },
    }
}

/// The step an implicit integrator takes (s), `0` for an explicit one: what the tools' default
/// damping is per unit of stiffness (see `ToolSpec::damping`). An explicit step is far shorter
/// than a contact's period and resolves no penetration at once, so it needs no such damping,
/// and a velocity damping it integrates explicitly would only lower its stable step.
fn implicit_step(config: &SceneConfig) -> f64 {
    let implicit = match &config.model {
        Model::Hexahedra(hex) => matches!(hex.integrator, Integrator::ImplicitEuler { .. }),
        Model::TensorMass(tm) => matches!(tm.integrator, TetIntegrator::ImplicitEuler { .. }),
    };
    if implicit { config.dt() } else { 0.0 }
}
