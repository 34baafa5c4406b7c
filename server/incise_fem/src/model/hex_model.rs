//! The mechanical model of a grid's top level: compact node numbering, rest positions, element
//! connectivity with each element's condensed stiffness and mass (Jeřábková 2010 §2.2), and the
//! lumped node masses.

use incise_grid::composite::CompositeLevels;
use incise_grid::hex8::{Mat8, Mat24};
use incise_grid::{BranchedGrid, GridChanges};
use incise_math::Vec3;
use std::collections::HashMap;
use std::sync::Arc;

/// One hexahedral element of the model.
#[derive(Clone, Debug)]
pub struct HexElement {
    /// Model node of each corner (corner `c` at `(c & 1, (c >> 1) & 1, c >> 2)`).
    pub nodes: [u32; 8],
    /// Condensed stiffness (N/m), degree of freedom `3·corner + axis`, exactly symmetric. Elements
    /// with bit-identical matrices (every full cell of one material) share one copy, so the
    /// element loops of a large mesh read a few kilobytes instead of 4.6 kB per element.
    pub stiffness: Arc<Mat24>,
    /// Consistent mass block (kg), `M = m ⊗ I₃`.
    pub mass: Mat8,
    /// The element's id in the grid's top level.
    pub grid_id: u32,
}

/// How a coarse element's stiffness is made from the voxels it holds. Masses are the condensed
/// ones with every kind, so all carry the same load; at level 0 every kind is the voxel's own
/// stiffness.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ElementKind {
    /// The Galerkin condensation of Jeřábková 2010 eq. 1–4. A cut re-condenses the elements whose
    /// voxels it removed.
    #[default]
    Condensed,
    /// Composite cells after Nesme et al. 2009 ([`incise_grid::composite`]): softer where a cell
    /// holds a thin neck beside bulk. Which of a cell's points are its own depends on its
    /// neighbours, so a cut makes again, at every level, the cells within one cell of the
    /// voxels it changed ([`incise_grid::composite::CompositeLevels::update`]).
    Composite,
    /// Incompatible modes (Wilson et al. 1973, [`incise_grid::incompatible`]): coarse elements
    /// that bend without shear locking. Each depends only on its own voxels, so a cut recomputes
    /// only the elements it re-condenses.
    Incompatible,
}

impl ElementKind {
    /// Every kind, cheapest to cut first.
    pub const ALL: [Self; 3] = [Self::Condensed, Self::Incompatible, Self::Composite];

    /// The kind's name in scenes and reports.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Condensed => "condensed",
            Self::Composite => "composite",
            Self::Incompatible => "incompatible",
        }
    }

    /// The kind called `name` ([`ElementKind::name`]).
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// Nodes and elements ready for the force fields and solvers.
#[derive(Clone, Debug)]
pub struct HexModel {
    /// Rest position of each node (m, grid frame).
    pub rest: Vec<Vec3>,
    /// Lumped mass of each node (kg).
    pub lumped_mass: Vec<f64>,
    /// The elements.
    pub elements: Vec<HexElement>,
    /// Edge lengths of every element (m).
    pub element_size: Vec3,
    /// Grid node id of each model node.
    pub grid_node: Vec<u32>,
    /// How the elements' stiffnesses are made; [`HexModel::update`] keeps to it.
    pub element: ElementKind,
    /// With composite elements: every grid level's composite stiffness, so that a cut makes
    /// again only the cells near it (shared between copies until one is cut).
    composite: Option<Arc<CompositeLevels>>,
}

impl HexModel {
    /// The model of `grid`'s top level. Nodes are numbered in grid-node order, elements in
    /// grid-element order, so the numbering is deterministic.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without matrices or with a dead node).
    #[must_use]
    pub fn from_grid(grid: &BranchedGrid) -> Self {
        Self::build(grid)
    }

