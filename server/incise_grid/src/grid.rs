//! The Dynamic Branched Grid (Jeřábková 2010, §2): fine voxels, coarse levels `1..=L` with
//! superimposed elements, and the condensed stiffness and mass of every element at the top level
//! `L` (the level the mechanics runs on).
//!
//! Edits ([`GridEdit`]) remove voxels or sever links between face neighbours (the separation-mode
//! cut). [`BranchedGrid::apply`] updates every level locally (§2.1: cell removal, split,
//! disconnect, or no topological change) and the top level's matrices by subtraction (eq. 5) or
//! direct condensation of the pieces of a split element, and reports what changed in a
//! [`GridChanges`] for the solver and surface.

use crate::condense::{
    CondensationTables, condense_mass, condense_stiffness, interpolation, lumped,
};
use crate::error::{EditError, VolumeError};
use crate::hex8::{Mat8, Mat24, Sym24, add_into, sub_from};
use crate::material::{Material, MaterialTable};
use crate::topology::{FineLevel, Level, LevelChanges, NONE, coords, linear};
use crate::volume::LabelVolume;
use incise_math::{Vec3, morton_encode};
use std::sync::Arc;

/// `k -= Σ K`, `m -= Σ M` over `removed` voxels (eq. 5), summing first so that each voxel term is
/// read once and the element is touched once.
fn subtract_voxels(
    tables: &CondensationTables,
    removed: &[(u32, u32, u16)],
    dims: [u32; 3],
    top_level: u32,
    k: &mut Sym24,
    m: &mut Mat8,
) {
    let mut ks = Sym24::zeros();
    let mut ms = [0.0; 64];
    for &(_, v, mat) in removed {
        let (kv, mv) =
            tables.voxel_terms(usize::from(mat), BranchedGrid::local_morton(v, dims, top_level));
        ks.add_assign(kv);
        add_into(&mut ms, mv);
    }
    k.sub_assign(&ks);
    sub_from(m, &ms);
}

/// Deepest supported level: a level-6 cell holds 262,144 voxels and its product table 1.2 GB.
pub const MAX_LEVELS: u32 = 5;

/// Condensed matrices of one top-level element.
#[derive(Clone, Debug, PartialEq)]
pub struct ElementMatrices {
    /// Stiffness `K` (24×24, N/m), degree of freedom `3·corner + axis`.
    pub stiffness: Mat24,
    /// Consistent mass `m` (8×8, kg) with `M = m ⊗ I₃`.
    pub mass: Mat8,
    /// Row sums of `m`: the lumped mass of each corner (kg).
    pub lumped_mass: [f64; 8],
}

impl ElementMatrices {
    fn new(stiffness: Mat24, mass: &Mat8) -> Self {
        let lumped_mass = lumped(mass);
        Self { stiffness, mass: *mass, lumped_mass }
    }
}

/// A set of voxel removals and link severings applied in one update.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GridEdit {
    /// Voxels to empty (already empty ones are ignored).
    pub remove_voxels: Vec<u32>,
    /// Pairs of face-neighbour voxels whose link to cut (the separation-mode cut: no volume is lost).
    pub sever_links: Vec<(u32, u32)>,
}

/// What one [`BranchedGrid::apply`] changed at the top level, in top-level ids.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GridChanges {
    /// Topology changes of the top level (element and node ids).
    pub top: LevelChanges,
    /// Top-level elements whose stiffness and mass were recomputed or updated.
    pub matrices_updated: Vec<u32>,
    /// Voxels actually removed (those that held material).
    pub voxels_removed: usize,
    /// Links actually severed (those not severed before).
    pub links_severed: usize,
    /// The voxels the edit changed (those removed, both ends of each link severed), sorted.
    pub dirty_voxels: Vec<u32>,
}

/// Element and node counts of one level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelSummary {
    /// Level number.
    pub level: u32,
    /// Live elements.
    pub elements: usize,
    /// Elements sharing their cell with another element.
    pub superimposed: usize,
    /// Live nodes.
    pub nodes: usize,
    /// Cells holding at least one element.
    pub occupied_cells: usize,
    /// Voxels held by elements / voxel capacity of the occupied cells (1 = every cell full).
    pub fill_ratio: f64,
}

