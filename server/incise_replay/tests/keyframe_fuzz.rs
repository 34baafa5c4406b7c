//! Fuzz-style: a keyframe or topology edit damaged in any way (bytes flipped, cut short, values
//! changed) is refused with an error when it is decoded or restored, or restores into a
//! simulation that then steps; it never panics.

use incise_convert::keyframe::{edit_from_message, keyframe_from_message};
use incise_protocol::v1;
use incise_replay::simulation;
use incise_sim::StepInputs;
use prost::Message;
use std::path::Path;

/// A small deterministic generator (xorshift64*).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

#[test]
fn damaged_keyframes_and_edits_are_refused_or_restored_never_a_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../recordings");
    let bytes = std::fs::read(dir.join("demo_press_cut_grasp.mcap")).unwrap();
    let contents = incise_record::read_recording_at(&bytes, Some(1000)).unwrap();
    let keyframe = contents.keyframe.clone().expect("the demo recording has a keyframe at 1 s");
    let encoded = keyframe.encode_to_vec();
    let mut sim = simulation(&contents, &dir).unwrap();
    for edit in contents.edits.iter().filter(|e| e.frame <= keyframe.frame) {
        let (grid, tets) = edit_from_message(edit).unwrap();
        sim.apply_edit(&grid, &tets).unwrap();
    }
    let pristine = keyframe_from_message(&keyframe).unwrap();
    sim.restore(&pristine).expect("the recorded keyframe restores");

    let mut rng = Rng(0x5eed_1234_abcd_0001);
    let (mut refused, mut restored) = (0, 0);
    for round in 0..300 {
        // Bytes: flipped, or the message cut short; then values, through the message's fields.
        let mut damaged = encoded.clone();
        match round % 3 {
            0 => {
                for _ in 0..=rng.below(8) {
                    let at = rng.below(damaged.len());
                    damaged[at] ^= 1 << rng.below(8);
                }
            }
            1 => damaged.truncate(rng.below(damaged.len())),
            _ => {}
        }
        let Ok(mut message) = v1::Keyframe::decode(&*damaged) else {
            refused += 1;
            continue;
        };
        if round % 3 == 2 {
            damage_values(&mut message, &mut rng);
        }
        let outcome = keyframe_from_message(&message).and_then(|k| {
            // Each try on a simulation at the keyframe's topology, restored cleanly first.
            sim.restore(&pristine).unwrap();
            sim.restore(&k).map_err(|e| e.to_string())
        });
        if let Err(e) = outcome {
            assert!(!e.is_empty());
            refused += 1;
        } else {
            // What restored steps (whatever its physics makes of it).
            for _ in 0..3 {
                let _ = sim.step(&StepInputs::default());
            }
            restored += 1;
        }
    }
    println!("{refused} refused, {restored} restored and stepped");
    assert!(refused > 100, "most damage is refused ({refused})");

    // Edits: odd link lists are refused; voxels beyond the volume are refused by the grid.
    let bad = v1::TopologyEdit { frame: 7, severed_links: vec![1, 2, 3], ..Default::default() };
    assert!(edit_from_message(&bad).unwrap_err().contains("frame 7"));
    let far = v1::TopologyEdit { frame: 8, removed_voxels: vec![u32::MAX], ..Default::default() };
    let (grid, tets) = edit_from_message(&far).unwrap();
    let mut fresh = simulation(&contents, &dir).unwrap();
    assert!(fresh.apply_edit(&grid, &tets).is_err());
}

/// Changes one value of `m` at random: a length, a tool's pose or points, a count.
fn damage_values(m: &mut v1::Keyframe, rng: &mut Rng) {
    match rng.below(8) {
        0 => {
            m.positions.pop();
        }
        1 => m
            .element_rotations
            .truncate(m.element_rotations.len().saturating_sub(1 + rng.below(12))),
        2 => m.warm_start.push(v1::NodeVectors { values: vec![0.0; 3 * (1 + rng.below(10))] }),
        3 => {
            if let Some(t) = m.tools.get_mut(rng.below(2)) {
                t.position.push(1.0);
            }
        }
        4 => {
            if let Some(t) = m.tools.get_mut(rng.below(2)) {
                t.gripper = f64::NAN;
            }
        }
        5 => {
            if let Some(t) = m.tools.get_mut(rng.below(2)) {
                // A proxy pose one value short, or not finite.
                if t.proxy.len() == 7 && rng.below(2) == 0 {
                    t.proxy[rng.below(7)] = f64::NAN;
                } else {
                    t.proxy.truncate(6);
                }
            }
        }
        6 => {
            if let Some(t) = m.tools.get_mut(rng.below(2)) {
                // Held points of vertices the surface does not have: let go of, never read.
                t.held_vertices.push(u32::MAX - 1);
                t.held_anchors.extend([0.0, 0.0, 0.0]);
            }
        }
        _ => m.tools.truncate(rng.below(2)),
    }
}
