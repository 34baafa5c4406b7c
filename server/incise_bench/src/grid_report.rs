//! `incise-bench grid`: the Dynamic Branched Grid report (Jeřábková 2010, §2).
//!
//! Measures, on one volume: the grid's per-level counts, the full build (volume → grid →
//! condensed K and M at the top level), direct vs recursive condensation (eq. 2–4 vs eq. 1) and
//! their largest difference, and a blade-shaped cut stroke applied incrementally vs rebuilt from
//! scratch, checking in the same run that the two agree.

use crate::progress;
use crate::stroke::{blade_links, blade_stroke};
use crate::timing::{Timing, measure};
use anyhow::{Context, bail};
use incise_grid::canonical::compare_grids;
use incise_grid::hex8::{mat8_frobenius, mat8_frobenius_diff};
use incise_grid::procedural::{TISSUE, TUMOUR, ellipsoid_with_inclusion};
use incise_grid::{BranchedGrid, GridEdit, LabelFilter, LabelVolume, Material, MaterialTable};
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `incise-bench grid`.
#[derive(clap::Args, Debug)]
pub struct GridArgs {
    /// Label volume (.nii, .nii.gz, .inr, .inr.gz). Without it, a procedural organ (an ellipsoid of
    /// liver-like tissue holding a stiffer tumour) is used.
    #[arg(long, value_name = "PATH")]
    volume: Option<PathBuf>,
    /// After cropping to the foreground, keep every X-th, Y-th, Z-th voxel (e.g. 4,4,2).
    #[arg(long, value_name = "X,Y,Z", default_value = "1,1,1", value_parser = parse_stride)]
    stride: [usize; 3],
    /// Top level L: each element covers 2^L × 2^L × 2^L voxels (0 = one element per voxel, at most 5).
    #[arg(long, default_value_t = 3)]
    levels: u32,
    /// Keep only these labels (comma-separated, applied after merging the fixture's stray label
    /// 84 into 85). Default: every label.
    #[arg(long, value_delimiter = ',', value_name = "L1,L2,…")]
    labels: Vec<u16>,
    /// Voxels removed by the cut stroke.
    #[arg(long, default_value_t = 500)]
    cut_voxels: usize,
    /// Repeats of each timed operation; the median is reported (recursive condensation, the slow
    /// reference, runs a third as often).
    #[arg(long, default_value_t = 9)]
    repeats: usize,
    /// Voxels along x of the procedural organ used without --volume.
    #[arg(long, default_value_t = 96)]
    procedural_size: usize,
    /// End with one line holding one JSON object with every figure.
    #[arg(long)]
    json: bool,
    /// Also write the per-level table as CSV to this file.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
}

fn parse_stride(s: &str) -> Result<[usize; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("stride '{s}' must be three comma-separated integers, e.g. 4,4,2"));
    }
    let mut out = [0; 3];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p
            .trim()
            .parse()
            .map_err(|_| format!("stride component '{p}' is not a positive integer"))?;
        if *o == 0 {
            return Err("stride components must be at least 1".into());
        }
    }
    Ok(out)
}

#[derive(Serialize)]
struct LevelRow {
    level: u32,
    elements: usize,
    superimposed: usize,
    nodes: usize,
    occupied_cells: usize,
    fill_ratio: f64,
}

#[derive(Serialize)]
struct Report {
    volume: String,
    dims: [usize; 3],
    spacing_m: [f64; 3],
    stride: [usize; 3],
    top_level: u32,
    voxels: usize,
    materials: usize,
    levels: Vec<LevelRow>,
    load_ms: f64,
    tables_ms: f64,
    build_ms: f64,
    build: Timing,
    condense_direct_ms: f64,
    condense_direct: Timing,
    condense_direct_steps: usize,
    condense_recursive_ms: f64,
    condense_recursive: Timing,
    direct_speedup: f64,
    condense_max_rel_diff: f64,
    /// Composite stiffness (`incise_grid::composite`) of every top-level element, from scratch.
    composite_ms: f64,
    composite: Timing,
    /// Incompatible-mode stiffness (`incise_grid::incompatible`) of every top-level element.
    incompatible_ms: f64,
    incompatible: Timing,
    cut_voxels: usize,
    cut500_update_ms: f64,
    cut500_update: Timing,
    cut500_rebuild_ms: f64,
    cut500_rebuild: Timing,
    cut500_speedup: f64,
    /// Incompatible modes of the elements the stroke touched (`cut500_matrices_updated` of
    /// them), added to `cut500_update_ms` when the grid runs incompatible-mode elements.
    cut500_incompatible_ms: f64,
    /// The stroke's grid update when every level's nodes are kept current (what a simulation
    /// of composite elements does, `BranchedGrid::track_all_nodes`).
    cut500_update_all_nodes_ms: f64,
    /// Composite stiffness after the stroke, updated locally (`CompositeLevels::update`: at
    /// every level the cells near a removed voxel whose inputs changed), added to
    /// `cut500_update_all_nodes_ms` when the grid runs composite elements.
    cut500_composite_ms: f64,
    /// Top-level composite elements whose stiffness the local update changed.
    cut500_composite_elements: usize,
    cut500_elements_added: usize,
    cut500_elements_removed: usize,
    cut500_matrices_updated: usize,
    incremental_equals_rebuild: bool,
    incremental_max_rel_diff: f64,
    sever500_update_ms: f64,
    sever500_links: usize,
    sever_equals_rebuild: bool,
}

