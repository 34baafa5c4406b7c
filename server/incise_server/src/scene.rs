//! The scene a server runs: a scene file, or the embedded demo organ (no files needed).

use anyhow::Context;
use incise_scene::{Scene, SceneGeometry};
use incise_sim::config::{Model, SceneConfig, ShapeSpec, TetSource, VolumeSpec};
use std::path::Path;

/// The largest file (bytes) a recording stores beside its scene: the liver CT fixture is 100 KB,
/// a typical segmented organ a few MB; a larger one is left out (and named in the log), and a
/// replay reads it from `--scene-dir`.
pub const STORED_FILE_LIMIT: u64 = 16 << 20;

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

/// The scene at `path`, or the embedded one.
pub fn load(path: Option<&Path>) -> anyhow::Result<Scene> {
    if let Some(path) = path {
        return incise_scene::read_scene(path)
            .with_context(|| format!("cannot load the scene {}", path.display()));
    }
    let config = SceneConfig::from_toml(DEMO_SCENE, "<embedded demo scene>")
        .context("the embedded scene")?;
    let volume = config.procedural_volume().context("the embedded scene is procedural")?;
    Ok(Scene { config, geometry: SceneGeometry::Volume(volume), notes: Vec::new() })
}

/// The files `config` reads (its volume or mesh, its tools' meshes) as written in the scene,
/// with their bytes read from `base`, to store in a recording so that it replays on its own;
/// files over [`STORED_FILE_LIMIT`] or unreadable are left out with a warning.
#[must_use]
pub fn stored_files(config: &SceneConfig, base: &Path) -> Vec<(String, Vec<u8>)> {
    fn volume(v: &VolumeSpec) -> Option<&str> {
        match v {
            VolumeSpec::File { path, .. } => Some(path.as_str()),
            _ => None,
        }
    }
    let mut paths: Vec<&str> = Vec::new();
    match &config.model {
        Model::Hexahedra(h) => paths.extend(volume(&h.volume)),
        Model::TensorMass(t) => match &t.source {
            TetSource::Volume { volume: v, .. } => paths.extend(volume(v)),
            TetSource::Mesh(m) => paths.push(&m.path),
        },
    }
    for tool in &config.tools {
        for shape in std::iter::once(&tool.outer).chain(&tool.inner) {
            if let ShapeSpec::Mesh { path, .. } = shape {
                paths.push(path);
            }
        }
    }
    paths.sort_unstable();
    paths.dedup();
    paths
        .into_iter()
        .filter_map(|p| {
            let file = base.join(p);
            match std::fs::metadata(&file) {
                Ok(m) if m.len() <= STORED_FILE_LIMIT => match std::fs::read(&file) {
                    Ok(bytes) => return Some((p.to_owned(), bytes)),
                    Err(e) => tracing::warn!("{}: not stored in the recording: {e}", file.display()),
                },
                Ok(m) => tracing::warn!(
                    "{}: {} MB, not stored in the recording (over {} MB); replay it with --scene-dir",
                    file.display(),
                    m.len() >> 20,
                    STORED_FILE_LIMIT >> 20
                ),
                Err(e) => tracing::warn!("{}: not stored in the recording: {e}", file.display()),
            }
            None
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_embedded_scene_loads_with_its_two_tools_and_two_tissues() {
        let scene = super::load(None).unwrap();
        assert_eq!(scene.config.tools.len(), 2);
        assert_eq!(scene.config.materials.len(), 2);
        let SceneGeometry::Volume(v) = &scene.geometry else { panic!("a volume") };
        let labels: std::collections::BTreeSet<u16> = v.labels().iter().copied().collect();
        assert_eq!(labels.into_iter().collect::<Vec<_>>(), [0, 1, 2]);
    }
    use super::*;
}
