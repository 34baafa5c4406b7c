//! `incise-bench reference`: how far the 13,648-voxel liver's finest model is from the finest
//! model affordable, the 109,201-voxel liver (the same CT at twice the resolution per axis),
//! both at level 0 and solved statically hanging from their hold under gravity.
//!
//! The two are compared on the same physical points: the centres of the coarse liver's voxels.
//! The coarse voxel `i` covers the fine voxels `2i` and `2i + 1` along each axis (both grids are
//! the CT cropped to the same corner, strided by 8, 8, 4 and 4, 4, 2), so its centre is a node
//! of the fine grid, where the fine model's displacement is exact; the coarse model's there is
//! its voxel's trilinear interpolation at the centre (the mean of its eight nodes). A coarse
//! voxel with no fine node at its centre (the strided labels differ at the organ's boundary)
//! is left out and counted.
//!
//! Over the points, each weighted alike: the centre of mass's displacement, the largest and the
//! RMS displacement, each with the coarse model's signed error `(coarse − fine) / fine`, and the
//! RMS of the difference of the two fields relative to the fine field's RMS.

use super::organ::Measures;
use super::{Case, Liver, Preconditioner, static_positions};
use anyhow::{Context, bail};
use incise_fem::Formulation;
use incise_math::Vec3;
use serde::Serialize;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `incise-bench reference`.
#[derive(clap::Args, Debug)]
pub struct ReferenceArgs {
    /// Folder of the scene files (`liver_13k.toml`, `liver_109k.toml`).
    #[arg(long, value_name = "DIR", default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes"))]
    scene_dir: PathBuf,
    /// Models to solve, comma-separated: `corotational` (the fine one takes about 5 minutes on
    /// a 2-core machine), `linear` (about 40 s).
    #[arg(long, value_delimiter = ',', default_value = "corotational,linear")]
    models: Vec<String>,
    /// How each Newton step's linear solve is preconditioned: `multigrid` (levels 0 to 3 of
    /// the same liver, `incise_fem::linsolve::multigrid`) or `block-jacobi`.
    #[arg(long, default_value = "multigrid")]
    solver: String,
    /// End with one line holding one JSON object.
    #[arg(long)]
    json: bool,
}

/// One model's comparison.
#[derive(Debug, Serialize)]
struct Comparison {
    model: &'static str,
    /// Coarse voxels compared, and those with no fine node at their centre.
    points: usize,
    unmatched: usize,
    /// The 109,201-voxel liver (the reference) and the 13,648-voxel one, at level 0.
    fine: Measures,
    coarse: Measures,
    /// `(coarse − fine) / fine` for each measure.
    error_signed: Measures,
    /// `RMS |u_coarse − u_fine| / RMS |u_fine|` over the points.
    field_rms_error: f64,
    /// Seconds the static solves took.
    fine_solve_s: f64,
    coarse_solve_s: f64,
}

/// Runs the comparison.
pub fn run(args: &ReferenceArgs) -> anyhow::Result<()> {
    let mut formulations = Vec::new();
    for m in &args.models {
        formulations.push(match m.as_str() {
            "corotational" => (Formulation::Corotational, "corotational"),
            "linear" => (Formulation::Linear, "linear"),
            other => bail!("--models: unknown model {other:?}; expected corotational or linear"),
        });
    }
    let multigrid = match args.solver.as_str() {
        "multigrid" => true,
        "block-jacobi" => false,
        other => bail!("--solver: unknown solver {other:?}; expected multigrid or block-jacobi"),
    };
    // Both livers built at levels 0 to 3 once, for both models: the multigrid's levels (the
    // hierarchy of each model is built within its solve's time).
    let small = Liver::read(&args.scene_dir, "liver-13k", "liver_13k.toml", 0)?;
    let large = Liver::read(&args.scene_dir, "liver-109k", "liver_109k.toml", 0)?;
    let coarse = small.case(0, "condensed")?;
    let fine = large.case(0, "condensed")?;
    let matching = Matching::new(&coarse, &small.supported.1, &fine, &large.supported.1)?;
    let mut rows = Vec::new();
    for (formulation, name) in formulations {
        let solve = |liver: &Liver, case: &Case, what: &str| -> anyhow::Result<(Vec<Vec3>, f64)> {
            eprintln!(
                "{name}: solving {what} at level 0 ({} nodes) statically with {} …",
                case.model.node_count(),
                args.solver
            );
            let start = Instant::now();
            let x = if multigrid {
                liver.static_level0(case, formulation)?
            } else {
                static_positions(case, formulation, &mut Preconditioner::BlockJacobi)
            }
            .with_context(|| format!("{name}: the static solve of {what} did not converge"))?;
            let s = start.elapsed().as_secs_f64();
            eprintln!("  {s:.1} s");
            Ok((x, s))
        };
        let (xc, coarse_solve_s) = solve(&small, &coarse, "the 13,648-voxel liver")?;
        let (xf, fine_solve_s) = solve(&large, &fine, "the 109,201-voxel liver")?;
        rows.push(matching.compare(name, &coarse, &xc, &fine, &xf, coarse_solve_s, fine_solve_s));
    }
    print(&rows);
    if args.json {
        println!("{}", serde_json::json!({ "scene": "liver", "models": rows }));
    }
    Ok(())
}

/// Which fine node lies at each coarse voxel's centre.
pub(super) struct Matching {
    /// Per coarse element (a voxel at level 0): the fine nodes at its centre (empty: none).
    nodes: Vec<Vec<u32>>,
}

