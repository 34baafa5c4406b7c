//! Composite coarse elements, after Nesme, Kry, Jeřábková, Faure 2009 (*Preserving topology and
//! elasticity for embedded deformable models*): a coarse element's stiffness from a static
//! condensation of what it holds, instead of the Galerkin product `Hᵀ K H` of eq. 1–4.
//!
//! Condensation with the trilinear `H` makes every voxel of a cell follow one trilinear field. A
//! cell holding a thin neck beside bulk tissue then strains the bulk whenever the neck bends,
//! which is why a coarse liver hangs far less than its voxels do (the 13,648-voxel liver's centre
//! of mass moves 42 % less at level 2 than at level 0, `tests/tests/nesme.rs`).
//!
//! Here, level by level (8 → 1, like the recursive scheme of eq. 1), each parent cell's 3 × 3 × 3
//! points are split in two:
//! - a point some element outside the parent also uses follows the trilinear field of the
//!   parent's corners, so neighbouring elements still agree on their common faces (the model
//!   stays conforming: never softer than the voxels, never stiffer than the Galerkin one);
//! - every other point (the cell's centre, and points on the organ's surface that only this
//!   element holds) takes the displacement of least energy for the given corners.
//!
//! The parent's stiffness is the Schur complement onto the corners. A point where superimposed
//! children meet without sharing a node is two points. Masses stay the condensed ones, so both
//! models carry the same load.
//!
//! Whether a point is shared depends on the cells around it, so a cut changes cells it did not
//! touch, but only next to the ones it did: [`CompositeLevels`] keeps every level's matrices, and
//! after an edit looks again, at level 1, at the cells whose 4 × 4 × 4 voxel block holds a changed
//! voxel and, above, at the cells within one cell of a changed voxel's cell.

use crate::grid::BranchedGrid;
use crate::hex8::{Mat24, corner};
use crate::topology::{Level, coords};
use std::collections::HashMap;
use std::sync::Arc;

/// The Galerkin stiffness's share in [`composite_stiffness`], `K = (1 − s) K_composite + s K_H`.
/// A corner that no material of its element touches gets no composite stiffness; under a load
/// spread through the trilinear shape functions (gravity on the condensed mass, a surface pull)
/// it sags far and drags the field sampled near it. On the 13,648-voxel liver at level 1
/// (`tests/tests/nesme.rs`, surface pull) a share of 1 % left the RMS error at 51 %, worse than
/// the condensed model's 25.7 %; 5 % brings it to 23.3 %. The centre of mass beats the condensed
/// model at every level with either.
pub const GALERKIN_SHARE: f64 = 5e-2;

/// A pivot below this fraction of its diagonal entry marks a direction the free points can move
/// in without energy (a child hanging from one corner turning about it).
const NULL_PIVOT: f64 = 1e-11;

/// One child placed in its parent's cell: its stiffness and, per corner, the point's key (equal
/// keys are one point), its lattice position `x + 3y + 9z` in the 3 × 3 × 3 points, and whether
/// the point belongs to this parent alone (no element outside it uses it).
struct Placed<'a> {
    stiffness: &'a Mat24,
    keys: [u64; 8],
    lattice: [u8; 8],
    private: [bool; 8],
}

/// Which octant of its parent cell (bit `a` set: the upper half along axis `a`) the cell or
/// voxel at coordinates `c` of the level below is.
fn octant(c: [u32; 3]) -> u8 {
    ((c[0] & 1) | (c[1] & 1) << 1 | (c[2] & 1) << 2) as u8
}

/// The lattice positions of a child's corners when the child sits in octant `o` of its parent.
fn lattice_of(o: [u32; 3]) -> [u8; 8] {
    std::array::from_fn(|c| {
        let b = corner(c);
        ((o[0] as usize + b[0]) + 3 * (o[1] as usize + b[1]) + 9 * (o[2] as usize + b[2])) as u8
    })
}

/// The parent's corners that lattice point `p` follows, with their trilinear weights: one at a
/// corner, two on an edge, four on a face, eight at the centre. Every weight is a power of two,
/// and so is any product of them: scaling by one rounds nothing.
#[derive(Clone, Copy)]
struct Weights {
    len: usize,
    corner: [u8; 8],
    weight: [f64; 8],
}

