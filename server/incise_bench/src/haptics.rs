//! `incise-bench haptics`: how the tools feel through a real server. A server (`haptics-server`)
//! runs the scene (the embedded demo scene unless `--scene`), recording it; a client in another
//! process (`haptics-client`) drives each of its tools in turn at 1 kHz over iceoryx2 or zenoh,
//! through three tests on the organ's top:
//!
//! - **depth sweep**: down at [`APPROACH_SPEED`] until the tissue first pushes back, on at
//!   `--speed` mm/s to `--depth` mm past that, and back;
//! - **jab**: the device jumps [`JAB_DEPTH`] into the organ in one pose, stays [`JAB_HOLD`],
//!   and jumps out;
//! - **cycles**: `--cycles` presses [`CYCLE_DEPTH`] in, each in, held, out and clear for the
//!   times of [`CYCLE`].
//!
//! The client logs the force in effect at each of its ticks and the pose it sent there: the
//! largest change of force between two ticks (what the hand feels as a step) and the energy the
//! device receives over the cycles, `Σ Fₖ · (xₖ₊₁ − xₖ)` (not positive: the hand does the work).
//! The server reports its haptic tick's cost (p50, p99: the work of a tick, rendering every
//! tool's coupling from the newest pose). Then the recording is replayed bit for bit on this
//! machine and, at every frame, each proxy's outer shape is measured against the deformed
//! surface: the largest penetration (how far the surface reaches into it; 0 when it never does).
//!
//! `--transport both` (the default) runs it once per transport, each against a fresh server.

use crate::role::{Role, free_port};
use anyhow::Context;
use incise_client::drive::drive;
use incise_client::{Client, Keys, TransportKind};
use incise_server::server::{self, Options};
use incise_transport::zenoh_link::Endpoints;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `haptics`' options.
#[derive(clap::Args, Debug)]
pub struct HapticsArgs {
    /// `iceoryx2` (shared memory), `zenoh` (loopback TCP) or `both`, one after the other.
    #[arg(long, default_value = "both")]
    transport: String,
    /// A scene file (default: the embedded demo scene, the organ with its scalpel and grasper).
    #[arg(long)]
    scene: Option<String>,
    /// The depth sweep's speed past first contact (mm/s).
    #[arg(long, default_value_t = 2.0)]
    speed: f64,
    /// How far past first contact the depth sweep goes (mm).
    #[arg(long, default_value_t = 10.0)]
    depth: f64,
    /// Press-hold-release cycles (1 to 100).
    #[arg(long, default_value_t = 20)]
    cycles: u32,
    /// End with one line of JSON: `runs`, one per transport, each with `transport`,
    /// `tick_cost_us_p50`, `tick_cost_us_p99`, `tick_cost_us_max`, `jitter_us_p99`, `frames`,
    /// `replayed_frames`, `diverged` (null, or where the replay left the recording) and
    /// `tools`, one per tool: `name`, `max_penetration_mm`, `max_force_step_n`,
    /// `max_force_step_n_by_test` (`sweep`, `jab`, `cycles`), `max_force_n`,
    /// `cycles_energy_j`, `cycles_work_j` (the work done either way, `Σ |Fₖ · Δx|`).
    #[arg(long)]
    json: bool,
}

/// The hidden server role's options.
#[derive(clap::Args, Debug)]
pub struct ServerRole {
    #[arg(long)]
    scene: Option<String>,
    #[arg(long)]
    listen: String,
    #[arg(long)]
    name: String,
    #[arg(long)]
    record: PathBuf,
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
    speed: f64,
    #[arg(long)]
    depth: f64,
    #[arg(long)]
    cycles: u32,
}

/// The tests, in the order a tool goes through them.
const TESTS: [&str; 3] = ["sweep", "jab", "cycles"];

/// The approach's speed until first contact (m/s) and where it starts above the organ (m).
const APPROACH_SPEED: f64 = 0.02;
const APPROACH_START: f64 = 0.005;
/// The jab's depth below first contact (m), how long it stays, and the waits around it (s).
const JAB_DEPTH: f64 = 0.05;
const JAB_HOLD: f64 = 0.3;
const JAB_WAIT: f64 = 0.2;
/// Each cycle: in, held, out, clear (s), and how deep past first contact it presses (m),
/// starting 1 mm above it.
const CYCLE: [f64; 4] = [0.1, 0.05, 0.1, 0.05];
const CYCLE_DEPTH: f64 = 0.005;
const CYCLE_CLEAR: f64 = 0.001;

