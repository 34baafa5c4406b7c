//! `incise-server`: see the crate documentation and `incise-server --help`.

use anyhow::Context;
use clap::Parser;
use incise_haptics::HapticSettings;
use incise_server::lifetime::ParentWatch;
use incise_server::server::{self, Options};
use incise_sim::config::SceneConfig;
use incise_transport::zenoh_link::Endpoints;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// The incise simulation server: steps a deformable organ in real time, renders each tool's
/// force at 1 kHz, and serves tool poses and forces over zenoh (network) and iceoryx2 (shared
/// memory) at once.
#[derive(Parser, Debug)]
#[allow(clippy::struct_excessive_bools, reason = "command-line switches")]
#[command(version, about, long_about = None)]
struct Cli {
    /// A scene file (TOML, see deploy/scenes/README.md); without one, the embedded demo organ
    /// (8 × 6 × 5 cm with a tumour, a scalpel and a grasper) runs.
    scene: Option<PathBuf>,
    /// zenoh endpoint to listen on (repeatable). Default: `tcp/127.0.0.1:7447` (loopback only),
    /// unless `--connect` or `--zenoh-config` says where the server's zenoh goes.
    #[arg(long, value_name = "ENDPOINT")]
    listen: Vec<String>,
    /// zenoh endpoint to connect to (repeatable), such as a site router's `tcp/10.0.0.2:7447`:
    /// clients then reach the server through it.
    #[arg(long, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// A zenoh configuration file (json5), such as `deploy/zenoh/server.json5` (a station's
    /// server behind a site router, TLS certificates): it decides the session's mode, endpoints,
    /// scouting and security; `--listen` and `--connect` replace its endpoints.
    #[arg(long, value_name = "FILE")]
    zenoh_config: Option<PathBuf>,
    /// A zenoh setting over the configuration's, `KEY:VALUE` with a json5 value (repeatable),
    /// e.g. `--zenoh-cfg 'transport/link/tls/connect_certificate:"/etc/incise/tls/a.crt"'`.
    #[arg(long = "zenoh-cfg", value_name = "KEY:VALUE")]
    zenoh_cfg: Vec<String>,
    /// The station's name, which prefixes all the server's keys (`incise/v1/<NAME>/…`) in place
    /// of the scene's name: one router then serves many servers, even of the same scene,
    /// without collisions. Letters, digits, `_` and `-`.
    #[arg(long, value_name = "NAME")]
    name: Option<String>,
    /// Find zenoh peers by UDP multicast too (off: explicit endpoints only).
    #[arg(long)]
    multicast_scouting: bool,
    /// Do not serve zenoh.
    #[arg(long)]
    no_zenoh: bool,
    /// Do not serve iceoryx2 (shared memory).
    #[arg(long)]
    no_iceoryx2: bool,
    /// The largest force sent to a device (N).
    #[arg(long, default_value_t = HapticSettings::default().max_force_n)]
    max_force: f64,
    /// Seconds between status lines.
    #[arg(long, default_value_t = 5.0)]
    status_every: f64,
    /// Stop when the process that started this one ends, even if it is killed without stopping
    /// its children (test harnesses, a simulator's front end). Off under a service manager.
    #[arg(long)]
    stop_with_parent: bool,
    /// Run the demo: the embedded scene driven by two scripted clients over the real
    /// transports (a scalpel presses and cuts over iceoryx2, a grasper lifts over zenoh), then
    /// a summary of frames, rates, round-trip latencies, forces and cuts.
    #[arg(long)]
    demo: bool,
    /// How long the demo's scripted tools run (s). The server then runs on, the tools idle,
    /// until it has simulated at least one keyframe interval (1 s), so that a recording holds a
    /// keyframe to replay from even where the machine steps the physics below real time.
    #[arg(long, default_value_t = 6.0, requires = "demo")]
    duration: f64,
    /// Record the session into DIR: `<scene>-<unix seconds>.mcap`, every physics frame (the tool
    /// poses it used, the tools' forces, a hash of the state, its statistics), the cuts, the
    /// organ's surface and the scene, readable by any MCAP tool (Foxglove draws it); and its
    /// twin `<scene>-<unix seconds>.rrd` for the Rerun viewer. The demo records into
    /// `incise-recordings` unless `--no-record`.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// Also stream the session live to a Rerun viewer, e.g. `rerun+http://127.0.0.1:9876/proxy`
    /// (start one with `rerun`). A slow viewer is sent fewer surfaces, never slows the physics.
    #[arg(long, value_name = "URL")]
    rerun_connect: Option<String>,
    /// How often a recording or live stream takes the organ's surface (Hz of simulated time);
    /// frames whose surface changed are always taken. Scalars are taken every frame.
    #[arg(long, value_name = "HZ", default_value_t = incise_server::physics::DEFAULT_GEOMETRY_HZ)]
    geometry_hz: f64,
    /// Run the haptic thread at this real-time priority (`SCHED_FIFO`, 1 to 99) where the host
    /// allows it (root, `CAP_SYS_NICE`, or systemd's `LimitRTPRIO`); refused, it logs why and runs
    /// at normal priority.
    #[arg(long, value_name = "1-99", value_parser = clap::value_parser!(u8).range(1..=99))]
    haptic_priority: Option<u8>,
    /// The demo does not record.
    #[arg(long, requires = "demo", conflicts_with = "record")]
    no_record: bool,
}

