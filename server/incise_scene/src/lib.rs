//! Scene files from disk: a TOML scene (`incise_sim::SceneConfig`, validated with the key and
//! line of every error) and the geometry it names, read relative to the scene file's folder by
//! `incise_io`: a label volume (procedural volumes are built in memory) or a tetrahedral mesh.
//!
//! This is the one place where mechanics configuration meets files, so that `incise_sim` stays
//! pure and `incise_io` knows only geometry.

pub mod environment;

use incise_grid::LabelVolume;
use incise_io::{IoError, MeshOptions};
use incise_mesh::TetMesh;
use incise_sim::config::{Model, ShapeSpec, TetSource, VolumeSpec};
use incise_sim::{Geometry, SceneConfig};
use incise_tool::Shape;
use std::path::Path;

/// The embedded scene: an 8 × 6 × 5 cm organ (6 kPa) holding a stiffer tumour (40 kPa),
/// resting on its held base, at level 2 (2.5 mm voxels, 1 cm elements) stepped implicitly at
/// 1 ms; a scalpel whose blade sits just inside its narrow outer shape (it pushes, then cuts
/// once pressed in) and a grasper whose jaws reach 1 cm from its hinge, where a small ball
/// touches the tissue.
pub const DEMO_SCENE: &str = r#"name = "demo_organ"
level = 2
gravity = [0.0, 0.0, -9.81]

[volume]
procedural = "organ"
size_m = [0.08, 0.06, 0.05]
voxels = [32, 24, 20]

[[materials]]
label = 1
youngs_modulus = 6000.0
poisson_ratio = 0.45
density = 1060.0

[[materials]]
label = 2
youngs_modulus = 40000.0
poisson_ratio = 0.45
density = 1060.0

[model]
kind = "corotational"

[integrator]
kind = "implicit-euler"
dt = 0.001
rayleigh_alpha = 2.0
rayleigh_beta = 0.01

[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 0.01]

[[tools]]
name = "scalpel"
stiffness = 50.0
cutting = "remove"
# The organ is soft: pressed 2 mm its top pushes back with about a tenth of a newton, 6 mm in
# with a few tenths; the blade cuts between the two.
cut_force = 0.3
outer = { shape = "box", half_extents = [0.006, 0.002, 0.008], offset = [0.0, 0.0, 0.008] }
inner = { shape = "blade", length = 0.012, height = 0.014, thickness = 0.0035, offset = [0.0, 0.0, 0.0005] }

[[tools]]
name = "grasper"
stiffness = 200.0
outer = { shape = "sphere", radius = 0.002 }

[tools.jaws]
length = 0.01
width = 0.008
close_below = 0.05
open_above = 0.3
stiffness = 300.0
"#;

/// Why a scene file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SceneFileError {
    /// The scene file itself could not be read.
    #[error("{file}: {source}")]
    Read {
        /// The scene file.
        file: String,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The scene file is not a valid scene (the message names the line and key).
    #[error("{0}")]
    Scene(#[from] incise_sim::SceneError),
    /// The volume or mesh the scene names could not be read (the message names that file).
    #[error("{0}")]
    Volume(#[from] IoError),
    /// An environment variable that overrides the scene holds something it does not take.
    #[error("{0}")]
    Environment(#[from] environment::EnvironmentError),
}

/// A scene file as read: its configuration and the geometry it is built on, as the file holds it
/// (the label filter, stride and mesh unit are applied by [`incise_sim::Simulation::new`]).
#[derive(Clone, Debug)]
pub struct Scene {
    /// The checked configuration.
    pub config: SceneConfig,
    /// The label volume or tetrahedral mesh it names.
    pub geometry: SceneGeometry,
    /// What the user should know about how the geometry was read (cells of a mesh file that
    /// are not tetrahedra and were skipped, where the regions came from); one sentence each.
    pub notes: Vec<String>,
}

/// The geometry a scene file names.
#[derive(Clone, Debug)]
pub enum SceneGeometry {
    /// A label volume (a file's, or a procedural block's).
    Volume(LabelVolume),
    /// A tetrahedral mesh (`volume.mesh`).
    Mesh(TetMesh),
}

impl<'a> From<&'a SceneGeometry> for Geometry<'a> {
    fn from(geometry: &'a SceneGeometry) -> Self {
        match geometry {
            SceneGeometry::Volume(volume) => Geometry::Volume(volume),
            SceneGeometry::Mesh(mesh) => Geometry::Mesh(mesh),
        }
    }
}

impl SceneGeometry {
    /// The label volume (`None` for a mesh).
    #[must_use]
    pub fn volume(&self) -> Option<&LabelVolume> {
        match self {
            Self::Volume(volume) => Some(volume),
            Self::Mesh(_) => None,
        }
    }

    /// The mesh (`None` for a label volume).
    #[must_use]
    pub fn mesh(&self) -> Option<&TetMesh> {
        match self {
            Self::Mesh(mesh) => Some(mesh),
            Self::Volume(_) => None,
        }
    }
}

/// Reads a scene file and the volume or mesh it names.
pub fn read_scene(path: &Path) -> Result<Scene, SceneFileError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|source| SceneFileError::Read { file: file.clone(), source })?;
    scene_from_toml(&text, &file, path.parent().unwrap_or_else(|| Path::new(".")))
}