/// What [`BranchedGrid::element_voxels_where`] does with a block of voxels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Block {
    /// None of its voxels is wanted.
    Skip,
    /// All of them are.
    All,
    /// Some may be: its voxels are listed, asking for the blocks inside it first.
    Some,
}

/// The Dynamic Branched Grid of one organ.
#[derive(Clone, Debug)]
pub struct BranchedGrid {
    spacing: Vec3,
    origin: Vec3,
    direction: [[f64; 3]; 3],
    materials: Vec<Material>,
    material_labels: Vec<u16>,
    fine: FineLevel,
    levels: Vec<Level>,
    top_level: u32,
    tables: Arc<CondensationTables>,
    /// Boxed so that growing the list after a split moves pointers, not 5 KB per element.
    matrices: Vec<Option<Box<ElementMatrices>>>,
}

impl BranchedGrid {
    /// Builds every level up to `top_level` from a label volume and condenses the top level's
    /// stiffness and mass. Every non-zero label of `volume` must have a material in `materials`.
    pub fn build(
        volume: &LabelVolume,
        materials: &MaterialTable,
        top_level: u32,
    ) -> Result<Self, VolumeError> {
        if top_level > MAX_LEVELS {
            return Err(VolumeError::LevelTooDeep { level: top_level, max: MAX_LEVELS });
        }
        let mut index_of = vec![0u16; usize::from(u16::MAX) + 1];
        let mut mats = Vec::new();
        let mut labels = Vec::new();
        for (label, m) in materials.iter() {
            m.validate(label)?;
            if mats.len() >= usize::from(u16::MAX) {
                return Err(VolumeError::TooManyMaterials { count: materials.len() });
            }
            mats.push(*m);
            labels.push(label);
            index_of[usize::from(label)] = mats.len() as u16;
        }
        let mut material = Vec::with_capacity(volume.labels().len());
        for &l in volume.labels() {
            let m = index_of[usize::from(l)];
            if l != 0 && m == 0 {
                let count = volume.labels().iter().filter(|&&x| x == l).count();
                return Err(VolumeError::UnknownLabel { label: l, count });
            }
            material.push(m);
        }
        if material.iter().all(|&m| m == 0) {
            return Err(VolumeError::EmptyForeground);
        }
        let dims = volume.dims().map(|d| d as u32);
        let n = material.len();
        let fine = FineLevel { dims, material, severed: vec![0; n], parent: vec![NONE; n] };
        let placement = (volume.spacing(), volume.origin(), volume.direction());
        Ok(Self::from_fine(fine, placement, mats, labels, top_level))
    }

    /// Builds all levels and the top level's matrices over `fine` (whose parents are reset).
    fn from_fine(
        mut fine: FineLevel,
        placement: (Vec3, Vec3, [[f64; 3]; 3]),
        materials: Vec<Material>,
        material_labels: Vec<u16>,
        top_level: u32,
    ) -> Self {
        let (spacing, origin, direction) = placement;
        fine.parent.iter_mut().for_each(|p| *p = NONE);
        let levels = if top_level == 0 {
            vec![Level::new(0, 0, fine.dims)]
        } else {
            let mut v: Vec<Level> = Vec::with_capacity(top_level as usize);
            let mut d = fine.dims;
            for l in 1..=top_level {
                let lvl = Level::new(l, 1, d);
                d = lvl.cell_dims();
                v.push(if l == top_level { lvl } else { lvl.without_node_tracking() });
            }
            v
        };
        let tables = Arc::new(CondensationTables::new(spacing, &materials, top_level));
        let all: Vec<u32> =
            (0..fine.material.len() as u32).filter(|&v| fine.material[v as usize] != 0).collect();
        let mut grid = Self {
            spacing,
            origin,
            direction,
            materials,
            material_labels,
            fine,
            levels,
            top_level,
            tables,
            matrices: Vec::new(),
        };
        grid.update_levels(&all);
        let ids: Vec<u32> = grid.top().elements().map(|(id, _)| id).collect();
        grid.matrices = vec![None; grid.top().element_capacity()];
        for id in ids {
            grid.matrices[id as usize] = Some(Box::new(grid.condense_direct(id)));
        }
        grid
    }

