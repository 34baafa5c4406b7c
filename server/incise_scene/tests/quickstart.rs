//! The README's Rust example runs, and the README shows it as it is.

#[path = "../examples/quickstart.rs"]
mod quickstart;

#[test]
fn the_readme_example_runs_from_the_repository_root() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    // The example's paths are relative to the root, where the README says to run it (this is the
    // only test in this binary, so changing the directory affects no other).
    std::env::set_current_dir(root).unwrap();
    quickstart::main().unwrap();
}

#[test]
fn the_readme_shows_the_example_as_it_is() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    let readme = std::fs::read_to_string(format!("{root}/README.md")).unwrap();
    let example = include_str!("../examples/quickstart.rs");
    let code: String =
        example.lines().skip_while(|l| l.starts_with("//!")).collect::<Vec<_>>().join("\n");
    assert!(readme.contains(&code), "README.md's example differs from examples/quickstart.rs");
}