    /// The model of `grid`'s top level with elements of `kind`.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without matrices or with a dead node).
    #[must_use]
    pub fn from_grid_of_kind(grid: &BranchedGrid, kind: ElementKind) -> Self {
        match kind {
            ElementKind::Condensed => Self::from_grid(grid),
            ElementKind::Composite => Self::from_grid_composite(grid),
            ElementKind::Incompatible => Self::from_grid_incompatible(grid),
        }
    }

    /// The model of `grid` after an edit whose change list is `changes`, `self` being the model
    /// of the grid before it: every element the grid did not condense again keeps its (shared)
    /// stiffness and mass; only added and re-condensed elements get new ones. Equal to
    /// [`HexModel::from_grid_of_kind`] of the edited grid, without re-reading and re-sharing
    /// every element's matrices ([`HexModel::update`] on a copy).
    #[must_use]
    pub fn updated(&self, grid: &BranchedGrid, changes: &GridChanges) -> Self {
        let mut model = self.clone();
        model.update(grid, changes);
        model
    }

    /// Brings this model of the grid before an edit up to date with `grid` after it (`changes`
    /// being the edit's change list), in place: [`HexModel::from_grid_of_kind`] of the edited
    /// grid with this model's [`ElementKind`], bit for bit, but only the nodes and elements the
    /// edit added or changed are read from the grid (matrices only where it condensed them again,
    /// shared among themselves), and only the lumped masses of the nodes around them summed
    /// again. The others keep their data (stiffness included: the same `Arc`) and move to their
    /// new indices; composite elements near the edit get their stiffness again (see
    /// [`ElementKind::Composite`]). Returns how the indices moved.
    ///
    /// # Panics
    /// Only on a broken grid invariant, or if `self` is not the model of the grid before the
    /// edit.
    pub fn update(&mut self, grid: &BranchedGrid, changes: &GridChanges) -> Renumbering {
        let top = &changes.top;
        let sorted = |ids: &mut Vec<u32>| {
            ids.sort_unstable();
            ids.dedup();
        };
        let mut nodes_gone = top.nodes_removed.clone();
        sorted(&mut nodes_gone);
        let mut nodes_new: Vec<u32> = top.nodes_added.iter().map(|&(id, _)| id).collect();
        sorted(&mut nodes_new);
        let mut elements_gone = top.elements_removed.clone();
        sorted(&mut elements_gone);
        let mut elements_new: Vec<u32> = top.elements_added.iter().map(|&(id, _)| id).collect();
        sorted(&mut elements_new);
        let mut touched: Vec<u32> = elements_new
            .iter()
            .chain(&top.elements_changed)
            .chain(&changes.matrices_updated)
            .copied()
            .collect();
        sorted(&mut touched);
        // Of those, the ones whose matrices the grid computed again; the others (their nodes or
        // neighbours changed) keep theirs.
        let mut recondensed: Vec<u32> =
            elements_new.iter().chain(&changes.matrices_updated).copied().collect();
        sorted(&mut recondensed);

        // Nodes: the old ones without those removed, the new ones merged in by grid id (a new
        // node may reuse the id of one removed in the same edit). New nodes start massless; the
        // elements around them are touched, so their masses are summed below.
        let grid_node_before = self.grid_node.clone();
        let old_count = grid_node_before.len();
        let (node_before, new_of_old) = if nodes_gone.is_empty() && nodes_new.is_empty() {
            ((0..old_count as u32).map(Some).collect(), (0..old_count as u32).collect())
        } else {
            let mut merged: Vec<(u32, Option<u32>)> =
                Vec::with_capacity(old_count + nodes_new.len());
            let mut fresh = nodes_new.iter().copied().peekable();
            for (j, &g) in grid_node_before.iter().enumerate() {
                while let Some(id) = fresh.next_if(|&id| id < g) {
                    merged.push((id, None));
                }
                if nodes_gone.binary_search(&g).is_err() {
                    merged.push((g, Some(j as u32)));
                }
            }
            merged.extend(fresh.map(|id| (id, None)));
            let mut new_of_old = vec![u32::MAX; old_count];
            let (mut rest, mut lumped) =
                (Vec::with_capacity(merged.len()), Vec::with_capacity(merged.len()));
            for (k, &(id, before)) in merged.iter().enumerate() {
                if let Some(j) = before {
                    new_of_old[j as usize] = k as u32;
                    rest.push(self.rest[j as usize]);
                    lumped.push(self.lumped_mass[j as usize]);
                } else {
                    rest.push(grid.node_rest_position(id).expect("an added node is live"));
                    lumped.push(0.0);
                }
            }
            self.grid_node = merged.iter().map(|&(id, _)| id).collect();
            (self.rest, self.lumped_mass) = (rest, lumped);
            (merged.into_iter().map(|(_, before)| before).collect(), new_of_old)
        };
        debug_assert_eq!(self.grid_node.len(), grid.top().node_count());
        let index_of = |grid_node: &[u32], n: u32| -> u32 {
            grid_node.binary_search(&n).expect("an element's node is live") as u32
        };

        // Elements, in place (a fresh vector of these 560-byte elements cost more in page faults
        // than the rest of the update): the removed ones leave, the touched ones are read from
        // the grid where they lie (their matrices only if the grid condensed them again), the
        // others have their nodes renumbered, and the new ones are merged in by grid id (new
        // ids mostly come after every old one). Nodes an element left or joined get their lumped
        // mass summed again.
        let old_ids: Vec<u32> = self.elements.iter().map(|e| e.grid_id).collect();
        let mut dirty = vec![false; self.rest.len()];
        let gone = |id: u32| elements_gone.binary_search(&id).is_ok();
        let is_touched = |id: u32| touched.binary_search(&id).is_ok();
        for e in &self.elements {
            if gone(e.grid_id) || is_touched(e.grid_id) {
                for &n in &e.nodes {
                    if let Some(&k) = new_of_old.get(n as usize).filter(|&&k| k != u32::MAX) {
                        dirty[k as usize] = true;
                    }
                }
            }
        }
        if !elements_gone.is_empty() {
            self.elements.retain(|e| !gone(e.grid_id));
        }
        let renumbered = !nodes_gone.is_empty() || !nodes_new.is_empty();
        let mut shared = SharedMatrices::default();
        let mut fresh_matrices = |id: u32| {
            let m = grid.matrices(id).expect("live element has matrices");
            (shared.get(m.stiffness.symmetrized()), m.mass)
        };
        let grid_nodes = |id: u32, dirty: &mut [bool]| {
            let e = grid.top().element(id).expect("a touched element is live");
            let nodes = e.nodes.map(|n| index_of(&self.grid_node, n));
            for &n in &nodes {
                dirty[n as usize] = true;
            }
            nodes
        };
        for e in &mut self.elements {
            if is_touched(e.grid_id) {
                e.nodes = grid_nodes(e.grid_id, &mut dirty);
                if recondensed.binary_search(&e.grid_id).is_ok() {
                    (e.stiffness, e.mass) = fresh_matrices(e.grid_id);
                }
            } else if renumbered {
                for n in &mut e.nodes {
                    *n = new_of_old[*n as usize];
                    debug_assert_ne!(*n, u32::MAX, "an untouched element lost a node");
                }
            }
        }
        let added: Vec<HexElement> = elements_new
            .iter()
            .map(|&id| {
                let nodes = grid_nodes(id, &mut dirty);
                let (stiffness, mass) = fresh_matrices(id);
                HexElement { nodes, stiffness, mass, grid_id: id }
            })
            .collect();
        merge_by_grid_id(&mut self.elements, added);
        let mut element_before = Vec::with_capacity(self.elements.len());
        let mut new_matrices = Vec::new();
        let mut survivors = old_ids.iter().enumerate().filter(|&(_, &id)| !gone(id));
        for (i, e) in self.elements.iter().enumerate() {
            if elements_new.binary_search(&e.grid_id).is_ok() {
                element_before.push(None);
                new_matrices.push(i as u32);
            } else {
                let (j, _) = survivors.next().expect("a surviving element was there before");
                element_before.push(Some(j as u32));
                if recondensed.binary_search(&e.grid_id).is_ok() {
                    new_matrices.push(i as u32);
                }
            }
        }
        debug_assert_eq!(self.elements.len(), grid.top().element_count());

        // Each dirty node's mass summed again as `build` sums it: over the elements in order.
        for (m, &d) in self.lumped_mass.iter_mut().zip(&dirty) {
            if d {
                *m = 0.0;
            }
        }
        for e in &self.elements {
            if e.nodes.iter().any(|&n| dirty[n as usize]) {
                let m = grid.matrices(e.grid_id).expect("live element has matrices");
                for (c, &n) in e.nodes.iter().enumerate() {
                    if dirty[n as usize] {
                        self.lumped_mass[n as usize] += m.lumped_mass[c];
                    }
                }
            }
        }
        // The enriched kinds: the stiffnesses the grid condensed again are replaced by their own.
        match self.element {
            ElementKind::Condensed => {}
            ElementKind::Incompatible => {
                let mut shared = SharedMatrices::default();
                let mut voxels = Vec::new();
                for &i in &new_matrices {
                    let e = &mut self.elements[i as usize];
                    let k =
                        incise_grid::incompatible::element_stiffness(grid, e.grid_id, &mut voxels)
                            .expect("live element has a stiffness");
                    e.stiffness = shared.get(k.symmetrized());
                }
            }
            ElementKind::Composite => {
                if let Some(levels) = self.composite.as_mut() {
                    let levels = Arc::make_mut(levels);
                    let mut made = levels.update(grid, &changes.dirty_voxels);
                    // The grid's own condensation enters as the Galerkin share: an element it
                    // condensed again changes even where its composite part did not.
                    let others: Vec<u32> = new_matrices
                        .iter()
                        .map(|&i| self.elements[i as usize].grid_id)
                        .filter(|id| made.binary_search_by_key(id, |&(m, _)| m).is_err())
                        .collect();
                    made.extend(levels.top(grid, &others));
                    let mut shared = SharedMatrices::default();
                    for (id, k) in made {
                        // The elements are in grid-id order.
                        let i = self
                            .elements
                            .binary_search_by_key(&id, |e| e.grid_id)
                            .expect("a live top element is in the model");
                        self.elements[i].stiffness = shared.get(k.symmetrized());
                        new_matrices.push(i as u32);
                    }
                    new_matrices.sort_unstable();
                    new_matrices.dedup();
                } else {
                    let (levels, k) = CompositeLevels::new(grid);
                    self.set_stiffness(&k);
                    self.composite = Some(Arc::new(levels));
                    new_matrices = (0..self.elements.len() as u32).collect();
                }
            }
        }
        Renumbering {
            node_before,
            grid_node_before,
            element_before,
            grid_id_before: old_ids,
            new_matrices,
        }
    }

