//! The element products, the innermost loops of every force evaluation and CG iteration,
//! compiled for the best instruction set the CPU offers (AVX2 with FMA where present, chosen at
//! run time by `pulp`).
//!
//! **Layout.** Inside an element pass an element's 24 degrees of freedom are kept component by
//! component (`8·axis + corner`), and each element stiffness is permuted to that layout once
//! ([`component_major`]). Rotating the eight corners by `Rᵀ` (into the element frame) or by `R`
//! (back) is then three rows of 8-wide multiply-adds per axis, instead of eight scalar 3×3
//! products: in the corner-major layout the rotations and the gathers cost more than the 24×24
//! product itself (26 % of scene B3's time against 18 %).
//!
//! **Determinism.** Every sum is written as explicit `mul_add`s in a fixed order, never
//! reordered: the AVX2 path's FMA instructions and the fallback's correctly rounded software `fma`
//! give the same bits, so frames replay bit for bit on any x86-64 machine. Neighbouring elements
//! that share a matrix are multiplied as a pair ([`Mat24::mul_vec_symmetric_pair`]), loading each
//! row once for both.

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
pub(crate) fn to_local(r: &Mat3, g: &Local) -> Local {
    let mut out = [0.0; 24];
    for i in 0..3 {
        for c in 0..8 {
            out[8 * i + c] = r[2][i].mul_add(g[16 + c], r[1][i].mul_add(g[8 + c], r[0][i] * g[c]));
        }
    }
    out
}

/// `scale · R l` per corner: element frame back to global.
#[allow(clippy::inline_always)]
#[inline(always)]
pub(crate) fn to_global(r: &Mat3, scale: f64, l: &Local) -> Local {
    let s: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| scale * r[i][j]));
    let mut out = [0.0; 24];
    for i in 0..3 {
        for c in 0..8 {
            out[8 * i + c] = s[i][2].mul_add(l[16 + c], s[i][1].mul_add(l[8 + c], s[i][0] * l[c]));
        }
    }
    out
}

/// `(k · v, k · w)` for a symmetric `k` ([`Mat24::mul_vec_symmetric_pair`]) in its own
/// vectorised function. Never inlined: inside a larger element loop the compiler keeps the 48
/// accumulators in scalar registers (spilling them) instead of vectorising the rows.
#[inline(never)]
pub(crate) fn product_pair(k: &Mat24, v: &Local, w: &Local) -> (Local, Local) {
    vectorized(
        #[inline(always)]
        || k.mul_vec_symmetric_pair(v, w),
    )
}

/// `k · v` for a symmetric `k`, like [`product_pair`].
#[inline(never)]
pub(crate) fn product(k: &Mat24, v: &Local) -> Local {
    vectorized(
        #[inline(always)]
        || k.mul_vec_symmetric(v),
    )
}

/// Runs `op` compiled for the best instruction set available. Everything `op` calls in its loop
/// must be inlined into it (`#[inline(always)]`) to get the wider instructions.
pub(crate) fn vectorized<R>(op: impl FnOnce() -> R) -> R {
    pulp::Arch::new().dispatch(Op(op))
}

/// A closure as a `pulp` operation. `pulp`'s own impl for closures goes through a `FnOnce` shim
/// the compiler does not inline, and the closure then runs without the wider instructions; here
/// the call is direct and inlined into the feature-enabled entry point.
struct Op<F>(F);

impl<R, F: FnOnce() -> R> pulp::WithSimd for Op<F> {
    type Output = R;

    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> R {
        (self.0)()
    }
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
        let back = to_global(&r, 2.0, &to_local(&r, &g));
        for i in 0..24 {
            assert!((back[i] - 2.0 * g[i]).abs() < 1e-14, "{i}");
        }
        // Corner c's global vector is (g[c], g[8 + c], g[16 + c]).
        let l = to_local(&r, &g);
        let direct = incise_math::mat3::mul_transpose_vec(&r, &[g[3], g[11], g[19]]);
        assert!((0..3).all(|k| (l[8 * k + 3] - direct[k]).abs() < 1e-15));
    }
}
