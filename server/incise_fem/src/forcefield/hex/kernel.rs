//! The element products, the innermost loops of every force evaluation and CG iteration,
//! compiled for AVX2 with FMA where the CPU has them (checked at run time through `pulp`).
//!
//! **Layout.** Inside an element pass an element's 24 degrees of freedom are kept component by
//! component (`8·axis + corner`), and each element stiffness is permuted to that layout once
//! ([`component_major`]). Rotating the eight corners into the element frame (`Rᵀ`) or back (`R`)
//! is then six 4-wide fused multiply-adds per row of the rotation ([`rotate`]) instead of 72
//! scalar operations; gather, rotations and scatter run in one inlined loop, and only the 24×24
//! product ([`product_pair`]) is a separate function: inlined into the larger loop, the compiler
//! kept its 48 accumulators in scalar registers (`profile_block` on scene B3 measures the
//! difference: `docs/notebook/code-comment-figures.md`).
//!
//! **Determinism.** Every sum is written as explicit fused multiply-adds in a fixed order, never
//! reordered: the AVX2 instructions and the fallback's correctly rounded `mul_add` lane by lane
//! give the same bits (`the_fallback_has_the_same_bits`), so frames replay bit for bit on any
//! machine. Neighbouring elements that share a matrix are multiplied as a pair
//! ([`Mat24::mul_vec_symmetric_pair`]), loading each row once for both.
//!
//! **Full cells** do not use the dense product at all: their stiffness is sparse in the
//! Walsh–Hadamard basis of the corners ([`crate::forcefield::hex::walsh`]), 45 of 576 entries, and that product is
//! inlined into the element loop (few accumulators, nothing to spill). The dense product serves
//! partially filled and superimposed cells.

use incise_grid::hex8::Mat24;
use incise_math::Vec3;
use incise_math::mat3::Mat3;

/// An element vector in the component-major layout: entry `8·axis + corner`.
pub(crate) type Local = [f64; 24];

/// `k` with its rows and columns reordered from `3·corner + axis` to `8·axis + corner` (still
/// symmetric when `k` is).
#[must_use]
pub(crate) fn component_major(k: &Mat24) -> Mat24 {
    let from = |i: usize| 3 * (i % 8) + i / 8;
    Mat24(std::array::from_fn(|ij| k.get(from(ij / 24), from(ij % 24))))
}

/// The element's corner values of `p`, component-major.
#[allow(clippy::inline_always)] // see `vectorized`
#[inline(always)]
pub(crate) fn gather(nodes: &[u32; 8], p: &[Vec3]) -> Local {
    let mut out = [0.0; 24];
    for (c, &n) in nodes.iter().enumerate() {
        let v = p[n as usize];
        out[c] = v[0];
        out[8 + c] = v[1];
        out[16 + c] = v[2];
    }
    out
}

/// `out[node] += g` per corner, in corner order.
#[allow(clippy::inline_always)]
#[inline(always)]
pub(crate) fn scatter_add(nodes: &[u32; 8], g: &Local, out: &mut [Vec3]) {
    for (c, &n) in nodes.iter().enumerate() {
        let o = &mut out[n as usize];
        o[0] += g[c];
        o[1] += g[8 + c];
        o[2] += g[16 + c];
    }
}

/// `Rᵀ g` per corner: global to element frame.
#[allow(clippy::inline_always)]
#[inline(always)]
pub(crate) fn to_local(wide: Wide, r: &Mat3, g: &Local) -> Local {
    let rt: Mat3 = std::array::from_fn(|i| std::array::from_fn(|k| r[k][i]));
    rotate(wide, &rt, g)
}

/// `scale · R l` per corner: element frame back to global.
#[allow(clippy::inline_always)]
#[inline(always)]
pub(crate) fn to_global(wide: Wide, r: &Mat3, scale: f64, l: &Local) -> Local {
    let s: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| scale * r[i][j]));
    rotate(wide, &s, l)
}

