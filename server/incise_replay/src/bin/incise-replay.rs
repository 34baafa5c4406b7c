//! `incise-replay RECORDING.mcap`: see `incise-replay --help`.

use anyhow::Context;
use clap::Parser;
use incise_replay::{Compare, replay, simulation};
use std::path::PathBuf;
use std::process::ExitCode;

/// Re-runs a recorded incise session frame by frame, from the scene and tool poses stored in
/// the recording, and compares each frame's state hash and tool forces with the recorded ones.
/// Exit status 0: every frame matches (bit for bit, or within --tolerance); 1: a frame diverged
/// (the first is printed, with what differed and by how much); 2: the recording could not be
/// read or its scene not rebuilt.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None)]
struct Cli {
    /// The recording (an MCAP file written by `incise-server --record`).
    recording: PathBuf,
    /// Compare forces and torques within this bound (N, N·m) instead of bit for bit, and skip
    /// the state hash: for a recording made on another machine or build.
    #[arg(long, value_name = "NEWTONS")]
    tolerance: Option<f64>,
    /// Folder the scene's files (volumes, meshes) are read from; by default the recording's.
    #[arg(long, value_name = "DIR")]
    scene_dir: Option<PathBuf>,
    /// End with one line of JSON: `frames`, `matched`, `first_divergence`, `replay_fps`,
    /// `recorded_fps`.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("incise-replay: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run() -> anyhow::Result<bool> {
    let cli = Cli::parse();
    if let Some(t) = cli.tolerance {
        anyhow::ensure!(t.is_finite() && t >= 0.0, "--tolerance must be a non-negative number");
    }
    let shown = cli.recording.display();
    let bytes = std::fs::read(&cli.recording).with_context(|| format!("cannot read {shown}"))?;
    let contents = incise_record::read_recording(&bytes).with_context(|| format!("{shown}"))?;
    if let Some(why) = &contents.truncated {
        eprintln!("{shown}: {why}; replaying the {} frames before it", contents.frames.len());
    }
    let base = cli
        .scene_dir
        .clone()
        .or_else(|| cli.recording.parent().map(PathBuf::from))
        .unwrap_or_default();
    let mut sim = simulation(&contents, &base).with_context(|| format!("{shown}"))?;
    let total = contents.frames.len() as u64;
    let bar = indicatif::ProgressBar::new(total).with_style(
        indicatif::ProgressStyle::with_template(
            "replaying {bar:40} {pos}/{len} frames ({per_sec}, {eta} left)",
        )
        .expect("a valid template"),
    );
    let outcome = replay(&contents, &mut sim, Compare { tolerance: cli.tolerance }, |n| {
        if n % 64 == 0 {
            bar.set_position(n);
        }
    });
    bar.finish_and_clear();
    let fps = outcome.frames as f64 / outcome.elapsed.as_secs_f64().max(1e-9);
    let dt = sim.config().dt();
    let how = match cli.tolerance {
        None => "bit for bit".to_owned(),
        Some(t) => format!("forces within {t} N"),
    };
    match &outcome.divergence {
        None => println!(
            "{shown}: all {} frames match {how}; replayed at {fps:.0} frames/s (recorded at {:.0} frames/s of simulated time, {:.2}× its pace)",
            outcome.frames,
            1.0 / dt,
            fps * dt
        ),
        Some(d) => println!(
            "{shown}: frame {} diverges ({}, largest deviation {:.3e}) after {} matching frames",
            d.frame,
            d.what,
            d.deviation,
            outcome.frames.saturating_sub(1)
        ),
    }
    if cli.json {
        let first = outcome.divergence.as_ref().map(
            |d| serde_json::json!({"frame": d.frame, "what": d.what, "deviation": d.deviation}),
        );
        let json = serde_json::json!({
            "frames": outcome.frames,
            "matched": outcome.divergence.is_none(),
            "first_divergence": first,
            "replay_fps": fps,
            "recorded_fps": 1.0 / dt,
        });
        println!("{json}");
    }
    Ok(outcome.divergence.is_none())
}
