//! Times the surface on the liver CT (`tests/data/liver.inr.gz`, filtered like the scenes and
//! strided 8,8,4 → 13,648 voxels and 4,4,2 → 109,201 voxels, grid level 3): full extraction, the
//! embedding, and one blade stroke removing about 500 voxels (grid update, local re-mesh,
//! re-embedding). Each time is the median of 5 runs; nothing is asserted.
//!
//! `cargo run --release --example surface_bench -p incise_surface`

use incise_grid::{BranchedGrid, GridEdit, LabelFilter, MaterialTable};
use incise_surface::{Surface, SurfaceMapping, SurfaceOptions, changed_elements};
use std::time::Instant;

const RUNS: usize = 5;

/// Median wall time of `RUNS` calls of `f` (ms), with the last call's result.
fn time<T>(mut f: impl FnMut() -> T) -> (f64, T) {
    let mut times = Vec::with_capacity(RUNS);
    let mut last = None;
    for _ in 0..RUNS {
        let t = Instant::now();
        last = Some(f());
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    (times[RUNS / 2], last.expect("RUNS > 0"))
}

/// A blade 2 voxels thick entering from the top across the middle of `x`: the first `count`
/// voxels with material, top layer first.
fn stroke(grid: &BranchedGrid, count: usize) -> Vec<u32> {
    let d = grid.fine().dims();
    let mut out = Vec::new();
    for z in (0..d[2]).rev() {
        for y in 0..d[1] {
            for x in d[0] / 2..d[0] / 2 + 2 {
                let v = x + d[0] * (y + d[1] * z);
                if grid.fine().material(v).is_some() && out.len() < count {
                    out.push(v);
                }
            }
        }
    }
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/liver.inr.gz");
    let raw = incise_io::read_volume(std::path::Path::new(path))?;
    let filtered = raw.filtered(&LabelFilter::abdominal_ct());
    let materials = MaterialTable::abdominal_ct();
    println!(
        "| voxels | groups | triangles | vertices | extract (ms) | embed (ms) | stroke voxels | grid update (ms) | re-mesh (ms) | triangles -/+ | re-embed (ms) | vertices re-embedded |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for stride in [[8, 8, 4], [4, 4, 2]] {
        let volume = filtered.crop_and_stride(stride)?;
        let grid = BranchedGrid::build(&volume, &materials, 3)?;
        let n_materials = grid.materials().count() as u16;
        for options in [SurfaceOptions::default(), SurfaceOptions::per_material(n_materials)] {
            let (t_extract, surface) =
                time(|| Surface::extract(grid.fine(), grid.spacing(), &options));
            let node = |n: u32| n;
            let (t_embed, mapping) = time(|| SurfaceMapping::embed(&surface, &grid, &node));
            // Sorted, as the simulation passes them.
            let mut voxels = stroke(&grid, 500);
            voxels.sort_unstable();
            let edit = GridEdit { remove_voxels: voxels, sever_links: vec![] };
            // Each run cuts fresh copies; only the cut itself is timed.
            let (mut t_grid, mut t_remesh, mut t_update) = (Vec::new(), Vec::new(), Vec::new());
            let (mut changes, mut count) = (None, 0);
            for _ in 0..RUNS {
                let (mut g, mut s, mut m) = (grid.clone(), surface.clone(), mapping.clone());
                let t = Instant::now();
                let grid_changes = g.apply(&edit)?;
                t_grid.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                let c = s.remesh(g.fine(), &edit.remove_voxels);
                t_remesh.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                count = m.update_by_grid_node(&s, &g, &changed_elements(&grid_changes), &c);
                t_update.push(t.elapsed().as_secs_f64() * 1e3);
                changes = Some(c);
            }
            let median = |mut v: Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[RUNS / 2]
            };
            let changes = changes.expect("RUNS > 0");
            println!(
                "| {} | {} | {} | {} | {t_extract:.2} | {t_embed:.2} | {} | {:.2} | {:.3} | {}/{} | {:.3} | {count} |",
                grid.fine().voxel_count(),
                surface.group_count(),
                surface.triangle_count(),
                surface.vertex_count(),
                edit.remove_voxels.len(),
                median(t_grid),
                median(t_remesh),
                changes.triangles_removed.len(),
                changes.triangles_added.len(),
                median(t_update),
            );
        }
    }
    Ok(())
}