    /// Runs the level updates bottom-up from the dirty fine voxels; returns the top level's changes.
    fn update_levels(&mut self, dirty_voxels: &[u32]) -> LevelChanges {
        let (first, rest) = self.levels.split_first_mut().expect("at least one level");
        let mut changes = LevelChanges::default();
        let mut dirty = first.update(&mut self.fine, dirty_voxels, &mut changes);
        let mut below: &mut Level = first;
        for lvl in rest.iter_mut() {
            changes = LevelChanges::default();
            dirty = lvl.update(below, &dirty, &mut changes);
            below = lvl;
        }
        changes
    }

    /// Applies voxel removals and link severings, updating every level and the top level's
    /// matrices locally. Nothing changes if the edit names a voxel or link that does not exist.
    ///
    /// # Panics
    /// Only on a broken internal invariant (a live element without matrices).
    pub fn apply(&mut self, edit: &GridEdit) -> Result<GridChanges, EditError> {
        let count = self.fine.material.len();
        for &v in &edit.remove_voxels {
            if v as usize >= count {
                return Err(EditError::VoxelOutOfRange { voxel: v, count });
            }
        }
        for &(a, b) in &edit.sever_links {
            for v in [a, b] {
                if v as usize >= count {
                    return Err(EditError::VoxelOutOfRange { voxel: v, count });
                }
            }
            if self.fine.link_axis(a.min(b), a.max(b)).is_none() {
                return Err(EditError::NotALink { a, b });
            }
        }
        // (top owner, voxel, material) of every voxel really removed, before the topology moves.
        let mut removed: Vec<(u32, u32, u16)> = Vec::new();
        for &v in &edit.remove_voxels {
            let m = self.fine.material[v as usize];
            if m != 0 {
                removed.push((self.top_owner(v), v, m - 1));
            }
        }
        removed.sort_unstable();
        removed.dedup();
        let mut dirty: Vec<u32> = Vec::with_capacity(removed.len() + 2 * edit.sever_links.len());
        for &(_, v, _) in &removed {
            self.fine.material[v as usize] = 0;
            self.fine.parent[v as usize] = NONE;
            dirty.push(v);
        }
        let mut links_severed = 0;
        for &(a, b) in &edit.sever_links {
            let (lo, hi) = (a.min(b), a.max(b));
            let axis = self.fine.link_axis(lo, hi).expect("validated above");
            let bits = &mut self.fine.severed[lo as usize];
            if *bits & (1 << axis) == 0 {
                *bits |= 1 << axis;
                links_severed += 1;
                dirty.extend([lo, hi]);
            }
        }
        dirty.sort_unstable();
        dirty.dedup();
        if dirty.is_empty() {
            return Ok(GridChanges::default());
        }
        let top = self.update_levels(&dirty);

        // Matrices: drop the vanished, condense the new pieces, update the shrunk ones (eq. 5).
        let capacity = self.top().element_capacity();
        if self.matrices.len() < capacity {
            self.matrices.resize(capacity, None);
        }
        for &id in &top.elements_removed {
            self.matrices[id as usize] = None;
        }
        let mut updated: Vec<u32> = Vec::new();
        // New pieces of split elements: direct condensation of their (usually few) voxels.
        for &(id, _) in &top.elements_added {
            self.matrices[id as usize] = Some(Box::new(self.condense_direct(id)));
            updated.push(id);
        }
        for &(id, old_count) in &top.elements_shrunk {
            let now = self.top().element(id).map_or(0, |e| e.voxel_count);
            let lo = removed.partition_point(|r| r.0 < id);
            let hi = removed.partition_point(|r| r.0 <= id);
            let mine = &removed[lo..hi];
            let pieces: Vec<u32> = top
                .elements_added
                .iter()
                .filter(|&&(_, o)| o == Some(id))
                .map(|&(p, _)| p)
                .collect();
            let piece_voxels: u32 =
                pieces.iter().map(|&p| self.top().element(p).map_or(0, |e| e.voxel_count)).sum();
            let subtracted = mine.len() as u32 + piece_voxels;
            // Eq. 5: what left the element (removed voxels, split-off pieces) is subtracted, as long as
            // less leaves than stays; beyond that a small difference of large sums would lose digits.
            if subtracted == old_count - now && subtracted < now {
                let mats = self.matrices[id as usize].as_ref().expect("live element has matrices");
                let mut k = Sym24::from_upper(&mats.stiffness);
                let mut m = mats.mass;
                subtract_voxels(&self.tables, mine, self.fine.dims, self.top_level, &mut k, &mut m);
                for &p in &pieces {
                    let pm = self.matrices[p as usize].as_ref().expect("piece condensed above");
                    k.sub_assign(&Sym24::from_upper(&pm.stiffness));
                    sub_from(&mut m, &pm.mass);
                }
                self.matrices[id as usize] = Some(Box::new(ElementMatrices::new(k.to_full(), &m)));
            } else {
                self.matrices[id as usize] = Some(Box::new(self.condense_direct(id)));
            }
            updated.push(id);
        }
        updated.sort_unstable();
        updated.dedup();
        Ok(GridChanges {
            top,
            matrices_updated: updated,
            voxels_removed: removed.len(),
            links_severed,
            dirty_voxels: dirty,
        })
    }

