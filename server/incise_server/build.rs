//! Names the git revision the server is built from (`INCISE_GIT_REVISION`), which its scene
//! description and recordings carry; empty outside a git checkout.

fn main() {
    let revision = std::process::Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .unwrap_or_default();
    println!("cargo:rustc-env=INCISE_GIT_REVISION={revision}");
    // A new commit changes HEAD's target; a checkout changes HEAD itself.
    println!("cargo:rerun-if-changed=../../.git/HEAD");
    println!("cargo:rerun-if-changed=../../.git/refs/heads");
}
