//! The stiffness of a full cell in the Walsh–Hadamard basis of its corners: a sparse product for
//! the element passes.
//!
//! **Why it is sparse.** A full cell of one isotropic material is symmetric under the three
//! reflections of the box, and the 8-point Walsh–Hadamard transform `Ĥ` (`Ĥ_wc = (−1)^popcount(w&c)`)
//! of a component's corner values diagonalises those reflections. In that basis the stiffness
//! `D = Ĥ K Ĥ` (`Ĥ` per component, component-major as in [`crate::forcefield::hex::kernel`]) couples mode `w` of
//! component `i` only with mode `w ⊕ bᵢ ⊕ bⱼ` of component `j` (`b = 1, 2, 4`, the bit of the axis
//! the component points along): 45 of its 576 entries are nonzero on B3's cells, instead of a
//! dense 24×24. So `K v = Ĥ (D/64) Ĥ v` is two transforms per component and three 8-wide
//! multiply-adds per component, against the 576 fused multiply-adds of the dense product, which
//! took about a sixth of the implicit step on scene B3.
//!
//! **Bits.** Every operation is an addition, a subtraction, a product or a fused multiply-add in a
//! fixed order, identical lane by lane on AVX2 and in the scalar fallback
//! (`the_fallback_has_the_same_bits`), so frames replay bit for bit on any machine. The result
//! differs from the dense product only by rounding (`agrees_with_the_dense_product`): the entries
//! of `D` outside the pattern are rounding noise of the matrix itself (checked to be below 1e-12 of
//! its largest entry, or the cell keeps the dense product).

use crate::forcefield::hex::kernel::{Local, Wide};
use incise_grid::hex8::Mat24;

/// The bit of the Walsh index that each pair of components `(i, j)` flips: `bᵢ ⊕ bⱼ`.
const FLIP: [[usize; 3]; 3] = [[0, 3, 5], [3, 0, 6], [5, 6, 0]];

/// Entries of `Ĥ K Ĥ` outside the pattern at most this fraction of its largest entry: rounding
/// noise (about 1e-16 relative on condensed full cells); anything larger keeps the dense product.
const PATTERN_TOLERANCE: f64 = 1e-12;

/// A stiffness in the Walsh–Hadamard basis: `d[i][j][w] = (Ĥ K Ĥ)[(i, w), (j, w ⊕ bᵢ ⊕ bⱼ)] / 64`.
#[derive(Clone, Debug)]
pub(crate) struct Walsh {
    d: [[[f64; 8]; 3]; 3],
}

impl Walsh {
    /// The sparse form of `k` (component-major, symmetric) when it has the pattern of a full cell
    /// of one isotropic material; `None` otherwise (partially filled cells, superimposed ones).
    pub(crate) fn of(k: &Mat24) -> Option<Self> {
        if off_pattern_in_first_block(k) {
            return None;
        }
        Self::transformed(k)
    }

    /// [`Walsh::of`] from the whole transform.
    fn transformed(k: &Mat24) -> Option<Self> {
        // D = Ĥ K Ĥ (Ĥ symmetric, per component block) by fast transforms of the rows' and then
        // the columns' 8-entry segments: a few thousand operations, since this runs for every
        // distinct matrix whenever a cut rebuilds the force field.
        let mut d_full = [[0.0; 24]; 24];
        for (r, row) in d_full.iter_mut().enumerate() {
            row.copy_from_slice(&k.0[24 * r..24 * r + 24]);
            for segment in row.chunks_exact_mut(8) {
                let segment: &mut [f64; 8] = segment.try_into().expect("8 entries");
                transform(segment);
            }
        }
        for col in 0..24 {
            for block in 0..3 {
                let mut segment: [f64; 8] = std::array::from_fn(|a| d_full[8 * block + a][col]);
                transform(&mut segment);
                for (a, x) in segment.into_iter().enumerate() {
                    d_full[8 * block + a][col] = x;
                }
            }
        }
        let largest = d_full.iter().flatten().fold(0.0_f64, |m, x| m.max(x.abs()));
        if largest == 0.0 || !largest.is_finite() {
            return None;
        }
        let mut d = [[[0.0; 8]; 3]; 3];
        for (r, row) in d_full.iter().enumerate() {
            let (i, w) = (r / 8, r % 8);
            for (col, &x) in row.iter().enumerate() {
                let (j, v) = (col / 8, col % 8);
                if v == w ^ FLIP[i][j] {
                    // Symmetrised, so the sparse operator is symmetric to rounding.
                    d[i][j][w] = 0.5 * (x + d_full[col][r]) / 64.0;
                } else if x.abs() > PATTERN_TOLERANCE * largest {
                    return None;
                }
            }
        }
        Some(Self { d })
    }

