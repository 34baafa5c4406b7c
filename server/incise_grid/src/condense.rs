//! Jeřábková 2010, §2.2 eq. 1–6: condensation of fine voxels into a coarse element's stiffness and
//! mass, directly over full octree sub-blocks (eq. 2–4, 6) with the recursive 8 → 1 scheme (eq. 1)
//! kept as the reference it is tested against.
//!
//! A coarse element at level `L` owns some of the `8^L` voxels of its cell. Its matrices are
//! `Σ Hᵀ A₀ H` over those voxels, where `H` interpolates the coarse trilinear field to the voxel's
//! corners. Sorting the voxels by Morton index (eq. 6) turns every full, single-material octree
//! sub-block at level `k` into an index interval `[i·8^k, (i+1)·8^k)`, which contributes
//! `H_(L−k),iᵀ (2^k K₀) H_(L−k),i` (eq. 2, 4) and `H ᵀ(2^{3k} M₀) H` (eq. 3) in one step.
//!
//! Every such product depends only on (material, k, i), so [`CondensationTables`] computes them once
//! per grid: adding or removing voxels (eq. 5) then costs additions, never matrix products.
//!
//! Heterogeneous materials (the paper's future work): each voxel contributes its own material's
//! `K₀, M₀`; a sub-block is taken in one step only where all its voxels share one material, so the
//! result is exact for any interleaving and fast where materials have clear borders.

use crate::hex8::{Mat8, Mat24, Sym24, add_into, corner, hex_mass, hex_stiffness, shape};
use crate::material::Material;
use incise_math::{Vec3, morton_decode};

/// `N[c][n]`: the coarse cell's shape function `n` evaluated at corner `c` of the sub-cell at
/// integer position `pos` in a cell split into `2^d` sub-cells per axis, so `H = N ⊗ I₃`.
/// The values are dyadic rationals, exact in floating point.
#[must_use]
pub fn interpolation(pos: [u32; 3], d: u32) -> [[f64; 8]; 8] {
    let per_axis = f64::from(1u32 << d);
    std::array::from_fn(|c| {
        let b = corner(c);
        let xi: Vec3 = std::array::from_fn(|a| (f64::from(pos[a]) + b[a] as f64) / per_axis);
        std::array::from_fn(|n| shape(n, xi))
    })
}

/// `Hᵀ A H` for `H = N ⊗ I₃`: the stiffness a sub-cell with matrix `a` adds to its coarse cell.
#[must_use]
pub fn condense_stiffness(a: &Mat24, n: &[[f64; 8]; 8]) -> Mat24 {
    // T = A H, then Hᵀ T; exploiting the Kronecker structure costs 2·24·24·8 products, not 2·24³.
    let mut t = [0.0; 576];
    for r in 0..24 {
        for m in 0..8 {
            for j in 0..3 {
                let mut s = 0.0;
                for d in 0..8 {
                    s += a.0[r * 24 + 3 * d + j] * n[d][m];
                }
                t[r * 24 + 3 * m + j] = s;
            }
        }
    }
    let mut out = Mat24::zeros();
    for nn in 0..8 {
        for i in 0..3 {
            for col in 0..24 {
                let mut s = 0.0;
                for c in 0..8 {
                    s += n[c][nn] * t[(3 * c + i) * 24 + col];
                }
                out.0[(3 * nn + i) * 24 + col] = s;
            }
        }
    }
    out
}

/// `Nᵀ m N`: the scalar mass block a sub-cell with mass `m ⊗ I₃` adds to its coarse cell.
#[must_use]
pub fn condense_mass(m: &Mat8, n: &[[f64; 8]; 8]) -> Mat8 {
    let mut t = [0.0; 64];
    for c in 0..8 {
        for b in 0..8 {
            t[c * 8 + b] = (0..8).map(|d| m[c * 8 + d] * n[d][b]).sum();
        }
    }
    let mut out = [0.0; 64];
    for a in 0..8 {
        for b in 0..8 {
            out[a * 8 + b] = (0..8).map(|c| n[c][a] * t[c * 8 + b]).sum();
        }
    }
    out
}

/// Per-material `K₀` and `M₀` of one voxel of the given spacing.
#[derive(Clone, Debug)]
pub struct VoxelMatrices {
    /// `K₀` (24×24).
    pub stiffness: Mat24,
    /// `m₀` with `M₀ = m₀ ⊗ I₃`.
    pub mass: Mat8,
}