    /// The top-level element owning voxel `v` (or `NONE` when it is empty).
    fn top_owner(&self, v: u32) -> u32 {
        let mut e = self.fine.parent[v as usize];
        for lvl in &self.levels[..self.levels.len() - 1] {
            if e == NONE {
                return NONE;
            }
            e = lvl.parent_of(e);
        }
        e
    }

    /// The top-level element that owns voxel `v`'s material: the element a point inside the voxel
    /// moves with (an embedded surface vertex, paper 1 §3). `None` when `v` is empty or out of
    /// range.
    #[must_use]
    pub fn voxel_element(&self, v: u32) -> Option<u32> {
        if v as usize >= self.fine.material.len() {
            return None;
        }
        let e = self.top_owner(v);
        (e != NONE).then_some(e)
    }

    /// Morton index (eq. 6) of voxel `v` inside its top-level cell.
    fn local_morton(v: u32, dims: [u32; 3], top_level: u32) -> u64 {
        let c = coords(v, dims);
        let mask = (1u32 << top_level) - 1;
        morton_encode(c[0] & mask, c[1] & mask, c[2] & mask)
    }

    /// The fine voxels owned by top-level element `id`, in no particular order.
    #[must_use]
    pub fn element_voxels(&self, id: u32) -> Vec<u32> {
        let mut out = Vec::new();
        self.element_voxels_into(id, &mut out);
        out
    }

    /// [`BranchedGrid::element_voxels`] appended to `out` (a buffer kept by a caller that asks
    /// for many elements).
    pub fn element_voxels_into(&self, id: u32, out: &mut Vec<u32>) {
        let top = self.levels.len() - 1;
        if let Some(e) = self.levels[top].element(id) {
            self.collect_voxels(top, e, out);
        }
    }

    /// [`BranchedGrid::element_voxels_into`] keeping only the blocks `keep` accepts: before a
    /// descendant's voxels are listed, `keep(first, size)` is asked for its cell's block of fine
    /// voxels (the lowest voxel's coordinates and the edge in voxels): [`Block::Skip`] skips it
    /// whole, [`Block::All`] takes all its voxels without asking for the blocks inside it. The
    /// voxels kept come in the same order as all of them would.
    pub fn element_voxels_where(
        &self,
        id: u32,
        keep: &mut impl FnMut([u32; 3], u32) -> Block,
        out: &mut Vec<u32>,
    ) {
        let top = self.levels.len() - 1;
        if let Some(e) = self.levels[top].element(id) {
            self.collect_voxels_where(top, e, keep, out);
        }
    }