/// A scene from its TOML `text` (named `file` in messages), with the files it names read
/// relative to `base`: what a recording's stored scene replays from.
pub fn scene_from_toml(text: &str, file: &str, base: &Path) -> Result<Scene, SceneFileError> {
    let mut config = SceneConfig::from_toml(text, file)?;
    config.exec = environment::exec_from_environment(config.exec)?;
    let file = file.to_owned();
    load_tool_meshes(&mut config, base, &file)?;
    let mut notes = Vec::new();
    let geometry = match &config.model {
        Model::TensorMass(tm) => match &tm.source {
            TetSource::Mesh(mesh) => {
                let mesh_path = base.join(&mesh.path);
                let options = MeshOptions { region: mesh.region.clone() };
                let read = incise_io::read_tet_mesh_with(&mesh_path, &options)?;
                let shown = mesh_path.display();
                notes.push(match &read.region_source {
                    Some(source) => format!("{shown}: regions from {source}"),
                    None => format!(
                        "{shown}: the file gives no regions; every tetrahedron is in region 1"
                    ),
                });
                notes.extend(read.skipped_note().map(|note| format!("{shown}: {note}")));
                SceneGeometry::Mesh(read.mesh)
            }
            TetSource::Volume { volume, .. } => volume_of(&config, volume, base)?,
        },
        Model::Hexahedra(hex) => volume_of(&config, &hex.volume, base)?,
    };
    Ok(Scene { config, geometry, notes })
}

/// Reads the tools' mesh files (relative to `base`) into their shapes.
fn load_tool_meshes(
    config: &mut SceneConfig,
    base: &Path,
    file: &str,
) -> Result<(), SceneFileError> {
    for tool in &mut config.tools {
        let name = tool.name.clone();
        for (which, spec) in [("outer", Some(&mut tool.outer)), ("inner", tool.inner.as_mut())] {
            let Some(spec) = spec else { continue };
            let ShapeSpec::Mesh { path, unit, offset } = spec else { continue };
            let mesh = incise_io::read_tri_mesh(&base.join(&*path))?;
            let mesh = mesh.scaled(1.0 / unit.per_metre());
            let shape = Shape::mesh(&mesh, *offset).map_err(|e| {
                SceneFileError::Scene(incise_sim::SceneError::Build {
                    file: file.to_owned(),
                    message: format!("tool {name:?}: its {which} mesh {path}: {e}"),
                })
            })?;
            *spec = ShapeSpec::Shape(shape);
        }
    }
    Ok(())
}

/// The label volume `volume` describes: built when procedural, read relative to `base` when a
/// file.
fn volume_of(
    config: &SceneConfig,
    volume: &VolumeSpec,
    base: &Path,
) -> Result<SceneGeometry, IoError> {
    Ok(SceneGeometry::Volume(match volume {
        VolumeSpec::File { path, .. } => incise_io::read_volume(&base.join(path))?,
        VolumeSpec::Block { .. } | VolumeSpec::Organ { .. } => {
            config.procedural_volume().expect("a block or an organ is a procedural volume")
        }
    }))
}

/// Gives `sim` the GPU its scene's `gpu` key asks for (`"auto"`: a hardware adapter; `"on"`:
/// any, a software one included), when the scene has volume contact; otherwise, or when there is
/// no such adapter, it stays on the CPU (never a failure). Returns what happened, for the log:
/// `None` when the scene asked for nothing.
pub fn attach_gpu(sim: &mut incise_sim::Simulation) -> Option<String> {
    use incise_sim::config::GpuSetting;
    let setting = sim.config().gpu;
    if setting == GpuSetting::Off || sim.config().volume_contact.is_none() {
        return None;
    }
    let key = match setting {
        GpuSetting::On => "gpu = \"on\"",
        _ => "gpu = \"auto\"",
    };
    #[cfg(feature = "gpu")]
    {
        let choice = match setting {
            GpuSetting::On => incise_gpu::GpuChoice::On,
            _ => incise_gpu::GpuChoice::Auto,
        };
        match incise_gpu::GpuContact::new(choice) {
            Ok(device) => {
                let name = incise_tool::volume_contact::ContactDevice::name(&device);
                sim.set_contact_device(Box::new(device));
                Some(format!("{key}: volume contact on the GPU {name}"))
            }
            Err(e) => Some(format!("{key}: {e}; volume contact on the CPU")),
        }
    }
    #[cfg(not(feature = "gpu"))]
    {
        Some(format!(
            "{key}: this build has no GPU support (incise_scene's `gpu` feature); volume contact \
             on the CPU"
        ))
    }
}