/// Runs the report.
pub fn run(args: &HapticsArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.speed.is_finite() && args.speed > 0.0 && args.speed <= 100.0,
        "--speed must be between 0 and 100 mm/s, not {}",
        args.speed
    );
    anyhow::ensure!(
        args.depth.is_finite() && args.depth > 0.0 && args.depth <= 30.0,
        "--depth must be between 0 and 30 mm, not {}",
        args.depth
    );
    anyhow::ensure!((1..=100).contains(&args.cycles), "--cycles must be between 1 and 100");
    let transports: Vec<TransportKind> = match args.transport.as_str() {
        "both" => vec![TransportKind::Iceoryx2, TransportKind::Zenoh],
        other => vec![other.parse().map_err(|e| anyhow::anyhow!("--transport {other}: {e}"))?],
    };
    if let Some(path) = &args.scene {
        let scene =
            incise_scene::read_scene(path.as_ref()).with_context(|| format!("--scene {path}"))?;
        anyhow::ensure!(!scene.config.tools.is_empty(), "--scene {path}: it has no tool to drive");
    }
    let exe = std::env::current_exe()?;
    let mut runs = Vec::new();
    for transport in transports {
        runs.push(run_transport(&exe, args, transport)?);
    }
    for run in &runs {
        print_run(run);
    }
    if args.json {
        println!("{}", serde_json::json!({ "runs": runs }));
    }
    Ok(())
}

