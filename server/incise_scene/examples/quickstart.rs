//! The library guide's example (`docs/library.md`): read a scene, build a `Simulation`, step it,
//! cut it, step on.
//! `cargo run --release -p incise_scene --example quickstart`
use incise_grid::GridEdit;
use incise_sim::{Simulation, StepInputs};

/// Steps the liver for 0.2 s, cuts it, and steps once more.
pub fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::path::Path::new("deploy/scenes/liver_13k.toml"); // the liver CT, level 3
    let scene = incise_scene::read_scene(path)?;
    let mut sim = Simulation::new(&scene.config, &scene.geometry, &path.display().to_string())?;
    for _ in 0..200 {
        sim.step(&StepInputs::default())?; // 1 ms each: the liver sags under gravity
    }
    let grid = sim.grid().expect("a hexahedral scene");
    let cut: Vec<u32> = grid
        .top()
        .elements()
        .step_by(4) // every fourth element loses
        .flat_map(|(id, _)| grid.element_voxels(id).into_iter().take(2)) // two of its voxels
        .collect();
    let changes = sim.cut(&GridEdit { remove_voxels: cut, sever_links: vec![] })?;
    let frame = sim.step(&StepInputs::default())?;
    println!(
        "t = {:.3} s: the cut changed {} elements; state hash {:016x}",
        frame.time,
        changes.top.elements_changed.len(),
        frame.state_hash
    );
    Ok(())
}
