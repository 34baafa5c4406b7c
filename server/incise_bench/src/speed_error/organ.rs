//! The liver rows' error: a configuration's displacement field against the liver's reference
//! (the 109,201-voxel liver at level 0, solved statically; `incise-bench reference` compares the
//! 13,648-voxel liver's level 0 with it), on the same physical points.
//!
//! The points are the centres of the 13,648-voxel liver's voxels that are nodes of the
//! 109,201-voxel liver's grid ([`super::reference`]'s matching). A model at any level of either
//! liver is read there through the trilinear field of its elements: its displacement is carried
//! to its own volume's level-0 nodes by the grid's prolongation (the multigrid's, each level-0
//! node following the element that owns its voxels), then a point takes the mean of its level-0
//! nodes: the eight corners of the coarse liver's voxel (the trilinear field at its centre), or
//! the fine liver's node there. Composite and incompatible elements are read through their
//! corners the same way: what they add inside an element is not a nodal displacement.

use incise_fem::HexModel;
use incise_fem::linsolve::multigrid::Prolongation;
use incise_grid::BranchedGrid;
use incise_math::Vec3;
use serde::Serialize;

/// Displacement measures over the compared points, each point weighted alike (m, or signed
/// fractions for an error).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Measures {
    /// The norm of the points' mean displacement (the centre of mass's: the coarse liver's
    /// voxels weigh alike).
    pub centre_of_mass: f64,
    /// The largest displacement.
    pub max: f64,
    /// The root mean square displacement.
    pub rms: f64,
}

impl Measures {
    /// The measures of the displacements `u`.
    pub fn of(u: &[Vec3]) -> Self {
        let count = u.len().max(1) as f64;
        let com: Vec3 = std::array::from_fn(|a| u.iter().map(|v| v[a]).sum::<f64>() / count);
        Self {
            centre_of_mass: norm(&com),
            max: u.iter().map(norm).fold(0.0, f64::max),
            rms: (u.iter().map(|v| norm(v).powi(2)).sum::<f64>() / count).sqrt(),
        }
    }

    /// `(self − reference) / reference`, measure by measure.
    pub fn signed_error(&self, reference: &Self) -> Self {
        let rel = |a: f64, r: f64| (a - r) / r;
        Self {
            centre_of_mass: rel(self.centre_of_mass, reference.centre_of_mass),
            max: rel(self.max, reference.max),
            rms: rel(self.rms, reference.rms),
        }
    }

    /// Of signed errors: the larger of the centre of mass's and the largest displacement's
    /// magnitudes, the two a configuration must hold within a bound.
    pub fn worst(&self) -> f64 {
        self.centre_of_mass.abs().max(self.max.abs())
    }
}

fn norm(u: &Vec3) -> f64 {
    (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
}

/// Reads a model's displacement at the compared points.
pub struct Sampler {
    /// From the model's level onto its volume's level 0.
    prolongation: Prolongation,
    level0_nodes: usize,
    /// Per compared point, the level-0 nodes whose mean displacement is the point's.
    points: Vec<Vec<u32>>,
}

impl Sampler {
    /// A sampler for `model` (of `grid`), whose volume's level 0 is `level0` (of `level0_grid`),
    /// at `points` (level-0 node lists, none empty).
    ///
    /// # Errors
    /// When the two grids were built from different volumes.
    pub fn new(
        (level0_grid, level0): (&BranchedGrid, &HexModel),
        (grid, model): (&BranchedGrid, &HexModel),
        points: Vec<Vec<u32>>,
    ) -> anyhow::Result<Self> {
        let prolongation =
            Prolongation::new(level0_grid, level0, grid, model).map_err(anyhow::Error::msg)?;
        Ok(Self { prolongation, level0_nodes: level0.node_count(), points })
    }

    /// The displacement at each point of the model at positions `x` (`rest` its rest positions).
    pub fn displacements(&self, rest: &[Vec3], x: &[Vec3]) -> Vec<Vec3> {
        let u: Vec<Vec3> =
            x.iter().zip(rest).map(|(p, q)| std::array::from_fn(|a| p[a] - q[a])).collect();
        let mut fine = vec![[0.0; 3]; self.level0_nodes];
        self.prolongation.add_prolonged(&u, &mut fine);
        self.points
            .iter()
            .map(|nodes| {
                let count = nodes.len() as f64;
                std::array::from_fn(|a| {
                    nodes.iter().map(|&n| fine[n as usize][a]).sum::<f64>() / count
                })
            })
            .collect()
    }

    /// The measures of the model at positions `x`.
    pub fn measures(&self, rest: &[Vec3], x: &[Vec3]) -> Measures {
        Measures::of(&self.displacements(rest, x))
    }
}

/// The reference's measures, per model.
#[derive(Clone, Debug, Serialize)]
pub struct OrganReference {
    /// Points compared, and the coarse liver's voxels with no fine node at their centre.
    pub points: usize,
    pub unmatched: usize,
    pub linear: Option<Measures>,
    pub corotational: Option<Measures>,
}
