//! Cross-crate tests of incise live in `tests/tests/*.rs`; this library only holds the path to the
//! committed fixtures so every test finds them whatever its working directory.

use std::path::PathBuf;

/// Absolute path of a committed fixture in `tests/data/`.
#[must_use]
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data").join(name)
}

/// Absolute path of a committed scene file in `deploy/scenes/`.
#[must_use]
pub fn scene(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("deploy").join("scenes").join(name)
}
