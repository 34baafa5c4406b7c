//! `incise-tool` as its own process against a real server (started in this test's process on
//! loopback, both transports): it presses the organ over each transport, every answered pose is
//! timed, the tissue pushes back; and a broken pose file is refused naming its line.

use incise_server::server::{self, Options};
use incise_transport::zenoh_link::Endpoints;
use std::process::Command;

/// The servers these tests start all serve the scene `demo_organ`, and iceoryx2 services are
/// named by scene: two at once would share them. The tests that start one take turns.
static ONE_SERVER: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The embedded scene served on a free loopback port, once the other tests' servers are gone:
/// the turn, the server and its zenoh endpoint.
fn demo_server() -> (std::sync::MutexGuard<'static, ()>, server::Running, String) {
    let turn = ONE_SERVER.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let port = free_port();
    let options = Options { zenoh: Some(Endpoints::listen_loopback(port)), ..Options::default() };
    let scene = incise_server::scene::load(None).unwrap();
    let running = server::start(&scene, "<embedded>", &options).unwrap();
    (turn, running, format!("tcp/127.0.0.1:{port}"))
}

#[test]
fn incise_tool_presses_the_organ_over_both_transports() {
    let (_turn, running, endpoint) = demo_server();
    for transport in ["iceoryx2", "zenoh"] {
        let out = Command::new(env!("CARGO_BIN_EXE_incise-tool"))
            .args(["--transport", transport, "--connect", &endpoint, "--tool", "1"])
            .args(["--script", "press", "--depth", "0.004", "--duration", "2", "--json"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{transport}: {}\n{stdout}",
            String::from_utf8_lossy(&out.stderr)
        );
        let last = stdout.lines().last().unwrap();
        let j: serde_json::Value = serde_json::from_str(last).unwrap();
        println!("{transport}: {last}");
        assert_eq!(j["transport"], transport);
        assert!(j["sent"].as_u64().unwrap() > 500, "{j}");
        assert!(j["samples"].as_u64().unwrap() > 100, "{j}");
        assert!(j["max_force_n"].as_f64().unwrap() > 0.0, "never in contact: {j}");
        for key in ["rtt_us_p50", "rtt_us_p99", "rtt_us_p999", "rtt_us_max"] {
            assert!(j[key].as_f64().unwrap() > 0.0, "{key}: {j}");
        }
    }
    running.stop();
}

#[test]
fn a_broken_pose_file_is_refused_naming_its_line() {
    let dir = std::env::temp_dir().join(format!("incise_tool_csv_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("poses.csv");
    std::fs::write(
        &file,
        "t,x,y,z,qw,qx,qy,qz,gripper\n0,0,0,0.05,1,0,0,0,0\n0.5,0,0,oops,1,0,0,0,0\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_incise-tool"))
        .args(["--script", file.to_str().unwrap(), "--at", "0,0,0", "--duration", "0.1"])
        .args(["--connect", &format!("tcp/127.0.0.1:{}", free_port())])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("poses.csv:3: column 4 is \"oops\""), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A client killed with SIGKILL while it presses the organ: the server stays up, and the tool's
/// force, watched by a second client that only listens, fades. Every force the server computed
/// 50 ms or more (its own clock) after the last one answering a live pose is zero.
#[test]
fn a_client_killed_mid_contact_leaves_a_force_that_fades_to_zero() {
    use incise_client::{Client, Keys, TransportKind};
    use incise_protocol::v1::ForceFlag;
    use std::time::{Duration, Instant};
    let (_turn, running, endpoint) = demo_server();
    let watcher =
        Client::connect(TransportKind::Zenoh, &Keys::new("demo_organ").unwrap(), 1, &endpoint)
            .unwrap();
    let mut tool = Command::new(env!("CARGO_BIN_EXE_incise-tool"))
        .args(["--transport", "iceoryx2", "--connect", &endpoint, "--tool", "1"])
        .args(["--script", "press", "--depth", "0.004", "--duration", "20", "--print-every", "0"])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Watch until the tool is in contact (a live force, not stale, pushing).
    let until = Instant::now() + Duration::from_mins(1);
    loop {
        if let Some(f) = watcher.recv_force(Duration::from_millis(100))
            && f.flags & ForceFlag::Stale as u32 == 0
            && f.force[2] > 1e-3
        {
            break;
        }
        assert!(Instant::now() < until, "the tool never pressed the organ");
    }
    tool.kill().unwrap();
    tool.wait().unwrap();
    let mut last_live = 0u64;
    let until = Instant::now() + Duration::from_secs(10);
    let zero = loop {
        let f = watcher.recv_force(Duration::from_millis(200)).expect("forces keep coming");
        assert!(f.force.iter().all(|c| c.is_finite()));
        if f.flags & ForceFlag::Stale as u32 == 0 {
            last_live = f.timestamp_ns;
        } else if f.force.iter().all(|&c| c == 0.0) {
            break f;
        }
        let after_ms = f.timestamp_ns.saturating_sub(last_live) as f64 * 1e-6;
        assert!(after_ms < 50.0 || f.force.iter().all(|&c| c == 0.0), "{after_ms} ms: {f:?}");
        assert!(Instant::now() < until, "the force never faded");
    };
    println!(
        "zero {:.1} ms (server clock) after the last live force",
        (zero.timestamp_ns - last_live) as f64 * 1e-6
    );
    running.stop();
}

/// Two `incise-tool` processes claim the scalpel: the first drives it; the second's poses (over
/// the other transport) are refused and counted while the first's keep coming, and the first
/// stays answered throughout. Once the first has finished and fallen silent, the tool passes to
/// the next client that asks.
#[test]
fn a_second_client_cannot_take_a_tool_that_another_drives() {
    use std::sync::atomic::Ordering;
    let (_turn, running, endpoint) = demo_server();
    let tool = |transport: &str, duration: &str| {
        Command::new(env!("CARGO_BIN_EXE_incise-tool"))
            .args(["--transport", transport, "--connect", &endpoint, "--tool", "0"])
            .args(["--script", "press", "--depth", "0.002", "--duration", duration])
            .args(["--print-every", "0", "--json"])
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let report = |child: std::process::Child| {
        let out = child.wait_with_output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{stdout}");
        let j: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
        j
    };
    let counters = &running.shared.counters;
    let first = tool("iceoryx2", "4");
    // The second starts once the first's poses are arriving.
    let until = std::time::Instant::now() + std::time::Duration::from_mins(1);
    while counters.poses.load(Ordering::Relaxed) < 200 {
        assert!(std::time::Instant::now() < until, "the first client's poses never came");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let second = report(tool("zenoh", "1"));
    let first = report(first);
    let claimed = counters.claimed.load(Ordering::Relaxed);
    println!("first: {first}\nsecond: {second}\nrefused as claimed: {claimed}");
    assert_eq!(second["samples"], 0, "the second client's poses were answered: {second}");
    assert!(claimed > 500, "{claimed} of the second client's ~1000 poses refused");
    let (sent, answered) = (first["sent"].as_u64().unwrap(), first["samples"].as_u64().unwrap());
    assert!(answered * 10 > sent * 9, "the first client lost its answers: {first}");
    // The first has finished: the next client drives the tool.
    let third = report(tool("zenoh", "1"));
    println!("third: {third}");
    assert!(third["samples"].as_u64().unwrap() > 100, "{third}");
    assert_eq!(counters.handovers.load(Ordering::Relaxed), 1);
    running.stop();
}

/// The async client, on a plain executor (no runtime of its own): over each transport, every
/// pose's answer is awaited and names it; above the organ the force is zero.
#[test]
fn the_async_client_awaits_the_force_answering_each_pose() {
    use incise_client::raw::RawToolPose;
    use incise_client::{AsyncClient, Keys, TransportKind};
    let (_turn, running, endpoint) = demo_server();
    let keys = Keys::new("demo_organ").unwrap();
    for kind in [TransportKind::Iceoryx2, TransportKind::Zenoh] {
        let client = AsyncClient::connect(kind, &keys, 1, &endpoint).unwrap();
        assert_ne!(client.client().session(), 0);
        let answered = futures::executor::block_on(async {
            let mut answered = 0;
            for sequence in 1..=50u64 {
                let pose = RawToolPose {
                    sequence,
                    timestamp_ns: sequence,
                    ..RawToolPose::at(1, [0.04, 0.03, 0.2])
                };
                // A subscription may take a moment to reach the other side: resend until the
                // answer comes (the haptic loop's ticks keep forces coming meanwhile).
                for _ in 0..2000 {
                    client.send_pose(&pose).unwrap();
                    let force = client.recv_force().await.expect("the connection is open");
                    if force.pose_sequence == sequence {
                        assert!(force.force.iter().all(|&c| c == 0.0), "20 cm above: {force:?}");
                        answered += 1;
                        break;
                    }
                }
            }
            answered
        });
        println!("{}: {answered} of 50 poses answered", kind.name());
        assert_eq!(answered, 50, "over {}", kind.name());
    }
    running.stop();
}
