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

use crate::lanes::{Lane, Lane4};
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
        matrix_of(&Quaternion { w: self.w, v: self.v })
    }

    /// `self · other` (apply `other` first).
    #[must_use]
    pub fn mul(&self, o: &Self) -> Self {
        let p = product(&Quaternion { w: self.w, v: self.v }, &Quaternion { w: o.w, v: o.v });
        Self { w: p.w, v: p.v }
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
    let mut current = Quaternion { w: q.w, v: q.v };
    let mut r = matrix_of(&current);
    for it in 0..max_iterations {
        let step = iterate(a, &current, &r);
        if step.converged {
            return Refined { iterations: it, matrix: r, alignment: step.alignment };
        }
        (current, r) = (step.next, step.next_matrix);
        *q = Quat { w: current.w, v: current.v };
        if step.accepted {
            return Refined { iterations: it, matrix: r, alignment: step.next_alignment };
        }
    }
    Refined { iterations: max_iterations, matrix: r, alignment: alignment(a, q) }
}

/// [`nearest`] for four matrices at once (`a`, lane `l` the `l`-th matrix), each lane with
/// exactly the bits [`nearest`] gives it: the iterations run on the lanes of `W` (vector
/// instructions), and the rare lane that needs more than [`refine`] (a half-turn restart) is
/// redone alone from its warm start.
#[allow(clippy::inline_always)] // inlined into callers compiled for wider vector instructions
#[inline(always)]
pub fn nearest4<W: Lane4>(a: &Matrix<W>, q: &mut [Quat; 4], max_iterations: usize) -> [Refined; 4] {
    // Plain loops throughout, no `array::map`/`from_fn` closures: whether those are inlined
    // depends on the caller's codegen unit, and out of line they cost the rotation pass 25 %.
    let like = a[0][0];
    let mut start = [[0.0; 4]; 4];
    for l in 0..4 {
        start[0][l] = q[l].w;
        for c in 0..3 {
            start[c + 1][l] = q[l].v[c];
        }
    }
    let mut current = Quaternion {
        w: W::from_lanes(like, start[0]),
        v: [
            W::from_lanes(like, start[1]),
            W::from_lanes(like, start[2]),
            W::from_lanes(like, start[3]),
        ],
    };
    let mut r = matrix_of(&current);
    let mut done: [Option<Refined>; 4] = [None; 4];
    for it in 0..max_iterations {
        let step = iterate(a, &current, &r);
        let converged = W::mask_lanes(step.converged);
        let alignment = step.alignment.lanes();
        for l in 0..4 {
            if done[l].is_none() && converged[l] {
                let matrix = lane_of(&r, l);
                done[l] = Some(Refined { iterations: it, matrix, alignment: alignment[l] });
            }
        }
        // Lanes that finished keep their rotation; the others take the turn.
        let mut still = [false; 4];
        for l in 0..4 {
            still[l] = done[l].is_none();
        }
        let moving = W::mask_from_lanes(like, still);
        current = Quaternion {
            w: W::select(moving, step.next.w, current.w),
            v: [
                W::select(moving, step.next.v[0], current.v[0]),
                W::select(moving, step.next.v[1], current.v[1]),
                W::select(moving, step.next.v[2], current.v[2]),
            ],
        };
        for (row, next) in r.iter_mut().zip(&step.next_matrix) {
            for (x, n) in row.iter_mut().zip(next) {
                *x = W::select(moving, *n, *x);
            }
        }
        let accepted = W::mask_lanes(step.accepted & moving);
        let next_alignment = step.next_alignment.lanes();
        for l in 0..4 {
            if accepted[l] {
                let matrix = lane_of(&r, l);
                done[l] = Some(Refined { iterations: it, matrix, alignment: next_alignment[l] });
            }
        }
        if done.iter().all(Option::is_some) {
            break;
        }
    }
    let w = current.w.lanes();
    let v = [current.v[0].lanes(), current.v[1].lanes(), current.v[2].lanes()];
    let mut out = [Refined { iterations: 0, matrix: [[0.0; 3]; 3], alignment: 0.0 }; 4];
    for l in 0..4 {
        out[l] = match done[l] {
            Some(first) if first.alignment >= 0.0 => {
                q[l] = Quat { w: w[l], v: [v[0][l], v[1][l], v[2][l]] };
                first
            }
            // Not converged, or on a saddle: what [`nearest`] does from the warm start.
            _ => nearest(&lane_of(a, l), &mut q[l], max_iterations),
        };
    }
    out
}

/// Lane `l` of a matrix of lane values.
#[allow(clippy::inline_always)]
#[inline(always)]
fn lane_of<W: Lane4>(m: &Matrix<W>, l: usize) -> Mat3 {
    let mut out = [[0.0; 3]; 3];
    for (o, row) in out.iter_mut().zip(m) {
        for (x, w) in o.iter_mut().zip(row) {
            *x = w.lanes()[l];
        }
    }
    out
}

/// A 3×3 matrix of lane values.
pub type Matrix<T> = [[T; 3]; 3];

