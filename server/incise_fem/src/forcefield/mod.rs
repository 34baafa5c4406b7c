//! Force fields: what computes internal forces and their Jacobian. [`hex`] holds the linear and
//! corotational hexahedra of the branched grid, [`tet`] paper 2's tensor-mass tetrahedra,
//! [`springs`] the springs on embedded points that a tool's contact and grasp are made of,
//! [`volume`] the penalty of an intersection volume (volume contact); all
//! reach the integrators through the [`ForceField`] trait.

#[cfg(test)]
mod checks;
pub mod hex;
pub mod springs;
pub mod tet;
pub mod volume;

use crate::model::HexModel;
use incise_math::Vec3;
use incise_math::mat3::Mat3;

/// What an integrator needs of a force field. Every method works on whole node vectors, so a
/// field may run its loops on its executor in whatever partition it likes, as long as its sums
/// come out the same on any thread count.
///
/// The Jacobian is `K = −∂f/∂x`, as the implicit step uses it: for a field whose exact Jacobian
/// is not symmetric (the corotational rotation term), `K` is the symmetric part the step solves
/// with. A contact's stiffness enters the implicit matrix through [`ForceField::add_stiffness_times`]
/// and [`ForceField::add_diagonal_blocks`], like the tissue's.
///
/// The integrator's Rayleigh stiffness damping `β K` is the tissue's own damping, against the
/// world. A field whose damping must act relative to something moving (a tool's contact and grasp
/// springs: their targets travel with the tool) opts out ([`ForceField::rayleigh_damped`]) and
/// brings its own viscous term `−C (v − w)` through [`ForceField::add_damping_forces`], which the
/// implicit step integrates like the stiffness (`h C` in its matrix).
///
/// A field is linearised at the positions of its last [`ForceField::update`]: an integrator calls
/// it once per step (or Newton iteration) before asking for forces or products.
///
/// The elastic fields are views of their model (`HexForceField::bind`,
/// `TensorMassForceField::bind`), made for a step. A topology change (a cut) changes the model
/// and the field that own the data: the hexahedral field is remapped to the new model, keeping
/// the rotations and permuted matrices of the elements the cut left alone
/// (`HexForceField::remapped`); the tensor-mass field subtracts the removed tetrahedra's terms
/// (`TensorMassForceField::remove_tet`); the state follows (`State::across_cut`); the view is
/// bound again. A field that holds node indices of its own across the change (a tool's contact
/// springs, found before a cut in the same step) is told through
/// [`ForceField::topology_changed`].
pub trait ForceField: Sync {
    /// Prepares evaluations at positions `x`: what the Jacobian depends on (element rotations,
    /// which tetrahedra are non-linear) is taken there.
    fn update(&mut self, x: &[Vec3]);

    /// `f += f(x)`, the field's forces at positions `x` (N per node).
    fn add_forces(&self, x: &[Vec3], f: &mut [Vec3]);

    /// `out += scale · K p`, with `K` the Jacobian at the last update (and at `x`, for a field
    /// whose Jacobian depends on the positions directly).
    fn add_stiffness_times(&self, x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]);

    /// `out += f(x) + scale · K p`: an implicit step's right-hand side. A field that can do both in
    /// one pass over its elements overrides this.
    fn add_forces_and_stiffness_times(&self, x: &[Vec3], scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        self.add_forces(x, out);
        self.add_stiffness_times(x, scale, p, out);
    }

    /// The field's potential energy at `x` (J).
    fn energy(&self, x: &[Vec3]) -> f64;

    /// `blocks[n] += K_nn`, the 3×3 diagonal blocks of the Jacobian (a block-Jacobi
    /// preconditioner's share): an approximation is allowed, as long as it stays symmetric
    /// positive semi-definite.
    fn add_diagonal_blocks(&self, x: &[Vec3], blocks: &mut [Mat3]);

    /// Whether the integrator's Rayleigh stiffness damping (`β K`) applies to this field: it does
    /// to the tissue's elasticity (the default).
    fn rayleigh_damped(&self) -> bool {
        true
    }

    /// `f += −C (v − w)`: the field's own viscous forces at node velocities `v`, with `C` its
    /// damping matrix and `w` the velocities it damps toward (none by default).
    fn add_damping_forces(&self, v: &[Vec3], f: &mut [Vec3]) {
        let _ = (v, f);
    }

    /// `out += scale · C p`.
    fn add_damping_times(&self, scale: f64, p: &[Vec3], out: &mut [Vec3]) {
        let _ = (scale, p, out);
    }

    /// `blocks[n] += C_nn`, the diagonal blocks of the damping matrix.
    fn add_damping_diagonal_blocks(&self, blocks: &mut [Mat3]) {
        let _ = blocks;
    }

    /// The executor the field runs its loops on; an integrator stepping it runs its own loops
    /// there too.
    fn executor(&self) -> &crate::exec::Executor;

    /// The hexahedral elasticity behind this field, for the solvers that work element by element
    /// on it (the two-thread lockstep CG, sparse Cholesky); `None` for every other field.
    fn hexahedra(&self) -> Option<(&HexModel, &hex::HexForceField)> {
        None
    }

    /// The model's nodes were renumbered by a cut: the field moves whatever it keeps per node to
    /// the new numbering. The elastic views keep nothing of their own (they borrow the model,
    /// which the borrow checker keeps unchanged while they live), so the default does nothing;
    /// [`springs::EmbeddedSprings`] follows its nodes.
    fn topology_changed(&mut self, change: &TopologyChange<'_>) {
        let _ = change;
    }
}

/// How a cut renumbered the model's nodes, as a field that keeps node indices sees it.
#[derive(Clone, Copy, Debug)]
pub struct TopologyChange<'a> {
    /// For each node before the change, its index after it (`None`: it did not survive).
    pub new_of_old: &'a [Option<u32>],
}

impl TopologyChange<'_> {
    /// The inverse of the new nodes' origins (`old_of_new`, as [`crate::model::CarriedState`]
    /// gives them) over `old_count` old nodes. Where several new nodes came from one old node (a
    /// node split by the cut), the old node maps to the first of them.
    #[must_use]
    pub fn invert(old_of_new: &[Option<usize>], old_count: usize) -> Vec<Option<u32>> {
        let mut new_of_old = vec![None; old_count];
        for (new, old) in old_of_new.iter().enumerate() {
            if let Some(slot) = old.and_then(|o| new_of_old.get_mut(o))
                && slot.is_none()
            {
                *slot = Some(new as u32);
            }
        }
        new_of_old
    }
}
