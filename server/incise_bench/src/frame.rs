//! `incise-bench frame`: the full surgical frame on an organ, stage by stage (Jeřábková 2010
//! §4.1 measured where its frame time went: solve 60 %, collision 15 %, grid update 10 %,
//! voxel search 2 %, re-mesh 2 %).
//!
//! A scripted scalpel comes down on the organ's top at its centre (where a hanging organ is
//! held, so the tissue does not slip away from the blade): it approaches, presses without
//! cutting, cuts a stroke (pushed in until its blade reaches the tissue, then drawn across),
//! retracts, and a second, long blade cuts a slab through the whole organ near one end, which
//! separates that end. Every frame is timed by stage (contact, cut search, grid and model
//! update, surface deformation, re-mesh, mechanics); the report prints each stage's median and
//! p99, the full-frame rate, and what the stroke cost in grid update, condensation and re-mesh.
//! Figures are measured, never asserted.

use crate::coexist::scene_path;
use crate::timing::quantile;
use anyhow::{Context, bail};
use incise_fem::{ElementKind, Executor, Formulation};
use incise_math::Vec3;
use incise_sim::config::{
    CouplingSpec, Cutting, DEFAULT_CUT_FORCE, Model, ShapeSpec, ToolContact, ToolSpec, VolumeSpec,
};
use incise_sim::{Frame, Simulation, StepInputs, ToolInput};
use incise_tool::{Primitive, Shape, ToolPose};
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `incise-bench frame`.
#[derive(clap::Args, Debug)]
pub struct FrameArgs {
    /// `liver` (the liver CT of `liver_13k.toml`, with `--stride` and `--levels`), a scene name
    /// in `--scene-dir`, or a scene file's path (hexahedral or tensor-mass).
    #[arg(long, default_value = "liver")]
    scene: String,
    /// Folder of the named scenes.
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Stride of a label-volume scene's image, `x,y,z` (8,8,4: 13,648 liver voxels; 4,4,2:
    /// 109,201).
    #[arg(long, value_delimiter = ',', value_name = "X,Y,Z")]
    stride: Option<Vec<usize>>,
    /// The grid level the hexahedra run on.
    #[arg(long)]
    levels: Option<u32>,
    /// How the hexahedra's coarse elements get their stiffness, overriding the scene's
    /// `model.element`: `condensed` (eq. 1–4), `incompatible` (nine bubble modes per element,
    /// re-made for the elements a cut touches) or `composite` (re-made, at every grid level,
    /// for the cells next to what a cut changed).
    #[arg(long, value_name = "KIND", value_parser = ["condensed", "incompatible", "composite"])]
    elements: Option<String>,
    /// Threads of the physics (1: what runs beside the haptic thread on 2 cores).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// End with one line holding one JSON object.
    #[arg(long)]
    json: bool,
    /// Also run the script again on a fresh build, recording every frame into DIR as
    /// `incise-server --record` does (an MCAP file), and report the full-frame rate with and
    /// without recording and their ratio, measured in this one run.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// Where the scene's volume contact runs, overriding its `gpu` key: `on` (any adapter, a
    /// software one included), `auto` (a hardware adapter if there is one) or `off` (the CPU).
    /// On a GPU the script is played a second time with every device pass also run on the CPU,
    /// for `gpu_cpu_max_diff`.
    #[arg(long, value_name = "on|auto|off")]
    gpu: Option<GpuArg>,
}

/// `--gpu`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum GpuArg {
    On,
    Auto,
    Off,
}

/// A stage's times over the frames (ms).
#[derive(Clone, Debug, Serialize)]
struct Stage {
    name: &'static str,
    median_ms: f64,
    p99_ms: f64,
    total_ms: f64,
}

