//! Recordings written and read back as real MCAP files: every frame and cut comes back in order
//! with the scene and the metadata, the schemas are embedded, a file cut short gives what came
//! before its last complete chunk, and damaged, foreign or future files are refused, never a
//! panic.

use incise_protocol::v1;
use incise_record::{McapRecording, ReadError, Record, Recorder, Session, read_recording};
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::path::PathBuf;

fn session() -> Session {
    Session {
        scene: "test_scene".into(),
        scene_toml: "name = \"test_scene\"\n[volume]\nprocedural = \"organ\"\n".into(),
        version: "0.1.0".into(),
        git_revision: "abc123".into(),
        tools: Vec::new(),
        scene_interval_s: 0.1,
        files: Vec::new(),
    }
}

fn frame(i: u64) -> v1::FrameRecord {
    let v = |x: f64| Some(v1::Vec3 { x, y: -x, z: 0.5 * x });
    v1::FrameRecord {
        frame: i,
        sim_time_s: i as f64 * 1e-3,
        poses: vec![v1::ToolPose {
            tool_id: 0,
            sequence: i + 7,
            timestamp_ns: i * 1_000_000,
            position: v(i as f64 * 1e-4),
            orientation: Some(v1::Quaternion { w: 1.0, x: 0.0, y: 0.0, z: 0.0 }),
            client: 42,
            ..Default::default()
        }],
        tools: vec![v1::ToolState {
            tool_id: 0,
            force: v(0.01 * i as f64),
            torque: v(0.0),
            flags: 1,
            contact_points: (i % 5) as u32,
            held_points: 0,
            proxy: Some(v1::Pose::of([0.0, 0.0, i as f64 * 1e-4 + 0.001], [1.0, 0.0, 0.0, 0.0])),
        }],
        state_hash: i.wrapping_mul(0x9e37_79b9_7f4a_7c15),
        stats: Some(v1::FrameStats { frame: i, frame_ms: 0.2, ..Default::default() }),
    }
}

fn cut(i: u64) -> v1::CutEvent {
    v1::CutEvent { frame: i, tool_id: 0, voxels_removed: 3, ..Default::default() }
}

/// A file `name` in a fresh directory that is removed with the returned guard (also when the
/// test fails).
fn temp(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::Builder::new().prefix("incise_record_").tempdir().unwrap();
    let path = dir.path().join(name);
    (dir, path)
}

/// 600 frames and 3 cuts through the recorder thread, written to `name` and read back.
fn recorded(name: &str) -> (Vec<u8>, Vec<v1::FrameRecord>) {
    let (_dir, path) = temp(name);
    let recorder = Recorder::start(McapRecording::create(&path, &session()).unwrap()).unwrap();
    let handle = recorder.handle();
    let frames: Vec<_> = (0..600).map(frame).collect();
    for f in &frames {
        handle.record(Record::Frame(f.clone()));
        if f.frame % 200 == 100 {
            handle.record(Record::Cut(cut(f.frame), f.sim_time_s));
        }
    }
    drop(handle);
    assert_eq!(recorder.finish().unwrap(), 600);
    (std::fs::read(&path).unwrap(), frames)
}

#[test]
fn a_recording_reads_back_whole_with_its_scene_metadata_and_schemas() {
    let (bytes, frames) = recorded("whole.mcap");
    let contents = read_recording(&bytes).unwrap();
    assert!(contents.truncated.is_none(), "{:?}", contents.truncated);
    assert_eq!(contents.frames, frames);
    let cuts: Vec<u64> = contents.cuts.iter().map(|(c, _)| c.frame).collect();
    assert_eq!(cuts, [100, 300, 500]);
    assert_eq!(contents.cuts[0].1, 100_000_000, "log time is simulated time (ns)");
    assert_eq!(contents.scene_toml.as_deref(), Some(session().scene_toml.as_str()));
    assert_eq!(contents.metadata["git_revision"], "abc123");
    assert_eq!(contents.metadata["protocol"], "incise.v1");
    assert_eq!(contents.metadata["scene_hash"], format!("{:016x}", session().scene_hash()));
    // Every channel carries protobuf with the protocol's descriptor set as its schema.
    let mut topics = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().expect("a schema");
        assert_eq!(
            (schema.encoding.as_str(), m.channel.message_encoding.as_str()),
            ("protobuf", "protobuf")
        );
        assert_eq!(&*schema.data, incise_protocol::DESCRIPTOR_SET);
        *topics.entry((m.channel.topic.clone(), schema.name.clone())).or_insert(0) += 1;
    }
    assert_eq!(topics[&("/incise/frame".into(), "incise.v1.FrameRecord".into())], 600);
    assert_eq!(topics[&("/incise/cut".into(), "incise.v1.CutEvent".into())], 3);
}

