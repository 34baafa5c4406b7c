//! `incise-bench coexist`: what the physics and a 1 kHz real-time thread cost each other on this
//! machine. The server runs a haptic thread that must wake every millisecond beside the physics;
//! on two cores the physics' workers, if they spin while idle, hold the core that thread needs.
//!
//! For each executor setting (physics on one or two threads; idle workers spinning or sleeping) a
//! probe thread wakes on a 1 ms schedule while the scene steps as fast as it can, and the report
//! prints the probe's period jitter (how far each period between two wake-ups is from 1 ms:
//! p50, p99, max) and the physics' steps per second. A first row runs the probe alone, the floor
//! this machine's timer gives.

use crate::timing::quantile;
use incise_fem::{Executor, Idle};
use incise_sim::{Simulation, StepInputs};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Arguments of `incise-bench coexist`.
#[derive(clap::Args, Debug)]
pub struct CoexistArgs {
    /// The scene that steps: a name in `--scene-dir` (`b1`, `b2`, `b3`, `liver_13k`, …) or a
    /// scene file's path.
    #[arg(long, default_value = "b3")]
    scene: String,
    /// Folder of the named scenes.
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Wall time each row runs (s).
    #[arg(long, default_value_t = 3.0)]
    seconds: f64,
    /// The probe's period (µs): 1,000 is the haptic loop's 1 kHz.
    #[arg(long, default_value_t = 1000)]
    period_us: u64,
    /// End with one line holding one JSON object `{"rows":[…]}`.
    #[arg(long)]
    json: bool,
}

/// One executor setting's figures.
#[derive(Clone, Debug, Serialize)]
struct Row {
    /// Threads the physics ran on (0: the probe alone).
    physics_threads: usize,
    /// Whether the physics' idle workers spun (`false`: they slept).
    spin: bool,
    /// Physics steps per second while the probe ran.
    steps_per_s: f64,
    /// The probe's period jitter, `|period − 1 ms|`, in µs.
    jitter_us_p50: f64,
    jitter_us_p99: f64,
    jitter_us_max: f64,
    /// Periods measured.
    periods: usize,
}

/// Wakes on a `period` schedule until `stop`; returns `|period − target|` of every period (µs).
/// The deadlines are absolute (`start + k·period`), so a late wake-up does not shift the ones
/// after it, and the thread sleeps, never spins, between them.
fn probe(period: Duration, stop: &AtomicBool) -> Vec<f64> {
    let start = Instant::now();
    let mut jitter = Vec::with_capacity(16_384);
    let mut last: Option<Instant> = None;
    let mut k = 1u32;
    while !stop.load(Ordering::Relaxed) {
        let deadline = start + period * k;
        let now = Instant::now();
        if deadline > now {
            std::thread::sleep(deadline - now);
        }
        let woke = Instant::now();
        if let Some(previous) = last {
            let actual = woke - previous;
            jitter.push((actual.as_secs_f64() - period.as_secs_f64()).abs() * 1e6);
        }
        last = Some(woke);
        // A wake-up later than a whole period skips the missed deadlines instead of firing them
        // back to back.
        k = k.max(((woke - start).as_nanos() / period.as_nanos()) as u32) + 1;
    }
    jitter
}

/// Runs the probe for `seconds` beside `physics` (stepping until the probe stops), and returns
/// the row.
fn measure(
    seconds: f64,
    period: Duration,
    physics: Option<(&mut Simulation, usize, bool)>,
) -> anyhow::Result<Row> {
    let stop = Arc::new(AtomicBool::new(false));
    let probe_stop = Arc::clone(&stop);
    let handle = std::thread::Builder::new()
        .name("incise-haptic-probe".into())
        .spawn(move || probe(period, &probe_stop))?;
    let start = Instant::now();
    let limit = Duration::from_secs_f64(seconds);
    let mut steps = 0u64;
    let (threads, spin) = if let Some((sim, threads, spin)) = physics {
        let inputs = StepInputs::default();
        while start.elapsed() < limit {
            sim.step(&inputs).map_err(|e| anyhow::anyhow!("step {steps}: {e}"))?;
            steps += 1;
        }
        (threads, spin)
    } else {
        std::thread::sleep(limit);
        (0, false)
    };
    let elapsed = start.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let mut jitter = handle.join().map_err(|_| anyhow::anyhow!("the probe thread panicked"))?;
    jitter.sort_by(f64::total_cmp);
    Ok(Row {
        physics_threads: threads,
        spin,
        steps_per_s: steps as f64 / elapsed,
        jitter_us_p50: quantile(&jitter, 0.5),
        jitter_us_p99: quantile(&jitter, 0.99),
        jitter_us_max: jitter.last().copied().unwrap_or(0.0),
        periods: jitter.len(),
    })
}