/// The report.
#[derive(Clone, Debug, Serialize)]
struct Report {
    scene: String,
    model: String,
    physics_threads: usize,
    voxels: Option<usize>,
    elements: usize,
    frames: usize,
    frame_hz_median: f64,
    frame_ms_median: f64,
    frame_ms_p99: f64,
    stages: Vec<Stage>,
    /// Grid update + condensation + re-mesh over the cut stroke (ms).
    cut_stroke_ms: f64,
    /// The stroke's cut search (ms), not in `cut_stroke_ms`.
    cut_stroke_search_ms: f64,
    /// The stroke's voxels removed in one edit of the settled organ instead of frame by frame:
    /// grid update, condensation, model and state, re-mesh and re-embedding (ms, median of 5).
    cut_stroke_batch_ms: Option<f64>,
    cut_stroke_voxels: usize,
    cut_stroke_frames: usize,
    voxels_removed: usize,
    tets_removed: usize,
    triangles: usize,
    tool_force_max_n: f64,
    /// Cutting had not started when the press phase ended.
    pressed_without_cutting: bool,
    /// Frames whose state was not finite (0 expected).
    non_finite_frames: usize,
    /// Every frame's state hash and surface change folded into one: equal for two builds that
    /// ran the script bit for bit alike (an A/B comparison's check that only the time moved).
    fingerprint: String,
    /// The adapter volume contact ran on, or "none" (the CPU).
    gpu: String,
    /// On a GPU: the largest difference between a device pass's overlap volume and the CPU's,
    /// relative to the larger, over a second playing of the script.
    gpu_cpu_max_diff: Option<f64>,
    /// On a GPU: voxels near a cutting shape that the device and the CPU disagreed on (held or
    /// not), over the same second playing.
    gpu_cpu_cut_mismatches: Option<usize>,
    /// Scenes with `[volume_contact]`: frames in which something overlapped, the most
    /// connected overlaps in one frame, and the largest total overlap volume (m³).
    volume_contact_frames: usize,
    overlap_regions_max: usize,
    overlap_volume_max_m3: f64,
    /// With `--record`: frames per second of wall time over the script without recording...
    record_frame_hz_off: Option<f64>,
    /// ...and with it (the recorder thread writing the MCAP and `.rrd` files, the surface at the
    /// server's default geometry rate)...
    record_frame_hz_on: Option<f64>,
    /// ...and on / off.
    record_ratio: Option<f64>,
    /// The recording's size (bytes) and whether its frames were bit-identical to the run
    /// without recording.
    record_bytes: Option<u64>,
    /// The `.rrd` twin's size (bytes).
    record_rrd_bytes: Option<u64>,
    /// The files' sizes per minute of session (MB per minute of simulated time, which a server
    /// keeps up with wall time): MCAP, `.rrd`.
    record_mb_per_min: Option<f64>,
    record_rrd_mb_per_min: Option<f64>,
    record_bit_identical: Option<bool>,
}

/// The script's phases.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Approach,
    Press,
    Stroke,
    Retract,
    Separate,
}

/// One frame's pose for each of the two tools (`None`: not in play).
struct Script {
    frames: Vec<(Phase, Option<Vec3>, Option<Vec3>)>,
}

/// The tools come from above, unrotated: edge down, shaft (+z) up.
const DOWN: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

/// A sharp scalpel: its blade sits just inside a narrow outer shape, so it cuts once pressed
/// a little into the tissue.
fn scalpel(unit: f64) -> ToolSpec {
    let outer = Primitive::Cuboid { half_extents: [2.5 * unit, 0.8 * unit, 3.0 * unit] };
    ToolSpec {
        name: "scalpel".into(),
        outer: ShapeSpec::Shape(Shape::new(outer, [0.0, 0.0, 3.0 * unit]).expect("positive")),
        inner: Some(ShapeSpec::Shape(
            Shape::new(
                Primitive::Blade { length: 5.0 * unit, height: 5.5 * unit, thickness: 1.4 * unit },
                [0.0, 0.0, 0.05 * unit],
            )
            .expect("positive"),
        )),
        contact: ToolContact::Points,
        coupling: CouplingSpec::default(),
        stiffness: 5.0,
        damping: None,
        cutting: Cutting::Remove,
        cut_force: DEFAULT_CUT_FORCE,
        jaws: None,
        path: None,
    }
}

