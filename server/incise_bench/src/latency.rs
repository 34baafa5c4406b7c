//! `incise-bench latency`: a real server on the liver (`deploy/scenes/liver_tools.toml`) and a
//! client in another process, over zenoh or iceoryx2. The client sends its scalpel's poses at
//! 1 kHz for a bounded time while it presses and cuts, and times each pose's round trip to the
//! force that answers it; the server measures its haptic thread's period jitter while the
//! physics runs. Both processes are this program, started again in a hidden role
//! (`latency-server`, `latency-client`), so the one command needs nothing else built.
//!
//! Then, unless `--no-floor`, the same client drives an echo server (`latency-echo`: the same
//! transport, a force sent back the moment a pose arrives, no physics, no haptic loop) for the
//! same time: the round trip this machine's scheduler and the transport alone give, measured in
//! the same run, against which the server's figures read.

use anyhow::{Context, bail};
use incise_client::drive::drive;
use incise_client::script::Script;
use incise_client::{Client, Keys, TransportKind};
use incise_server::server::{self, Options};
use incise_transport::zenoh_link::Endpoints;
use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `latency`'s options.
#[derive(clap::Args, Debug)]
pub struct LatencyArgs {
    /// `iceoryx2` (shared memory) or `zenoh` (loopback TCP).
    #[arg(long, default_value = "iceoryx2")]
    transport: TransportKind,
    /// The scene the server runs (it must have a tool 0).
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes/liver_tools.toml"))]
    scene: String,
    /// Seconds of poses (bounded: at most 60).
    #[arg(long, default_value_t = 5.0)]
    duration: f64,
    /// End with one line of JSON: `transport`, `rtt_us_p50`, `rtt_us_p99`, `rtt_us_p999`,
    /// `rtt_us_max`, `jitter_us_p99`, `samples` (and `floor_us_p50`, `floor_us_p99`,
    /// `floor_us_p999` unless `--no-floor`).
    #[arg(long)]
    json: bool,
    /// Skip the echo server's floor measurement.
    #[arg(long)]
    no_floor: bool,
}

/// The hidden echo role's options.
#[derive(clap::Args, Debug)]
pub struct EchoRole {
    #[arg(long)]
    transport: TransportKind,
    #[arg(long)]
    listen: String,
    #[arg(long)]
    scene_name: String,
}

/// The hidden server role's options.
#[derive(clap::Args, Debug)]
pub struct ServerRole {
    #[arg(long)]
    scene: String,
    #[arg(long)]
    listen: String,
}

/// The hidden client role's options.
#[derive(clap::Args, Debug)]
pub struct ClientRole {
    #[arg(long)]
    transport: TransportKind,
    #[arg(long)]
    connect: String,
    #[arg(long)]
    scene_name: String,
    #[arg(long)]
    duration: f64,
    /// Drive the echo server: a fixed pose, no scene to ask about.
    #[arg(long)]
    echo: bool,
}

/// A half turn about x: the tool's +z (its blade, from the edge at its origin) points down
/// the grid's −z, so the edge leads upwards.
const BLADE_UP: [f64; 4] = [0.0, 1.0, 0.0, 0.0];