/// Loads, filters, crops and strides the volume, and picks materials for its labels.
fn prepare(args: &GridArgs) -> anyhow::Result<(String, LabelVolume, MaterialTable)> {
    let (name, raw, mut table) = if let Some(path) = &args.volume {
        let v = incise_io::read_volume(path)?;
        (path.display().to_string(), v, MaterialTable::abdominal_ct())
    } else {
        let v = ellipsoid_with_inclusion(args.procedural_size, 2.5e-3);
        let mut t = MaterialTable::new();
        t.insert(TISSUE, Material::liver());
        t.insert(TUMOUR, Material { youngs_modulus: 45_000.0, ..Material::liver() });
        (
            format!("procedural ellipsoid with tumour ({} voxels along x)", args.procedural_size),
            v,
            t,
        )
    };
    let mut filter = LabelFilter::abdominal_ct();
    if !args.labels.is_empty() {
        filter = filter.keep(&args.labels);
    }
    let filtered = raw.filtered(&filter);
    let volume = filtered
        .crop_and_stride(args.stride)
        .with_context(|| format!("{name}: cropping with stride {:?}", args.stride))?;
    for (label, count) in volume.histogram() {
        if label != 0 && table.get(label).is_none() {
            eprintln!(
                "note: label {label} ({count} voxels) has no preset material; using liver tissue"
            );
            table.insert(label, Material::liver());
        }
    }
    Ok((name, volume, table))
}

