//! Shared helpers of the grid tests: random volumes and an independent brute-force reference of
//! the branched topology, written for clarity rather than speed.

#![allow(dead_code)]

use incise_grid::canonical::{CanonicalElement, CanonicalLevel};
use incise_grid::{BranchedGrid, GridEdit, LabelVolume, Material, MaterialTable};
use std::collections::BTreeMap;

/// Proptest cases: `n` by default, `INCISE_PROPTEST_CASES` to hunt harder (e.g. 5000 in release).
pub fn cases(n: u32) -> u32 {
    std::env::var("INCISE_PROPTEST_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(n)
}

/// xorshift64*: a tiny deterministic generator so a proptest case is (dims, density, seed).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A random volume: each voxel holds material with probability `density`; with `materials > 1`
/// labels come in blobs (a label per 2×2×2 block, then a few single-voxel changes) so both full
/// single-material sub-blocks and interleaving occur.
pub fn random_volume(dims: [usize; 3], density: f64, materials: u16, seed: u64) -> LabelVolume {
    let mut rng = Rng(seed | 1);
    let n = dims[0] * dims[1] * dims[2];
    let block_label: Vec<u16> =
        (0..n).map(|_| 1 + rng.below(u64::from(materials)) as u16).collect();
    let mut labels = vec![0u16; n];
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let i = x + dims[0] * (y + dims[1] * z);
                if rng.unit() < density {
                    let b = (x / 2) + dims[0] * ((y / 2) + dims[1] * (z / 2));
                    labels[i] = if rng.unit() < 0.1 {
                        1 + rng.below(u64::from(materials)) as u16
                    } else {
                        block_label[b]
                    };
                }
            }
        }
    }
    if labels.iter().all(|&l| l == 0) {
        labels[0] = 1;
    }
    LabelVolume::new(dims, [1e-3, 1.5e-3, 2e-3], labels).unwrap()
}

/// Materials 1..=k with different stiffness, Poisson ratio and density.
pub fn materials(k: u16) -> MaterialTable {
    let mut t = MaterialTable::new();
    for l in 1..=k {
        let f = f64::from(l);
        t.insert(l, Material::new(1e3 * f * f, 0.25 + 0.05 * f, 900.0 + 100.0 * f));
    }
    t
}

/// The fine graph: material and intact links, straight from the grid's fine level.
pub fn fine_neighbors(grid: &BranchedGrid, v: u32) -> Vec<u32> {
    let fine = grid.fine();
    let d = fine.dims();
    let (x, y, z) = (v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1]));
    let mut out = Vec::new();
    let mut consider = |u: u32| {
        if fine.material(u).is_some() && !fine.is_severed(v, u) {
            out.push(u);
        }
    };
    if x + 1 < d[0] {
        consider(v + 1);
    }
    if x > 0 {
        consider(v - 1);
    }
    if y + 1 < d[1] {
        consider(v + d[0]);
    }
    if y > 0 {
        consider(v - d[0]);
    }
    if z + 1 < d[2] {
        consider(v + d[0] * d[1]);
    }
    if z > 0 {
        consider(v - d[0] * d[1]);
    }
    out
}

