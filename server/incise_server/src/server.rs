//! Starting and stopping a server: the simulation, the haptic loop, the transports and the
//! threads between them.

use crate::network::Network;
use crate::physics::{self, PhysicsStats};
use anyhow::Context;
use incise_haptics::{HapticLoop, HapticSettings, LoopIo, LoopShared};
use incise_protocol::keys::Keys;
use incise_protocol::v1;
use incise_record::{LiveStream, McapRecording, Recorder, RerunLog, Session, Sinks};
use incise_scene::Scene;
use incise_sim::Simulation;
use incise_sim::config::Cutting;
use incise_transport::shm::{ShmPorts, ShmServer};
use incise_transport::zenoh_link::{Endpoints, ZenohServer};
use incise_transport::{Faults, PoseHandler, ServerSide, TransportKind};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{JoinHandle, Thread};
use std::time::Duration;

/// How a server runs.
#[derive(Clone, Debug)]
pub struct Options {
    /// The name the server's keys carry (`incise/v1/<name>/…`) instead of the scene's own, so
    /// that one router can serve several stations running the same scene.
    pub name: Option<String>,
    /// How zenoh is served: its endpoints, or a configuration file (`None`: no zenoh).
    pub zenoh: Option<Endpoints>,
    /// Whether to serve iceoryx2.
    pub iceoryx2: bool,
    /// The haptic loop's limits.
    pub haptics: HapticSettings,
    /// Record the session into this folder (`<scene>-<unix seconds>.mcap` and `.rrd`).
    pub record: Option<PathBuf>,
    /// Also stream the session live to the Rerun viewer at this URL.
    pub rerun_connect: Option<String>,
    /// How often a recording takes the organ's surface (Hz of simulated time).
    pub geometry_hz: f64,
    /// Run the haptic thread at this real-time priority (`SCHED_FIFO`, 1–99) where the host
    /// allows it; `None`: the normal scheduler.
    pub haptic_priority: Option<u8>,
    /// The scene file's text, stored in a recording (so it replays on its own).
    pub scene_toml: String,
    /// The files the scene reads, stored in a recording beside it
    /// ([`crate::scene::stored_files`]).
    pub scene_files: Vec<(String, Vec<u8>)>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            name: None,
            zenoh: Some(Endpoints::listen_loopback(incise_transport::zenoh_link::DEFAULT_PORT)),
            iceoryx2: true,
            haptics: HapticSettings::default(),
            record: None,
            rerun_connect: None,
            geometry_hz: physics::DEFAULT_GEOMETRY_HZ,
            haptic_priority: None,
            scene_toml: crate::scene::DEMO_SCENE.to_owned(),
            scene_files: Vec::new(),
        }
    }
}

/// A running server.
pub struct Running {
    /// The scene's keys.
    pub keys: Keys,
    /// The tools' names, by id.
    pub tools: Vec<String>,
    /// What the haptic loop shares.
    pub shared: Arc<LoopShared>,
    /// What the transports refused.
    pub faults: Arc<Faults>,
    /// What the physics thread counts.
    pub physics: Arc<PhysicsStats>,
    /// The physics time step (s).
    pub dt: f64,
    transports: Arc<ServerSide>,
    network: Network,
    recorder: Option<Recorder>,
    started: std::time::Instant,
    /// Resident memory once running (MB).
    rss_at_start_mb: Option<f64>,
    stop: Arc<AtomicBool>,
    /// The physics thread's own stop flag and the thread, stopped first ([`Running::stop_physics`]).
    physics_stop: Arc<AtomicBool>,
    physics_thread: Option<JoinHandle<()>>,
    threads: Vec<JoinHandle<()>>,
    zenoh_sender: Option<Thread>,
}

/// The haptic thread's I/O: with iceoryx2 it waits on the poses event, takes iceoryx2's poses
/// and publishes their forces itself; zenoh's forces go to the sending thread it wakes.
struct HapticIo {
    shm: Option<ShmPorts>,
    zenoh_sender: Option<Thread>,
}

