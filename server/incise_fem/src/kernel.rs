//! The element stiffness product, the innermost loop of every force evaluation and CG iteration,
//! compiled for the best instruction set the CPU offers (AVX2 where present, chosen at run time by
//! `pulp`): 4-wide fused multiply-adds instead of SSE2's 2-wide multiplies and adds. The sums are
//! written as explicit `mul_add`s in a fixed order, never reordered: the AVX2 path's FMA
//! instructions and the fallback's correctly rounded software `fma` give the same bits, so frames
//! replay bit for bit on any x86-64 machine. Neighbouring elements that share a matrix are
//! multiplied as a pair ([`symmetric_product_pair`]), loading each row once for both.

use incise_grid::hex8::Mat24;

/// `k · v` for a symmetric element stiffness `k` (see [`Mat24::mul_vec_symmetric`]).
#[inline]
pub(crate) fn symmetric_product(k: &Mat24, v: &[f64; 24]) -> [f64; 24] {
    pulp::Arch::new().dispatch(Product { k, v })
}

/// The product as a `pulp` operation. A struct rather than a closure: a closure handed to
/// `dispatch` goes through a `FnOnce` shim the compiler does not inline, and then runs without
/// the wider instructions.
struct Product<'a> {
    k: &'a Mat24,
    v: &'a [f64; 24],
}

impl pulp::WithSimd for Product<'_> {
    type Output = [f64; 24];

    // Inlined into pulp's feature-enabled entry point, or it would not get the wide instructions.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> [f64; 24] {
        self.k.mul_vec_symmetric(self.v)
    }
}

/// `(k · v, k · w)`, bit-identical to two [`symmetric_product`] calls, about twice as fast.
#[inline]
pub(crate) fn symmetric_product_pair(
    k: &Mat24,
    v: &[f64; 24],
    w: &[f64; 24],
) -> ([f64; 24], [f64; 24]) {
    pulp::Arch::new().dispatch(PairProduct { k, v, w })
}

/// [`symmetric_product_pair`] as a `pulp` operation (see [`Product`]).
struct PairProduct<'a> {
    k: &'a Mat24,
    v: &'a [f64; 24],
    w: &'a [f64; 24],
}

impl pulp::WithSimd for PairProduct<'_> {
    type Output = ([f64; 24], [f64; 24]);

    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> ([f64; 24], [f64; 24]) {
        self.k.mul_vec_symmetric_pair(self.v, self.w)
    }
}
