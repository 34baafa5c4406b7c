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
    /// Surviving elements with a corner node that changed, sorted (a subset of
    /// `elements_changed`): what embeds in an element moves with other nodes only for these and
    /// for added elements.
    pub elements_renoded: Vec<u32>,
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

    /// Unions the members of one parent cell that are face-connected (`uf` indexes `members`).
    /// `base` is the child-cell coordinate of the parent cell's first child.
    fn union_within_cell(
        &self,
        members: &[u32],
        _base: [u32; 3],
        uf: &mut [usize],
        nbrs: &mut Vec<u32>,
    ) {
        for i in 0..members.len() {
            nbrs.clear();
            self.push_neighbors(members[i], nbrs);
            for &n in nbrs.iter() {
                if let Some(j) = members.iter().position(|&x| x == n) {
                    union(uf, i, j);
                }
            }
        }
    }

    /// Pushes the neighbours of `e` that may lie outside its parent cell (all of them by default;
    /// the caller drops those with the same parent). `base` as in [`ChildLevel::union_within_cell`].
    fn push_outside_neighbors(&self, e: u32, _base: [u32; 3], _per_axis: u32, out: &mut Vec<u32>) {
        self.push_neighbors(e, out);
    }
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

    /// True when the link between voxel `v` and its `+axis` face neighbour is severed:
    /// [`FineLevel::is_severed`] for a pair whose axis the caller knows, without finding it
    /// from both voxels' coordinates (the re-meshing and the cut search ask this in their
    /// innermost loops).
    #[must_use]
    pub fn is_severed_along(&self, v: u32, axis: usize) -> bool {
        self.severed[v as usize] & (1 << axis) != 0
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

    // The voxels of one cell sit in a 2×2×2 block at `base`: their offsets from the block's first
    // voxel decode to block-local bits without the divisions `coords` needs.
    fn union_within_cell(
        &self,
        members: &[u32],
        base: [u32; 3],
        uf: &mut [usize],
        _nbrs: &mut Vec<u32>,
    ) {
        let first = linear(base, self.dims);
        let bits: [u32; 8] =
            std::array::from_fn(|i| members.get(i).map_or(0, |&v| self.block_bits(v - first)));
        for i in 0..members.len() {
            for j in i + 1..members.len() {
                let diff = bits[i] ^ bits[j];
                if diff.is_power_of_two() {
                    let axis = diff.trailing_zeros();
                    let lo = members[i].min(members[j]);
                    if self.severed[lo as usize] & (1 << axis) == 0 {
                        union(uf, i, j);
                    }
                }
            }
        }
    }

    fn push_outside_neighbors(&self, v: u32, base: [u32; 3], per_axis: u32, out: &mut Vec<u32>) {
        let first = linear(base, self.dims);
        let bits = if per_axis == 1 { 0 } else { self.block_bits(v - first) };
        let d = self.dims;
        let stride = [1, d[0], d[0] * d[1]];
        for a in 0..3 {
            let b = (bits >> a) & 1;
            let x = base[a] + b;
            if (b == 0 || per_axis == 1) && x > 0 {
                let u = v - stride[a];
                if self.material[u as usize] != 0 && self.severed[u as usize] & (1 << a) == 0 {
                    out.push(u);
                }
            }
            if (b == 1 || per_axis == 1) && x + 1 < d[a] {
                let u = v + stride[a];
                if self.material[u as usize] != 0 && self.severed[v as usize] & (1 << a) == 0 {
                    out.push(u);
                }
            }
        }
    }
}

impl FineLevel {
    /// Block-local bits `x | y << 1 | z << 2` of a voxel `offset` past the first voxel of its
    /// aligned 2×2×2 block.
    #[inline]
    fn block_bits(&self, offset: u32) -> u32 {
        let (sx, sxy) = (self.dims[0], self.dims[0] * self.dims[1]);
        let bz = u32::from(offset >= sxy);
        let rest = offset - bz * sxy;
        let by = u32::from(rest >= sx);
        let bx = rest - by * sx;
        bx | (by << 1) | (bz << 2)
    }
}

/// One coarse level of the grid.
#[derive(Debug)]
pub struct Level {
    number: u32,
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
    scratch: Scratch,
    /// Whether nodes are kept current on every update (the simulation level) or computed on
    /// demand by [`Level::with_nodes`] (levels only used to build the ones above).
    track_nodes: bool,
}

/// A connected component found in a dirty cell; its members are `Scratch::comp_members[start..end]`.
#[derive(Clone, Copy, Debug)]
struct Component {
    start: u32,
    end: u32,
    min_voxel: u32,
    voxel_count: u32,
    old_parent: u32,
    id: u32,
}