    /// The model of `grid`.
    fn build(grid: &BranchedGrid) -> Self {
        let top = grid.top();
        let mut model_of = vec![u32::MAX; top.node_capacity()];
        let mut rest = Vec::with_capacity(top.node_count());
        let mut grid_node = Vec::with_capacity(top.node_count());
        for (id, _) in top.nodes() {
            model_of[id as usize] = rest.len() as u32;
            rest.push(grid.node_rest_position(id).expect("live node"));
            grid_node.push(id);
        }
        let mut lumped_mass = vec![0.0; rest.len()];
        // Room for the pieces a few cuts split off: growing a full vector moves every element.
        let count = top.element_count();
        let mut elements = Vec::with_capacity(count + count / 16 + 16);
        let mut shared = SharedMatrices::default();
        for (id, e) in top.elements() {
            let m = grid.matrices(id).expect("live element has matrices");
            let nodes = e.nodes.map(|n| model_of[n as usize]);
            for (c, &n) in nodes.iter().enumerate() {
                lumped_mass[n as usize] += m.lumped_mass[c];
            }
            let stiffness = shared.get(m.stiffness.symmetrized());
            elements.push(HexElement { nodes, stiffness, mass: m.mass, grid_id: id });
        }
        Self {
            rest,
            lumped_mass,
            elements,
            element_size: grid.element_size(),
            grid_node,
            element: ElementKind::Condensed,
            composite: None,
        }
    }

