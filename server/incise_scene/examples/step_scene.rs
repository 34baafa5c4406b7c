//! Steps a scene file (its volume read from disk or built procedurally) and prints, per window of steps, the steps/s and
//! the mean CG iterations (how a scene's cost changes as its motion settles) and, in a scene
//! whose tools follow scripted paths, what they cut and the largest force on them.
//! `cargo run --release -p incise_scene --example step_scene -- deploy/scenes/b1.toml 6000 500`

use incise_sim::{Simulation, StepInputs};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).map_or("deploy/scenes/b1.toml", String::as_str);
    let steps: usize = args.get(2).map_or(6000, |s| s.parse().expect("steps"));
    let window: usize = args.get(3).map_or(500, |s| s.parse().expect("window"));
    let scene = incise_scene::read_scene(path.as_ref()).unwrap_or_else(|e| panic!("{e}"));
    for note in &scene.notes {
        eprintln!("note: {note}");
    }
    let mut sim =
        Simulation::new(&scene.config, &scene.geometry, path).unwrap_or_else(|e| panic!("{e}"));
    let none = StepInputs::default();
    let (mut iterations, mut residual) = (0usize, 0.0f64);
    let (mut removed, mut severed, mut force) = (0usize, 0usize, 0.0f64);
    let mut start = std::time::Instant::now();
    for k in 1..=steps {
        let frame = sim.step(&none).expect("no inputs to refuse");
        iterations += frame.counters.solver_iterations;
        residual = residual.max(frame.counters.solver_residual);
        removed += frame.counters.voxels_removed + frame.counters.tets_removed;
        severed += frame.counters.links_severed;
        for tool in &frame.surgical.tools {
            force = force.max(tool.force().iter().map(|c| c * c).sum::<f64>().sqrt());
        }
        if k % window == 0 {
            let s = start.elapsed().as_secs_f64();
            let speed: f64 = sim.state().v.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
            let tools = if frame.surgical.tools.is_empty() {
                String::new()
            } else {
                format!("  cut {removed} cells, {severed} links  tool force ≤ {force:.3} N")
            };
            println!(
                "steps {:>6}..{k:<6} {:>9.1} steps/s  {:>6.2} CG iterations/step  worst residual {residual:.1e}  |v| {speed:.2e} m/s{tools}",
                k + 1 - window,
                window as f64 / s,
                iterations as f64 / window as f64
            );
            (iterations, residual) = (0, 0.0);
            (removed, severed, force) = (0, 0, 0.0);
            start = std::time::Instant::now();
        }
    }
}