/// `m v` per corner, each row as `m₂ v₂ + (m₁ v₁ + m₀ v₀)` in fused multiply-adds: four corners
/// per instruction where AVX2 is present, the same operations lane by lane otherwise.
#[allow(clippy::inline_always)]
#[inline(always)]
fn rotate(wide: Wide, m: &Mat3, v: &Local) -> Local {
    #[cfg(target_arch = "x86_64")]
    if let Some(simd) = wide.0 {
        // Plain loops, not `array::from_fn`: a closure the compiler declines to inline runs
        // without the target features, and its intrinsics then become calls.
        let v: [pulp::f64x4; 6] = pulp::cast(*v);
        let mut out = [simd.splat_f64x4(0.0); 6];
        for (k, o) in out.iter_mut().enumerate() {
            let (i, half) = (k / 2, k % 2);
            let first = simd.mul_f64x4(simd.splat_f64x4(m[i][0]), v[half]);
            let second = simd.mul_add_f64x4(simd.splat_f64x4(m[i][1]), v[2 + half], first);
            *o = simd.mul_add_f64x4(simd.splat_f64x4(m[i][2]), v[4 + half], second);
        }
        return pulp::cast(out);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = wide;
    std::array::from_fn(|k| {
        let (i, c) = (k / 8, k % 8);
        m[i][2].mul_add(v[16 + c], m[i][1].mul_add(v[8 + c], m[i][0] * v[c]))
    })
}

/// Four `f64` lanes in one AVX register, for code generic over [`Lane`] (element rotations): every
/// operation is the scalar one lane by lane, so a lane has the scalar code's bits.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Avx4 {
    simd: pulp::x86::V3,
    v: pulp::f64x4,
}

#[cfg(target_arch = "x86_64")]
mod avx4 {
    // Inlined into the feature-enabled loops, or the intrinsics become calls.
    #![allow(clippy::inline_always)]

    use super::Avx4;
    use incise_math::lanes::{Lane, Lane4};
    use pulp::m64x4;
    use std::ops::{Add, Div, Mul, Neg, Sub};

    macro_rules! binary {
        ($trait:ident, $method:ident, $simd:ident) => {
            impl $trait for Avx4 {
                type Output = Self;
                #[inline(always)]
                fn $method(self, other: Self) -> Self {
                    Self { simd: self.simd, v: self.simd.$simd(self.v, other.v) }
                }
            }
        };
    }
    binary!(Add, add, add_f64x4);
    binary!(Sub, sub, sub_f64x4);
    binary!(Mul, mul, mul_f64x4);
    binary!(Div, div, div_f64x4);

    impl Neg for Avx4 {
        type Output = Self;
        #[inline(always)]
        fn neg(self) -> Self {
            let zero = self.simd.splat_f64x4(-0.0);
            Self { simd: self.simd, v: self.simd.sub_f64x4(zero, self.v) }
        }
    }

    /// A lane mask with its token.
    #[derive(Clone, Copy)]
    pub(crate) struct Mask {
        simd: pulp::x86::V3,
        m: m64x4,
    }

    impl std::ops::BitAnd for Mask {
        type Output = Self;
        #[inline(always)]
        fn bitand(self, other: Self) -> Self {
            Self { simd: self.simd, m: self.simd.and_m64x4(self.m, other.m) }
        }
    }

    impl std::ops::BitOr for Mask {
        type Output = Self;
        #[inline(always)]
        fn bitor(self, other: Self) -> Self {
            Self { simd: self.simd, m: self.simd.or_m64x4(self.m, other.m) }
        }
    }

    impl std::ops::Not for Mask {
        type Output = Self;
        #[inline(always)]
        fn not(self) -> Self {
            Self { simd: self.simd, m: self.simd.not_m64x4(self.m) }
        }
    }

    impl Lane for Avx4 {
        type Mask = Mask;