    /// The same grid with every element's stiffness that of a full cell of its first voxel's
    /// material ("uniform" stiffness, the baseline Nesme et al. 2006 improve on); masses stay
    /// condensed, so gravity is the same load as on the condensed model.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without voxels).
    #[must_use]
    pub fn from_grid_uniform(grid: &BranchedGrid) -> Self {
        let mut model = Self::from_grid(grid);
        let size = grid.element_size();
        let materials: Vec<incise_grid::Material> = grid.materials().map(|(_, m)| *m).collect();
        let mut shared = SharedMatrices::default();
        for e in &mut model.elements {
            let voxel =
                *grid.element_voxels(e.grid_id).iter().min().expect("live element owns voxels");
            let m = materials
                [usize::from(grid.fine().material(voxel).expect("owned voxel holds material"))];
            e.stiffness = shared.get(
                incise_grid::hex8::hex_stiffness(size, m.youngs_modulus, m.poisson_ratio)
                    .symmetrized(),
            );
        }
        model
    }

    /// The same grid with composite elements: every element's stiffness condensed statically
    /// onto its corners, the points inside it free ([`incise_grid::composite`]); masses stay
    /// condensed.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without a stiffness).
    #[must_use]
    pub fn from_grid_composite(grid: &BranchedGrid) -> Self {
        let mut model = Self::from_grid(grid);
        let (levels, k) = CompositeLevels::new(grid);
        model.set_stiffness(&k);
        model.composite = Some(Arc::new(levels));
        model.element = ElementKind::Composite;
        model
    }