impl LoopIo for HapticIo {
    fn wait(&mut self, shared: &LoopShared, timeout: Duration) {
        let Some(ports) = &self.shm else {
            std::thread::park_timeout(timeout);
            return;
        };
        ports.wait(timeout);
        ports.receive(|pose| shared.accept_pose(TransportKind::Iceoryx2.source(), pose));
    }

    fn forces_ready(&mut self, shared: &LoopShared, tools: u64) {
        if let Some(ports) = &self.shm {
            for tool in (0..shared.tools().min(64)).filter(|t| tools & (1 << t) != 0) {
                if let Some((rendered, _)) = shared.force(tool) {
                    ports.send_force(&rendered.force);
                }
            }
        }
        if let Some(t) = &self.zenoh_sender {
            t.unpark();
        }
    }
}

/// A scene name as the keys need it: characters a key cannot hold become `_`.
fn key_name(name: &str) -> String {
    let mut n: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '_' })
        .take(incise_protocol::keys::MAX_SCENE_NAME)
        .collect();
    if n.is_empty() {
        n.push_str("scene");
    }
    n
}

/// Moves the calling thread to the real-time FIFO scheduler at priority `priority` (1–99), or
/// says why it stays where it is: an unprivileged process may not (it needs `CAP_SYS_NICE`, or
/// an `RLIMIT_RTPRIO` of at least `priority`, which systemd's `LimitRTPRIO` sets).
fn raise_priority(priority: u8) {
    use thread_priority::{
        RealtimeThreadSchedulePolicy, ThreadPriority, ThreadSchedulePolicy,
        set_thread_priority_and_policy, thread_native_id,
    };
    let result = ThreadPriority::try_from(priority).map_err(|e| format!("{e:?}")).and_then(|p| {
        set_thread_priority_and_policy(
            thread_native_id(),
            p,
            ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
        )
        .map_err(|e| format!("{e:?}"))
    });
    match result {
        Ok(()) => tracing::info!("haptic thread: real-time priority {priority} (SCHED_FIFO)"),
        Err(e) => tracing::warn!(
            "haptic thread: real-time priority {priority} refused ({e}); it runs at normal priority \
             (allow it with CAP_SYS_NICE or LimitRTPRIO={priority} in its systemd unit)"
        ),
    }
}

/// Poses refused, by reason: the haptic loop's checks, then the transports'.
fn refusals(shared: &LoopShared, faults: &Faults) -> impl Iterator<Item = (&'static str, u64)> {
    let c = &shared.counters;
    let get = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
    [("invalid", get(&c.invalid)), ("backwards", get(&c.backwards)), ("claimed", get(&c.claimed))]
        .into_iter()
        .chain(faults.snapshot())
}

/// What the stats queryable answers: the counters of the haptic loop, the transports and the
/// physics at the time of the query.
fn server_stats(
    scene: &str,
    started: std::time::Instant,
    shared: &LoopShared,
    faults: &Faults,
    physics: &PhysicsStats,
) -> v1::ServerStats {
    let get = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
    let c = &shared.counters;
    let refused = refusals(shared, faults)
        .map(|(reason, count)| v1::RefusedCount { reason: reason.to_owned(), count })
        .collect();
    v1::ServerStats {
        scene: scene.to_owned(),
        uptime_s: started.elapsed().as_secs_f64(),
        frames: get(&physics.frames),
        late_frames: get(&physics.late),
        poses: shared.tool_counts.iter().map(|t| get(&t.poses)).collect(),
        missing_poses: shared.tool_counts.iter().map(|t| get(&t.missing)).collect(),
        refused,
        haptic_updates: get(&c.updates),
        stale_forces: get(&c.stale),
    }
}