/// A blade as long as the organ is wide, cutting where it touches (inner = outer).
fn transector(unit: f64, width: f64) -> ToolSpec {
    let blade = Primitive::Blade { length: width, height: 3.0 * unit, thickness: 1.4 * unit };
    let shape = ShapeSpec::Shape(Shape::new(blade, [0.0; 3]).expect("positive"));
    ToolSpec {
        name: "transector".into(),
        outer: shape.clone(),
        inner: Some(shape),
        contact: ToolContact::Points,
        coupling: CouplingSpec::default(),
        stiffness: 300.0,
        damping: None,
        cutting: Cutting::Remove,
        cut_force: DEFAULT_CUT_FORCE,
        jaws: None,
        path: None,
    }
}

/// The organ's surface: bounds, where the scalpel goes in (the top of the thickest column of
/// tissue, and which way along y the tissue runs on), and a length unit (the mean surface
/// edge, about a voxel).
struct Organ {
    lo: Vec3,
    hi: Vec3,
    entry: [f64; 2],
    top: f64,
    along_y: f64,
    unit: f64,
}

fn organ(sim: &Simulation) -> anyhow::Result<Organ> {
    let positions = sim.surface_positions().context("the scene has no surface")?;
    let surface = sim.surface().context("the scene has no surface")?;
    let live = surface.live_vertices();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &v in live {
        let p = positions[v as usize];
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let triangles = surface.triangle_list();
    let edge = |a: u32, b: u32| {
        let (p, q) = (positions[a as usize], positions[b as usize]);
        (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt()
    };
    let total: f64 = triangles.iter().map(|t| edge(t[0], t[1])).sum();
    let unit = 1.2 * total / triangles.len().max(1) as f64;
    let (mut entry, mut along_y) = ([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])], 1.0);
    if let Some(grid) = sim.grid() {
        // The column holding the most voxels, the nearest to the middle among equals, and the
        // side of it along y where its row holds more voxels.
        let (fine, h) = (grid.fine(), grid.spacing());
        let d = fine.dims();
        let count = |x: u32, y: u32| {
            (0..d[2]).filter(|&z| fine.material(x + d[0] * (y + d[1] * z)).is_some()).count()
        };
        let mut best = (0, u32::MAX, 0, 0);
        for y in 0..d[1] {
            for x in 0..d[0] {
                let off = x.abs_diff(d[0] / 2) + y.abs_diff(d[1] / 2);
                let n = count(x, y);
                if n > best.0 || (n == best.0 && off < best.1) {
                    best = (n, off, x, y);
                }
            }
        }
        let (x, y) = (best.2, best.3);
        let ahead: usize = (y..d[1]).map(|j| count(x, j)).sum();
        let behind: usize = (0..y).map(|j| count(x, j)).sum();
        along_y = if ahead >= behind { 1.0 } else { -1.0 };
        entry = [(f64::from(x) + 0.5) * h[0], (f64::from(y) + 0.5) * h[1]];
    }
    let top = live
        .iter()
        .map(|&v| positions[v as usize])
        .filter(|p| (p[0] - entry[0]).abs() < 0.6 * unit && (p[1] - entry[1]).abs() < 0.6 * unit)
        .map(|p| p[2])
        .fold(f64::NEG_INFINITY, f64::max);
    if !top.is_finite() {
        bail!("no surface above the organ's thickest part");
    }
    Ok(Organ { lo, hi, entry, top, along_y, unit })
}

