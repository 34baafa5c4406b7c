//! The library guide's Rust example (`docs/library.md`) runs, and the guide shows it as it is.

#[path = "../examples/quickstart.rs"]
mod quickstart;

#[test]
fn the_library_guides_example_runs_from_the_repository_root() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    // The example's paths are relative to the root, where the guide says to run it (this is the
    // only test in this binary, so changing the directory affects no other).
    std::env::set_current_dir(root).unwrap();
    quickstart::main().unwrap();
}

#[test]
fn the_library_guide_shows_the_example_as_it_is() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    let guide = std::fs::read_to_string(format!("{root}/docs/library.md")).unwrap();
    let example = include_str!("../examples/quickstart.rs");
    let code: String =
        example.lines().skip_while(|l| l.starts_with("//!")).collect::<Vec<_>>().join("\n");
    assert!(guide.contains(&code), "docs/library.md's example differs from examples/quickstart.rs");
}