/// Starts a server on `scene` (read from `file`, for messages).
pub fn start(scene: &Scene, file: &str, options: &Options) -> anyhow::Result<Running> {
    let config = &scene.config;
    let keys = match &options.name {
        Some(name) => Keys::new(name).context("--name")?,
        None => Keys::new(&key_name(&config.name)).context("the scene's name")?,
    };
    // The physics must leave the haptic thread a core: unless the scene says otherwise, one
    // thread fewer than the cores, whose idle workers sleep.
    let exec = config.exec.executor_beside_realtime_thread();
    let mut sim = Simulation::with_executor(config, &scene.geometry, file, &exec)
        .with_context(|| format!("cannot build the simulation of {file}"))?;
    if let Some(gpu) = incise_scene::attach_gpu(&mut sim) {
        tracing::info!("{gpu}");
    }
    if let Some(c) = sim.calibration() {
        for l in &c.levels {
            tracing::info!(
                "model.kind = \"auto\": level {} {} ({} elements, {} unknowns), estimated error {:.2} % against level {}",
                l.level,
                l.element.name(),
                l.elements,
                l.dofs,
                100.0 * l.error,
                c.reference_level
            );
        }
        tracing::info!(
            "model.kind = \"auto\": runs level {} with {} elements, the coarsest within max_error = {:.1} %",
            c.chosen,
            c.chosen_element.name(),
            100.0 * c.max_error
        );
    }
    let tools: Vec<String> = config.tools.iter().map(|t| t.name.clone()).collect();
    let shared = LoopShared::new(tools.len(), &options.haptics);
    let faults = Arc::new(Faults::default());
    let handler: PoseHandler = {
        let shared = Arc::clone(&shared);
        Arc::new(move |kind, pose| shared.offer_pose(kind.source(), pose))
    };
    let info = scene_info(scene, &keys, &sim, &options.haptics);
    let physics_stats = Arc::new(PhysicsStats::default());
    let zenoh = match &options.zenoh {
        Some(endpoints) => {
            let mut z = ZenohServer::start(
                &keys,
                tools.len(),
                &info,
                endpoints,
                Arc::clone(&handler),
                Arc::clone(&faults),
            )
            .context("cannot serve zenoh (another server on the port? choose one with --listen)")?;
            let stats = {
                let (shared, faults, physics) =
                    (Arc::clone(&shared), Arc::clone(&faults), Arc::clone(&physics_stats));
                let (scene, started) = (keys.scene().to_owned(), std::time::Instant::now());
                move || server_stats(&scene, started, &shared, &faults, &physics)
            };
            z.serve_stats(&keys, stats).context("cannot serve the server's statistics")?;
            Some(z)
        }
        None => None,
    };
    let iceoryx2 = if options.iceoryx2 {
        Some(
            ShmServer::start(&keys, tools.len(), Arc::clone(&faults))
                .context("cannot serve iceoryx2 (is /dev/shm there? --no-iceoryx2 turns it off)")?,
        )
    } else {
        None
    };
    let transports = Arc::new(ServerSide { zenoh, iceoryx2 });
    let stop = Arc::new(AtomicBool::new(false));
    let dt = config.dt();
    let recorder =
        start_recorder(options, keys.scene(), &incise_convert::tools::tool_looks(config), &shared)?;
    let network =
        Network::start(Arc::clone(&transports)).context("cannot start the network runtime")?;
    let mut threads = Vec::new();
    // zenoh's force sender: parked until the haptic loop has forces, then sends the new ones
    // (a zenoh put may allocate, so not on the haptic thread).
    let zenoh_sender = if transports.zenoh.is_some() {
        let (shared, transports, stop) =
            (Arc::clone(&shared), Arc::clone(&transports), Arc::clone(&stop));
        let sender = std::thread::Builder::new().name("incise-forces".into()).spawn(move || {
            let mut sent = vec![0u64; shared.tools()];
            while !stop.load(Ordering::Acquire) {
                std::thread::park_timeout(Duration::from_millis(100));
                for (tool, last) in sent.iter_mut().enumerate() {
                    if let Some((rendered, version)) = shared.force(tool)
                        && version > *last
                    {
                        *last = version;
                        let message =
                            v1::ToolForce::from(&rendered.force).with_proxy(rendered.proxy);
                        transports.send_zenoh_force(&message);
                    }
                }
            }
        })?;
        let thread = sender.thread().clone();
        threads.push(sender);
        Some(thread)
    } else {
        None
    };
    if transports.iceoryx2.is_some() {
        // Weak: the transports hold the pose handler, which holds `shared`.
        let transports = Arc::downgrade(&transports);
        shared.set_waker(Box::new(move || {
            if let Some(t) = transports.upgrade() {
                t.ring();
            }
        }));
    }
    threads.push({
        // The loop stops through `LoopShared::stop`, which `Running::stop` calls. It opens
        // iceoryx2's ports itself (they stay on the thread that opens them) and says whether
        // it could.
        let haptics = HapticLoop::new(Arc::clone(&shared), options.haptics);
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (transports, sender) = (Arc::clone(&transports), zenoh_sender.clone());
        let priority = options.haptic_priority;
        let thread =
            std::thread::Builder::new().name("incise-haptics".into()).spawn(move || {
                if let Some(p) = priority {
                    raise_priority(p);
                }
                let shm = transports.iceoryx2.as_ref().map(ShmServer::open_ports).transpose();
                let shm = match shm {
                    Ok(shm) => shm,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                drop(transports);
                let _ = ready_tx.send(Ok(()));
                haptics.run(&mut HapticIo { shm, zenoh_sender: sender });
            })?;
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                stop.store(true, Ordering::Release);
                if let Some(t) = &zenoh_sender {
                    t.unpark();
                }
                return Err(anyhow::Error::new(e).context("cannot open the iceoryx2 ports"));
            }
            Err(_) => anyhow::bail!("the haptic thread died before it started"),
        }
        thread
    });
    let physics_stop = Arc::new(AtomicBool::new(false));
    let physics_thread = {
        let record = recorder.as_ref().map(Recorder::handle);
        let clock = physics::GeometryClock::new(options.geometry_hz);
        let (shared, outbox, stats, stop) = (
            Arc::clone(&shared),
            network.outbox(),
            Arc::clone(&physics_stats),
            Arc::clone(&physics_stop),
        );
        std::thread::Builder::new().name("incise-physics".into()).spawn(move || {
            let recording = record.as_ref().map(|r| (r, clock));
            physics::run(sim, &shared, &outbox, recording, &stats, &stop);
        })?
    };
    Ok(Running {
        keys,
        tools,
        shared,
        faults,
        physics: physics_stats,
        dt,
        transports,
        network,
        recorder,
        started: std::time::Instant::now(),
        rss_at_start_mb: resident_mb(),
        stop,
        physics_stop,
        physics_thread: Some(physics_thread),
        threads,
        zenoh_sender,
    })
}

