//! Helpers shared by the surface tests: grids of small volumes, the closed-manifold check, and
//! the comparison of a re-meshed surface with a fresh extraction.

#![allow(dead_code)] // each test file uses its own subset

use incise_grid::{BranchedGrid, GridEdit, LabelVolume, Material, MaterialTable};
use incise_mesh::topology::{check_closed, check_manifold};
use incise_surface::{Surface, SurfaceChanges, SurfaceOptions};
use std::collections::BTreeSet;

/// Voxel edge length of the test volumes (m).
pub const H: f64 = 1e-3;

/// A grid at `level` over `volume`, every label `1..=labels` a material of liver stiffness.
pub fn grid_of(volume: &LabelVolume, labels: u16, level: u32) -> BranchedGrid {
    let l: Vec<u16> = (1..=labels).collect();
    BranchedGrid::build(volume, &MaterialTable::uniform(&l, Material::liver()), level).unwrap()
}

/// A full box of `dims` voxels, label 1, or label 2 from `x = split` on when `split` is given.
pub fn block(dims: [usize; 3], split: Option<usize>) -> LabelVolume {
    incise_grid::procedural::from_fn(dims, [H; 3], |x, _, _| match split {
        Some(s) if x as usize >= s => 2,
        _ => 1,
    })
}

/// `Ok` when the live triangles form a closed, consistently oriented 2-manifold (every edge in
/// exactly two triangles, used once each way; every vertex's triangles one fan) and the live
/// vertices are exactly those the triangles use.
pub fn check_surface(s: &Surface) -> Result<(), String> {
    let tris = s.triangle_list();
    check_closed(&tris).map_err(|e| format!("edge {e:?} is not matched by its reverse"))?;
    check_manifold(&tris)?;
    let used: BTreeSet<u32> = tris.iter().flatten().copied().collect();
    let live: BTreeSet<u32> =
        s.vertices().iter().enumerate().filter(|(_, v)| v.alive).map(|(i, _)| i as u32).collect();
    if used != live {
        return Err(format!("{} vertices used, {} live", used.len(), live.len()));
    }
    if s.vertex_count() != live.len() || s.triangle_count() != tris.len() {
        return Err("live counts disagree with the slots".into());
    }
    for t in &tris {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return Err(format!("triangle {t:?} repeats a vertex"));
        }
    }
    Ok(())
}

/// The voxels whose cubes an edit touches: removed voxels and both ends of severed links.
pub fn touched(edit: &GridEdit) -> Vec<u32> {
    let mut t = edit.remove_voxels.clone();
    for &(a, b) in &edit.sever_links {
        t.extend([a, b]);
    }
    t
}

/// Applies `edit` to the grid and re-meshes `surface` locally.
pub fn cut(grid: &mut BranchedGrid, surface: &mut Surface, edit: &GridEdit) -> SurfaceChanges {
    grid.apply(edit).unwrap();
    surface.remesh(grid.fine(), &touched(edit))
}

/// `Ok` when `surface` has the same triangles as a fresh extraction of the grid's fine level.
pub fn matches_full(
    surface: &Surface,
    grid: &BranchedGrid,
    options: &SurfaceOptions,
) -> Result<(), String> {
    let full = Surface::extract(grid.fine(), grid.spacing(), options);
    let (a, b) = (surface.canonical_triangles(), full.canonical_triangles());
    if a == b {
        return Ok(());
    }
    let only_local = a.iter().find(|t| b.binary_search(t).is_err());
    let only_full = b.iter().find(|t| a.binary_search(t).is_err());
    Err(format!(
        "local {} triangles, full {}; only local: {only_local:?}; only full: {only_full:?}",
        a.len(),
        b.len()
    ))
}

/// Linear index of voxel `(x, y, z)` in a volume of `dims`.
pub fn voxel(dims: [u32; 3], x: u32, y: u32, z: u32) -> u32 {
    x + dims[0] * (y + dims[1] * z)
}

/// A small deterministic generator (xorshift64*), so tests need no seed files.
pub struct Rng(u64);

impl Rng {
    /// Seeded (zero is replaced: xorshift has no zero state).
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `0..n`.
    pub fn below(&mut self, n: u32) -> u32 {
        (self.next_u64() % u64::from(n)) as u32
    }

    /// Uniform in `[-1, 1)`.
    pub fn signed(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A face-connected cluster of up to `size` voxels grown at random from `centre`.
pub fn cluster(dims: [u32; 3], centre: u32, size: usize, rng: &mut Rng) -> Vec<u32> {
    let mut set = vec![centre];
    let count: u32 = dims.iter().product();
    for _ in 0..8 * size {
        if set.len() >= size {
            break;
        }
        let v = set[rng.below(set.len() as u32) as usize];
        if let Some(n) = neighbour(dims, v, rng.below(6))
            && n < count
            && !set.contains(&n)
        {
            set.push(n);
        }
    }
    set
}

/// The face neighbour of `v` in direction `dir` (`2·axis + [negative]`), if inside the volume.
pub fn neighbour(dims: [u32; 3], v: u32, dir: u32) -> Option<u32> {
    let mut c = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
    let a = (dir / 2) as usize;
    if dir.is_multiple_of(2) {
        c[a] += 1;
        (c[a] < dims[a]).then(|| voxel(dims, c[0], c[1], c[2]))
    } else {
        (c[a] > 0).then(|| {
            c[a] -= 1;
            voxel(dims, c[0], c[1], c[2])
        })
    }
}
