//! Paper 2's tensor-mass tetrahedra as a [`ForceField`]: the stored stiffness tensors, the live
//! tetrahedra of a topology, and the optional incompressibility penalty, bound together so that
//! any integrator (the explicit central differences of the paper, or implicit Euler) can step
//! them.

use super::element::TetModel;
use super::incompressible::Incompressibility;
use super::tensor_mass::TensorMassForceField;
use crate::forcefield::ForceField;
use incise_math::Vec3;
use incise_math::mat3::Mat3;
use incise_mesh::TetTopology;

/// A tensor-mass field bound to its model, topology and penalty (see
/// [`TensorMassForceField::bind`]).
pub struct TetElasticity<'a> {
    model: &'a TetModel,
    topology: &'a TetTopology,
    field: &'a mut TensorMassForceField,
    penalty: Option<&'a Incompressibility>,
}

impl TensorMassForceField {
    /// This field, the tetrahedra `topology` keeps alive and `penalty`, as one [`ForceField`].
    pub fn bind<'a>(
        &'a mut self,
        model: &'a TetModel,
        topology: &'a TetTopology,
        penalty: Option<&'a Incompressibility>,
    ) -> TetElasticity<'a> {
        TetElasticity { model, topology, field: self, penalty }
    }
}

impl ForceField for TetElasticity<'_> {
    fn executor(&self) -> &crate::exec::Executor {
        self.field.executor()
    }

    /// Switches tetrahedra between linear and St Venant-Kirchhoff where adaptive non-linearity
    /// is on (paper 2 §6); nothing else depends on the linearisation point.
    fn update(&mut self, x: &[Vec3]) {
        if self.field.elasticity() == super::Elasticity::StVenantKirchhoff {
            self.field.update_adaptive(self.model, self.topology, x);
        }
    }

    fn add_forces(&self, x: &[Vec3], f: &mut [Vec3]) {
        self.field.add_forces(self.model, x, f);
        if let Some(p) = self.penalty {
            p.add_forces(self.model, |t| self.topology.is_alive(t), x, f);
        }
    }

    fn add_stiffness_times(&self, x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.field.add_scaled_stiffness_times(self.model, x, scale, p, out);
        if let Some(penalty) = self.penalty {
            penalty.add_stiffness_times(
                self.model,
                |t| self.topology.is_alive(t),
                x,
                scale,
                p,
                out,
            );
        }
    }

    fn energy(&self, x: &[Vec3]) -> f64 {
        let penalty =
            self.penalty.map_or(0.0, |p| p.energy(self.model, |t| self.topology.is_alive(t), x));
        self.field.energy(self.model, x) + penalty
    }

    fn add_diagonal_blocks(&self, x: &[Vec3], blocks: &mut [Mat3]) {
        self.field.add_rest_diagonal_blocks(blocks);
        if let Some(p) = self.penalty {
            p.add_diagonal_blocks(self.model, |t| self.topology.is_alive(t), x, blocks);
        }
    }
}
