//! `incise-bench tensor-mass`: paper 2's Table 1 (relative volume change of a cylinder bent by its
//! top centre vertex, and of the liver pulled by one lobe, for the linear, St Venant-Kirchhoff and
//! SVK + incompressibility tensor-mass models, plus our corotational hexahedra on the voxelised
//! cylinder), the explicit speed of each model, and adaptive non-linearity (paper 2 §6) against
//! full SVK on the liver.
//!
//! The paper gives the cylinder only in figures, so it is defined here: radius r = 1 cm, height
//! 3r, ν = 0.45 (E = 3 kPa, which does not change a displacement-driven static shape), bottom face
//! fixed, the top face's centre vertex moved sideways by 25 %, 50 % and 75 % of the height (left,
//! middle and right of Fig. 3/5), static equilibrium for each. The liver is the real CT
//! (`tests/data/liver.inr.gz`, strided 8,8,4: 13,648 voxels) tetrahedralised at grid level 1, held
//! by the vertices within 15 % of its length of the middle of its back (the −y face of its bounding
//! box), and its +x-most vertex (the tip of one lobe) moved by `--liver-pull` (default 50 %) of its
//! length along +y. The incompressibility strength is `--kappa-over-lambda` (default 1000) times
//! the largest Lamé λ of the mesh: paper 2 gives no value, and at 1000 λ the penalty's pressure
//! matches the bulk stiffness at a volume change of 0.1 %.

use crate::progress;
use anyhow::{Context, bail};
use incise_fem::FixedNodes;
use incise_fem::forcefield::tet::element::Elasticity;
use incise_fem::forcefield::tet::incompressible::Incompressibility;
use incise_fem::forcefield::tet::{Lame, TensorMassForceField, TetMaterial, TetModel};
use incise_fem::ode::central_difference::{CentralDifference, stable_dt};
use incise_fem::ode::relax::{Prescribed, RelaxSettings, Statics, relax};
use incise_fem::ode::static_solve;
use incise_fem::{Formulation, HexForceField, HexModel};
use incise_grid::{BranchedGrid, LabelFilter, LabelVolume, Material, MaterialTable};
use incise_math::Vec3;
use incise_mesh::generate::{KUHN, cylinder, cylinder_top_centre, from_volume};
use incise_mesh::signed_volume;
use incise_mesh::{TetMesh, TetTopology};
use serde::Serialize;
use std::time::Instant;

/// Arguments of `incise-bench tensor-mass`.
#[derive(clap::Args, Debug)]
pub struct TensorMassArgs {
    /// End the output with one line holding one JSON object: {"table1":[…],"speed":[…],"adaptive":{…}}.
    #[arg(long)]
    json: bool,
    /// Cylinder cells across its diameter (even) and along its height, for Table 1.
    #[arg(long, default_value = "4,12", value_name = "ACROSS,LAYERS")]
    cylinder: String,
    /// Incompressibility strength κ as a multiple of the Lamé λ (paper 2 §4 gives no value).
    #[arg(long, default_value_t = 1000.0)]
    kappa_over_lambda: f64,
    /// How far the liver's lobe tip is pulled, as a fraction of the liver's length.
    #[arg(long, default_value_t = 0.5)]
    liver_pull: f64,
    /// Seconds of stepping per speed measurement.
    #[arg(long, default_value_t = 1.0)]
    seconds: f64,
    /// Adaptive threshold as a fraction of the liver's length (paper 2 §6: 2 cm on 30 cm).
    #[arg(long, default_value_t = 0.07)]
    threshold: f64,
    /// Skip the liver (its Table 1 row, speed rows and the adaptive comparison): a quick run on
    /// the cylinder alone.
    #[arg(long)]
    cylinder_only: bool,
}

/// One Table 1 cell.
#[derive(Debug, Serialize)]
struct VolumeRow {
    case: String,
    model: String,
    volume_change_pct: f64,
    paper_pct: Option<f64>,
    converged: bool,
    elements: usize,
}

