//! `SceneConfig`: a scene described in TOML — the geometry (a label volume, a procedural block or
//! a tetrahedral mesh file), label → material, the model with its integrator, gravity, fixed
//! regions, loads and the executor.
//!
//! The types are built so that a contradictory scene cannot be written down in Rust either: the
//! integrator's settings live in the variant that uses them (an explicit step has no solver and
//! no stiffness damping, the exact Cholesky solve no CG tolerance), and a tensor-mass model has
//! its own integrators (no static solve, no sparse factor, no consistent mass). So the TOML
//! decoder is the one place that checks a scene file: the raw document is deserialised with
//! spans (`toml::Spanned`), and every refusal names the key and the line.

mod tools;

pub use tools::{
    CouplingSpec, Cutting, DEFAULT_COUPLING_STIFFNESS, DEFAULT_CUT_FORCE, DEFAULT_MAX_FORCE,
    DEFAULT_PENALTY_STIFFNESS, ShapeSpec, ToolContact, ToolSpec,
};

pub use incise_fem::ElementKind;
use incise_fem::forcefield::tet::Elasticity;
use incise_fem::ode::{LinearSolver, MassMatrix, Rayleigh};
use incise_fem::{Executor, Formulation, Idle};
use incise_grid::LabelFilter;
use serde::Deserialize;
use std::ops::Range;
use toml::Spanned;

/// CG's relative tolerance where a scene gives none (`integrator.cg_tolerance`).
pub const DEFAULT_CG_TOLERANCE: f64 = 1e-6;

/// The most threads `[exec] threads` may ask for.
pub const MAX_THREADS: usize = 256;

/// A scene file that cannot be used.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum SceneError {
    /// Not TOML, an unknown key, or a value of the wrong type.
    #[error("{file}:{line}: {message}")]
    Parse {
        /// The file (or name given for the text).
        file: String,
        /// 1-based line, 0 when unknown.
        line: usize,
        /// What was wrong.
        message: String,
    },
    /// A key whose value is out of range or inconsistent.
    #[error("{file}:{line}: `{key}` {message}")]
    Invalid {
        /// The file.
        file: String,
        /// 1-based line of the value.
        line: usize,
        /// The key, dotted (`integrator.dt`).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// The scene could not be built (its volume, grid, mesh or materials).
    #[error("{file}: {message}")]
    Build {
        /// The file.
        file: String,
        /// What failed.
        message: String,
    },
}

/// A validated scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneConfig {
    /// Scene name (used in keys and reports).
    pub name: String,
    /// The mechanics: the model, the geometry it is built on, and its integrator.
    pub model: Model,
    /// Label (or mesh region) → material.
    pub materials: Vec<MaterialSpec>,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
    /// Fixed regions.
    pub fixed: Vec<FixedSpec>,
    /// Patch loads.
    pub loads: Vec<PatchLoad>,
    /// The threads the physics runs on (`[exec]`).
    pub exec: ExecSpec,
    /// The tools (`[[tools]]`).
    pub tools: Vec<ToolSpec>,
    /// How the organ's surface is built (`[surface]`).
    pub surface: SurfaceSpec,
    /// Contact between organs and within a cut by their intersection volume (`[volume_contact]`;
    /// `None`: none).
    pub volume_contact: Option<VolumeContactSpec>,
    /// Whether volume contact's per-frame passes run on a GPU (`gpu`).
    pub gpu: GpuSetting,
}

/// `gpu`: where volume contact's per-frame passes (the surface's deformation, the layered depth
/// images) run. A scene without `[volume_contact]` makes no device whatever it says.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GpuSetting {
    /// `"off"` (the default): on the CPU, in `f64`, bit for bit the same on every machine (so a
    /// recording replays exactly anywhere).
    #[default]
    Off,
    /// `"auto"`: on a hardware adapter when there is one (which one is logged), else on the CPU;
    /// software rasterisers are passed over (the CPU path is faster than they are). The
    /// simulation is given its device by whoever builds it for a user (`incise_scene::attach_gpu`,
    /// which the server, the replay and the benchmarks call); a build of `incise_scene` without
    /// its `gpu` feature has none, and runs on the CPU.
    Auto,
    /// `"on"`: on any adapter, a software one included; if there is none, the CPU, with a
    /// warning (never a failure).
    On,
}

/// `[volume_contact]`: organs, and the walls of a cut, pushed apart where their surfaces overlap,
/// by the overlap's volume (Faure et al. 2008, paper 1 §3, Fig. 10). Each connected overlap is
/// pressed apart with a pressure of `pressure` per metre of its depth (its volume over its area).
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeContactSpec {
    /// Contact pressure per metre of depth (`pressure`, N/m³; default
    /// [`VolumeContactSpec::DEFAULT_PRESSURE`]).
    pub pressure: f64,
    /// Pixels per side of each of the three views over an overlap's box (`resolution`; default
    /// [`VolumeContactSpec::DEFAULT_RESOLUTION`]): the views' cost is fixed, their pixels as fine
    /// as the box is small.
    pub resolution: usize,
    /// Tissues (label pairs) that are separate bodies touching each other (`pairs`): the links
    /// between their voxels are severed when the scene is built, and where their surfaces
    /// overlap they are pushed apart. Needs `[surface] interfaces = true` (a surface per tissue).
    pub pairs: Vec<[u16; 2]>,
    /// Whether the organ's surface is pushed apart where it overlaps itself around the walls of
    /// its cuts (`self`, default false): a cut's flaps, or the two faces of a severed cut pressed
    /// back together.
    pub self_contact: bool,
}

impl VolumeContactSpec {
    /// 10 kPa per millimetre of depth: a liver resting on a kidney (about 6 kPa of contact
    /// pressure) sinks in by under a millimetre.
    pub const DEFAULT_PRESSURE: f64 = 1e7;
    /// 32 pixels per side: a 5 cm overlap box has 1.6 mm pixels, finer than the organs' voxels.
    pub const DEFAULT_RESOLUTION: usize = 32;
}

/// `[surface]`: how the organ's surface is built (for the tools, and for rendering).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SurfaceSpec {
    /// One closed surface per material, coincident where tissues touch, instead of one surface
    /// of the whole organ (`interfaces = true`: a scene that shows the liver/kidney boundary).
    pub interfaces: bool,
    /// Taubin smoothing steps on the rest surface (`smoothing`, 0 = none): the vertices stay
    /// within half a voxel of their voxels, so the embedding stays valid. Vertices a cut creates
    /// start unsmoothed at their voxel face centres.
    pub smoothing: u32,
}

/// The mechanical model, with the geometry it is built on and the integrator that steps it.
#[derive(Clone, Debug, PartialEq)]
pub enum Model {
    /// Hexahedra on the branched grid of a label volume (`model.kind = "linear"`,
    /// `"corotational"` or `"auto"`).
    Hexahedra(HexSpec),
    /// Paper 2's tensor-mass tetrahedra (`model.kind = "tensor-mass"`).
    TensorMass(TensorMassSpec),
}

/// A hexahedral model.
#[derive(Clone, Debug, PartialEq)]
pub struct HexSpec {
    /// The label volume the grid is built on.
    pub volume: VolumeSpec,
    /// With or without element rotations.
    pub formulation: Formulation,
    /// The grid level the mechanics runs on.
    pub level: Level,
    /// How coarse elements get their stiffness (`model.element`: `"condensed"`, the default,
    /// `"composite"` or `"incompatible"`). With `model.kind = "auto"` and no `model.element`,
    /// the calibration chooses it.
    pub element: ElementKind,
    /// How it is stepped.
    pub integrator: Integrator,
}

/// The grid level of a hexahedral model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Level {
    /// This level (`level`, 0 to [`incise_grid::grid::MAX_LEVELS`]).
    Fixed(u32),
    /// Chosen when the scene is built (`model.kind = "auto"`).
    Auto(AutoLevel),
}

/// `model.kind = "auto"`: the grid level is chosen when the scene is built, as the coarsest level
/// (up to `max_level`) whose estimated error fits `max_error`; the error of each level is
/// estimated by a static calibration against the finest affordable level (see
/// `incise_sim::calibration`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AutoLevel {
    /// Largest acceptable relative error (0.05 = 5 %).
    pub max_error: f64,
    /// Coarsest level considered.
    pub max_level: u32,
    /// Whether the calibration also chooses the element kind (no `model.element` given); else
    /// it keeps [`HexSpec::element`].
    pub any_element: bool,
}

