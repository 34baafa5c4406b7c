//! The mass matrix an integrator sees: lumped (diagonal, per node) always; the consistent one
//! where the model has it.

use crate::model::HexModel;
use incise_math::Vec3;

/// A model's mass.
pub trait Mass: Sync {
    /// Lumped mass per node (kg).
    fn lumped(&self) -> &[f64];

    /// Whether [`Mass::add_consistent_times`] uses a consistent mass matrix (otherwise it is the
    /// lumped one).
    fn has_consistent(&self) -> bool {
        false
    }

    /// `out += scale · M p` with the consistent mass matrix (the lumped one where the model has
    /// none).
    fn add_consistent_times(&self, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        for ((o, q), &m) in out.iter_mut().zip(p).zip(self.lumped()) {
            for k in 0..3 {
                o[k] += scale * m * q[k];
            }
        }
    }

    /// The consistent mass matrix's diagonal, per node (kg).
    fn consistent_diagonal(&self) -> Vec<f64> {
        self.lumped().to_vec()
    }
}

impl Mass for HexModel {
    fn lumped(&self) -> &[f64] {
        &self.lumped_mass
    }

    fn has_consistent(&self) -> bool {
        true
    }

    fn add_consistent_times(&self, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.add_consistent_mass_times(scale, p, out);
    }

    fn consistent_diagonal(&self) -> Vec<f64> {
        self.consistent_mass_diagonal()
    }
}

impl Mass for crate::forcefield::tet::TetModel {
    fn lumped(&self) -> &[f64] {
        &self.lumped_mass
    }
}
