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
        let outcome = replay(&contents, &mut sim, Compare::default(), |_| {});
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
