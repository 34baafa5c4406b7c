//! `incise-bench ldi`: one volume-contact pass (three layered depth images over a box and the
//! overlap intervals of their rays) on the CPU and on a GPU, at several resolutions, on a
//! scene's surface, settled 200 steps under gravity: the pair of tissues of its `[volume_contact] pairs` over their boxes'
//! overlap, and its first tissue against itself over its whole box (the worst case of the self
//! test, which a scene runs only around its cuts).

use crate::timing::quantile;
use anyhow::{Context, bail};
use incise_gpu::{GpuChoice, GpuContact};
use incise_math::Vec3;
use incise_sim::Simulation;
use incise_tool::volume_contact::{
    ContactDevice, OverlapInterval, TriangleSurface, overlap_intervals, self_overlap_intervals,
};
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `incise-bench ldi`.
#[derive(clap::Args, Debug)]
pub struct LdiArgs {
    /// A scene name in `--scene-dir` or a scene file with `[volume_contact] pairs`.
    #[arg(long, default_value = "liver_kidney")]
    scene: String,
    /// Folder of the named scenes.
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Pixels per side of each view.
    #[arg(long, value_delimiter = ',', default_value = "32,64,128,256,512")]
    resolutions: Vec<usize>,
    /// Timed repetitions per pass (the median is reported).
    #[arg(long, default_value_t = 9)]
    repeat: usize,
    /// Which adapter: `on` (any, a software one included) or `auto` (hardware only).
    #[arg(long, default_value = "on", value_name = "on|auto")]
    gpu: String,
    /// End with one line holding one JSON object.
    #[arg(long)]
    json: bool,
}

