//! Preconditioned Bi-CGSTAB (van der Vorst 1992) for the nonsymmetric Newton systems of the
//! corotational static solve with its full tangent ([`crate::tangent`]). Same interface and
//! stopping rule as [`crate::cg::solve`]; dot products in node order, so deterministic.

use crate::cg::{CgReport, CgSettings, dot};
use crate::constraints::FixedNodes;
use incise_math::Vec3;

/// `y = a + s · b`, node by node.
fn axpy(out: &mut [Vec3], a: &[Vec3], s: f64, b: &[Vec3]) {
    for ((o, x), y) in out.iter_mut().zip(a).zip(b) {
        *o = std::array::from_fn(|k| x[k] + s * y[k]);
    }
}

/// Solves `A x = b` on the free nodes from the starting `x`, `A` not necessarily symmetric:
/// `apply(p, out)` sets `out = A p`, `precondition(r, z)` sets `z ≈ A⁻¹ r`. Stops when
/// `‖r‖ ≤ tolerance · ‖b‖`; `iterations` counts operator products, two per Bi-CGSTAB step, so
/// it compares with CG's count.
pub fn solve(
    apply: impl Fn(&[Vec3], &mut [Vec3]),
    precondition: impl Fn(&[Vec3], &mut [Vec3]),
    fixed: &FixedNodes,
    b: &[Vec3],
    x: &mut [Vec3],
    settings: CgSettings,
) -> CgReport {
    let n = b.len();
    let mut bb = b.to_vec();
    fixed.project(&mut bb);
    fixed.project(x);
    let b_norm = dot(&bb, &bb).sqrt();
    if b_norm == 0.0 {
        x.fill([0.0; 3]);
        return CgReport { iterations: 0, relative_residual: 0.0, converged: true };
    }
    let product = |p: &[Vec3], out: &mut [Vec3]| {
        out.fill([0.0; 3]);
        apply(p, out);
        fixed.project(out);
    };
    let precondition = |r: &[Vec3], z: &mut [Vec3]| {
        precondition(r, z);
        fixed.project(z);
    };
    let mut v = vec![[0.0; 3]; n];
    product(x, &mut v);
    let mut r: Vec<Vec3> = vec![[0.0; 3]; n];
    axpy(&mut r, &bb, -1.0, &v);
    let shadow = r.clone();
    let (mut p, mut y, mut s, mut z, mut t) =
        (vec![[0.0; 3]; n], vec![[0.0; 3]; n], vec![[0.0; 3]; n], vec![[0.0; 3]; n], r.clone());
    v.fill([0.0; 3]);
    let (mut rho, mut alpha, mut omega) = (1.0, 1.0, 1.0);
    let mut rel = dot(&r, &r).sqrt() / b_norm;
    let mut products = 0;
    while rel > settings.tolerance && products < settings.max_iterations {
        let rho_new = dot(&shadow, &r);
        if rho_new == 0.0 || omega == 0.0 {
            break;
        }
        let beta = (rho_new / rho) * (alpha / omega);
        rho = rho_new;
        for i in 0..n {
            for k in 0..3 {
                p[i][k] = r[i][k] + beta * (p[i][k] - omega * v[i][k]);
            }
        }
        precondition(&p, &mut y);
        product(&y, &mut v);
        products += 1;
        let sv = dot(&shadow, &v);
        if sv == 0.0 {
            break;
        }
        alpha = rho / sv;
        axpy(&mut s, &r, -alpha, &v);
        t.copy_from_slice(x);
        axpy(x, &t, alpha, &y);
        rel = dot(&s, &s).sqrt() / b_norm;
        if rel <= settings.tolerance {
            break;
        }
        precondition(&s, &mut z);
        product(&z, &mut t);
        products += 1;
        let tt = dot(&t, &t);
        if tt == 0.0 {
            break;
        }
        omega = dot(&t, &s) / tt;
        for i in 0..n {
            for k in 0..3 {
                x[i][k] += omega * z[i][k];
                r[i][k] = s[i][k] - omega * t[i][k];
            }
        }
        rel = dot(&r, &r).sqrt() / b_norm;
    }
    CgReport { iterations: products, relative_residual: rel, converged: rel <= settings.tolerance }
}
