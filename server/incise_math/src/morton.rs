//! Jeřábková 2010, §2.2 eq. 6: the octree (Morton, Z-order) index of a voxel inside a coarse cell.
//!
//! `Idx = Σ_l (4·z_l + 2·y_l + x_l)·8^l`, where `x_l` is bit `l` of `x`. A full octree sub-node at
//! level `l` is then exactly the index interval `[i·8^l, (i+1)·8^l)`, which is what lets direct
//! condensation find full sub-blocks by scanning sorted indices instead of building an octree.

/// Spreads the low 21 bits of `v` so that bit `l` lands at bit `3l`.
#[inline]
fn spread(v: u32) -> u64 {
    let mut x = u64::from(v) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Inverse of [`spread`]: gathers every third bit back into the low 21 bits.
#[inline]
fn compact(v: u64) -> u32 {
    let mut x = v & 0x1249_2492_4924_9249;
    x = (x | (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x | (x >> 16)) & 0x001f_0000_0000_ffff;
    x = (x | (x >> 32)) & 0x1f_ffff;
    x as u32
}

/// Morton index of `(x, y, z)` (each below 2²¹), eq. 6 of Jeřábková 2010.
#[inline]
#[must_use]
pub fn morton_encode(x: u32, y: u32, z: u32) -> u64 {
    spread(x) | (spread(y) << 1) | (spread(z) << 2)
}

/// The `(x, y, z)` whose Morton index is `m`.
#[inline]
#[must_use]
pub fn morton_decode(m: u64) -> (u32, u32, u32) {
    (compact(m), compact(m >> 1), compact(m >> 2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Eq. 6 written out bit by bit, the definition the fast version must match.
    fn eq6(x: u32, y: u32, z: u32) -> u64 {
        (0..21)
            .map(|l| u64::from(4 * ((z >> l) & 1) + 2 * ((y >> l) & 1) + ((x >> l) & 1)) << (3 * l))
            .sum()
    }

    #[test]
    fn paper_figure_6_example() {
        // Fig. 6 is 2-D (a quadtree): node 39 sits at x = 3, y = 5, i.e. Σ (2·y_l + x_l)·4^l.
        // In 3-D with z = 0 the same bits give (2·y_l + x_l)·8^l.
        // Bit pairs (y_l x_l) = 11, 01, 10 → 3 + 1·4 + 2·16 = 39 in the quadtree, 3 + 1·8 + 2·64 here.
        let quadtree: u64 = (0..3u32)
            .map(|l| u64::from(2 * ((5u32 >> l) & 1) + ((3u32 >> l) & 1)) << (2 * l))
            .sum();
        assert_eq!(quadtree, 39);
        assert_eq!(morton_encode(3, 5, 0), 3 + 8 + 2 * 64);
        assert_eq!(morton_encode(1, 0, 0), 1);
        assert_eq!(morton_encode(0, 1, 0), 2);
        assert_eq!(morton_encode(0, 0, 1), 4);
        assert_eq!(morton_encode(1, 1, 1), 7);
        assert_eq!(morton_encode(2, 0, 0), 8);
    }

    proptest! {
        #[test]
        fn matches_equation_6(x in 0u32..(1 << 21), y in 0u32..(1 << 21), z in 0u32..(1 << 21)) {
            prop_assert_eq!(morton_encode(x, y, z), eq6(x, y, z));
        }

        #[test]
        fn decode_inverts_encode(x in 0u32..(1 << 21), y in 0u32..(1 << 21), z in 0u32..(1 << 21)) {
            prop_assert_eq!(morton_decode(morton_encode(x, y, z)), (x, y, z));
        }

        #[test]
        fn full_subnode_is_an_interval(x in 0u32..64, y in 0u32..64, z in 0u32..64, l in 0u32..6) {
            // Every voxel of the aligned 2^l block containing (x,y,z) has an index in
            // [base, base + 8^l), and the interval holds exactly those voxels.
            let base = morton_encode(x >> l << l, y >> l << l, z >> l << l);
            let m = morton_encode(x, y, z);
            prop_assert_eq!(m >> (3 * l) << (3 * l), base);
        }
    }
}
