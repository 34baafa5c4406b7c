//! `incise-server --demo`: the embedded scene served as usual, driven by two scripted clients
//! in their own threads over the real transports (the scalpel over iceoryx2, the grasper over
//! zenoh): the scalpel presses, then cuts a stroke; the grasper takes hold of the tissue beside
//! the cut and lifts it. Each client times every pose's round trip to the force that answers
//! it. A progress line shows while it runs; the summary follows.

use crate::server::{self, Options, Running};
use incise_client::drive::{Report, drive};
use incise_client::script::ramp;
use incise_sim::Simulation;
use incise_transport::{Client, TransportKind};
use std::fmt::Write as _;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// The tool's z axis down the grid's −z (a half turn about x): the grasper's jaws point down.
const POINT_DOWN: [f64; 4] = [0.0, 1.0, 0.0, 0.0];
/// Unrotated: the scalpel's edge down, its shaft up.
const UPRIGHT: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

/// What a viewer watching the scene over zenoh saw during the demo.
#[derive(Clone, Debug, Default)]
pub struct Watched {
    /// Frame statistics received.
    pub frames: u64,
    /// The last frame's index.
    pub last_frame: u64,
    /// Cut events received.
    pub cuts: u64,
    /// Voxels those cut events removed.
    pub voxels: u64,
}

/// One scripted client's results: the tool, its transport, and what [`drive`] measured.
#[derive(Clone, Debug, Default)]
pub struct ClientReport {
    /// The tool's name.
    pub tool: String,
    /// `zenoh` or `iceoryx2`.
    pub transport: &'static str,
    /// The round trips and forces.
    pub report: Report,
}

/// Where the script puts the tools: the organ's top surface height, settled under gravity, at
/// the scalpel's and the grasper's x, y.
struct Stage {
    scalpel: [f64; 3],
    grasper: [f64; 3],
}

/// The highest surface point within 3 mm of `(x, y)`.
fn top_at(sim: &Simulation, x: f64, y: f64) -> f64 {
    let p = sim.surface_positions().expect("the scene has tools, so a surface");
    sim.surface()
        .expect("a surface")
        .live_vertices()
        .iter()
        .map(|&v| p[v as usize])
        .filter(|q| (q[0] - x).hypot(q[1] - y) < 0.003)
        .map(|q| q[2])
        .fold(f64::NEG_INFINITY, f64::max)
}

fn stage(scene: &incise_scene::Scene) -> anyhow::Result<Stage> {
    let mut sim = Simulation::new(&scene.config, &scene.geometry, "<demo>")?;
    // The soft organ sags under its weight by millimetres: aim at its settled surface.
    for _ in 0..(0.8 / scene.config.dt()) as usize {
        sim.step(&incise_sim::StepInputs::default())?;
    }
    let (sx, sy) = (0.035, 0.03);
    let (gx, gy) = (0.035, 0.045);
    Ok(Stage { scalpel: [sx, sy, top_at(&sim, sx, sy)], grasper: [gx, gy, top_at(&sim, gx, gy)] })
}

/// The scalpel at time fraction `f` of the demo: down to the surface, pressed 2 mm (it pushes),
/// 6 mm (it cuts), drawn 2 cm along x, lifted out.
fn scalpel(s: &Stage, f: f64) -> ([f64; 3], [f64; 4], f64) {
    let [x, y, top] = s.scalpel;
    let z = ramp(
        &[(0.0, 0.01), (0.08, 0.001), (0.25, -0.002), (0.4, -0.006), (0.6, -0.006), (0.7, 0.01)],
        f,
    );
    let dx = ramp(&[(0.4, 0.0), (0.6, 0.02)], f);
    ([x + dx, y, top + z], UPRIGHT, 0.0)
}

/// The grasper: lowered open until its hinge is 2 mm into the surface, closed, lifted 5 mm,
/// opened and raised.
fn grasper(s: &Stage, f: f64) -> ([f64; 3], [f64; 4], f64) {
    let [x, y, top] = s.grasper;
    let z = ramp(
        &[(0.5, 0.012), (0.62, -0.001), (0.7, -0.001), (0.82, 0.003), (0.9, 0.003), (0.97, 0.012)],
        f,
    );
    let gripper = ramp(&[(0.64, 0.5), (0.66, 0.0), (0.9, 0.0), (0.92, 0.5)], f);
    ([x, y, top + z], POINT_DOWN, gripper)
}

type Script = fn(&Stage, f64) -> ([f64; 3], [f64; 4], f64);

