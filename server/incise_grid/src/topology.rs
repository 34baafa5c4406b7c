//! Jeřábková 2010, §2.1 (Fig. 3, 5): topology of the Dynamic Branched Grid, built and updated level
//! by level on the element graph.
//!
//! Level `l` groups the elements of level `l − 1` by cell (`2×2×2` child cells). Within a cell,
//! the connected components of the child graph (restricted to the cell) each become one element;
//! several components in one cell give superimposed elements. Two elements are neighbours when a
//! child of one is a neighbour of a child of the other (material connects them across the face).
//! Nodes: at each grid point, the elements touching it are grouped by face connection; each group
//! shares one node there, so corners are shared only where material connects.
//!
//! The same routine builds a level from scratch (every cell dirty, nothing to match) and updates
//! it after voxels are removed or links severed (only the dirty cells and their corner points are
//! redone). Only removal happens, so every new component lies inside exactly one old element; the
//! largest piece keeps the old id, the others appear as new elements whose `origin` names it.

use std::collections::BTreeSet;

/// "No element / node": an absent parent, origin or corner.
pub const NONE: u32 = u32::MAX;

/// One element of a coarse level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Element {
    /// Linear index of the cell it fills (`x` fastest over the level's cell grid).
    pub cell: u32,
    /// Smallest voxel index it owns: with the level, a canonical name independent of numbering.
    pub min_voxel: u32,
    /// Number of fine voxels it owns.
    pub voxel_count: u32,
    /// Elements of the level below that it consists of (voxel indices at level 1).
    pub children: Vec<u32>,
    /// Face-connected elements of the same level, sorted by id.
    pub neighbors: Vec<u32>,
    /// Node id of each corner, corner `c` at `(c & 1, (c >> 1) & 1, c >> 2)`.
    pub nodes: [u32; 8],
    pub(crate) parent: u32,
    pub(crate) alive: bool,
}

/// One node of a coarse level: a grid point, possibly one of several superimposed there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Node {
    /// Linear index of the grid point (`x` fastest over `cell_dims + 1`).
    pub point: u32,
    pub(crate) alive: bool,
}

/// Changes of one level during an update, in the level's ids.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LevelChanges {
    /// New elements with the element they split from (`None` when built from scratch).
    pub elements_added: Vec<(u32, Option<u32>)>,
    /// Elements that no longer exist (all their voxels were removed).
    pub elements_removed: Vec<u32>,
    /// Surviving elements whose voxels, neighbours or corner nodes changed, sorted.
    pub elements_changed: Vec<u32>,
    /// Elements whose voxel set shrank, with their voxel count before the update.
    pub elements_shrunk: Vec<(u32, u32)>,
    /// New nodes with the node at the same grid point they were split from, if any.
    pub nodes_added: Vec<(u32, Option<u32>)>,
    /// Nodes that no longer exist.
    pub nodes_removed: Vec<u32>,
}

/// What a level needs to know about the level below it.
pub(crate) trait ChildLevel {
    fn cell_dims(&self) -> [u32; 3];
    fn push_cell_elements(&self, cell: u32, out: &mut Vec<u32>);
    fn push_neighbors(&self, e: u32, out: &mut Vec<u32>);
    fn min_voxel(&self, e: u32) -> u32;
    fn voxel_count(&self, e: u32) -> u32;
    fn parent(&self, e: u32) -> u32;
    fn set_parent(&mut self, e: u32, p: u32);
}

/// Linear index ↔ coordinates over a box of `dims`.
#[inline]
pub(crate) fn coords(i: u32, dims: [u32; 3]) -> [u32; 3] {
    [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])]
}

#[inline]
pub(crate) fn linear(c: [u32; 3], dims: [u32; 3]) -> u32 {
    c[0] + dims[0] * (c[1] + dims[1] * c[2])
}

/// The fine level: voxels with a material, face links, severed links.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FineLevel {
    pub(crate) dims: [u32; 3],
    /// 0 = empty, otherwise material index + 1.
    pub(crate) material: Vec<u16>,
    /// Bit `a` set: the link from this voxel to its `+a` neighbour is severed.
    pub(crate) severed: Vec<u8>,
    pub(crate) parent: Vec<u32>,
}