fn weights(p: u8) -> Weights {
    // Per axis, the parent corners (0 or 1 along it) at lattice coordinate 0, 1, 2.
    let axis = |q: u8| -> &'static [(u8, f64)] {
        match q {
            0 => &[(0, 1.0)],
            1 => &[(0, 0.5), (1, 0.5)],
            _ => &[(1, 1.0)],
        }
    };
    let mut w = Weights { len: 0, corner: [0; 8], weight: [0.0; 8] };
    for &(bz, wz) in axis(p / 9) {
        for &(by, wy) in axis((p / 3) % 3) {
            for &(bx, wx) in axis(p % 3) {
                w.corner[w.len] = bx | by << 1 | bz << 2;
                w.weight[w.len] = wx * wy * wz;
                w.len += 1;
            }
        }
    }
    w
}

/// `acc` (24 columns, row-major) block `(m, n)` += `s` times the 3 × 3 block `(a, b)` of `k`.
#[inline]
fn add_block(acc: &mut [f64], row: usize, col: usize, s: f64, k: &Mat24, a: usize, b: usize) {
    for i in 0..3 {
        let src = &k.0[(3 * a + i) * 24 + 3 * b..][..3];
        let dst = &mut acc[(row + i) * 24 + col..][..3];
        for (d, x) in dst.iter_mut().zip(src) {
            *d += s * x;
        }
    }
}