fn fmt_count(n: usize) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// Runs the report.
pub fn run(args: &GridArgs) -> anyhow::Result<()> {
    if args.levels > incise_grid::grid::MAX_LEVELS {
        bail!(
            "--levels {} is above the supported maximum {}",
            args.levels,
            incise_grid::grid::MAX_LEVELS
        );
    }
    let repeats = args.repeats.max(1);
    let bar = progress::stages(7);
    bar.set_message("loading volume");
    let start = Instant::now();
    let (name, volume, table) = prepare(args)?;
    let load_ms = start.elapsed().as_secs_f64() * 1e3;
    let voxels = volume.foreground_count();
    bar.inc(1);

    bar.set_message("condensation tables");
    let mats: Vec<Material> = table.iter().map(|(_, m)| *m).collect();
    let (tables, _) = measure(
        repeats,
        || (),
        |()| incise_grid::condense::CondensationTables::new(volume.spacing(), &mats, args.levels),
    );
    bar.inc(1);

    bar.set_message("building the grid");
    let (build, grid) =
        measure(repeats, || (), |()| BranchedGrid::build(&volume, &table, args.levels));
    let grid = grid.with_context(|| format!("{name}: building the grid"))?;
    bar.inc(1);

    bar.set_message("level summary");
    let levels: Vec<LevelRow> = grid
        .summary()
        .into_iter()
        .map(|s| LevelRow {
            level: s.level,
            elements: s.elements,
            superimposed: s.superimposed,
            nodes: s.nodes,
            occupied_cells: s.occupied_cells,
            fill_ratio: s.fill_ratio,
        })
        .collect();
    bar.inc(1);

    bar.set_message("direct vs recursive condensation");
    let ids: Vec<u32> = grid.top().elements().map(|(id, _)| id).collect();
    let (direct, steps) = measure(
        repeats,
        || (),
        |()| ids.iter().map(|&id| grid.condense_direct_with_steps(id).2).sum::<usize>(),
    );
    let (recursive, rec) = measure(repeats.div_ceil(3), || (), |()| grid.condense_recursive());
    let mut max_diff = 0.0f64;
    for &id in &ids {
        let (d, r) = (grid.matrices(id).expect("live"), rec[id as usize].as_ref().expect("live"));
        max_diff = max_diff
            .max(d.stiffness.frobenius_diff(&r.stiffness) / r.stiffness.frobenius())
            .max(mat8_frobenius_diff(&d.mass, &r.mass) / mat8_frobenius(&r.mass));
    }
    drop(rec);
    let (composite, _) = measure(
        repeats.div_ceil(3),
        || (),
        |()| incise_grid::composite::composite_stiffness(&grid),
    );
    let (incompatible, _) = measure(
        repeats.div_ceil(3),
        || (),
        |()| incise_grid::incompatible::incompatible_stiffness(&grid),
    );
    bar.inc(1);

    bar.set_message("cut stroke: incremental update vs rebuild");
    let stroke = blade_stroke(&grid, args.cut_voxels);
    let edit = GridEdit { remove_voxels: stroke.clone(), sever_links: vec![] };
    let (update, (cut_grid, changes)) = measure(
        repeats,
        || grid.clone(),
        |mut g| {
            let c = g.apply(&edit);
            (g, c)
        },
    );
    let changes = changes?;
    let (rebuild, rebuilt) = measure(repeats, || (), |()| cut_grid.rebuild());
    // Incompatible modes depend on each element's own voxels: the elements the cut touched get
    // them again.
    let touched = &changes.matrices_updated;
    let (cut_incompatible, _) = measure(repeats, Vec::new, |mut buffer| {
        touched
            .iter()
            .map(|&id| incise_grid::incompatible::element_stiffness(&cut_grid, id, &mut buffer))
            .count()
    });
    // Composite elements: a simulation of them keeps every level's nodes current, so its grid
    // update does more, and then every level's cells near the stroke are made again.
    let mut tracked = grid.clone();
    tracked.track_all_nodes();
    let (composite_levels, _) = incise_grid::composite::CompositeLevels::new(&tracked);
    let (update_all_nodes, (tracked_cut, tracked_changes)) = measure(
        repeats,
        || tracked.clone(),
        |mut g| {
            let c = g.apply(&edit);
            (g, c)
        },
    );
    let tracked_changes = tracked_changes?;
    let (cut_composite, (_, composite_made)) = measure(
        repeats,
        || composite_levels.clone(),
        |mut levels| {
            let made = levels.update(&tracked_cut, &tracked_changes.dirty_voxels).len();
            (levels, made)
        },
    );
    drop((tracked, tracked_cut, composite_levels));
    let cmp = compare_grids(&cut_grid, &rebuilt, 1e-12);
    if let Err(e) = &cmp {
        eprintln!("incremental update differs from rebuild: {e}");
    }
    bar.inc(1);

    bar.set_message("separation-mode stroke");
    let links = blade_links(&grid, &stroke);
    let sever = GridEdit { remove_voxels: vec![], sever_links: links.clone() };
    let (sever_t, (sever_grid, sever_changes)) = measure(
        repeats,
        || grid.clone(),
        |mut g| {
            let c = g.apply(&sever);
            (g, c)
        },
    );
    sever_changes?;
    let sever_ok = compare_grids(&sever_grid, &sever_grid.rebuild(), 1e-12).is_ok();
    bar.inc(1);
    bar.finish_and_clear();

    let report = Report {
        volume: name,
        dims: volume.dims(),
        spacing_m: volume.spacing(),
        stride: args.stride,
        top_level: args.levels,
        voxels,
        materials: table.len(),
        levels,
        load_ms,
        tables_ms: tables.median_ms,
        build_ms: build.median_ms,
        build,
        condense_direct_ms: direct.median_ms,
        condense_direct: direct.clone(),
        condense_direct_steps: steps,
        condense_recursive_ms: recursive.median_ms,
        direct_speedup: recursive.median_ms / direct.median_ms,
        condense_recursive: recursive,
        condense_max_rel_diff: max_diff,
        composite_ms: composite.median_ms,
        composite,
        incompatible_ms: incompatible.median_ms,
        incompatible,
        cut_voxels: stroke.len(),
        cut500_update_ms: update.median_ms,
        cut500_rebuild_ms: rebuild.median_ms,
        cut500_speedup: rebuild.median_ms / update.median_ms,
        cut500_update_all_nodes_ms: update_all_nodes.median_ms,
        cut500_composite_ms: cut_composite.median_ms,
        cut500_composite_elements: composite_made,
        cut500_incompatible_ms: cut_incompatible.median_ms,
        cut500_update: update,
        cut500_rebuild: rebuild,
        cut500_elements_added: changes.top.elements_added.len(),
        cut500_elements_removed: changes.top.elements_removed.len(),
        cut500_matrices_updated: changes.matrices_updated.len(),
        incremental_equals_rebuild: cmp.is_ok(),
        incremental_max_rel_diff: cmp.unwrap_or(f64::NAN),
        sever500_update_ms: sever_t.median_ms,
        sever500_links: links.len(),
        sever_equals_rebuild: sever_ok,
    };
    print_table(&report);
    if let Some(path) = &args.csv {
        write_csv(path, &report).with_context(|| format!("writing {}", path.display()))?;
    }
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    }
    if !report.incremental_equals_rebuild || !report.sever_equals_rebuild {
        bail!("the incremental update does not equal the rebuild (see above)");
    }
    Ok(())
}

