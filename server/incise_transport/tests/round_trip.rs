//! Each transport end to end in one process (the server-side ports and a client's, on real
//! zenoh sessions over loopback TCP and real iceoryx2 services): a pose reaches the handler,
//! a force sent for it reaches the client and names the pose, the scene's description is
//! answered, and refused input is counted by kind.

use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_protocol::v1;
use incise_transport::shm::{ShmPorts, ShmServer};
use incise_transport::zenoh_link::{Endpoints, ZenohServer};
use incise_transport::{Client, Faults, PoseHandler, TransportKind};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The poses a handler was given.
type Seen = Arc<Mutex<Vec<(TransportKind, RawToolPose)>>>;

/// A handler that keeps every pose it is given, for tools 0 and 1.
fn recorder() -> (PoseHandler, Seen) {
    let seen = Arc::new(Mutex::new(Vec::new()));
    let kept = Arc::clone(&seen);
    let handler: PoseHandler = Arc::new(move |kind, pose: &RawToolPose| {
        kept.lock().unwrap().push((kind, *pose));
        pose.tool_id < 2
    });
    (handler, seen)
}

fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
    let until = Instant::now() + Duration::from_secs(10);
    while !done() {
        assert!(Instant::now() < until, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn pose(tool: u32, sequence: u64) -> RawToolPose {
    RawToolPose { sequence, timestamp_ns: sequence, ..RawToolPose::at(tool, [0.01, 0.02, 0.03]) }
}

fn answer(pose: &RawToolPose) -> RawToolForce {
    RawToolForce {
        pose_sequence: pose.sequence,
        timestamp_ns: 1,
        force: [0.0, 0.0, 1.5],
        torque: [0.0; 3],
        gripper_force: 0.0,
        tool_id: pose.tool_id,
        flags: 1,
    }
}

/// The force for `pose`, sent until the client has it (the first sends may go before the
/// client's subscription is known to the publisher).
fn exchange(client: &Client, send: &dyn Fn(&RawToolForce), pose: &RawToolPose) -> RawToolForce {
    let until = Instant::now() + Duration::from_secs(10);
    loop {
        send(&answer(pose));
        if let Some(f) = client.recv_force(Duration::from_millis(50))
            && f.pose_sequence == pose.sequence
        {
            return f;
        }
        assert!(Instant::now() < until, "no force came back");
    }
}

#[test]
fn zenoh_carries_poses_forces_and_the_scene_info_and_counts_garbage() {
    let keys = Keys::new(&format!("zenoh_rt_{}", std::process::id())).unwrap();
    let port = free_port();
    let (handler, seen) = recorder();
    let faults = Arc::new(Faults::default());
    let info =
        v1::SceneInfo { scene: keys.scene().into(), length_unit: "m".into(), ..Default::default() };
    let server = ZenohServer::start(
        &keys,
        2,
        &info,
        &Endpoints::listen_loopback(port),
        handler,
        Arc::clone(&faults),
    )
    .unwrap();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let client = Client::connect(TransportKind::Zenoh, &keys, 1, &endpoint).unwrap();
    // The subscription may take a moment to reach the server: resend until a pose arrives.
    let mut sequence = 0;
    wait_for("a pose over zenoh", || {
        sequence += 1;
        client.send_pose(&pose(1, sequence)).unwrap();
        std::thread::sleep(Duration::from_millis(5));
        !seen.lock().unwrap().is_empty()
    });
    let (kind, got) = seen.lock().unwrap()[0];
    assert_eq!(kind, TransportKind::Zenoh);
    assert_eq!(got.tool_id, 1);
    assert_eq!(got.client, client.session(), "the pose carries the client's session");
    let f = exchange(&client, &|f| server.send_force(f), &got);
    assert_eq!(f, answer(&got), "the force arrives bit for bit");
    let Client::Zenoh(z) = &client else { unreachable!() };
    assert_eq!(z.scene_info(Duration::from_secs(5)).unwrap().scene, keys.scene());
    // Garbage on the pose key: oversized, malformed, incomplete; and a pose for another tool.
    z.send_bytes(&[0u8; 4000]).unwrap();
    z.send_bytes(&[0xff, 0xff, 0xff]).unwrap();
    z.send_bytes(&prost::Message::encode_to_vec(&v1::ToolPose::default())).unwrap();
    client.send_pose(&pose(0, 99)).unwrap();
    wait_for("the refusals to be counted", || {
        faults.oversized.load(Ordering::Relaxed) == 1
            && faults.malformed.load(Ordering::Relaxed) == 1
            && faults.incomplete.load(Ordering::Relaxed) == 1
            && faults.mismatched.load(Ordering::Relaxed) == 1
    });
}

#[test]
fn iceoryx2_carries_poses_and_forces_and_counts_unknown_tools() {
    let keys = Keys::new(&format!("shm_rt_{}", std::process::id())).unwrap();
    let (handler, seen) = recorder();
    let faults = Arc::new(Faults::default());
    // Three tools' services, but the handler knows only tools 0 and 1. The ports live on this
    // thread, as they do on the server's haptic thread.
    let server = ShmServer::start(&keys, 3, Arc::clone(&faults)).unwrap();
    let ports = server.open_ports().unwrap();
    let take = |ports: &ShmPorts| {
        ports.wait(Duration::from_millis(2));
        ports.receive(|p| handler(TransportKind::Iceoryx2, p));
    };
    let client = Client::connect(TransportKind::Iceoryx2, &keys, 0, "").unwrap();
    client.send_pose(&pose(0, 1)).unwrap();
    wait_for("a pose over iceoryx2", || {
        take(&ports);
        !seen.lock().unwrap().is_empty()
    });
    let (kind, got) = seen.lock().unwrap()[0];
    // The pose arrives bit for bit, stamped with the client's session.
    let sent = RawToolPose { client: client.session(), ..pose(0, 1) };
    assert_ne!(sent.client, 0);
    assert_eq!((kind, got), (TransportKind::Iceoryx2, sent));
    let f = exchange(&client, &|f| ports.send_force(f), &got);
    assert_eq!(f, answer(&got));
    let stranger = Client::connect(TransportKind::Iceoryx2, &keys, 2, "").unwrap();
    stranger.send_pose(&pose(2, 1)).unwrap();
    wait_for("the unknown tool to be counted", || {
        take(&ports);
        faults.unknown_tool.load(Ordering::Relaxed) == 1
    });
    // Another thread's ring wakes the ports' holder well before its timeout.
    std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(Duration::from_millis(20));
            server.ring();
        });
        let started = Instant::now();
        ports.wait(Duration::from_secs(20));
        assert!(started.elapsed() < Duration::from_secs(10), "the ring did not wake the wait");
    });
}