fn free_port() -> anyhow::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// Runs the report.
pub fn run(args: &LatencyArgs) -> anyhow::Result<()> {
    if !(args.duration.is_finite() && args.duration > 0.0 && args.duration <= 60.0) {
        bail!("--duration must be between 0 and 60 s");
    }
    let scene = incise_scene::read_scene(args.scene.as_ref())
        .with_context(|| format!("--scene {}", args.scene))?;
    anyhow::ensure!(
        !scene.config.tools.is_empty(),
        "--scene {}: it has no tool to drive",
        args.scene
    );
    let name = scene.config.name.clone();
    let exe = std::env::current_exe()?;
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    eprintln!(
        "latency: server on {} ({endpoint}), client over {}",
        args.scene,
        args.transport.name()
    );
    let server_args = ["latency-server", "--scene", &args.scene, "--listen", &endpoint];
    let (client, rest) =
        with_server(&exe, &server_args, |exe| run_client(exe, args, &endpoint, &name, false))?;
    let floor = if args.no_floor {
        None
    } else {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
        let scene_name = format!("latency_floor_{}", std::process::id());
        eprintln!("latency: echo server over {} (the transport's floor)", args.transport.name());
        let echo_args = [
            "latency-echo",
            "--transport",
            args.transport.name(),
            "--listen",
            &endpoint,
            "--scene-name",
            &scene_name,
        ];
        let (floor, _) = with_server(&exe, &echo_args, |exe| {
            run_client(exe, args, &endpoint, &scene_name, true)
        })?;
        Some(floor)
    };
    let parse = |text: &str, who: &str| -> anyhow::Result<serde_json::Value> {
        let last = text.lines().last().with_context(|| format!("the {who} printed nothing"))?;
        serde_json::from_str(last).with_context(|| format!("the {who}'s last line: {last}"))
    };
    let c = parse(&client, "client")?;
    let s = parse(&rest, "server")?;
    let floor = floor.map(|text| parse(&text, "floor client")).transpose()?;
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    println!(
        "latency over {} ({} for {:.1} s, client and server in separate processes)",
        args.transport.name(),
        args.scene,
        args.duration
    );
    println!("pose → force round trip: {} samples of {} poses", c["samples"], c["sent"]);
    println!(
        "  p50 {:.0} µs   p99 {:.0} µs   p99.9 {:.0} µs   max {:.0} µs",
        f(&c, "rtt_us_p50"),
        f(&c, "rtt_us_p99"),
        f(&c, "rtt_us_p999"),
        f(&c, "rtt_us_max")
    );
    println!(
        "haptic period jitter while the physics ran: p50 {:.0} µs   p99 {:.0} µs   max {:.0} µs ({} physics frames, {} late)",
        f(&s, "jitter_us_p50"),
        f(&s, "jitter_us_p99"),
        f(&s, "jitter_us_max"),
        s["frames"],
        s["late"]
    );
    println!("max force {:.3} N; voxels cut {}", f(&c, "max_force_n"), s["removed"]);
    if let Some(e) = &floor {
        println!(
            "transport floor (an echo server answering at once, no physics): p50 {:.0} µs   p99 {:.0} µs   p99.9 {:.0} µs ({} samples); the server adds p50 {:+.0} µs, p99 {:+.0} µs",
            f(e, "rtt_us_p50"),
            f(e, "rtt_us_p99"),
            f(e, "rtt_us_p999"),
            e["samples"],
            f(&c, "rtt_us_p50") - f(e, "rtt_us_p50"),
            f(&c, "rtt_us_p99") - f(e, "rtt_us_p99"),
        );
    }
    if args.json {
        let json = serde_json::json!({
            "transport": args.transport.name(),
            "rtt_us_p50": c["rtt_us_p50"],
            "rtt_us_p99": c["rtt_us_p99"],
            "rtt_us_p999": c["rtt_us_p999"],
            "rtt_us_max": c["rtt_us_max"],
            "jitter_us_p99": s["jitter_us_p99"],
            "samples": c["samples"],
            "sent": c["sent"],
            "max_force_n": c["max_force_n"],
            "frames": s["frames"],
            "floor_us_p50": floor.as_ref().map(|e| e["rtt_us_p50"].clone()),
            "floor_us_p99": floor.as_ref().map(|e| e["rtt_us_p99"].clone()),
            "floor_us_p999": floor.as_ref().map(|e| e["rtt_us_p999"].clone()),
        });
        println!("{json}");
    }
    Ok(())
}

/// Starts this program in a server role (`args`), waits for its `ready`, runs `during`, then
/// closes the server's input (it stops) and returns what `during` returned and everything the
/// server printed after `ready`.
fn with_server<T>(
    exe: &std::path::Path,
    args: &[&str],
    during: impl FnOnce(&std::path::Path) -> anyhow::Result<T>,
) -> anyhow::Result<(T, String)> {
    let mut server = Command::new(exe)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()?;
    let mut lines = BufReader::new(server.stdout.take().expect("piped"));
    let mut line = String::new();
    lines.read_line(&mut line)?;
    if line.trim() != "ready" {
        let _ = server.kill();
        bail!("the {} did not start: {line}", args[0]);
    }
    let result = during(exe);
    drop(server.stdin.take()); // the server stops when its input closes
    let mut rest = String::new();
    lines.read_to_string(&mut rest)?;
    server.wait()?;
    Ok((result?, rest))
}

