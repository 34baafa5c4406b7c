//! The mechanical model of a grid's top level: compact node numbering, rest positions, element
//! connectivity with each element's condensed stiffness and mass (Jeřábková 2010 §2.2), and the
//! lumped node masses.

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
}

impl HexModel {
    /// The model of `grid`'s top level. Nodes are numbered in grid-node order, elements in
    /// grid-element order, so the numbering is deterministic.
    ///
    /// # Panics
    /// Only on a broken grid invariant (a live element without matrices or with a dead node).
    #[must_use]
    pub fn from_grid(grid: &BranchedGrid) -> Self {
        Self::build(grid, |_| None)
    }

    /// The model of `grid` after an edit whose change list is `changes`, `self` being the model
    /// of the grid before it: every element the edit did not touch keeps its (shared) stiffness
    /// and mass; only added, changed and re-condensed elements get new ones. Equal to
    /// [`HexModel::from_grid`] of the edited grid, without re-reading and re-sharing every
    /// element's matrices.
    #[must_use]
    pub fn updated(&self, grid: &BranchedGrid, changes: &GridChanges) -> Self {
        let mut touched: Vec<u32> = changes
            .top
            .elements_added
            .iter()
            .map(|&(id, _)| id)
            .chain(changes.top.elements_changed.iter().copied())
            .chain(changes.matrices_updated.iter().copied())
            .collect();
        touched.sort_unstable();
        touched.dedup();
        // Old elements are in grid-element order, so their ids are sorted.
        let old = &self.elements;
        Self::build(grid, |id| {
            if touched.binary_search(&id).is_ok() {
                return None;
            }
            let j = old.binary_search_by_key(&id, |e| e.grid_id).ok()?;
            Some((old[j].stiffness.clone(), old[j].mass))
        })
    }

    /// The model of `grid`, taking an element's matrices from `reuse(grid id)` when it has them.
    fn build(grid: &BranchedGrid, reuse: impl Fn(u32) -> Option<(Arc<Mat24>, Mat8)>) -> Self {
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
        let mut elements = Vec::with_capacity(top.element_count());
        let mut shared = SharedMatrices::default();
        for (id, e) in top.elements() {
            let m = grid.matrices(id).expect("live element has matrices");
            let nodes = e.nodes.map(|n| model_of[n as usize]);
            for (c, &n) in nodes.iter().enumerate() {
                lumped_mass[n as usize] += m.lumped_mass[c];
            }
            let (stiffness, mass) =
                reuse(id).unwrap_or_else(|| (shared.get(m.stiffness.symmetrized()), m.mass));
            elements.push(HexElement { nodes, stiffness, mass, grid_id: id });
        }
        Self { rest, lumped_mass, elements, element_size: grid.element_size(), grid_node }
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