/// The integrator of a hexahedral model (`[integrator]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Integrator {
    /// Linearised backward Euler, one solve per step.
    ImplicitEuler {
        /// Time step (s).
        dt: f64,
        /// How each step's linear system is solved.
        solver: ImplicitSolver,
        /// The mass matrix.
        mass: MassMatrix,
        /// Rayleigh damping.
        damping: Rayleigh,
    },
    /// Symplectic Euler with the lumped mass. Stiffness damping would cap its stable step near
    /// 2/(β ω²) for the mesh's highest frequency ω, so there is only mass damping.
    Explicit {
        /// Time step (s); at most the mesh's stable step when the scene is built.
        dt: f64,
        /// Mass-proportional damping α (1/s).
        rayleigh_alpha: f64,
    },
    /// Newton iterations to static equilibrium every step (for references).
    Static {
        /// The simulated time one frame stands for (s).
        dt: f64,
        /// Newton stops at this residual relative to the load.
        tolerance: f64,
        /// How each Newton step's CG is preconditioned.
        solver: StaticSolver,
        /// Damping the static solve has no use for: the scene's damping for tools that run the
        /// same scene dynamically (`incise-bench speed-error`).
        damping: Rayleigh,
    },
}

/// The implicit step's linear solver (`integrator.solver` with `integrator.cg_tolerance`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ImplicitSolver {
    /// Block-Jacobi CG (`"jacobi-cg"`, the default).
    JacobiCg {
        /// CG stops at this times `max(‖b‖, h‖f_ext‖)`.
        cg_tolerance: f64,
    },
    /// CG preconditioned by a refreshed sparse Cholesky factor (`"cholesky-cg"`).
    CholeskyCg {
        /// CG stops at this times `max(‖b‖, h‖f_ext‖)`.
        cg_tolerance: f64,
    },
    /// The exact sparse Cholesky factor every step (`"cholesky"`): no CG, no tolerance.
    Cholesky,
}

/// The preconditioner of a static scene's Newton steps (`integrator.solver`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StaticSolver {
    /// Block-Jacobi (`"jacobi-cg"`, the default).
    JacobiCg,
    /// A factorisation of the stiffness (`"cholesky-cg"` or `"cholesky"`: both precondition).
    CholeskyCg,
}

/// `model.kind = "tensor-mass"`: the tetrahedral model's settings (`[model]` keys), where its
/// tetrahedra come from, and its integrator.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorMassSpec {
    /// Generated from a label volume, or read from a mesh file.
    pub source: TetSource,
    /// `model.elasticity`: `"svk"` (default) or `"linear"`.
    pub elasticity: Elasticity,
    /// `model.incompressibility`: the penalty strength κ (Pa), none by default.
    pub incompressibility: Option<f64>,
    /// `model.adaptive_threshold`: displacement (m) above which a vertex is non-linear (paper 2
    /// §6); none (every tetrahedron SVK) by default.
    pub adaptive_threshold: Option<f64>,
    /// `model.fibre` and `model.fibre_ratio`: a fibre direction for every tetrahedron and how
    /// many times stiffer (λ and μ) the tissue is along it.
    pub fibre: Option<([f64; 3], f64)>,
    /// How it is stepped.
    pub integrator: TetIntegrator,
}

/// Where a tensor-mass model's tetrahedra come from.
#[derive(Clone, Debug, PartialEq)]
pub enum TetSource {
    /// Six tetrahedra per cell of the volume's grid at `level`; a tetrahedron's region is its
    /// cell's label.
    Volume {
        /// The label volume.
        volume: VolumeSpec,
        /// The grid level whose cells are split (`level`).
        level: u32,
    },
    /// A tetrahedral mesh file (`volume.mesh`); a tetrahedron's region is the one the file gives.
    Mesh(MeshSpec),
}

/// `[volume] mesh`: a tetrahedral mesh file.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSpec {
    /// `.msh`, `.vtk` or `.vtu`, relative to the scene file's folder.
    pub path: String,
    /// The unit of the file's coordinates (`volume.unit`).
    pub unit: LengthUnit,
    /// The cell-data array holding each tetrahedron's region (`volume.region`); `None` lets the
    /// reader pick (`gmsh:physical`, `medit:ref`, `CellEntityIds`, else the file's first integer
    /// cell array).
    pub region: Option<String>,
}

/// The unit of a mesh file's coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LengthUnit {
    /// `"m"` (the default).
    Metre,
    /// `"cm"`.
    Centimetre,
    /// `"mm"`: what imaging pipelines usually write.
    Millimetre,
}

impl LengthUnit {
    /// How many of this unit make a metre. Coordinates are divided by it rather than multiplied
    /// by its inverse, so that a round number in the file is the nearest `f64` to its value in
    /// metres, as if typed in a scene file.
    #[must_use]
    pub fn per_metre(self) -> f64 {
        match self {
            Self::Metre => 1.0,
            Self::Centimetre => 100.0,
            Self::Millimetre => 1000.0,
        }
    }
}

/// The integrator of a tensor-mass model (`[integrator]`): the tetrahedra have no sparse factor,
/// no consistent mass and no static solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TetIntegrator {
    /// Linearised backward Euler with block-Jacobi CG and the lumped mass.
    ImplicitEuler {
        /// Time step (s).
        dt: f64,
        /// CG stops at this times `max(‖b‖, h‖f_ext‖)`.
        cg_tolerance: f64,
        /// Rayleigh damping.
        damping: Rayleigh,
    },
    /// Paper 2's central differences with the lumped mass.
    Explicit {
        /// Time step (s); at most the mesh's stable step when the scene is built.
        dt: f64,
        /// Mass-proportional damping α (1/s).
        rayleigh_alpha: f64,
    },
}

/// Where a label volume comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSpec {
    /// A label volume file (NIfTI or INR), relative to the scene file's folder.
    File {
        /// The path as written in the scene.
        path: String,
        /// Per-axis stride after filtering and cropping to the foreground.
        stride: [usize; 3],
        /// Labels merged into others and labels kept (`volume.merge`, `volume.keep`); the
        /// identity when the scene gives neither.
        labels: LabelFilter,
    },
    /// A box of `voxels` cells filling `size_m` (label 1).
    Block {
        /// Edge lengths (m).
        size_m: [f64; 3],
        /// Voxels per axis.
        voxels: [usize; 3],
    },
    /// An organ with a tumour in a box of `voxels` cells filling `size_m`: the ellipsoid
    /// inscribed in the box (label 1) holding an off-centre sphere (label 2); see
    /// `incise_grid::procedural::organ`.
    Organ {
        /// Edge lengths of the box (m).
        size_m: [f64; 3],
        /// Voxels per axis.
        voxels: [usize; 3],
    },
}

/// A tissue of one label (or mesh region).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaterialSpec {
    /// The label it applies to.
    pub label: u16,
    /// Young's modulus (Pa).
    pub youngs_modulus: f64,
    /// Poisson's ratio.
    pub poisson_ratio: f64,
    /// Density (kg/m³).
    pub density: f64,
}

impl MaterialSpec {
    /// The material, undamped: damping is the scene's ([`Integrator`]), not a tissue's.
    #[must_use]
    pub fn material(&self) -> incise_grid::Material {
        incise_grid::Material {
            youngs_modulus: self.youngs_modulus,
            poisson_ratio: self.poisson_ratio,
            density: self.density,
            rayleigh_mass: 0.0,
            rayleigh_stiffness: 0.0,
        }
    }
}

/// A region of fixed nodes.
#[derive(Clone, Debug, PartialEq)]
pub enum FixedSpec {
    /// Nodes on the plane `x[axis] = value` (m).
    Plane {
        /// 0 = x, 1 = y, 2 = z.
        axis: usize,
        /// Coordinate of the plane (m, grid frame).
        value: f64,
    },
    /// Nodes inside the box `[min, max]` (m, grid frame).
    Box {
        /// Lower corner.
        min: [f64; 3],
        /// Upper corner.
        max: [f64; 3],
    },
    /// Every node of every element (hexahedron, or a tensor-mass cell's tetrahedra) that holds a
    /// voxel with this label, or of every tetrahedron of a mesh file in this region: tissue held
    /// by an attachment segmented in the image (a ligament, a vessel, a neighbouring organ). At a
    /// coarse level the whole element holding such a voxel is held.
    Label {
        /// The voxel label or mesh region (one of the scene's `[[materials]]`).
        label: u16,
    },
}

/// A force spread evenly over the nodes within `radius` of `centre`.
#[derive(Clone, Debug, PartialEq)]
pub struct PatchLoad {
    /// Centre of the patch (m, grid frame).
    pub centre: [f64; 3],
    /// Radius (m).
    pub radius: f64,
    /// Total force (N).
    pub force: [f64; 3],
}

