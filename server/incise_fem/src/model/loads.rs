//! External loads: gravity on the lumped masses and per-node forces (a patch pull, a tool).

use crate::model::Mass;
use incise_math::Vec3;

/// External loads: gravity (m/s²) on every node's lumped mass, plus per-node forces (N).
#[derive(Clone, Debug, PartialEq)]
pub struct Loads {
    /// Gravitational acceleration.
    pub gravity: Vec3,
    /// Extra force on each node (empty = none).
    pub nodal: Vec<Vec3>,
}

impl Loads {
    /// Gravity only.
    #[must_use]
    pub fn gravity(g: Vec3) -> Self {
        Self { gravity: g, nodal: Vec::new() }
    }

    /// Spreads `force` (N) evenly over the nodes of `rest` within `radius` of `centre`, added
    /// to the per-node forces (a tool pushing or pulling on a patch: a single-node force would
    /// depend on the mesh). Returns how many nodes share it (0: none lies that close, and
    /// nothing is added).
    pub fn add_patch(&mut self, rest: &[Vec3], centre: Vec3, radius: f64, force: Vec3) -> usize {
        let patch: Vec<usize> = (0..rest.len())
            .filter(|&n| {
                (0..3).map(|a| (rest[n][a] - centre[a]).powi(2)).sum::<f64>().sqrt() <= radius
            })
            .collect();
        if patch.is_empty() {
            return 0;
        }
        self.nodal.resize(rest.len(), [0.0; 3]);
        let share = 1.0 / patch.len() as f64;
        for &n in &patch {
            for a in 0..3 {
                self.nodal[n][a] += force[a] * share;
            }
        }
        patch.len()
    }

    /// `f += external forces`, gravity acting on `mass`'s lumped masses.
    pub fn add_to(&self, mass: &(impl Mass + ?Sized), f: &mut [Vec3]) {
        let lumped = mass.lumped();
        for (n, fi) in f.iter_mut().enumerate() {
            self.add_at(lumped, n, fi);
        }
    }

    /// `f += the external force on node n`, gravity acting on its lumped mass `lumped[n]`.
    #[inline]
    pub(crate) fn add_at(&self, lumped: &[f64], n: usize, f: &mut Vec3) {
        let m = lumped[n];
        for k in 0..3 {
            f[k] += m * self.gravity[k];
        }
        if let Some(extra) = self.nodal.get(n) {
            for k in 0..3 {
                f[k] += extra[k];
            }
        }
    }
}