/// One transport's figures (the JSON's `runs` entry).
fn run_transport(
    exe: &Path,
    args: &HapticsArgs,
    transport: TransportKind,
) -> anyhow::Result<serde_json::Value> {
    let name = format!("haptics_{}_{}", std::process::id(), transport.name());
    let dir = std::env::temp_dir().join(&name);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let mut role = vec![
        "haptics-server".to_owned(),
        "--listen".into(),
        endpoint.clone(),
        "--name".into(),
        name.clone(),
        "--record".into(),
        dir.display().to_string(),
    ];
    if let Some(scene) = &args.scene {
        role.extend(["--scene".into(), scene.clone()]);
    }
    eprintln!("haptics: a server on {endpoint}, the client over {}", transport.name());
    let server = Role::start(exe, &role)?;
    let client = Command::new(exe)
        .args(["haptics-client", "--transport", transport.name()])
        .args(["--connect", &endpoint, "--scene-name", &name])
        .args(["--speed", &args.speed.to_string(), "--depth", &args.depth.to_string()])
        .args(["--cycles", &args.cycles.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .output();
    let served = server.finish()?;
    let client = client?;
    anyhow::ensure!(client.status.success(), "the client failed");
    let last = |text: &str, who: &str| -> anyhow::Result<serde_json::Value> {
        let line = text.lines().last().with_context(|| format!("the {who} printed nothing"))?;
        serde_json::from_str(line).with_context(|| format!("the {who}'s last line: {line}"))
    };
    let client = last(&String::from_utf8_lossy(&client.stdout), "client")?;
    let served = last(&served, "server")?;
    let recording = served["recording"].as_str().context("the server recorded nothing")?;
    let depths = penetrations(Path::new(recording))?;
    let _ = std::fs::remove_dir_all(&dir);
    let mut tools = client["tools"].as_array().cloned().unwrap_or_default();
    for tool in &mut tools {
        let id = tool["id"].as_u64().unwrap_or(u64::MAX) as usize;
        tool["max_penetration_mm"] = depths.tools.get(id).copied().unwrap_or(f64::NAN).into();
    }
    Ok(serde_json::json!({
        "transport": transport.name(),
        "tick_cost_us_p50": served["cost_us_p50"],
        "tick_cost_us_p99": served["cost_us_p99"],
        "tick_cost_us_max": served["cost_us_max"],
        "jitter_us_p99": served["jitter_us_p99"],
        "frames": served["frames"],
        "replayed_frames": depths.frames,
        "diverged": depths.diverged,
        "tools": tools,
    }))
}

fn print_run(run: &serde_json::Value) {
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    println!(
        "haptics over {}: {} physics frames; haptic tick cost p50 {:.1} µs, p99 {:.1} µs (every tool's coupling, from the newest pose); period jitter p99 {:.0} µs",
        run["transport"].as_str().unwrap_or("?"),
        run["frames"],
        f(&run["tick_cost_us_p50"]),
        f(&run["tick_cost_us_p99"]),
        f(&run["jitter_us_p99"]),
    );
    match run["diverged"].as_str() {
        Some(what) => println!(
            "  the replay left the recording ({what}): penetrations over its first {} frames",
            run["replayed_frames"]
        ),
        None => println!("  replayed bit for bit: {} frames", run["replayed_frames"]),
    }
    println!(
        "  {:<10} {:>16} {:>12} {:>10} {:>10} {:>10} {:>10} {:>14} {:>8}",
        "tool",
        "penetration mm",
        "max force N",
        "step N",
        "sweep",
        "jab",
        "cycles",
        "cycles energy",
        "/ work"
    );
    for t in run["tools"].as_array().into_iter().flatten() {
        let by = &t["max_force_step_n_by_test"];
        let (energy, work) = (f(&t["cycles_energy_j"]), f(&t["cycles_work_j"]));
        println!(
            "  {:<10} {:>16.4} {:>12.3} {:>10.3} {:>10.3} {:>10.3} {:>10.3} {:>12.2e} J {:>+7.2}%",
            t["name"].as_str().unwrap_or("?"),
            f(&t["max_penetration_mm"]),
            f(&t["max_force_n"]),
            f(&t["max_force_step_n"]),
            f(&by["sweep"]),
            f(&by["jab"]),
            f(&by["cycles"]),
            energy,
            100.0 * energy / work.max(f64::MIN_POSITIVE),
        );
    }
}

/// The server role: serves the scene over both transports, recording it, until its standard
/// input closes; then prints its haptic tick's cost and where the recording is, as one JSON
/// line.
pub fn serve(role: &ServerRole) -> anyhow::Result<()> {
    let path = role.scene.as_deref().map(Path::new);
    let scene = incise_server::scene::load(path)?;
    let (file, toml, scene_files) = match path {
        Some(path) => (
            path.display().to_string(),
            std::fs::read_to_string(path)?,
            incise_server::scene::stored_files(
                &scene.config,
                path.parent().unwrap_or(Path::new(".")),
            ),
        ),
        None => ("demo".to_owned(), incise_scene::DEMO_SCENE.to_owned(), Vec::new()),
    };
    let options = Options {
        name: Some(role.name.clone()),
        zenoh: Some(Endpoints { listen: vec![role.listen.clone()], ..Endpoints::default() }),
        iceoryx2: true,
        record: Some(role.record.clone()),
        scene_toml: toml,
        scene_files,
        ..Options::default()
    };
    let mut running = server::start(&scene, &file, &options)?;
    println!("ready");
    let _ = std::io::stdin().read_to_end(&mut Vec::new());
    running.stop_physics();
    let (cost, jitter) = (running.shared.cost(), running.shared.jitter());
    let frames = running.physics.frames.load(std::sync::atomic::Ordering::Relaxed);
    let json = serde_json::json!({
        "cost_us_p50": cost.quantile_us(0.5),
        "cost_us_p99": cost.quantile_us(0.99),
        "cost_us_max": cost.max_us(),
        "jitter_us_p99": jitter.quantile_us(0.99),
        "frames": frames,
        "recording": running.recording().map(|p| p.display().to_string()),
    });
    running.stop();
    println!("{json}");
    Ok(())
}

/// What one tool's drive logged at each tick: the time (s), the test it was in (an index into
/// [`TESTS`], or none between them), the pose's position it sent, and the force in effect
/// when it sent it (the newest force received).
struct Tick {
    test: Option<usize>,
    position: [f64; 3],
    force: [f64; 3],
}

/// Where a tool is in its script.
#[derive(Clone, Copy)]
enum Stage {
    /// Coming down, not yet touching.
    Approach,
    /// First contact at this height, at this time (s).
    Touched { z: f64, t: f64 },
}

/// The client role: drives each of the scene's tools in turn through the tests, then prints
/// each one's figures as one JSON line.
pub fn client(role: &ClientRole) -> anyhow::Result<()> {
    let keys = Keys::new(&role.scene_name)?;
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
    let mut tools = info.tools.clone();
    tools.sort_by_key(|t| t.id);
    let (cx, cy) = (
        0.5 * (info.bounds_min_x + info.bounds_max_x),
        0.5 * (info.bounds_min_y + info.bounds_max_y),
    );
    let n = tools.len() as f64;
    let mut out = Vec::new();
    for (i, tool) in tools.iter().enumerate() {
        // Each tool on a spot of its own, 15 mm apart along x about the middle.
        let x = cx + 0.015 * (i as f64 - 0.5 * (n - 1.0));
        eprintln!("haptics: {} at ({x:.3}, {cy:.3})", tool.name);
        let ticks = drive_tool(role, &keys, tool.id, [x, cy, info.bounds_max_z])?;
        out.push(figures(&tool.name, tool.id, &ticks));
    }
    println!("{}", serde_json::json!({ "tools": out }));
    Ok(())
}

/// Drives tool `id` through the tests above `top` (the organ's bounding box's top over the
/// tool's spot); the ticks it logged.
fn drive_tool(role: &ClientRole, keys: &Keys, id: u32, top: [f64; 3]) -> anyhow::Result<Vec<Tick>> {
    let client = Client::connect(role.transport, keys, id, &role.connect)?;
    // Let the subscriptions meet before the first pose.
    std::thread::sleep(Duration::from_millis(300));
    let (speed, depth) = (role.speed * 1e-3, role.depth * 1e-3);
    let sweep = 2.0 * depth / speed;
    let jab = 3.0 * JAB_WAIT + JAB_HOLD;
    let cycle: f64 = CYCLE.iter().sum();
    let cycles = f64::from(role.cycles) * cycle;
    // The approach may take up to 1.5 s (3 cm below the box's top).
    let total = 1.5 + sweep + jab + cycles + 0.2;
    let stage = std::cell::Cell::new(Stage::Approach);
    let force = std::cell::Cell::new([0.0; 3]);
    let last_t = std::cell::Cell::new(0.0);
    let ticks = std::cell::RefCell::new(Vec::new());
    let start_z = top[2] + APPROACH_START;
    let at = |z: f64| [top[0], top[1], z];
    let report = drive(
        &client,
        id,
        1000.0,
        Duration::from_secs_f64(total),
        |t| {
            last_t.set(t);
            let (test, z) = match stage.get() {
                Stage::Approach => (None, (start_z - APPROACH_SPEED * t).max(top[2] - 0.03)),
                Stage::Touched { z: z0, t: t0 } => {
                    let s = t - t0;
                    if s < sweep {
                        let past = if s < 0.5 * sweep { speed * s } else { speed * (sweep - s) };
                        (Some(0), z0 - past)
                    } else if s < sweep + jab {
                        let j = s - sweep;
                        let inside = (2.0 * JAB_WAIT..2.0 * JAB_WAIT + JAB_HOLD).contains(&j);
                        // A wait clear of the tissue first (the sweep ends at first contact).
                        (Some(1), if inside { z0 - JAB_DEPTH } else { z0 + 0.005 })
                    } else if s < sweep + jab + cycles {
                        let c = (s - sweep - jab) % cycle;
                        let (high, low) = (z0 + CYCLE_CLEAR, z0 - CYCLE_DEPTH);
                        let z = if c < CYCLE[0] {
                            high + (low - high) * c / CYCLE[0]
                        } else if c < CYCLE[0] + CYCLE[1] {
                            low
                        } else if c < CYCLE[0] + CYCLE[1] + CYCLE[2] {
                            low + (high - low) * (c - CYCLE[0] - CYCLE[1]) / CYCLE[2]
                        } else {
                            high
                        };
                        (Some(2), z)
                    } else {
                        (None, z0 + 0.02)
                    }
                }
            };
            ticks.borrow_mut().push(Tick { test, position: at(z), force: force.get() });
            (at(z), [1.0, 0.0, 0.0, 0.0], 1.0)
        },
        |f| {
            force.set(f.force);
            if matches!(stage.get(), Stage::Approach) && f.force.iter().any(|c| c.abs() > 1e-4) {
                let t = last_t.get();
                let z = (start_z - APPROACH_SPEED * t).max(top[2] - 0.03);
                stage.set(Stage::Touched { z, t });
            }
        },
    );
    anyhow::ensure!(
        matches!(stage.get(), Stage::Touched { .. }),
        "tool {id} never touched the organ ({} poses sent, {} forces received)",
        report.sent,
        report.forces
    );
    Ok(ticks.into_inner())
}

/// A tool's figures from its ticks: the largest force, the largest force step between two
/// ticks (over all and per test), and the energy the device received over the cycles.
fn figures(name: &str, id: u32, ticks: &[Tick]) -> serde_json::Value {
    let norm = |v: [f64; 3]| v.iter().map(|c| c * c).sum::<f64>().sqrt();
    let mut step_by = [0.0f64; 3];
    let mut step = 0.0f64;
    let (mut energy, mut work) = (0.0, 0.0);
    for pair in ticks.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        let jump = norm(std::array::from_fn(|k| b.force[k] - a.force[k]));
        step = step.max(jump);
        if let Some(test) = b.test {
            step_by[test] = step_by[test].max(jump);
        }
        // The force in effect while the device moved from a to b: the newest one when b was
        // sent.
        if a.test == Some(2) {
            let w: f64 = (0..3).map(|k| b.force[k] * (b.position[k] - a.position[k])).sum();
            energy += w;
            work += w.abs();
        }
    }
    let by: serde_json::Map<String, serde_json::Value> =
        TESTS.iter().zip(step_by).map(|(t, s)| ((*t).to_owned(), s.into())).collect();
    serde_json::json!({
        "name": name,
        "id": id,
        "ticks": ticks.len(),
        "max_force_n": ticks.iter().map(|t| norm(t.force)).fold(0.0, f64::max),
        "max_force_step_n": step,
        "max_force_step_n_by_test": by,
        "cycles_energy_j": energy,
        "cycles_work_j": work,
    })
}

/// What the replay of a recording measured.
struct Depths {
    /// Per tool id: the largest penetration of its proxy (mm).
    tools: Vec<f64>,
    frames: u64,
    /// Where the replay left the recording, if it did.
    diverged: Option<String>,
}

/// Replays the recording at `path` and measures, at every frame, how far the deformed surface
/// reaches into each proxy's outer shape.
fn penetrations(path: &Path) -> anyhow::Result<Depths> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let contents = incise_record::read_recording(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let mut sim = incise_replay::simulation(&contents, Path::new("."))?;
    let shapes: Vec<Option<incise_tool::Shape>> = sim
        .config()
        .tools
        .iter()
        .map(|t| match &t.outer {
            incise_sim::config::ShapeSpec::Shape(s) => Some(s.clone()),
            incise_sim::config::ShapeSpec::Mesh { .. } => None,
        })
        .collect();
    let mut deepest = vec![0.0f64; shapes.len()];
    let total = contents.frames.len();
    let started = Instant::now();
    let outcome = incise_replay::replay(
        &contents,
        &mut sim,
        incise_replay::Compare::default(),
        |n, sim, frame| {
            if n % 2000 == 0 {
                eprintln!(
                    "haptics: replayed {n} of {total} frames ({:.0} s)",
                    started.elapsed().as_secs_f64()
                );
            }
            for (i, tool) in frame.surgical.tools.iter().enumerate() {
                if let (Some(proxy), Some(Some(shape))) = (&tool.proxy, shapes.get(i)) {
                    let gap = surface_gap(sim, shape, proxy);
                    deepest[i] = deepest[i].max(-gap);
                }
            }
        },
    );
    Ok(Depths {
        tools: deepest.iter().map(|d| d * 1e3).collect(),
        frames: outcome.frames,
        diverged: outcome.divergence.map(|d| format!("frame {}: {}", d.frame, d.what)),
    })
}

/// The least signed distance between `shape` at `pose` and the surface (m; negative: the
/// surface reaches into the shape by that much), over the triangles whose bounding boxes come
/// within 1 mm of the shape's bounding ball.
fn surface_gap(
    sim: &incise_sim::Simulation,
    shape: &incise_tool::Shape,
    pose: &incise_tool::Pose,
) -> f64 {
    let (Some(surface), Some(positions)) = (sim.surface(), sim.surface_positions()) else {
        return f64::INFINITY;
    };
    let (lo, hi) = shape.bounds();
    let centre_tool: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let reach = 0.5 * (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt() + 1e-3;
    let centre = pose.grid_from_tool(centre_tool);
    surface
        .triangle_list()
        .iter()
        .filter(|t| {
            (0..3).all(|k| {
                let (a, b) = t.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    let c = positions[v as usize][k];
                    (a.min(c), b.max(c))
                });
                centre[k] >= a - reach && centre[k] <= b + reach
            })
        })
        .map(|t| {
            let corners = t.map(|v| pose.tool_from_grid(positions[v as usize]));
            incise_tool::proxy::triangle_gap(shape, &corners).distance
        })
        .fold(f64::INFINITY, f64::min)
}