impl FineLevel {
    /// Voxels per axis.
    #[must_use]
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Material index of voxel `v`, or `None` when it is empty.
    #[must_use]
    pub fn material(&self, v: u32) -> Option<u16> {
        self.material[v as usize].checked_sub(1)
    }

    /// True when the link between face neighbours `a` and `b` is severed.
    #[must_use]
    pub fn is_severed(&self, a: u32, b: u32) -> bool {
        let (lo, hi) = (a.min(b), a.max(b));
        let axis = self.link_axis(lo, hi);
        axis.is_some_and(|axis| self.severed[lo as usize] & (1 << axis) != 0)
    }

    /// The axis along which `hi` is the `+axis` face neighbour of `lo`, if it is one.
    pub(crate) fn link_axis(&self, lo: u32, hi: u32) -> Option<u32> {
        let d = self.dims;
        let (p, q) = (coords(lo, d), coords(hi, d));
        (0..3u32).find(|&a| {
            let a = a as usize;
            q[a] == p[a] + 1 && (0..3).all(|b| b == a || p[b] == q[b])
        })
    }

    /// True when both hold the same voxels and severed links (parents, which name elements, aside).
    #[must_use]
    pub fn same_material_and_links(&self, other: &Self) -> bool {
        self.dims == other.dims && self.material == other.material && self.severed == other.severed
    }

    /// Number of voxels with material.
    #[must_use]
    pub fn voxel_count(&self) -> usize {
        self.material.iter().filter(|&&m| m != 0).count()
    }

    /// The face neighbours of `v` that hold material and whose link to `v` is intact.
    pub(crate) fn for_each_link(&self, v: u32, mut f: impl FnMut(u32)) {
        let d = self.dims;
        let c = coords(v, d);
        let stride = [1, d[0], d[0] * d[1]];
        for a in 0..3 {
            if c[a] + 1 < d[a] {
                let u = v + stride[a];
                if self.material[u as usize] != 0 && self.severed[v as usize] & (1 << a) == 0 {
                    f(u);
                }
            }
            if c[a] > 0 {
                let u = v - stride[a];
                if self.material[u as usize] != 0 && self.severed[u as usize] & (1 << a) == 0 {
                    f(u);
                }
            }
        }
    }
}

impl ChildLevel for FineLevel {
    fn cell_dims(&self) -> [u32; 3] {
        self.dims
    }
    fn push_cell_elements(&self, cell: u32, out: &mut Vec<u32>) {
        if self.material[cell as usize] != 0 {
            out.push(cell);
        }
    }
    fn push_neighbors(&self, e: u32, out: &mut Vec<u32>) {
        self.for_each_link(e, |u| out.push(u));
    }
    fn min_voxel(&self, e: u32) -> u32 {
        e
    }
    fn voxel_count(&self, _e: u32) -> u32 {
        1
    }
    fn parent(&self, e: u32) -> u32 {
        self.parent[e as usize]
    }
    fn set_parent(&mut self, e: u32, p: u32) {
        self.parent[e as usize] = p;
    }
}

/// One coarse level of the grid.
#[derive(Clone, Debug)]
pub struct Level {
    level: u32,
    /// log2 of child cells per axis in one cell: 1 normally, 0 for a level-0 element level.
    shift: u32,
    cell_dims: [u32; 3],
    elements: Vec<Element>,
    free_elements: BTreeSet<u32>,
    live_elements: usize,
    nodes: Vec<Node>,
    free_nodes: BTreeSet<u32>,
    live_nodes: usize,
    cell_elements: Vec<Vec<u32>>,
    point_nodes: Vec<Vec<u32>>,
    mark: Vec<u32>,
    epoch: u32,
}

/// A connected component found in a dirty cell.
struct Component {
    members: Vec<u32>,
    min_voxel: u32,
    voxel_count: u32,
    old_parent: u32,
    id: u32,
}

/// Union-find over a handful of local indices.
fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

fn union(parent: &mut [usize], a: usize, b: usize) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // Smaller root wins so the result does not depend on edge order.
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        parent[hi] = lo;
    }
}