/// The parent's stiffness from its children's: every point the parent shares with another
/// element follows the trilinear field of the parent's corners (so neighbours still agree on
/// their common faces), every other point takes the displacement of least energy, and the result
/// is the Schur complement `K = Tᵀ K_bb T − (K_fb T)ᵀ K_ff⁺ (K_fb T)` with `T` the trilinear
/// weights of the bound points.
fn condense_onto_corners(children: &[Placed<'_>]) -> Mat24 {
    // Local points, in order of first appearance: key, free index (`usize::MAX` when bound).
    let mut points: Vec<(u64, usize)> = Vec::with_capacity(27);
    let mut nf = 0;
    let placed: Vec<[usize; 8]> = children
        .iter()
        .map(|ch| {
            std::array::from_fn(|c| {
                let key = ch.keys[c];
                if let Some(i) = points.iter().position(|&(k, _)| k == key) {
                    return i;
                }
                let p = ch.lattice[c];
                let at_corner = [p % 3, (p / 3) % 3, p / 9].iter().all(|&q| q != 1);
                let free = if !at_corner && (p == 13 || ch.private[c]) {
                    nf += 1;
                    nf - 1
                } else {
                    usize::MAX
                };
                points.push((key, free));
                points.len() - 1
            })
        })
        .collect();
    let nfd = 3 * nf;
    // Tᵀ K_bb T = A + Aᵀ, A summing each pair (a, b ≥ a) of a child's bound corners once, the
    // pair of a corner with itself at half weight: the block (b, a) of a child's stiffness is
    // the transpose of (a, b) (every stiffness here is symmetric), so half the products do.
    let mut half = [0.0; 576];
    let mut kfb = vec![0.0; nfd * 24];
    let mut kff = vec![0.0; nfd * nfd];
    for (ch, map) in children.iter().zip(&placed) {
        let k = ch.stiffness;
        let free: [usize; 8] = map.map(|i| points[i].1);
        let w: [Weights; 8] = std::array::from_fn(|c| weights(ch.lattice[c]));
        for a in 0..8 {
            if free[a] != usize::MAX {
                // A free point's rows: K_fb T and K_ff.
                let fa = free[a];
                for b in 0..8 {
                    if free[b] == usize::MAX {
                        let wb = &w[b];
                        for (&n, &s) in wb.corner[..wb.len].iter().zip(&wb.weight) {
                            add_block(&mut kfb, 3 * fa, 3 * usize::from(n), s, k, a, b);
                        }
                    } else {
                        for i in 0..3 {
                            let src = &k.0[(3 * a + i) * 24 + 3 * b..][..3];
                            let dst = &mut kff[(3 * fa + i) * nfd + 3 * free[b]..][..3];
                            for (d, x) in dst.iter_mut().zip(src) {
                                *d += x;
                            }
                        }
                    }
                }
                continue;
            }
            let wa = &w[a];
            for b in a..8 {
                if free[b] != usize::MAX {
                    continue;
                }
                let wb = &w[b];
                let pair = if a == b { 0.5 } else { 1.0 };
                for (&m, &v) in wa.corner[..wa.len].iter().zip(&wa.weight) {
                    for (&n, &s) in wb.corner[..wb.len].iter().zip(&wb.weight) {
                        let (m, n) = (3 * usize::from(m), 3 * usize::from(n));
                        add_block(&mut half, m, n, pair * v * s, k, a, b);
                    }
                }
            }
        }
    }
    let mut kbb = Mat24([0.0; 576]);
    for i in 0..24 {
        for j in 0..24 {
            kbb.0[i * 24 + j] = half[i * 24 + j] + half[j * 24 + i];
        }
    }
    // A piece hanging from one point turning about it is a zero-energy direction of the free
    // points: `schur::complement` drops it.
    crate::schur::complement(&kbb, kff, kfb, NULL_PIVOT)
}

/// The composite stiffness of every top-level element of `grid` (indexed by element id), plus
/// [`GALERKIN_SHARE`] of its condensed stiffness. At level 0 it is the condensed stiffness.
///
/// # Panics
/// Only on a broken grid invariant (a live element with a dead child).
#[must_use]
pub fn composite_stiffness(grid: &BranchedGrid) -> Vec<Option<Mat24>> {
    CompositeLevels::new(grid).1
}

/// Every level's composite stiffness by element id, kept beside a model so that after a cut only
/// the cells near it are condensed again ([`CompositeLevels::update`]). Cells full of one
/// material at level 1 share one matrix.
#[derive(Clone, Debug, Default)]
pub struct CompositeLevels {
    /// `levels[i][id]`: element `id` of grid level `i + 1` (of level 0 when the grid has only
    /// that), before the Galerkin share is mixed in.
    levels: Vec<Vec<Option<Arc<Mat24>>>>,
    /// `inputs[i][id]`: what element `id` of level `i + 1` was condensed from (levels 2 and up),
    /// so that an update near a cut condenses again only the cells whose inputs changed.
    inputs: Vec<Vec<Option<Box<[ChildInput]>>>>,
    /// Level-1 stiffness by (materials of the cell's 8 voxels, private points): most cells are
    /// full or hold one of a few patterns, and a cut meets the same patterns again.
    level1: HashMap<([u16; 8], u32), Arc<Mat24>>,
    /// `uses[i][n]`: how many elements of level `i + 1` use node `n`, as of the last pass. A
    /// cell whose children and their nodes are as before has the same private points when
    /// these counts are too, which is cheaper to see than the points themselves.
    uses: Vec<Vec<u32>>,
    /// `cells[i][c]`: the elements of level `i + 1` in cell `c`, and `nodes[i][id]` element
    /// `id`'s nodes, as of the last pass: an update finds the elements gone and brings `uses` up
    /// to date from the cells near the cut alone.
    cells: Vec<Vec<Vec<u32>>>,
    nodes: Vec<Vec<[u32; 8]>>,
    /// Scratch of the update of `uses`: all false between passes.
    seen: Vec<bool>,
    /// Per level, whether the grid kept its nodes current at the last pass: a level that starts
    /// to between two passes has its nodes numbered afresh, so it is counted afresh.
    tracked: Vec<bool>,
}

/// Past this many level-1 patterns the cache starts again (each holds a 4.6 KB matrix).
const LEVEL1_PATTERNS: usize = 4096;

/// One child as a parent's condensation sees it, besides its stiffness: which element it is,
/// where it sits, its corners' nodes (equal nodes are one point) and which corners are private
/// (bit `c`). Equal inputs and unchanged children's stiffnesses give the same parent, bit for bit.
#[derive(Clone, Debug, PartialEq, Eq)]
struct ChildInput {
    child: u32,
    octant: u8,
    nodes: [u32; 8],
    private: u8,
}

/// True when `a` and `b` hold the same bits (a `-0.0` against a `0.0` differs).
fn same_bits(a: &Mat24, b: &Mat24) -> bool {
    a.0.iter().zip(&b.0).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The cells of every level (index 0: level 1) an update looks at.
#[derive(Default)]
struct Near {
    /// Sorted: the cells whose elements are condensed again if their inputs changed.
    examine: Vec<Vec<u32>>,
    /// Sorted: the cells within one cell of one holding a dirty voxel, the only ones where an
    /// element can have appeared, vanished or changed its nodes.
    region: Vec<Vec<u32>>,
}

/// Appends the cells of the box `lo..=hi` (cell coordinates, inclusive) of a level with
/// `dims` cells per axis.
fn push_cells(out: &mut Vec<u32>, lo: [u32; 3], hi: [u32; 3], dims: [u32; 3]) {
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            for x in lo[0]..=hi[0] {
                out.push(x + dims[0] * (y + dims[1] * z));
            }
        }
    }
}

