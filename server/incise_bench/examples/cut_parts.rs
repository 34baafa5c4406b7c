//! Where a cut's time goes on the liver (`deploy/scenes/liver_13k.toml` at strides 8,8,4 and
//! 4,4,2, level 3): the steps `Simulation::cut` takes, replayed one by one through the crates'
//! public interfaces and timed apart, for small cuts (a stroke removed `k` voxels at a time) and
//! for a 500-voxel stroke in one edit; then `Simulation::cut` itself on the same edits, the figure
//! the parts should add up to. Medians (µs); nothing is asserted.
//!
//! `cargo run --release -p incise_bench --example cut_parts [-- [--repeat N] [--parts-only]
//! [--evict MB] STRIDE...]` (strides such as `8,8,4`; `--repeat`: runs of each case, 3 by
//! default; `--parts-only`: no `Simulation::cut`, for a profiler's eyes; `--evict MB`: write
//! that much memory before each cut, untimed).
//!
//! Cuts timed back to back find everything they touch in the caches. In a simulation the
//! physics, contact and cut search run between two cuts and push it out, so a frame's cut costs
//! 2–3× more than the warm figure. `--evict 4` empties the private caches before each cut and
//! `--evict 64` this machine's shared one as well; the frame's figures lie between the two.

use incise_fem::model::State;
use incise_fem::{Executor, FixedNodes, Formulation, HexForceField, HexModel, Idle};
use incise_grid::{BranchedGrid, GridEdit};
use incise_sim::config::{Level, Model, VolumeSpec};
use incise_sim::{OrganSurface, Simulation};
use incise_surface::{Surface, SurfaceMapping, SurfaceOptions, changed_elements};
use std::time::Instant;

/// Timed steps, in the order a cut takes them, their sum, and the surface's step split by a
/// replay on a twin surface (not in the sum).
const PARTS: [&str; 9] = [
    "grid.apply",
    "model update",
    "state across cut",
    "force field remap",
    "fixed nodes",
    "surface",
    "sum",
    "(surface: remesh)",
    "(surface: re-embed)",
];

/// The mechanics and surface a cut updates.
struct Body {
    grid: BranchedGrid,
    model: HexModel,
    field: HexForceField,
    state: State,
    organ: OrganSurface,
    /// The organ's surface and embedding again, to time re-meshing and re-embedding apart.
    surface: Surface,
    mapping: SurfaceMapping,
}

/// The box the liver scene holds its top by.
const HOLD: ([f64; 3], [f64; 3]) = ([-1.0, -1.0, 0.17], [1.0, 1.0, 1.0]);

impl Body {
    /// One cut (removing sorted voxels), step by step as `Simulation::cut` takes them; each
    /// step's time (µs).
    fn cut(&mut self, edit: &GridEdit) -> [f64; PARTS.len()] {
        let mut t = [0.0; PARTS.len()];
        let mut clock = Instant::now();
        let mut lap = |k: usize, t: &mut [f64; PARTS.len()]| {
            t[k] = clock.elapsed().as_secs_f64() * 1e6;
            clock = Instant::now();
        };
        let changes = self.grid.apply(edit).expect("the stroke's voxels exist");
        lap(0, &mut t);
        let renumbering = self.model.update(&self.grid, &changes);
        lap(1, &mut t);
        let old_of_new = self.state.carry(&self.model, &renumbering, &changes);
        lap(2, &mut t);
        let added = &changes.top.elements_added;
        self.field.remap(&self.model, &renumbering, |g| {
            added.iter().find(|&&(id, _)| id == g).and_then(|&(_, origin)| origin)
        });
        lap(3, &mut t);
        let fixed = FixedNodes::none(self.model.node_count()).union(&FixedNodes::aabb(
            &self.model.rest,
            HOLD.0,
            HOLD.1,
        ));
        for (i, v) in self.state.v.iter_mut().enumerate() {
            if fixed.is_fixed(i) {
                *v = [0.0; 3];
            }
        }
        std::hint::black_box((vec![[0.0; 3]; self.model.node_count()], old_of_new));
        lap(4, &mut t);
        self.organ.after_grid_edit(&self.grid, &self.model, &edit.remove_voxels, &changes);
        lap(5, &mut t);
        t[6] = t[..6].iter().sum();
        let clock = Instant::now();
        let surface_changes = self.surface.remesh(self.grid.fine(), &edit.remove_voxels);
        t[7] = clock.elapsed().as_secs_f64() * 1e6;
        let clock = Instant::now();
        let changed = changed_elements(&changes);
        self.mapping.update_by_grid_node(&self.surface, &self.grid, &changed, &surface_changes);
        t[8] = clock.elapsed().as_secs_f64() * 1e6;
        t
    }
}

/// A blade 2 voxels thick entering from the top across the middle of `x`: the first `count`
/// voxels with material, top layer first (as `incise_surface`'s `surface_bench`).
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

/// Memory written before each cut (empty: none), to push the cut's data out of the caches as a
/// simulation step between two cuts does.
struct Evict(Vec<u64>);

