//! The workspace's layering, checked on the dependency graph `cargo metadata` resolves:
//! - the physics crates build without any heavy crate (async runtimes, transports, recorders,
//!   GPU), so they stay quick to build and usable without a network or a device;
//! - the geometry and file-format crates do not depend on mechanics, so a mesh or a volume can be
//!   read without building the solvers.
//!
//! Later crates join the lists where they belong; a crate missing from the workspace is skipped,
//! so the lists may name crates that are still to come.

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};

/// Pure physics: data in, data out.
const PHYSICS: &[&str] = &[
    "incise_math",
    "incise_grid",
    "incise_mesh",
    "incise_fem",
    "incise_sim",
    "incise_surface",
    "incise_tool",
    "incise_haptics",
];

/// Geometry and file formats.
const GEOMETRY_AND_IO: &[&str] =
    &["incise_math", "incise_grid", "incise_mesh", "incise_surface", "incise_io"];

/// Crates the physics must never pull in, directly or through another crate.
const HEAVY: &[&str] = &["tokio", "zenoh", "iceoryx2", "mcap", "rerun", "wgpu"];

/// Mechanics: what geometry and I/O must not depend on.
const MECHANICS: &[&str] = &["incise_fem", "incise_sim", "incise_tool", "incise_haptics"];

/// Every workspace package's name → the names of everything it depends on at run time
/// (normal dependencies, transitively; build and dev dependencies left out).
fn runtime_closure() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata runs");
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    let meta: Value = serde_json::from_slice(&out.stdout).expect("cargo metadata prints JSON");
    let name_of: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .expect("packages")
        .iter()
        .map(|p| (p["id"].as_str().expect("id"), p["name"].as_str().expect("name")))
        .collect();
    // Normal (run-time) edges of the resolved graph.
    let mut edges: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().expect("a resolved graph") {
        let id = node["id"].as_str().expect("id");
        let deps = node["deps"].as_array().expect("deps").iter().filter(|d| {
            d["dep_kinds"].as_array().expect("dep_kinds").iter().any(|k| k["kind"].is_null())
        });
        edges.insert(id, deps.map(|d| d["pkg"].as_str().expect("pkg")).collect());
    }
    let members = meta["workspace_members"].as_array().expect("workspace members");
    members
        .iter()
        .map(|m| {
            let root = m.as_str().expect("member id");
            let mut seen = BTreeSet::new();
            let mut stack = vec![root];
            while let Some(id) = stack.pop() {
                for &dep in edges.get(id).map_or(&[][..], Vec::as_slice) {
                    if seen.insert(dep) {
                        stack.push(dep);
                    }
                }
            }
            (name_of[root].to_owned(), seen.into_iter().map(|id| name_of[id].to_owned()).collect())
        })
        .collect()
}

/// Which of `crates` (present in the workspace) reach one of `forbidden`, with what they reach.
fn violations(
    closure: &BTreeMap<String, BTreeSet<String>>,
    crates: &[&str],
    forbidden: &[&str],
) -> Vec<String> {
    crates
        .iter()
        .filter_map(|c| closure.get(*c).map(|deps| (c, deps)))
        .filter_map(|(c, deps)| {
            let bad: Vec<&str> =
                forbidden.iter().copied().filter(|f| deps.contains(*f) && f != c).collect();
            (!bad.is_empty()).then(|| format!("{c} depends on {}", bad.join(", ")))
        })
        .collect()
}

#[test]
fn physics_crates_depend_on_no_heavy_crate() {
    let closure = runtime_closure();
    assert!(closure.contains_key("incise_fem"), "the workspace has its physics crates");
    let bad = violations(&closure, PHYSICS, HEAVY);
    assert!(bad.is_empty(), "{bad:?}");
}

#[test]
fn geometry_and_io_crates_do_not_depend_on_mechanics() {
    let closure = runtime_closure();
    assert!(closure.contains_key("incise_io"), "the workspace has its file-format crate");
    let bad = violations(&closure, GEOMETRY_AND_IO, MECHANICS);
    assert!(bad.is_empty(), "{bad:?}");
}

#[test]
fn the_check_sees_a_violation_where_there_is_one() {
    // The scene loader joins mechanics and files: it must show up as depending on mechanics, or
    // the closure above would be missing edges.
    let closure = runtime_closure();
    let bad = violations(&closure, &["incise_scene"], MECHANICS);
    assert_eq!(bad, ["incise_scene depends on incise_fem, incise_sim, incise_tool".to_owned()]);
}