    fn collect_voxels_where(
        &self,
        level_index: usize,
        e: &crate::topology::Element,
        keep: &mut impl FnMut([u32; 3], u32) -> Block,
        out: &mut Vec<u32>,
    ) {
        let level = &self.levels[level_index];
        let size = 1u32 << level.level();
        match keep(level.cell_coords(e.cell).map(|c| c * size), size) {
            Block::Skip => {}
            Block::All => self.collect_voxels(level_index, e, out),
            Block::Some if level_index == 0 => out.extend_from_slice(&e.children),
            Block::Some => {
                for &c in &e.children {
                    let child = &self.levels[level_index - 1]
                        .element(c)
                        .expect("child of a live element is live");
                    self.collect_voxels_where(level_index - 1, child, keep, out);
                }
            }
        }
    }

    fn collect_voxels(&self, level_index: usize, e: &crate::topology::Element, out: &mut Vec<u32>) {
        if level_index == 0 {
            out.extend_from_slice(&e.children);
        } else {
            for &c in &e.children {
                let child = &self.levels[level_index - 1]
                    .element(c)
                    .expect("child of a live element is live");
                self.collect_voxels(level_index - 1, child, out);
            }
        }
    }

    /// The fine voxels owned by top-level element `id`, each with its offset in voxels from its
    /// cell's lowest corner (each component below `2^top_level`).
    ///
    /// An element alone in its cell owns every voxel with material in the cell's box, so the box
    /// is scanned row by row, reading only the labels (index order): a few cache lines per row,
    /// where walking the element's descendants would follow a pointer per child. The pieces of a
    /// split cell are walked (in the order of [`BranchedGrid::element_voxels_into`]), since they
    /// usually hold a small part of their box.
    pub fn element_voxel_offsets_into(&self, id: u32, out: &mut Vec<(u32, [u32; 3])>) {
        let top = self.top();
        let Some(e) = top.element(id) else { return };
        let per = 1u32 << self.top_level;
        let corner = top.cell_coords(e.cell).map(|c| c * per);
        let dims = self.fine.dims;
        if top.cell_elements(e.cell).len() > 1 {
            let start = out.len();
            let mut voxels = Vec::with_capacity(e.voxel_count as usize);
            self.collect_voxels(self.levels.len() - 1, e, &mut voxels);
            out.extend(voxels.into_iter().map(|v| {
                let c = coords(v, dims);
                (v, std::array::from_fn(|a| c[a] - corner[a]))
            }));
            debug_assert_eq!(out.len() - start, e.voxel_count as usize);
            return;
        }
        let end: [u32; 3] = std::array::from_fn(|a| (corner[a] + per).min(dims[a]));
        for z in corner[2]..end[2] {
            for y in corner[1]..end[1] {
                let row = linear([0, y, z], dims);
                for x in corner[0]..end[0] {
                    let v = row + x;
                    if self.fine.material[v as usize] != 0 {
                        out.push((v, [x - corner[0], y - corner[1], z - corner[2]]));
                    }
                }
            }
        }
    }

    /// Direct condensation (eq. 2–4, 6) of top-level element `id`.
    fn condense_direct(&self, id: u32) -> ElementMatrices {
        let (k, m, _) = self.condense_direct_with_steps(id);
        ElementMatrices::new(k, &m)
    }

    /// Direct condensation of top-level element `id`, with the number of condensation steps.
    #[must_use]
    pub fn condense_direct_with_steps(&self, id: u32) -> (Mat24, Mat8, usize) {
        let mut owned = Vec::new();
        self.element_voxel_offsets_into(id, &mut owned);
        let mut voxels: Vec<(u64, u16)> = owned
            .into_iter()
            .map(|(v, o)| (morton_encode(o[0], o[1], o[2]), self.fine.material[v as usize] - 1))
            .collect();
        self.tables.condense(&mut voxels)
    }

