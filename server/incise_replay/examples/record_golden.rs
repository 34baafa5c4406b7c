//! Records the scripted golden recordings into a folder (see `recordings/README.md`):
//!
//! ```sh
//! cargo run --release -p incise_replay --example record_golden -- recordings/
//! ```
//!
//! `separation_frees_a_piece.mcap`: a 4 cm block (16³ voxels of 2.5 mm, held at its base) and a
//! blade in separation mode laid flat at 2.5 cm, drawn through the block along +y until every
//! link across that plane is severed and the top piece is free; the blade holds it a moment,
//! is pulled out sideways, and the piece falls (through the block: pieces do not collide yet). The frames are stepped as the server steps them
//! (each pose checked, recorded as checked and converted by
//! `incise_convert::tools::tool_input`), so they replay bit for bit.

use anyhow::Context;
use incise_convert::frame::{cut_event, frame_record, frame_stats};
use incise_convert::keyframe::{edit_message, keyframe_message};
use incise_convert::tools::tool_input;
use incise_protocol::check::check_pose;
use incise_protocol::raw::RawToolPose;
use incise_record::{McapRecording, Session};
use incise_sim::{Simulation, StepInputs};
use std::path::PathBuf;

/// The separation scene: the standard soft block of the hard-case tests with a separating blade.
const SEPARATION: &str = r#"name = "separation"
level = 2
gravity = [0.0, 0.0, -9.81]

[volume]
procedural = "block"
size_m = [0.04, 0.04, 0.04]
voxels = [16, 16, 16]

[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0

[model]
kind = "corotational"

[integrator]
kind = "implicit-euler"
dt = 0.001
rayleigh_alpha = 2.0
rayleigh_beta = 0.01

[[fixed]]
plane = "z"
value = 0.0

# A thin blade whose contact is soft beside the tissue, as a sharp blade's is: it severs the
# links across its mid-plane instead of pushing the tissue ahead of it.
[[tools]]
name = "separator"
stiffness = 10.0
cutting = "separate"
outer = { shape = "blade", length = 0.06, height = 0.06, thickness = 0.0005 }
inner = { shape = "blade", length = 0.06, height = 0.06, thickness = 0.0005 }
"#;

/// A quarter turn about x: the blade's mid-plane (tool y = 0) horizontal, its edge leading
/// along the grid's +y.
const LAY_FLAT: [f64; 4] =
    [std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0];

fn main() -> anyhow::Result<()> {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "recordings".into()));
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let path = dir.join("separation_frees_a_piece.mcap");
    // The blade's mid-plane on the boundary between voxel layers 9 and 10.
    let z = 0.025;
    let mut script = Vec::new();
    // In along +y from 5 mm before the block until it lies under all of it...
    for i in 0..110 {
        script.push([0.02, -0.005 + 0.0005 * f64::from(i), z]);
    }
    // ...holds the freed piece a moment, is pulled out sideways, and the piece falls.
    script.extend(std::iter::repeat_n([0.02, 0.0495, z], 40));
    script.extend(std::iter::repeat_n([0.02, 0.12, z], 120));
    let (frames, sim) = record(SEPARATION, &path, &script)?;
    // The block is held at z = 0 and nothing stops a freed piece (there is no contact between
    // pieces yet), so a piece is free once a node has fallen well below the base.
    let lowest = sim.state().x.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    println!(
        "{}: {frames} frames; the lowest node is {:.1} mm below the held base",
        path.display(),
        -lowest * 1e3
    );
    anyhow::ensure!(lowest < -0.01, "the separation should have freed the top piece");
    Ok(())
}

/// Steps `scene` with tool 0 at each of `positions` (laid flat) and records every frame to
/// `path`, as the server does; the frames recorded, and the simulation at the end.
fn record(
    scene: &str,
    path: &std::path::Path,
    positions: &[[f64; 3]],
) -> anyhow::Result<(u64, Simulation)> {
    let parsed = incise_scene::scene_from_toml(scene, "<golden scene>", std::path::Path::new("."))?;
    let mut sim = Simulation::new(&parsed.config, &parsed.geometry, "<golden scene>")?;
    let session = Session {
        scene: parsed.config.name.clone(),
        scene_toml: scene.to_owned(),
        version: env!("CARGO_PKG_VERSION").into(),
        git_revision: String::new(),
        tools: incise_convert::tools::tool_looks(&parsed.config),
        scene_interval_s: 0.1,
        files: Vec::new(),
    };
    let mut recording = McapRecording::create(path, &session)?;
    for (i, &position) in positions.iter().enumerate() {
        let raw = RawToolPose {
            orientation: LAY_FLAT,
            sequence: i as u64,
            ..RawToolPose::at(0, position)
        };
        // Checked as the server checks a pose where it enters, and recorded as checked.
        let checked = check_pose(&raw).context("a scripted pose is unusable")?;
        let input = tool_input(&checked);
        let started = std::time::Instant::now();
        let frame = sim.step(&StepInputs { tools: vec![input], ..StepInputs::default() })?;
        let stats = frame_stats(&frame, &sim, started.elapsed(), 0.0);
        recording.frame(&frame_record(&frame, &[*checked.raw()], stats))?;
        for cut in &frame.surgical.cuts {
            recording.cut(&cut_event(&frame, cut), frame.time)?;
        }
        if let Some(edit) = edit_message(&frame) {
            recording.edit(&edit, frame.time)?;
        }
        if sim.is_keyframe(frame.index) {
            recording.keyframe(&keyframe_message(&sim.keyframe()), frame.time)?;
        }
        if i % 100 == 99 {
            recording.close_chunk()?;
        }
    }
    Ok((recording.finish()?, sim))
}