impl CompositeLevels {
    /// The levels of `grid` and [`composite_stiffness`] of it.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element with a dead child).
    #[must_use]
    pub fn new(grid: &BranchedGrid) -> (Self, Vec<Option<Mat24>>) {
        let mut cache = Self::default();
        cache.pass(grid, None);
        let full = cache.stiffness(grid);
        (cache, full)
    }

    /// Brings the levels up to date with `grid` after an edit that removed voxels or severed
    /// links at `dirty_voxels` (both ends of a link), `self` being the levels of the grid before
    /// it. Returns the top-level elements whose stiffness was made again, with it (plus
    /// [`GALERKIN_SHARE`] of the condensed stiffness), in id order; the others keep theirs.
    ///
    /// A cell's composite stiffness depends on its children's stiffnesses and on which of its
    /// points elements outside it use. A level-1 cell is made from the voxels of its 4 × 4 × 4
    /// block (its own and the ring around it), so the level-1 cells whose block holds a dirty
    /// voxel are looked at again. Above, a change reaches a cell's nodes and, through the points
    /// on its faces, the cells next to it, so the cells within one cell of a dirty voxel's cell
    /// are. Of those, a cell is condensed again only when what it is condensed from changed (a
    /// child's stiffness, its children, their nodes, which of its points are private; the last
    /// is worked out only when the users of its children's nodes changed), and it counts as
    /// changed for the level above only when its stiffness did. Only elements whose stiffness
    /// changed are returned: the caller takes [`CompositeLevels::top`] for others it needs (those
    /// the grid condensed again). The result equals [`CompositeLevels::new`] of the edited grid,
    /// bit for bit (a proptest checks it).
    ///
    /// # Panics
    /// On a broken grid invariant (a live element with a dead child), or when `self` does not
    /// come from [`CompositeLevels::new`] of this grid's lineage (a default value, say).
    pub fn update(&mut self, grid: &BranchedGrid, dirty_voxels: &[u32]) -> Vec<(u32, Mat24)> {
        let dims = grid.fine().dims();
        let dirty: Vec<[u32; 3]> = dirty_voxels.iter().map(|&v| coords(v, dims)).collect();
        let mut near = Near::default();
        for lvl in grid.levels() {
            let cd = lvl.cell_dims();
            let mut examine = Vec::new();
            let mut region = Vec::new();
            let mut dirty_cells: Vec<[u32; 3]> =
                dirty.iter().map(|v| v.map(|x| x >> lvl.level())).collect();
            dirty_cells.sort_unstable();
            dirty_cells.dedup();
            for c in dirty_cells {
                let lo = c.map(|x| x.saturating_sub(1));
                let hi = std::array::from_fn(|a| (c[a] + 1).min(cd[a] - 1));
                push_cells(&mut region, lo, hi, cd);
            }
            region.sort_unstable();
            region.dedup();
            if lvl.level() == 1 {
                // A level-1 cell is made from the voxels of its 4 × 4 × 4 block (its own and the
                // ring around it): cells `c` with `2c − 1 ≤ v ≤ 2c + 2`.
                for v in &dirty {
                    let lo = v.map(|x| x.saturating_sub(2).div_ceil(2));
                    let hi = std::array::from_fn(|a| v[a].div_ceil(2).min(cd[a] - 1));
                    push_cells(&mut examine, lo, hi, cd);
                }
                examine.sort_unstable();
                examine.dedup();
            } else {
                examine.clone_from(&region);
            }
            near.examine.push(examine);
            near.region.push(region);
        }
        let ids = self.pass(grid, Some(&near));
        self.top(grid, &ids)
    }

    /// Every live top-level element's stiffness (by id), the Galerkin share mixed in: what
    /// [`composite_stiffness`] gives for the grid these levels are of.
    #[must_use]
    pub fn stiffness(&self, grid: &BranchedGrid) -> Vec<Option<Mat24>> {
        let mut full = vec![None; grid.top().element_capacity()];
        for (id, k) in self.top(grid, &Self::top_ids(grid)) {
            full[id as usize] = Some(k);
        }
        full
    }