/// `[exec]`: the executor's settings; what is not given takes [`Executor::configured`]'s
/// defaults. (The programs let the environment override them when they load a scene:
/// `incise_scene::environment`.)
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExecSpec {
    /// `exec.threads`: 1 to [`MAX_THREADS`].
    pub threads: Option<usize>,
    /// `exec.idle`: `"spin"` ([`Idle::DEFAULT_SPIN`]) or `"sleep"`.
    pub idle: Option<Idle>,
}

impl ExecSpec {
    /// The executor these settings describe ([`Executor::configured`]).
    #[must_use]
    pub fn executor(&self) -> Executor {
        Executor::configured(self.threads, self.idle)
    }

    /// The executor for a process that also runs a real-time thread (the server's 1 kHz
    /// haptic loop): what is not given takes [`Executor::beside_realtime_thread`]'s settings
    /// (one thread fewer than the cores, idle workers sleep), so that thread always finds a
    /// core.
    #[must_use]
    pub fn executor_beside_realtime_thread(&self) -> Executor {
        let realtime = Executor::beside_realtime_thread();
        Executor::configured(
            Some(self.threads.unwrap_or(realtime.threads())),
            Some(self.idle.unwrap_or(realtime.idle())),
        )
    }
}

impl Integrator {
    /// The time step (s); for a static scene, the time one frame stands for.
    #[must_use]
    pub fn dt(&self) -> f64 {
        match *self {
            Self::ImplicitEuler { dt, .. }
            | Self::Explicit { dt, .. }
            | Self::Static { dt, .. } => dt,
        }
    }

    /// The Rayleigh damping (β is 0 for the explicit integrator).
    #[must_use]
    pub fn damping(&self) -> Rayleigh {
        match *self {
            Self::ImplicitEuler { damping, .. } | Self::Static { damping, .. } => damping,
            Self::Explicit { rayleigh_alpha, .. } => Rayleigh { alpha: rayleigh_alpha, beta: 0.0 },
        }
    }

    /// The CG tolerance the scene gives (a static scene's Newton tolerance); `None` for the
    /// explicit integrator and the exact Cholesky solve.
    #[must_use]
    pub fn cg_tolerance(&self) -> Option<f64> {
        match *self {
            Self::ImplicitEuler { solver, .. } => solver.cg_tolerance(),
            Self::Static { tolerance, .. } => Some(tolerance),
            Self::Explicit { .. } => None,
        }
    }
}

impl ImplicitSolver {
    /// CG's tolerance (`None` for the exact solve).
    #[must_use]
    pub fn cg_tolerance(&self) -> Option<f64> {
        match *self {
            Self::JacobiCg { cg_tolerance } | Self::CholeskyCg { cg_tolerance } => {
                Some(cg_tolerance)
            }
            Self::Cholesky => None,
        }
    }

    /// The solver [`incise_fem::ode::BackwardEuler`] runs.
    #[must_use]
    pub fn linear_solver(&self) -> LinearSolver {
        match self {
            Self::JacobiCg { .. } => LinearSolver::JacobiCg,
            Self::CholeskyCg { .. } => LinearSolver::CholeskyCg { refresh_iterations: 8 },
            Self::Cholesky => LinearSolver::Cholesky,
        }
    }
}

impl TetIntegrator {
    /// The time step (s).
    #[must_use]
    pub fn dt(&self) -> f64 {
        match *self {
            Self::ImplicitEuler { dt, .. } | Self::Explicit { dt, .. } => dt,
        }
    }
}

impl SceneConfig {
    /// The time step (s) (a static scene's: the time one frame stands for).
    #[must_use]
    pub fn dt(&self) -> f64 {
        match &self.model {
            Model::Hexahedra(hex) => hex.integrator.dt(),
            Model::TensorMass(tm) => tm.integrator.dt(),
        }
    }

    /// The label volume the model is built on (`None` for a mesh read from a file).
    #[must_use]
    pub fn volume(&self) -> Option<&VolumeSpec> {
        match &self.model {
            Model::Hexahedra(HexSpec { volume, .. })
            | Model::TensorMass(TensorMassSpec {
                source: TetSource::Volume { volume, .. }, ..
            }) => Some(volume),
            Model::TensorMass(_) => None,
        }
    }

    /// [`Self::volume`], to change it.
    #[must_use]
    pub fn volume_mut(&mut self) -> Option<&mut VolumeSpec> {
        match &mut self.model {
            Model::Hexahedra(HexSpec { volume, .. })
            | Model::TensorMass(TensorMassSpec {
                source: TetSource::Volume { volume, .. }, ..
            }) => Some(volume),
            Model::TensorMass(_) => None,
        }
    }

    /// The grid level the model is built on; `None` while `model.kind = "auto"` has not chosen
    /// it ([`crate::Simulation::config`] has the level chosen) and for a mesh read from a file.
    #[must_use]
    pub fn level(&self) -> Option<u32> {
        match &self.model {
            Model::Hexahedra(HexSpec { level: Level::Fixed(level), .. })
            | Model::TensorMass(TensorMassSpec {
                source: TetSource::Volume { level, .. }, ..
            }) => Some(*level),
            Model::Hexahedra(_) | Model::TensorMass(_) => None,
        }
    }

    /// The scene's volume when it is procedural (`None` for a file, which the caller reads).
    #[must_use]
    pub fn procedural_volume(&self) -> Option<incise_grid::LabelVolume> {
        match self.volume()? {
            VolumeSpec::Block { size_m, voxels } => {
                let spacing = std::array::from_fn(|a| size_m[a] / voxels[a] as f64);
                Some(incise_grid::procedural::from_fn(*voxels, spacing, |_, _, _| {
                    incise_grid::procedural::TISSUE
                }))
            }
            VolumeSpec::Organ { size_m, voxels } => {
                let spacing = std::array::from_fn(|a| size_m[a] / voxels[a] as f64);
                Some(incise_grid::procedural::organ(*voxels, spacing))
            }
            VolumeSpec::File { .. } => None,
        }
    }
}