impl Matching {
    /// The matching of `coarse`'s voxels (`coarse_volume`'s at level 0) with `fine`'s nodes.
    ///
    /// # Errors
    /// When the two grids do not nest.
    pub(super) fn new(
        coarse: &Case,
        coarse_volume: &incise_grid::LabelVolume,
        fine: &Case,
        fine_volume: &incise_grid::LabelVolume,
    ) -> anyhow::Result<Self> {
        let h = fine_volume.spacing();
        let (Some((coarse_lo, _)), Some((fine_lo, _))) =
            (coarse_volume.foreground_bounds(), fine_volume.foreground_bounds())
        else {
            bail!("an empty liver");
        };
        // Each grid frame starts at its own volume's foreground corner.
        let shift: Vec3 = std::array::from_fn(|a| {
            coarse_lo[a] as f64 * coarse_volume.spacing()[a] - fine_lo[a] as f64 * h[a]
        });
        let key = |p: Vec3| -> [i64; 3] { std::array::from_fn(|a| (p[a] / h[a]).round() as i64) };
        let mut at: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (n, &p) in fine.model.rest.iter().enumerate() {
            at.entry(key(p)).or_default().push(n as u32);
        }
        let rest = &coarse.model.rest;
        let nodes = coarse
            .model
            .elements
            .iter()
            .map(|e| {
                let c: Vec3 = std::array::from_fn(|a| {
                    e.nodes.iter().map(|&n| rest[n as usize][a]).sum::<f64>() / 8.0 + shift[a]
                });
                let k = key(c);
                // A centre between fine nodes would be a misaligned grid, not a missing node.
                let off = (0..3).map(|a| (c[a] / h[a] - k[a] as f64).abs()).fold(0.0, f64::max);
                if off > 1e-6 {
                    return Err(off);
                }
                Ok(at.get(&k).cloned().unwrap_or_default())
            })
            .collect::<Result<Vec<_>, f64>>()
            .map_err(|off| {
                anyhow::anyhow!(
                    "a coarse voxel's centre lies {off:.3} fine voxels off the fine grid's nodes: \
                     the two livers' grids do not nest"
                )
            })?;
        Ok(Self { nodes })
    }

    /// The compared points as the coarse model's level-0 nodes: each matched voxel's corners.
    pub(super) fn coarse_points(&self, coarse: &incise_fem::HexModel) -> Vec<Vec<u32>> {
        coarse
            .elements
            .iter()
            .zip(&self.nodes)
            .filter(|(_, fine)| !fine.is_empty())
            .map(|(e, _)| e.nodes.to_vec())
            .collect()
    }

    /// The compared points as the fine model's level-0 nodes.
    pub(super) fn fine_points(&self) -> Vec<Vec<u32>> {
        self.nodes.iter().filter(|n| !n.is_empty()).cloned().collect()
    }

    /// Coarse voxels with no fine node at their centre.
    pub(super) fn unmatched(&self) -> usize {
        self.nodes.iter().filter(|n| n.is_empty()).count()
    }

    #[allow(clippy::too_many_arguments, reason = "both models, both solutions and their times")]
    fn compare(
        &self,
        model: &'static str,
        coarse: &Case,
        xc: &[Vec3],
        fine: &Case,
        xf: &[Vec3],
        coarse_solve_s: f64,
        fine_solve_s: f64,
    ) -> Comparison {
        let (mut uc, mut uf) = (Vec::new(), Vec::new());
        for (e, nodes) in coarse.model.elements.iter().zip(&self.nodes) {
            if nodes.is_empty() {
                continue;
            }
            uc.push(mean_displacement(&e.nodes, &coarse.model.rest, xc));
            uf.push(mean_displacement(nodes, &fine.model.rest, xf));
        }
        let (c, f) = (Measures::of(&uc), Measures::of(&uf));
        let difference: Vec<Vec3> =
            uc.iter().zip(&uf).map(|(a, b)| std::array::from_fn(|k| a[k] - b[k])).collect();
        Comparison {
            model,
            points: uc.len(),
            unmatched: self.nodes.len() - uc.len(),
            fine: f,
            coarse: c,
            error_signed: c.signed_error(&f),
            field_rms_error: Measures::of(&difference).rms / f.rms,
            fine_solve_s,
            coarse_solve_s,
        }
    }
}

/// The mean displacement of `nodes` (not empty) at positions `x` from `rest`.
fn mean_displacement(nodes: &[u32], rest: &[Vec3], x: &[Vec3]) -> Vec3 {
    let count = nodes.len() as f64;
    std::array::from_fn(|a| {
        nodes.iter().map(|&n| x[n as usize][a] - rest[n as usize][a]).sum::<f64>() / count
    })
}

fn print(rows: &[Comparison]) {
    println!();
    println!("the 13,648-voxel liver at level 0 against the 109,201-voxel liver at level 0");
    println!("(static, hanging under gravity; displacements at the coarse voxels' centres)");
    println!(
        "{:<13} {:>7} {:>14} {:>14} {:>14} {:>12}",
        "model", "points", "com mm", "max mm", "rms mm", "field rms"
    );
    for r in rows {
        let cell =
            |c: f64, f: f64, e: f64| format!("{:.2}/{:.2} {:+.1}%", c * 1e3, f * 1e3, e * 1e2);
        println!(
            "{:<13} {:>7} {:>14} {:>14} {:>14} {:>11.1}%",
            r.model,
            r.points,
            cell(r.coarse.centre_of_mass, r.fine.centre_of_mass, r.error_signed.centre_of_mass),
            cell(r.coarse.max, r.fine.max, r.error_signed.max),
            cell(r.coarse.rms, r.fine.rms, r.error_signed.rms),
            r.field_rms_error * 1e2
        );
        println!(
            "{:<13} {} coarse voxels with no fine node at their centre; solves {:.1} s (coarse), \
             {:.1} s (fine)",
            "", r.unmatched, r.coarse_solve_s, r.fine_solve_s
        );
    }
    println!("cells: coarse/fine and the coarse model's signed error");
}