/// Where the server's zenoh listens and connects, for the log.
fn describe_zenoh(z: &Endpoints) -> String {
    let mut parts = Vec::new();
    if let Some(file) = &z.config_file {
        parts.push(format!("config {}", file.display()));
    }
    if !z.listen.is_empty() {
        parts.push(format!("listening on {}", z.listen.join(" ")));
    }
    if !z.connect.is_empty() {
        parts.push(format!("connecting to {}", z.connect.join(" ")));
    }
    format!("zenoh ({})", parts.join(", "))
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                // Rerun's file sink warns that a file written without its chunk index seeks
                // slowly; a session's `.rrd` gets the index when the session ends.
                .unwrap_or_else(|_| {
                    tracing_subscriber::EnvFilter::new(
                        "info,zenoh=warn,re_log_encoding::rrd::file_sink=error",
                    )
                }),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let parent = ParentWatch::new(cli.stop_with_parent);
    anyhow::ensure!(
        cli.geometry_hz.is_finite() && cli.geometry_hz >= 0.0,
        "--geometry-hz must be a rate of 0 Hz or more, not {}",
        cli.geometry_hz
    );
    anyhow::ensure!(
        cli.max_force.is_finite() && cli.max_force > 0.0,
        "--max-force must be a positive number of newtons, not {}",
        cli.max_force
    );
    let listen = if cli.listen.is_empty() && cli.connect.is_empty() && cli.zenoh_config.is_none() {
        vec![format!("tcp/127.0.0.1:{}", incise_transport::zenoh_link::DEFAULT_PORT)]
    } else {
        cli.listen.clone()
    };
    let mut options = Options {
        name: cli.name.clone(),
        zenoh: (!cli.no_zenoh).then(|| Endpoints {
            listen,
            connect: cli.connect.clone(),
            multicast_scouting: cli.multicast_scouting,
            config_file: cli.zenoh_config.clone(),
            settings: cli.zenoh_cfg.clone(),
        }),
        iceoryx2: !cli.no_iceoryx2,
        haptics: HapticSettings { max_force_n: cli.max_force, ..HapticSettings::default() },
        record: match (&cli.record, cli.demo && !cli.no_record) {
            (Some(dir), _) => Some(dir.clone()),
            (None, true) => Some(PathBuf::from("incise-recordings")),
            (None, false) => None,
        },
        rerun_connect: cli.rerun_connect.clone(),
        geometry_hz: cli.geometry_hz,
        haptic_priority: cli.haptic_priority,
        scene_toml: match &cli.scene {
            Some(path) => std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the scene {}", path.display()))?,
            None => incise_server::scene::DEMO_SCENE.to_owned(),
        },
        scene_files: Vec::new(),
    };
    if let (Some(path), Some(_)) = (&cli.scene, &options.record) {
        // A scene that does not parse is reported by the scene loader below, with its place.
        if let Ok(config) = SceneConfig::from_toml(&options.scene_toml, &path.display().to_string())
        {
            let base = path.parent().unwrap_or(std::path::Path::new("."));
            options.scene_files = incise_server::scene::stored_files(&config, base);
        }
    }
    if cli.demo {
        anyhow::ensure!(
            cli.scene.is_none(),
            "--demo runs its own scene; leave out {:?}",
            cli.scene
        );
        anyhow::ensure!(
            cli.zenoh_config.is_none() && cli.connect.is_empty() && cli.name.is_none(),
            "--demo serves its own scene on its own endpoint; leave out --zenoh-config, --connect and --name"
        );
        anyhow::ensure!(
            cli.duration.is_finite() && cli.duration > 0.0,
            "--duration must be a positive number of seconds"
        );
        let duration = Duration::from_secs_f64(cli.duration);
        let (mut running, reports, watched) = incise_server::demo::run(&options, duration)?;
        running.stop_physics();
        println!("{}", incise_server::demo::summary(&running, &reports, &watched, duration));
        let recording = running.recording().map(|p| p.display().to_string());
        running.stop();
        if let Some(path) = recording {
            let rrd = std::path::Path::new(&path).with_extension("rrd");
            println!("recording: {path} (open it with any MCAP tool, e.g. `mcap info {path}`)");
            println!("           {} (open it with `rerun {0}`)", rrd.display());
        }
        return Ok(());
    }
    let scene = incise_server::scene::load(cli.scene.as_deref())?;
    for note in &scene.notes {
        tracing::info!("{note}");
    }
    let file =
        cli.scene.as_ref().map_or("<embedded demo scene>".into(), |p| p.display().to_string());
    let running = server::start(&scene, &file, &options)?;
    tracing::info!(
        "serving {} ({} tools: {}) on {}{}",
        running.keys.scene(),
        running.tools.len(),
        running.tools.join(", "),
        options.zenoh.as_ref().map_or("no zenoh".into(), describe_zenoh),
        if options.iceoryx2 { " and iceoryx2" } else { "" }
    );
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::Release))
            .context("cannot install the SIGINT/SIGTERM handler")?;
    }
    let every = Duration::from_secs_f64(cli.status_every.max(0.1));
    let mut last = Instant::now();
    while !stop.load(Ordering::Acquire) {
        if parent.parent_gone() {
            tracing::info!("the process that started this server has ended");
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
        if last.elapsed() >= every {
            tracing::info!("{}", running.status());
            last = Instant::now();
        }
    }
    tracing::info!("stopping: {}", running.status());
    running.stop();
    Ok(())
}
