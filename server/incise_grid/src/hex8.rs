//! The trilinear 8-node hexahedron on an axis-aligned box: stiffness K₀ and consistent mass M₀
//! (Jeřábková 2010 §2.2: the `A_(0)` matrices every coarse element is condensed from).
//!
//! Corner `c` sits at `(c & 1, (c >> 1) & 1, c >> 2)` in cell units, so corner order is Morton
//! order; degree of freedom `3c + i` is the displacement of corner `c` along axis `i`. Both
//! integrals use 2×2×2 Gauss points, which is exact on a box: the strain-energy integrand of a
//! trilinear field is at most quadratic per axis, the mass integrand too.

use incise_math::Vec3;

/// `dst += src`, element by element (condensation sums: one fixed order, so bit-reproducible).
#[inline]
pub fn add_into(dst: &mut [f64], src: &[f64]) {
    for (a, b) in dst.iter_mut().zip(src) {
        *a += *b;
    }
}

/// `dst -= src`, element by element.
#[inline]
pub fn sub_from(dst: &mut [f64], src: &[f64]) {
    for (a, b) in dst.iter_mut().zip(src) {
        *a -= *b;
    }
}

/// A dense 24×24 matrix, row-major: entry `(r, c)` at `r * 24 + c`.
#[derive(Clone, PartialEq)]
pub struct Mat24(pub [f64; 576]);

/// A dense 8×8 scalar matrix, row-major. The consistent mass of a hexahedron is `m ⊗ I₃`, so an
/// element stores only `m`.
pub type Mat8 = [f64; 64];

impl Mat24 {
    /// All zeros.
    #[must_use]
    pub fn zeros() -> Self {
        Self([0.0; 576])
    }

    /// Entry `(r, c)`.
    #[inline]
    #[must_use]
    pub fn get(&self, r: usize, c: usize) -> f64 {
        self.0[r * 24 + c]
    }

    /// `self += other`.
    #[inline]
    pub fn add_assign(&mut self, other: &Self) {
        add_into(&mut self.0, &other.0);
    }

    /// `self -= other`.
    #[inline]
    pub fn sub_assign(&mut self, other: &Self) {
        sub_from(&mut self.0, &other.0);
    }

    /// `self · v`.
    #[must_use]
    pub fn mul_vec(&self, v: &[f64; 24]) -> [f64; 24] {
        std::array::from_fn(|r| (0..24).map(|c| self.get(r, c) * v[c]).sum())
    }

    /// `self · v` for a symmetric matrix: the sum of `v[c]` times row `c` (= column `c`), a
    /// sequence of 24-wide fused multiply-adds (`mul_add`: one rounding, the same bits from an FMA
    /// instruction or the software fallback) the compiler vectorises, in a fixed order.
    /// Several times faster than [`Mat24::mul_vec`]; wrong for a non-symmetric matrix.
    // Always inlined: the caller may be compiled for wider vector instructions (incise_fem's
    // run-time dispatch), and only an inlined copy gets them.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    #[must_use]
    pub fn mul_vec_symmetric(&self, v: &[f64; 24]) -> [f64; 24] {
        let mut out = [0.0; 24];
        for (row, &vc) in self.0.chunks_exact(24).zip(v) {
            for (o, &k) in out.iter_mut().zip(row) {
                *o = k.mul_add(vc, *o);
            }
        }
        out
    }

    /// [`Mat24::mul_vec_symmetric`] of two vectors at once: each row of the matrix is loaded
    /// once for both products (the single product is bound by those loads). Each result has the
    /// same bits as its own single product: the same operations in the same order.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    #[must_use]
    pub fn mul_vec_symmetric_pair(&self, v: &[f64; 24], w: &[f64; 24]) -> ([f64; 24], [f64; 24]) {
        let mut a = [0.0; 24];
        let mut b = [0.0; 24];
        for ((row, &vc), &wc) in self.0.chunks_exact(24).zip(v).zip(w) {
            for ((x, y), &k) in a.iter_mut().zip(b.iter_mut()).zip(row) {
                *x = k.mul_add(vc, *x);
                *y = k.mul_add(wc, *y);
            }
        }
        (a, b)
    }

    /// `(self + selfᵀ) / 2`: exactly symmetric, for [`Mat24::mul_vec_symmetric`].
    #[must_use]
    pub fn symmetrized(&self) -> Self {
        Self(std::array::from_fn(|i| {
            let (r, c) = (i / 24, i % 24);
            0.5 * (self.0[r * 24 + c] + self.0[c * 24 + r])
        }))
    }

    /// Frobenius norm.
    #[must_use]
    pub fn frobenius(&self) -> f64 {
        self.0.iter().map(|a| a * a).sum::<f64>().sqrt()
    }

