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
//!
//! `--via-router --scenes N` (zenoh): a zenoh router (`latency-router`) and N servers, each of
//! its own scene name (`latency-0` …), connected to it; N clients, one per scene, drive their
//! scene's scalpel at 1 kHz at once, every pose and force going through the router. The round
//! trips of all clients are pooled into one distribution (the same JSON keys as without the
//! router, plus `scenes`, `via_router` and each scene's p99); the floor is N echo servers
//! behind the same router.

use crate::role::{Role, free_port};
use anyhow::{Context, bail};
use incise_client::drive::{RoundTrips, drive};
use incise_client::script::Script;
use incise_client::{Client, Keys, TransportKind};
use incise_server::server::{self, Options};
use incise_transport::zenoh_link::Endpoints;
use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `latency`'s options.
#[derive(clap::Args, Debug)]
#[allow(clippy::struct_excessive_bools, reason = "command-line switches")]
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
    /// Go through a zenoh router (zenoh only): servers and clients connect to it, as on a
    /// site (deploy/README.md).
    #[arg(long)]
    via_router: bool,
    /// How many scenes, one server and one client each, run at once behind the router
    /// (1 to 16; more than 1 needs `--via-router`).
    #[arg(long, default_value_t = 1)]
    scenes: usize,
    /// With `--via-router`: a subscriber on the router counts the bytes and messages of every
    /// kind (poses, forces, frames, cuts) while the clients drive, and reports each scene's
    /// bandwidth (`bandwidth` in the JSON). It receives everything, so it loads the router:
    /// take latencies from a run without it.
    #[arg(long, requires = "via_router")]
    bandwidth: bool,
}

/// Every message on the router, counted by kind (the key's last chunk).
struct Tap {
    counts: std::sync::Arc<std::sync::Mutex<std::collections::BTreeMap<String, (u64, u64)>>>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
    _session: zenoh::Session,
}