    /// The same grid with incompatible-mode elements: every element's condensed stiffness
    /// enriched with nine internal bubble modes, condensed out ([`incise_grid::incompatible`]);
    /// masses stay condensed.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without a stiffness).
    #[must_use]
    pub fn from_grid_incompatible(grid: &BranchedGrid) -> Self {
        let mut model = Self::from_grid(grid);
        model.set_stiffness(&incise_grid::incompatible::incompatible_stiffness(grid));
        model.element = ElementKind::Incompatible;
        model
    }

    /// Each element's stiffness taken from `stiffness` (by grid id).
    fn set_stiffness(&mut self, stiffness: &[Option<incise_grid::hex8::Mat24>]) {
        let mut shared = SharedMatrices::default();
        for e in &mut self.elements {
            let k = stiffness[e.grid_id as usize].as_ref().expect("live element has a stiffness");
            e.stiffness = shared.get(k.symmetrized());
        }
    }

    /// `out += scale · M p` with the condensed consistent mass (`Mₑ ⊗ I₃` per element), summed
    /// in element order.
    pub fn add_consistent_mass_times(&self, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        for e in &self.elements {
            for (a, &na) in e.nodes.iter().enumerate() {
                let mut sum = [0.0; 3];
                for (b, &nb) in e.nodes.iter().enumerate() {
                    let m = e.mass[8 * a + b];
                    for k in 0..3 {
                        sum[k] += m * p[nb as usize][k];
                    }
                }
                for k in 0..3 {
                    out[na as usize][k] += scale * sum[k];
                }
            }
        }
    }

    /// The diagonal of the condensed consistent mass, per node (kg).
    #[must_use]
    pub fn consistent_mass_diagonal(&self) -> Vec<f64> {
        let mut d = vec![0.0; self.rest.len()];
        for e in &self.elements {
            for (a, &n) in e.nodes.iter().enumerate() {
                d[n as usize] += e.mass[9 * a];
            }
        }
        d
    }

    /// Number of nodes.
    #[must_use]
    pub fn node_count(&self) -> usize {
        self.rest.len()
    }

    /// Degrees of freedom (3 per node).
    #[must_use]
    pub fn dof_count(&self) -> usize {
        3 * self.rest.len()
    }

