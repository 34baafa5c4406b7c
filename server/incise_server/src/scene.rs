//! The scene a server runs: a scene file, or the embedded demo organ (no files needed).

use anyhow::Context;
use incise_scene::{Scene, SceneGeometry};
use incise_sim::config::{Model, SceneConfig, ShapeSpec, TetSource, VolumeSpec};
use std::path::Path;

/// The largest file (bytes) a recording stores beside its scene: the liver CT fixture is 100 KB,
/// a typical segmented organ a few MB; a larger one is left out (and named in the log), and a
/// replay reads it from `--scene-dir`.
pub const STORED_FILE_LIMIT: u64 = 16 << 20;

/// The embedded scene (`incise_scene::DEMO_SCENE`).
pub use incise_scene::DEMO_SCENE;

/// The scene at `path`, or the embedded one.
pub fn load(path: Option<&Path>) -> anyhow::Result<Scene> {
    if let Some(path) = path {
        return incise_scene::read_scene(path)
            .with_context(|| format!("cannot load the scene {}", path.display()));
    }
    let mut config = SceneConfig::from_toml(DEMO_SCENE, "<embedded demo scene>")
        .context("the embedded scene")?;
    config.exec = incise_scene::environment::exec_from_environment(config.exec)?;
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
