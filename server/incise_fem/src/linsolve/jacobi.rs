//! Block-Jacobi preconditioning: the inverse 3×3 diagonal blocks of `a·M + b·K`, per node.

use crate::forcefield::ForceField;
use crate::forcefield::hex::HexForceField;
use crate::linsolve::cg::invert_block;
use crate::model::HexModel;
use incise_math::Vec3;
use incise_math::mat3::Mat3;

/// Block-Jacobi preconditioner of `a·M + b·K` (`mass` lumped, per node), `K` at the field's
/// rotations.
#[must_use]
pub fn preconditioner(
    model: &HexModel,
    ff: &HexForceField,
    mass: &[f64],
    a: f64,
    b: f64,
) -> Vec<Mat3> {
    let mut blocks = Vec::new();
    preconditioner_into(model, ff, mass, (a, b), &mut blocks, &mut Vec::new());
    blocks
}

/// [`preconditioner`] into `blocks`, with `scratch` for the element sums (buffers kept between
/// rebuilds).
pub(crate) fn preconditioner_into(
    model: &HexModel,
    ff: &HexForceField,
    mass: &[f64],
    (a, b): (f64, f64),
    blocks: &mut Vec<Mat3>,
    scratch: &mut Vec<Mat3>,
) {
    ff.diagonal_blocks_into(model, blocks, scratch);
    ff.executor().update_elements(blocks, |n, k| {
        let mut blk = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                blk[i][j] = b * k[i][j];
            }
            blk[i][i] += a * mass[n];
        }
        *k = invert_block(&blk);
    });
}

/// Block-Jacobi preconditioner of a step's matrix for any set of force fields (see
/// [`crate::linsolve::implicit`]): per node, `a·m·I + b·K_nn + h²·K_own,nn + h·C_nn` inverted, the
/// fields' diagonal blocks taken at `x`.
pub(crate) fn field_preconditioner(
    fields: &[&mut dyn ForceField],
    x: &[Vec3],
    mass: &[f64],
    a: f64,
    b: f64,
    h: f64,
) -> Vec<Mat3> {
    let zero = || vec![[[0.0; 3]; 3]; mass.len()];
    let (mut blocks, mut own, mut damping) = (zero(), zero(), zero());
    for field in fields {
        if field.rayleigh_damped() {
            field.add_diagonal_blocks(x, &mut blocks);
        } else {
            field.add_diagonal_blocks(x, &mut own);
        }
        field.add_damping_diagonal_blocks(&mut damping);
    }
    for (((k, o), c), &m) in blocks.iter_mut().zip(&own).zip(&damping).zip(mass) {
        let mut blk = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                blk[i][j] = b * k[i][j] + h * h * o[i][j] + h * c[i][j];
            }
            blk[i][i] += a * m;
        }
        *k = invert_block(&blk);
    }
    blocks
}