/// A quaternion of lane values (see [`Quat`]).
#[derive(Clone, Copy)]
struct Quaternion<T> {
    w: T,
    v: [T; 3],
}

/// What one iteration found: at the current rotation, and after its turn.
struct Iteration<T: Lane> {
    /// The turn would be negligible: the current rotation is the answer.
    converged: T::Mask,
    /// `tr(Rᵀa)` at the current rotation.
    alignment: T,
    /// The rotation after the turn.
    next: Quaternion<T>,
    /// The rotation after the turn, as a matrix.
    next_matrix: Matrix<T>,
    /// A Newton turn under 1e-6 rad: its result is the answer (its error, of order |θ|², is
    /// below what `converged` accepts), without an iteration that would only confirm it.
    accepted: T::Mask,
    /// `tr(Rᵀa)` after the turn.
    next_alignment: T,
}

/// The rotation matrix of a unit quaternion.
#[allow(clippy::inline_always)]
#[inline(always)]
fn matrix_of<T: Lane>(q: &Quaternion<T>) -> Matrix<T> {
    let (w, [x, y, z]) = (q.w, q.v);
    let (one, two) = (w.constant(1.0), w.constant(2.0));
    [
        [one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y)],
        [two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x)],
        [two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y)],
    ]
}

#[allow(clippy::inline_always)]
#[inline(always)]
fn dot3<T: Lane>(a: &[T; 3], b: &[T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// One iteration from the rotation `q` (with matrix `r`) towards the maximiser of `tr(Rᵀa)`.
#[allow(clippy::inline_always)]
#[inline(always)]
fn iterate<T: Lane>(a: &Matrix<T>, q: &Quaternion<T>, r: &Matrix<T>) -> Iteration<T> {
    // B = Rᵀa. Turning R by a small θ in its own frame, R' = R·exp([θ]×), changes tr(R'ᵀa)
    // by gᵀθ − ½ θᵀHθ with g = axial(B − Bᵀ) and H = tr(B)·I − sym(B).
    //
    // Plain loops, not `array::from_fn` or `map`: on vector lanes this runs under a run-time
    // target feature, and a closure the compiler leaves out of line runs without it, turning
    // every lane operation into a call (which slowed the whole step markedly when it happened).
    let mut b: Matrix<T> = *a;
    for (i, row) in b.iter_mut().enumerate() {
        for (j, bij) in row.iter_mut().enumerate() {
            *bij = r[0][i] * a[0][j] + r[1][i] * a[1][j] + r[2][i] * a[2][j];
        }
    }
    let g = [b[2][1] - b[1][2], b[0][2] - b[2][0], b[1][0] - b[0][1]];
    let t = b[0][0] + b[1][1] + b[2][2];
    let mut h: Matrix<T> = b;
    for (i, row) in h.iter_mut().enumerate() {
        for (j, hij) in row.iter_mut().enumerate() {
            let s = t.constant(-0.5) * (b[i][j] + b[j][i]);
            *hij = if i == j { s + t } else { s };
        }
    }
    let (newton, trusted) = newton_step(&h, &g);
    // Müller et al.'s step: H replaced by |tr B|·I, safe far from the maximum (and for inverted
    // elements), but only linearly convergent (about a factor 3 per iteration).
    let inv = t.constant(1.0) / (t.abs() + t.constant(1e-9));
    let mut theta = g;
    for (k, th) in theta.iter_mut().enumerate() {
        *th = T::select(trusted, newton[k], g[k] * inv);
    }
    let size = dot3(&theta, &theta);
    // The turn by θ is taken as the unnormalised quaternion (1, θ/2): the same axis and an
    // angle 2·atan(|θ|/2) ≈ |θ| as θ → 0, so the fixed point (θ = 0) is the same, a step never
    // exceeds half a turn, and no sin/cos is evaluated (this runs per element per step).
    let half = t.constant(0.5);
    let turn = [half * theta[0], half * theta[1], half * theta[2]];
    let turned = product(q, &Quaternion { w: t.constant(1.0), v: turn });
    let next = normalized(&turned);
    let next_matrix = matrix_of(&next);
    Iteration {
        converged: size.lt(t.constant(1e-24)),
        alignment: t,
        next,
        next_matrix,
        accepted: trusted & size.lt(t.constant(1e-12)),
        next_alignment: trace_product(&next_matrix, a),
    }
}

/// `tr(rᵀa)`.
#[allow(clippy::inline_always)]
#[inline(always)]
fn trace_product<T: Lane>(r: &Matrix<T>, a: &Matrix<T>) -> T {
    let mut sum = r[0][0] * a[0][0];
    for (k, c) in [(1, 0), (2, 0), (0, 1), (1, 1), (2, 1), (0, 2), (1, 2), (2, 2)] {
        sum = sum + r[k][c] * a[k][c];
    }
    sum
}

/// `a · b` (apply `b` first).
#[allow(clippy::inline_always)]
#[inline(always)]
fn product<T: Lane>(a: &Quaternion<T>, b: &Quaternion<T>) -> Quaternion<T> {
    Quaternion {
        w: a.w * b.w - dot3(&a.v, &b.v),
        v: [
            a.w * b.v[0] + b.w * a.v[0] + a.v[1] * b.v[2] - a.v[2] * b.v[1],
            a.w * b.v[1] + b.w * a.v[1] + a.v[2] * b.v[0] - a.v[0] * b.v[2],
            a.w * b.v[2] + b.w * a.v[2] + a.v[0] * b.v[1] - a.v[1] * b.v[0],
        ],
    }
}

/// `q` with unit norm (the identity for a zero quaternion).
#[allow(clippy::inline_always)]
#[inline(always)]
fn normalized<T: Lane>(q: &Quaternion<T>) -> Quaternion<T> {
    let n = (q.w * q.w + dot3(&q.v, &q.v)).sqrt();
    let positive = n.gt(n.constant(0.0));
    Quaternion {
        w: T::select(positive, q.w / n, n.constant(1.0)),
        v: [
            T::select(positive, q.v[0] / n, n.constant(0.0)),
            T::select(positive, q.v[1] / n, n.constant(0.0)),
            T::select(positive, q.v[2] / n, n.constant(0.0)),
        ],
    }
}

/// The Newton step `H⁻¹g`, and where it is trusted: where `H` is clearly positive definite (near
/// the maximum, where it converges quadratically: two or three iterations from the previous
/// step's rotation) and the step is under a radian (the quadratic model is not trusted further).
#[allow(clippy::inline_always)]
#[inline(always)]
fn newton_step<T: Lane>(h: &Matrix<T>, g: &[T; 3]) -> ([T; 3], T::Mask) {
    let scale = h[0][0].abs() + h[1][1].abs() + h[2][2].abs();
    let m1 = h[0][0];
    let m2 = h[0][0] * h[1][1] - h[0][1] * h[1][0];
    let d = h[0][0] * (h[1][1] * h[2][2] - h[1][2] * h[2][1])
        - h[0][1] * (h[1][0] * h[2][2] - h[1][2] * h[2][0])
        + h[0][2] * (h[1][0] * h[2][1] - h[1][1] * h[2][0]);
    let eps = scale.constant(1e-6) * scale;
    let definite = m1.gt(eps) & m2.gt(eps * scale) & d.gt(eps * scale * scale);
    let inv = scale.constant(1.0) / d;
    let cof = |i: usize, j: usize| {
        let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
        let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
        h[i1][j1] * h[i2][j2] - h[i1][j2] * h[i2][j1]
    };
    // H is symmetric, so its inverse is the cofactor matrix over the determinant.
    let mut theta = *g;
    for (i, th) in theta.iter_mut().enumerate() {
        *th = (cof(i, 0) * g[0] + cof(i, 1) * g[1] + cof(i, 2) * g[2]) * inv;
    }
    let short = dot3(&theta, &theta).le(scale.constant(1.0));
    (theta, definite & short)
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
    use crate::lanes::F64x4;
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

    /// Four matrices to refine at once, and their warm starts: a nearby warm start, a lane that
    /// needs Müller's steps, an inverted element, and a half-turn saddle.
    fn four_cases() -> ([Mat3; 4], [Quat; 4]) {
        let s = [[1.05, 0.02, -0.01], [0.02, 0.97, 0.015], [-0.01, 0.015, 1.02]];
        let a = [
            mul(&axis_angle(&[0.36, -0.48, 0.8], 0.9), &s),
            mul(&axis_angle(&[0.0, 0.0, 1.0], 2.5), &s),
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -0.5]],
            axis_angle(&[0.0, 1.0, 0.0], std::f64::consts::PI),
        ];
        let warm = [
            Quat::from_axis_angle(&[0.36, -0.48, 0.8], 0.88),
            Quat::IDENTITY,
            Quat::from_axis_angle(&[1.0, 0.0, 0.0], 0.1),
            Quat::IDENTITY,
        ];
        (a, warm)
    }

    /// Each lane of [`nearest4`] has the bits [`nearest`] gives it alone.
    #[test]
    fn four_lanes_give_the_single_bits() {
        let (a, warm) = four_cases();
        let mut q4 = warm;
        let lanes: Matrix<F64x4> =
            std::array::from_fn(|i| std::array::from_fn(|j| F64x4(a.map(|m| m[i][j]))));
        let wide = nearest4(&lanes, &mut q4, 100);
        for l in 0..4 {
            let mut q = warm[l];
            let single = nearest(&a[l], &mut q, 100);
            let bits = |m: &Mat3| m.map(|row| row.map(f64::to_bits));
            assert_eq!(bits(&wide[l].matrix), bits(&single.matrix), "lane {l}");
            assert_eq!(wide[l].alignment.to_bits(), single.alignment.to_bits(), "lane {l}");
            assert_eq!(wide[l].iterations, single.iterations, "lane {l}");
            assert_eq!(q4[l], q, "lane {l}");
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