    /// Frobenius norm of `self − other`.
    #[must_use]
    pub fn frobenius_diff(&self, other: &Self) -> f64 {
        self.0.iter().zip(other.0.iter()).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt()
    }
}

impl std::fmt::Debug for Mat24 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Mat24(‖·‖F = {:e})", self.frobenius())
    }
}

/// A symmetric 24×24 matrix stored as its upper triangle, row by row (300 entries): condensed
/// stiffness is symmetric, so sums over voxels touch half the memory.
#[derive(Clone, PartialEq)]
pub struct Sym24(pub [f64; 300]);

impl Sym24 {
    /// All zeros.
    #[must_use]
    pub fn zeros() -> Self {
        Self([0.0; 300])
    }

    /// The upper triangle of `m` (its lower triangle is ignored).
    #[must_use]
    pub fn from_upper(m: &Mat24) -> Self {
        let mut out = [0.0; 300];
        let mut k = 0;
        for r in 0..24 {
            for c in r..24 {
                out[k] = m.0[r * 24 + c];
                k += 1;
            }
        }
        Self(out)
    }

    /// The full symmetric matrix.
    #[must_use]
    pub fn to_full(&self) -> Mat24 {
        let mut m = Mat24::zeros();
        let mut k = 0;
        for r in 0..24 {
            for c in r..24 {
                m.0[r * 24 + c] = self.0[k];
                m.0[c * 24 + r] = self.0[k];
                k += 1;
            }
        }
        m
    }

    /// `self += other`.
    #[inline]
    pub fn add_assign(&mut self, other: &Self) {
        add_into(&mut self.0, &other.0);
    }

    /// `self -= other`.
    #[inline]
    pub fn sub_assign(&mut self, other: &Self) {
        sub_from(&mut self.0, &other.0);
    }
}

impl std::fmt::Debug for Sym24 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Sym24(‖·‖F = {:e})", self.to_full().frobenius())
    }
}

/// Frobenius norm of the difference of two 8×8 matrices.
#[must_use]
pub fn mat8_frobenius_diff(a: &Mat8, b: &Mat8) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

/// Frobenius norm of an 8×8 matrix.
#[must_use]
pub fn mat8_frobenius(a: &Mat8) -> f64 {
    a.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Corner `c` of the unit cube, `(c & 1, (c >> 1) & 1, c >> 2)`.
#[inline]
#[must_use]
pub fn corner(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, c >> 2]
}

/// Value of the trilinear shape function of corner `n` at local coordinates `xi ∈ [0, 1]³`.
#[inline]
#[must_use]
pub fn shape(n: usize, xi: Vec3) -> f64 {
    let b = corner(n);
    (0..3).map(|a| if b[a] == 1 { xi[a] } else { 1.0 - xi[a] }).product()
}

/// Gradient (w.r.t. physical coordinates) of corner `n`'s shape function at `xi`, on a box of
/// edge lengths `size`.
pub(crate) fn shape_gradient(n: usize, xi: Vec3, size: Vec3) -> Vec3 {
    let b = corner(n);
    let f = |a: usize| if b[a] == 1 { xi[a] } else { 1.0 - xi[a] };
    let d = |a: usize| if b[a] == 1 { 1.0 / size[a] } else { -1.0 / size[a] };
    [d(0) * f(1) * f(2), f(0) * d(1) * f(2), f(0) * f(1) * d(2)]
}

/// The 2×2×2 Gauss points in `[0, 1]³` (each with weight 1/8 of the cell volume).
pub(crate) fn gauss_points() -> [Vec3; 8] {
    let g = 0.5 / 3f64.sqrt();
    let p = [0.5 - g, 0.5 + g];
    std::array::from_fn(|c| {
        let b = corner(c);
        [p[b[0]], p[b[1]], p[b[2]]]
    })
}

/// Stiffness of an isotropic trilinear hexahedron filling a box of edge lengths `size` (m),
/// Young's modulus `youngs` (Pa), Poisson ratio `poisson`:
/// `K_(ai)(bj) = ∫ λ ∂ᵢNₐ ∂ⱼN_b + μ ∂ⱼNₐ ∂ᵢN_b + μ δᵢⱼ ∇Nₐ·∇N_b dV`.
#[must_use]
pub fn hex_stiffness(size: Vec3, youngs: f64, poisson: f64) -> Mat24 {
    let lambda = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    let mu = youngs / (2.0 * (1.0 + poisson));
    let weight = size[0] * size[1] * size[2] / 8.0;
    let mut k = Mat24::zeros();
    for xi in gauss_points() {
        let g: [Vec3; 8] = std::array::from_fn(|n| shape_gradient(n, xi, size));
        for a in 0..8 {
            for b in 0..8 {
                let dot = g[a][0] * g[b][0] + g[a][1] * g[b][1] + g[a][2] * g[b][2];
                for i in 0..3 {
                    for j in 0..3 {
                        let mut v = lambda * g[a][i] * g[b][j] + mu * g[a][j] * g[b][i];
                        if i == j {
                            v += mu * dot;
                        }
                        k.0[(3 * a + i) * 24 + 3 * b + j] += weight * v;
                    }
                }
            }
        }
    }
    k
}