/// Runs the client role against `endpoint`'s scene `scene_name`; its standard output.
fn run_client(
    exe: &std::path::Path,
    args: &LatencyArgs,
    endpoint: &str,
    scene_name: &str,
    echo: bool,
) -> anyhow::Result<String> {
    let mut command = Command::new(exe);
    command
        .args(["latency-client", "--transport", args.transport.name(), "--connect", endpoint])
        .args(["--scene-name", scene_name, "--duration", &args.duration.to_string()]);
    if echo {
        command.arg("--echo");
    }
    let out = command.output()?;
    anyhow::ensure!(
        out.status.success(),
        "the client failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The echo role: serves one tool over one transport and answers every pose with a zero force
/// the moment it arrives, until its standard input closes.
pub fn echo(role: &EchoRole) -> anyhow::Result<()> {
    use incise_client::raw::{RawToolForce, RawToolPose};
    use incise_transport::Faults;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let keys = Keys::new(&role.scene_name)?;
    let stop = Arc::new(AtomicBool::new(false));
    let answer = |pose: &RawToolPose| RawToolForce {
        pose_sequence: pose.sequence,
        tool_id: pose.tool_id,
        ..RawToolForce::default()
    };
    let watch_input = |stop: Arc<AtomicBool>| {
        std::thread::spawn(move || {
            let _ = std::io::stdin().read_to_end(&mut Vec::new());
            stop.store(true, Ordering::Release);
        })
    };
    let faults = Arc::new(Faults::default());
    match role.transport {
        TransportKind::Iceoryx2 => {
            let server = incise_transport::shm::ShmServer::start(&keys, 1, faults)?;
            let ports = server.open_ports()?;
            println!("ready");
            watch_input(Arc::clone(&stop));
            while !stop.load(Ordering::Acquire) {
                ports.wait(Duration::from_millis(20));
                let mut poses = Vec::new();
                ports.receive(|p| {
                    poses.push(*p);
                    true
                });
                for p in &poses {
                    ports.send_force(&answer(p));
                }
            }
        }
        TransportKind::Zenoh => {
            let (tx, rx) = flume::unbounded();
            let handler: incise_transport::PoseHandler = Arc::new(move |_, p| {
                let _ = tx.send(*p);
                true
            });
            let info =
                incise_client::v1::SceneInfo { scene: keys.scene().into(), ..Default::default() };
            let server = incise_transport::zenoh_link::ZenohServer::start(
                &keys,
                1,
                &info,
                &Endpoints { listen: vec![role.listen.clone()], ..Endpoints::default() },
                handler,
                faults,
            )?;
            println!("ready");
            watch_input(Arc::clone(&stop));
            while !stop.load(Ordering::Acquire) {
                if let Ok(p) = rx.recv_timeout(Duration::from_millis(20)) {
                    server.send_force(&answer(&p));
                }
            }
        }
    }
    Ok(())
}

/// The server role: serves the scene until its standard input closes, then prints its
/// statistics as one JSON line.
pub fn serve(role: &ServerRole) -> anyhow::Result<()> {
    let scene = incise_scene::read_scene(role.scene.as_ref())?;
    let options = Options {
        zenoh: Some(Endpoints { listen: vec![role.listen.clone()], ..Endpoints::default() }),
        ..Options::default()
    };
    let running = server::start(&scene, &role.scene, &options)?;
    println!("ready");
    let mut sink = Vec::new();
    let _ = std::io::stdin().read_to_end(&mut sink);
    let get = |a: &std::sync::atomic::AtomicU64| a.load(std::sync::atomic::Ordering::Relaxed);
    let j = running.shared.jitter();
    let json = serde_json::json!({
        "jitter_us_p50": j.quantile_us(0.5),
        "jitter_us_p99": j.quantile_us(0.99),
        "jitter_us_max": j.max_us(),
        "frames": get(&running.physics.frames),
        "late": get(&running.physics.late),
        "removed": get(&running.physics.removed),
    });
    running.stop();
    println!("{json}");
    Ok(())
}

/// The client role: brings tool 0 up to the organ's underside, presses and cuts for the rest of
/// the duration, then prints the round trips as one JSON line.
pub fn client(role: &ClientRole) -> anyhow::Result<()> {
    let keys = Keys::new(&role.scene_name)?;
    if role.echo {
        return echo_client(role, &keys);
    }
    // The server answers its scene description once it is up; ask until it does.
    let until = Instant::now() + Duration::from_secs(30);
    let info = loop {
        if let Ok(z) = incise_transport::client::ZenohClient::connect(&keys, 0, &role.connect)
            && let Ok(info) = z.scene_info(Duration::from_millis(500))
        {
            break info;
        }
        anyhow::ensure!(Instant::now() < until, "no server answered at {}", role.connect);
        std::thread::sleep(Duration::from_millis(100));
    };
    // From 1 cm under the organ's middle, blade up, 2 cm/s up until the tissue pushes back (the
    // organ is held at its top, so its underside is where a tool meets it); from there the
    // script presses 12 mm in and cuts a 2 cm stroke along x.
    let (x, y) = (
        0.5 * (info.bounds_min_x + info.bounds_max_x),
        0.5 * (info.bounds_min_y + info.bounds_max_y),
    );
    let start_z = info.bounds_min_z - 0.01;
    let client = Client::connect(role.transport, &keys, 0, &role.connect)?;
    let duration = Duration::from_secs_f64(role.duration);
    let touched = std::cell::Cell::new(None::<(f64, f64)>);
    let last_t = std::cell::Cell::new(0.0);
    let report = drive(
        &client,
        0,
        1000.0,
        duration,
        |t| {
            last_t.set(t);
            let (position, _, gripper) = match touched.get() {
                None => ([x, y, start_z + 0.02 * t], BLADE_UP, 0.0),
                Some((z, t0)) => {
                    let left = (role.duration - t0).max(1e-3);
                    let script = Script::PressCut { at: [x, y, 0.0], depth: 0.012, stroke: 0.02 };
                    let (p, _, g) = script.pose_at(t - t0, left);
                    // The script presses down (−z); from below, in is up.
                    ([p[0], p[1], z - p[2]], BLADE_UP, g)
                }
            };
            (position, BLADE_UP, gripper)
        },
        |f| {
            if touched.get().is_none() && f.force.iter().any(|c| c.abs() > 1e-4) {
                let t = last_t.get();
                touched.set(Some((start_z + 0.02 * t, t)));
            }
        },
    );
    print_report(&report);
    Ok(())
}

/// A client role's last line: its round trips as one JSON object.
fn print_report(report: &incise_client::drive::Report) {
    let json = serde_json::json!({
        "samples": report.rtt_us.len(),
        "sent": report.sent,
        "rtt_us_p50": report.quantile(0.5),
        "rtt_us_p99": report.quantile(0.99),
        "rtt_us_p999": report.quantile(0.999),
        "rtt_us_max": report.quantile(1.0),
        "max_force_n": report.max_force_n,
    });
    println!("{json}");
}

/// The client role against the echo server: a fixed pose at 1 kHz for the duration (after a
/// moment for the subscriptions to meet).
fn echo_client(role: &ClientRole, keys: &Keys) -> anyhow::Result<()> {
    let client = Client::connect(role.transport, keys, 0, &role.connect)?;
    std::thread::sleep(Duration::from_millis(500));
    let duration = Duration::from_secs_f64(role.duration);
    let report = drive(&client, 0, 1000.0, duration, |_| ([0.0; 3], BLADE_UP, 0.0), |_| {});
    print_report(&report);
    Ok(())
}
