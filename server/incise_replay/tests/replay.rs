//! `incise-replay` on a real session: the demo recorded in this process (the server's own
//! code, over the real transports), then replayed by the binary: bit for bit. Copies of the
//! recording with one frame's state hash or one force changed diverge at exactly that frame;
//! within a tolerance the changed force passes; a file that is not a recording is refused.

use incise_record::{McapRecording, Session, read_recording};
use incise_server::server::Options;
use incise_transport::zenoh_link::Endpoints;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

fn replay(file: &Path, extra: &[&str]) -> (i32, serde_json::Value, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_incise-replay"))
        .arg(file)
        .args(extra)
        .arg("--json")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let json = stdout.lines().last().and_then(|l| serde_json::from_str(l).ok());
    (out.status.code().unwrap(), json.unwrap_or_default(), format!("{stdout}{stderr}"))
}

/// `contents` written again to `path` with `edit` applied to each frame.
fn rewrite(
    path: &Path,
    contents: &incise_record::Contents,
    mut edit: impl FnMut(&mut incise_protocol::v1::FrameRecord),
) {
    let session = Session {
        scene: "demo_organ".into(),
        scene_toml: contents.scene_toml.clone().unwrap(),
        version: "test".into(),
        git_revision: String::new(),
        tools: Vec::new(),
        scene_interval_s: 0.1,
        files: Vec::new(),
    };
    let mut recording = McapRecording::create(path, &session).unwrap();
    for f in &contents.frames {
        let mut f = f.clone();
        edit(&mut f);
        recording.frame(&f).unwrap();
    }
    recording.finish().unwrap();
}

#[test]
fn a_recorded_demo_replays_bit_for_bit_and_a_changed_frame_is_found() {
    let dir = std::env::temp_dir().join(format!("incise_replay_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let options = Options {
        zenoh: Some(Endpoints::listen_loopback(port)),
        record: Some(dir.clone()),
        ..Options::default()
    };
    let (running, _, _) = incise_server::demo::run(&options, Duration::from_secs(2)).unwrap();
    let file: PathBuf = running.recording().unwrap().to_owned();
    running.stop();

    let (code, json, out) = replay(&file, &[]);
    println!("{out}");
    assert_eq!(code, 0, "{out}");
    assert_eq!(json["matched"], true);
    let contents = read_recording(&std::fs::read(&file).unwrap()).unwrap();
    assert_eq!(json["frames"].as_u64(), Some(contents.frames.len() as u64));
    // A loaded machine steps fewer of the 2,000 frames the 2 s allow; the checks below need
    // 200 frames after a third of them.
    assert!(contents.frames.len() > 300, "{} frames", contents.frames.len());

    // One state hash changed: found at that frame, and not before.
    let k = contents.frames[contents.frames.len() / 3].frame;
    let changed = dir.join("changed_state.mcap");
    rewrite(&changed, &contents, |f| {
        if f.frame == k {
            f.state_hash ^= 1;
        }
    });
    let (code, json, out) = replay(&changed, &[]);
    assert_eq!(code, 1, "{out}");
    assert_eq!(json["first_divergence"]["frame"].as_u64(), Some(k), "{out}");
    assert_eq!(json["first_divergence"]["what"], "state");
    // --from after it compares only what follows (the frames before are stepped, not
    // compared); --to stops there.
    let (from, to) = (k.to_string(), (k + 200).to_string());
    let after = (k + 1).to_string();
    let (code, json, out) = replay(&changed, &["--from", &after, "--to", &to]);
    assert_eq!(code, 0, "{out}");
    assert_eq!(json["frames"].as_u64(), Some(k + 200), "{out}");
    let (code, _, out) = replay(&changed, &["--from", &from, "--to", &to]);
    assert_eq!(code, 1, "{out}");

    // --to-rrd renders a stretch of the recording for the viewer, from the keyframe before it.
    let rrd = dir.join("stretch.rrd");
    let out = Command::new(env!("CARGO_BIN_EXE_incise-replay"))
        .arg(&file)
        .args(["--from", &from, "--to", &to, "--to-rrd"])
        .arg(&rrd)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{said}{}", String::from_utf8_lossy(&out.stderr));
    assert!(said.contains("201 frames rendered"), "{said}");
    assert!(std::fs::metadata(&rrd).unwrap().len() > 10_000);

    // One recorded force moved by 1 µN where the scalpel presses: a divergence bit for bit,
    // none within 1 mN (which skips the state hash).
    let pressing = contents
        .frames
        .iter()
        .find(|f| f.tools.iter().any(|t| t.force.as_ref().is_some_and(|v| v.z.abs() > 1e-3)))
        .expect("a frame in contact")
        .frame;
    let nudged = dir.join("changed_force.mcap");
    rewrite(&nudged, &contents, |f| {
        if f.frame == pressing {
            for t in &mut f.tools {
                if let Some(v) = &mut t.force {
                    v.z += 1e-6;
                }
            }
        }
    });
    let (code, json, out) = replay(&nudged, &[]);
    assert_eq!(code, 1, "{out}");
    assert_eq!(json["first_divergence"]["frame"].as_u64(), Some(pressing), "{out}");
    let deviation = json["first_divergence"]["deviation"].as_f64().unwrap();
    assert!((deviation - 1e-6).abs() < 1e-9, "{deviation}");
    let (code, _, out) = replay(&nudged, &["--tolerance", "1e-3"]);
    assert_eq!(code, 0, "{out}");

    // Not a recording: refused with the reason, exit 2.
    let foreign = dir.join("foreign.mcap");
    std::fs::write(&foreign, b"this is not an MCAP file").unwrap();
    let (code, _, out) = replay(&foreign, &[]);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("not an MCAP file"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A recording of a scene read from files stores the files it reads (the liver CT, 100 KB),
/// so it replays bit for bit from a folder where the scene's relative paths lead nowhere.
#[test]
fn a_recording_carries_its_volume_and_replays_anywhere() {
    use incise_convert::frame::{frame_record, frame_stats};
    let scene_file =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/scenes/liver_13k.toml");
    let toml = std::fs::read_to_string(&scene_file).unwrap();
    let config = incise_sim::SceneConfig::from_toml(&toml, "liver_13k.toml").unwrap();
    let files = incise_server::scene::stored_files(&config, scene_file.parent().unwrap());
    assert_eq!(files.len(), 1, "the liver CT");
    assert_eq!(files[0].0, "../../tests/data/liver.inr.gz");
    let scene = incise_scene::read_scene(&scene_file).unwrap();
    let mut sim = incise_sim::Simulation::new(&scene.config, &scene.geometry, "liver").unwrap();
    let dir = std::env::temp_dir().join(format!("incise_replay_stored_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("liver.mcap");
    let session = Session {
        scene: "liver_13k".into(),
        scene_toml: toml,
        version: "test".into(),
        git_revision: String::new(),
        tools: Vec::new(),
        scene_interval_s: 0.1,
        files,
    };
    let mut recording = McapRecording::create(&file, &session).unwrap();
    for _ in 0..20 {
        let frame = sim.step(&incise_sim::StepInputs::default()).unwrap();
        let stats = frame_stats(&frame, &sim, Duration::ZERO, 0.0);
        recording.frame(&frame_record(&frame, &[], stats)).unwrap();
    }
    recording.finish().unwrap();
    let (code, json, out) = replay(&file, &[]);
    assert_eq!(code, 0, "{out}");
    assert_eq!(json["frames"].as_u64(), Some(20), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}