impl Running {
    /// Stops the physics (the last frame it stepped is the last one recorded) and waits for it;
    /// the transports and the haptic loop go on until [`Self::stop`]. What a summary of the
    /// session reads after this counts the frames the recording holds.
    pub fn stop_physics(&mut self) {
        self.physics_stop.store(true, Ordering::Release);
        if let Some(t) = self.physics_thread.take() {
            let _ = t.join();
        }
    }

    /// Stops every thread and closes the transports.
    pub fn stop(mut self) {
        self.stop_physics();
        self.stop.store(true, Ordering::Release);
        self.shared.stop();
        if let Some(t) = &self.zenoh_sender {
            t.unpark();
        }
        for t in self.threads {
            let _ = t.join();
        }
        self.network.stop();
        drop(self.transports);
        if let Some(recorder) = self.recorder {
            let path = recorder.path().display().to_string();
            let stats = recorder.stats();
            let waits = stats.waits.load(Ordering::Relaxed);
            let surfaces = stats.surfaces.load(Ordering::Relaxed);
            let forces = stats.forces.load(Ordering::Relaxed);
            let forces_dropped = self.shared.force_log().map_or(0, |log| log.dropped());
            let live_dropped = stats.live_dropped_geometry.load(Ordering::Relaxed);
            match recorder.finish() {
                Ok(frames) if path.is_empty() => tracing::info!(
                    "streamed {frames} frames and {surfaces} surfaces live ({live_dropped} surfaces dropped: the viewer was behind)"
                ),
                Ok(frames) => tracing::info!(
                    "recorded {frames} frames, {surfaces} surfaces and {forces} sent forces ({forces_dropped} dropped from the log) to {path} and its .rrd (the physics waited for the recorder {waits} times)"
                ),
                Err(e) => tracing::error!("the recording is incomplete: {e}"),
            }
        }
    }