/// One speed measurement.
#[derive(Debug, Serialize)]
struct SpeedRow {
    mesh: String,
    tets: usize,
    model: String,
    steps_per_s: f64,
    dt_s: f64,
}

/// Adaptive non-linearity against full SVK, measured in the same run.
#[derive(Debug, Serialize)]
struct AdaptiveRow {
    mesh: String,
    tets: usize,
    vertices: usize,
    threshold_m: f64,
    steps: usize,
    svk_steps_per_s: f64,
    adaptive_steps_per_s: f64,
    speedup: f64,
    nonlinear_vertices: usize,
    displacement_error: f64,
}

const RADIUS: f64 = 0.01;
const YOUNG: f64 = 3_000.0;
const POISSON: f64 = 0.45;

/// Paper 2 Table 1 (%): (linear, non-linear, non-linear incompressible) per case.
const PAPER: [(&str, [f64; 3]); 4] = [
    ("cylinder-left", [7.0, 0.3, 0.2]),
    ("cylinder-middle", [28.0, 1.0, 0.5]),
    ("cylinder-right", [63.0, 2.0, 1.0]),
    ("liver", [9.0, 1.5, 0.7]),
];

const MODELS: [&str; 3] = ["linear", "svk", "svk-incompressible"];

fn paper(case: &str, model: usize) -> Option<f64> {
    PAPER.iter().find(|(c, _)| *c == case).map(|(_, v)| v[model])
}

fn parse_pair(s: &str) -> anyhow::Result<(usize, usize)> {
    let parts: Vec<usize> = s
        .split(',')
        .map(|p| p.trim().parse())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--cylinder {s}: expected ACROSS,LAYERS like 4,12"))?;
    match parts[..] {
        [a, l] if a > 0 && a % 2 == 0 && l > 0 => Ok((a, l)),
        _ => {
            bail!("--cylinder {s}: expected an even number across and a positive number of layers")
        }
    }
}

/// Total volume of the live tetrahedra at `x`.
fn tet_volume(model: &TetModel, x: &[Vec3]) -> f64 {
    (0..model.tets.len()).map(|t| model.current_volume(t, x)).sum()
}

/// A Table 1 case: the mesh, its model, held vertices and the prescribed move.
struct VolumeCase {
    name: String,
    mesh: TetMesh,
    model: TetModel,
    fixed: FixedNodes,
    prescribed: Prescribed,
}

fn cylinder_case(name: &str, across: usize, layers: usize, fraction: f64) -> VolumeCase {
    let height = 3.0 * RADIUS;
    let mesh = cylinder(RADIUS, height, across, layers);
    let lame = Lame::from_young_poisson(YOUNG, POISSON);
    let model = TetModel::new(&mesh, |_| TetMaterial::isotropic(lame, 1_000.0));
    let top = cylinder_top_centre(&mesh);
    let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-12).with(top);
    let target = {
        let r = model.rest[top];
        [r[0] + fraction * height, r[1], r[2]]
    };
    VolumeCase {
        name: name.into(),
        mesh,
        model,
        fixed,
        prescribed: Prescribed { targets: vec![(top, target)], ramp_steps: 20_000 },
    }
}

/// The liver volume used for the tetrahedral liver (13,648 voxels).
fn liver_volume() -> anyhow::Result<LabelVolume> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/liver.inr.gz");
    let raw = incise_io::read_volume(std::path::Path::new(path))?;
    Ok(raw.filtered(&LabelFilter::abdominal_ct()).crop_and_stride([8, 8, 4])?.largest_component())
}

fn liver_material(region: u32) -> TetMaterial {
    let table = MaterialTable::abdominal_ct();
    let m = u16::try_from(region)
        .ok()
        .and_then(|l| table.get(l).copied())
        .unwrap_or_else(Material::liver);
    TetMaterial::isotropic(Lame::from_young_poisson(m.youngs_modulus, m.poisson_ratio), m.density)
}

