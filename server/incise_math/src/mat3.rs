//! 3×3 kernels for per-element mechanics: products, transposes, determinants. Row-major
//! `[[f64; 3]; 3]`, `m[r][c]`; plain arrays so they cost nothing to pass and copy.

use crate::Vec3;

/// A 3×3 matrix, row-major: `m[row][col]`.
pub type Mat3 = [[f64; 3]; 3];

/// The identity.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `a · b`.
#[inline]
#[must_use]
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|r| {
        std::array::from_fn(|c| a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c])
    })
}

/// `aᵀ`.
#[inline]
#[must_use]
pub fn transpose(a: &Mat3) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| a[c][r]))
}

/// `a · v`.
#[inline]
#[must_use]
pub fn mul_vec(a: &Mat3, v: &Vec3) -> Vec3 {
    std::array::from_fn(|r| a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2])
}

/// `aᵀ · v`.
#[inline]
#[must_use]
pub fn mul_transpose_vec(a: &Mat3, v: &Vec3) -> Vec3 {
    std::array::from_fn(|c| a[0][c] * v[0] + a[1][c] * v[1] + a[2][c] * v[2])
}

/// Determinant.
#[inline]
#[must_use]
pub fn det(a: &Mat3) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

/// Cross product.
#[inline]
#[must_use]
pub fn cross(a: &Vec3, b: &Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Dot product.
#[inline]
#[must_use]
pub fn dot(a: &Vec3, b: &Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Difference `a − b`.
#[inline]
#[must_use]
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Euclidean length `|a|`.
#[inline]
#[must_use]
pub fn norm(a: Vec3) -> f64 {
    dot(&a, &a).sqrt()
}

/// Rotation by `angle` (rad) about the unit `axis` (Rodrigues).
#[must_use]
pub fn axis_angle(axis: &Vec3, angle: f64) -> Mat3 {
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    let [x, y, z] = *axis;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}