    /// Every live top-level element's id.
    fn top_ids(grid: &BranchedGrid) -> Vec<u32> {
        grid.top().elements().map(|(id, _)| id).collect()
    }

    /// The stiffness of top-level elements `ids` (live ones), the Galerkin share mixed in: the
    /// matrices [`CompositeLevels::stiffness`] gives them.
    ///
    /// # Panics
    /// If an element of `ids` is not live.
    #[must_use]
    pub fn top(&self, grid: &BranchedGrid, ids: &[u32]) -> Vec<(u32, Mat24)> {
        let top = self.levels.last().expect("at least one level");
        ids.iter()
            .map(|&id| {
                let mut k = top[id as usize].as_deref().expect("live element").clone();
                if grid.top_level() > 0 {
                    let m = grid.matrices(id).expect("live element has matrices");
                    for (a, g) in k.0.iter_mut().zip(&m.stiffness.0) {
                        *a = (1.0 - GALERKIN_SHARE) * *a + GALERKIN_SHARE * g;
                    }
                }
                (id, k)
            })
            .collect()
    }

    /// Brings `uses`, `cells` and `nodes` of one level (as [`CompositeLevels`] keeps them) up
    /// to date with `lvl`: from the cells of `region` alone when given, every element
    /// otherwise. Returns the nodes whose number of users changed, sorted (`None` without
    /// `region`).
    fn count_users(
        uses: &mut Vec<u32>,
        cells: &mut Vec<Vec<u32>>,
        nodes: &mut Vec<[u32; 8]>,
        seen: &mut Vec<bool>,
        lvl: &Level,
        region: Option<&[u32]>,
    ) -> Option<Vec<u32>> {
        // Never shorter (a level's capacities do not shrink, and a full count zeroes it anyway).
        uses.resize(uses.len().max(lvl.node_capacity()), 0);
        nodes.resize(nodes.len().max(lvl.element_capacity()), [0; 8]);
        let Some(region) = region else {
            uses.fill(0);
            cells.clear();
            cells.resize(lvl.cell_dims().iter().product::<u32>() as usize, Vec::new());
            for (id, e) in lvl.elements() {
                for n in e.nodes {
                    uses[n as usize] += 1;
                }
                nodes[id as usize] = e.nodes;
                cells[e.cell as usize].push(id);
            }
            return None;
        };
        // The elements of the region as the last pass left them leave, those there now come
        // in; `before` keeps each node's count before its first change (`seen` marks those).
        let mut before: Vec<(u32, u32)> = Vec::new();
        seen.resize(seen.len().max(uses.len()), false);
        let mut note = |n: u32, count: u32| {
            if !std::mem::replace(&mut seen[n as usize], true) {
                before.push((n, count));
            }
        };
        for &cell in region {
            for &id in &cells[cell as usize] {
                for n in nodes[id as usize] {
                    note(n, uses[n as usize]);
                    uses[n as usize] -= 1;
                }
            }
        }
        for &cell in region {
            let now = lvl.cell_elements(cell);
            for &id in now {
                let e = lvl.element(id).expect("a cell's elements are live");
                for n in e.nodes {
                    note(n, uses[n as usize]);
                    uses[n as usize] += 1;
                }
                nodes[id as usize] = e.nodes;
            }
            cells[cell as usize].clear();
            cells[cell as usize].extend_from_slice(now);
        }
        let mut moved = Vec::new();
        for (n, was) in before {
            seen[n as usize] = false;
            if uses[n as usize] != was {
                moved.push(n);
            }
        }
        moved.sort_unstable();
        Some(moved)
    }