fn liver_case(volume: &LabelVolume, pull: f64) -> anyhow::Result<(VolumeCase, f64)> {
    let mesh = from_volume(volume, 1).context("tetrahedralising the liver")?;
    let model = TetModel::new(&mesh, liver_material);
    let lo =
        model.rest.iter().fold([f64::INFINITY; 3], |m, p| std::array::from_fn(|a| m[a].min(p[a])));
    let hi = model
        .rest
        .iter()
        .fold([f64::NEG_INFINITY; 3], |m, p| std::array::from_fn(|a| m[a].max(p[a])));
    let length = (0..3).map(|a| hi[a] - lo[a]).fold(0.0f64, f64::max);
    let back = [0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])];
    let dist = |p: &Vec3, q: &Vec3| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt();
    // The held patch: around the vertex closest to the middle of the back.
    let anchor = model
        .rest
        .iter()
        .min_by(|a, b| dist(a, &back).total_cmp(&dist(b, &back)))
        .copied()
        .unwrap_or(back);
    let tip = (0..model.rest.len())
        .max_by(|&a, &b| model.rest[a][0].total_cmp(&model.rest[b][0]))
        .context("the liver mesh has vertices")?;
    let target = {
        let r = model.rest[tip];
        [r[0], r[1] + pull * length, r[2]]
    };
    let fixed =
        FixedNodes::by_position(&model.rest, |p| dist(p, &anchor) <= 0.15 * length).with(tip);
    Ok((
        VolumeCase {
            name: "liver".into(),
            mesh,
            model,
            fixed,
            prescribed: Prescribed { targets: vec![(tip, target)], ramp_steps: 20_000 },
        },
        length,
    ))
}

/// Relative volume change (%) of `case` at equilibrium under `model_index` (see [`MODELS`]).
fn tet_volume_change(case: &VolumeCase, model_index: usize, kappa_over_lambda: f64) -> (f64, bool) {
    let topo = TetTopology::new(&case.mesh);
    let kind = if model_index == 0 { Elasticity::Linear } else { Elasticity::StVenantKirchhoff };
    let ff = TensorMassForceField::new(&case.model, &topo, kind);
    let lambda = case.model.lame.iter().map(|l| l.lambda).fold(0.0f64, f64::max);
    let penalty =
        (model_index == 2).then_some(Incompressibility { kappa: kappa_over_lambda * lambda });
    let dt = stable_dt(&case.model, &ff, &case.fixed);
    let mut x = case.model.rest.clone();
    let problem = Statics {
        model: &case.model,
        topology: &topo,
        force_field: &ff,
        penalty: penalty.as_ref(),
        fixed: &case.fixed,
        prescribed: &case.prescribed,
        external: &[],
    };
    let report =
        relax(&problem, 0.5 * dt, &mut x, RelaxSettings { tolerance: 1e-4, max_steps: 400_000 });
    let v0 = tet_volume(&case.model, &case.model.rest);
    (100.0 * (tet_volume(&case.model, &x) - v0).abs() / v0, report.converged)
}