/// The scene file `name` names: a path to an existing file, or `<scene_dir>/<name>.toml`.
pub fn scene_path(name: &str, scene_dir: &std::path::Path) -> PathBuf {
    let as_path = PathBuf::from(name);
    if as_path.is_file() { as_path } else { scene_dir.join(format!("{name}.toml")) }
}

/// Runs the report.
pub fn run(args: &CoexistArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.seconds > 0.0, "--seconds must be positive");
    anyhow::ensure!(args.period_us > 0, "--period-us must be positive");
    let path = scene_path(&args.scene, &args.scene_dir);
    let scene = incise_scene::read_scene(&path).map_err(|e| anyhow::anyhow!("--scene: {e}"))?;
    for note in &scene.notes {
        eprintln!("note: {note}");
    }
    let period = Duration::from_micros(args.period_us);
    let settings: [(usize, bool); 4] = [(1, false), (1, true), (2, false), (2, true)];
    // Progress as plain lines: a progress bar's ticking thread would wake beside the probe.
    let total = settings.len() + 1;
    eprintln!("coexist: row 1/{total}: the probe alone");
    let mut rows = vec![measure(args.seconds, period, None)?];
    for (i, (threads, spin)) in settings.into_iter().enumerate() {
        eprintln!(
            "coexist: row {}/{total}: physics on {threads} thread(s), idle workers {}",
            i + 2,
            if spin { "spinning" } else { "sleeping" }
        );
        let idle = if spin { Idle::DEFAULT_SPIN } else { Idle::Sleep };
        let exec = Executor::new(threads, idle);
        let mut sim = Simulation::with_executor(
            &scene.config,
            &scene.geometry,
            &path.display().to_string(),
            &exec,
        )?;
        rows.push(measure(args.seconds, period, Some((&mut sim, threads, spin)))?);
    }
    println!(
        "coexist: {} ({}), a probe thread waking every {} µs beside the stepping physics, {} s per row, {} cores",
        args.scene,
        path.display(),
        args.period_us,
        args.seconds,
        std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
    );
    println!(
        "{:>15} {:>6} {:>10} {:>12} {:>12} {:>12} {:>8}",
        "physics_threads", "idle", "steps/s", "jitter p50", "jitter p99", "jitter max", "periods"
    );
    for r in &rows {
        let idle = match (r.physics_threads, r.spin) {
            (0, _) => "-",
            (_, true) => "spin",
            (_, false) => "sleep",
        };
        println!(
            "{:>15} {:>6} {:>10.1} {:>9.1} µs {:>9.1} µs {:>9.1} µs {:>8}",
            if r.physics_threads == 0 { "none".into() } else { r.physics_threads.to_string() },
            idle,
            r.steps_per_s,
            r.jitter_us_p50,
            r.jitter_us_p99,
            r.jitter_us_max,
            r.periods
        );
    }
    println!(
        "jitter: |period − {} µs| between consecutive wake-ups of the probe (absolute deadlines, \
         sleeping in between); spin: idle physics workers spin for 0.5 ms after a job, sleep: \
         they sleep at once",
        args.period_us
    );
    if args.json {
        println!("{}", serde_json::json!({ "scene": args.scene, "rows": rows }));
    }
    Ok(())
}