impl Level {
    /// An empty level `level` over child cells of extent `child_dims`; `shift` is 1 for coarse
    /// levels (2×2×2 child cells per cell) and 0 for a level made of single voxels.
    pub(crate) fn new(level: u32, shift: u32, child_dims: [u32; 3]) -> Self {
        let cell_dims = child_dims.map(|d| d.div_ceil(1 << shift));
        let cells = cell_dims.iter().map(|&d| d as usize).product();
        let points = cell_dims.iter().map(|&d| d as usize + 1).product();
        Self {
            level,
            shift,
            cell_dims,
            elements: Vec::new(),
            free_elements: BTreeSet::new(),
            live_elements: 0,
            nodes: Vec::new(),
            free_nodes: BTreeSet::new(),
            live_nodes: 0,
            cell_elements: vec![Vec::new(); cells],
            point_nodes: vec![Vec::new(); points],
            mark: vec![0; cells],
            epoch: 0,
        }
    }

    /// The level number `l`: cells of `2^l` voxels per axis.
    #[must_use]
    pub fn level(&self) -> u32 {
        self.level
    }

    /// Cells per axis.
    #[must_use]
    pub fn cell_dims(&self) -> [u32; 3] {
        self.cell_dims
    }

    /// Number of live elements.
    #[must_use]
    pub fn element_count(&self) -> usize {
        self.live_elements
    }

    /// Number of live nodes.
    #[must_use]
    pub fn node_count(&self) -> usize {
        self.live_nodes
    }

    /// One past the largest element id (ids of removed elements are reused later).
    #[must_use]
    pub fn element_capacity(&self) -> usize {
        self.elements.len()
    }

    /// One past the largest node id.
    #[must_use]
    pub fn node_capacity(&self) -> usize {
        self.nodes.len()
    }

    /// Element `id`, if it is alive.
    #[must_use]
    pub fn element(&self, id: u32) -> Option<&Element> {
        self.elements.get(id as usize).filter(|e| e.alive)
    }

    /// Node `id`, if it is alive.
    #[must_use]
    pub fn node(&self, id: u32) -> Option<&Node> {
        self.nodes.get(id as usize).filter(|n| n.alive)
    }

    /// Live elements with their ids, in id order.
    pub fn elements(&self) -> impl Iterator<Item = (u32, &Element)> {
        self.elements.iter().enumerate().filter(|(_, e)| e.alive).map(|(i, e)| (i as u32, e))
    }

    /// Live nodes with their ids, in id order.
    pub fn nodes(&self) -> impl Iterator<Item = (u32, &Node)> {
        self.nodes.iter().enumerate().filter(|(_, n)| n.alive).map(|(i, n)| (i as u32, n))
    }

    /// Ids of the elements in `cell` (more than one where they are superimposed).
    #[must_use]
    pub fn cell_elements(&self, cell: u32) -> &[u32] {
        &self.cell_elements[cell as usize]
    }

    /// Number of elements that share their cell with another element.
    #[must_use]
    pub fn superimposed_count(&self) -> usize {
        self.cell_elements.iter().filter(|c| c.len() > 1).map(Vec::len).sum()
    }

    /// Coordinates of a cell.
    #[must_use]
    pub fn cell_coords(&self, cell: u32) -> [u32; 3] {
        coords(cell, self.cell_dims)
    }

    /// Coordinates of a grid point.
    #[must_use]
    pub fn point_coords(&self, point: u32) -> [u32; 3] {
        coords(point, self.cell_dims.map(|d| d + 1))
    }

    pub(crate) fn parent_of(&self, e: u32) -> u32 {
        self.elements[e as usize].parent
    }

    fn alloc_element(&mut self) -> u32 {
        self.live_elements += 1;
        if let Some(id) = self.free_elements.pop_first() {
            id
        } else {
            self.elements.push(Element {
                cell: 0,
                min_voxel: 0,
                voxel_count: 0,
                children: Vec::new(),
                neighbors: Vec::new(),
                nodes: [NONE; 8],
                parent: NONE,
                alive: false,
            });
            (self.elements.len() - 1) as u32
        }
    }

    fn alloc_node(&mut self, point: u32) -> u32 {
        self.live_nodes += 1;
        let id = if let Some(id) = self.free_nodes.pop_first() {
            id
        } else {
            self.nodes.push(Node { point, alive: false });
            (self.nodes.len() - 1) as u32
        };
        self.nodes[id as usize] = Node { point, alive: true };
        id
    }

