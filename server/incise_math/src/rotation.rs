//! The rotational part of a deformation gradient, for corotational elements.
//!
//! Müller, Bender, Chentanez, Macklin 2016, "A robust method to extract the rotational part of
//! deformations": the rotation R maximising tr(Rᵀ A) is found by rotating R about
//! `ω = Σᵢ rᵢ × aᵢ / (|Σᵢ rᵢ · aᵢ| + ε)` until ω vanishes (`rᵢ`, `aᵢ` the columns). Unlike a
//! polar decomposition through the SVD it always returns a proper rotation, also for an inverted
//! element (det A < 0), where the polar factor would be a reflection: the inversion then shows up
//! as a large displacement in the rotated frame, so the elastic force pushes the element back
//! instead of locking or flipping it.
//!
//! Müller's step is a Newton step on `tr(RᵀA)` with its Hessian `H = tr(B)·I − sym(B)`
//! (`B = RᵀA`) replaced by `tr(B)·I`; for a nearly isotropic stretch that overestimates `H` by
//! half, so each iteration gains only a factor of about three (eighteen iterations per element
//! per step were measured). Where `H` is clearly positive definite (near the maximum) the exact
//! Newton step is taken instead, which converges quadratically: warm-started from the previous
//! step's rotation, two or three iterations. Elsewhere (far away, saddles, inversions) Müller's
//! step keeps the method's robustness.

use crate::Vec3;
use crate::mat3::{Mat3, dot};

/// A unit quaternion `w + xi + yj + zk`, the state carried between steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quat {
    /// Scalar part.
    pub w: f64,
    /// Vector part.
    pub v: [f64; 3],
}

impl Quat {
    /// No rotation.
    pub const IDENTITY: Self = Self { w: 1.0, v: [0.0; 3] };

    /// The rotation matrix.
    #[must_use]
    pub fn to_matrix(&self) -> Mat3 {
        let (w, [x, y, z]) = (self.w, self.v);
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        ]
    }

    /// `self · other` (apply `other` first).
    #[must_use]
    pub fn mul(&self, o: &Self) -> Self {
        let (a, b) = (self, o);
        Self {
            w: a.w * b.w - dot(&a.v, &b.v),
            v: [
                a.w * b.v[0] + b.w * a.v[0] + a.v[1] * b.v[2] - a.v[2] * b.v[1],
                a.w * b.v[1] + b.w * a.v[1] + a.v[2] * b.v[0] - a.v[0] * b.v[2],
                a.w * b.v[2] + b.w * a.v[2] + a.v[0] * b.v[1] - a.v[1] * b.v[0],
            ],
        }
    }

    /// Rotation by `angle` about the unit `axis`.
    #[must_use]
    pub fn from_axis_angle(axis: &[f64; 3], angle: f64) -> Self {
        let (s, c) = (0.5 * angle).sin_cos();
        Self { w: c, v: [axis[0] * s, axis[1] * s, axis[2] * s] }
    }

    /// The same rotation with unit norm (guards against drift over many steps).
    #[must_use]
    pub fn normalized(&self) -> Self {
        let n = (self.w * self.w + dot(&self.v, &self.v)).sqrt();
        if n > 0.0 {
            Self { w: self.w / n, v: [self.v[0] / n, self.v[1] / n, self.v[2] / n] }
        } else {
            Self::IDENTITY
        }
    }
}

/// The result of refining a rotation: how many rotations it took, and the rotation matrix and
/// `tr(Rᵀa)` at the result (what the iteration computed last, so callers need not recompute them).
#[derive(Clone, Copy, Debug)]
pub struct Refined {
    /// Rotations applied.
    pub iterations: usize,
    /// The rotation as a matrix.
    pub matrix: Mat3,
    /// `tr(Rᵀa)`, what the iteration maximises ([`alignment`]).
    pub alignment: f64,
}

/// Refines `q` (a warm start, e.g. the previous step's rotation) to the rotation closest to `a`
/// in the sense of maximal tr(Rᵀa); at most `max_iterations` rotations. Returns the iterations used.
pub fn extract_rotation(a: &Mat3, q: &mut Quat, max_iterations: usize) -> usize {
    refine(a, q, max_iterations).iterations
}

/// [`extract_rotation`], returning what the last iteration computed too.
pub fn refine(a: &Mat3, q: &mut Quat, max_iterations: usize) -> Refined {
    for it in 0..max_iterations {
        if let Some((matrix, alignment)) = iterate(a, q) {
            return Refined { iterations: it, matrix, alignment };
        }
    }
    Refined { iterations: max_iterations, matrix: q.to_matrix(), alignment: alignment(a, q) }
}