        #[inline(always)]
        fn constant(self, v: f64) -> Self {
            Self { simd: self.simd, v: self.simd.splat_f64x4(v) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            Self { simd: self.simd, v: self.simd.abs_f64x4(self.v) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Self { simd: self.simd, v: self.simd.sqrt_f64x4(self.v) }
        }
        #[inline(always)]
        fn lt(self, other: Self) -> Mask {
            Mask { simd: self.simd, m: self.simd.cmp_lt_f64x4(self.v, other.v) }
        }
        #[inline(always)]
        fn le(self, other: Self) -> Mask {
            Mask { simd: self.simd, m: self.simd.cmp_le_f64x4(self.v, other.v) }
        }
        #[inline(always)]
        fn gt(self, other: Self) -> Mask {
            Mask { simd: self.simd, m: self.simd.cmp_gt_f64x4(self.v, other.v) }
        }
        #[inline(always)]
        fn select(mask: Mask, if_true: Self, if_false: Self) -> Self {
            Self { simd: mask.simd, v: mask.simd.select_f64x4(mask.m, if_true.v, if_false.v) }
        }
    }

    impl Lane4 for Avx4 {
        #[inline(always)]
        fn from_lanes(like: Self, lanes: [f64; 4]) -> Self {
            Self { simd: like.simd, v: pulp::cast(lanes) }
        }
        #[inline(always)]
        fn lanes(self) -> [f64; 4] {
            pulp::cast(self.v)
        }
        #[inline(always)]
        fn mask_lanes(mask: Mask) -> [bool; 4] {
            let bits: [u64; 4] = pulp::cast(mask.m);
            bits.map(|b| b != 0)
        }
        #[inline(always)]
        fn mask_from_lanes(like: Self, lanes: [bool; 4]) -> Mask {
            let bits: [u64; 4] = lanes.map(|b| if b { u64::MAX } else { 0 });
            Mask { simd: like.simd, m: pulp::cast(bits) }
        }
    }
}

impl Wide {
    /// The four-lane type for lane-generic code, where AVX2 is present.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    pub(crate) fn lanes(self) -> Option<Avx4> {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = self.0 {
            return Some(Avx4 { simd, v: simd.splat_f64x4(0.0) });
        }
        None
    }
}

