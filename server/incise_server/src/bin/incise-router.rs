//! `incise-router`: a zenoh router, for sites without `zenohd`. It is the zenoh crate in router
//! mode and nothing else, configured by the same json5 files `zenohd` reads (`deploy/zenoh/`):
//! servers and clients connect to it, it routes their keys, and it enforces the access control
//! and TLS that its configuration asks for.

use anyhow::Context;
use clap::Parser;
use incise_transport::zenoh_link::{DEFAULT_PORT, Endpoints};
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// A zenoh router for incise servers and clients: routes keys between them, with the access
/// control and TLS its configuration sets. Stops on SIGINT or SIGTERM.
#[derive(Parser, Debug)]
#[command(version, long_about = None)]
struct Cli {
    /// A zenoh configuration file (json5), such as `deploy/zenoh/router-site.json5`. Without
    /// one: a router on `tcp/127.0.0.1:7447`, multicast scouting off.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// An endpoint to listen on (repeatable), replacing the configuration's.
    #[arg(long, value_name = "ENDPOINT")]
    listen: Vec<String>,
    /// Another router to connect to (repeatable), replacing the configuration's: how routers
    /// of a site's several rooms join into one key space.
    #[arg(long, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// A setting over the configuration's, `KEY:VALUE` with a json5 value (repeatable), as
    /// `zenohd --cfg` takes it, e.g. `'transport/link/tls/root_ca_certificate:"/etc/incise/tls/ca.crt"'`.
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    cfg: Vec<String>,
    /// Stop when the process that started this one ends, even if it is killed without stopping
    /// its children (test harnesses). Off under a service manager.
    #[arg(long)]
    stop_with_parent: bool,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let parent = incise_server::lifetime::ParentWatch::new(cli.stop_with_parent);
    let listen = if cli.listen.is_empty() && cli.config.is_none() {
        vec![format!("tcp/127.0.0.1:{DEFAULT_PORT}")]
    } else {
        cli.listen.clone()
    };
    let endpoints = Endpoints {
        listen,
        connect: cli.connect.clone(),
        multicast_scouting: false,
        config_file: cli.config.clone(),
        settings: cli.cfg.clone(),
    };
    let session = endpoints.open("router").context("cannot start the router")?;
    let listening = endpoints.config("router")?.get_json("listen/endpoints").unwrap_or_default();
    // One line on standard output once it routes, for whoever started it.
    println!("incise-router {} routing, listening on {listening}", session.zid());
    std::io::stdout().flush()?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::Release))
            .context("cannot install the SIGINT/SIGTERM handler")?;
    }
    while !stop.load(Ordering::Acquire) && !parent.parent_gone() {
        std::thread::sleep(Duration::from_millis(100));
    }
    tracing::info!("stopping");
    drop(session);
    Ok(())
}
