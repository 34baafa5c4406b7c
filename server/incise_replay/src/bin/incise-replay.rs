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
    /// `recorded_fps`, `recorded_frames`, `missing_frames`, `keyframe` (the frame the replay
    /// started after, 0 for the first).
    #[arg(long)]
    json: bool,
    /// First frame to compare (and to render with --to-rrd). The replay starts at the last
    /// keyframe before it (one a second of simulated time): the recorded cuts up to it are
    /// applied and its state restored, and only the frames after it are stepped.
    #[arg(long, value_name = "FRAME")]
    from: Option<u64>,
    /// Last frame to compare (and to render); the replay stops there.
    #[arg(long, value_name = "FRAME")]
    to: Option<u64>,
    /// Render the recording for the Rerun viewer into OUT.rrd instead of replaying it: the
    /// recorded surfaces, tools, forces, time series and cuts of the frames in --from..--to,
    /// starting at the whole surface (a keyframe, one a second) at or before --from.
    #[arg(long, value_name = "OUT.rrd")]
    to_rrd: Option<PathBuf>,
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
    // The keyframe a replay of --from starts at: the last one before that frame.
    let seek = cli.from.filter(|_| cli.to_rrd.is_none()).map(|f| f.saturating_sub(1));
    let contents =
        incise_record::read_recording_at(&bytes, seek).with_context(|| format!("{shown}"))?;
    if let Some(why) = &contents.truncated {
        eprintln!("{shown}: {why}; replaying the {} frames before it", contents.frames.len());
    }
    // Frames are numbered from 1 without gaps: a gap is a frame the recorder lost.
    let missing: u64 =
        contents.frames.windows(2).map(|w| w[1].frame.saturating_sub(w[0].frame + 1)).sum::<u64>()
            + contents.frames.first().map_or(0, |f| f.frame.saturating_sub(1));
    eprintln!(
        "{shown}: {} frames, {missing} missing; {} cuts; {} surface frames; {} keyframes",
        contents.frames.len(),
        contents.cuts.len(),
        contents.surfaces.len(),
        contents.keyframe_frames.len()
    );
    if let (Some(from), Some(to)) = (cli.from, cli.to) {
        anyhow::ensure!(from <= to, "--from {from} is after --to {to}");
    }
    if let Some(out) = &cli.to_rrd {
        let base = cli.scene_dir.clone().or_else(|| cli.recording.parent().map(PathBuf::from));
        let toml = contents.scene_toml.as_deref().unwrap_or_default();
        // The tools' shapes come from the scene; a recording without one draws no tools.
        let tools = incise_scene::scene_from_toml(
            toml,
            "<the recording's scene>",
            &base.unwrap_or_default(),
        )
        .map(|s| incise_convert::tools::tool_looks(&s.config))
        .unwrap_or_default();
        let mut rrd = incise_record::RerunLog::save(out, &tools).map_err(anyhow::Error::msg)?;
        let written = incise_replay::render(
            &contents,
            cli.from.unwrap_or(1),
            cli.to.unwrap_or(u64::MAX),
            &mut rrd,
        )?;
        rrd.finish().map_err(anyhow::Error::msg)?;
        println!("{shown}: {written} frames rendered into {}", out.display());
        return Ok(true);
    }
    let base = cli
        .scene_dir
        .clone()
        .or_else(|| cli.recording.parent().map(PathBuf::from))
        .unwrap_or_default();
    let mut sim = simulation(&contents, &base).with_context(|| format!("{shown}"))?;
    let keyframe = incise_replay::seek(&contents, &mut sim)
        .with_context(|| format!("{shown}: starting at the keyframe before --from"))?;
    if keyframe > 0 {
        eprintln!(
            "{shown}: starting after the keyframe of frame {keyframe} ({} recorded edits applied)",
            contents.edits.iter().filter(|e| e.frame <= keyframe).count()
        );
    } else if cli.from.is_some_and(|f| f > 1) {
        eprintln!("{shown}: no keyframe before --from; stepping from the first frame");
    }
    let total = contents
        .frames
        .iter()
        .filter(|r| r.frame > keyframe && r.frame <= cli.to.unwrap_or(u64::MAX))
        .count() as u64;
    let bar = indicatif::ProgressBar::new(total).with_style(
        indicatif::ProgressStyle::with_template(
            "replaying {bar:40} {pos}/{len} frames ({per_sec}, {eta} left)",
        )
        .expect("a valid template"),
    );
    let compare = Compare { tolerance: cli.tolerance, from: cli.from, to: cli.to };
    let outcome = replay(&contents, &mut sim, compare, |n, _, _| {
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
            "recorded_frames": contents.frames.len(),
            "missing_frames": missing,
            "keyframe": keyframe,
        });
        println!("{json}");
    }
    Ok(outcome.divergence.is_none())
}