/// One iteration of [`refine`]: turns `q` towards the maximiser of `tr(Rᵀa)`, or returns its
/// matrix and `tr(Rᵀa)` when the turn would be negligible (converged; `q` unchanged).
#[inline]
fn iterate(a: &Mat3, q: &mut Quat) -> Option<(Mat3, f64)> {
    let r = q.to_matrix();
    // B = Rᵀa. Turning R by a small θ in its own frame, R' = R·exp([θ]×), changes tr(R'ᵀa)
    // by gᵀθ − ½ θᵀHθ with g = axial(B − Bᵀ) and H = tr(B)·I − sym(B).
    let b: Mat3 = std::array::from_fn(|i| {
        std::array::from_fn(|j| r[0][i] * a[0][j] + r[1][i] * a[1][j] + r[2][i] * a[2][j])
    });
    let g = [b[2][1] - b[1][2], b[0][2] - b[2][0], b[1][0] - b[0][1]];
    let t = b[0][0] + b[1][1] + b[2][2];
    let h: Mat3 = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let s = -0.5 * (b[i][j] + b[j][i]);
            if i == j { s + t } else { s }
        })
    });
    let newton = newton_step(&h, &g);
    // Müller et al.'s step: H replaced by |tr B|·I, safe far from the maximum (and for inverted
    // elements), but only linearly convergent (about a factor 3 per iteration).
    let theta = newton.unwrap_or_else(|| {
        let inv = 1.0 / (t.abs() + 1e-9);
        [g[0] * inv, g[1] * inv, g[2] * inv]
    });
    let size = dot(&theta, &theta);
    if size < 1e-24 {
        return Some((r, t));
    }
    // The turn by θ is taken as the unnormalised quaternion (1, θ/2): the same axis and an
    // angle 2·atan(|θ|/2) ≈ |θ| as θ → 0, so the fixed point (θ = 0) is the same, a step never
    // exceeds half a turn, and no sin/cos is evaluated (this runs per element per step).
    let step = Quat { w: 1.0, v: [0.5 * theta[0], 0.5 * theta[1], 0.5 * theta[2]] };
    *q = q.mul(&step).normalized();
    // A Newton step of |θ| < 1e-6 leaves an error of order |θ|² < 1e-12, what the test above
    // accepts: the iteration that would only confirm it is skipped (warm-started at 1 ms, it
    // was every element's last).
    if newton.is_some() && size < 1e-12 {
        return Some((q.to_matrix(), alignment(a, q)));
    }
    None
}

/// The Newton step `H⁻¹g` when `H` is clearly positive definite (near the maximum, where it
/// converges quadratically: two or three iterations from the previous step's rotation), else
/// `None`. Steps over a radian are refused too: the quadratic model is not trusted that far.
fn newton_step(h: &Mat3, g: &Vec3) -> Option<Vec3> {
    let scale = h[0][0].abs() + h[1][1].abs() + h[2][2].abs();
    let m1 = h[0][0];
    let m2 = h[0][0] * h[1][1] - h[0][1] * h[1][0];
    let d = crate::mat3::det(h);
    let eps = 1e-6 * scale;
    if !(m1 > eps && m2 > eps * scale && d > eps * scale * scale) {
        return None;
    }
    let inv = 1.0 / d;
    let cof = |i: usize, j: usize| {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        h[i1][j1] * h[i2][j2] - h[i1][j2] * h[i2][j1]
    };
    // H is symmetric, so its inverse is the cofactor matrix over the determinant.
    let theta: Vec3 = std::array::from_fn(|i| (0..3).map(|j| cof(i, j) * g[j]).sum::<f64>() * inv);
    (dot(&theta, &theta) <= 1.0).then_some(theta)
}

/// `tr(Rᵀa)` for the rotation `q`: what [`extract_rotation`] maximises.
#[must_use]
pub fn alignment(a: &Mat3, q: &Quat) -> f64 {
    let r = q.to_matrix();
    (0..3).map(|c| (0..3).map(|k| r[k][c] * a[k][c]).sum::<f64>()).sum()
}

/// [`extract_rotation`] made robust to a warm start half a turn away, where the iteration sits on
/// a saddle (ω = 0 although R is not the maximiser): when the result is not clearly aligned with
/// `a` (negative `tr(Rᵀa)`) or did not converge, it also starts from the three half-turns of the
/// warm start and keeps the best. Returns the iterations used.
pub fn nearest_rotation(a: &Mat3, q: &mut Quat, max_iterations: usize) -> usize {
    nearest(a, q, max_iterations).iterations
}

