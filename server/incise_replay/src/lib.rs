//! Replaying a recording: the scene stored in it is rebuilt, every frame is stepped again with the
//! tool poses the server stepped it with (converted exactly as the server converts them), and
//! each frame's state hash and tool forces are compared with the recorded ones. On the machine
//! and build that recorded it, a replay matches bit for bit; elsewhere, `tolerance` compares the
//! forces within bounds instead (the state hash then cannot match and is not compared).
//!
//! A replay of a frame range starts at the last keyframe before it ([`seek`]): the scene is
//! rebuilt, every frame's recorded topology edit up to the keyframe re-applied, and the
//! keyframe's state restored, so only the frames after it are stepped.
//!
//! [`render`] turns a recording into an `.rrd` file for the Rerun viewer from what it holds
//! (frames, cuts, the surface), without stepping anything: a frame range starts at the whole
//! surface (keyframe) at or before it.

use incise_protocol::check::CheckedPose;
use incise_protocol::raw::RawToolPose;
use incise_protocol::v1;
use incise_record::Contents;
use incise_sim::{Simulation, StepInputs};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How a replay compares.
#[derive(Clone, Copy, Debug, Default)]
pub struct Compare {
    /// `None`: bit for bit (state hash and forces). `Some(t)`: forces and torques within `t`
    /// (N, N·m), state hash not compared.
    pub tolerance: Option<f64>,
    /// Compare from this frame on (the frames between the simulation's frame, see [`seek`],
    /// and this one are stepped, not compared).
    pub from: Option<u64>,
    /// Stop after this frame.
    pub to: Option<u64>,
}

/// Where a replay first left the recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Divergence {
    /// The frame.
    pub frame: u64,
    /// What differed: `state`, `tool N force`, `tool N torque`, `frame index`, `step`.
    pub what: String,
    /// The largest difference found there (N or N·m; 0 for the state hash, which has no
    /// magnitude).
    pub deviation: f64,
}

/// What a replay found.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// Frames stepped and compared.
    pub frames: u64,
    /// The first divergence, if any.
    pub divergence: Option<Divergence>,
    /// Wall time of the stepping.
    pub elapsed: Duration,
}

/// Rebuilds `contents`' scene. The files it names are read relative to `base`; when one is
/// not there and the recording stores it, the stored files are used instead (written under a
/// temporary folder in the places the scene names).
pub fn simulation(contents: &Contents, base: &Path) -> anyhow::Result<Simulation> {
    let toml = contents.scene_toml.as_deref().ok_or_else(|| {
        anyhow::anyhow!("the recording holds no scene (no scene.toml attachment)")
    })?;
    let missing = contents.files.keys().any(|name| !base.join(name).is_file());
    let stored = if missing { Some(unpack_files(contents)?) } else { None };
    let base = stored.as_ref().map_or(base, |(_, b)| b.as_path());
    let scene = incise_scene::scene_from_toml(toml, "<the recording's scene>", base)?;
    let mut sim = Simulation::new(&scene.config, &scene.geometry, "<the recording's scene>")?;
    // The scene's own choice, as the session made it: a session on a GPU replays on one.
    if let Some(gpu) = incise_scene::attach_gpu(&mut sim) {
        eprintln!("{gpu}");
    }
    if let Some((dir, _)) = stored {
        let _ = std::fs::remove_dir_all(dir);
    }
    Ok(sim)
}

/// Writes the recording's stored files under a new temporary folder, each at the place its
/// name (relative to the scene, possibly through `..`) points to from the returned base: the
/// folder and the base.
fn unpack_files(contents: &Contents) -> anyhow::Result<(PathBuf, PathBuf)> {
    use std::path::Component;
    static UNPACKED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = UNPACKED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("incise-replay-{}-{n}", std::process::id()));
    // Deep enough that every name's leading `..` stays inside the folder.
    let depth = contents
        .files
        .keys()
        .map(|name| Path::new(name).components().take_while(|c| *c == Component::ParentDir).count())
        .max()
        .unwrap_or(0);
    let base = (0..depth).fold(dir.join("scene"), |b, i| b.join(format!("d{i}")));
    for (name, bytes) in &contents.files {
        let path = Path::new(name);
        anyhow::ensure!(
            path.components().all(|c| matches!(
                c,
                Component::Normal(_) | Component::ParentDir | Component::CurDir
            )),
            "the recording stores a file named {name:?}, which is not a relative path"
        );
        // Resolved by hand: the folders a `..` climbs out of do not exist yet.
        let mut at = base.clone();
        for c in path.components() {
            match c {
                Component::ParentDir => {
                    at.pop();
                }
                Component::Normal(part) => at.push(part),
                _ => {}
            }
        }
        anyhow::ensure!(at.starts_with(&dir), "{name:?} climbs out of the scene's folder");
        if let Some(parent) = at.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(&at, bytes)?;
    }
    std::fs::create_dir_all(&base)?;
    Ok((dir, base))
}

/// Brings `sim` (just built by [`simulation`]) to `contents`' keyframe (read by
/// `incise_record::read_recording_at` with the frame before the first to compare): applies
/// every recorded topology edit up to it, then restores it. Returns the keyframe's frame, after
/// which [`replay`] steps; 0 when the contents hold no keyframe (the replay then starts at the
/// first frame).
///
/// # Errors
/// When an edit or the keyframe does not decode or does not fit the scene (a recording of
/// another build whose state differs refuses here, at its hash check).
pub fn seek(contents: &Contents, sim: &mut Simulation) -> anyhow::Result<u64> {
    use incise_convert::keyframe::{edit_from_message, keyframe_from_message};
    let Some(message) = &contents.keyframe else { return Ok(0) };
    let keyframe = keyframe_from_message(message).map_err(anyhow::Error::msg)?;
    for edit in contents.edits.iter().take_while(|e| e.frame <= keyframe.frame) {
        let (grid, tets) = edit_from_message(edit).map_err(anyhow::Error::msg)?;
        sim.apply_edit(&grid, &tets)
            .map_err(|e| anyhow::anyhow!("the recorded edit of frame {}: {e}", edit.frame))?;
    }
    sim.restore(&keyframe)?;
    Ok(keyframe.frame)
}