    /// The recording's MCAP file, when recording (its `.rrd` twin has the same stem).
    #[must_use]
    pub fn recording(&self) -> Option<&Path> {
        self.recorder.as_ref().map(Recorder::path).filter(|p| !p.as_os_str().is_empty())
    }

    /// Resident memory (MB) once the server had started, and now: a long session's memory
    /// should stay flat.
    #[must_use]
    pub fn memory_mb(&self) -> (Option<f64>, Option<f64>) {
        (self.rss_at_start_mb, resident_mb())
    }

    /// How long the server has run.
    #[must_use]
    pub fn uptime(&self) -> Duration {
        self.started.elapsed()
    }

    /// One line on how the server is doing.
    #[must_use]
    pub fn status(&self) -> String {
        let p = &self.physics;
        let c = &self.shared.counters;
        let get = |a: &std::sync::atomic::AtomicU64| a.load(Ordering::Relaxed);
        let forces: Vec<String> = self
            .tools
            .iter()
            .enumerate()
            .take(8)
            .map(|(i, name)| format!("{name} {:.2} N", get(&p.tool_force_un[i]) as f64 * 1e-6))
            .collect();
        let kinds: Vec<(&str, u64)> =
            refusals(&self.shared, &self.faults).filter(|(_, n)| *n > 0).collect();
        let refused: u64 = kinds.iter().map(|(_, n)| n).sum();
        let refused = if kinds.is_empty() {
            "0 refused".to_owned()
        } else {
            let each: Vec<String> = kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
            format!("{refused} refused: {}", each.join(", "))
        };
        let jitter = self.shared.jitter().quantile_us(0.99).unwrap_or(0.0);
        let recording = match &self.recorder {
            Some(r) => {
                let s = r.stats();
                let failed = if s.failed.load(Ordering::Relaxed) { ", FAILED" } else { "" };
                let live = match get(&s.live_dropped_geometry) {
                    0 => String::new(),
                    n => format!(", live viewer behind: {n} surfaces dropped"),
                };
                format!(
                    " | recorded {} frames, {} surfaces, {} forces ({} waits{failed}{live})",
                    get(&s.frames),
                    get(&s.surfaces),
                    get(&s.forces),
                    get(&s.waits)
                )
            }
            None => String::new(),
        };
        let dropped = match self.network.dropped() {
            0 => String::new(),
            n => format!(" | {n} frame messages dropped (the network fell behind)"),
        };
        format!(
            "frame {} ({} late, {} µs last) | haptics {} updates, jitter p99 {jitter:.0} µs | poses {} ({refused}) | forces: {} | removed {}{recording}{dropped}",
            get(&p.frames),
            get(&p.late),
            get(&p.last_frame_us),
            get(&c.updates),
            get(&c.poses),
            forces.join(", "),
            get(&p.removed),
        )
    }
}

/// This process's resident memory (MB), from `/proc/self/statm` (`None` where there is none).
#[must_use]
pub fn resident_mb() -> Option<f64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: f64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // Linux's page size on every platform incise targets.
    Some(pages * 4096.0 / 1e6)
}

/// Sent forces the ring to the recorder holds: 4 s of two tools at 1 kHz, against the
/// recorder's 2 ms between takes.
const FORCE_LOG: usize = 8192;

/// The simulated time between two Foxglove scene updates in a recording (s): each repeats the
/// whole surface in Foxglove's verbose points (hundreds of kilobytes on the 13k liver), so twice
/// a second; the
/// `.rrd` and `/incise/surface` carry the surface at the geometry rate.
const SCENE_INTERVAL_S: f64 = 0.5;