/// Buffers reused across updates so a small edit allocates almost nothing.
#[derive(Clone, Debug, Default)]
struct Scratch {
    members: Vec<u32>,
    nbrs: Vec<u32>,
    uf: Vec<usize>,
    root_comp: Vec<u32>,
    comps: Vec<Component>,
    comp_members: Vec<u32>,
    /// Components of dirty cell `i` are `comps[cell_comps[i]..cell_comps[i + 1]]`.
    cell_comps: Vec<u32>,
    old_elems: Vec<u32>,
    /// Old elements of dirty cell `i` are `old_elems[cell_old[i]..cell_old[i + 1]]`.
    cell_old: Vec<u32>,
    fresh: Vec<u32>,
    set: Vec<u32>,
    points: Vec<u32>,
    around: Vec<(u32, usize)>,
    classes: Vec<(u32, usize)>,
    claimed: Vec<u32>,
    class_node: Vec<u32>,
    class_origin: Vec<u32>,
    changed: Vec<u32>,
    renoded: Vec<u32>,
    /// Dirty cells whose elements appeared, vanished or changed face connections.
    touched: Vec<u32>,
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
            number: level,
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
            scratch: Scratch::default(),
            track_nodes: true,
        }
    }

    /// The same level that skips node bookkeeping on updates (an intermediate level).
    pub(crate) fn without_node_tracking(mut self) -> Self {
        self.track_nodes = false;
        self
    }

    /// True when nodes are kept current on every update; otherwise they are empty and
    /// [`Level::with_nodes`] computes them.
    #[must_use]
    pub fn tracks_nodes(&self) -> bool {
        self.track_nodes
    }

    /// This level with its nodes (computed from scratch when it does not track them): an
    /// intermediate level's nodes are not needed to build the levels above, only to report them.
    #[must_use]
    pub fn with_nodes(&self) -> std::borrow::Cow<'_, Self> {
        if self.track_nodes {
            return std::borrow::Cow::Borrowed(self);
        }
        let mut lvl = self.clone();
        lvl.track_nodes = true;
        let mut sc = Scratch::default();
        let pdims = lvl.cell_dims.map(|d| d + 1);
        let mut changes = LevelChanges::default();
        let points: u32 = pdims.iter().product();
        for p in 0..points {
            lvl.update_point(p, pdims, &mut sc, &|_| true, &mut changes);
        }
        std::borrow::Cow::Owned(lvl)
    }

    /// The level number `l`: cells of `2^l` voxels per axis.
    #[must_use]
    pub fn level(&self) -> u32 {
        self.number
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
    pub(crate) fn update<C: ChildLevel>(
        &mut self,
        child: &mut C,
        dirty_child_cells: &[u32],
        changes: &mut LevelChanges,
    ) -> Vec<u32> {
        let mut sc = std::mem::take(&mut self.scratch);
        let dirty = self.update_with(child, dirty_child_cells, changes, &mut sc);
        self.scratch = sc;
        dirty
    }

    fn mark_dirty(&mut self, dirty: &[u32]) {
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.epoch = 1;
        }
        for &c in dirty {
            self.mark[c as usize] = self.epoch;
        }
    }

    #[inline]
    fn is_dirty(&self, e: u32) -> bool {
        self.mark[self.elements[e as usize].cell as usize] == self.epoch
    }

    fn update_with<C: ChildLevel>(
        &mut self,
        child: &mut C,
        dirty_child_cells: &[u32],
        changes: &mut LevelChanges,
        sc: &mut Scratch,
    ) -> Vec<u32> {
        let child_dims = child.cell_dims();
        let shift = self.shift;
        let mut dirty: Vec<u32> = dirty_child_cells
            .iter()
            .map(|&c| linear(coords(c, child_dims).map(|x| x >> shift), self.cell_dims))
            .collect();
        dirty.sort_unstable();
        dirty.dedup();
        self.mark_dirty(&dirty);

        // Collect the old elements of dirty cells; their neighbour lists stay until rebuilt, so a
        // survivor can tell whether (and how) its connections changed.
        sc.old_elems.clear();
        sc.cell_old.clear();
        sc.touched.clear();
        for &c in &dirty {
            sc.cell_old.push(sc.old_elems.len() as u32);
            sc.old_elems.extend_from_slice(&self.cell_elements[c as usize]);
            self.cell_elements[c as usize].clear();
        }
        sc.cell_old.push(sc.old_elems.len() as u32);

        // Phase A: components of every dirty cell, matched to the old element they came from.
        sc.comps.clear();
        sc.comp_members.clear();
        sc.cell_comps.clear();
        let per_axis = 1u32 << shift;
        for &c in &dirty {
            sc.cell_comps.push(sc.comps.len() as u32);
            let cc = coords(c, self.cell_dims);
            sc.members.clear();
            for dz in 0..per_axis {
                for dy in 0..per_axis {
                    for dx in 0..per_axis {
                        let q =
                            [(cc[0] << shift) + dx, (cc[1] << shift) + dy, (cc[2] << shift) + dz];
                        if q[0] < child_dims[0] && q[1] < child_dims[1] && q[2] < child_dims[2] {
                            child.push_cell_elements(linear(q, child_dims), &mut sc.members);
                        }
                    }
                }
            }
            let m = sc.members.len();
            sc.uf.clear();
            sc.uf.extend(0..m);
            child.union_within_cell(&sc.members, cc.map(|x| x << shift), &mut sc.uf, &mut sc.nbrs);
            // Group members by root: count, then place, so each component is one slice.
            let first = sc.comps.len();
            sc.root_comp.clear();
            sc.root_comp.resize(m, u32::MAX);
            for i in 0..m {
                let r = find(&mut sc.uf, i);
                if sc.root_comp[r] == u32::MAX {
                    sc.root_comp[r] = (sc.comps.len() - first) as u32;
                    sc.comps.push(Component {
                        start: 0,
                        end: 0,
                        min_voxel: u32::MAX,
                        voxel_count: 0,
                        old_parent: NONE,
                        id: NONE,
                    });
                }
                let comp = &mut sc.comps[first + sc.root_comp[r] as usize];
                let x = sc.members[i];
                let mv = child.min_voxel(x);
                comp.end += 1;
                comp.voxel_count += child.voxel_count(x);
                if mv < comp.min_voxel {
                    comp.min_voxel = mv;
                    let p = child.parent(x);
                    let valid = p != NONE
                        && (p as usize) < self.elements.len()
                        && self.elements[p as usize].alive
                        && self.elements[p as usize].cell == c;
                    comp.old_parent = if valid { p } else { NONE };
                }
            }
            let base = sc.comp_members.len() as u32;
            let mut offset = base;
            for comp in &mut sc.comps[first..] {
                let len = comp.end;
                comp.start = offset;
                comp.end = offset;
                offset += len;
            }
            sc.comp_members.resize(offset as usize, NONE);
            for i in 0..m {
                let r = find(&mut sc.uf, i);
                let comp = &mut sc.comps[first + sc.root_comp[r] as usize];
                sc.comp_members[comp.end as usize] = sc.members[i];
                comp.end += 1;
            }
            sc.comps[first..].sort_unstable_by_key(|k| k.min_voxel);
            for comp in &sc.comps[first..] {
                sc.comp_members[comp.start as usize..comp.end as usize]
                    .sort_unstable_by_key(|&x| child.min_voxel(x));
            }
        }
        sc.cell_comps.push(sc.comps.len() as u32);

        // Phase B: keep one piece per old element (the largest), free the vanished, allocate new.
        for ci in 0..dirty.len() {
            let comps = &mut sc.comps[sc.cell_comps[ci] as usize..sc.cell_comps[ci + 1] as usize];
            for &old in &sc.old_elems[sc.cell_old[ci] as usize..sc.cell_old[ci + 1] as usize] {
                let best = comps
                    .iter()
                    .enumerate()
                    .filter(|(_, k)| k.old_parent == old)
                    .max_by_key(|(_, k)| (k.voxel_count, std::cmp::Reverse(k.min_voxel)))
                    .map(|(i, _)| i);
                if let Some(b) = best {
                    comps[b].id = old;
                } else {
                    let nbrs = std::mem::take(&mut self.elements[old as usize].neighbors);
                    for &n in &nbrs {
                        if !self.is_dirty(n) {
                            let list = &mut self.elements[n as usize].neighbors;
                            if let Ok(pos) = list.binary_search(&old) {
                                list.remove(pos);
                            }
                        }
                    }
                    sc.touched.push(dirty[ci]);
                    let e = &mut self.elements[old as usize];
                    e.neighbors = nbrs;
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
        }
        sc.fresh.clear();
        for k in 0..sc.comps.len() {
            if sc.comps[k].id != NONE {
                continue;
            }
            let origin = sc.comps[k].old_parent;
            let id = self.alloc_element();
            sc.comps[k].id = id;
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
            sc.fresh.push(id);
        }
        sc.fresh.sort_unstable();
        let fresh = std::mem::take(&mut sc.fresh);
        let is_fresh = |id: u32| fresh.binary_search(&id).is_ok();
        sc.changed.clear();
        for (ci, &c) in dirty.iter().enumerate() {
            for comp in &sc.comps[sc.cell_comps[ci] as usize..sc.cell_comps[ci + 1] as usize] {
                let id = comp.id;
                self.cell_elements[c as usize].push(id);
                let members = &sc.comp_members[comp.start as usize..comp.end as usize];
                for &x in members {
                    child.set_parent(x, id);
                }
                let e = &mut self.elements[id as usize];
                if !is_fresh(id) {
                    if e.voxel_count != comp.voxel_count {
                        changes.elements_shrunk.push((id, e.voxel_count));
                    }
                    if e.children != members || e.voxel_count != comp.voxel_count {
                        sc.changed.push(id);
                    }
                }
                e.cell = c;
                e.min_voxel = comp.min_voxel;
                e.voxel_count = comp.voxel_count;
                e.children.clear();
                e.children.extend_from_slice(members);
                e.alive = true;
            }
        }

        // Edges of every element in a dirty cell, mirrored into clean neighbours.
        for &c in &dirty {
            let base = coords(c, self.cell_dims).map(|x| x << shift);
            for k in 0..self.cell_elements[c as usize].len() {
                let e = self.cell_elements[c as usize][k];
                sc.set.clear();
                for &x in &self.elements[e as usize].children {
                    sc.nbrs.clear();
                    child.push_outside_neighbors(x, base, per_axis, &mut sc.nbrs);
                    for &n in &sc.nbrs {
                        let p = child.parent(n);
                        if p != e {
                            sc.set.push(p);
                        }
                    }
                }
                sc.set.sort_unstable();
                sc.set.dedup();
                if self.elements[e as usize].neighbors == sc.set {
                    continue;
                }
                // Mirror the difference into clean neighbours (dirty ones rebuild their own lists).
                let old = std::mem::take(&mut self.elements[e as usize].neighbors);
                let (mut i, mut j) = (0, 0);
                while i < old.len() || j < sc.set.len() {
                    let (a, b) = (
                        old.get(i).copied().unwrap_or(NONE),
                        sc.set.get(j).copied().unwrap_or(NONE),
                    );
                    if a == b {
                        i += 1;
                        j += 1;
                        continue;
                    }
                    let (p, added) = if a < b { (a, false) } else { (b, true) };
                    if added {
                        j += 1;
                    } else {
                        i += 1;
                    }
                    if self.is_dirty(p) {
                        continue;
                    }
                    let list = &mut self.elements[p as usize].neighbors;
                    match (list.binary_search(&e), added) {
                        (Err(pos), true) => list.insert(pos, e),
                        (Ok(pos), false) => {
                            list.remove(pos);
                        }
                        _ => {}
                    }
                }
                if !is_fresh(e) {
                    sc.changed.push(e);
                }
                sc.touched.push(c);
                let el = &mut self.elements[e as usize];
                el.neighbors = old;
                el.neighbors.clear();
                el.neighbors.extend_from_slice(&sc.set);
            }
        }

        // Nodes at the corners of cells whose elements appeared, vanished or changed connections:
        // elsewhere the grouping at a point (elements around it, their face links) is unchanged.
        for &(id, _) in &changes.elements_added {
            sc.touched.push(self.elements[id as usize].cell);
        }
        if !self.track_nodes {
            sc.touched.clear();
        }
        let pdims = self.cell_dims.map(|d| d + 1);
        sc.points.clear();
        for &c in &sc.touched {
            let cc = coords(c, self.cell_dims);
            for corner in 0..8u32 {
                sc.points.push(linear(
                    [cc[0] + (corner & 1), cc[1] + ((corner >> 1) & 1), cc[2] + (corner >> 2)],
                    pdims,
                ));
            }
        }
        sc.points.sort_unstable();
        sc.points.dedup();
        sc.renoded.clear();
        for pi in 0..sc.points.len() {
            let p = sc.points[pi];
            self.update_point(p, pdims, sc, &is_fresh, changes);
        }
        sc.changed.sort_unstable();
        sc.changed.dedup();
        changes.elements_changed.clone_from(&sc.changed);
        sc.renoded.sort_unstable();
        sc.renoded.dedup();
        changes.elements_renoded.clone_from(&sc.renoded);
        sc.fresh = fresh;
        dirty
    }

    /// Regroups the elements around grid point `p` into nodes, keeping old node ids where a group
    /// still holds an element that had it.
    fn update_point(
        &mut self,
        p: u32,
        pdims: [u32; 3],
        sc: &mut Scratch,
        is_fresh: &impl Fn(u32) -> bool,
        changes: &mut LevelChanges,
    ) {
        let pc = coords(p, pdims);
        sc.around.clear();
        for corner in 0..8usize {
            let b = [corner as u32 & 1, (corner as u32 >> 1) & 1, corner as u32 >> 2];
            if (0..3).any(|a| pc[a] < b[a] || pc[a] - b[a] >= self.cell_dims[a]) {
                continue;
            }
            let cell = linear([pc[0] - b[0], pc[1] - b[1], pc[2] - b[2]], self.cell_dims);
            for &e in &self.cell_elements[cell as usize] {
                sc.around.push((e, corner));
            }
        }
        let m = sc.around.len();
        sc.uf.clear();
        sc.uf.extend(0..m);
        for i in 0..m {
            let nbrs = &self.elements[sc.around[i].0 as usize].neighbors;
            for j in i + 1..m {
                if nbrs.binary_search(&sc.around[j].0).is_ok() {
                    union(&mut sc.uf, i, j);
                }
            }
        }
        // Flatten to roots once; classes in order of their smallest element key.
        for i in 0..m {
            let r = find(&mut sc.uf, i);
            sc.uf[i] = r;
        }
        sc.classes.clear();
        for i in 0..m {
            let r = sc.uf[i];
            let key = self.elements[sc.around[i].0 as usize].min_voxel;
            match sc.classes.iter_mut().find(|(_, root)| *root == r) {
                Some(entry) => entry.0 = entry.0.min(key),
                None => sc.classes.push((key, r)),
            }
        }
        sc.classes.sort_unstable();
        let mut old_nodes = std::mem::take(&mut self.point_nodes[p as usize]);
        sc.claimed.clear();
        sc.class_node.clear();
        sc.class_origin.clear();
        for ki in 0..sc.classes.len() {
            let r = sc.classes[ki].1;
            let mut pick = NONE;
            let mut origin = NONE;
            for i in 0..m {
                if sc.uf[i] != r {
                    continue;
                }
                let (e, corner) = sc.around[i];
                let n = self.elements[e as usize].nodes[corner];
                if n != NONE && old_nodes.contains(&n) {
                    origin = origin.min(n);
                    if !sc.claimed.contains(&n) {
                        pick = pick.min(n);
                    }
                }
            }
            if pick != NONE {
                sc.claimed.push(pick);
            }
            sc.class_node.push(pick);
            sc.class_origin.push(origin);
        }
        for &n in &old_nodes {
            if !sc.claimed.contains(&n) {
                self.nodes[n as usize].alive = false;
                self.free_nodes.insert(n);
                self.live_nodes -= 1;
                changes.nodes_removed.push(n);
            }
        }
        old_nodes.clear();
        for ki in 0..sc.classes.len() {
            let r = sc.classes[ki].1;
            let id = if sc.class_node[ki] == NONE {
                let id = self.alloc_node(p);
                let origin = sc.class_origin[ki];
                changes.nodes_added.push((id, (origin != NONE).then_some(origin)));
                id
            } else {
                sc.class_node[ki]
            };
            old_nodes.push(id);
            for i in 0..m {
                if sc.uf[i] == r {
                    let (e, corner) = sc.around[i];
                    let el = &mut self.elements[e as usize];
                    if el.nodes[corner] != id {
                        el.nodes[corner] = id;
                        if !is_fresh(e) {
                            sc.changed.push(e);
                            sc.renoded.push(e);
                        }
                    }
                }
            }
        }
        self.point_nodes[p as usize] = old_nodes;
    }
}

impl Clone for Level {
    /// A copy with room for the elements and nodes a few cuts add, so the first split after
    /// cloning (e.g. a what-if cut on a copy) does not move every element.
    fn clone(&self) -> Self {
        let mut elements = Vec::with_capacity(self.elements.len() + self.elements.len() / 16 + 16);
        elements.extend_from_slice(&self.elements);
        let mut nodes = Vec::with_capacity(self.nodes.len() + self.nodes.len() / 16 + 16);
        nodes.extend_from_slice(&self.nodes);
        Self {
            number: self.number,
            shift: self.shift,
            cell_dims: self.cell_dims,
            elements,
            free_elements: self.free_elements.clone(),
            live_elements: self.live_elements,
            nodes,
            free_nodes: self.free_nodes.clone(),
            live_nodes: self.live_nodes,
            cell_elements: self.cell_elements.clone(),
            point_nodes: self.point_nodes.clone(),
            mark: self.mark.clone(),
            epoch: self.epoch,
            scratch: Scratch::default(),
            track_nodes: self.track_nodes,
        }
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