    /// Rebuilds the dirty part of this level from the (already updated) level below.
    /// `dirty_child_cells` are the child cells whose elements or links changed; returns this
    /// level's dirty cells, sorted, for the level above.
    pub(crate) fn update<C: ChildLevel>(&mut self, child: &mut C, dirty_child_cells: &[u32], changes: &mut LevelChanges) -> Vec<u32> {
        let child_dims = child.cell_dims();
        let shift = self.shift;
        let mut dirty: Vec<u32> = dirty_child_cells
            .iter()
            .map(|&c| linear(coords(c, child_dims).map(|x| x >> shift), self.cell_dims))
            .collect();
        dirty.sort_unstable();
        dirty.dedup();
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.epoch = 1;
        }
        for &c in &dirty {
            self.mark[c as usize] = self.epoch;
        }
        let is_dirty = |lvl: &Self, e: u32| lvl.mark[lvl.elements[e as usize].cell as usize] == lvl.epoch;

        // Detach the old elements of dirty cells from neighbours that will not be rebuilt.
        let mut old_of_cell: Vec<Vec<u32>> = Vec::with_capacity(dirty.len());
        for &c in &dirty {
            let old = std::mem::take(&mut self.cell_elements[c as usize]);
            for &e in &old {
                let nbrs = std::mem::take(&mut self.elements[e as usize].neighbors);
                for &n in &nbrs {
                    if !is_dirty(self, n) {
                        let list = &mut self.elements[n as usize].neighbors;
                        if let Ok(pos) = list.binary_search(&e) {
                            list.remove(pos);
                        }
                    }
                }
                // Keep the old list so a surviving element can tell whether it changed.
                self.elements[e as usize].neighbors = nbrs;
            }
            old_of_cell.push(old);
        }

        // Phase A: components of every dirty cell, matched to the old element they came from.
        let mut comps_of_cell: Vec<Vec<Component>> = Vec::with_capacity(dirty.len());
        let mut members = Vec::new();
        let mut nbrs = Vec::new();
        let per_axis = 1u32 << shift;
        for &c in &dirty {
            let cc = coords(c, self.cell_dims);
            members.clear();
            for dz in 0..per_axis {
                for dy in 0..per_axis {
                    for dx in 0..per_axis {
                        let q = [(cc[0] << shift) + dx, (cc[1] << shift) + dy, (cc[2] << shift) + dz];
                        if q[0] < child_dims[0] && q[1] < child_dims[1] && q[2] < child_dims[2] {
                            child.push_cell_elements(linear(q, child_dims), &mut members);
                        }
                    }
                }
            }
            let mut uf: Vec<usize> = (0..members.len()).collect();
            for i in 0..members.len() {
                nbrs.clear();
                child.push_neighbors(members[i], &mut nbrs);
                for &n in &nbrs {
                    if let Some(j) = members.iter().position(|&m| m == n) {
                        union(&mut uf, i, j);
                    }
                }
            }
            let mut comps: Vec<Component> = Vec::new();
            let mut root_comp = vec![usize::MAX; members.len()];
            for i in 0..members.len() {
                let r = find(&mut uf, i);
                if root_comp[r] == usize::MAX {
                    root_comp[r] = comps.len();
                    comps.push(Component { members: Vec::new(), min_voxel: u32::MAX, voxel_count: 0, old_parent: NONE, id: NONE });
                }
                let comp = &mut comps[root_comp[r]];
                let m = members[i];
                let mv = child.min_voxel(m);
                comp.members.push(m);
                comp.voxel_count += child.voxel_count(m);
                if mv < comp.min_voxel {
                    comp.min_voxel = mv;
                    let p = child.parent(m);
                    let valid = p != NONE
                        && (p as usize) < self.elements.len()
                        && self.elements[p as usize].alive
                        && self.elements[p as usize].cell == c;
                    comp.old_parent = if valid { p } else { NONE };
                }
            }
            comps.sort_unstable_by_key(|k| k.min_voxel);
            for comp in &mut comps {
                comp.members.sort_unstable_by_key(|&m| child.min_voxel(m));
            }
            comps_of_cell.push(comps);
        }