/// A crash: the file as it stands after a chunk was closed and more frames were written into the
/// next, still open. Everything up to the closed chunk reads back.
#[test]
fn frames_in_closed_chunks_survive_a_crash() {
    let (_dir, path) = temp("crash.mcap");
    let mut recording = McapRecording::create(&path, &session()).unwrap();
    for i in 0..100 {
        recording.frame(&frame(i)).unwrap();
    }
    recording.close_chunk().unwrap();
    for i in 100..150 {
        recording.frame(&frame(i)).unwrap();
    }
    // The process dies here: what is on disk is what a reader gets.
    let on_disk = std::fs::read(&path).unwrap();
    std::mem::forget(recording);
    let contents = read_recording(&on_disk).unwrap();
    assert!(contents.frames.len() >= 100, "{} frames", contents.frames.len());
    assert_eq!(
        contents.frames[..],
        (0..contents.frames.len() as u64).map(frame).collect::<Vec<_>>()[..]
    );
    assert!(contents.truncated.is_some() || contents.frames.len() == 150);
}

#[test]
fn foreign_and_future_files_are_refused_by_name() {
    assert!(matches!(read_recording(b"not an mcap file"), Err(ReadError::NotMcap(_))));
    let mcap_without = |metadata: Option<(&str, &str)>| {
        let mut w = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
        if let Some((k, v)) = metadata {
            let metadata = BTreeMap::from([(k.to_owned(), v.to_owned())]);
            w.write_metadata(&mcap::records::Metadata { name: "incise".into(), metadata }).unwrap();
        }
        let ch = w.add_channel(0, "/camera", "raw", &BTreeMap::new()).unwrap();
        let header = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: 1,
            log_time: 1,
            publish_time: 1,
        };
        w.write_to_known_channel(&header, &[1, 2, 3]).unwrap();
        w.finish().unwrap();
        w.into_inner().into_inner()
    };
    assert_eq!(read_recording(&mcap_without(None)).unwrap_err(), ReadError::Foreign);
    let future = read_recording(&mcap_without(Some(("protocol", "incise.v9")))).unwrap_err();
    assert!(
        matches!(&future, ReadError::Version { found, .. } if found == "incise.v9"),
        "{future}"
    );
    println!("{future}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Fuzz-style: a recording cut at any length reads as a prefix of its frames or is refused;
    /// with bytes overwritten anywhere it reads or is refused; never a panic.
    #[test]
    fn a_damaged_recording_is_read_or_refused_never_a_panic(
        cut_at in 0.0..1.0f64,
        flips in proptest::collection::vec((0.0..1.0f64, any::<u8>()), 0..8),
    ) {
        static RECORDED: std::sync::OnceLock<(Vec<u8>, Vec<v1::FrameRecord>)> = std::sync::OnceLock::new();
        let (bytes, frames) = RECORDED.get_or_init(|| recorded("fuzzed.mcap"));
        let cut = &bytes[..(cut_at * bytes.len() as f64) as usize];
        if let Ok(c) = read_recording(cut) {
            prop_assert!(c.frames.len() <= frames.len());
            prop_assert_eq!(&c.frames[..], &frames[..c.frames.len()]);
        }
        let mut damaged = bytes.clone();
        for (at, byte) in flips {
            let i = ((at * damaged.len() as f64) as usize).min(damaged.len() - 1);
            damaged[i] = byte;
        }
        let _ = read_recording(&damaged);
    }
}
