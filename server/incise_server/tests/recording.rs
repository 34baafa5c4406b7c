//! `incise-server --record DIR` killed with SIGKILL mid-session, a tool in contact: the MCAP file
//! it leaves holds every frame up to its last closed chunk, in order, none missing, and reads
//! without the summary the server never wrote.

use incise_protocol::keys::Keys;
use incise_protocol::raw::RawToolPose;
use incise_transport::{Client, TransportKind};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_recording_survives_sigkill_up_to_its_last_closed_chunk() {
    let dir = std::env::temp_dir().join(format!("incise_sigkill_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // zenoh only: the other tests' demo_organ servers serve iceoryx2.
    let mut server = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--listen", &endpoint, "--no-iceoryx2", "--stop-with-parent", "--record"])
        .arg(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let keys = Keys::new("demo_organ").unwrap();
    let until = Instant::now() + Duration::from_mins(1);
    let client = loop {
        if let Ok(c) = Client::connect(TransportKind::Zenoh, &keys, 1, &endpoint)
            && let Client::Zenoh(z) = &c
            && z.scene_info(Duration::from_millis(500)).is_ok()
        {
            break c;
        }
        assert!(Instant::now() < until, "the server never answered");
        std::thread::sleep(Duration::from_millis(100));
    };
    // The grasper pressed into the organ's top for a second and a half, and until the physics
    // has stepped 1,500 frames (a loaded machine runs it below 1 kHz), then the kill.
    let started = Instant::now();
    let mut sequence = 0;
    let mut stepped = 0;
    let mut asked = Instant::now();
    while started.elapsed() < Duration::from_millis(1500) || stepped < 1500 {
        assert!(started.elapsed() < Duration::from_mins(1), "the physics stepped {stepped} frames");
        if asked.elapsed() > Duration::from_millis(200)
            && let Client::Zenoh(z) = &client
            && let Ok(stats) = z.server_stats(Duration::from_millis(500))
        {
            stepped = stats.frames;
            asked = Instant::now();
        }
        sequence += 1;
        let pose = RawToolPose {
            sequence,
            timestamp_ns: sequence,
            ..RawToolPose::at(1, [0.04, 0.03, 0.049])
        };
        client.send_pose(&pose).unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    server.kill().unwrap();
    server.wait().unwrap();
    let files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    assert_eq!(files.len(), 1, "{files:?}");
    let bytes = std::fs::read(&files[0]).unwrap();
    let contents = incise_record::read_recording(&bytes).unwrap();
    println!(
        "{} bytes, {} frames; truncated: {:?}",
        bytes.len(),
        contents.frames.len(),
        contents.truncated
    );
    // Chunks close every 250 frames or 250 ms; the physics stepped at least 1,500 frames, so
    // more than 1,000 of them are in closed chunks.
    assert!(contents.frames.len() > 1000, "{} frames", contents.frames.len());
    for (i, f) in contents.frames.iter().enumerate() {
        assert_eq!(f.frame, i as u64 + 1, "frames in order from 1, none missing");
    }
    assert!(
        contents.frames.iter().any(|f| f.poses.iter().any(|p| p.tool_id == 1)),
        "the grasper's poses are in the frames"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