/// The corotational hexahedral model on the voxelised cylinder (voxels of r / (across/2)), the
/// top centre node moved like the tetrahedral one in 20 load steps of Newton iterations.
fn hex_volume_change(across: usize, fraction: f64) -> anyhow::Result<(f64, bool, usize)> {
    let height = 3.0 * RADIUS;
    let h = 2.0 * RADIUS / across as f64;
    let layers = (height / h).round() as usize;
    let dims = [across, across, layers];
    let labels: Vec<u16> = (0..across * across * layers)
        .map(|i| {
            let (x, y) = (i % across, (i / across) % across);
            let c = |k: usize| (k as f64 + 0.5) * h - RADIUS;
            u16::from(c(x).hypot(c(y)) <= RADIUS)
        })
        .collect();
    let volume = LabelVolume::new(dims, [h; 3], labels)?;
    let grid = BranchedGrid::build(
        &volume,
        &MaterialTable::uniform(&[1], Material::new(YOUNG, POISSON, 1_000.0)),
        0,
    )?;
    let model = HexModel::from_grid(&grid);
    let centre = [RADIUS, RADIUS, height];
    let top = (0..model.node_count())
        .min_by(|&a, &b| {
            let d = |n: usize| (0..3).map(|k| (model.rest[n][k] - centre[k]).powi(2)).sum::<f64>();
            d(a).total_cmp(&d(b))
        })
        .context("the voxelised cylinder has nodes")?;
    let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-12).with(top);
    let mut ff = HexForceField::new(&model, Formulation::Corotational);
    let mut x = model.rest.clone();
    let loads = incise_fem::model::Loads::gravity([0.0; 3]);
    let steps = 20;
    for s in 1..=steps {
        x[top][0] = model.rest[top][0] + fraction * height * f64::from(s) / f64::from(steps);
        static_solve(&model, &mut ff, &fixed, &loads, &mut x, 1e-9, 12);
    }
    // Equilibrium check: the force on free nodes against the reaction at the held ones.
    ff.update_rotations(&model, &x);
    let mut f = vec![[0.0; 3]; model.node_count()];
    ff.add_forces(&model, &x, &mut f);
    let converged = fixed.residual_ratio(&f) <= 1e-4;
    let hex_volume = |x: &[Vec3]| -> f64 {
        model
            .elements
            .iter()
            .map(|e| {
                KUHN.iter()
                    .map(|t| signed_volume(&t.map(|c| x[e.nodes[c] as usize])))
                    .map(f64::abs)
                    .sum::<f64>()
            })
            .sum()
    };
    let v0 = hex_volume(&model.rest);
    Ok((100.0 * (hex_volume(&x) - v0).abs() / v0, converged, model.elements.len()))
}

/// Explicit steps per second of `model_name` on `mesh`, stepping for about `seconds`.
fn speed(
    mesh_name: &str,
    mesh: &TetMesh,
    model: &TetModel,
    model_name: &str,
    kappa: f64,
    seconds: f64,
) -> SpeedRow {
    let topo = TetTopology::new(mesh);
    let kind =
        if model_name == "linear" { Elasticity::Linear } else { Elasticity::StVenantKirchhoff };
    let ff = TensorMassForceField::new(model, &topo, kind);
    let penalty = (model_name == "svk-incompressible").then_some(Incompressibility { kappa });
    let top = model.rest.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    let fixed = FixedNodes::by_position(&model.rest, |p| p[2] >= top - 1e-9);
    let dt = stable_dt(model, &ff, &fixed);
    let mut x = model.rest.clone();
    let mut cd = CentralDifference::new(model, &ff, &fixed, &x, dt, 5.0).expect("the stable step");
    let gravity: Vec<Vec3> = model.lumped_mass.iter().map(|m| [0.0, 0.0, -9.81 * m]).collect();
    let start = Instant::now();
    let mut steps = 0usize;
    while start.elapsed().as_secs_f64() < seconds {
        for _ in 0..100 {
            cd.step(model, &topo, &ff, penalty.as_ref(), &fixed, &gravity, &mut x);
        }
        steps += 100;
    }
    SpeedRow {
        mesh: mesh_name.into(),
        tets: mesh.tets().len(),
        model: model_name.into(),
        steps_per_s: steps as f64 / start.elapsed().as_secs_f64(),
        dt_s: dt,
    }
}