/// One pass at one resolution.
#[derive(Clone, Debug, Serialize)]
struct Row {
    pass: &'static str,
    resolution: usize,
    triangles: usize,
    intervals: usize,
    cpu_ms: f64,
    /// The device's pass, the node positions sent and the surface deformed on it included.
    gpu_ms: Option<f64>,
    /// `cpu_ms / gpu_ms`, measured in this run.
    speedup: Option<f64>,
    /// The overlap volumes' difference, relative to the CPU's.
    gpu_cpu_volume_diff: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
struct Report {
    scene: String,
    gpu: String,
    cpu_threads: usize,
    rows: Vec<Row>,
}

/// A pass: its name, the other surface group (`None`: the first against itself), the box looked
/// at, and the triangles rasterised.
type Pass = (&'static str, Option<u16>, (Vec3, Vec3), usize);

fn volume(intervals: &[OverlapInterval]) -> f64 {
    intervals.iter().map(|i| i.area * (i.depths[1] - i.depths[0])).sum()
}

fn median_ms(times: &mut [f64]) -> f64 {
    times.sort_by(f64::total_cmp);
    quantile(times, 0.5)
}

/// Runs the report.
pub fn run(args: &LdiArgs) -> anyhow::Result<()> {
    let path = crate::coexist::scene_path(&args.scene, &args.scene_dir);
    let scene = incise_scene::read_scene(&path)
        .map_err(|e| anyhow::anyhow!("--scene {}: {e}", args.scene))?;
    let Some(contact) = &scene.config.volume_contact else {
        bail!("--scene {}: the scene has no [volume_contact]", args.scene);
    };
    let Some(&[la, lb]) = contact.pairs.first() else {
        bail!("--scene {}: the scene's [volume_contact] names no pairs", args.scene);
    };
    let mut sim = Simulation::new(&scene.config, &scene.geometry, &args.scene)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // Settled under gravity, as the frame report meets it: the tissues pressed into each other
    // (at rest their surfaces only touch, and the overlap is nothing to compare).
    for _ in 0..200 {
        sim.step(&incise_sim::StepInputs::default()).map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let surface = sim.surface().context("the scene has no surface")?;
    let positions = sim.surface_positions().context("the scene has no surface")?;
    let grid = sim.grid().context("a pair of tissues needs a label volume")?;
    let group_of = |label: u16| {
        grid.materials().position(|(l, _)| l == label).map(|m| m as u16).context("a paired label")
    };
    let (ga, gb) = (group_of(la)?, group_of(lb)?);
    let groups = surface.triangles_by_group();
    let side =
        |g: u16| TriangleSurface { positions: &positions, triangles: &groups[usize::from(g)] };
    let (a, b) = (side(ga), side(gb));
    let ((alo, ahi), (blo, bhi)) =
        (a.bounds().context("an empty tissue")?, b.bounds().context("an empty tissue")?);
    let pair_box: (Vec3, Vec3) =
        (std::array::from_fn(|k| alo[k].max(blo[k])), std::array::from_fn(|k| ahi[k].min(bhi[k])));
    let choice = if args.gpu == "auto" { GpuChoice::Auto } else { GpuChoice::On };
    let mut device = match GpuContact::new(choice) {
        Ok(d) => Some(d),
        Err(e) => {
            eprintln!("ldi: {e}; timing the CPU alone");
            None
        }
    };
    let gpu_name = device.as_ref().map_or_else(|| "none".to_owned(), ContactDevice::name);
    eprintln!("ldi: {} on {gpu_name}", args.scene);
    let x = &sim.state().x;
    if let Some(d) = device.as_mut() {
        let (embeddings, nodes) = surface.stable_embeddings();
        d.set_embeddings(&embeddings, nodes);
        d.set_triangles(&surface.group_slots());
    }
    let stable = surface.stable_nodes(x, sim.model());
    let mut rows = Vec::new();
    let passes: [Pass; 2] = [
        ("pair", Some(gb), pair_box, a.triangles.len() + b.triangles.len()),
        ("self", None, a.bounds().context("an empty tissue")?, a.triangles.len()),
    ];
    for &resolution in &args.resolutions {
        for &(pass, other, region, triangles) in &passes {
            let cpu_pass = || match other {
                Some(_) => overlap_intervals(&a, &b, region, resolution),
                None => self_overlap_intervals(&a, region, resolution),
            };
            let reference = cpu_pass();
            let mut cpu = Vec::new();
            for _ in 0..args.repeat.max(1) {
                let t = Instant::now();
                std::hint::black_box(cpu_pass());
                cpu.push(t.elapsed().as_secs_f64() * 1e3);
            }
            let cpu_ms = median_ms(&mut cpu);
            let (mut gpu_ms, mut diff) = (None, None);
            if let Some(d) = device.as_mut() {
                let mut times = Vec::new();
                let mut last = None;
                for _ in 0..=args.repeat.max(1) {
                    let t = Instant::now();
                    d.deform(&stable);
                    last = d.overlap_intervals(ga, other, region, resolution);
                    times.push(t.elapsed().as_secs_f64() * 1e3);
                }
                // The first run builds the buffers for this size.
                times.remove(0);
                if let Some(found) = last {
                    gpu_ms = Some(median_ms(&mut times));
                    let (v, w) = (volume(&found), volume(&reference));
                    diff = Some(if w > 0.0 { (v - w).abs() / w } else { v.abs() });
                }
            }
            let row = Row {
                pass,
                resolution,
                triangles,
                intervals: reference.len(),
                cpu_ms,
                gpu_ms,
                speedup: gpu_ms.map(|g| cpu_ms / g),
                gpu_cpu_volume_diff: diff,
            };
            eprintln!(
                "{:<5} {:>5}² {:>7} triangles {:>8} intervals: CPU {:>9.3} ms, GPU {}",
                row.pass,
                row.resolution,
                row.triangles,
                row.intervals,
                row.cpu_ms,
                row.gpu_ms.map_or("-".into(), |g| format!(
                    "{g:.3} ms ({:.2}×, volume differs by {:.1e})",
                    row.speedup.unwrap_or(0.0),
                    row.gpu_cpu_volume_diff.unwrap_or(0.0)
                ))
            );
            rows.push(row);
        }
    }
    let report = Report { scene: args.scene.clone(), gpu: gpu_name, cpu_threads: 1, rows };
    print_table(&report);
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    }
    Ok(())
}

fn print_table(r: &Report) {
    println!("\nvolume-contact passes on {} (CPU: 1 thread; GPU: {})", r.scene, r.gpu);
    println!(
        "{:<5} {:>10} {:>10} {:>10} {:>10} {:>10} {:>9} {:>12}",
        "pass", "pixels", "triangles", "intervals", "CPU ms", "GPU ms", "CPU/GPU", "volume diff"
    );
    for row in &r.rows {
        println!(
            "{:<5} {:>10} {:>10} {:>10} {:>10.3} {:>10} {:>9} {:>12}",
            row.pass,
            format!("{0}²", row.resolution),
            row.triangles,
            row.intervals,
            row.cpu_ms,
            row.gpu_ms.map_or("-".into(), |g| format!("{g:.3}")),
            row.speedup.map_or("-".into(), |s| format!("{s:.2}")),
            row.gpu_cpu_volume_diff.map_or("-".into(), |d| format!("{d:.1e}"))
        );
    }
}