impl VoxelMatrices {
    /// The matrices of one voxel of edge lengths `spacing` made of `material`.
    #[must_use]
    pub fn new(spacing: Vec3, material: &Material) -> Self {
        Self {
            stiffness: hex_stiffness(spacing, material.youngs_modulus, material.poisson_ratio),
            mass: hex_mass(spacing, material.density),
        }
    }
}

/// One material's stiffness and mass tables, indexed `[k][i]`.
type MaterialTables = (Vec<Vec<Sym24>>, Vec<Vec<Mat8>>);

/// The cached products `H_(L−k),iᵀ A_(k) H_(L−k),i` for every material, block level
/// `k ∈ 0..=L` and sub-position `i ∈ 0..8^(L−k)` (Morton order), for elements at level `L`.
#[derive(Clone, Debug)]
pub struct CondensationTables {
    levels: u32,
    voxel: Vec<VoxelMatrices>,
    /// `stiffness[mat][k][i]`, upper triangles.
    stiffness: Vec<Vec<Vec<Sym24>>>,
    /// `mass[mat][k][i]`.
    mass: Vec<Vec<Vec<Mat8>>>,
}

impl CondensationTables {
    /// Builds the tables for elements at level `levels` over voxels of edge lengths `spacing`.
    ///
    /// # Panics
    /// If a table thread panics (it only does arithmetic, so only on a bug).
    #[must_use]
    pub fn new(spacing: Vec3, materials: &[Material], levels: u32) -> Self {
        let voxel: Vec<VoxelMatrices> =
            materials.iter().map(|m| VoxelMatrices::new(spacing, m)).collect();
        let per_material = |v: &VoxelMatrices| {
            let mut ks = Vec::with_capacity(levels as usize + 1);
            let mut ms = Vec::with_capacity(levels as usize + 1);
            for k in 0..=levels {
                // Eq. 2–3: a full block of 2^k voxels per axis is the voxel scaled by 2^k (K), 2^{3k} (M);
                // powers of two scale without rounding.
                let ks_k = f64::from(1u32 << k);
                let ms_k = ks_k * ks_k * ks_k;
                let mut a = v.stiffness.clone();
                for x in &mut a.0 {
                    *x *= ks_k;
                }
                let mut m = v.mass;
                for x in &mut m {
                    *x *= ms_k;
                }
                let d = levels - k;
                let count = 1usize << (3 * d);
                let mut kt = Vec::with_capacity(count);
                let mut mt = Vec::with_capacity(count);
                for i in 0..count {
                    let (x, y, z) = morton_decode(i as u64);
                    let n = interpolation([x, y, z], d);
                    kt.push(Sym24::from_upper(&condense_stiffness(&a, &n)));
                    mt.push(condense_mass(&m, &n));
                }
                ks.push(kt);
                ms.push(mt);
            }
            (ks, ms)
        };
        // The materials are independent, so build them on separate threads (results do not depend
        // on the thread count: each table is computed by exactly one thread, in one order).
        let built: Vec<MaterialTables> = if voxel.len() > 1 {
            std::thread::scope(|s| {
                let handles: Vec<_> =
                    voxel.iter().map(|v| s.spawn(move || per_material(v))).collect();
                handles.into_iter().map(|h| h.join().expect("table thread panicked")).collect()
            })
        } else {
            voxel.iter().map(per_material).collect()
        };
        let (stiffness, mass) = built.into_iter().unzip();
        Self { levels, voxel, stiffness, mass }
    }

    /// The element level these tables condense into.
    #[must_use]
    pub fn levels(&self) -> u32 {
        self.levels
    }

    /// `K₀`, `M₀` of material `mat`.
    #[must_use]
    pub fn voxel(&self, mat: usize) -> &VoxelMatrices {
        &self.voxel[mat]
    }

    /// Eq. 4 term of one voxel (block level 0) at local Morton index `morton`.
    #[must_use]
    pub fn voxel_terms(&self, mat: usize, morton: u64) -> (&Sym24, &Mat8) {
        (&self.stiffness[mat][0][morton as usize], &self.mass[mat][0][morton as usize])
    }