impl Evict {
    fn run(&mut self) {
        for x in &mut self.0 {
            *x = x.wrapping_mul(3).wrapping_add(1);
        }
        std::hint::black_box(&self.0);
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// `edits` one after the other, on a new `body()` (per-part medians) and through
/// `Simulation::cut` on a fresh simulation (its median), `repeat` times each (from scratch).
fn measure(
    body: &dyn Fn() -> Body,
    fresh: Option<&dyn Fn() -> Simulation>,
    edits: &[GridEdit],
    repeat: usize,
    evict: &mut Evict,
) -> ([f64; PARTS.len()], f64) {
    let mut parts: Vec<Vec<f64>> = vec![Vec::new(); PARTS.len()];
    let mut whole = Vec::new();
    for _ in 0..repeat {
        let mut b = body();
        for edit in edits {
            evict.run();
            for (k, t) in b.cut(edit).into_iter().enumerate() {
                parts[k].push(t);
            }
        }
        let Some(fresh) = fresh else { continue };
        let mut sim = fresh();
        for edit in edits {
            evict.run();
            let t = Instant::now();
            sim.cut(edit).expect("the stroke's voxels exist");
            whole.push(t.elapsed().as_secs_f64() * 1e6);
        }
    }
    let parts = parts.into_iter().map(median).collect::<Vec<_>>();
    let whole = if whole.is_empty() { f64::NAN } else { median(whole) };
    (parts.try_into().expect("one median per part"), whole)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (mut strides, mut repeat, mut parts_only, mut evict_mb) = (Vec::new(), 3, false, 0usize);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--repeat" => repeat = args.next().ok_or("--repeat N")?.parse()?,
            "--parts-only" => parts_only = true,
            "--evict" => evict_mb = args.next().ok_or("--evict MB")?.parse()?,
            _ => {
                let v: Vec<usize> = a.split(',').map(str::parse).collect::<Result<_, _>>()?;
                strides.push(<[usize; 3]>::try_from(v).map_err(|_| "a stride is x,y,z")?);
            }
        }
    }
    if strides.is_empty() {
        strides = vec![[8, 8, 4], [4, 4, 2]];
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes/liver_13k.toml");
    let mut scene = incise_scene::read_scene(std::path::Path::new(path))?;
    let exec = Executor::new(1, Idle::Sleep);
    let mut evict = Evict(vec![1; evict_mb << 17]);
    print!("| voxels | elements | nodes | cut |");
    for p in PARTS {
        print!(" {p} |");
    }
    println!(" Simulation::cut |");
    println!("|---:|---:|---:|---|{}---:|", "---:|".repeat(PARTS.len()));
    for stride in strides {
        if let Some(VolumeSpec::File { stride: s, .. }) = scene.config.volume_mut() {
            *s = stride;
        }
        if let Model::Hexahedra(hex) = &mut scene.config.model {
            hex.level = Level::Fixed(3);
        }
        let fresh = || {
            let mut sim = Simulation::with_executor(&scene.config, &scene.geometry, "liver", &exec)
                .expect("the liver scene builds");
            sim.enable_surface();
            sim
        };
        let sim = fresh();
        let (grid, model) = (sim.grid().expect("hexahedral"), sim.model().expect("hexahedral"));
        let options = SurfaceOptions::default();
        // Surfaces and models built, not cloned: a clone has no room to grow, and its first cut
        // would pay for moving every vertex, triangle or element.
        let body = || {
            let surface = Surface::extract(grid.fine(), grid.spacing(), &options);
            Body {
                field: HexForceField::new(model, Formulation::Corotational),
                state: State::at_rest(model),
                organ: OrganSurface::voxels(grid, model, &options, 0),
                mapping: SurfaceMapping::embed(&surface, grid, &|g| g),
                surface,
                grid: grid.clone(),
                model: HexModel::from_grid(grid),
            }
        };
        let voxels = stroke(grid, 500);
        let edit = |v: &[u32]| {
            let mut remove_voxels = v.to_vec();
            remove_voxels.sort_unstable();
            GridEdit { remove_voxels, sever_links: Vec::new() }
        };
        let mut cases: Vec<(String, Vec<GridEdit>, usize)> = [1, 5, 20]
            .into_iter()
            .map(|k| {
                let edits: Vec<GridEdit> = voxels.chunks(k).take(40).map(edit).collect();
                (format!("{k} voxels ×{}", edits.len()), edits, repeat)
            })
            .collect();
        cases.push((format!("{} voxels, one edit", voxels.len()), vec![edit(&voxels)], repeat + 2));
        for (name, edits, repeat) in cases {
            let (parts, whole) =
                measure(&body, (!parts_only).then_some(&fresh), &edits, repeat, &mut evict);
            print!(
                "| {} | {} | {} | {name} |",
                grid.fine().voxel_count(),
                model.elements.len(),
                model.node_count()
            );
            for t in parts {
                print!(" {t:.1} |");
            }
            println!(" {whole:.1} |");
        }
    }
    Ok(())
}