/// Full SVK and adaptive SVK on the liver case's pull, the same steps, timed in one run.
fn adaptive(case: &VolumeCase, length: f64, threshold_fraction: f64) -> AdaptiveRow {
    let topo = TetTopology::new(&case.mesh);
    let full = TensorMassForceField::new(&case.model, &topo, Elasticity::StVenantKirchhoff);
    let mut adaptive = full.clone();
    let threshold = threshold_fraction * length;
    adaptive.enable_adaptive(&case.model, threshold, 0.2);
    let dt = stable_dt(&case.model, &full, &case.fixed);
    let steps = case.prescribed.ramp_steps;
    let run = |ff: &mut TensorMassForceField, update: bool| -> (Vec<Vec3>, f64, usize) {
        let mut x = case.model.rest.clone();
        let mut cd =
            CentralDifference::new(&case.model, ff, &case.fixed, &x, dt, 5.0).expect("stable");
        let mut count = 0;
        let start = Instant::now();
        for step in 1..=steps {
            let s = step as f64 / steps as f64;
            for &(v, target) in &case.prescribed.targets {
                let r = case.model.rest[v];
                x[v] = std::array::from_fn(|k| r[k] + s * (target[k] - r[k]));
            }
            if update {
                count = ff.update_adaptive(&case.model, &topo, &x);
            }
            cd.step(&case.model, &topo, ff, None, &case.fixed, &[], &mut x);
        }
        (x, start.elapsed().as_secs_f64(), count)
    };
    let mut full_ff = full;
    let (x_full, t_full, _) = run(&mut full_ff, false);
    let (x_adaptive, t_adaptive, count) = run(&mut adaptive, true);
    // A motion that blew up shows as an infinite difference (max() would skip NaN).
    let finite = |x: &[Vec3]| x.iter().flatten().all(|c| c.is_finite());
    let blew_up = !(finite(&x_full) && finite(&x_adaptive));
    let max_disp = x_full
        .iter()
        .zip(&case.model.rest)
        .map(|(p, r)| (0..3).map(|k| (p[k] - r[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0f64, f64::max);
    let err = x_full
        .iter()
        .zip(&x_adaptive)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0f64, f64::max);
    AdaptiveRow {
        mesh: "liver".into(),
        tets: case.mesh.tets().len(),
        vertices: case.model.vertex_count(),
        threshold_m: threshold,
        steps,
        svk_steps_per_s: steps as f64 / t_full,
        adaptive_steps_per_s: steps as f64 / t_adaptive,
        speedup: t_full / t_adaptive,
        nonlinear_vertices: count,
        displacement_error: if blew_up {
            f64::INFINITY
        } else {
            err / max_disp.max(f64::MIN_POSITIVE)
        },
    }
}

/// Runs the report.
pub fn run(args: &TensorMassArgs) -> anyhow::Result<()> {
    let (across, layers) = parse_pair(&args.cylinder)?;
    let lambda = Lame::from_young_poisson(YOUNG, POISSON).lambda;
    let bar = progress::stages(16);
    let mut table = Vec::new();
    let liver = if args.cylinder_only {
        None
    } else {
        Some(liver_case(&liver_volume()?, args.liver_pull)?)
    };
    let cases: Vec<(VolumeCase, f64)> =
        [("cylinder-left", 0.25), ("cylinder-middle", 0.5), ("cylinder-right", 0.75)]
            .into_iter()
            .map(|(name, f)| (cylinder_case(name, across, layers, f), f))
            .collect();
    for (case, fraction) in &cases {
        for (m, model) in MODELS.iter().enumerate() {
            bar.set_message(format!("{} {model}", case.name));
            let (pct, converged) = tet_volume_change(case, m, args.kappa_over_lambda);
            table.push(VolumeRow {
                case: case.name.clone(),
                model: (*model).into(),
                volume_change_pct: pct,
                paper_pct: paper(&case.name, m),
                converged,
                elements: case.mesh.tets().len(),
            });
            bar.inc(1);
        }
        bar.set_message(format!("{} corotational hex", case.name));
        let (pct, converged, elements) = hex_volume_change(across, *fraction)?;
        table.push(VolumeRow {
            case: case.name.clone(),
            model: "corotational-hex".into(),
            volume_change_pct: pct,
            paper_pct: None,
            converged,
            elements,
        });
        bar.inc(1);
    }
    for (m, model) in MODELS.iter().enumerate() {
        let Some((liver, _)) = &liver else { break };
        bar.set_message(format!("liver {model}"));
        let (pct, converged) = tet_volume_change(liver, m, args.kappa_over_lambda);
        table.push(VolumeRow {
            case: "liver".into(),
            model: (*model).into(),
            volume_change_pct: pct,
            paper_pct: paper("liver", m),
            converged,
            elements: liver.mesh.tets().len(),
        });
        bar.inc(1);
    }
    // Speed: the ≈2,000-tetrahedron cylinder (paper 2: 25 Hz on 2,000 tetrahedra) and the liver.
    let speed_mesh = cylinder(RADIUS, 3.0 * RADIUS, 6, 9);
    let speed_model = TetModel::new(&speed_mesh, |_| {
        TetMaterial::isotropic(Lame::from_young_poisson(YOUNG, POISSON), 1_000.0)
    });
    let mut speeds = Vec::new();
    for model in MODELS {
        bar.set_message(format!("speed {model}"));
        speeds.push(speed(
            "cylinder-6x9",
            &speed_mesh,
            &speed_model,
            model,
            args.kappa_over_lambda * lambda,
            args.seconds,
        ));
        if let Some((liver, _)) = &liver {
            let liver_lambda = liver.model.lame.iter().map(|l| l.lambda).fold(0.0f64, f64::max);
            speeds.push(speed(
                "liver",
                &liver.mesh,
                &liver.model,
                model,
                args.kappa_over_lambda * liver_lambda,
                args.seconds,
            ));
        }
    }
    bar.set_message("adaptive");
    let adaptive = liver.as_ref().map(|(liver, length)| adaptive(liver, *length, args.threshold));
    bar.finish_and_clear();

    println!(
        "Paper 2 Table 1: relative volume change at static equilibrium (%), κ = {} λ",
        args.kappa_over_lambda
    );
    println!(
        "{:<16} {:<20} {:>8} {:>12} {:>8} {:>9}",
        "case", "model", "ours %", "paper %", "elements", "converged"
    );
    for r in &table {
        let paper = r.paper_pct.map_or("-".into(), |p| format!("{p}"));
        println!(
            "{:<16} {:<20} {:>8.2} {:>12} {:>8} {:>9}",
            r.case,
            r.model,
            r.volume_change_pct,
            paper,
            r.elements,
            if r.converged { "yes" } else { "NO" }
        );
    }
    println!();
    println!("Explicit speed (central differences at the stable step, release build):");
    println!("{:<14} {:>6} {:<20} {:>12} {:>10}", "mesh", "tets", "model", "steps/s", "dt (s)");
    for s in &speeds {
        println!(
            "{:<14} {:>6} {:<20} {:>12.0} {:>10.2e}",
            s.mesh, s.tets, s.model, s.steps_per_s, s.dt_s
        );
    }
    if let Some(adaptive) = &adaptive {
        println!();
        println!(
            "Adaptive non-linearity on the liver ({} tets, threshold {:.1} mm = {:.0} % of its length): \
         {:.0} vs {:.0} steps/s for full SVK, speed-up {:.2}× (paper: 2.5×); {} of {} vertices non-linear; \
         displacement difference {:.2e} of the largest displacement",
            adaptive.tets,
            1e3 * adaptive.threshold_m,
            100.0 * args.threshold,
            adaptive.adaptive_steps_per_s,
            adaptive.svk_steps_per_s,
            adaptive.speedup,
            adaptive.nonlinear_vertices,
            adaptive.vertices,
            adaptive.displacement_error
        );
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "table1": table, "speed": speeds, "adaptive": adaptive })
        );
    }
    Ok(())
}