    /// Total mass (kg).
    #[must_use]
    pub fn total_mass(&self) -> f64 {
        self.lumped_mass.iter().sum()
    }

    /// Displacement of the centre of mass (lumped masses) at positions `x` (m).
    #[must_use]
    pub fn centre_of_mass_shift(&self, x: &[Vec3]) -> Vec3 {
        let mass = self.total_mass();
        let mut u = [0.0; 3];
        for ((p, q), m) in x.iter().zip(&self.rest).zip(&self.lumped_mass) {
            for a in 0..3 {
                u[a] += m * (p[a] - q[a]) / mass;
            }
        }
        u
    }
}

/// Merges `added` (sorted by grid id) into `elements` (sorted by grid id) in place, from the
/// back: each old element after an insertion point moves once, and new ids past every old one
/// (the usual case: a split takes fresh ids) move none.
fn merge_by_grid_id(elements: &mut Vec<HexElement>, mut added: Vec<HexElement>) {
    let Some(filler) = added.first().cloned() else { return };
    let mut unmerged = elements.len();
    elements.resize(unmerged + added.len(), filler);
    // Invariant: `elements[unmerged..end]` are spare slots, as many as `added` still holds.
    let mut end = elements.len();
    while let Some(last) = added.last() {
        end -= 1;
        if unmerged > 0 && elements[unmerged - 1].grid_id > last.grid_id {
            unmerged -= 1;
            elements.swap(unmerged, end);
        } else {
            elements[end] = added.pop().expect("not empty");
        }
    }
}

/// How [`HexModel::update`] moved the model's nodes and elements: what the force field, the
/// state and the integrators need to carry their own per-node and per-element data across a cut.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Renumbering {
    /// Per node of the updated model, its index before the edit (`None`: a node the edit added).
    pub node_before: Vec<Option<u32>>,
    /// The grid node id of each node before the edit (sorted).
    pub grid_node_before: Vec<u32>,
    /// Per element of the updated model, its index before the edit (`None`: added).
    pub element_before: Vec<Option<u32>>,
    /// The grid id of each element before the edit (sorted).
    pub grid_id_before: Vec<u32>,
    /// The elements (updated indices) whose matrices were read from the grid again: added and
    /// re-condensed ones; sorted. The others kept their stiffness (the same `Arc`) and mass.
    pub new_matrices: Vec<u32>,
}

impl Renumbering {
    /// True when every node kept its index (the edit added and removed no node).
    #[must_use]
    pub fn same_nodes(&self) -> bool {
        self.node_before.len() == self.grid_node_before.len()
            && self.node_before.iter().enumerate().all(|(i, &b)| b == Some(i as u32))
    }

    /// The index before the edit of the node with grid id `g`, if there was one.
    #[must_use]
    pub fn node_before_by_grid_id(&self, g: u32) -> Option<usize> {
        self.grid_node_before.binary_search(&g).ok()
    }

    /// The index before the edit of the element with grid id `id`, if there was one (an element
    /// the edit removed included: a new element may reuse its id).
    #[must_use]
    pub fn element_before_by_grid_id(&self, id: u32) -> Option<usize> {
        self.grid_id_before.binary_search(&id).ok()
    }
}

/// One shared copy per distinct (bit-identical) stiffness matrix. Keyed by a few sampled entries
/// (hashing all 576 on every element made a model rebuild after a cut several times slower) and
/// confirmed by a full comparison.
#[derive(Default)]
struct SharedMatrices(HashMap<[u64; 6], Vec<Arc<Mat24>>>);

impl SharedMatrices {
    fn get(&mut self, m: Mat24) -> Arc<Mat24> {
        let key = [0, 25, 100, 299, 433, 575].map(|i| m.0[i].to_bits());
        let same = self.0.entry(key).or_default();
        if let Some(found) =
            same.iter().find(|s| s.0.iter().zip(&m.0).all(|(a, b)| a.to_bits() == b.to_bits()))
        {
            return found.clone();
        }
        let shared = Arc::new(m);
        same.push(shared.clone());
        shared
    }
}
