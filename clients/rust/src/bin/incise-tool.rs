//! `incise-tool`: a scripted haptic device. Connects to a running `incise-server` over zenoh or
//! iceoryx2, drives one tool along a trajectory at a fixed rate, prints the forces it receives
//! and a summary of the pose → force round trips.

use anyhow::{Context, bail};
use clap::Parser;
use incise_client::drive::{Report, drive};
use incise_client::script::{Script, parse_csv};
use incise_client::{Client, Keys, TransportKind};
use incise_transport::zenoh_link::Endpoints;
use std::time::Duration;

/// Drives one tool of a running incise-server along a scripted trajectory and reports the
/// forces and round trips.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None)]
struct Cli {
    /// `zenoh` (network) or `iceoryx2` (shared memory, same machine).
    #[arg(long, default_value = "zenoh")]
    transport: TransportKind,
    /// The server's (or the site router's) zenoh endpoint, also asked for the scene's
    /// description. Default: `tcp/127.0.0.1:7447`, unless `--zenoh-config` names one.
    #[arg(long, value_name = "ENDPOINT")]
    connect: Option<String>,
    /// A zenoh configuration file (json5) for the connection, such as
    /// `deploy/zenoh/driver.json5` (TLS certificates, the site router); `--connect`, when
    /// given, replaces its endpoints.
    #[arg(long, value_name = "FILE")]
    zenoh_config: Option<std::path::PathBuf>,
    /// A zenoh setting over the configuration's, `KEY:VALUE` with a json5 value (repeatable).
    #[arg(long = "zenoh-cfg", value_name = "KEY:VALUE")]
    zenoh_cfg: Vec<String>,
    /// The scene's name, as the server's keys carry it.
    #[arg(long, default_value = "demo_organ")]
    scene: String,
    /// The tool to drive (its id in the scene).
    #[arg(long, default_value_t = 0)]
    tool: u32,
    /// `press`, `press-cut`, `circle`, or a CSV file of poses (t, x, y, z, qw, qx, qy, qz,
    /// gripper).
    #[arg(long, default_value = "press")]
    script: String,
    /// The surface point the scripts work at, `x,y,z` in metres (default: the top of the organ,
    /// from the server's scene description).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    at: Option<Vec<f64>>,
    /// How far the scripts press in (m).
    #[arg(long, default_value_t = 0.004)]
    depth: f64,
    /// Seconds to run.
    #[arg(long, default_value_t = 4.0)]
    duration: f64,
    /// Poses per second.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Print every n-th force (0: none).
    #[arg(long, default_value_t = 250)]
    print_every: u64,
    /// End with one line of JSON: `transport`, `samples`, `rtt_us_p50`, `rtt_us_p99`,
    /// `rtt_us_p999`, `rtt_us_max`, `sent`, `max_force_n`.
    #[arg(long)]
    json: bool,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    if !(cli.duration.is_finite() && cli.duration > 0.0) {
        bail!("--duration must be a positive number of seconds");
    }
    if !(cli.rate.is_finite() && cli.rate > 0.0 && cli.rate <= 20_000.0) {
        bail!("--rate must be between 0 and 20000 poses per second");
    }
    let keys = Keys::new(&cli.scene)?;
    let connect = match (&cli.connect, &cli.zenoh_config) {
        (Some(endpoint), _) => vec![endpoint.clone()],
        (None, None) => vec!["tcp/127.0.0.1:7447".to_owned()],
        (None, Some(_)) => Vec::new(),
    };
    let endpoints = Endpoints {
        connect: connect.clone(),
        config_file: cli.zenoh_config.clone(),
        settings: cli.zenoh_cfg.clone(),
        ..Endpoints::default()
    };
    let at = match &cli.at {
        Some(v) if v.len() == 3 && v.iter().all(|c| c.is_finite()) => [v[0], v[1], v[2]],
        Some(v) => bail!("--at takes three finite numbers, x,y,z in metres, not {v:?}"),
        None => {
            let probe =
                incise_transport::client::ZenohClient::connect_with(&keys, cli.tool, &endpoints)?;
            let info = probe.scene_info(Duration::from_secs(5)).with_context(|| {
                format!(
                    "no scene {} answered at {} (give --at x,y,z to go without)",
                    cli.scene,
                    if connect.is_empty() {
                        "the configured endpoints".into()
                    } else {
                        connect.join(" ")
                    }
                )
            })?;
            [
                0.5 * (info.bounds_min_x + info.bounds_max_x),
                0.5 * (info.bounds_min_y + info.bounds_max_y),
                info.bounds_max_z,
            ]
        }
    };
    let script = match cli.script.as_str() {
        "press" => Script::Press { at, depth: cli.depth },
        "press-cut" => Script::PressCut { at, depth: cli.depth, stroke: 0.02 },
        "circle" => Script::Circle { at, radius: 0.005, depth: cli.depth, period: 1.0 },
        file => {
            let text = std::fs::read_to_string(file).with_context(|| {
                format!("--script {file}: not press, press-cut, circle or a readable CSV file")
            })?;
            Script::Csv(parse_csv(&text, file).map_err(anyhow::Error::msg)?)
        }
    };
    let client = match cli.transport {
        TransportKind::Zenoh => Client::connect_zenoh(&keys, cli.tool, &endpoints)?,
        TransportKind::Iceoryx2 => Client::connect(cli.transport, &keys, cli.tool, "")?,
    };
    let duration = Duration::from_secs_f64(cli.duration);
    let mut count = 0u64;
    let report = drive(
        &client,
        cli.tool,
        cli.rate,
        duration,
        |t| script.pose_at(t, cli.duration),
        |f| {
            count += 1;
            if cli.print_every > 0 && count.is_multiple_of(cli.print_every) {
                println!(
                    "pose {:>6}: force ({:+.3}, {:+.3}, {:+.3}) N, flags {:#x}",
                    f.pose_sequence, f.force[0], f.force[1], f.force[2], f.flags
                );
            }
        },
    );
    print_summary(&cli, &report);
    Ok(())
}

fn print_summary(cli: &Cli, r: &Report) {
    println!("tool {} over {}: {r}", cli.tool, cli.transport.name());
    if cli.json {
        let json = serde_json::json!({
            "transport": cli.transport.name(),
            "samples": r.rtt_us.len(),
            "sent": r.sent,
            "rtt_us_p50": r.quantile(0.5),
            "rtt_us_p99": r.quantile(0.99),
            "rtt_us_p999": r.quantile(0.999),
            "rtt_us_max": r.quantile(1.0),
            "max_force_n": r.max_force_n,
        });
        println!("{json}");
    }
}