        // Phase B: keep one piece per old element (the largest), free the vanished, allocate new.
        let mut origin_of: Vec<(usize, usize, u32)> = Vec::new();
        for (ci, comps) in comps_of_cell.iter_mut().enumerate() {
            for &old in &old_of_cell[ci] {
                let mut best: Option<usize> = None;
                for (k, comp) in comps.iter().enumerate() {
                    if comp.old_parent == old {
                        let better = best.is_none_or(|b| {
                            let cb = &comps[b];
                            (comp.voxel_count, std::cmp::Reverse(comp.min_voxel)) > (cb.voxel_count, std::cmp::Reverse(cb.min_voxel))
                        });
                        if better {
                            best = Some(k);
                        }
                    }
                }
                if let Some(b) = best {
                    comps[b].id = old;
                } else {
                    let e = &mut self.elements[old as usize];
                    e.alive = false;
                    e.children.clear();
                    e.neighbors.clear();
                    e.nodes = [NONE; 8];
                    e.parent = NONE;
                    self.free_elements.insert(old);
                    self.live_elements -= 1;
                    changes.elements_removed.push(old);
                }
            }
            for (k, comp) in comps.iter().enumerate() {
                if comp.id == NONE {
                    origin_of.push((ci, k, comp.old_parent));
                }
            }
        }
        let mut fresh: Vec<bool> = Vec::new();
        for &(ci, k, origin) in &origin_of {
            let id = self.alloc_element();
            comps_of_cell[ci][k].id = id;
            let (parent, nodes) = if origin == NONE {
                (NONE, [NONE; 8])
            } else {
                let o = &self.elements[origin as usize];
                (o.parent, o.nodes)
            };
            let e = &mut self.elements[id as usize];
            e.parent = parent;
            e.nodes = nodes;
            e.neighbors.clear();
            changes.elements_added.push((id, (origin != NONE).then_some(origin)));
            if fresh.len() <= id as usize {
                fresh.resize(id as usize + 1, false);
            }
            fresh[id as usize] = true;
        }
        let is_fresh = |fresh: &[bool], id: u32| fresh.get(id as usize).copied().unwrap_or(false);
        let mut changed: Vec<u32> = Vec::new();
        for (ci, comps) in comps_of_cell.iter_mut().enumerate() {
            let c = dirty[ci];
            let list = &mut self.cell_elements[c as usize];
            for comp in comps.iter_mut() {
                let id = comp.id;
                list.push(id);
                for &m in &comp.members {
                    child.set_parent(m, id);
                }
                let e = &mut self.elements[id as usize];
                if !is_fresh(&fresh, id) {
                    if e.voxel_count != comp.voxel_count {
                        changes.elements_shrunk.push((id, e.voxel_count));
                    }
                    if e.children != comp.members || e.voxel_count != comp.voxel_count {
                        changed.push(id);
                    }
                }
                e.cell = c;
                e.min_voxel = comp.min_voxel;
                e.voxel_count = comp.voxel_count;
                e.children = std::mem::take(&mut comp.members);
                e.alive = true;
            }
        }

        // Edges of every element in a dirty cell, mirrored into clean neighbours.
        for &c in &dirty {
            for k in 0..self.cell_elements[c as usize].len() {
                let e = self.cell_elements[c as usize][k];
                let mut set: Vec<u32> = Vec::new();
                for &m in &self.elements[e as usize].children {
                    nbrs.clear();
                    child.push_neighbors(m, &mut nbrs);
                    for &n in &nbrs {
                        let p = child.parent(n);
                        if p != e {
                            set.push(p);
                        }
                    }
                }
                set.sort_unstable();
                set.dedup();
                for &p in &set {
                    if !is_dirty(self, p) {
                        let list = &mut self.elements[p as usize].neighbors;
                        if let Err(pos) = list.binary_search(&e) {
                            list.insert(pos, e);
                        }
                    }
                }
                let el = &mut self.elements[e as usize];
                if !is_fresh(&fresh, e) && el.neighbors != set {
                    changed.push(e);
                }
                el.neighbors = set;
            }
        }

