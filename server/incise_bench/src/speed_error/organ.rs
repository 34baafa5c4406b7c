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

    /// The nodal loads on the model (of `nodes` nodes) consistent with `force` spread evenly
    /// over the points: the transpose of reading the points' mean displacement, so the loads do
    /// the same work on any displacement as the force on that mean.
    pub fn mean_load(&self, force: Vec3, nodes: usize) -> Vec<Vec3> {
        let mut fine = vec![[0.0; 3]; self.level0_nodes];
        for point in &self.points {
            let share = 1.0 / (point.len() * self.points.len()) as f64;
            for &n in point {
                for a in 0..3 {
                    fine[n as usize][a] += share * force[a];
                }
            }
        }
        let mut coarse = vec![[0.0; 3]; nodes];
        self.prolongation.restrict(&fine, &mut coarse);
        coarse
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

#[cfg(test)]
mod tests {
    use super::*;
    use incise_fem::ElementKind;
    use incise_grid::{Material, MaterialTable};

    /// The loads are the transpose of the reading: for any displacement, the work of the nodal
    /// loads equals the force times the points' mean displacement; and a linear field is read
    /// exactly at every level (trilinear interpolation reproduces it).
    #[test]
    fn a_sampler_reads_linear_fields_exactly_and_its_loads_are_its_transpose() {
        let volume = incise_grid::procedural::ellipsoid_with_inclusion(12, 1e-3);
        let table = MaterialTable::uniform(&[1, 2], Material::new(3e3, 0.45, 1000.0));
        let grid0 = BranchedGrid::build(&volume, &table, 0).unwrap();
        let model0 = HexModel::from_grid_of_kind(&grid0, ElementKind::Condensed);
        // Every tenth voxel's corners: points spread through the body.
        let points: Vec<Vec<u32>> =
            model0.elements.iter().step_by(10).map(|e| e.nodes.to_vec()).collect();
        let centres: Vec<Vec3> = points
            .iter()
            .map(|p| {
                std::array::from_fn(|a| {
                    p.iter().map(|&n| model0.rest[n as usize][a]).sum::<f64>() / 8.0
                })
            })
            .collect();
        let field = |p: &Vec3| -> Vec3 {
            [
                1e-3 + 0.02 * p[0] - 0.01 * p[2],
                -2e-3 + 0.03 * p[1],
                0.5e-3 + 0.01 * p[0] + 0.02 * p[1] - 0.04 * p[2],
            ]
        };
        for level in 0..=2 {
            let grid = BranchedGrid::build(&volume, &table, level).unwrap();
            let model = HexModel::from_grid_of_kind(&grid, ElementKind::Condensed);
            let sampler = Sampler::new((&grid0, &model0), (&grid, &model), points.clone()).unwrap();
            let x: Vec<Vec3> = model
                .rest
                .iter()
                .map(|p| {
                    let u = field(p);
                    std::array::from_fn(|a| p[a] + u[a])
                })
                .collect();
            let read = sampler.displacements(&model.rest, &x);
            for (u, c) in read.iter().zip(&centres) {
                let exact = field(c);
                for a in 0..3 {
                    assert!((u[a] - exact[a]).abs() <= 1e-15, "level {level}: {u:?} {exact:?}");
                }
            }
            // Any field, here a wavy one: the loads' work against the force's on the mean.
            let force = [0.3, -1.2, 2.0];
            let load = sampler.mean_load(force, model.node_count());
            let wavy: Vec<Vec3> = model
                .rest
                .iter()
                .enumerate()
                .map(|(n, p)| std::array::from_fn(|a| p[a] + 1e-3 * ((n * (a + 3)) as f64).sin()))
                .collect();
            let u = sampler.displacements(&model.rest, &wavy);
            let mean: Vec3 =
                std::array::from_fn(|a| u.iter().map(|v| v[a]).sum::<f64>() / u.len() as f64);
            let work_point: f64 = (0..3).map(|a| force[a] * mean[a]).sum();
            let work_nodes: f64 = load
                .iter()
                .zip(&wavy)
                .zip(&model.rest)
                .map(|((f, x), r)| (0..3).map(|a| f[a] * (x[a] - r[a])).sum::<f64>())
                .sum();
            assert!(
                (work_point - work_nodes).abs() <= 1e-14,
                "level {level}: {work_point:e} against {work_nodes:e}"
            );
        }
    }
}