// --- the raw document, with spans --------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    name: String,
    volume: Spanned<RawVolume>,
    #[serde(default)]
    level: Option<Spanned<i64>>,
    #[serde(default)]
    materials: Option<Spanned<Vec<Spanned<RawMaterial>>>>,
    #[serde(default)]
    model: Option<RawModel>,
    integrator: RawIntegrator,
    #[serde(default)]
    gravity: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    fixed: Vec<Spanned<RawFixed>>,
    #[serde(default)]
    loads: Vec<RawLoad>,
    #[serde(default)]
    exec: Option<RawExec>,
    #[serde(default)]
    tools: Vec<Spanned<tools::RawTool>>,
    #[serde(default)]
    surface: Option<RawSurface>,
    #[serde(default)]
    volume_contact: Option<Spanned<RawVolumeContact>>,
    #[serde(default)]
    gpu: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVolumeContact {
    #[serde(default)]
    pressure: Option<Spanned<f64>>,
    #[serde(default)]
    resolution: Option<Spanned<i64>>,
    #[serde(default)]
    pairs: Option<Spanned<Vec<Spanned<[i64; 2]>>>>,
    #[serde(default, rename = "self")]
    self_contact: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSurface {
    #[serde(default)]
    interfaces: Option<bool>,
    #[serde(default)]
    smoothing: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVolume {
    file: Option<Spanned<String>>,
    stride: Option<Spanned<[i64; 3]>>,
    labels: Option<Spanned<Vec<Spanned<i64>>>>,
    keep: Option<Spanned<Vec<Spanned<i64>>>>,
    merge: Option<Spanned<Vec<Spanned<[i64; 2]>>>>,
    procedural: Option<Spanned<String>>,
    size_m: Option<Spanned<[f64; 3]>>,
    voxels: Option<Spanned<[i64; 3]>>,
    mesh: Option<Spanned<String>>,
    unit: Option<Spanned<String>>,
    region: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMaterial {
    label: Spanned<i64>,
    youngs_modulus: Spanned<f64>,
    poisson_ratio: Spanned<f64>,
    density: Spanned<f64>,
    #[serde(default)]
    rayleigh_mass: Option<Spanned<f64>>,
    #[serde(default)]
    rayleigh_stiffness: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModel {
    kind: Spanned<String>,
    #[serde(default)]
    max_error: Option<Spanned<f64>>,
    #[serde(default)]
    max_level: Option<Spanned<i64>>,
    #[serde(default)]
    element: Option<Spanned<String>>,
    #[serde(default)]
    elasticity: Option<Spanned<String>>,
    #[serde(default)]
    incompressibility: Option<Spanned<f64>>,
    #[serde(default)]
    adaptive_threshold: Option<Spanned<f64>>,
    #[serde(default)]
    fibre: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    fibre_ratio: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIntegrator {
    kind: Spanned<String>,
    dt: Spanned<f64>,
    #[serde(default)]
    cg_tolerance: Option<Spanned<f64>>,
    #[serde(default)]
    solver: Option<Spanned<String>>,
    #[serde(default)]
    mass: Option<Spanned<String>>,
    #[serde(default)]
    rayleigh_alpha: Option<Spanned<f64>>,
    #[serde(default)]
    rayleigh_beta: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFixed {
    plane: Option<Spanned<String>>,
    value: Option<Spanned<f64>>,
    min: Option<Spanned<[f64; 3]>>,
    max: Option<Spanned<[f64; 3]>>,
    label: Option<Spanned<u16>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLoad {
    centre: Spanned<[f64; 3]>,
    radius: Spanned<f64>,
    force: Spanned<[f64; 3]>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawExec {
    #[serde(default)]
    threads: Option<Spanned<i64>>,
    #[serde(default)]
    idle: Option<Spanned<String>>,
}

/// 1-based line of byte offset `at` in `text`.
fn line_of(text: &str, at: usize) -> usize {
    text[..at.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

/// `model.kind`.
#[derive(Clone, Copy, PartialEq, Eq)]
enum ModelKind {
    Hexahedra(Formulation),
    Auto,
    TensorMass,
}

/// `integrator.kind`.
#[derive(Clone, Copy, PartialEq, Eq)]
enum IntegratorKind {
    ImplicitEuler,
    Explicit,
    Static,
}

/// `integrator.solver` as written.
#[derive(Clone, Copy, PartialEq, Eq)]
enum SolverName {
    JacobiCg,
    CholeskyCg,
    Cholesky,
}

/// The `[integrator]` values, each checked on its own, before they are checked against each
/// other and against the model.
struct IntegratorKeys {
    kind: IntegratorKind,
    dt: f64,
    cg_tolerance: Option<(Range<usize>, f64)>,
    solver: Option<(Range<usize>, SolverName)>,
    mass: Option<(Range<usize>, MassMatrix)>,
    damping: Rayleigh,
}

/// `[volume]` as described: a label volume, or a mesh file (with the span of its key).
enum Geometry {
    Volume(VolumeSpec),
    Mesh(MeshSpec, Range<usize>),
}

/// The tensor-mass keys of `[model]`.
struct TetSettings {
    elasticity: Elasticity,
    incompressibility: Option<f64>,
    adaptive_threshold: Option<f64>,
    fibre: Option<([f64; 3], f64)>,
}

struct Checker<'a> {
    text: &'a str,
    file: &'a str,
}

impl Checker<'_> {
    fn invalid(&self, span: Range<usize>, key: &str, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            file: self.file.to_owned(),
            line: line_of(self.text, span.start),
            key: key.to_owned(),
            message: message.into(),
        }
    }

    /// The first of `keys` that is given, refused with `why`.
    fn refuse(&self, keys: &[(Option<Range<usize>>, &str)], why: &str) -> Result<(), SceneError> {
        match keys.iter().find_map(|(span, key)| span.clone().map(|s| (s, *key))) {
            Some((span, key)) => Err(self.invalid(span, key, why)),
            None => Ok(()),
        }
    }

    /// `[[materials]]`: at least one, one per label.
    fn materials(
        &self,
        raw: Option<&Spanned<Vec<Spanned<RawMaterial>>>>,
    ) -> Result<Vec<MaterialSpec>, SceneError> {
        let mut materials: Vec<MaterialSpec> = Vec::new();
        let (materials_at, raw_materials) = match raw {
            Some(list) => (list.span(), list.get_ref().as_slice()),
            None => (0..0, &[][..]),
        };
        for (i, m) in raw_materials.iter().enumerate() {
            let m = m.get_ref();
            let key = |k: &str| format!("materials[{i}].{k}");
            // Damping is one Rayleigh pair for the scene: the implicit system is a·M + b·K with
            // two scalars (its matrix-free product and factorisation rely on that), so a value
            // per tissue would be silently dropped. Refused until per-tissue damping exists.
            if let Some((span, k)) =
                m.rayleigh_mass.as_ref().map(|v| (v.span(), "rayleigh_mass")).or_else(|| {
                    m.rayleigh_stiffness.as_ref().map(|v| (v.span(), "rayleigh_stiffness"))
                })
            {
                return Err(self.invalid(
                    span,
                    &key(k),
                    "is not supported per material yet: damping is set for the whole scene by \
                     `integrator.rayleigh_alpha` (mass) and `integrator.rayleigh_beta` (stiffness)",
                ));
            }
            let label = *m.label.get_ref();
            if !(1..=i64::from(u16::MAX)).contains(&label) {
                return Err(self.invalid(
                    m.label.span(),
                    &key("label"),
                    format!("is {label}; labels are 1..=65535"),
                ));
            }
            if let Some(j) = materials.iter().position(|m| i64::from(m.label) == label) {
                return Err(self.invalid(
                    m.label.span(),
                    &key("label"),
                    format!("{label} is already materials[{j}]'s label; a label has one material"),
                ));
            }
            let nu = *m.poisson_ratio.get_ref();
            if !(nu > -1.0 && nu < 0.5) {
                return Err(self.invalid(
                    m.poisson_ratio.span(),
                    &key("poisson_ratio"),
                    format!("is {nu}; it must lie in (-1, 0.5)"),
                ));
            }
            materials.push(MaterialSpec {
                label: label as u16,
                // From a gel (1 Pa) to steel (2e11 Pa) and beyond; outside, the condensed
                // matrices over- or underflow against the mass.
                youngs_modulus: self.within(
                    &m.youngs_modulus,
                    &key("youngs_modulus"),
                    (1e-3, 1e13),
                    "Pa",
                )?,
                poisson_ratio: nu,
                // Lighter than air to denser than osmium (22,590 kg/m³).
                density: self.within(&m.density, &key("density"), (1e-3, 1e5), "kg/m³")?,
            });
        }
        if materials.is_empty() {
            // An empty `materials = []` at its line; a missing table at line 1, as serde reports
            // its own "missing field" errors.
            return Err(self.invalid(
                materials_at,
                "materials",
                "is missing: the scene needs at least one `[[materials]]` entry",
            ));
        }
        Ok(materials)
    }

    /// `[model]` with the `[volume]`, `level` and `[integrator]` it uses.
    fn model(&self, raw: &RawScene, materials: &[MaterialSpec]) -> Result<Model, SceneError> {
        let m = raw.model.as_ref();
        let kind = match m.map(|m| m.kind.get_ref().as_str()) {
            None | Some("corotational") => ModelKind::Hexahedra(Formulation::Corotational),
            Some("linear") => ModelKind::Hexahedra(Formulation::Linear),
            Some("auto") => ModelKind::Auto,
            Some("tensor-mass") => ModelKind::TensorMass,
            Some(other) => {
                return Err(self.invalid(
                    m.map_or(0..0, |m| m.kind.span()),
                    "model.kind",
                    format!(
                        "is \"{other}\"; expected \"linear\", \"corotational\", \"auto\" or \"tensor-mass\""
                    ),
                ));
            }
        };
        if let Some(m) = m {
            if kind == ModelKind::TensorMass {
                self.refuse(
                    &[(m.element.as_ref().map(Spanned::span), "model.element")],
                    "applies only to hexahedra (`model.kind = \"linear\"`, \"corotational\" or \"auto\"): tetrahedra have no coarse elements",
                )?;
            } else {
                self.refuse(
                    &[
                        (m.elasticity.as_ref().map(Spanned::span), "model.elasticity"),
                        (
                            m.incompressibility.as_ref().map(Spanned::span),
                            "model.incompressibility",
                        ),
                        (
                            m.adaptive_threshold.as_ref().map(Spanned::span),
                            "model.adaptive_threshold",
                        ),
                        (m.fibre.as_ref().map(Spanned::span), "model.fibre"),
                        (m.fibre_ratio.as_ref().map(Spanned::span), "model.fibre_ratio"),
                    ],
                    "applies only to `model.kind = \"tensor-mass\"`",
                )?;
            }
            if kind != ModelKind::Auto {
                self.refuse(
                    &[
                        (m.max_error.as_ref().map(Spanned::span), "model.max_error"),
                        (m.max_level.as_ref().map(Spanned::span), "model.max_level"),
                    ],
                    "applies only to `model.kind = \"auto\"`",
                )?;
            }
        }
        let geometry = self.volume(&raw.volume, materials)?;
        let keys = self.integrator_keys(&raw.integrator)?;
        if kind == ModelKind::TensorMass {
            let settings = self.tensor_mass(m.expect("tensor-mass is a `[model]` kind"))?;
            let source = match geometry {
                Geometry::Volume(volume) => {
                    TetSource::Volume { volume, level: self.level(raw.level.as_ref())? }
                }
                Geometry::Mesh(mesh, _) => {
                    if let Some(l) = &raw.level {
                        return Err(self.invalid(
                            l.span(),
                            "level",
                            "does not apply to a mesh read from a file (`volume.mesh`): its tetrahedra are not a grid's cells",
                        ));
                    }
                    TetSource::Mesh(mesh)
                }
            };
            return Ok(Model::TensorMass(TensorMassSpec {
                source,
                elasticity: settings.elasticity,
                incompressibility: settings.incompressibility,
                adaptive_threshold: settings.adaptive_threshold,
                fibre: settings.fibre,
                integrator: self.tet_integrator(&raw.integrator, keys)?,
            }));
        }
        let volume = match geometry {
            Geometry::Volume(volume) => volume,
            Geometry::Mesh(_, span) => {
                return Err(self.invalid(
                    span,
                    "volume.mesh",
                    "applies only to `model.kind = \"tensor-mass\"`: hexahedra are built on a label volume (`file` or `procedural`)",
                ));
            }
        };
        let element = self.element(m)?;
        let (formulation, level) = if let ModelKind::Hexahedra(formulation) = kind {
            (formulation, Level::Fixed(self.level(raw.level.as_ref())?))
        } else {
            if let Some(l) = &raw.level {
                return Err(self.invalid(
                    l.span(),
                    "level",
                    "is chosen by `model.kind = \"auto\"`; remove `level` (or set `model.max_level`)",
                ));
            }
            let m = m.expect("auto is a `[model]` kind");
            let mut auto = self.auto_level(m)?;
            auto.any_element = element.is_none();
            (Formulation::Corotational, Level::Auto(auto))
        };
        Ok(Model::Hexahedra(HexSpec {
            volume,
            formulation,
            level,
            element: element.unwrap_or_default(),
            integrator: Self::hex_integrator(keys),
        }))
    }

    /// `model.element`, when given.
    fn element(&self, m: Option<&RawModel>) -> Result<Option<ElementKind>, SceneError> {
        let Some(e) = m.and_then(|m| m.element.as_ref()) else { return Ok(None) };
        ElementKind::from_name(e.get_ref()).map(Some).ok_or_else(|| {
            self.invalid(
                e.span(),
                "model.element",
                format!(
                    "is \"{}\"; expected \"condensed\", \"composite\" or \"incompatible\"",
                    e.get_ref()
                ),
            )
        })
    }

    /// `level`: 0 by default.
    fn level(&self, level: Option<&Spanned<i64>>) -> Result<u32, SceneError> {
        match level {
            Some(l) if !(0..=i64::from(incise_grid::grid::MAX_LEVELS)).contains(l.get_ref()) => {
                Err(self.invalid(
                    l.span(),
                    "level",
                    format!(
                        "is {}; it must be between 0 and {}",
                        l.get_ref(),
                        incise_grid::grid::MAX_LEVELS
                    ),
                ))
            }
            Some(l) => Ok(*l.get_ref() as u32),
            None => Ok(0),
        }
    }

    /// `model.max_error` and `model.max_level` of `model.kind = "auto"`.
    fn auto_level(&self, m: &RawModel) -> Result<AutoLevel, SceneError> {
        let max_error = match &m.max_error {
            None => 0.05,
            Some(e) if *e.get_ref() > 0.0 && *e.get_ref() <= 1.0 => *e.get_ref(),
            Some(e) => {
                return Err(self.invalid(
                    e.span(),
                    "model.max_error",
                    format!("is {}; it is a relative error in (0, 1], e.g. 0.05", e.get_ref()),
                ));
            }
        };
        let max_level = match &m.max_level {
            None => 3,
            Some(l) if (0..=i64::from(incise_grid::grid::MAX_LEVELS)).contains(l.get_ref()) => {
                *l.get_ref() as u32
            }
            Some(l) => {
                return Err(self.invalid(
                    l.span(),
                    "model.max_level",
                    format!(
                        "is {}; it must be between 0 and {}",
                        l.get_ref(),
                        incise_grid::grid::MAX_LEVELS
                    ),
                ));
            }
        };
        Ok(AutoLevel { max_error, max_level, any_element: true })
    }

    /// The tensor-mass keys of `[model]`.
    fn tensor_mass(&self, m: &RawModel) -> Result<TetSettings, SceneError> {
        let elasticity = match m.elasticity.as_ref().map(|e| (e.span(), e.get_ref().as_str())) {
            None | Some((_, "svk")) => Elasticity::StVenantKirchhoff,
            Some((_, "linear")) => Elasticity::Linear,
            Some((span, other)) => {
                return Err(self.invalid(
                    span,
                    "model.elasticity",
                    format!("is \"{other}\"; expected \"svk\" or \"linear\""),
                ));
            }
        };
        let incompressibility = m
            .incompressibility
            .as_ref()
            .map(|v| self.positive(v, "model.incompressibility"))
            .transpose()?;
        let adaptive_threshold = m
            .adaptive_threshold
            .as_ref()
            .map(|v| self.positive(v, "model.adaptive_threshold"))
            .transpose()?;
        let fibre = match (&m.fibre, &m.fibre_ratio) {
            (None, None) => None,
            (Some(f), ratio) => {
                let d = *f.get_ref();
                if !(d.iter().all(|x| x.is_finite()) && d.iter().any(|&x| x != 0.0)) {
                    return Err(self.invalid(
                        f.span(),
                        "model.fibre",
                        format!("{d:?} is not a direction"),
                    ));
                }
                let r =
                    ratio.as_ref().map_or(Ok(1.0), |r| self.positive(r, "model.fibre_ratio"))?;
                Some((d, r))
            }
            (None, Some(r)) => {
                return Err(self.invalid(
                    r.span(),
                    "model.fibre_ratio",
                    "needs `model.fibre` (a direction)",
                ));
            }
        };
        Ok(TetSettings { elasticity, incompressibility, adaptive_threshold, fibre })
    }

    /// Each `[integrator]` value on its own, and what every model refuses: a consistent mass
    /// without implicit steps, a CG tolerance with the exact solve, and the explicit step's
    /// solver, tolerance and stiffness damping.
    fn integrator_keys(&self, i: &RawIntegrator) -> Result<IntegratorKeys, SceneError> {
        let kind = match i.kind.get_ref().as_str() {
            "implicit-euler" => IntegratorKind::ImplicitEuler,
            "explicit" => IntegratorKind::Explicit,
            "static" => IntegratorKind::Static,
            other => {
                return Err(self.invalid(
                    i.kind.span(),
                    "integrator.kind",
                    format!(
                        "is \"{other}\"; expected \"implicit-euler\", \"explicit\" or \"static\""
                    ),
                ));
            }
        };
        let mass = match &i.mass {
            None => None,
            Some(m) => {
                let mass = match m.get_ref().as_str() {
                    "lumped" => MassMatrix::Lumped,
                    "consistent" => MassMatrix::Consistent,
                    other => {
                        return Err(self.invalid(
                            m.span(),
                            "integrator.mass",
                            format!("is \"{other}\"; expected \"lumped\" or \"consistent\""),
                        ));
                    }
                };
                if mass == MassMatrix::Consistent && kind != IntegratorKind::ImplicitEuler {
                    return Err(self.invalid(
                        m.span(),
                        "integrator.mass",
                        "\"consistent\" needs `kind = \"implicit-euler\"` (explicit steps need a diagonal mass)",
                    ));
                }
                Some((m.span(), mass))
            }
        };
        let dt = self.positive(&i.dt, "integrator.dt")?;
        if dt > 1.0 {
            return Err(self.invalid(
                i.dt.span(),
                "integrator.dt",
                format!("is {dt} s; a step above 1 s is not an interactive scene"),
            ));
        }
        let cg_tolerance = match &i.cg_tolerance {
            Some(t) => {
                let v = self.positive(t, "integrator.cg_tolerance")?;
                if v >= 1.0 {
                    return Err(self.invalid(
                        t.span(),
                        "integrator.cg_tolerance",
                        format!("is {v}; it must be below 1"),
                    ));
                }
                Some((t.span(), v))
            }
            None => None,
        };
        let solver = match &i.solver {
            None => None,
            Some(sv) => Some((
                sv.span(),
                match sv.get_ref().as_str() {
                    "jacobi-cg" => SolverName::JacobiCg,
                    "cholesky-cg" => SolverName::CholeskyCg,
                    "cholesky" => SolverName::Cholesky,
                    other => {
                        return Err(self.invalid(
                            sv.span(),
                            "integrator.solver",
                            format!(
                                "is \"{other}\"; expected \"jacobi-cg\", \"cholesky-cg\" or \"cholesky\""
                            ),
                        ));
                    }
                },
            )),
        };
        let damping = Rayleigh {
            alpha: self.non_negative(
                i.rayleigh_alpha.as_ref(),
                "integrator.rayleigh_alpha",
                0.0,
            )?,
            beta: self.non_negative(i.rayleigh_beta.as_ref(), "integrator.rayleigh_beta", 0.0)?,
        };
        if kind == IntegratorKind::ImplicitEuler
            && matches!(solver, Some((_, SolverName::Cholesky)))
            && let Some((span, _)) = &cg_tolerance
        {
            return Err(self.invalid(
                span.clone(),
                "integrator.cg_tolerance",
                "does not apply to `solver = \"cholesky\"`: the implicit step then solves exactly, without CG",
            ));
        }
        if kind == IntegratorKind::Explicit {
            // An explicit step has no linear solve; and stiffness-proportional damping would cap
            // its stable step near 2/(β ω²) (ω the mesh's highest frequency): microseconds here.
            let no_solve = "does not apply to `integrator.kind = \"explicit\"`: an explicit step solves no linear system";
            self.refuse(&[(solver.as_ref().map(|s| s.0.clone()), "integrator.solver")], no_solve)?;
            self.refuse(
                &[(cg_tolerance.as_ref().map(|t| t.0.clone()), "integrator.cg_tolerance")],
                no_solve,
            )?;
            self.refuse(
                &[(
                    i.rayleigh_beta.as_ref().filter(|b| *b.get_ref() != 0.0).map(Spanned::span),
                    "integrator.rayleigh_beta",
                )],
                "does not apply to `integrator.kind = \"explicit\"`: (stiffness damping) would cap an explicit step near 2/(β·ω²) for the mesh's highest frequency ω; use `rayleigh_alpha` or `kind = \"implicit-euler\"`",
            )?;
        }
        Ok(IntegratorKeys { kind, dt, cg_tolerance, solver, mass, damping })
    }

    /// The integrator of a hexahedral model.
    fn hex_integrator(keys: IntegratorKeys) -> Integrator {
        let IntegratorKeys { kind, dt, cg_tolerance, solver, mass, damping } = keys;
        let tolerance = cg_tolerance.map_or(DEFAULT_CG_TOLERANCE, |(_, t)| t);
        let solver = solver.map_or(SolverName::JacobiCg, |(_, s)| s);
        match kind {
            IntegratorKind::ImplicitEuler => Integrator::ImplicitEuler {
                dt,
                solver: match solver {
                    SolverName::JacobiCg => ImplicitSolver::JacobiCg { cg_tolerance: tolerance },
                    SolverName::CholeskyCg => {
                        ImplicitSolver::CholeskyCg { cg_tolerance: tolerance }
                    }
                    SolverName::Cholesky => ImplicitSolver::Cholesky,
                },
                mass: mass.map_or(MassMatrix::Lumped, |(_, m)| m),
                damping,
            },
            IntegratorKind::Explicit => Integrator::Explicit { dt, rayleigh_alpha: damping.alpha },
            IntegratorKind::Static => Integrator::Static {
                dt,
                tolerance,
                solver: match solver {
                    SolverName::JacobiCg => StaticSolver::JacobiCg,
                    SolverName::CholeskyCg | SolverName::Cholesky => StaticSolver::CholeskyCg,
                },
                damping,
            },
        }
    }

    /// The integrator of a tensor-mass model: no static solve, no sparse factor, no consistent
    /// mass.
    fn tet_integrator(
        &self,
        i: &RawIntegrator,
        keys: IntegratorKeys,
    ) -> Result<TetIntegrator, SceneError> {
        let IntegratorKeys { kind, dt, cg_tolerance, solver, mass, damping } = keys;
        if kind == IntegratorKind::Static {
            return Err(self.invalid(
                i.kind.span(),
                "integrator.kind",
                "\"static\" is for hexahedra; with `model.kind = \"tensor-mass\"` use \"explicit\" (paper 2's central differences) or \"implicit-euler\"",
            ));
        }
        let factor = solver.filter(|(_, s)| *s != SolverName::JacobiCg).map(|(span, _)| span);
        let consistent = mass.filter(|(_, m)| *m == MassMatrix::Consistent).map(|(span, _)| span);
        for (span, key, what) in [
            (factor, "integrator.solver", "a sparse factor"),
            (consistent, "integrator.mass", "a consistent mass matrix"),
        ] {
            if let Some(span) = span {
                return Err(self.invalid(
                    span,
                    key,
                    format!("tensor-mass tetrahedra have no {what}; use the default (`solver = \"jacobi-cg\"`, `mass = \"lumped\"`)"),
                ));
            }
        }
        Ok(match kind {
            IntegratorKind::Explicit => {
                TetIntegrator::Explicit { dt, rayleigh_alpha: damping.alpha }
            }
            _ => TetIntegrator::ImplicitEuler {
                dt,
                cg_tolerance: cg_tolerance.map_or(DEFAULT_CG_TOLERANCE, |(_, t)| t),
                damping,
            },
        })
    }

    /// `[surface]`.
    fn surface(&self, s: Option<&RawSurface>) -> Result<SurfaceSpec, SceneError> {
        let Some(s) = s else { return Ok(SurfaceSpec::default()) };
        let smoothing = match &s.smoothing {
            None => 0,
            Some(n) => {
                let v = *n.get_ref();
                if !(0..=100).contains(&v) {
                    return Err(self.invalid(
                        n.span(),
                        "surface.smoothing",
                        format!("is {v}; it must be between 0 and 100 steps"),
                    ));
                }
                v as u32
            }
        };
        Ok(SurfaceSpec { interfaces: s.interfaces.unwrap_or(false), smoothing })
    }

    /// `[volume_contact]`, against the scene's materials, model and surface.
    fn volume_contact(
        &self,
        raw: Option<&Spanned<RawVolumeContact>>,
        materials: &[MaterialSpec],
        model: &Model,
        surface: SurfaceSpec,
    ) -> Result<Option<VolumeContactSpec>, SceneError> {
        let Some(raw) = raw else { return Ok(None) };
        let at = raw.span();
        let r = raw.get_ref();
        let pressure = match &r.pressure {
            None => VolumeContactSpec::DEFAULT_PRESSURE,
            Some(p) => self.within(p, "volume_contact.pressure", (1.0, 1e12), "N/m³")?,
        };
        let resolution = match &r.resolution {
            None => VolumeContactSpec::DEFAULT_RESOLUTION,
            Some(n) => {
                let v = *n.get_ref();
                if !(1..=1024).contains(&v) {
                    return Err(self.invalid(
                        n.span(),
                        "volume_contact.resolution",
                        format!("is {v}; it must be between 1 and 1024 pixels per side"),
                    ));
                }
                v as usize
            }
        };
        let mut pairs = Vec::new();
        for (k, pair) in
            r.pairs.as_ref().map_or(&[][..], |p| p.get_ref().as_slice()).iter().enumerate()
        {
            let key = format!("volume_contact.pairs[{k}]");
            let [a, b] = *pair.get_ref();
            for l in [a, b] {
                if !materials.iter().any(|m| i64::from(m.label) == l) {
                    let known: Vec<u16> = materials.iter().map(|m| m.label).collect();
                    return Err(self.invalid(
                        pair.span(),
                        &key,
                        format!(
                            "names label {l}, which has no [[materials]] entry (labels: {known:?})"
                        ),
                    ));
                }
            }
            if a == b {
                return Err(self.invalid(
                    pair.span(),
                    &key,
                    format!(
                        "pairs label {a} with itself; a tissue against itself is `self = true`"
                    ),
                ));
            }
            // Both labels are materials' labels, so they fit in u16.
            let labels = [a.min(b) as u16, a.max(b) as u16];
            if pairs.contains(&labels) {
                return Err(self.invalid(
                    pair.span(),
                    &key,
                    format!("repeats the pair {labels:?}"),
                ));
            }
            pairs.push(labels);
        }
        let self_contact = r.self_contact.unwrap_or(false);
        if pairs.is_empty() && !self_contact {
            return Err(self.invalid(
                at,
                "volume_contact",
                "has nothing to do: name tissues in contact with `pairs = [[LABEL, LABEL]]`, or \
                 push a cut's walls apart with `self = true`",
            ));
        }
        if !pairs.is_empty() {
            if let Model::TensorMass(_) = model {
                return Err(self.invalid(
                    r.pairs.as_ref().map_or(at.clone(), Spanned::span),
                    "volume_contact.pairs",
                    "needs hexahedra on a label volume (tensor-mass tetrahedra carry no tissue \
                     labels); `self = true` works on both",
                ));
            }
            if !surface.interfaces {
                return Err(self.invalid(
                    r.pairs.as_ref().map_or(at.clone(), Spanned::span),
                    "volume_contact.pairs",
                    "needs a surface per tissue: add `[surface] interfaces = true`",
                ));
            }
        }
        if matches!(model, Model::Hexahedra(HexSpec { integrator: Integrator::Static { .. }, .. }))
        {
            return Err(self.invalid(
                at,
                "volume_contact",
                "a static scene has no motion for contact to act on; use integrator.kind = \
                 \"implicit-euler\" or \"explicit\"",
            ));
        }
        Ok(Some(VolumeContactSpec { pressure, resolution, pairs, self_contact }))
    }

    /// `[exec]`.
    fn exec(&self, e: Option<&RawExec>) -> Result<ExecSpec, SceneError> {
        let Some(e) = e else { return Ok(ExecSpec::default()) };
        let threads = match &e.threads {
            None => None,
            Some(t) => {
                let n = *t.get_ref();
                if !(1..=MAX_THREADS as i64).contains(&n) {
                    return Err(self.invalid(
                        t.span(),
                        "exec.threads",
                        format!("is {n}; it must be between 1 and {MAX_THREADS}"),
                    ));
                }
                Some(n as usize)
            }
        };
        let idle = match &e.idle {
            None => None,
            Some(i) => Some(match i.get_ref().as_str() {
                "spin" => Idle::DEFAULT_SPIN,
                "sleep" => Idle::Sleep,
                other => {
                    return Err(self.invalid(
                        i.span(),
                        "exec.idle",
                        format!("is \"{other}\"; expected \"spin\" or \"sleep\""),
                    ));
                }
            }),
        };
        Ok(ExecSpec { threads, idle })
    }

    /// A finite number (NaN and infinities are TOML numbers too).
    /// A length unit (`"m"`, the default, `"cm"` or `"mm"`).
    fn unit(&self, u: Option<&Spanned<String>>, key: &str) -> Result<LengthUnit, SceneError> {
        match u.map(|u| (u.span(), u.get_ref().as_str())) {
            None | Some((_, "m")) => Ok(LengthUnit::Metre),
            Some((_, "cm")) => Ok(LengthUnit::Centimetre),
            Some((_, "mm")) => Ok(LengthUnit::Millimetre),
            Some((span, other)) => Err(self.invalid(
                span,
                key,
                format!("is \"{other}\"; expected \"m\", \"cm\" or \"mm\""),
            )),
        }
    }

    fn finite(&self, v: &Spanned<f64>, key: &str) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite")))
        }
    }

    /// Three finite numbers.
    fn finite3(&self, v: &Spanned<[f64; 3]>, key: &str) -> Result<[f64; 3], SceneError> {
        let x = *v.get_ref();
        if x.iter().all(|c| c.is_finite()) {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x:?}; every entry must be finite")))
        }
    }

    /// A number in `[lo, hi]`, with its unit in the message.
    fn within(
        &self,
        v: &Spanned<f64>,
        key: &str,
        (lo, hi): (f64, f64),
        unit: &str,
    ) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if (lo..=hi).contains(&x) {
            Ok(x)
        } else {
            Err(self.invalid(
                v.span(),
                key,
                format!("is {x}; it must be between {lo:e} and {hi:e} {unit}"),
            ))
        }
    }

    fn positive(&self, v: &Spanned<f64>, key: &str) -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite and positive")))
        }
    }

    fn non_negative(
        &self,
        v: Option<&Spanned<f64>>,
        key: &str,
        default: f64,
    ) -> Result<f64, SceneError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        if x.is_finite() && x >= 0.0 {
            Ok(x)
        } else {
            Err(self.invalid(v.span(), key, format!("is {x}; it must be finite and non-negative")))
        }
    }

    /// `[volume]`: a label file (with its `stride`, `merge` and `keep`), a procedural block (with
    /// its `size_m` and `voxels`) or a mesh file (with its `unit`); a key of another kind is
    /// refused rather than ignored.
    fn volume(
        &self,
        v: &Spanned<RawVolume>,
        materials: &[MaterialSpec],
    ) -> Result<Geometry, SceneError> {
        let header = v.span();
        let v = v.get_ref();
        let span = |s: Option<&Spanned<String>>| s.map(Spanned::span);
        let procedural_keys = [
            (span(v.procedural.as_ref()), "volume.procedural"),
            (v.size_m.as_ref().map(Spanned::span), "volume.size_m"),
            (v.voxels.as_ref().map(Spanned::span), "volume.voxels"),
        ];
        let file_keys = [
            (v.stride.as_ref().map(Spanned::span), "volume.stride"),
            (v.labels.as_ref().map(Spanned::span), "volume.labels"),
            (v.merge.as_ref().map(Spanned::span), "volume.merge"),
            (v.keep.as_ref().map(Spanned::span), "volume.keep"),
        ];
        let mesh_keys = [
            (span(v.mesh.as_ref()), "volume.mesh"),
            (span(v.unit.as_ref()), "volume.unit"),
            (span(v.region.as_ref()), "volume.region"),
        ];
        if let Some(path) = &v.file {
            self.refuse(
                &procedural_keys,
                "describes a procedural volume; it cannot be given together with `volume.file`",
            )?;
            self.refuse(
                &mesh_keys,
                "describes a mesh file; it cannot be given together with `volume.file`",
            )?;
            let stride = match &v.stride {
                Some(s) => self.counts(s, "volume.stride", 64)?,
                None => [1, 1, 1],
            };
            let labels = self.label_filter(v, materials)?;
            return Ok(Geometry::Volume(VolumeSpec::File {
                path: path.get_ref().clone(),
                stride,
                labels,
            }));
        }
        if let Some(path) = &v.mesh {
            self.refuse(
                &procedural_keys,
                "describes a procedural volume; it cannot be given together with `volume.mesh`",
            )?;
            self.refuse(
                &file_keys,
                "applies to a volume file; a mesh file has no voxels (its regions are `[[materials]]` labels)",
            )?;
            let unit = self.unit(v.unit.as_ref(), "volume.unit")?;
            let region = match &v.region {
                Some(name) if name.get_ref().trim().is_empty() => {
                    return Err(self.invalid(
                        name.span(),
                        "volume.region",
                        "is empty; name the mesh file's cell-data array that holds the regions",
                    ));
                }
                other => other.as_ref().map(|name| name.get_ref().clone()),
            };
            return Ok(Geometry::Mesh(
                MeshSpec { path: path.get_ref().clone(), unit, region },
                path.span(),
            ));
        }
        let Some(kind) = &v.procedural else {
            return Err(self.invalid(header, "volume", "needs `file`, `procedural` or `mesh`"));
        };
        self.refuse(
            &file_keys,
            "applies to a volume file; a procedural volume has no stride or labels",
        )?;
        self.refuse(&mesh_keys[1..], "applies only to `volume.mesh`")?;
        let organ = match kind.get_ref().as_str() {
            "block" => false,
            "organ" => true,
            other => {
                return Err(self.invalid(
                    kind.span(),
                    "volume.procedural",
                    format!("is \"{other}\"; the known volumes are \"block\" and \"organ\""),
                ));
            }
        };
        let (Some(size), Some(voxels)) = (&v.size_m, &v.voxels) else {
            return Err(self.invalid(
                kind.span(),
                "volume.procedural",
                format!("\"{}\" needs `size_m` and `voxels`", kind.get_ref()),
            ));
        };
        let s = *size.get_ref();
        if !s.iter().all(|&x| x.is_finite() && x > 0.0) {
            return Err(self.invalid(
                size.span(),
                "volume.size_m",
                format!("is {s:?}; every edge must be finite and positive"),
            ));
        }
        let voxels = self.counts(voxels, "volume.voxels", 4096)?;
        Ok(Geometry::Volume(if organ {
            VolumeSpec::Organ { size_m: s, voxels }
        } else {
            VolumeSpec::Block { size_m: s, voxels }
        }))
    }

    /// `volume.merge` (`[from, into]` pairs) and `volume.keep` (or its older name
    /// `volume.labels`): every label merged into or kept must have a material, a label merges
    /// into one other, and a merge does not chain (merges apply once, before `keep`).
    fn label_filter(
        &self,
        v: &RawVolume,
        materials: &[MaterialSpec],
    ) -> Result<LabelFilter, SceneError> {
        let has = |l: u16| materials.iter().any(|m| m.label == l);
        let label = |v: i64, span: Range<usize>, key: &str| {
            u16::try_from(v)
                .ok()
                .filter(|&l| l != 0)
                .ok_or_else(|| self.invalid(span, key, format!("names {v}; labels are 1..=65535")))
        };
        let mut filter = LabelFilter::all();
        let mut merged: Vec<(u16, u16)> = Vec::new();
        for (k, pair) in v.merge.iter().flat_map(|m| m.get_ref().iter()).enumerate() {
            let key = format!("volume.merge[{k}]");
            let [from, into] = *pair.get_ref();
            let (from, into) = (label(from, pair.span(), &key)?, label(into, pair.span(), &key)?);
            let refuse = |message: String| Err(self.invalid(pair.span(), &key, message));
            if from == into {
                return refuse(format!("merges label {from} into itself"));
            }
            if let Some(j) = merged.iter().position(|&(f, _)| f == from) {
                return refuse(format!(
                    "merges label {from} again (`volume.merge[{j}]` merges it into {}); a label merges into one other",
                    merged[j].1
                ));
            }
            if let Some(j) = merged.iter().position(|&(f, i)| f == into || i == from) {
                return refuse(format!(
                    "and `volume.merge[{j}]` ({} into {}) chain, but merges apply once: merge each label straight into the last",
                    merged[j].0, merged[j].1
                ));
            }
            if !has(into) {
                return refuse(format!(
                    "merges {from} into {into}, which no `[[materials]]` entry has"
                ));
            }
            merged.push((from, into));
            filter = filter.merge(from, into);
        }
        let keep = match (&v.keep, &v.labels) {
            (Some(_), Some(labels)) => {
                return Err(self.invalid(
                    labels.span(),
                    "volume.labels",
                    "is the older name of `volume.keep`; give one of them",
                ));
            }
            (Some(keep), None) => Some((keep, "volume.keep")),
            (None, Some(labels)) => Some((labels, "volume.labels")),
            (None, None) => None,
        };
        if let Some((list, key)) = keep {
            if list.get_ref().is_empty() {
                return Err(self.invalid(
                    list.span(),
                    key,
                    "keeps no label; leave it out to keep every label",
                ));
            }
            let mut kept = Vec::with_capacity(list.get_ref().len());
            for l in list.get_ref() {
                let label = label(*l.get_ref(), l.span(), key)?;
                if let Some(&(_, into)) = merged.iter().find(|&&(from, _)| from == label) {
                    return Err(self.invalid(
                        l.span(),
                        key,
                        format!(
                            "keeps {label}, which `volume.merge` merges into {into} first; keep {into}"
                        ),
                    ));
                }
                if !has(label) {
                    return Err(self.invalid(
                        l.span(),
                        key,
                        format!("keeps {label}, which no `[[materials]]` entry has"),
                    ));
                }
                kept.push(label);
            }
            filter = filter.keep(&kept);
        }
        Ok(filter)
    }

    /// `[[fixed]]` entry `k`: a `plane` with its `value`, a box (`min` + `max`) or a `label`;
    /// a key of another kind of region is refused rather than ignored.
    fn fixed(
        &self,
        f: &Spanned<RawFixed>,
        k: usize,
        materials: &[MaterialSpec],
    ) -> Result<FixedSpec, SceneError> {
        let header = f.span();
        let f = f.get_ref();
        let key = |name: &str| format!("fixed[{k}].{name}");
        if let Some(label) = &f.label {
            if let Some((span, name)) = f
                .plane
                .as_ref()
                .map(|v| (v.span(), "plane"))
                .or_else(|| f.value.as_ref().map(|v| (v.span(), "value")))
                .or_else(|| f.min.as_ref().map(|v| (v.span(), "min")))
                .or_else(|| f.max.as_ref().map(|v| (v.span(), "max")))
            {
                return Err(self.invalid(
                    span,
                    &key(name),
                    "cannot be given with `label`: a fixed region is a `plane`, a box (`min` + `max`) or a `label`",
                ));
            }
            let l = *label.get_ref();
            if !materials.iter().any(|m| m.label == l) {
                return Err(self.invalid(
                    label.span(),
                    &key("label"),
                    format!("is {l}, which no `[[materials]]` entry has"),
                ));
            }
            return Ok(FixedSpec::Label { label: l });
        }
        if let Some(axis) = &f.plane {
            if let Some((span, name)) = f
                .min
                .as_ref()
                .map(|v| (v.span(), "min"))
                .or_else(|| f.max.as_ref().map(|v| (v.span(), "max")))
            {
                return Err(self.invalid(
                    span,
                    &key(name),
                    "cannot be given with `plane`: a plane region is `plane` + `value`",
                ));
            }
            let a = match axis.get_ref().as_str() {
                "x" => 0,
                "y" => 1,
                "z" => 2,
                other => {
                    return Err(self.invalid(
                        axis.span(),
                        &key("plane"),
                        format!("is \"{other}\"; expected \"x\", \"y\" or \"z\""),
                    ));
                }
            };
            let Some(value) = &f.value else {
                return Err(self.invalid(axis.span(), &key("plane"), "needs a `value` (m)"));
            };
            return Ok(FixedSpec::Plane { axis: a, value: self.finite(value, &key("value"))? });
        }
        if let Some(value) = &f.value {
            return Err(self.invalid(
                value.span(),
                &key("value"),
                "needs `plane` (the axis the value is a coordinate on)",
            ));
        }
        match (&f.min, &f.max) {
            (Some(min), Some(max)) => {
                let lo = self.finite3(min, &key("min"))?;
                let hi = self.finite3(max, &key("max"))?;
                if (0..3).any(|a| hi[a] < lo[a]) {
                    return Err(self.invalid(
                        max.span(),
                        &key("max"),
                        format!("{hi:?} is below `min` {lo:?}"),
                    ));
                }
                Ok(FixedSpec::Box { min: lo, max: hi })
            }
            (Some(min), None) => {
                Err(self.invalid(min.span(), &key("min"), "needs `max`: a box is `min` + `max`"))
            }
            (None, Some(max)) => {
                Err(self.invalid(max.span(), &key("max"), "needs `min`: a box is `min` + `max`"))
            }
            (None, None) => Err(self.invalid(
                header,
                &format!("fixed[{k}]"),
                "needs `plane` + `value`, `min` + `max`, or `label`",
            )),
        }
    }

    fn counts(&self, v: &Spanned<[i64; 3]>, key: &str, max: i64) -> Result<[usize; 3], SceneError> {
        let a = *v.get_ref();
        if a.iter().all(|&n| (1..=max).contains(&n)) {
            Ok(a.map(|n| n as usize))
        } else {
            Err(self.invalid(
                v.span(),
                key,
                format!("is {a:?}; each entry must be between 1 and {max}"),
            ))
        }
    }
}