        // Nodes at every corner point of a dirty cell.
        let pdims = self.cell_dims.map(|d| d + 1);
        let mut points: Vec<u32> = Vec::with_capacity(dirty.len() * 8);
        for &c in &dirty {
            let cc = coords(c, self.cell_dims);
            for corner in 0..8u32 {
                points.push(linear([cc[0] + (corner & 1), cc[1] + ((corner >> 1) & 1), cc[2] + (corner >> 2)], pdims));
            }
        }
        points.sort_unstable();
        points.dedup();
        let mut around: Vec<(u32, usize)> = Vec::new();
        let mut claimed: Vec<u32> = Vec::new();
        for &p in &points {
            let pc = coords(p, pdims);
            around.clear();
            for corner in 0..8usize {
                let b = [corner as u32 & 1, (corner as u32 >> 1) & 1, corner as u32 >> 2];
                if (0..3).any(|a| pc[a] < b[a] || pc[a] - b[a] >= self.cell_dims[a]) {
                    continue;
                }
                let cell = linear([pc[0] - b[0], pc[1] - b[1], pc[2] - b[2]], self.cell_dims);
                for &e in &self.cell_elements[cell as usize] {
                    around.push((e, corner));
                }
            }
            let mut uf: Vec<usize> = (0..around.len()).collect();
            for i in 0..around.len() {
                for &n in &self.elements[around[i].0 as usize].neighbors {
                    if let Some(j) = around.iter().position(|&(m, _)| m == n) {
                        union(&mut uf, i, j);
                    }
                }
            }
            // Classes in order of their smallest element key.
            let mut classes: Vec<(u32, usize)> = Vec::new(); // (min key, root)
            for i in 0..around.len() {
                let r = find(&mut uf, i);
                let key = self.elements[around[i].0 as usize].min_voxel;
                match classes.iter_mut().find(|(_, root)| *root == r) {
                    Some(entry) => entry.0 = entry.0.min(key),
                    None => classes.push((key, r)),
                }
            }
            classes.sort_unstable();
            let old_nodes = std::mem::take(&mut self.point_nodes[p as usize]);
            claimed.clear();
            let mut class_node: Vec<u32> = Vec::with_capacity(classes.len());
            let mut class_origin: Vec<u32> = Vec::with_capacity(classes.len());
            for &(_, r) in &classes {
                let mut pick = NONE;
                let mut origin = NONE;
                for i in 0..around.len() {
                    if find(&mut uf, i) != r {
                        continue;
                    }
                    let (e, corner) = around[i];
                    let n = self.elements[e as usize].nodes[corner];
                    if n != NONE && old_nodes.contains(&n) {
                        origin = origin.min(n);
                        if !claimed.contains(&n) {
                            pick = pick.min(n);
                        }
                    }
                }
                if pick != NONE {
                    claimed.push(pick);
                }
                class_node.push(pick);
                class_origin.push(origin);
            }
            for &n in &old_nodes {
                if !claimed.contains(&n) {
                    self.nodes[n as usize].alive = false;
                    self.free_nodes.insert(n);
                    self.live_nodes -= 1;
                    changes.nodes_removed.push(n);
                }
            }
            let mut new_list = Vec::with_capacity(classes.len());
            for (k, &(_, r)) in classes.iter().enumerate() {
                let id = if class_node[k] == NONE {
                    let id = self.alloc_node(p);
                    let origin = class_origin[k];
                    changes.nodes_added.push((id, (origin != NONE).then_some(origin)));
                    id
                } else {
                    class_node[k]
                };
                new_list.push(id);
                for i in 0..around.len() {
                    if find(&mut uf, i) == r {
                        let (e, corner) = around[i];
                        let el = &mut self.elements[e as usize];
                        if el.nodes[corner] != id {
                            el.nodes[corner] = id;
                            if !is_fresh(&fresh, e) {
                                changed.push(e);
                            }
                        }
                    }
                }
            }
            self.point_nodes[p as usize] = new_list;
        }
        changed.sort_unstable();
        changed.dedup();
        changes.elements_changed = changed;
        dirty
    }
}

impl ChildLevel for Level {
    fn cell_dims(&self) -> [u32; 3] {
        self.cell_dims
    }
    fn push_cell_elements(&self, cell: u32, out: &mut Vec<u32>) {
        out.extend_from_slice(&self.cell_elements[cell as usize]);
    }
    fn push_neighbors(&self, e: u32, out: &mut Vec<u32>) {
        out.extend_from_slice(&self.elements[e as usize].neighbors);
    }
    fn min_voxel(&self, e: u32) -> u32 {
        self.elements[e as usize].min_voxel
    }
    fn voxel_count(&self, e: u32) -> u32 {
        self.elements[e as usize].voxel_count
    }
    fn parent(&self, e: u32) -> u32 {
        self.elements[e as usize].parent
    }
    fn set_parent(&mut self, e: u32, p: u32) {
        self.elements[e as usize].parent = p;
    }
}