/// Starts the recorder when the session is recorded (`--record DIR`: creates DIR and writes
/// `<scene>-<unix seconds>.mcap` and `.rrd` there) or streamed (`--rerun-connect URL`).
fn start_recorder(
    options: &Options,
    scene: &str,
    tools: &[incise_record::ToolLook],
    shared: &LoopShared,
) -> anyhow::Result<Option<Recorder>> {
    let mut sinks = Sinks::default();
    if let Some(dir) = &options.record {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--record {}: cannot create the folder", dir.display()))?;
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let path = dir.join(format!("{scene}-{secs}.mcap"));
        let session = Session {
            scene: scene.to_owned(),
            scene_toml: options.scene_toml.clone(),
            version: env!("CARGO_PKG_VERSION").into(),
            git_revision: option_env!("INCISE_GIT_REVISION").unwrap_or("").into(),
            tools: tools.to_vec(),
            scene_interval_s: SCENE_INTERVAL_S,
            files: options.scene_files.clone(),
        };
        sinks.mcap = Some(McapRecording::create(&path, &session)?);
        sinks.forces = Some(shared.log_forces(FORCE_LOG));
        sinks.rrd = Some(
            RerunLog::save_session(&path.with_extension("rrd"), tools)
                .map_err(anyhow::Error::msg)?,
        );
    }
    if let Some(url) = &options.rerun_connect {
        let log =
            RerunLog::connect(url, tools).map_err(anyhow::Error::msg).context("--rerun-connect")?;
        sinks.live = Some(LiveStream::start(log)?);
    }
    if sinks.mcap.is_none() && sinks.live.is_none() {
        return Ok(None);
    }
    Ok(Some(Recorder::with_sinks(sinks)?))
}

/// What the `…/info` queryable answers.
fn scene_info(
    scene: &Scene,
    keys: &Keys,
    sim: &Simulation,
    haptics: &HapticSettings,
) -> v1::SceneInfo {
    let config = &scene.config;
    let tools = config
        .tools
        .iter()
        .enumerate()
        .map(|(id, t)| v1::ToolInfo {
            id: id as u32,
            name: t.name.clone(),
            cutting: match t.cutting {
                Cutting::Off => "off",
                Cutting::Remove => "remove",
                Cutting::Separate => "separate",
            }
            .into(),
            grasps: t.jaws.is_some(),
            max_force_n: haptics.max_force_n,
            stiffness_n_per_m: t.stiffness,
        })
        .collect();
    let materials = config
        .materials
        .iter()
        .map(|m| v1::MaterialInfo {
            label: u32::from(m.label),
            youngs_modulus_pa: m.youngs_modulus,
            poisson_ratio: m.poisson_ratio,
            density_kg_per_m3: m.density,
        })
        .collect();
    let (lo, hi) = bounds(sim);
    v1::SceneInfo {
        scene: keys.scene().into(),
        length_unit: "m".into(),
        dt_s: config.dt(),
        frame_rate_hz: 1.0 / config.dt(),
        haptic_rate_hz: haptics.rate_hz,
        tools,
        materials,
        versions: Some(v1::Versions {
            incise: env!("CARGO_PKG_VERSION").into(),
            protocol: incise_protocol::PACKAGE.into(),
            git_revision: option_env!("INCISE_GIT_REVISION").unwrap_or("").into(),
        }),
        bounds_min_x: lo[0],
        bounds_min_y: lo[1],
        bounds_min_z: lo[2],
        bounds_max_x: hi[0],
        bounds_max_y: hi[1],
        bounds_max_z: hi[2],
    }
}

/// The organ's bounding box at rest (m): its surface's where it has one, else its nodes'.
fn bounds(sim: &Simulation) -> ([f64; 3], [f64; 3]) {
    let points: Vec<[f64; 3]> = match (sim.surface(), sim.surface_positions()) {
        (Some(surface), Some(p)) => {
            surface.live_vertices().iter().map(|&v| p[v as usize]).collect()
        }
        _ => sim.state().x.clone(),
    };
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}
