//! The README's main command, `incise-server --demo`, as its own process: the scripted scalpel
//! (iceoryx2) presses and cuts, the grasper (zenoh) takes hold, a viewer over zenoh sees every
//! frame's statistics and the cuts, the summary says so, and the session's recording holds
//! every frame and cut.

mod common;

use std::process::Command;

/// The first number after `label` in `text`.
fn number_after(text: &str, label: &str) -> f64 {
    let rest = text.split(label).nth(1).unwrap_or_else(|| panic!("no {label:?} in:\n{text}"));
    let digits: String =
        rest.trim_start().chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    digits.parse().unwrap_or_else(|_| panic!("no number after {label:?} in:\n{text}"))
}

#[test]
fn the_demo_presses_cuts_grasps_and_reports() {
    let dir = std::env::temp_dir().join(format!("incise_demo_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--demo", "--duration", "4", "--record"])
        .arg(&dir)
        .output()
        .unwrap();
    let summary = String::from_utf8_lossy(&out.stdout);
    println!("{summary}");
    assert!(out.status.success(), "{summary}{}", String::from_utf8_lossy(&out.stderr));
    let frames = number_after(&summary, "physics:");
    // However fast the machine, the demo steps on (its tools idle) until a keyframe interval
    // and a tenth of simulated time has passed, so that the recording holds a keyframe past
    // the first to replay from: a count of frames, not a rate (rates are the benchmarks').
    let dt_s = number_after(&summary, "dt") * 1e-3;
    let least = (incise_server::physics::KEYFRAME_INTERVAL_S * 1.1 / dt_s).ceil();
    assert!(frames >= least, "{frames} frames, fewer than the {least} the demo runs to");
    assert!(number_after(&summary, "removed") > 0.0, "the scalpel never cut");
    for tool in ["scalpel over iceoryx2:", "grasper over zenoh:"] {
        let line = summary.lines().find(|l| l.starts_with(tool)).expect(tool);
        // Each client sent poses, the server answered some with forces (no more than were
        // sent), and one of those pushed (the scalpel on the organ, the grasper holding it).
        let (sent, answered) = (number_after(line, ":"), number_after(line, "poses,"));
        assert!(sent > 0.0 && answered > 0.0 && answered <= sent, "{line}");
        assert!(number_after(line, "max force") > 0.0, "{line}");
    }
    let viewer = summary.lines().find(|l| l.starts_with("a viewer over zenoh:")).unwrap();
    // Frames published while the viewer's subscription was being set up may be missed.
    assert!(number_after(viewer, "zenoh:") > frames * 0.9, "{viewer}");
    assert!(number_after(viewer, "statistics (up to frame") > 0.0, "{viewer}");
    assert!(number_after(viewer, "),") > 0.0, "no cut event: {viewer}");
    assert!(summary.contains("faults: none"), "{summary}");

    // The recording: an MCAP file and its `.rrd` twin; in the MCAP file every frame in order
    // with the poses it used and a state hash, the cuts the viewer saw, the surface, the scene
    // that replays it.
    let mut files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    assert_eq!(files.len(), 2, "{files:?}");
    assert_eq!(files[0].extension().unwrap(), "mcap");
    assert_eq!(files[1], files[0].with_extension("rrd"));
    assert!(summary.contains(&*files[0].display().to_string()), "the summary names the file");
    let contents = incise_record::read_recording(&std::fs::read(&files[0]).unwrap()).unwrap();
    assert!(contents.truncated.is_none());
    let recorded = contents.frames.len() as f64;
    println!("recording: {} frames, {} cuts", contents.frames.len(), contents.cuts.len());
    // The summary is taken once the physics has stopped: every frame it stepped is recorded.
    assert!((recorded - frames).abs() < 0.5, "{recorded} frames recorded of {frames}");
    for (i, f) in contents.frames.iter().enumerate() {
        assert_eq!(f.frame, i as u64 + 1, "frames in order from 1, none missing");
    }
    assert!(contents.frames.iter().any(|f| f.poses.len() == 2 && f.tools.len() == 2));
    assert!(contents.frames.windows(2).any(|w| w[0].state_hash != w[1].state_hash));
    let voxels: u32 = contents.cuts.iter().map(|(c, _)| c.voxels_removed).sum();
    let removed = number_after(&summary, "removed") as u32;
    assert!(
        voxels > 0 && voxels == removed,
        "{voxels} voxels in the cut events, {removed} removed"
    );
    assert_eq!(contents.scene_toml.as_deref(), Some(incise_server::scene::DEMO_SCENE));
    // The surface: at least the default 60 Hz of simulated time, whole on the first frame and
    // once a second, and every cut's change on the frame that cut. Applied in order, the
    // changes give each keyframe's triangles exactly (incremental equals whole).
    let surfaces = &contents.surfaces;
    let sim_s = contents.frames.last().unwrap().sim_time_s;
    assert!(
        surfaces.len() as f64 >= 60.0 * sim_s * 0.95,
        "{} surfaces in {sim_s} s",
        surfaces.len()
    );
    assert!(surfaces[0].0.full && surfaces[0].0.frame == 1);
    for (cut, _) in &contents.cuts {
        assert!(
            surfaces.iter().any(|(s, _)| s.frame == cut.frame
                && (s.full || !s.triangle_ids.is_empty() || !s.removed_triangle_ids.is_empty())),
            "frame {} cut and its surface change is not recorded",
            cut.frame
        );
    }
    // Every force the haptic loop sent, each naming a frame that was recorded.
    let updates = number_after(&summary, "haptics:");
    let sent = contents.forces.len() as f64;
    println!("{sent} sent forces recorded, {updates} haptic updates");
    assert!((sent - updates).abs() <= updates * 0.02, "{sent} forces recorded of {updates} sent");
    let last = contents.frames.last().unwrap().frame;
    assert!(contents.forces.iter().all(|f| f.snapshot_frame <= last + 1));
    assert!(
        contents
            .forces
            .iter()
            .any(|f| f.snapshot_frame > 0 && f.force.as_ref().is_some_and(|f| f.force.is_some()))
    );
    let mut state = incise_record::SurfaceState::default();
    let mut keyframes_checked = 0;
    // A whole surface on a frame that also cut holds that frame's change too (it is recorded
    // once, whole), so only a whole surface on a frame without a cut equals the surface the
    // earlier frames built up.
    let cut_frames: std::collections::HashSet<u64> =
        contents.cuts.iter().map(|(c, _)| c.frame).collect();
    for (m, t) in surfaces {
        let frame = incise_record::SurfaceFrame::from_message(m, *t as f64 * 1e-9).unwrap();
        if frame.whole && frame.frame > 1 && !cut_frames.contains(&frame.frame) {
            let mut whole = incise_record::SurfaceState::default();
            whole.apply(&frame);
            assert_eq!(state.triangles(), whole.triangles(), "keyframe {}", frame.frame);
            keyframes_checked += 1;
        }
        state.apply(&frame);
    }
    assert!(keyframes_checked >= 1);
    let keyframes = surfaces.iter().filter(|(s, _)| s.full).count();
    assert!(keyframes as f64 >= sim_s.floor(), "{keyframes} whole surfaces in {sim_s} s");

    // MCAP's own Python libraries (nothing of ours) decode every message with the schemas the
    // file embeds.
    let python = common::python("python-venv-mcap", "tools/mcap-check/requirements.txt");
    let out = Command::new(python)
        .arg(common::root().join("tools/mcap-check/check_mcap.py"))
        .arg(&files[0])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    println!("{stdout}");
    let j: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(j["topics"]["/incise/frame"].as_u64(), Some(contents.frames.len() as u64));
    assert_eq!(j["topics"]["/incise/cut"].as_u64(), Some(contents.cuts.len() as u64));
    assert_eq!(j["schemas"]["/incise/frame"], "incise.v1.FrameRecord");
    assert_eq!(j["metadata"]["incise"]["scene"], "demo_organ");
    assert_eq!(j["attachments"][0], "scene.toml");
    assert_eq!(j["topics"]["/incise/surface"].as_u64(), Some(surfaces.len() as u64));
    // A keyframe every 1,000 frames (1 s at 1 kHz), an edit on every frame that cut.
    let count = |topic: &str| j["topics"][topic].as_u64().unwrap_or(0);
    assert_eq!(contents.keyframe_frames.len() as u64, contents.frames.len() as u64 / 1000);
    assert_eq!(count("/incise/keyframe"), contents.keyframe_frames.len() as u64);
    assert_eq!(count("/incise/edit"), contents.edits.len() as u64);
    assert_eq!(
        contents.edits.len(),
        contents
            .frames
            .iter()
            .filter(|f| f.stats.as_ref().is_some_and(|s| s.voxels_removed > 0))
            .count()
    );
    assert_eq!(j["schemas"]["/foxglove/scene"], "foxglove.SceneUpdate");
    assert!(j["topics"]["/foxglove/scene"].as_u64().unwrap() >= sim_s as u64 * 2);
    for tool in ["scalpel", "grasper"] {
        for what in ["pose", "proxy"] {
            let topic = format!("/foxglove/tools/{tool}/{what}");
            assert_eq!(j["schemas"][&topic], "foxglove.PoseInFrame", "{topic}");
            assert!(j["topics"][&topic].as_u64().unwrap() > 0, "{topic}");
        }
    }

    // Rerun's own tool accepts the `.rrd` file.
    let python = common::python("python-venv-rerun", "tools/rerun-check/requirements.txt");
    let rerun = python.with_file_name("rerun");
    // No usage reports leave the machine.
    let off = Command::new(&rerun).args(["analytics", "disable"]).output().unwrap();
    assert!(off.status.success(), "{}", String::from_utf8_lossy(&off.stderr));
    let out = Command::new(&rerun).args(["rrd", "verify"]).arg(&files[1]).output().unwrap();
    let said =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("rerun rrd verify: {said}");
    assert!(out.status.success(), "rerun rrd verify refused {}: {said}", files[1].display());
    let _ = std::fs::remove_dir_all(&dir);
}
