//! A numbering-free description of a grid, so two grids built in different ways (from scratch,
//! or by a sequence of incremental updates) can be compared: "equal up to renumbering".
//!
//! An element is named by its smallest voxel (elements of one level partition the voxels), a
//! node by its grid point and the smallest element name among the elements sharing it.

use crate::grid::BranchedGrid;
use crate::hex8::{mat8_frobenius, mat8_frobenius_diff};
use crate::topology::Level;
use std::collections::BTreeMap;

/// One element without ids.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct CanonicalElement {
    /// Smallest voxel owned.
    pub key: u32,
    /// Cell index.
    pub cell: u32,
    /// Voxels owned.
    pub voxel_count: u32,
    /// Keys of the children (voxel indices at level 1), sorted.
    pub children: Vec<u32>,
    /// Keys of the face-connected neighbours, sorted.
    pub neighbors: Vec<u32>,
    /// Per corner: (grid point, key of the node = smallest element key sharing it).
    pub nodes: [(u32, u32); 8],
}

/// One level without ids, elements sorted by key.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CanonicalLevel {
    /// Level number.
    pub level: u32,
    /// Its elements.
    pub elements: Vec<CanonicalElement>,
    /// Number of distinct nodes.
    pub node_count: usize,
}

impl CanonicalLevel {
    /// The canonical form of `lvl`; `child_key` names a child id at the level below.
    pub fn of(lvl: &Level, child_key: impl Fn(u32) -> u32) -> Self {
        let mut node_key: BTreeMap<u32, u32> = BTreeMap::new();
        for (_, e) in lvl.elements() {
            for &n in &e.nodes {
                let k = node_key.entry(n).or_insert(u32::MAX);
                *k = (*k).min(e.min_voxel);
            }
        }
        let key_of = |id: u32| lvl.element(id).map_or(u32::MAX, |e| e.min_voxel);
        let mut elements: Vec<CanonicalElement> = lvl
            .elements()
            .map(|(_, e)| {
                let mut children: Vec<u32> = e.children.iter().map(|&c| child_key(c)).collect();
                children.sort_unstable();
                let mut neighbors: Vec<u32> = e.neighbors.iter().map(|&n| key_of(n)).collect();
                neighbors.sort_unstable();
                let nodes = e.nodes.map(|n| {
                    (
                        lvl.node(n).map_or(u32::MAX, |x| x.point),
                        node_key.get(&n).copied().unwrap_or(u32::MAX),
                    )
                });
                CanonicalElement {
                    key: e.min_voxel,
                    cell: e.cell,
                    voxel_count: e.voxel_count,
                    children,
                    neighbors,
                    nodes,
                }
            })
            .collect();
        elements.sort_unstable();
        Self { level: lvl.level(), elements, node_count: lvl.node_count() }
    }

    /// A sentence naming the first difference from `other`, or `None` when they are equal.
    #[must_use]
    pub fn first_difference(&self, other: &Self) -> Option<String> {
        if self == other {
            return None;
        }
        if self.elements.len() != other.elements.len() || self.node_count != other.node_count {
            return Some(format!(
                "level {}: {} elements / {} nodes vs {} elements / {} nodes",
                self.level,
                self.elements.len(),
                self.node_count,
                other.elements.len(),
                other.node_count
            ));
        }
        self.elements
            .iter()
            .zip(other.elements.iter())
            .find(|(a, b)| a != b)
            .map(|(a, b)| format!("level {}: element {a:?} vs {b:?}", self.level))
    }
}

/// Canonical forms of every stored level of `grid`, bottom-up.
#[must_use]
pub fn canonical_levels(grid: &BranchedGrid) -> Vec<CanonicalLevel> {
    let levels = grid.levels();
    levels
        .iter()
        .enumerate()
        .map(|(i, lvl)| {
            let lvl = &lvl.with_nodes();
            if i == 0 {
                CanonicalLevel::of(lvl, |v| v)
            } else {
                let below = &levels[i - 1];
                CanonicalLevel::of(lvl, |c| below.element(c).map_or(u32::MAX, |e| e.min_voxel))
            }
        })
        .collect()
}

/// Compares two grids up to renumbering: every level's topology must be equal, and each top-level
/// element's K and M must agree to `rel_tol` relative Frobenius norm. Returns the largest relative
/// difference seen, or a sentence naming the first mismatch.
pub fn compare_grids(a: &BranchedGrid, b: &BranchedGrid, rel_tol: f64) -> Result<f64, String> {
    let (ca, cb) = (canonical_levels(a), canonical_levels(b));
    if ca.len() != cb.len() {
        return Err(format!("{} levels vs {}", ca.len(), cb.len()));
    }
    for (x, y) in ca.iter().zip(cb.iter()) {
        if let Some(d) = x.first_difference(y) {
            return Err(d);
        }
    }
    if !a.fine().same_material_and_links(b.fine()) {
        return Err("fine levels differ".into());
    }
    let by_key = |g: &BranchedGrid| -> BTreeMap<u32, u32> {
        g.top().elements().map(|(id, e)| (e.min_voxel, id)).collect()
    };
    let (ka, kb) = (by_key(a), by_key(b));
    let mut worst = 0.0f64;
    for (key, &ia) in &ka {
        let ib = kb[key];
        let (ma, mb) =
            (a.matrices(ia).ok_or("missing matrices")?, b.matrices(ib).ok_or("missing matrices")?);
        let dk = ma.stiffness.frobenius_diff(&mb.stiffness)
            / mb.stiffness.frobenius().max(f64::MIN_POSITIVE);
        let dm = mat8_frobenius_diff(&ma.mass, &mb.mass)
            / mat8_frobenius(&mb.mass).max(f64::MIN_POSITIVE);
        worst = worst.max(dk).max(dm);
        if dk > rel_tol || dm > rel_tol {
            return Err(format!(
                "element with voxel {key}: K differs by {dk:e}, M by {dm:e} (relative), above {rel_tol:e}"
            ));
        }
    }
    Ok(worst)
}