    /// Recursive condensation (eq. 1), the 8 → 1 scheme of Nesme et al. 2006, level by level from
    /// the voxels: the reference direct condensation is tested against. Indexed by top element id.
    ///
    /// # Panics
    /// Only on a broken internal invariant (a live element with a dead child).
    #[must_use]
    pub fn condense_recursive(&self) -> Vec<Option<ElementMatrices>> {
        let voxel_terms = |v: u32, pos_bits: u32| -> (Mat24, Mat8) {
            let vm = self.tables.voxel(usize::from(self.fine.material[v as usize] - 1));
            if pos_bits == u32::MAX {
                return (vm.stiffness.clone(), vm.mass);
            }
            let c = coords(v, self.fine.dims);
            let n = interpolation([c[0] & 1, c[1] & 1, c[2] & 1], 1);
            (condense_stiffness(&vm.stiffness, &n), condense_mass(&vm.mass, &n))
        };
        if self.top_level == 0 {
            let top = self.top();
            let mut out = vec![None; top.element_capacity()];
            for (id, e) in top.elements() {
                let (k, m) = voxel_terms(e.children[0], u32::MAX);
                out[id as usize] = Some(ElementMatrices::new(k, &m));
            }
            return out;
        }
        let mut below: Vec<Option<(Mat24, Mat8)>> = Vec::new();
        for (li, lvl) in self.levels.iter().enumerate() {
            let mut here: Vec<Option<(Mat24, Mat8)>> = vec![None; lvl.element_capacity()];
            for (id, e) in lvl.elements() {
                let mut k = Mat24::zeros();
                let mut m = [0.0; 64];
                for &c in &e.children {
                    let (kc, mc) = if li == 0 {
                        voxel_terms(c, 0)
                    } else {
                        let child_level = &self.levels[li - 1];
                        let cc = child_level
                            .cell_coords(child_level.element(c).expect("live child").cell);
                        let n = interpolation([cc[0] & 1, cc[1] & 1, cc[2] & 1], 1);
                        let (ka, ma) = below[c as usize].as_ref().expect("child condensed");
                        (condense_stiffness(ka, &n), condense_mass(ma, &n))
                    };
                    k.add_assign(&kc);
                    add_into(&mut m, &mc);
                }
                here[id as usize] = Some((k, m));
            }
            below = here;
        }
        below.into_iter().map(|x| x.map(|(k, m)| ElementMatrices::new(k, &m))).collect()
    }

    /// Condensed matrices of top-level element `id`.
    #[must_use]
    pub fn matrices(&self, id: u32) -> Option<&ElementMatrices> {
        self.matrices.get(id as usize).and_then(Option::as_deref)
    }

    /// The level the mechanics runs on.
    ///
    /// # Panics
    /// Never: a grid always holds at least one level.
    #[must_use]
    pub fn top(&self) -> &Level {
        self.levels.last().expect("at least one level")
    }

    /// Its number `L`.
    #[must_use]
    pub fn top_level(&self) -> u32 {
        self.top_level
    }

    /// Coarse level `l` (`1..=L`; level 0 too when `L = 0`).
    #[must_use]
    pub fn level(&self, l: u32) -> Option<&Level> {
        self.levels.iter().find(|lvl| lvl.level() == l)
    }

    /// Keeps every level's nodes current from now on, not only the top level's: what composite
    /// elements read below the top after each cut ([`crate::composite::CompositeLevels`]), which
    /// otherwise computes them for the whole level each time. Each update then costs the nodes
    /// around its dirty cells at every level.
    pub fn track_all_nodes(&mut self) {
        for lvl in &mut self.levels {
            if !lvl.tracks_nodes() {
                *lvl = lvl.with_nodes().into_owned();
            }
        }
    }

    /// All stored levels, bottom-up.
    #[must_use]
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// The fine voxels.
    #[must_use]
    pub fn fine(&self) -> &FineLevel {
        &self.fine
    }