    /// Direct condensation (eq. 2–4, 6) of the voxels `(local Morton index, material)` of one
    /// element. Sorts `voxels` in place; returns `(K, m)` with `M = m ⊗ I₃`, and the number of
    /// condensation steps taken (one per full sub-block).
    pub fn condense(&self, voxels: &mut [(u64, u16)]) -> (Mat24, Mat8, usize) {
        let (k, m, steps) = self.condense_packed(voxels);
        (k.to_full(), m, steps)
    }

    /// [`CondensationTables::condense`] with the stiffness left as an upper triangle.
    pub fn condense_packed(&self, voxels: &mut [(u64, u16)]) -> (Sym24, Mat8, usize) {
        voxels.sort_unstable();
        let n = voxels.len();
        // run[i]: how many entries from i on have consecutive indices and one material.
        let mut run = vec![1u32; n];
        for i in (0..n.saturating_sub(1)).rev() {
            let (m, mat) = voxels[i];
            if voxels[i + 1] == (m + 1, mat) {
                run[i] = run[i + 1] + 1;
            }
        }
        let mut k_sum = Sym24::zeros();
        let mut m_sum = [0.0; 64];
        let mut steps = 0;
        let mut i = 0;
        while i < n {
            let (m, mat) = voxels[i];
            let mut k = self.levels;
            while k > 0 && !(m.trailing_zeros() >= 3 * k && u64::from(run[i]) >= 1 << (3 * k)) {
                k -= 1;
            }
            let pos = (m >> (3 * k)) as usize;
            k_sum.add_assign(&self.stiffness[mat as usize][k as usize][pos]);
            add_into(&mut m_sum, &self.mass[mat as usize][k as usize][pos]);
            steps += 1;
            i += 1 << (3 * k);
        }
        (k_sum, m_sum, steps)
    }
}

/// Row sums of `m`: the lumped mass of each corner (the same as interpolating the voxels' lumped
/// masses, since `H·1 = 1`).
#[must_use]
pub fn lumped(m: &Mat8) -> [f64; 8] {
    std::array::from_fn(|a| m[a * 8..a * 8 + 8].iter().sum())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hex8::hex_stiffness;

    #[test]
    fn interpolation_is_a_partition_of_unity() {
        for d in 0..4 {
            for p in 0..(1u32 << d) {
                let n = interpolation([p, 0, (1 << d) - 1 - p], d);
                for row in n {
                    assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-15);
                }
            }
        }
    }

    #[test]
    fn eight_children_condense_to_the_parent_exactly() {
        // Eq. 2: K_(1) of a full block equals the coarse hexahedron of twice the size.
        let h = [1e-3, 2e-3, 1.5e-3];
        let k0 = hex_stiffness(h, 5e3, 0.3);
        let mut sum = Mat24::zeros();
        for c in 0..8 {
            let b = corner(c);
            sum.add_assign(&condense_stiffness(
                &k0,
                &interpolation([b[0] as u32, b[1] as u32, b[2] as u32], 1),
            ));
        }
        let direct = hex_stiffness([2e-3, 4e-3, 3e-3], 5e3, 0.3);
        assert!(sum.frobenius_diff(&direct) <= 1e-13 * direct.frobenius());
    }

    #[test]
    fn paper_figure_6_step_count() {
        // The 2-D example of Fig. 6 lifted to 3-D: voxel intervals give one step per full sub-block.
        let tables = CondensationTables::new([1.0; 3], &[Material::new(1.0, 0.3, 1.0)], 2);
        let mut voxels: Vec<(u64, u16)> = (0..64).map(|m| (m, 0)).collect();
        assert_eq!(tables.condense(&mut voxels).2, 1, "a full cell is one step");
        let mut voxels: Vec<(u64, u16)> = (0..64).filter(|&m| m != 9).map(|m| (m, 0)).collect();
        // Block 1 (indices 8..16) loses voxel 9: 7 single voxels + 7 full level-1 blocks.
        assert_eq!(tables.condense(&mut voxels).2, 7 + 7);
        let mut mixed: Vec<(u64, u16)> = (0..64).map(|m| (m, u16::from(m >= 32))).collect();
        let two = CondensationTables::new(
            [1.0; 3],
            &[Material::new(1.0, 0.3, 1.0), Material::new(2.0, 0.3, 1.0)],
            2,
        );
        assert_eq!(
            two.condense(&mut mixed).2,
            8,
            "a material border splits the cell into 8 blocks"
        );
    }
}