/// Consistent mass `m_ab = ρ ∫ Nₐ N_b dV` of a box of edge lengths `size` and density `density`;
/// the full 24×24 mass is `m ⊗ I₃`.
#[must_use]
pub fn hex_mass(size: Vec3, density: f64) -> Mat8 {
    let weight = density * size[0] * size[1] * size[2] / 8.0;
    let mut m = [0.0; 64];
    for xi in gauss_points() {
        let n: [f64; 8] = std::array::from_fn(|a| shape(a, xi));
        for a in 0..8 {
            for b in 0..8 {
                m[a * 8 + b] += weight * n[a] * n[b];
            }
        }
    }
    m
}

/// The six rigid-body modes (three translations, three infinitesimal rotations about the box
/// centre) of a box of edge lengths `size`, as 24-vectors.
#[must_use]
pub fn rigid_modes(size: Vec3) -> [[f64; 24]; 6] {
    std::array::from_fn(|mode| {
        let mut v = [0.0; 24];
        for c in 0..8 {
            let b = corner(c);
            let x: Vec3 = std::array::from_fn(|a| (b[a] as f64 - 0.5) * size[a]);
            let u = match mode {
                0 => [1.0, 0.0, 0.0],
                1 => [0.0, 1.0, 0.0],
                2 => [0.0, 0.0, 1.0],
                3 => [0.0, -x[2], x[1]],
                4 => [x[2], 0.0, -x[0]],
                _ => [-x[1], x[0], 0.0],
            };
            v[3 * c..3 * c + 3].copy_from_slice(&u);
        }
        v
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetric_product_matches_the_general_one() {
        let k = hex_stiffness([2e-3, 3e-3, 1.5e-3], 3e3, 0.45).symmetrized();
        let v: [f64; 24] = std::array::from_fn(|i| (i as f64 * 0.37).sin());
        let (a, b) = (k.mul_vec(&v), k.mul_vec_symmetric(&v));
        let w: [f64; 24] = std::array::from_fn(|i| v[23 - i] - 0.5);
        let (pv, pw) = k.mul_vec_symmetric_pair(&v, &w);
        let bits = |x: &[f64; 24]| x.map(f64::to_bits);
        assert_eq!(bits(&pv), bits(&b), "the pair's first product is the single one, bit for bit");
        assert_eq!(bits(&pw), bits(&k.mul_vec_symmetric(&w)), "and so is its second");
        let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        // Same terms summed in a different order: equal to rounding.
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 1e-14 * scale));
    }

    #[test]
    fn stiffness_is_symmetric_with_rigid_null_space() {
        let size = [2e-3, 3e-3, 1.5e-3];
        let k = hex_stiffness(size, 3e3, 0.45);
        for r in 0..24 {
            for c in 0..24 {
                assert!((k.get(r, c) - k.get(c, r)).abs() <= 1e-12 * k.frobenius());
            }
        }
        for mode in rigid_modes(size) {
            let f = k.mul_vec(&mode);
            let norm = f.iter().map(|x| x * x).sum::<f64>().sqrt();
            let scale = k.frobenius() * mode.iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!(norm <= 1e-12 * scale, "rigid mode produces force {norm:e} (scale {scale:e})");
        }
    }

    #[test]
    fn uniaxial_stretch_gives_youngs_modulus() {
        // Stretch a unit cube by ε along x with lateral faces free of the Poisson constraint:
        // with ν = 0 the x-face force is E·ε·A exactly.
        let k = hex_stiffness([1.0, 1.0, 1.0], 10.0, 0.0);
        let mut u = [0.0; 24];
        for c in 0..8 {
            u[3 * c] = 0.01 * corner(c)[0] as f64;
        }
        let f = k.mul_vec(&u);
        let right: f64 = (0..8).filter(|&c| corner(c)[0] == 1).map(|c| f[3 * c]).sum();
        assert!((right - 10.0 * 0.01).abs() < 1e-12, "{right}");
    }

    #[test]
    fn mass_sums_to_rho_v() {
        let m = hex_mass([1e-3, 2e-3, 4e-3], 1000.0);
        let total: f64 = m.iter().sum();
        assert!((total - 1000.0 * 8e-9).abs() <= 1e-15 * total.abs().max(1.0) + 1e-24, "{total}");
    }
}