fn script(o: &Organ) -> Script {
    let [cx, cy] = o.entry;
    let u = o.unit;
    let mut frames = Vec::new();
    let ramp = |from: f64, to: f64, n: usize| {
        (0..n).map(move |i| from + (to - from) * (i + 1) as f64 / n as f64)
    };
    for z in ramp(3.0 * u, 0.2 * u, 100) {
        frames.push((Phase::Approach, Some([cx, cy, o.top + z]), None));
    }
    // Pressed 0.1 unit into the surface: the blade, 0.05 unit inside the outer shape, stays
    // clear of the voxel centres half a voxel below.
    for z in ramp(0.2 * u, -0.1 * u, 100) {
        frames.push((Phase::Press, Some([cx, cy, o.top + z]), None));
    }
    // In until the blade is 5 units deep, then drawn 9 units across along y.
    for z in ramp(-0.1 * u, -5.0 * u, 150) {
        frames.push((Phase::Stroke, Some([cx, cy, o.top + z]), None));
    }
    let end = cy + o.along_y * 9.0 * u;
    for y in ramp(cy, end, 300) {
        frames.push((Phase::Stroke, Some([cx, y, o.top - 5.0 * u]), None));
    }
    for z in ramp(-5.0 * u, 4.0 * u, 100) {
        frames.push((Phase::Retract, Some([cx, end, o.top + z]), None));
    }
    // The transector comes down through the whole organ near its +x end.
    let x = o.hi[0] - 0.2 * (o.hi[0] - o.lo[0]);
    let mid = 0.5 * (o.lo[1] + o.hi[1]);
    for z in ramp(o.hi[2] + 2.0 * u, o.lo[2] - 2.0 * u, 300) {
        frames.push((Phase::Separate, None, Some([x, mid, z])));
    }
    Script { frames }
}

