//! TOML scene files: the `SceneConfig` of `incise_sim` plus the label volume it names, read
//! relative to the scene file's folder (procedural volumes are built in memory).

use crate::error::IoError;
use incise_grid::LabelVolume;
use incise_sim::SceneConfig;
use incise_sim::config::VolumeSpec;
use std::path::Path;

/// Reads a scene file and its volume.
pub fn read_scene(path: &Path) -> Result<(SceneConfig, LabelVolume), IoError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|source| IoError::Io { file: file.clone(), source })?;
    let config = SceneConfig::from_toml(&text, &file)
        .map_err(|source| IoError::Scene { file: file.clone(), source })?;
    let volume = match (&config.volume, config.procedural_volume()) {
        (_, Some(v)) => v,
        (VolumeSpec::File { path: rel, .. }, None) => {
            let base = path.parent().unwrap_or_else(|| Path::new("."));
            crate::read_volume(&base.join(rel))?
        }
        (VolumeSpec::Block { .. }, None) => return Err(IoError::UnknownFormat { file }),
    };
    Ok((config, volume))
}
