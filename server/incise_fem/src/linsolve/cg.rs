//! Preconditioned conjugate gradients for the symmetric positive definite systems of the static
//! and implicit solvers, matrix-free, with a block-Jacobi (3×3 per node) preconditioner and fixed
//! nodes projected out. Dot products run in node order, so results are deterministic.

use crate::constraint::FixedNodes;
use incise_math::Vec3;
use incise_math::mat3::{Mat3, det, mul_vec};

/// When to stop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CgSettings {
    /// Stop when ‖r‖ ≤ tolerance · ‖b‖ ([`solve`]), or tolerance · max(‖b‖, reference)
    /// ([`solve_against`], the implicit step's rule).
    pub tolerance: f64,
    /// Give up after this many iterations.
    pub max_iterations: usize,
}

impl Default for CgSettings {
    fn default() -> Self {
        Self { tolerance: 1e-8, max_iterations: 10_000 }
    }
}

/// What a solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CgReport {
    /// Iterations run.
    pub iterations: usize,
    /// ‖r‖ / ‖b‖ at the end (0 when b = 0); with [`solve_against`], relative to the larger of
    /// ‖b‖ and its reference.
    pub relative_residual: f64,
    /// Whether the tolerance was reached.
    pub converged: bool,
}

/// `a · b` summed in four fixed lanes (components `i mod 4` of the flattened vectors), combined
/// as `(l0 + l1) + (l2 + l3)`: the compiler keeps the lanes in one vector register, and the order
/// is fixed, so the result is deterministic.
pub(crate) fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    let (a, b) = (a.as_flattened(), b.as_flattened());
    let mut lanes = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            lanes[k] += x[k] * y[k];
        }
    }
    for (k, (x, y)) in ra.iter().zip(rb).enumerate() {
        lanes[k] += x * y;
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
}

/// Inverse of a 3×3 block, or zero when it is singular (a node no element stiffens).
#[must_use]
pub fn invert_block(m: &Mat3) -> Mat3 {
    let d = det(m);
    if d.abs() <= f64::MIN_POSITIVE {
        return [[0.0; 3]; 3];
    }
    let inv = 1.0 / d;
    [
        [
            (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv,
        ],
        [
            (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv,
        ],
        [
            (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv,
        ],
    ]
}

/// The block-Jacobi preconditioner: `z[n] = blocks[n] · r[n]`.
pub fn block_jacobi(blocks: &[Mat3]) -> impl Fn(&[Vec3], &mut [Vec3]) + '_ {
    move |r, z| {
        for ((zi, ri), m) in z.iter_mut().zip(r).zip(blocks) {
            *zi = mul_vec(m, ri);
        }
    }
}

/// `b` on the free nodes and its norm, with `x` projected the same way; `None` (and `x`
/// zeroed) when that right-hand side is zero, whose answer is `x = 0` at once.
pub(crate) fn free_rhs(fixed: &FixedNodes, b: &[Vec3], x: &mut [Vec3]) -> Option<(Vec<Vec3>, f64)> {
    let mut bb = b.to_vec();
    fixed.project(&mut bb);
    fixed.project(x);
    let b_norm = dot(&bb, &bb).sqrt();
    if b_norm == 0.0 {
        x.fill([0.0; 3]);
        return None;
    }
    Some((bb, b_norm))
}

/// Solves `A x = b` on the free nodes, starting from `x` (warm start), where `apply(p, out)`
/// sets `out = A p` and `precondition(r, z)` sets `z ≈ A⁻¹ r`.
pub fn solve(
    apply: impl Fn(&[Vec3], &mut [Vec3]),
    precondition: impl Fn(&[Vec3], &mut [Vec3]),
    fixed: &FixedNodes,
    b: &[Vec3],
    x: &mut [Vec3],
    settings: CgSettings,
) -> CgReport {
    solve_against(apply, precondition, fixed, b, x, settings, 0.0)
}

/// [`solve`], stopping when `‖r‖ ≤ tolerance · max(‖b‖, reference)`: `reference` is the size
/// `b` has when the problem's forces are out of balance (an implicit step's `h ‖f_ext‖`), so a
/// right-hand side that has shrunk to rounding noise at rest is not solved to `tolerance` of
/// that noise. `relative_residual` is then relative to that larger size.
#[allow(clippy::too_many_arguments)] // solve's six and the scale it measures against
pub fn solve_against(
    apply: impl Fn(&[Vec3], &mut [Vec3]),
    precondition: impl Fn(&[Vec3], &mut [Vec3]),
    fixed: &FixedNodes,
    b: &[Vec3],
    x: &mut [Vec3],
    settings: CgSettings,
    reference: f64,
) -> CgReport {
    let n = b.len();
    let Some((bb, b_norm)) = free_rhs(fixed, b, x) else {
        return CgReport { iterations: 0, relative_residual: 0.0, converged: true };
    };
    let mut ap = vec![[0.0; 3]; n];
    apply(x, &mut ap);
    let mut r: Vec<Vec3> =
        bb.iter().zip(&ap).map(|(b, a)| [b[0] - a[0], b[1] - a[1], b[2] - a[2]]).collect();
    fixed.project(&mut r);
    let precondition = |r: &[Vec3], z: &mut Vec<Vec3>| {
        precondition(r, z);
        fixed.project(z);
    };
    let mut z = vec![[0.0; 3]; n];
    precondition(&r, &mut z);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let scale = b_norm.max(reference);
    let mut rel = dot(&r, &r).sqrt() / scale;
    let mut it = 0;
    while rel > settings.tolerance && it < settings.max_iterations {
        ap.fill([0.0; 3]);
        apply(&p, &mut ap);
        fixed.project(&mut ap);
        let pap = dot(&p, &ap);
        if pap <= 0.0 {
            break;
        }
        let alpha = rz / pap;
        for i in 0..n {
            for k in 0..3 {
                x[i][k] += alpha * p[i][k];
                r[i][k] -= alpha * ap[i][k];
            }
        }
        precondition(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            for k in 0..3 {
                p[i][k] = z[i][k] + beta * p[i][k];
            }
        }
        rel = dot(&r, &r).sqrt() / scale;
        it += 1;
    }
    CgReport { iterations: it, relative_residual: rel, converged: rel <= settings.tolerance }
}
