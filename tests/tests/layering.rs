//! The workspace's layering, checked on the dependency graph `cargo metadata` resolves:
//! - the physics crates build without any heavy crate (async runtimes, transports, recorders,
//!   GPU), so they stay quick to build and usable without a network or a device;
//! - the geometry and file-format crates do not depend on mechanics, so a mesh or a volume can be
//!   read without building the solvers.
//!
//! Later crates join the lists where they belong; a crate missing from the workspace is skipped,
//! so the lists may name crates that are still to come.
//!
//! The same graph's licences: every package the workspace builds offers a licence `deny.toml`
//! allows, and the names built in two versions are listed.

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

/// The workspace's resolved graph, as `cargo metadata` prints it.
fn metadata() -> Value {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata runs");
    assert!(out.status.success(), "cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("cargo metadata prints JSON")
}

/// Every workspace package's name → the names of everything it depends on at run time
/// (normal dependencies, transitively; build and dev dependencies left out).
fn runtime_closure() -> BTreeMap<String, BTreeSet<String>> {
    let meta = metadata();
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

/// The licences `deny.toml` allows.
fn allowed_licences() -> BTreeSet<String> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deny.toml");
    let text = std::fs::read_to_string(&path).expect("deny.toml at the workspace's root");
    let deny: toml::Table = toml::from_str(&text).expect("deny.toml is TOML");
    deny["licenses"]["allow"]
        .as_array()
        .expect("licenses.allow")
        .iter()
        .map(|l| l.as_str().expect("a licence name").to_owned())
        .collect()
}

/// Whether the SPDX expression `expr` (`AND`, `OR`, `WITH`, parentheses, and the old `/` for
/// `OR`) can be met with `allowed` licences alone. `None`: not an expression it can read.
fn licence_allowed(expr: &str, allowed: &BTreeSet<String>) -> Option<bool> {
    let spaced = expr.replace('(', " ( ").replace(')', " ) ").replace('/', " OR ");
    let tokens: Vec<&str> = spaced.split_whitespace().collect();
    let mut at = 0;
    let value = or_expr(&tokens, &mut at, allowed)?;
    (at == tokens.len()).then_some(value)
}

fn or_expr(tokens: &[&str], at: &mut usize, allowed: &BTreeSet<String>) -> Option<bool> {
    let mut value = and_expr(tokens, at, allowed)?;
    while tokens.get(*at) == Some(&"OR") {
        *at += 1;
        value |= and_expr(tokens, at, allowed)?;
    }
    Some(value)
}

fn and_expr(tokens: &[&str], at: &mut usize, allowed: &BTreeSet<String>) -> Option<bool> {
    let mut value = term(tokens, at, allowed)?;
    while tokens.get(*at) == Some(&"AND") {
        *at += 1;
        value &= term(tokens, at, allowed)?;
    }
    Some(value)
}

fn term(tokens: &[&str], at: &mut usize, allowed: &BTreeSet<String>) -> Option<bool> {
    let token = *tokens.get(*at)?;
    *at += 1;
    if token == "(" {
        let value = or_expr(tokens, at, allowed)?;
        (tokens.get(*at) == Some(&")")).then(|| *at += 1)?;
        return Some(value);
    }
    if ["AND", "OR", "WITH", ")"].contains(&token) {
        return None;
    }
    if tokens.get(*at) == Some(&"WITH") {
        let exception = tokens.get(*at + 1)?;
        *at += 2;
        return Some(allowed.contains(&format!("{token} WITH {exception}")));
    }
    Some(allowed.contains(token))
}

#[test]
fn every_package_has_an_allowed_licence() {
    let meta = metadata();
    let allowed = allowed_licences();
    let packages = meta["packages"].as_array().expect("packages");
    let refused: Vec<String> = packages
        .iter()
        .filter_map(|p| {
            let licence = p["license"].as_str().unwrap_or("(none given)");
            let ok = licence_allowed(licence, &allowed) == Some(true);
            (!ok).then(|| format!("{} {}: {licence}", p["name"], p["version"]))
        })
        .collect();
    let mut versions: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    for p in packages {
        let (name, version) =
            (p["name"].as_str().expect("name"), p["version"].as_str().expect("v"));
        versions.entry(name).or_default().insert(version);
    }
    let twice: Vec<String> = versions
        .iter()
        .filter(|(_, v)| v.len() > 1)
        .map(|(n, v)| format!("{n} {}", v.iter().copied().collect::<Vec<_>>().join(", ")))
        .collect();
    println!(
        "{} packages; {} names in two or more versions:\n  {}",
        packages.len(),
        twice.len(),
        twice.join("\n  ")
    );
    assert!(refused.is_empty(), "licences deny.toml does not allow:\n{}", refused.join("\n"));
}

#[test]
fn the_licence_check_refuses_what_is_not_allowed() {
    let allowed: BTreeSet<String> =
        ["MIT", "Apache-2.0", "Apache-2.0 WITH LLVM-exception"].map(str::to_owned).into();
    for (expr, want) in [
        ("MIT", Some(true)),
        ("GPL-3.0-only", Some(false)),
        ("MIT OR GPL-3.0-only", Some(true)),
        ("MIT/Apache-2.0", Some(true)),
        ("(MIT OR Apache-2.0) AND GPL-3.0-only", Some(false)),
        ("(MIT OR Apache-2.0) AND Apache-2.0", Some(true)),
        ("Apache-2.0 WITH LLVM-exception OR GPL-3.0-only", Some(true)),
        ("GPL-2.0-only WITH Classpath-exception-2.0", Some(false)),
        ("MIT AND", None),
        ("(MIT", None),
    ] {
        assert_eq!(licence_allowed(expr, &allowed), want, "{expr}");
    }
}