impl Tap {
    fn start(endpoint: &str) -> anyhow::Result<Self> {
        use zenoh::Wait;
        let session = Endpoints::connect_to(endpoint).open("client")?;
        let counts = std::sync::Arc::new(std::sync::Mutex::new(std::collections::BTreeMap::new()));
        let c = std::sync::Arc::clone(&counts);
        let subscriber = session
            .declare_subscriber("incise/v1/**")
            .callback(move |sample| {
                let kind = sample.key_expr().as_str().rsplit('/').next().unwrap_or("").to_owned();
                let mut c = c.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                let e = c.entry(kind).or_insert((0, 0));
                e.0 += 1;
                e.1 += sample.payload().len() as u64;
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("the bandwidth tap cannot subscribe: {e}"))?;
        Ok(Self { counts, _subscriber: subscriber, _session: session })
    }

    /// Per kind: messages per second and payload bytes per second, per scene.
    fn per_scene(&self, seconds: f64, scenes: usize) -> serde_json::Value {
        let c = self.counts.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let per = |n: u64| n as f64 / seconds / scenes as f64;
        let kinds: serde_json::Map<String, serde_json::Value> = c
            .iter()
            .map(|(k, (m, b))| {
                (
                    k.clone(),
                    serde_json::json!({ "messages_per_s": per(*m), "bytes_per_s": per(*b) }),
                )
            })
            .collect();
        serde_json::Value::Object(kinds)
    }
}

/// The hidden router role's options.
#[derive(clap::Args, Debug)]
pub struct RouterRole {
    #[arg(long)]
    listen: String,
}

/// The hidden echo role's options.
#[derive(clap::Args, Debug)]
pub struct EchoRole {
    #[arg(long)]
    transport: TransportKind,
    #[arg(long)]
    listen: Option<String>,
    #[arg(long)]
    connect: Option<String>,
    #[arg(long)]
    scene_name: String,
}

/// The hidden server role's options.
#[derive(clap::Args, Debug)]
pub struct ServerRole {
    #[arg(long)]
    scene: String,
    #[arg(long)]
    listen: Option<String>,
    #[arg(long)]
    connect: Option<String>,
    /// The keys' name, in place of the scene's.
    #[arg(long)]
    name: Option<String>,
}

/// A role's zenoh endpoints: listen on one, or connect to one (a router).
fn role_endpoints(listen: Option<&String>, connect: Option<&String>) -> Endpoints {
    Endpoints {
        listen: listen.into_iter().cloned().collect(),
        connect: connect.into_iter().cloned().collect(),
        ..Endpoints::default()
    }
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

/// Runs the report.
pub fn run(args: &LatencyArgs) -> anyhow::Result<()> {
    if !(args.duration.is_finite() && args.duration > 0.0 && args.duration <= 60.0) {
        bail!("--duration must be between 0 and 60 s");
    }
    anyhow::ensure!((1..=16).contains(&args.scenes), "--scenes must be between 1 and 16");
    anyhow::ensure!(args.scenes == 1 || args.via_router, "--scenes above 1 needs --via-router");
    anyhow::ensure!(
        !args.via_router || args.transport == TransportKind::Zenoh,
        "--via-router is a zenoh router: use --transport zenoh"
    );
    let scene = incise_scene::read_scene(args.scene.as_ref())
        .with_context(|| format!("--scene {}", args.scene))?;
    anyhow::ensure!(
        !scene.config.tools.is_empty(),
        "--scene {}: it has no tool to drive",
        args.scene
    );
    let exe = std::env::current_exe()?;
    // Through a router every server and client connects to its one endpoint; otherwise each
    // server listens on an endpoint of its own.
    let router_endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let _router = if args.via_router {
        eprintln!("latency: a zenoh router on {router_endpoint}");
        Some(Role::start(
            &exe,
            &["latency-router".into(), "--listen".into(), router_endpoint.clone()],
        )?)
    } else {
        None
    };
    let names: Vec<String> = if args.via_router {
        (0..args.scenes).map(|i| format!("latency-{i}")).collect()
    } else {
        vec![scene.config.name.clone()]
    };
    // A server's endpoint arguments, and the endpoint its client connects to.
    let place = || -> anyhow::Result<(Vec<String>, String)> {
        if args.via_router {
            Ok((vec!["--connect".into(), router_endpoint.clone()], router_endpoint.clone()))
        } else {
            let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
            Ok((vec!["--listen".into(), endpoint.clone()], endpoint))
        }
    };
    eprintln!(
        "latency: {} server{} on {}, client{} over {}{}",
        names.len(),
        if names.len() == 1 { "" } else { "s" },
        args.scene,
        if names.len() == 1 { "" } else { "s" },
        args.transport.name(),
        if args.via_router { " through the router" } else { "" }
    );
    let mut servers = Vec::new();
    let mut clients = Vec::new();
    for name in &names {
        let (server_place, client_endpoint) = place()?;
        let mut role = vec!["latency-server".into(), "--scene".into(), args.scene.clone()];
        role.extend(server_place);
        if args.via_router {
            role.extend(["--name".into(), name.clone()]);
        }
        servers.push(role);
        clients.push((client_endpoint, name.clone()));
    }
    let tap = if args.bandwidth { Some(Tap::start(&router_endpoint)?) } else { None };
    let (outputs, rest) =
        with_servers(&exe, &servers, |exe| run_clients(exe, args, &clients, false))?;
    let bandwidth = tap.map(|t| t.per_scene(args.duration, names.len()));
    let floor = if args.no_floor {
        None
    } else {
        let mut echoes = Vec::new();
        let mut clients = Vec::new();
        for i in 0..names.len() {
            let (echo_place, client_endpoint) = place()?;
            let name = format!("latency_floor_{}_{i}", std::process::id());
            let mut role =
                vec!["latency-echo".into(), "--transport".into(), args.transport.name().into()];
            role.extend(echo_place);
            role.extend(["--scene-name".into(), name.clone()]);
            echoes.push(role);
            clients.push((client_endpoint, name));
        }
        eprintln!(
            "latency: echo server{} over {} (the transport's floor)",
            if echoes.len() == 1 { "" } else { "s" },
            args.transport.name()
        );
        let (floor, _) = with_servers(&exe, &echoes, |exe| run_clients(exe, args, &clients, true))?;
        Some(floor)
    };
    let parse = |text: &str, who: &str| -> anyhow::Result<serde_json::Value> {
        let last = text.lines().last().with_context(|| format!("the {who} printed nothing"))?;
        serde_json::from_str(last).with_context(|| format!("the {who}'s last line: {last}"))
    };
    let clients: Vec<serde_json::Value> =
        outputs.iter().map(|o| parse(o, "client")).collect::<Result<_, _>>()?;
    let servers: Vec<serde_json::Value> =
        rest.iter().map(|o| parse(o, "server")).collect::<Result<_, _>>()?;
    let floor = floor
        .map(|f| f.iter().map(|o| parse(o, "floor client")).collect::<Result<Vec<_>, _>>())
        .transpose()?;
    let c = pooled(&clients)?;
    let e = floor.as_ref().map(|f| pooled(f)).transpose()?;
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    let worst = |k: &str| servers.iter().map(|s| f(s, k)).fold(f64::NAN, f64::max);
    let total = |k: &str| servers.iter().map(|s| s[k].as_u64().unwrap_or(0)).sum::<u64>();
    let per_scene: Vec<f64> = clients.iter().map(|c| f(c, "rtt_us_p99")).collect();
    println!(
        "latency over {}{} ({} for {:.1} s, {} scene{}, clients and servers in separate processes)",
        args.transport.name(),
        if args.via_router { " through a zenoh router" } else { "" },
        args.scene,
        args.duration,
        names.len(),
        if names.len() == 1 { "" } else { "s" },
    );
    println!("pose → force round trip: {} samples of {} poses", c.samples, c.sent);
    println!(
        "  p50 {:.0} µs   p99 {:.0} µs   p99.9 {:.0} µs   max {:.0} µs",
        c.quantile(0.5),
        c.quantile(0.99),
        c.quantile(0.999),
        c.quantile(1.0)
    );
    if names.len() > 1 {
        let list: Vec<String> = per_scene.iter().map(|p| format!("{p:.0}")).collect();
        println!("  p99 per scene (µs): {}", list.join(", "));
    }
    println!(
        "haptic period jitter while the physics ran (worst server): p50 {:.0} µs   p99 {:.0} µs   max {:.0} µs ({} physics frames, {} late)",
        worst("jitter_us_p50"),
        worst("jitter_us_p99"),
        worst("jitter_us_max"),
        total("frames"),
        total("late")
    );
    println!("max force {:.3} N; voxels cut {}", c.max_force_n, total("removed"));
    if let Some(e) = &e {
        println!(
            "transport floor (echo servers answering at once, no physics): p50 {:.0} µs   p99 {:.0} µs   p99.9 {:.0} µs ({} samples); the servers add p50 {:+.0} µs, p99 {:+.0} µs",
            e.quantile(0.5),
            e.quantile(0.99),
            e.quantile(0.999),
            e.samples,
            c.quantile(0.5) - e.quantile(0.5),
            c.quantile(0.99) - e.quantile(0.99),
        );
    }
    if let Some(b) = &bandwidth {
        println!("per scene through the router (payload bytes, without zenoh's framing):");
        for (kind, v) in b.as_object().into_iter().flatten() {
            println!(
                "  {kind:<8} {:>8.0} messages/s {:>10.0} B/s",
                v["messages_per_s"].as_f64().unwrap_or(0.0),
                v["bytes_per_s"].as_f64().unwrap_or(0.0)
            );
        }
    }
    if args.json {
        let json = serde_json::json!({
            "transport": args.transport.name(),
            "via_router": args.via_router,
            "scenes": names.len(),
            "rtt_us_p50": c.quantile(0.5),
            "rtt_us_p99": c.quantile(0.99),
            "rtt_us_p999": c.quantile(0.999),
            "rtt_us_max": c.quantile(1.0),
            "rtt_us_p99_per_scene": per_scene,
            "jitter_us_p99": worst("jitter_us_p99"),
            "samples": c.samples,
            "sent": c.sent,
            "max_force_n": c.max_force_n,
            "frames": total("frames"),
            "floor_us_p50": e.as_ref().map(|e| e.quantile(0.5)),
            "floor_us_p99": e.as_ref().map(|e| e.quantile(0.99)),
            "floor_us_p999": e.as_ref().map(|e| e.quantile(0.999)),
            "bandwidth": bandwidth,
        });
        println!("{json}");
    }
    Ok(())
}

/// Several clients' round trips pooled into one distribution.
struct Pooled {
    trips: RoundTrips,
    samples: u64,
    sent: u64,
    max_force_n: f64,
}

impl Pooled {
    fn quantile(&self, q: f64) -> f64 {
        self.trips.quantile(q).unwrap_or(f64::NAN)
    }
}

/// Pools the clients' histograms (their `rtt_buckets`).
fn pooled(clients: &[serde_json::Value]) -> anyhow::Result<Pooled> {
    let mut p = Pooled { trips: RoundTrips::default(), samples: 0, sent: 0, max_force_n: 0.0 };
    for c in clients {
        let buckets: Vec<(usize, u32)> = serde_json::from_value(c["rtt_buckets"].clone())
            .context("a client's line has no rtt_buckets")?;
        p.trips.add_buckets(&buckets, c["rtt_us_max"].as_f64().unwrap_or(0.0));
        p.samples += c["samples"].as_u64().unwrap_or(0);
        p.sent += c["sent"].as_u64().unwrap_or(0);
        p.max_force_n = p.max_force_n.max(c["max_force_n"].as_f64().unwrap_or(0.0));
    }
    Ok(p)
}

/// Starts this program in each server role of `servers`, runs `during`, then stops them and
/// returns what `during` returned and everything each server printed after `ready`.
fn with_servers<T>(
    exe: &std::path::Path,
    servers: &[Vec<String>],
    during: impl FnOnce(&std::path::Path) -> anyhow::Result<T>,
) -> anyhow::Result<(T, Vec<String>)> {
    let started =
        servers.iter().map(|args| Role::start(exe, args)).collect::<Result<Vec<_>, _>>()?;
    let result = during(exe);
    let rest = started.into_iter().map(Role::finish).collect::<Result<Vec<_>, _>>()?;
    Ok((result?, rest))
}

/// Runs a client role for each `(endpoint, scene name)` at once; their standard outputs.
fn run_clients(
    exe: &std::path::Path,
    args: &LatencyArgs,
    clients: &[(String, String)],
    echo: bool,
) -> anyhow::Result<Vec<String>> {
    let children = clients
        .iter()
        .map(|(endpoint, scene_name)| {
            let mut command = Command::new(exe);
            command
                .args(["latency-client", "--transport", args.transport.name()])
                .args(["--connect", endpoint, "--scene-name", scene_name])
                .args(["--duration", &args.duration.to_string()])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped());
            if echo {
                command.arg("--echo");
            }
            command.spawn()
        })
        .collect::<Result<Vec<_>, _>>()?;
    children
        .into_iter()
        .map(|child| {
            let out = child.wait_with_output()?;
            anyhow::ensure!(
                out.status.success(),
                "a client failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            Ok(String::from_utf8_lossy(&out.stdout).into_owned())
        })
        .collect()
}

/// The router role: a zenoh router on `listen` until its standard input closes.
pub fn route(role: &RouterRole) -> anyhow::Result<()> {
    let _router =
        Endpoints { listen: vec![role.listen.clone()], ..Endpoints::default() }.open("router")?;
    println!("ready");
    let _ = std::io::stdin().read_to_end(&mut Vec::new());
    Ok(())
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
                &role_endpoints(role.listen.as_ref(), role.connect.as_ref()),
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
        name: role.name.clone(),
        zenoh: Some(role_endpoints(role.listen.as_ref(), role.connect.as_ref())),
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
        "rtt_buckets": report.rtt_us.buckets(),
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