/// Brute-force level `l`: elements are connected components of the fine graph restricted to each
/// level-`l` cell (flood fill over voxels, no hierarchy), neighbours are components joined by a
/// fine link, nodes are classes of elements at a grid point joined by neighbour relations.
/// Children are left empty (they name the level below).
pub fn reference_level(grid: &BranchedGrid, l: u32) -> CanonicalLevel {
    let fine = grid.fine();
    let d = fine.dims();
    let cd = d.map(|x| x.div_ceil(1 << l));
    let n = d[0] * d[1] * d[2];
    let cell_of = |v: u32| {
        let (x, y, z) = (v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1]));
        (x >> l) + cd[0] * ((y >> l) + cd[1] * (z >> l))
    };
    // comp[v] = smallest voxel of v's component within its cell.
    let mut comp = vec![u32::MAX; n as usize];
    for v in 0..n {
        if fine.material(v).is_none() || comp[v as usize] != u32::MAX {
            continue;
        }
        let mut stack = vec![v];
        let mut members = vec![v];
        comp[v as usize] = v;
        while let Some(u) = stack.pop() {
            for w in fine_neighbors(grid, u) {
                if cell_of(w) == cell_of(v) && comp[w as usize] == u32::MAX {
                    comp[w as usize] = v;
                    stack.push(w);
                    members.push(w);
                }
            }
        }
    }
    let mut elems: BTreeMap<u32, (u32, u32, Vec<u32>)> = BTreeMap::new(); // key → (cell, count, nbrs)
    for v in 0..n {
        if comp[v as usize] == u32::MAX {
            continue;
        }
        let key = comp[v as usize];
        let entry = elems.entry(key).or_insert((cell_of(v), 0, Vec::new()));
        entry.1 += 1;
        for w in fine_neighbors(grid, v) {
            if comp[w as usize] != key {
                entry.2.push(comp[w as usize]);
            }
        }
    }
    for e in elems.values_mut() {
        e.2.sort_unstable();
        e.2.dedup();
    }
    // Nodes: per grid point, union-find over the elements of the ≤ 8 cells around it.
    let pd = cd.map(|x| x + 1);
    let mut cell_elems: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for (&k, e) in &elems {
        cell_elems.entry(e.0).or_default().push(k);
    }
    let mut node_of: BTreeMap<(u32, u32), (u32, u32)> = BTreeMap::new(); // (elem, corner) → (point, class key)
    let mut node_count = 0;
    for pz in 0..pd[2] {
        for py in 0..pd[1] {
            for px in 0..pd[0] {
                let p = px + pd[0] * (py + pd[1] * pz);
                let mut around: Vec<(u32, usize)> = Vec::new();
                for corner in 0..8usize {
                    let b = [(corner & 1) as u32, ((corner >> 1) & 1) as u32, (corner >> 2) as u32];
                    let c = [px.wrapping_sub(b[0]), py.wrapping_sub(b[1]), pz.wrapping_sub(b[2])];
                    if (0..3).any(|a| c[a] >= cd[a]) {
                        continue;
                    }
                    let cell = c[0] + cd[0] * (c[1] + cd[1] * c[2]);
                    for &e in cell_elems.get(&cell).map_or(&[][..], |v| &v[..]) {
                        around.push((e, corner));
                    }
                }
                // Classes by repeated merging until stable.
                let mut class: Vec<u32> = around.iter().map(|&(e, _)| e).collect();
                loop {
                    let mut changed = false;
                    for i in 0..around.len() {
                        for j in 0..around.len() {
                            if elems[&around[i].0].2.contains(&around[j].0) && class[i] != class[j]
                            {
                                let m = class[i].min(class[j]);
                                let (ci, cj) = (class[i], class[j]);
                                for c in &mut class {
                                    if *c == ci || *c == cj {
                                        *c = m;
                                    }
                                }
                                changed = true;
                            }
                        }
                    }
                    if !changed {
                        break;
                    }
                }
                let mut distinct = class.clone();
                distinct.sort_unstable();
                distinct.dedup();
                node_count += distinct.len();
                for (i, &(e, corner)) in around.iter().enumerate() {
                    node_of.insert((e, corner as u32), (p, class[i]));
                }
            }
        }
    }
    let elements = elems
        .iter()
        .map(|(&key, (cell, count, nbrs))| CanonicalElement {
            key,
            cell: *cell,
            voxel_count: *count,
            children: Vec::new(),
            neighbors: nbrs.clone(),
            nodes: std::array::from_fn(|c| node_of[&(key, c as u32)]),
        })
        .collect();
    CanonicalLevel { level: l, elements, node_count }
}

/// The grid's canonical level `index` with children dropped, to compare with [`reference_level`].
pub fn without_children(mut c: CanonicalLevel) -> CanonicalLevel {
    for e in &mut c.elements {
        e.children.clear();
    }
    c
}

/// A random edit: some voxels removed, some links severed (most of them between material voxels).
pub fn random_edit(grid: &BranchedGrid, rng: &mut Rng, removals: usize, severs: usize) -> GridEdit {
    let d = grid.fine().dims();
    let n = u64::from(d[0] * d[1] * d[2]);
    let mut edit = GridEdit::default();
    for _ in 0..removals {
        edit.remove_voxels.push(rng.below(n) as u32);
    }
    for _ in 0..severs {
        let v = rng.below(n) as u32;
        let (x, y, z) = (v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1]));
        let axis = rng.below(3);
        let (ok, u) = match axis {
            0 => (x + 1 < d[0], v + 1),
            1 => (y + 1 < d[1], v + d[0]),
            _ => (z + 1 < d[2], v + d[0] * d[1]),
        };
        if ok {
            edit.sever_links.push(if rng.below(2) == 0 { (v, u) } else { (u, v) });
        }
    }
    edit
}
