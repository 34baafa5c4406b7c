//! The golden recordings in `recordings/` replay bit for bit: every frame's state hash and every
//! tool's force and torque (see `recordings/README.md`).

use incise_replay::{Compare, replay, simulation};
use std::path::Path;

#[test]
fn every_golden_recording_replays_bit_for_bit() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings");
    let mut replayed = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "mcap") {
            continue;
        }
        let contents = incise_record::read_recording(&std::fs::read(&path).unwrap()).unwrap();
        assert!(contents.truncated.is_none(), "{}: {:?}", path.display(), contents.truncated);
        let mut sim = simulation(&contents, &dir).unwrap();
        let outcome = replay(&contents, &mut sim, Compare::default(), |_, _, _| {});
        println!(
            "{}: {} frames in {:.2} s",
            path.display(),
            outcome.frames,
            outcome.elapsed.as_secs_f64()
        );
        assert_eq!(outcome.divergence, None, "{}", path.display());
        assert_eq!(outcome.frames, contents.frames.len() as u64);
        replayed += 1;
    }
    assert!(replayed >= 1, "no recordings in {}", dir.display());
}

/// Starting at any keyframe (the recorded cuts before it re-applied, its state restored) gives
/// every later frame's state hash and forces as stepping from the first frame did: the recording
/// was made by stepping from the first frame, and the replay compares against it bit for bit.
#[test]
fn every_keyframe_of_the_golden_recordings_starts_a_bit_exact_replay() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings");
    let (mut seeks, mut edits_before) = (0, 0);
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "mcap") {
            continue;
        }
        let bytes = std::fs::read(&path).unwrap();
        let listed = incise_record::read_recording(&bytes).unwrap();
        assert!(
            listed.keyframe_frames.windows(2).all(|w| w[1] > w[0]),
            "{}: keyframes in order",
            path.display()
        );
        for &k in &listed.keyframe_frames {
            let contents = incise_record::read_recording_at(&bytes, Some(k)).unwrap();
            let mut sim = simulation(&contents, &dir).unwrap();
            assert_eq!(incise_replay::seek(&contents, &mut sim).unwrap(), k);
            let compare = Compare { from: Some(k + 1), ..Compare::default() };
            let outcome = replay(&contents, &mut sim, compare, |_, _, _| {});
            assert_eq!(
                outcome.divergence,
                None,
                "{} from the keyframe of frame {k}",
                path.display()
            );
            let after = contents.frames.iter().filter(|f| f.frame > k).count() as u64;
            assert_eq!(
                outcome.frames,
                after,
                "{}: only the frames after {k} stepped",
                path.display()
            );
            seeks += 1;
            edits_before += contents.edits.iter().filter(|e| e.frame <= k).count();
        }
    }
    assert!(seeks >= 2, "the golden recordings should hold keyframes ({seeks})");
    assert!(edits_before > 0, "a keyframe should follow a cut");
}

/// `incise-replay --from F` starts at the keyframe before F and says so.
#[test]
fn replay_from_a_frame_starts_at_the_keyframe_before_it() {
    let file =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings/demo_press_cut_grasp.mcap");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_incise-replay"))
        .arg(&file)
        .args(["--from", "2100", "--json"])
        .output()
        .unwrap();
    let said =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{said}");
    let json: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap();
    assert_eq!(json["keyframe"], 2000, "{said}");
    assert_eq!(json["matched"], true, "{said}");
    let frames = json["recorded_frames"].as_u64().unwrap();
    assert_eq!(json["frames"].as_u64(), Some(frames - 2000), "{said}");
    assert!(said.contains("starting after the keyframe of frame 2000"), "{said}");
}