impl SceneConfig {
    /// Parses and checks a scene; `file` names the text in errors.
    pub fn from_toml(text: &str, file: &str) -> Result<Self, SceneError> {
        let raw: RawScene = toml::from_str(text).map_err(|e| SceneError::Parse {
            file: file.to_owned(),
            line: e.span().map_or(0, |s| line_of(text, s.start)),
            message: e.message().trim().to_owned(),
        })?;
        let c = Checker { text, file };
        let materials = c.materials(raw.materials.as_ref())?;
        let model = c.model(&raw, &materials)?;
        let exec = c.exec(raw.exec.as_ref())?;
        let mut fixed = Vec::new();
        for (k, f) in raw.fixed.iter().enumerate() {
            fixed.push(c.fixed(f, k, &materials)?);
        }
        let mut loads = Vec::new();
        for (k, l) in raw.loads.iter().enumerate() {
            loads.push(PatchLoad {
                centre: c.finite3(&l.centre, &format!("loads[{k}].centre"))?,
                radius: c.positive(&l.radius, &format!("loads[{k}].radius"))?,
                force: c.finite3(&l.force, &format!("loads[{k}].force"))?,
            });
        }
        let gravity = match &raw.gravity {
            Some(g) => c.finite3(g, "gravity")?,
            None => [0.0, 0.0, -9.81],
        };
        let tools = c.tools(&raw.tools)?;
        let surface = c.surface(raw.surface.as_ref())?;
        let volume_contact =
            c.volume_contact(raw.volume_contact.as_ref(), &materials, &model, surface)?;
        let gpu = match &raw.gpu {
            None => GpuSetting::Off,
            Some(g) => match g.get_ref().as_str() {
                "off" => GpuSetting::Off,
                "auto" => GpuSetting::Auto,
                "on" => GpuSetting::On,
                other => {
                    return Err(c.invalid(
                        g.span(),
                        "gpu",
                        format!("is \"{other}\"; expected \"auto\", \"on\" or \"off\""),
                    ));
                }
            },
        };
        Ok(Self {
            name: raw.name,
            model,
            materials,
            gravity,
            fixed,
            loads,
            exec,
            tools,
            surface,
            volume_contact,
            gpu,
        })
    }
}
