//! What the tests that run Python share: a venv under `target/` with a requirements file
//! installed, made once.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A Python with `requirements` (relative to the root) installed: `INCISE_PYTHON` when set (an
/// interpreter that already has them), else the venv `target/<venv>`, made on first use.
pub fn python(venv: &str, requirements: &str) -> PathBuf {
    if let Some(p) = std::env::var_os("INCISE_PYTHON") {
        return p.into();
    }
    let venv = root().join("target").join(venv);
    let python = venv.join("bin/python");
    let ready = venv.join(".requirements-installed");
    let wanted = std::fs::read_to_string(root().join(requirements)).unwrap();
    if std::fs::read_to_string(&ready).ok().as_deref() != Some(wanted.as_str()) {
        let made = Command::new("python3").arg("-m").arg("venv").arg(&venv).status().unwrap();
        assert!(made.success(), "python3 -m venv failed");
        let installed = Command::new(&python)
            .args(["-m", "pip", "install", "--quiet", "-r"])
            .arg(root().join(requirements))
            .status()
            .unwrap();
        assert!(installed.success(), "pip install -r {requirements} failed");
        std::fs::write(&ready, wanted).unwrap();
    }
    python
}
