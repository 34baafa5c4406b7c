//! The rotational part of a deformation gradient, for corotational elements.
//!
//! Müller, Bender, Chentanez, Macklin 2016, "A robust method to extract the rotational part of
//! deformations": the rotation R maximising tr(Rᵀ A) is found by rotating R about
//! `ω = Σᵢ rᵢ × aᵢ / (|Σᵢ rᵢ · aᵢ| + ε)` until ω vanishes (`rᵢ`, `aᵢ` the columns). Unlike a
//! polar decomposition through the SVD it always returns a proper rotation, also for an inverted
//! element (det A < 0), where the polar factor would be a reflection: the inversion then shows up
//! as a large displacement in the rotated frame, so the elastic force pushes the element back
//! instead of locking or flipping it. Warm-started from the previous step's rotation it converges
//! in one or two iterations.

use crate::mat3::{Mat3, cross, dot};

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

/// Refines `q` (a warm start, e.g. the previous step's rotation) to the rotation closest to `a`
/// in the sense of maximal tr(Rᵀa); at most `max_iterations` rotations. Returns the iterations used.
pub fn extract_rotation(a: &Mat3, q: &mut Quat, max_iterations: usize) -> usize {
    let col = |m: &Mat3, c: usize| [m[0][c], m[1][c], m[2][c]];
    for it in 0..max_iterations {
        let r = q.to_matrix();
        let mut num = [0.0; 3];
        let mut den = 0.0;
        for c in 0..3 {
            let (rc, ac) = (col(&r, c), col(a, c));
            let x = cross(&rc, &ac);
            num = [num[0] + x[0], num[1] + x[1], num[2] + x[2]];
            den += dot(&rc, &ac);
        }
        let inv = 1.0 / (den.abs() + 1e-9);
        let omega = [num[0] * inv, num[1] * inv, num[2] * inv];
        let w = dot(&omega, &omega).sqrt();
        if w < 1e-12 {
            return it;
        }
        let axis = [omega[0] / w, omega[1] / w, omega[2] / w];
        *q = Quat::from_axis_angle(&axis, w).mul(q).normalized();
    }
    max_iterations
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
    let mut used = extract_rotation(a, q, max_iterations);
    if alignment(a, q) >= 0.0 && used < max_iterations {
        return used;
    }
    let mut best = (*q, alignment(a, q));
    for axis in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
        let mut trial = Quat::from_axis_angle(&axis, std::f64::consts::PI).mul(q).normalized();
        used += extract_rotation(a, &mut trial, max_iterations);
        let t = alignment(a, &trial);
        if t > best.1 {
            best = (trial, t);
        }
    }
    *q = best.0;
    used
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
    fn warm_start_converges_at_once() {
        let r = axis_angle(&[0.0, 1.0, 0.0], 0.7);
        let mut q = Quat::from_axis_angle(&[0.0, 1.0, 0.0], 0.7);
        assert!(extract_rotation(&r, &mut q, 10) <= 1);
    }
}