    /// `K v` (component-major), through the transforms.
    #[allow(clippy::inline_always)] // inlined into the vectorised element passes
    #[inline(always)]
    pub(crate) fn apply(&self, wide: Wide, v: &Local) -> Local {
        #[cfg(target_arch = "x86_64")]
        if let Some(simd) = wide.0 {
            return avx::apply(simd, &self.d, v);
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = wide;
        let mut a = [[0.0; 8]; 3];
        for (i, ai) in a.iter_mut().enumerate() {
            ai.copy_from_slice(&v[8 * i..8 * i + 8]);
            transform(ai);
        }
        let mut out = [0.0; 24];
        for i in 0..3 {
            let mut o = [0.0; 8];
            for (w, ow) in o.iter_mut().enumerate() {
                let d = &self.d[i];
                let mut sum = d[0][w] * a[0][w ^ FLIP[i][0]];
                sum = d[1][w].mul_add(a[1][w ^ FLIP[i][1]], sum);
                *ow = d[2][w].mul_add(a[2][w ^ FLIP[i][2]], sum);
            }
            transform(&mut o);
            out[8 * i..8 * i + 8].copy_from_slice(&o);
        }
        out
    }
}

/// The unnormalised 8-point Walsh–Hadamard transform in place: butterflies `(x + y, x − y)` over
/// index bit 2, then bit 1, then bit 0 (the order the AVX2 path follows).
#[allow(clippy::inline_always)]
#[inline(always)]
/// True when the first component block of `Ĥ K Ĥ` already has an entry outside the pattern
/// past the tolerance, whatever the rest holds. A partly filled cell breaks the pattern across
/// the matrix, so this block shows it at a ninth of the whole transform's cost (a cut's
/// re-condensed cells paid for the whole). Every entry of `Ĥ K Ĥ` sums 64 entries of `K`, so
/// twice 64 times the largest of those bounds its largest entry, rounding included: an entry past
/// the tolerance of that bound is past the tolerance of the largest entry too.
fn off_pattern_in_first_block(k: &Mat24) -> bool {
    let bound = 128.0 * k.0.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let mut block = [[0.0; 8]; 8];
    for (w, row) in block.iter_mut().enumerate() {
        row.copy_from_slice(&k.0[24 * w..24 * w + 8]);
        transform(row);
    }
    (0..8).any(|v| {
        let mut column: [f64; 8] = std::array::from_fn(|w| block[w][v]);
        transform(&mut column);
        // In the block of components (0, 0) the pattern is the diagonal.
        column.iter().enumerate().any(|(w, x)| w != v && x.abs() > PATTERN_TOLERANCE * bound)
    })
}

fn transform(x: &mut [f64; 8]) {
    for stride in [4, 2, 1] {
        for k in 0..8 {
            if k & stride == 0 {
                let (a, b) = (x[k], x[k + stride]);
                x[k] = a + b;
                x[k + stride] = a - b;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx {
    //! The same operations on AVX2 registers: a component's eight corners in two registers,
    //! corners 0–3 and 4–7. Written with plain loops and inlined: a closure or call left out of
    //! line runs without the target features.
    #![allow(clippy::inline_always)]

    use super::{FLIP, Local};
    use pulp::f64x4;
    use pulp::x86::V3;

    /// Butterflies over bit 2 (across the registers), then bit 1 and bit 0 (within each, as
    /// `x·(±1) + swapped`: the product is exact, so the fused operation rounds as the scalar
    /// addition or subtraction does).
    #[inline(always)]
    fn transform(simd: V3, [lo, hi]: [f64x4; 2]) -> [f64x4; 2] {
        let (lo, hi) = (simd.add_f64x4(lo, hi), simd.sub_f64x4(lo, hi));
        let bit1 = pulp::cast(f64x4(1.0, 1.0, -1.0, -1.0));
        let bit0 = pulp::cast(f64x4(1.0, -1.0, 1.0, -1.0));
        let mut out = [lo, hi];
        for x in &mut out {
            let v = pulp::cast(*x);
            let swapped = simd.avx._mm256_permute2f128_pd::<0x01>(v, v);
            let v = simd.fma._mm256_fmadd_pd(v, bit1, swapped);
            let swapped = simd.avx._mm256_permute_pd::<0b0101>(v);
            *x = pulp::cast(simd.fma._mm256_fmadd_pd(v, bit0, swapped));
        }
        out
    }

    /// `x[w ⊕ flip]` for the flips of [`FLIP`].
    #[inline(always)]
    fn flipped(simd: V3, [lo, hi]: [f64x4; 2], flip: usize) -> [f64x4; 2] {
        let (l, h) = (pulp::cast(lo), pulp::cast(hi));
        let (l, h) = match flip {
            0 => (l, h),
            3 => (
                simd.avx2._mm256_permute4x64_pd::<0x1B>(l),
                simd.avx2._mm256_permute4x64_pd::<0x1B>(h),
            ),
            5 => (simd.avx._mm256_permute_pd::<0b0101>(h), simd.avx._mm256_permute_pd::<0b0101>(l)),
            _ => (
                simd.avx._mm256_permute2f128_pd::<0x01>(h, h),
                simd.avx._mm256_permute2f128_pd::<0x01>(l, l),
            ),
        };
        [pulp::cast(l), pulp::cast(h)]
    }

    #[inline(always)]
    pub(super) fn apply(simd: V3, d: &[[[f64; 8]; 3]; 3], v: &Local) -> Local {
        let v: [[f64x4; 2]; 3] = pulp::cast(*v);
        let mut a = v;
        for x in &mut a {
            *x = transform(simd, *x);
        }
        let mut out = a;
        for (i, o) in out.iter_mut().enumerate() {
            let di: [[f64x4; 2]; 3] = pulp::cast(d[i]);
            let mut sum = [simd.splat_f64x4(0.0); 2];
            for j in 0..3 {
                let x = flipped(simd, a[j], FLIP[i][j]);
                for h in 0..2 {
                    sum[h] = if j == 0 {
                        simd.mul_f64x4(di[j][h], x[h])
                    } else {
                        simd.mul_add_f64x4(di[j][h], x[h], sum[h])
                    };
                }
            }
            *o = transform(simd, sum);
        }
        pulp::cast(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forcefield::hex::kernel::{component_major, vectorized};
    use incise_grid::hex8::hex_stiffness;

    fn input(seed: f64) -> Local {
        std::array::from_fn(|i| (i as f64 * 0.77 + seed).sin() * 1e-3)
    }

    /// On full cells of several shapes and materials the transform path gives the dense product
    /// to rounding: 1e-13 of the result's largest entry (each sums 24 terms of either sign).
    #[test]
    fn agrees_with_the_dense_product() {
        for (size, e, nu) in [
            ([0.01, 0.01, 0.01], 3e3, 0.45),
            ([0.0068, 0.0067, 0.0067], 3e3, 0.3),
            ([0.02, 0.005, 0.011], 1e6, 0.49),
        ] {
            let k = component_major(&hex_stiffness(size, e, nu).symmetrized());
            let walsh = Walsh::of(&k).expect("a full cell has the pattern");
            for seed in [0.0, 1.3, 2.9] {
                let v = input(seed);
                let dense = k.mul_vec(&v);
                let scale = dense.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
                for wide in [Wide::SCALAR, vectorized(|w| w)] {
                    let fast = walsh.apply(wide, &v);
                    for (a, b) in fast.iter().zip(&dense) {
                        assert!((a - b).abs() <= 1e-13 * scale, "{a} vs {b}");
                    }
                }
            }
        }
    }

    /// The AVX2 path and the scalar fallback give the same bits.
    #[test]
    fn the_fallback_has_the_same_bits() {
        let k = component_major(&hex_stiffness([0.012, 0.009, 0.007], 5e3, 0.4).symmetrized());
        let walsh = Walsh::of(&k).expect("pattern");
        let v = input(0.4);
        let scalar = walsh.apply(Wide::SCALAR, &v);
        let wide = vectorized(|wide| walsh.apply(wide, &v));
        assert_eq!(scalar.map(f64::to_bits), wide.map(f64::to_bits));
    }

    /// A cell with one voxel missing has lost the reflection symmetries: it keeps the dense
    /// product.
    #[test]
    fn the_first_block_decides_as_the_whole_transform() {
        use incise_grid::procedural::{TISSUE, TUMOUR, ellipsoid_with_inclusion, from_fn};
        use incise_grid::{BranchedGrid, Material, MaterialTable};
        let mut table = MaterialTable::new();
        table.insert(TISSUE, Material::new(3e3, 0.45, 1000.0));
        table.insert(TUMOUR, Material::new(3e4, 0.45, 1000.0));
        // Full, partly filled and superimposed cells; and cells missing their corner voxels, or
        // a mirror-symmetric slab, which keep the reflections (and so the sparse form).
        let corners = |x: f64, y: f64, z: f64| {
            let at_corner = [x, y, z].iter().all(|&c| matches!(c as u32 % 4, 0 | 3));
            if at_corner { 0 } else { TISSUE }
        };
        let slab = |_: f64, _: f64, z: f64| if matches!(z as u32 % 4, 0 | 3) { 0 } else { TISSUE };
        let volumes = [
            ellipsoid_with_inclusion(20, 2e-3),
            from_fn([8, 8, 8], [2e-3; 3], corners),
            from_fn([8, 8, 8], [2e-3; 3], slab),
        ];
        let (mut sparse, mut dense) = (0, 0);
        for v in &volumes {
            for level in 1..=2 {
                let grid = BranchedGrid::build(v, &table, level).expect("grid");
                for (id, _) in grid.top().elements() {
                    let k = &grid.matrices(id).expect("matrices").stiffness;
                    let k = component_major(&k.symmetrized());
                    let (of, whole) = (Walsh::of(&k), Walsh::transformed(&k));
                    let bits = |w: &Walsh| {
                        w.d.as_flattened()
                            .as_flattened()
                            .iter()
                            .map(|x| x.to_bits())
                            .collect::<Vec<_>>()
                    };
                    assert_eq!(of.as_ref().map(bits), whole.as_ref().map(bits), "element {id}");
                    if of.is_some() { sparse += 1 } else { dense += 1 }
                }
            }
        }
        assert!(sparse > 0 && dense > 0, "{sparse} sparse, {dense} dense");
    }

    #[test]
    fn a_partly_filled_cell_has_no_sparse_form() {
        use incise_grid::{BranchedGrid, Material, MaterialTable, procedural::from_fn};
        let v = from_fn([2, 2, 2], [0.005; 3], |x, y, z| u16::from(x + y + z > 0.0));
        let table = MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0));
        let grid = BranchedGrid::build(&v, &table, 1).expect("grid");
        let (id, _) = grid.top().elements().next().expect("one element");
        let k = &grid.matrices(id).expect("matrices").stiffness;
        assert!(Walsh::of(&component_major(&k.symmetrized())).is_none());
        // The full cell of the same grid has it.
        let v = from_fn([2, 2, 2], [0.005; 3], |_, _, _| 1);
        let grid = BranchedGrid::build(&v, &table, 1).expect("grid");
        let (id, _) = grid.top().elements().next().expect("one element");
        let k = &grid.matrices(id).expect("matrices").stiffness;
        assert!(Walsh::of(&component_major(&k.symmetrized())).is_some());
    }
}