    /// Voxel edge lengths (m).
    #[must_use]
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// Edge lengths (m) of a top-level element.
    #[must_use]
    pub fn element_size(&self) -> Vec3 {
        let s = f64::from(1u32 << self.top_level);
        self.spacing.map(|h| h * s)
    }

    /// Rest position of top-level node `id` in the grid frame (metres; voxel (0,0,0) spans
    /// `[0, spacing]`). [`BranchedGrid::world_from_grid`] maps it to the image's world frame.
    #[must_use]
    pub fn node_rest_position(&self, id: u32) -> Option<Vec3> {
        let top = self.top();
        let p = top.point_coords(top.node(id)?.point);
        let size = self.element_size();
        Some(std::array::from_fn(|a| f64::from(p[a]) * size[a]))
    }

    /// World position (m) of a point given in the grid frame.
    #[must_use]
    pub fn world_from_grid(&self, p: Vec3) -> Vec3 {
        let q: Vec3 = std::array::from_fn(|a| p[a] - 0.5 * self.spacing[a]);
        std::array::from_fn(|r| {
            self.origin[r] + (0..3).map(|c| self.direction[r][c] * q[c]).sum::<f64>()
        })
    }

    /// Materials in index order, with the label each came from.
    pub fn materials(&self) -> impl Iterator<Item = (u16, &Material)> {
        self.material_labels.iter().copied().zip(self.materials.iter())
    }

    /// The product tables used for condensation.
    #[must_use]
    pub fn tables(&self) -> &CondensationTables {
        &self.tables
    }

    /// Per-level element, superimposed-element and node counts, bottom-up, starting with level 0
    /// (the voxels themselves, computed on demand with the same routine as the coarse levels).
    #[must_use]
    pub fn summary(&self) -> Vec<LevelSummary> {
        let mut out = Vec::new();
        if self.top_level > 0 {
            let mut fine = self.fine.clone();
            let mut l0 = Level::new(0, 0, fine.dims);
            let all: Vec<u32> = (0..fine.material.len() as u32)
                .filter(|&v| fine.material[v as usize] != 0)
                .collect();
            let mut ch = LevelChanges::default();
            l0.update(&mut fine, &all, &mut ch);
            out.push(Self::summarize(&l0));
        }
        out.extend(self.levels.iter().map(|l| Self::summarize(&l.with_nodes())));
        out
    }

    fn summarize(lvl: &Level) -> LevelSummary {
        let mut occupied = 0usize;
        let cells = lvl.cell_dims().iter().map(|&d| d as usize).product::<usize>();
        let mut voxels = 0u64;
        for c in 0..cells as u32 {
            if !lvl.cell_elements(c).is_empty() {
                occupied += 1;
            }
        }
        for (_, e) in lvl.elements() {
            voxels += u64::from(e.voxel_count);
        }
        let capacity = occupied as f64 * f64::from(1u32 << (3 * lvl.level()));
        LevelSummary {
            level: lvl.level(),
            elements: lvl.element_count(),
            superimposed: lvl.superimposed_count(),
            nodes: lvl.node_count(),
            occupied_cells: occupied,
            fill_ratio: if capacity > 0.0 { voxels as f64 / capacity } else { 0.0 },
        }
    }

    /// The fine level's current labels (`x` fastest; removed voxels are 0), e.g. to write the cut
    /// organ back to a volume file. Severed links are not labels and are not included.
    #[must_use]
    pub fn fine_labels(&self) -> Vec<u16> {
        self.fine
            .material
            .iter()
            .map(|&m| if m == 0 { 0 } else { self.material_labels[usize::from(m - 1)] })
            .collect()
    }

    /// A grid built from scratch on this grid's current fine level (removed voxels and severed
    /// links included): the reference every incremental update must equal.
    #[must_use]
    pub fn rebuild(&self) -> Self {
        let placement = (self.spacing, self.origin, self.direction);
        Self::from_fine(
            self.fine.clone(),
            placement,
            self.materials.clone(),
            self.material_labels.clone(),
            self.top_level,
        )
    }
}