/// Whether the element passes may use AVX2 with FMA, and the token that lets them.
#[derive(Clone, Copy)]
pub(crate) struct Wide(#[cfg(target_arch = "x86_64")] pub(crate) Option<pulp::x86::V3>);

impl Wide {
    /// Lane-by-lane scalar code (the fallback; the same bits).
    #[cfg(test)]
    pub(crate) const SCALAR: Self = Self(
        #[cfg(target_arch = "x86_64")]
        None,
    );
}

/// `(k · v, k · w)` for a symmetric `k` ([`Mat24::mul_vec_symmetric_pair`]) in its own
/// vectorised function. Never inlined: inside a larger element loop the compiler keeps the 48
/// accumulators in scalar registers (spilling them) instead of vectorising the rows.
#[inline(never)]
pub(crate) fn product_pair(k: &Mat24, v: &Local, w: &Local) -> (Local, Local) {
    vectorized(
        #[inline(always)]
        |_| k.mul_vec_symmetric_pair(v, w),
    )
}

/// `k · v` for a symmetric `k`, like [`product_pair`].
#[inline(never)]
pub(crate) fn product(k: &Mat24, v: &Local) -> Local {
    vectorized(
        #[inline(always)]
        |_| k.mul_vec_symmetric(v),
    )
}

/// Runs `op` compiled for AVX2 with FMA where the CPU has them (else as it is), handing it the
/// [`Wide`] token. Everything `op` calls in its loop must be inlined into it (`#[inline(always)]`)
/// to get the wider instructions.
pub(crate) fn vectorized<R>(op: impl FnOnce(Wide) -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if let Some(simd) = pulp::x86::V3::try_new() {
        return simd.vectorize(
            #[inline(always)]
            move || op(Wide(Some(simd))),
        );
    }
    op(Wide(
        #[cfg(target_arch = "x86_64")]
        None,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layouts_agree() {
        let k = Mat24(std::array::from_fn(|ij| {
            let (a, b) = (ij / 24, ij % 24);
            (a.min(b) * 31 + a.max(b)) as f64
        }));
        let v: [f64; 24] = std::array::from_fn(|i| (i as f64 * 0.37).sin());
        let local: Local = std::array::from_fn(|i| v[3 * (i % 8) + i / 8]);
        let kv = k.mul_vec(&v);
        let kl = component_major(&k).mul_vec(&local);
        for (i, &l) in kl.iter().enumerate() {
            let expected = kv[3 * (i % 8) + i / 8];
            assert!((l - expected).abs() <= 1e-12 * expected.abs().max(1.0), "{i}");
        }
    }

    #[test]
    fn rotations_round_trip() {
        let r = incise_math::mat3::axis_angle(&[0.6, 0.0, 0.8], 0.9);
        let g: Local = std::array::from_fn(|i| (i as f64 * 1.3).cos());
        vectorized(|wide| {
            let back = to_global(wide, &r, 2.0, &to_local(wide, &r, &g));
            for i in 0..24 {
                assert!((back[i] - 2.0 * g[i]).abs() < 1e-14, "{i}");
            }
            // Corner c's global vector is (g[c], g[8 + c], g[16 + c]).
            let l = to_local(wide, &r, &g);
            let direct = incise_math::mat3::mul_transpose_vec(&r, &[g[3], g[11], g[19]]);
            assert!((0..3).all(|k| (l[8 * k + 3] - direct[k]).abs() < 1e-15));
        });
    }

    /// The wide path and the scalar fallback give the same bits (frames replay on any machine).
    #[test]
    fn the_fallback_has_the_same_bits() {
        let r = incise_math::mat3::axis_angle(&[0.36, 0.48, 0.8], 2.1);
        let g: Local = std::array::from_fn(|i| (i as f64 * 0.71).sin() * 1e-3 + 0.1);
        let scalar = to_global(Wide::SCALAR, &r, -0.7, &to_local(Wide::SCALAR, &r, &g));
        let wide = vectorized(|wide| to_global(wide, &r, -0.7, &to_local(wide, &r, &g)));
        assert_eq!(scalar.map(f64::to_bits), wide.map(f64::to_bits));
    }

    /// On AVX2 lanes, each element's rotation has the bits the scalar solver gives it (the
    /// lanes' grouping, which follows the thread count's split, cannot change a frame).
    #[test]
    fn rotations_on_avx_lanes_have_the_scalar_bits() {
        use incise_math::lanes::Lane4;
        use incise_math::mat3::{Mat3, axis_angle, mul};
        use incise_math::rotation::{Quat, nearest, nearest4};
        // Stretched rotations warm-started nearby or far away, and an inverted element.
        let a: [Mat3; 4] = std::array::from_fn(|l| {
            let stretch = 1.0 + 0.03 * l as f64;
            let r = axis_angle(&[0.6, 0.0, 0.8], 0.7 * l as f64);
            let mut m = mul(&r, &[[stretch, 0.01, 0.0], [0.01, 0.98, 0.02], [0.0, 0.02, 1.0]]);
            if l == 3 {
                m[2] = m[2].map(|c| -0.5 * c);
            }
            m
        });
        let warm: [Quat; 4] =
            std::array::from_fn(|l| Quat::from_axis_angle(&[0.0, 0.6, 0.8], 0.05 + 1.4 * l as f64));
        vectorized(|wide| {
            let Some(like) = wide.lanes() else { return };
            let lanes = std::array::from_fn(|i| {
                std::array::from_fn(|j| Lane4::from_lanes(like, a.map(|m| m[i][j])))
            });
            let mut q4 = warm;
            let four = nearest4(&lanes, &mut q4, 100);
            for l in 0..4 {
                let mut q = warm[l];
                let one = nearest(&a[l], &mut q, 100);
                assert_eq!(
                    four[l].matrix.map(|r| r.map(f64::to_bits)),
                    one.matrix.map(|r| r.map(f64::to_bits))
                );
                assert_eq!((four[l].iterations, q4[l]), (one.iterations, q), "lane {l}");
            }
        });
    }
}
