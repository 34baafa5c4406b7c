//! Preconditioned Bi-CGSTAB (van der Vorst 1992) for the nonsymmetric Newton systems of the
//! corotational static solve with its full tangent ([`crate::forcefield::hex::tangent`]). Same interface and
//! stopping rule as [`crate::linsolve::cg::solve`]; dot products in node order, so deterministic.

use crate::constraint::FixedNodes;
use crate::linsolve::cg::{CgReport, CgSettings, dot, free_rhs};
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
    let Some((bb, b_norm)) = free_rhs(fixed, b, x) else {
        return CgReport { iterations: 0, relative_residual: 0.0, converged: true };
    };
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
    let zeros = || vec![[0.0; 3]; n];
    let (mut p, mut y, mut s, mut z, mut t) = (zeros(), zeros(), zeros(), zeros(), zeros());
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
        for (xi, yi) in x.iter_mut().zip(&y) {
            for k in 0..3 {
                xi[k] += alpha * yi[k];
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linsolve::cg::block_jacobi;

    #[test]
    fn solves_a_nonsymmetric_system_on_the_free_nodes() {
        // A chain of 30 nodes: a nonsymmetric, diagonally dominant 3×3 block per node and
        // unequal couplings to each neighbour (a convection-like operator), node 0 fixed.
        // The answer is known: b = A x* for a chosen x*. 1e-12 relative residual is asked;
        // the check allows 1e-10 on x (the system's condition number is below 10).
        let n = 30;
        let fixed = FixedNodes::from_list(n, &[0]);
        let block = |i: usize| -> [[f64; 3]; 3] {
            let s = i as f64;
            [[6.0 + 0.1 * s, 1.0, -0.5], [-1.5, 7.0, 0.8], [0.3, -1.2, 5.5 - 0.05 * s]]
        };
        let apply = |p: &[Vec3], out: &mut [Vec3]| {
            for i in 0..n {
                let own = incise_math::mat3::mul_vec(&block(i), &p[i]);
                for k in 0..3 {
                    let left = if i > 0 { -1.5 * p[i - 1][k] } else { 0.0 };
                    let right = if i + 1 < n { -0.5 * p[i + 1][k] } else { 0.0 };
                    out[i][k] += own[k] + left + right;
                }
            }
        };
        let want: Vec<Vec3> = (0..n)
            .map(|i| if i == 0 { [0.0; 3] } else { [(i as f64).sin(), 0.5, -(i as f64) * 0.1] })
            .collect();
        let mut b = vec![[0.0; 3]; n];
        apply(&want, &mut b);
        let blocks: Vec<_> = (0..n).map(|i| crate::linsolve::cg::invert_block(&block(i))).collect();
        let mut x = vec![[1.0; 3]; n];
        let settings = CgSettings { tolerance: 1e-12, max_iterations: 500 };
        let report = solve(apply, block_jacobi(&blocks), &fixed, &b, &mut x, settings);
        assert!(report.converged, "{report:?}");
        assert!(x[0].iter().all(|&c| c == 0.0), "the fixed node stays put: {:?}", x[0]);
        for (got, want) in x.iter().zip(&want).skip(1) {
            for k in 0..3 {
                assert!((got[k] - want[k]).abs() <= 1e-10, "{got:?} vs {want:?}");
            }
        }
    }
}