/// [`nearest_rotation`], returning the rotation matrix and alignment too ([`Refined`]).
pub fn nearest(a: &Mat3, q: &mut Quat, max_iterations: usize) -> Refined {
    let first = refine(a, q, max_iterations);
    if first.alignment >= 0.0 && first.iterations < max_iterations {
        return first;
    }
    let mut used = first.iterations;
    let mut best = (*q, first);
    for axis in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
        let mut trial = Quat::from_axis_angle(&axis, std::f64::consts::PI).mul(q).normalized();
        let refined = refine(a, &mut trial, max_iterations);
        used += refined.iterations;
        if refined.alignment > best.1.alignment {
            best = (trial, refined);
        }
    }
    *q = best.0;
    Refined { iterations: used, ..best.1 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mat3::{IDENTITY, axis_angle, det, mul, transpose};

    fn close(a: &Mat3, b: &Mat3, tol: f64) -> bool {
        (0..3).all(|r| (0..3).all(|c| (a[r][c] - b[r][c]).abs() <= tol))
    }

    #[test]
    fn recovers_a_rotation_times_a_stretch() {
        let r = axis_angle(&[0.6, 0.0, 0.8], 1.2);
        let s = [[1.3, 0.1, 0.0], [0.1, 0.8, 0.05], [0.0, 0.05, 1.1]];
        let a = mul(&r, &s);
        let mut q = Quat::IDENTITY;
        extract_rotation(&a, &mut q, 100);
        assert!(close(&q.to_matrix(), &r, 1e-9), "{:?} vs {r:?}", q.to_matrix());
    }

    /// Warm-started from the last step's rotation, the Newton step that is accepted without a
    /// confirming iteration (|θ| < 1e-6) still lands within 1e-11 of the exact polar rotation.
    #[test]
    fn a_small_turn_from_the_warm_start_is_exact() {
        let s = [[1.02, 0.01, 0.0], [0.01, 0.97, 0.02], [0.0, 0.02, 1.01]];
        let mut q = Quat::from_axis_angle(&[0.0, 0.6, 0.8], 0.7);
        for turn in [1e-3, 1e-5, 1e-7] {
            let r = mul(&axis_angle(&[1.0, 0.0, 0.0], turn), &q.to_matrix());
            let refined = nearest(&mul(&r, &s), &mut q, 100);
            assert!(close(&refined.matrix, &r, 1e-11), "turn {turn}: {:?}", refined.matrix);
            assert!(close(&q.to_matrix(), &refined.matrix, 0.0));
            assert!(refined.iterations <= 2, "turn {turn}: {refined:?}");
        }
    }

    #[test]
    fn quarter_and_half_turns_are_found() {
        for (axis, angle) in
            [([0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2), ([1.0, 0.0, 0.0], 3.0)]
        {
            let r = axis_angle(&axis, angle);
            let mut q = Quat::IDENTITY;
            extract_rotation(&r, &mut q, 200);
            assert!(close(&q.to_matrix(), &r, 1e-9));
        }
    }

    #[test]
    fn an_inverted_element_still_gets_a_proper_rotation() {
        let a = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -0.5]];
        let mut q = Quat::IDENTITY;
        extract_rotation(&a, &mut q, 100);
        let m = q.to_matrix();
        assert!((det(&m) - 1.0).abs() < 1e-12);
        assert!(close(&mul(&transpose(&m), &m), &IDENTITY, 1e-12));
    }

    #[test]
    fn a_half_turn_from_the_warm_start_is_not_a_trap() {
        let r = axis_angle(&[0.0, 1.0, 0.0], std::f64::consts::PI);
        let mut q = Quat::IDENTITY;
        extract_rotation(&r, &mut q, 100);
        assert!(!close(&q.to_matrix(), &r, 1e-3), "the plain iteration stalls on the saddle");
        let mut q = Quat::IDENTITY;
        nearest_rotation(&r, &mut q, 100);
        assert!(close(&q.to_matrix(), &r, 1e-9));
    }

    #[test]
    fn newton_steps_converge_quadratically_from_a_nearby_warm_start() {
        // F = R S with S symmetric positive definite: R is the exact polar factor. Müller's plain
        // step needed about 18 iterations here (a factor ~3 per iteration from 0.05 rad to 1e-12).
        let r = axis_angle(&[0.36, -0.48, 0.8], 0.9);
        let s = [[1.05, 0.02, -0.01], [0.02, 0.97, 0.015], [-0.01, 0.015, 1.02]];
        let a = mul(&r, &s);
        let mut q = Quat::from_axis_angle(&[0.0, 0.0, 1.0], 0.05)
            .mul(&Quat::from_axis_angle(&[0.36, -0.48, 0.8], 0.9).normalized())
            .normalized();
        let used = extract_rotation(&a, &mut q, 100);
        assert!(used <= 4, "{used} iterations");
        assert!(close(&q.to_matrix(), &r, 1e-12));
    }

    #[test]
    fn warm_start_converges_at_once() {
        let r = axis_angle(&[0.0, 1.0, 0.0], 0.7);
        let mut q = Quat::from_axis_angle(&[0.0, 1.0, 0.0], 0.7);
        assert!(extract_rotation(&r, &mut q, 10) <= 1);
    }
}
