//! Scene files from disk: a TOML scene (`incise_sim::SceneConfig`, validated with the key and
//! line of every error) and the label volume it names, read relative to the scene file's folder
//! by `incise_io` (procedural volumes are built in memory).
//!
//! This is the one place where mechanics configuration meets files, so that `incise_sim` stays
//! pure and `incise_io` knows only geometry.

use incise_grid::LabelVolume;
use incise_io::IoError;
use incise_sim::SceneConfig;
use incise_sim::config::VolumeSpec;
use std::path::Path;

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
    /// The volume the scene names could not be read (the message names that file).
    #[error("{0}")]
    Volume(#[from] IoError),
}

/// Reads a scene file and its volume.
pub fn read_scene(path: &Path) -> Result<(SceneConfig, LabelVolume), SceneFileError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|source| SceneFileError::Read { file: file.clone(), source })?;
    let config = SceneConfig::from_toml(&text, &file)?;
    let volume = match (&config.volume, config.procedural_volume()) {
        (_, Some(v)) => v,
        (VolumeSpec::File { path: rel, .. }, None) => {
            let base = path.parent().unwrap_or_else(|| Path::new("."));
            incise_io::read_volume(&base.join(rel))?
        }
        (VolumeSpec::Block { .. }, None) => {
            return Err(IoError::UnknownFormat { file }.into());
        }
    };
    Ok((config, volume))
}