/// Runs the report.
pub fn run(args: &FrameArgs) -> anyhow::Result<()> {
    let named = if args.scene == "liver" { "liver_13k" } else { args.scene.as_str() };
    let path = scene_path(named, &args.scene_dir);
    let mut scene = incise_scene::read_scene(&path)
        .map_err(|e| anyhow::anyhow!("--scene {}: {e}", args.scene))?;
    for note in &scene.notes {
        eprintln!("note: {note}");
    }
    if let Some(stride) = &args.stride {
        let &[x, y, z] = stride.as_slice() else {
            bail!("--stride takes three counts, x,y,z (e.g. 8,8,4)");
        };
        anyhow::ensure!(x > 0 && y > 0 && z > 0, "--stride: counts must be positive");
        match scene.config.volume_mut() {
            Some(VolumeSpec::File { stride: s, .. }) => *s = [x, y, z],
            _ => bail!("--stride: the scene is not built on a volume file"),
        }
    }
    if let Some(level) = args.levels {
        match &mut scene.config.model {
            Model::Hexahedra(hex) => hex.level = incise_sim::config::Level::Fixed(level),
            Model::TensorMass(_) => bail!("--levels: a tensor-mass scene has no grid levels"),
        }
    }
    if let Some(kind) = &args.elements {
        match &mut scene.config.model {
            Model::Hexahedra(hex) => {
                hex.element = ElementKind::from_name(kind).expect("clap checked the name");
            }
            Model::TensorMass(_) => bail!("--elements: a tensor-mass scene has no grid elements"),
        }
    }
    if let Some(gpu) = args.gpu {
        scene.config.gpu = match gpu {
            GpuArg::On => incise_sim::config::GpuSetting::On,
            GpuArg::Auto => incise_sim::config::GpuSetting::Auto,
            GpuArg::Off => incise_sim::config::GpuSetting::Off,
        };
    }
    let exec = Executor::new(args.threads.max(1), incise_fem::Idle::Sleep);
    // A first build finds the organ's size, which sizes the tools.
    let mut probe = Simulation::with_executor(&scene.config, &scene.geometry, &args.scene, &exec)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    probe.enable_surface();
    let o = organ(&probe)?;
    drop(probe);
    scene.config.tools = vec![scalpel(o.unit), transector(o.unit, 1.2 * (o.hi[1] - o.lo[1]))];
    let mut sim = Simulation::with_executor(&scene.config, &scene.geometry, &args.scene, &exec)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    if let Some(gpu) = incise_scene::attach_gpu(&mut sim) {
        eprintln!("frame: {gpu}");
    }
    let voxels = sim.grid().map(|g| g.fine().voxel_count());
    let elements = match (sim.model(), sim.tet()) {
        (Some(m), _) => m.elements.len(),
        (None, Some(t)) => t.topology.live_count(),
        _ => 0,
    };
    let model = match (&scene.config.model, sim.model()) {
        (Model::Hexahedra(spec), Some(m)) => format!(
            "{} hexahedra, {} elements",
            match spec.formulation {
                Formulation::Linear => "linear",
                Formulation::Corotational => "corotational",
            },
            m.element.name()
        ),
        _ => "tensor-mass".to_owned(),
    };
    eprintln!(
        "frame: {} ({model}, {} voxels, {elements} elements), unit {:.2} mm, {} physics thread(s)",
        args.scene,
        voxels.map_or("no".into(), |v| v.to_string()),
        o.unit * 1e3,
        args.threads.max(1)
    );
    // Let the organ settle under gravity first, so the script meets it at rest.
    for _ in 0..200 {
        sim.step(&StepInputs::default()).map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let o = Organ { unit: o.unit, ..organ(&sim)? };
    let script = script(&o);
    let (frames, wall_off) = play(&mut sim, &script, &o, None)?;
    let mut report = summarise(args, &sim, &model, voxels, elements, &frames);
    let stroke: Vec<u32> = frames
        .iter()
        .filter(|(p, _)| *p == Phase::Stroke)
        .flat_map(|(_, f)| f.surgical.edit.remove_voxels.iter().copied())
        .collect();
    if !stroke.is_empty() && sim.grid().is_some() {
        report.cut_stroke_batch_ms = Some(batch_cut(&scene, &args.scene, &exec, &stroke)?);
    }
    if sim.gpu().is_some() {
        let mut checked =
            Simulation::with_executor(&scene.config, &scene.geometry, &args.scene, &exec)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        incise_scene::attach_gpu(&mut checked);
        for _ in 0..200 {
            checked.step(&StepInputs::default()).map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        checked.check_gpu(true);
        let (frames, _) = play(&mut checked, &script, &o, None)?;
        report.gpu_cpu_max_diff =
            Some(frames.iter().map(|(_, f)| f.counters.gpu_cpu_volume_diff).fold(0.0, f64::max));
        report.gpu_cpu_cut_mismatches =
            Some(frames.iter().map(|(_, f)| f.counters.gpu_cpu_cut_mismatches).sum());
    }
    if let Some(dir) = &args.record {
        let mut again =
            Simulation::with_executor(&scene.config, &scene.geometry, &args.scene, &exec)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        for _ in 0..200 {
            again.step(&StepInputs::default()).map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        std::fs::create_dir_all(dir).with_context(|| format!("--record {}", dir.display()))?;
        let file = dir.join(format!("frame-{}.mcap", args.scene.replace(['/', '.'], "_")));
        let tools = incise_convert::tools::tool_looks(&scene.config);
        let session = incise_record::Session {
            scene: args.scene.clone(),
            scene_toml: std::fs::read_to_string(&path).unwrap_or_default(),
            version: env!("CARGO_PKG_VERSION").into(),
            git_revision: String::new(),
            tools: tools.clone(),
            scene_interval_s: 0.5,
            files: incise_server::scene::stored_files(
                &scene.config,
                path.parent().unwrap_or(std::path::Path::new(".")),
            ),
        };
        // What the server records: the MCAP file and its `.rrd` twin.
        let recorder = incise_record::Recorder::with_sinks(incise_record::Sinks {
            mcap: Some(incise_record::McapRecording::create(&file, &session)?),
            rrd: Some(
                incise_record::RerunLog::save_session(&file.with_extension("rrd"), &tools)
                    .map_err(anyhow::Error::msg)?,
            ),
            live: None,
            // No haptic loop runs here.
            forces: None,
        })?;
        let (recorded, wall_on) = play(&mut again, &script, &o, Some(&recorder.handle()))?;
        let waits = recorder.stats().waits.load(std::sync::atomic::Ordering::Relaxed);
        recorder.finish()?;
        let hz = |n: usize, wall: std::time::Duration| n as f64 / wall.as_secs_f64();
        let (off, on) = (hz(frames.len(), wall_off), hz(recorded.len(), wall_on));
        report.record_frame_hz_off = Some(off);
        report.record_frame_hz_on = Some(on);
        report.record_ratio = Some(on / off);
        report.record_bytes = Some(std::fs::metadata(&file)?.len());
        report.record_rrd_bytes = Some(std::fs::metadata(file.with_extension("rrd"))?.len());
        let sim_s = recorded.len() as f64 * scene.config.dt();
        let per_min = |bytes: Option<u64>| bytes.map(|b| b as f64 / 1e6 / sim_s * 60.0);
        report.record_mb_per_min = per_min(report.record_bytes);
        report.record_rrd_mb_per_min = per_min(report.record_rrd_bytes);
        report.record_bit_identical = Some(
            frames.len() == recorded.len()
                && frames.iter().zip(&recorded).all(|(a, b)| a.1.state_hash == b.1.state_hash),
        );
        eprintln!(
            "recorded into {} (the physics waited for the recorder {waits} times)",
            file.display()
        );
    }
    print_report(&report);
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    }
    Ok(())
}

/// Steps `script` on `sim` (tools posed as the script says), handing every frame's record and
/// the surface at the default geometry rate to `recorder` when given, as the server's physics
/// thread does; the frames and the loop's wall time.
fn play(
    sim: &mut Simulation,
    script: &Script,
    o: &Organ,
    recorder: Option<&incise_record::RecordHandle>,
) -> anyhow::Result<(Vec<(Phase, Frame)>, std::time::Duration)> {
    let started = std::time::Instant::now();
    let mut frames: Vec<(Phase, Frame)> = Vec::with_capacity(script.frames.len());
    let mut clock =
        incise_server::physics::GeometryClock::new(incise_server::physics::DEFAULT_GEOMETRY_HZ);
    for (phase, scalpel, transector) in &script.frames {
        let mut tools = Vec::new();
        if let Some(p) = scalpel {
            tools.push(ToolInput { tool: 0, pose: ToolPose::new(*p, DOWN, 0.0)? });
        }
        if let Some(p) = transector {
            tools.push(ToolInput { tool: 1, pose: ToolPose::new(*p, DOWN, 0.0)? });
        }
        if scalpel.is_none()
            && transector.is_some()
            && frames.last().is_some_and(|f| f.0 == Phase::Retract)
        {
            // Park the scalpel out of the way.
            let away = [o.lo[0] - 10.0 * o.unit, o.lo[1], o.hi[2] + 10.0 * o.unit];
            tools.push(ToolInput { tool: 0, pose: ToolPose::new(away, DOWN, 0.0)? });
        }
        // The poses as the server would have received them, only when recording: the run
        // without recording must not pay for it.
        let raw: Option<Vec<incise_protocol::raw::RawToolPose>> = recorder.map(|_| {
            tools
                .iter()
                .map(|t| incise_protocol::raw::RawToolPose {
                    orientation: t.pose.pose().rotation(),
                    ..incise_protocol::raw::RawToolPose::at(t.tool as u32, t.pose.pose().position())
                })
                .collect()
        });
        let step_started = std::time::Instant::now();
        let frame = sim
            .step(&StepInputs { tools, ..StepInputs::default() })
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if let (Some(recorder), Some(raw)) = (recorder, raw) {
            use incise_convert::frame::{frame_record, frame_stats};
            use incise_server::physics::record_state;
            let stats = frame_stats(&frame, sim, step_started.elapsed(), 0.0);
            recorder.record(incise_record::Record::Frame(frame_record(&frame, &raw, stats)));
            record_state(recorder, sim, &frame);
            if let Some(surface) = clock.surface(sim, &frame) {
                recorder.record(incise_record::Record::Surface(surface));
            }
        }
        frames.push((*phase, frame));
    }
    Ok((frames, started.elapsed()))
}

/// The time (ms, median of 5) to remove `voxels` in one edit from the settled organ, surface
/// included.
fn batch_cut(
    scene: &incise_scene::Scene,
    name: &str,
    exec: &Executor,
    voxels: &[u32],
) -> anyhow::Result<f64> {
    let mut config = scene.config.clone();
    config.tools.clear();
    let edit = incise_grid::GridEdit { remove_voxels: voxels.to_vec(), sever_links: Vec::new() };
    let mut times = Vec::new();
    for _ in 0..5 {
        let mut sim = Simulation::with_executor(&config, &scene.geometry, name, exec)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        sim.enable_surface();
        for _ in 0..200 {
            sim.step(&StepInputs::default()).map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        let start = std::time::Instant::now();
        sim.cut(&edit)?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    Ok(quantile(&times, 0.5))
}

fn summarise(
    args: &FrameArgs,
    sim: &Simulation,
    model: &str,
    voxels: Option<usize>,
    elements: usize,
    frames: &[(Phase, Frame)],
) -> Report {
    let ms = |ns: u64| ns as f64 * 1e-6;
    let stage = |name: &'static str, f: &dyn Fn(&Frame) -> u64| {
        let mut t: Vec<f64> = frames.iter().map(|(_, fr)| ms(f(fr))).collect();
        let total = t.iter().sum();
        t.sort_by(f64::total_cmp);
        Stage { name, median_ms: quantile(&t, 0.5), p99_ms: quantile(&t, 0.99), total_ms: total }
    };
    let stages = vec![
        stage("contact", &|f| f.counters.contact_ns),
        stage("cut search", &|f| f.counters.cut_ns),
        stage("grid + model update", &|f| f.counters.grid_ns),
        stage("surface deform", &|f| f.counters.surface_ns),
        stage("re-mesh + re-embed", &|f| f.counters.remesh_ns),
        stage("volume contact", &|f| f.counters.volume_contact_ns),
        stage("mechanics", &|f| f.counters.mechanics_ns),
        stage("frame", &|f| f.counters.step_ns),
    ];
    let frame = stages.last().expect("the frame stage").clone();
    let stroke: Vec<&Frame> =
        frames.iter().filter(|(p, _)| *p == Phase::Stroke).map(|(_, f)| f).collect();
    let cut_stroke_ms = stroke.iter().map(|f| ms(f.counters.grid_ns + f.counters.remesh_ns)).sum();
    let cut_stroke_search_ms = stroke.iter().map(|f| ms(f.counters.cut_ns)).sum();
    let cut_stroke_voxels =
        stroke.iter().map(|f| f.counters.voxels_removed + f.counters.tets_removed).sum();
    let cut_stroke_frames = stroke.iter().filter(|f| !f.surgical.cuts.is_empty()).count();
    let pressed_without_cutting = frames
        .iter()
        .filter(|(p, _)| matches!(p, Phase::Approach | Phase::Press))
        .all(|(_, f)| f.surgical.cuts.is_empty());
    let tool_force_max_n = frames
        .iter()
        .flat_map(|(_, f)| {
            f.surgical.tools.iter().map(|t| t.force().iter().map(|c| c * c).sum::<f64>().sqrt())
        })
        .fold(0.0, f64::max);
    Report {
        scene: args.scene.clone(),
        model: model.to_owned(),
        physics_threads: args.threads.max(1),
        voxels,
        elements,
        frames: frames.len(),
        frame_hz_median: 1e3 / frame.median_ms,
        frame_ms_median: frame.median_ms,
        frame_ms_p99: frame.p99_ms,
        stages,
        cut_stroke_ms,
        cut_stroke_search_ms,
        cut_stroke_batch_ms: None,
        cut_stroke_voxels,
        cut_stroke_frames,
        voxels_removed: frames.iter().map(|(_, f)| f.counters.voxels_removed).sum(),
        tets_removed: frames.iter().map(|(_, f)| f.counters.tets_removed).sum(),
        triangles: sim.surface().map_or(0, incise_sim::OrganSurface::triangle_count),
        tool_force_max_n,
        pressed_without_cutting,
        non_finite_frames: frames
            .iter()
            .filter(|(_, f)| !f.positions.iter().flatten().all(|c| c.is_finite()))
            .count(),
        fingerprint: format!("{:016x}", fingerprint(frames.iter().map(|(_, f)| f))),
        gpu: sim.gpu().unwrap_or_else(|| "none".to_owned()),
        gpu_cpu_max_diff: None,
        gpu_cpu_cut_mismatches: None,
        volume_contact_frames: frames
            .iter()
            .filter(|(_, f)| f.counters.overlap_regions > 0)
            .count(),
        overlap_regions_max: frames
            .iter()
            .map(|(_, f)| f.counters.overlap_regions)
            .max()
            .unwrap_or(0),
        overlap_volume_max_m3: frames
            .iter()
            .map(|(_, f)| f.counters.overlap_volume)
            .fold(0.0, f64::max),
        record_frame_hz_off: None,
        record_frame_hz_on: None,
        record_ratio: None,
        record_bytes: None,
        record_rrd_bytes: None,
        record_mb_per_min: None,
        record_rrd_mb_per_min: None,
        record_bit_identical: None,
    }
}

/// FNV-1a over each frame's state hash, voxels removed and surface triangles added and removed.
fn fingerprint<'a>(frames: impl Iterator<Item = &'a Frame>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for f in frames {
        let surface = &f.surgical.surface;
        let words = [f.state_hash, f.counters.voxels_removed as u64].into_iter().chain(
            surface.triangles_added.iter().chain(&surface.triangles_removed).map(|&t| u64::from(t)),
        );
        for w in words {
            for b in w.to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
    h
}

fn print_report(r: &Report) {
    println!(
        "\nfull frame on {} ({}, {} voxels, {} elements, {} physics thread(s)), {} frames",
        r.scene,
        r.model,
        r.voxels.map_or("no".into(), |v| v.to_string()),
        r.elements,
        r.physics_threads,
        r.frames
    );
    println!("{:<22} {:>10} {:>10} {:>11}", "stage", "median ms", "p99 ms", "total ms");
    for s in &r.stages {
        println!("{:<22} {:>10.4} {:>10.4} {:>11.2}", s.name, s.median_ms, s.p99_ms, s.total_ms);
    }
    println!(
        "full frame: {:.0} Hz at the median ({:.3} ms), p99 {:.3} ms",
        r.frame_hz_median, r.frame_ms_median, r.frame_ms_p99
    );
    println!(
        "cut stroke: {} cells over {} frames; grid + condensation + re-mesh {:.3} ms over those frames (search {:.3} ms); in one edit {}",
        r.cut_stroke_voxels,
        r.cut_stroke_frames,
        r.cut_stroke_ms,
        r.cut_stroke_search_ms,
        r.cut_stroke_batch_ms.map_or("-".into(), |t| format!("{t:.3} ms"))
    );
    println!(
        "removed {} voxels, {} tetrahedra; surface {} triangles; tool force up to {:.3} N; pressed without cutting: {}; non-finite frames: {}; fingerprint {}",
        r.voxels_removed,
        r.tets_removed,
        r.triangles,
        r.tool_force_max_n,
        r.pressed_without_cutting,
        r.non_finite_frames,
        r.fingerprint
    );
    if r.gpu != "none" {
        println!(
            "volume contact and cut marking on the GPU: {}; largest GPU/CPU overlap volume \
             difference {}; cut voxels marked differently {}",
            r.gpu,
            r.gpu_cpu_max_diff.map_or("-".into(), |d| format!("{d:.2e}")),
            r.gpu_cpu_cut_mismatches.map_or("-".into(), |d| d.to_string())
        );
    }
    if r.volume_contact_frames > 0 {
        println!(
            "volume contact: overlaps in {} frames, up to {} regions and {:.3} cm³ in one frame",
            r.volume_contact_frames,
            r.overlap_regions_max,
            r.overlap_volume_max_m3 * 1e6
        );
    }
    if let (Some(off), Some(on), Some(ratio)) =
        (r.record_frame_hz_off, r.record_frame_hz_on, r.record_ratio)
    {
        println!(
            "recording: {off:.0} frames/s without, {on:.0} with ({ratio:.3}×, one run); MCAP {} bytes ({:.1} MB per minute of session), .rrd {} bytes ({:.1} MB/min); frames bit-identical: {}",
            r.record_bytes.unwrap_or(0),
            r.record_mb_per_min.unwrap_or(0.0),
            r.record_rrd_bytes.unwrap_or(0),
            r.record_rrd_mb_per_min.unwrap_or(0.0),
            r.record_bit_identical.unwrap_or(false)
        );
    }
}