fn print_table(r: &Report) {
    let s = r.spacing_m.map(|h| h * 1e3);
    println!("incise-bench grid: {}", r.volume);
    println!(
        "  stride {},{},{} -> {}x{}x{} voxels of {:.3}x{:.3}x{:.3} mm, {} with material, {} material(s), top level {}",
        r.stride[0],
        r.stride[1],
        r.stride[2],
        r.dims[0],
        r.dims[1],
        r.dims[2],
        s[0],
        s[1],
        s[2],
        fmt_count(r.voxels),
        r.materials,
        r.top_level
    );
    println!();
    println!(
        "  {:>5} {:>10} {:>13} {:>10} {:>8}",
        "level", "elements", "superimposed", "nodes", "fill"
    );
    for l in &r.levels {
        println!(
            "  {:>5} {:>10} {:>13} {:>10} {:>8.3}",
            l.level,
            fmt_count(l.elements),
            fmt_count(l.superimposed),
            fmt_count(l.nodes),
            l.fill_ratio
        );
    }
    println!();
    let row = |what: &str, t: &Timing| {
        println!(
            "  {what:<52} {:>10.3} {:>10.3} {:>10.3} {:>4}",
            t.median_ms, t.min_ms, t.max_ms, t.repeats
        );
    };
    println!("  {:<52} {:>10} {:>10} {:>10} {:>4}", "timing (ms)", "median", "min", "max", "n");
    println!("  {:<52} {:>10.3}", "load + crop + stride (once)", r.load_ms);
    row(
        &format!("condensation tables (part of build, L = {})", r.top_level),
        &Timing { median_ms: r.tables_ms, min_ms: r.tables_ms, max_ms: r.tables_ms, repeats: 1 },
    );
    row("build: volume -> grid -> condensed K, M at top", &r.build);
    row(
        &format!(
            "direct condensation, all elements ({} steps)",
            fmt_count(r.condense_direct_steps)
        ),
        &r.condense_direct,
    );
    row("recursive condensation (eq. 1), all levels", &r.condense_recursive);
    row("composite stiffness, all levels", &r.composite);
    row("incompatible-mode stiffness, all elements", &r.incompatible);
    row(&format!("cut stroke of {} voxels: incremental update", r.cut_voxels), &r.cut500_update);
    row("cut stroke: rebuild from scratch", &r.cut500_rebuild);
    println!(
        "  {:<52} {:>10.3}",
        "cut stroke: incompatible modes of touched elements", r.cut500_incompatible_ms
    );
    println!(
        "  {:<52} {:>10.3}",
        "cut stroke: update keeping every level's nodes", r.cut500_update_all_nodes_ms
    );
    println!(
        "  {:<52} {:>10.3}",
        format!("cut stroke: composite, near it ({} top elements)", r.cut500_composite_elements),
        r.cut500_composite_ms
    );
    println!(
        "  {:<52} {:>10.3}",
        format!("separation stroke, {} links severed: update", r.sever500_links),
        r.sever500_update_ms
    );
    println!();
    println!(
        "  direct vs recursive: {:.1}x faster, max relative difference {:.2e}",
        r.direct_speedup, r.condense_max_rel_diff
    );
    println!(
        "  cut stroke: update {:.1}x faster than rebuild; {} elements added, {} removed, {} matrices updated",
        r.cut500_speedup,
        r.cut500_elements_added,
        r.cut500_elements_removed,
        r.cut500_matrices_updated
    );
    println!(
        "  incremental equals rebuild: {} (max relative K/M difference {:.2e}); separation stroke: {}",
        r.incremental_equals_rebuild, r.incremental_max_rel_diff, r.sever_equals_rebuild
    );
}

fn write_csv(path: &std::path::Path, r: &Report) -> std::io::Result<()> {
    let mut f = std::fs::File::create(path)?;
    writeln!(f, "volume,voxels,level,elements,superimposed,nodes,occupied_cells,fill_ratio")?;
    for l in &r.levels {
        writeln!(
            f,
            "\"{}\",{},{},{},{},{},{},{}",
            r.volume,
            r.voxels,
            l.level,
            l.elements,
            l.superimposed,
            l.nodes,
            l.occupied_cells,
            l.fill_ratio
        )?;
    }
    Ok(())
}
