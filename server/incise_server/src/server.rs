//! Starting and stopping a server: the simulation, the haptic loop, the transports and the
//! threads between them.

use crate::physics::{self, PhysicsStats};
use anyhow::Context;
use incise_haptics::{ForceSink, HapticLoop, HapticSettings, LoopShared};
use incise_protocol::keys::Keys;
use incise_protocol::v1;
use incise_scene::Scene;
use incise_sim::Simulation;
use incise_sim::config::Cutting;
use incise_transport::shm::ShmServer;
use incise_transport::zenoh_link::{Endpoints, ZenohServer};
use incise_transport::{Faults, PoseHandler, ServerSide};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{JoinHandle, Thread};
use std::time::Duration;

/// How a server runs.
#[derive(Clone, Debug)]
pub struct Options {
    /// zenoh endpoints to listen on (`None`: no zenoh).
    pub zenoh: Option<Endpoints>,
    /// Whether to serve iceoryx2.
    pub iceoryx2: bool,
    /// The haptic loop's limits.
    pub haptics: HapticSettings,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            zenoh: Some(Endpoints::listen_loopback(incise_transport::zenoh_link::DEFAULT_PORT)),
            iceoryx2: true,
            haptics: HapticSettings::default(),
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
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    forces: Thread,
}

/// Wakes the force-sending thread.
struct Wake(Thread);

impl ForceSink for Wake {
    fn forces_ready(&mut self, _tools: u64) {
        self.0.unpark();
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

/// Starts a server on `scene` (read from `file`, for messages).
pub fn start(scene: &Scene, file: &str, options: &Options) -> anyhow::Result<Running> {
    let config = &scene.config;
    let keys = Keys::new(&key_name(&config.name)).context("the scene's name")?;
    let sim = Simulation::new(config, &scene.geometry, file)
        .with_context(|| format!("cannot build the simulation of {file}"))?;
    let tools: Vec<String> = config.tools.iter().map(|t| t.name.clone()).collect();
    let shared = LoopShared::new(tools.len());
    let faults = Arc::new(Faults::default());
    let handler: PoseHandler = {
        let shared = Arc::clone(&shared);
        Arc::new(move |kind, pose| shared.offer_pose(kind.source(), pose))
    };
    let info = scene_info(scene, &keys, &sim, &options.haptics);
    let zenoh = match &options.zenoh {
        Some(endpoints) => Some(
            ZenohServer::start(
                &keys,
                tools.len(),
                &info,
                endpoints,
                Arc::clone(&handler),
                Arc::clone(&faults),
            )
            .context("cannot serve zenoh (another server on the port? choose one with --listen)")?,
        ),
        None => None,
    };
    let iceoryx2 = if options.iceoryx2 {
        Some(
            ShmServer::start(&keys, tools.len(), handler, Arc::clone(&faults))
                .context("cannot serve iceoryx2 (is /dev/shm there? --no-iceoryx2 turns it off)")?,
        )
    } else {
        None
    };
    let transports = Arc::new(ServerSide { zenoh, iceoryx2 });
    let stop = Arc::new(AtomicBool::new(false));
    let physics_stats = Arc::new(PhysicsStats::default());
    let dt = config.dt();
    let mut threads = Vec::new();
    // The force sender: parked until the haptic loop has forces, then sends the new ones.
    let sender = {
        let (shared, transports, stop) =
            (Arc::clone(&shared), Arc::clone(&transports), Arc::clone(&stop));
        std::thread::Builder::new().name("incise-forces".into()).spawn(move || {
            let mut sent = vec![0u64; shared.tools()];
            while !stop.load(Ordering::Acquire) {
                std::thread::park_timeout(Duration::from_millis(100));
                for (tool, last) in sent.iter_mut().enumerate() {
                    if let Some((force, version)) = shared.force(tool)
                        && version > *last
                    {
                        *last = version;
                        transports.send_force(&force);
                    }
                }
            }
        })?
    };
    let forces = sender.thread().clone();
    threads.push(sender);
    threads.push({
        // The loop stops through `LoopShared::stop`, which `Running::stop` calls.
        let haptics = HapticLoop::new(Arc::clone(&shared), options.haptics);
        let mut wake = Wake(forces.clone());
        std::thread::Builder::new()
            .name("incise-haptics".into())
            .spawn(move || haptics.run(&mut wake))?
    });
    threads.push({
        let (shared, transports, stats, stop) = (
            Arc::clone(&shared),
            Arc::clone(&transports),
            Arc::clone(&physics_stats),
            Arc::clone(&stop),
        );
        std::thread::Builder::new().name("incise-physics".into()).spawn(move || {
            physics::run(sim, &shared, &transports, &stats, &stop);
        })?
    });
    Ok(Running {
        keys,
        tools,
        shared,
        faults,
        physics: physics_stats,
        dt,
        transports,
        stop,
        threads,
        forces,
    })
}

impl Running {
    /// Stops every thread and closes the transports.
    pub fn stop(self) {
        self.stop.store(true, Ordering::Release);
        self.shared.stop();
        self.forces.unpark();
        for t in self.threads {
            let _ = t.join();
        }
        drop(self.transports);
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
        let refused: u64 = self.faults.snapshot().iter().map(|(_, n)| n).sum::<u64>()
            + get(&c.invalid)
            + get(&c.backwards);
        let jitter = self.shared.jitter().quantile_us(0.99).unwrap_or(0.0);
        format!(
            "frame {} ({} late, {} µs last) | haptics {} updates, jitter p99 {jitter:.0} µs | poses {} ({refused} refused) | forces: {} | removed {}",
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