/// Runs the demo for `duration` with `options` (and on, the tools idle, until at least a
/// keyframe interval of simulated time has passed); prints progress to stderr and returns the
/// server's final status and each client's report.
///
/// # Panics
/// If a scripted client's thread panics.
pub fn run(
    options: &Options,
    duration: Duration,
) -> anyhow::Result<(Running, Vec<ClientReport>, Watched)> {
    let scene = crate::scene::load(None)?;
    let stage = stage(&scene)?;
    let running = server::start(&scene, "<embedded demo scene>", options)?;
    let endpoint =
        options.zenoh.as_ref().and_then(|z| z.listen.first().cloned()).ok_or_else(|| {
            anyhow::anyhow!("the demo drives its grasper over zenoh: do not turn zenoh off")
        })?;
    let scalpel_kind =
        if options.iceoryx2 { TransportKind::Iceoryx2 } else { TransportKind::Zenoh };
    let plan: [(u32, TransportKind, Script); 2] =
        [(0, scalpel_kind, scalpel), (1, TransportKind::Zenoh, grasper)];
    // A viewer: the frames' statistics and the cuts, as any zenoh subscriber gets them.
    let viewer = incise_transport::client::ZenohClient::connect(&running.keys, 1, &endpoint)?;
    let frames = viewer.watch::<incise_protocol::v1::FrameStats>(&running.keys.frame())?;
    let cuts = viewer.watch::<incise_protocol::v1::CutEvent>(&running.keys.cut())?;
    let mut watched = Watched::default();
    let take = |watched: &mut Watched| {
        for f in frames.drain() {
            watched.frames += 1;
            watched.last_frame = f.frame;
        }
        for c in cuts.drain() {
            watched.cuts += 1;
            watched.voxels += u64::from(c.voxels_removed);
        }
    };
    let reports = std::thread::scope(|scope| -> anyhow::Result<Vec<ClientReport>> {
        let mut handles = Vec::new();
        for (tool, kind, script) in plan {
            let client = Client::connect(kind, &running.keys, tool, &endpoint)?;
            let (stage, name) = (&stage, running.tools[tool as usize].clone());
            handles.push(scope.spawn(move || {
                let secs = duration.as_secs_f64();
                let report =
                    drive(&client, tool, 1000.0, duration, |t| script(stage, t / secs), |_| {});
                ClientReport { tool: name, transport: kind.name(), report }
            }));
        }
        let start = Instant::now();
        while handles.iter().any(|h| !h.is_finished()) {
            std::thread::sleep(Duration::from_millis(500));
            take(&mut watched);
            eprint!(
                "\r\x1b[2Kdemo {:.1}/{:.1} s | {}",
                start.elapsed().as_secs_f64().min(duration.as_secs_f64()),
                duration.as_secs_f64(),
                running.status()
            );
        }
        eprintln!();
        Ok(handles.into_iter().map(|h| h.join().expect("a demo client panicked")).collect())
    })?;
    // A machine too loaded to step the physics in real time has simulated less than the run
    // lasted: the server runs on (the tools idle) until a keyframe interval is simulated and
    // a little more, so that the recording always holds a keyframe past the first to replay
    // from. A minute at most.
    let keyframe = ((crate::physics::KEYFRAME_INTERVAL_S * 1.1) / running.dt).ceil() as u64;
    let until = Instant::now() + Duration::from_mins(1);
    while running.physics.frames.load(Ordering::Relaxed) < keyframe && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
        take(&mut watched);
    }
    // The last frames are still on their way.
    std::thread::sleep(Duration::from_millis(100));
    take(&mut watched);
    Ok((running, reports, watched))
}

/// The summary the demo prints.
#[must_use]
pub fn summary(
    running: &Running,
    reports: &[ClientReport],
    watched: &Watched,
    duration: Duration,
) -> String {
    let get = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
    let p = &running.physics;
    let secs = duration.as_secs_f64();
    let jitter = running.shared.jitter();
    let mut out = format!(
        "demo: {secs:.1} s of {} with {} tools\nphysics: {} frames ({:.0} Hz, dt {} ms), {} late, {} step errors; removed {} voxels\nhaptics: {} updates; period jitter p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs\n",
        running.keys.scene(),
        running.tools.len(),
        get(&p.frames),
        get(&p.frames) as f64 / running.uptime().as_secs_f64(),
        running.dt * 1e3,
        get(&p.late),
        get(&p.step_errors),
        get(&p.removed),
        get(&running.shared.counters.updates),
        jitter.quantile_us(0.5).unwrap_or(0.0),
        jitter.quantile_us(0.99).unwrap_or(0.0),
        jitter.max_us(),
    );
    if let (Some(start), Some(now)) = running.memory_mb() {
        let _ =
            writeln!(out, "memory: {start:.1} MB resident once started, {now:.1} MB at the end");
    }
    for c in reports {
        let r = &c.report;
        let _ = writeln!(out, "{} over {}: {r}", c.tool, c.transport);
    }
    let _ = writeln!(
        out,
        "a viewer over zenoh: {} frame statistics (up to frame {}), {} cut events ({} voxels)",
        watched.frames, watched.last_frame, watched.cuts, watched.voxels
    );
    let faults: Vec<String> = running
        .faults
        .snapshot()
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(k, n)| format!("{n} {k}"))
        .collect();
    let _ = write!(
        out,
        "faults: {}",
        if faults.is_empty() { "none".into() } else { faults.join(", ") }
    );
    out
}