/// Replays `contents` on `sim`, calling `progress` after every frame (with the frames stepped so
/// far, the simulation and the frame it stepped: what a report measures on the replayed
/// state); stops at the first divergence. The frames `sim` has already stepped (or restored, see
/// [`seek`]) are skipped.
pub fn replay(
    contents: &Contents,
    sim: &mut Simulation,
    compare: Compare,
    mut progress: impl FnMut(u64, &Simulation, &incise_sim::Frame),
) -> Outcome {
    let started = Instant::now();
    let mut frames = 0;
    let to = compare.to.unwrap_or(u64::MAX);
    let done = sim.frame_index();
    for record in
        contents.frames.iter().skip_while(|r| r.frame <= done).take_while(|r| r.frame <= to)
    {
        let tools = record
            .poses
            .iter()
            .filter_map(|p| RawToolPose::try_from(p).ok())
            .filter_map(|raw| CheckedPose::verified(&raw).ok())
            .map(|pose| incise_convert::tools::tool_input(&pose))
            .collect();
        let inputs = StepInputs { tools, ..StepInputs::default() };
        let diverged = |frames: u64, what: String, deviation: f64| Outcome {
            frames,
            divergence: Some(Divergence { frame: record.frame, what, deviation }),
            elapsed: started.elapsed(),
        };
        let frame = match sim.step(&inputs) {
            Ok(f) => f,
            Err(e) => return diverged(frames, format!("step: {e}"), 0.0),
        };
        frames += 1;
        if record.frame < compare.from.unwrap_or(0) {
            progress(frames, sim, &frame);
            continue;
        }
        if frame.index != record.frame {
            let what = format!("frame index {} (recorded {})", frame.index, record.frame);
            return diverged(frames, what, 0.0);
        }
        if let Some(d) = compare_tools(&frame, record, compare) {
            return diverged(frames, d.0, d.1);
        }
        if compare.tolerance.is_none() && frame.state_hash != record.state_hash {
            return diverged(frames, "state".into(), 0.0);
        }
        progress(frames, sim, &frame);
    }
    Outcome { frames, divergence: None, elapsed: started.elapsed() }
}

/// The first tool whose force or torque differs beyond the comparison's bound: what and by how
/// much (the largest component difference).
fn compare_tools(
    frame: &incise_sim::Frame,
    record: &v1::FrameRecord,
    compare: Compare,
) -> Option<(String, f64)> {
    let array = |v: &Option<v1::Vec3>| v.as_ref().map_or([0.0; 3], |v| [v.x, v.y, v.z]);
    for t in &record.tools {
        let Some(tool) = frame.surgical.tools.get(t.tool_id as usize) else {
            return Some((format!("tool {} missing", t.tool_id), 0.0));
        };
        let lin = &tool.linearisation;
        for (what, got, want) in
            [("force", lin.force, array(&t.force)), ("torque", lin.torque, array(&t.torque))]
        {
            let bits_differ = got.iter().zip(&want).any(|(a, b)| a.to_bits() != b.to_bits());
            // The largest difference, NaN if any is (f64::max would drop it).
            let off = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, |m: f64, d| if d.is_nan() || d > m { d } else { m });
            let differs = match compare.tolerance {
                None => bits_differ,
                // A NaN deviation is a divergence too.
                Some(bound) => off.is_nan() || off > bound,
            };
            if differs {
                return Some((format!("tool {} {what}", t.tool_id), off));
            }
        }
    }
    None
}

/// Writes `contents`' frames in `from..=to` to `rrd`: every frame's time series and cuts, and
/// the recorded surfaces, starting at the last whole surface at or before `from` (the view a
/// seek shows); `tools` draws the tools. The frames written.
pub fn render(
    contents: &Contents,
    from: u64,
    to: u64,
    rrd: &mut incise_record::RerunLog,
) -> anyhow::Result<u64> {
    use incise_record::SurfaceFrame;
    let start = contents
        .surfaces
        .iter()
        .filter(|(s, _)| s.full && s.frame <= from.max(1))
        .map(|(s, _)| s.frame)
        .next_back()
        .unwrap_or(0);
    let mut surfaces = contents.surfaces.iter().filter(|(s, _)| s.frame >= start).peekable();
    let mut cuts = contents.cuts.iter().peekable();
    let mut written = 0;
    for record in contents.frames.iter().filter(|r| r.frame >= start.min(from) && r.frame <= to) {
        if record.frame >= from {
            rrd.frame(record);
            written += 1;
        }
        while let Some((cut, t)) = cuts.next_if(|(c, _)| c.frame <= record.frame) {
            if cut.frame >= from {
                rrd.cut(cut, *t as f64 * 1e-9);
            }
        }
        while let Some((surface, t)) = surfaces.next_if(|(s, _)| s.frame <= record.frame) {
            let surface = SurfaceFrame::from_message(surface, *t as f64 * 1e-9)
                .map_err(|e| anyhow::anyhow!("the recorded surface: {e}"))?;
            rrd.surface(&surface, (surface.frame == record.frame).then_some(record));
        }
    }
    Ok(written)
}
