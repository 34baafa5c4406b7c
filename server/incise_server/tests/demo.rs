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
    assert!(frames > 1000.0, "{frames} frames in 4 s at dt 1 ms");
    assert!(number_after(&summary, "removed") > 0.0, "the scalpel never cut");
    for tool in ["scalpel over iceoryx2:", "grasper over zenoh:"] {
        let line = summary.lines().find(|l| l.starts_with(tool)).expect(tool);
        assert!(number_after(line, "poses,") > 1000.0, "{line}");
        assert!(number_after(line, "max force") > 0.0, "{line}");
    }
    let viewer = summary.lines().find(|l| l.starts_with("a viewer over zenoh:")).unwrap();
    // Frames published while the viewer's subscription was being set up may be missed.
    assert!(number_after(viewer, "zenoh:") > frames * 0.9, "{viewer}");
    assert!(number_after(viewer, "statistics (up to frame") > 0.0, "{viewer}");
    assert!(number_after(viewer, "),") > 0.0, "no cut event: {viewer}");
    assert!(summary.contains("faults: none"), "{summary}");

    // The recording: one file, every frame in order with the poses it used and a state hash,
    // the cuts the viewer saw, the scene that replays it.
    let files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(files.len(), 1, "{files:?}");
    assert!(summary.contains(&*files[0].display().to_string()), "the summary names the file");
    let contents = incise_record::read_recording(&std::fs::read(&files[0]).unwrap()).unwrap();
    assert!(contents.truncated.is_none());
    let recorded = contents.frames.len() as f64;
    println!("recording: {} frames, {} cuts", contents.frames.len(), contents.cuts.len());
    assert!((recorded - frames).abs() <= 1.0, "{recorded} frames recorded of {frames}");
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
    let _ = std::fs::remove_dir_all(&dir);
}
