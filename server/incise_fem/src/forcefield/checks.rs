//! Checks every force field's tests share: its forces against its energy, its product against its
//! forces, its diagonal blocks against its product.

use super::ForceField;
use incise_math::Vec3;

/// Tolerance of a comparison, `(relative, absolute)`: `|got − want| ≤ relative · |want| +
/// absolute`.
pub(crate) type Tolerance = (f64, f64);

fn within(got: f64, want: f64, (relative, absolute): Tolerance) -> bool {
    (got - want).abs() <= relative * want.abs() + absolute
}

/// At `x`, the forces are minus the energy's central differences (step 1e-6, within
/// `gradient`), and `2 K p` is minus the forces' forward difference along `p` (within `product`).
pub(crate) fn forces_and_product(
    field: &dyn ForceField,
    x: &[Vec3],
    p: &[Vec3],
    gradient: Tolerance,
    product: Tolerance,
) {
    let n = x.len();
    let mut f = vec![[0.0; 3]; n];
    field.add_forces(x, &mut f);
    let h = 1e-6;
    for i in 0..n {
        for k in 0..3 {
            let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
            xp[i][k] += h;
            xm[i][k] -= h;
            let grad = (field.energy(&xp) - field.energy(&xm)) / (2.0 * h);
            assert!(within(-grad, f[i][k], gradient), "force {i},{k}: {} against {grad}", f[i][k]);
        }
    }
    let mut kp = vec![[0.0; 3]; n];
    field.add_stiffness_times(x, 2.0, p, &mut kp);
    let xp: Vec<Vec3> =
        x.iter().zip(p).map(|(a, b)| std::array::from_fn(|k| a[k] + h * b[k])).collect();
    let mut fp = vec![[0.0; 3]; n];
    field.add_forces(&xp, &mut fp);
    for i in 0..n {
        for k in 0..3 {
            let df = (fp[i][k] - f[i][k]) / h;
            assert!(within(-2.0 * df, kp[i][k], product), "product {i},{k}");
        }
    }
}

/// The diagonal blocks at `x` are the product's diagonal (within `tolerance`).
pub(crate) fn diagonal_blocks(field: &dyn ForceField, x: &[Vec3], tolerance: Tolerance) {
    let n = x.len();
    let mut blocks = vec![[[0.0; 3]; 3]; n];
    field.add_diagonal_blocks(x, &mut blocks);
    for i in 0..n {
        for c in 0..3 {
            let mut e = vec![[0.0; 3]; n];
            e[i][c] = 1.0;
            let mut column = vec![[0.0; 3]; n];
            field.add_stiffness_times(x, 1.0, &e, &mut column);
            for r in 0..3 {
                assert!(within(blocks[i][r][c], column[i][r], tolerance), "block {i} ({r}, {c})");
            }
        }
    }
}
