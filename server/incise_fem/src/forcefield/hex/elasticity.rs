//! The hexahedral model's elasticity as a [`ForceField`]: a [`HexForceField`] bound to the
//! [`HexModel`] whose elements it holds the rotations of.

use super::HexForceField;
use crate::forcefield::ForceField;
use crate::model::HexModel;
use incise_math::Vec3;
use incise_math::mat3::Mat3;

/// A hexahedral force field together with its model, for the integrators (see
/// [`HexForceField::bind`]). It borrows both: a cut replaces the model and remaps the field, and
/// the next step binds them again.
pub struct HexElasticity<'a> {
    model: &'a HexModel,
    field: &'a mut HexForceField,
}

impl HexForceField {
    /// This field bound to `model` as a [`ForceField`].
    pub fn bind<'a>(&'a mut self, model: &'a HexModel) -> HexElasticity<'a> {
        HexElasticity { model, field: self }
    }
}

impl ForceField for HexElasticity<'_> {
    fn executor(&self) -> &crate::exec::Executor {
        self.field.executor()
    }

    fn update(&mut self, x: &[Vec3]) {
        self.field.update_rotations(self.model, x);
    }

    fn add_forces(&self, x: &[Vec3], f: &mut [Vec3]) {
        self.field.add_forces(self.model, x, f);
    }

    fn add_stiffness_times(&self, _x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.field.add_stiffness_times(self.model, scale, p, out);
    }

    fn add_forces_and_stiffness_times(&self, x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.field.add_forces_and_stiffness_times(self.model, x, scale, p, out);
    }

    fn energy(&self, x: &[Vec3]) -> f64 {
        self.field.energy(self.model, x)
    }

    fn add_diagonal_blocks(&self, _x: &[Vec3], blocks: &mut [Mat3]) {
        for (b, d) in blocks.iter_mut().zip(self.field.diagonal_blocks(self.model)) {
            for i in 0..3 {
                for j in 0..3 {
                    b[i][j] += d[i][j];
                }
            }
        }
    }

    fn hexahedra(&self) -> Option<(&HexModel, &HexForceField)> {
        Some((self.model, self.field))
    }
}