    /// Condenses the elements of every level in the cells `near` examines whose inputs changed
    /// (all of them without `near`), from the level below's; returns the top-level elements whose
    /// stiffness changed (every one without `near`), in id order.
    fn pass(&mut self, grid: &BranchedGrid, near: Option<&Near>) -> Vec<u32> {
        let levels = grid.levels();
        self.levels.resize(levels.len(), Vec::new());
        self.inputs.resize(levels.len(), Vec::new());
        self.uses.resize(levels.len(), Vec::new());
        self.cells.resize(levels.len(), Vec::new());
        self.nodes.resize(levels.len(), Vec::new());
        self.tracked.resize(levels.len(), false);
        if grid.top_level() == 0 {
            let top = grid.top();
            let here = &mut self.levels[0];
            here.clear();
            here.resize(top.element_capacity(), None);
            for (id, _) in top.elements() {
                let k = grid.matrices(id).expect("live element has matrices").stiffness.clone();
                here[id as usize] = Some(Arc::new(k));
            }
            return Self::top_ids(grid);
        }
        let fine = grid.fine();
        let dims = fine.dims();
        let tables = grid.tables();
        if self.level1.len() > LEVEL1_PATTERNS {
            self.level1.clear();
        }
        let level1 = &mut self.level1;
        let mut child_level: Option<std::borrow::Cow<'_, crate::topology::Level>> = None;
        // Nodes of the level below whose number of users changed in this pass, sorted; `None`
        // when any may have (a pass from scratch, or a level whose nodes are numbered afresh).
        let mut users_changed: Option<Vec<u32>> = None;
        // Elements of the level below (then of this one) whose stiffness changed in this pass.
        let mut changed_below: Vec<bool> = Vec::new();
        let mut made = Vec::new();
        // Scratch of a cell's inputs: its children's corner nodes, and what it is condensed from.
        let mut mine: Vec<u32> = Vec::new();
        let mut input: Vec<ChildInput> = Vec::new();
        for (li, lvl) in levels.iter().enumerate() {
            let lvl = lvl.with_nodes();
            let (done, rest) = self.levels.split_at_mut(li);
            let here = &mut rest[0];
            let below = done.last();
            let inputs = &mut self.inputs[li];
            here.resize(lvl.element_capacity(), None);
            inputs.resize(lvl.element_capacity(), None);
            // Forget the elements gone since the last pass, so that an id used again in a later
            // pass does not meet what its former element was condensed from. (An id gone and
            // used again within this edit keeps its slot: its inputs are compared by value.)
            let gone = |id: u32| lvl.element(id).is_none();
            match near {
                None => {
                    for id in (0..here.len() as u32).filter(|&id| gone(id)) {
                        (here[id as usize], inputs[id as usize]) = (None, None);
                    }
                }
                Some(near) => {
                    for &cell in &near.region[li] {
                        for &id in self.cells[li].get(cell as usize).into_iter().flatten() {
                            if gone(id) {
                                (here[id as usize], inputs[id as usize]) = (None, None);
                            }
                        }
                    }
                }
            }
            // The level below's node users (restored below).
            let uses = if li > 0 { std::mem::take(&mut self.uses[li - 1]) } else { Vec::new() };
            let mut changed = vec![false; lvl.element_capacity()];
            made.clear();
            let ids: Vec<u32> = match near {
                None => lvl.elements().map(|(id, _)| id).collect(),
                Some(near) => near.examine[li]
                    .iter()
                    .flat_map(|&cell| lvl.cell_elements(cell).iter().copied())
                    .collect(),
            };
            for id in ids {
                let e = lvl.element(id).expect("a cell's elements are live");
                let k = if li == 0 {
                    let mut pattern = [0u16; 8];
                    for &v in &e.children {
                        let c = coords(v, dims);
                        pattern[usize::from(octant(c))] = fine.material(v).map_or(0, |m| m + 1);
                    }
                    let cc = lvl.cell_coords(e.cell);
                    // Voxels of the 4 × 4 × 4 block around the cell (bit `x + 4y + 16z`, from
                    // the voxel before the cell's first) that hold material of another element:
                    // a point is private when none of the eight voxels around it does.
                    let mut foreign = 0u64;
                    for z in 0..4u32 {
                        for y in 0..4u32 {
                            for x in 0..4u32 {
                                let q = [x, y, z];
                                let q: [u32; 3] =
                                    std::array::from_fn(|a| (2 * cc[a] + q[a]).wrapping_sub(1));
                                if (0..3).any(|a| q[a] >= dims[a]) {
                                    continue;
                                }
                                let v = q[0] + dims[0] * (q[1] + dims[1] * q[2]);
                                if fine.material(v).is_some() && !e.children.contains(&v) {
                                    foreign |= 1 << (x + 4 * y + 16 * z);
                                }
                            }
                        }
                    }
                    let mut private = 0u32;
                    for p in 0..27u32 {
                        let around = 0x0033_0033_u64 << (p % 3 + 4 * ((p / 3) % 3) + 16 * (p / 9));
                        private |= u32::from(foreign & around == 0) << p;
                    }
                    level1
                        .entry((pattern, private))
                        .or_insert_with(|| {
                            let placed: Vec<Placed<'_>> = pattern
                                .iter()
                                .enumerate()
                                .filter(|&(_, &m)| m != 0)
                                .map(|(o, &m)| {
                                    let b = corner(o);
                                    let lattice =
                                        lattice_of([b[0] as u32, b[1] as u32, b[2] as u32]);
                                    Placed {
                                        stiffness: &tables.voxel(usize::from(m - 1)).stiffness,
                                        // One element's voxels share every point they meet at.
                                        keys: lattice.map(u64::from),
                                        lattice,
                                        private: lattice.map(|p| private >> p & 1 == 1),
                                    }
                                })
                                .collect();
                            Arc::new(condense_onto_corners(&placed))
                        })
                        .clone()
                } else {
                    let child_level = child_level.as_deref().expect("the level below");
                    let below = below.expect("the level below");
                    // Near a cut most cells keep their children, their nodes and the users
                    // of those nodes: then their inputs are as stored.
                    let unchanged = |stored: &[ChildInput]| {
                        stored.len() == e.children.len()
                            && stored.iter().zip(&e.children).all(|(ci, &c)| {
                                let ch = child_level.element(c).expect("live child");
                                ci.child == c
                                    && ci.nodes == ch.nodes
                                    && ci.octant == octant(child_level.cell_coords(ch.cell))
                                    && users_changed.as_ref().is_some_and(|moved| {
                                        ch.nodes.iter().all(|n| moved.binary_search(n).is_err())
                                    })
                            })
                    };
                    // A stored matrix can stand when no child's stiffness changed and the inputs
                    // are as stored.
                    let may_keep = near.is_some()
                        && here[id as usize].is_some()
                        && !e.children.iter().any(|&c| changed_below[c as usize]);
                    if may_keep && inputs[id as usize].as_deref().is_some_and(unchanged) {
                        continue;
                    }
                    // Every corner node of every child, sorted: a node is private when this
                    // element's children are all its users.
                    mine.clear();
                    for &c in &e.children {
                        mine.extend(child_level.element(c).expect("live child").nodes);
                    }
                    mine.sort_unstable();
                    let count = |n: u32| {
                        let from = mine.partition_point(|&m| m < n);
                        mine[from..].iter().take_while(|&&m| m == n).count() as u32
                    };
                    input.clear();
                    input.extend(e.children.iter().map(|&c| {
                        let ch = child_level.element(c).expect("live child");
                        let private = (0..8)
                            .filter(|&k| count(ch.nodes[k]) == uses[ch.nodes[k] as usize])
                            .fold(0u8, |bits, k| bits | 1 << k);
                        ChildInput {
                            child: c,
                            octant: octant(child_level.cell_coords(ch.cell)),
                            nodes: ch.nodes,
                            private,
                        }
                    }));
                    if may_keep && inputs[id as usize].as_deref() == Some(&input[..]) {
                        continue;
                    }
                    let placed: Vec<Placed<'_>> = input
                        .iter()
                        .map(|ci| {
                            let o = u32::from(ci.octant);
                            Placed {
                                stiffness: below[ci.child as usize]
                                    .as_deref()
                                    .expect("child condensed"),
                                keys: ci.nodes.map(u64::from),
                                lattice: lattice_of([o & 1, (o >> 1) & 1, o >> 2]),
                                private: std::array::from_fn(|k| ci.private >> k & 1 == 1),
                            }
                        })
                        .collect();
                    let k = Arc::new(condense_onto_corners(&placed));
                    inputs[id as usize] = Some(input.as_slice().into());
                    k
                };
                if near.is_some()
                    && here[id as usize].as_deref().is_some_and(|old| same_bits(old, &k))
                {
                    continue;
                }
                here[id as usize] = Some(k);
                changed[id as usize] = true;
                made.push(id);
            }
            changed_below = changed;
            if li > 0 {
                self.uses[li - 1] = uses;
            }
            users_changed = Self::count_users(
                &mut self.uses[li],
                &mut self.cells[li],
                &mut self.nodes[li],
                &mut self.seen,
                &lvl,
                // A level whose nodes are numbered afresh for this pass is counted afresh.
                near.filter(|_| self.tracked[li] && levels[li].tracks_nodes())
                    .map(|near| &near.region[li][..]),
            );
            self.tracked[li] = levels[li].tracks_nodes();
            child_level = Some(lvl);
        }
        made.sort_unstable();
        made
    }
}
