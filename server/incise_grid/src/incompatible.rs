//! Coarse elements with incompatible modes (Wilson, Taylor, Doherty, Ghaboussi 1973; Taylor,
//! Beresford, Wilson 1976): the condensed element of eq. 1–4 enriched with nine internal bubble
//! displacements, condensed out again per element.
//!
//! A trilinear element cannot bend without shearing, and a coarse element spans what the voxels
//! let bend: a neck, a lobe's edge. Its condensed stiffness then holds the bent material back
//! (shear locking), and with ν = 0.45 its volume constraints at every voxel's Gauss points hold
//! it back further. Each coarse element here also gets the modes `α_ik · 4 s_k (1 − s_k)`
//! (displacement component `i`, bubble along local axis `k`, zero on the cell's faces), whose
//! strains `G` complete the bending field. They are internal to the element, so they leave the
//! grid's nodes and the rest of the pipeline unchanged:
//! `K = K_uu − K_αuᵀ K_αα⁻¹ K_αu`, `K_αα = ∫ G̃ᵀ D G̃`, `K_αu = ∫ G̃ᵀ D B` over the voxels the
//! element owns, `K_uu` the condensed stiffness. `G̃ = G − Ḡ` subtracts the mean over those
//! voxels (Taylor's correction, here for a cell the material fills only partly): a homogeneous
//! element then still reproduces every constant strain exactly (the patch test).
//!
//! The integrands are products of one polynomial of degree at most two per local axis, so they
//! are integrated exactly from the 27 moments `∫ s_x^a s_y^b s_z^c` of each material's owned
//! voxels (`a, b, c ≤ 2`), which a voxel adds to in closed form. They are summed as integers
//! (exact, so in-place and rebuilt grids agree to the bit), three additions per voxel and 27 per
//! row of voxels, then a few thousand operations make the matrices; a unit test checks the
//! result against 2 × 2 × 2 Gauss points in every voxel (also exact for these integrands).

use crate::grid::BranchedGrid;
use crate::hex8::{Mat24, corner};

/// A pivot below this fraction of its diagonal entry marks a bubble the owned voxels do not
/// strain (cannot happen for a cell's own voxels, kept for safety against rounding).
const NULL_PIVOT: f64 = 1e-12;

/// Isotropic elasticity in Voigt form, strains `[εxx, εyy, εzz, γxy, γyz, γxz]`.
fn elasticity(youngs: f64, poisson: f64) -> [[f64; 6]; 6] {
    let lambda = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    let mu = youngs / (2.0 * (1.0 + poisson));
    let mut d = [[0.0; 6]; 6];
    for (i, row) in d.iter_mut().enumerate().take(3) {
        for (j, v) in row.iter_mut().enumerate().take(3) {
            *v = lambda + if i == j { 2.0 * mu } else { 0.0 };
        }
    }
    for (i, row) in d.iter_mut().enumerate().skip(3) {
        row[i] = mu;
    }
    d
}

/// The Voigt row of the engineering shear between axes `a` and `b` (`a ≠ b`).
fn shear_row(a: usize, b: usize) -> usize {
    match (a.min(b), a.max(b)) {
        (0, 1) => 3,
        (1, 2) => 4,
        _ => 5,
    }
}

/// The stiffness of every top-level element of `grid` (indexed by element id) with its nine
/// incompatible modes condensed out ([`element_stiffness`] of each).
///
/// # Panics
/// Only on a broken grid invariant (a live element without voxels or matrices).
#[must_use]
pub fn incompatible_stiffness(grid: &BranchedGrid) -> Vec<Option<Mat24>> {
    let top = grid.top();
    let mut out = vec![None; top.element_capacity()];
    let mut voxels = Vec::new();
    for (id, _) in top.elements() {
        out[id as usize] = element_stiffness(grid, id, &mut voxels);
    }
    out
}

/// The stiffness of top-level element `id` with its nine incompatible modes condensed out
/// (`None` for an element that does not exist). At level 0 the elements are voxels, whose own
/// field is the finest there is: the condensed stiffness is returned. Each element depends only
/// on the voxels it owns, so after a cut only the elements the cut touched need it again.
/// `voxels` is a buffer kept by a caller that asks for many elements.
///
/// The integrals are taken through the moments of the owned voxels (see the module docs): every
/// integrand is a product of one polynomial of degree at most two per local axis, so the 27
/// moments of each material's voxels give `K_αα` and `K_αu` exactly, at a cost of 27 products
/// per voxel instead of a quadrature's thousands.
///
/// # Panics
/// Only on a broken grid invariant (a live element without voxels or matrices).
pub fn element_stiffness(
    grid: &BranchedGrid,
    id: u32,
    voxels: &mut Vec<(u32, [u32; 3])>,
) -> Option<Mat24> {
    grid.top().element(id)?;
    let k_uu = &grid.matrices(id).expect("live element has matrices").stiffness;
    if grid.top_level() == 0 {
        return Some(k_uu.clone());
    }
    voxels.clear();
    grid.element_voxel_offsets_into(id, voxels);
    let moments = material_moments(grid, voxels);
    let elasticities: Vec<[[f64; 6]; 6]> =
        grid.materials().map(|(_, m)| elasticity(m.youngs_modulus, m.poisson_ratio)).collect();
    let (k_aa, k_au) = bubble_matrices(&moments, &elasticities, grid.element_size());
    Some(crate::schur::complement(k_uu, k_aa, k_au, NULL_PIVOT))
}

/// The integrals of the monomials `s_x^a s_y^b s_z^c` (`a, b, c ∈ {0, 1, 2}`, index
/// `a + 3b + 9c`) over a set of voxels, in the cell's local coordinates `s ∈ [0, 1]³`.
type Moments = [f64; 27];

/// A polynomial in one local coordinate, `c₀ + c₁ s + c₂ s²`.
type Poly = [f64; 3];

/// A product of one [`Poly`] per local axis.
type Separable = [Poly; 3];

/// The moments of the `voxels` (owned by one element, with their offsets in its cell) per
/// material, as
/// `(material index, moments)` in ascending material order.
///
/// A voxel at offset `(i, j, k)` in a cell of `p` voxels per axis adds
/// `X_a(i) Y_b(j) Z_c(k) / ((a+1)(b+1)(c+1) p^(a+b+c+3))` to moment `(a, b, c)`, with the integers
/// `X_a(i) = (i+1)^(a+1) − i^(a+1)`. The integer numerators are summed exactly (a full cell's sum
/// is `p^(a+b+c+3)`, at most 2^45 at level 5), so the moments are each rounded once, whatever order the voxels
/// come in: a cut in place and a rebuild give the same bits. The sum runs in two passes: each
/// voxel adds its three `X_a(i)` to its row `(j, k)`, then each row is weighted by `Y_b Z_c`.
fn material_moments(grid: &BranchedGrid, voxels: &[(u32, [u32; 3])]) -> Vec<(usize, Moments)> {
    let per = 1u32 << grid.top_level();
    let p = per as usize;
    let numerators: Vec<[i64; 3]> = (0..p)
        .map(|i| {
            let (lo, hi) = (i as i64, i as i64 + 1);
            [hi - lo, hi * hi - lo * lo, hi * hi * hi - lo * lo * lo]
        })
        .collect();
    // Per material: the row sums `Σ X_a(i)` over the voxels of row `(j, k)`, at `j + p k`.
    let mut rows: Vec<(usize, Vec<[i64; 3]>)> = Vec::new();
    for &(v, o) in voxels {
        let m = usize::from(grid.fine().material(v).expect("owned voxel holds material"));
        let at = if let Some(at) = rows.iter().position(|(mm, _)| *mm == m) {
            at
        } else {
            rows.push((m, vec![[0; 3]; p * p]));
            rows.len() - 1
        };
        let row = &mut rows[at].1[o[1] as usize + p * o[2] as usize];
        for (r, n) in row.iter_mut().zip(&numerators[o[0] as usize]) {
            *r += n;
        }
    }
    let scale: [f64; 27] = std::array::from_fn(|idx| {
        let (a, b, c) = (idx % 3, (idx / 3) % 3, idx / 9);
        let power = f64::from(per).powi((a + b + c + 3) as i32);
        ((a + 1) * (b + 1) * (c + 1)) as f64 * power
    });
    let mut moments: Vec<(usize, Moments)> = rows
        .into_iter()
        .map(|(m, rows)| {
            let mut sum = [0i64; 27];
            for (at, row) in rows.iter().enumerate() {
                if *row == [0; 3] {
                    continue;
                }
                let (y, z) = (&numerators[at % p], &numerators[at / p]);
                for (c, zc) in z.iter().enumerate() {
                    for (b, yb) in y.iter().enumerate() {
                        let yz = yb * zc;
                        for (a, xa) in row.iter().enumerate() {
                            sum[a + 3 * b + 9 * c] += xa * yz;
                        }
                    }
                }
            }
            // At most 2^45, so the conversion does not round.
            #[allow(clippy::cast_precision_loss)]
            let moments: Moments = std::array::from_fn(|i| sum[i] as f64 / scale[i]);
            (m, moments)
        })
        .collect();
    moments.sort_unstable_by_key(|(m, _)| *m);
    moments
}

/// `∫ f ds` over the voxels whose moments are `m`.
fn integrate(m: &Moments, f: &Separable) -> f64 {
    let mut sum = 0.0;
    for c in 0..3 {
        for b in 0..3 {
            let yz = f[1][b] * f[2][c];
            if yz == 0.0 {
                continue;
            }
            for a in 0..3 {
                sum += f[0][a] * yz * m[a + 3 * b + 9 * c];
            }
        }
    }
    sum
}

/// The product of two polynomials of degree at most one.
fn times(p: &Poly, q: &Poly) -> Poly {
    debug_assert!(p[2] == 0.0 && q[2] == 0.0, "degree two at most");
    [p[0] * q[0], p[0] * q[1] + p[1] * q[0], p[1] * q[1]]
}

/// The product of two separable functions of degree at most one per axis.
fn product(f: &Separable, g: &Separable) -> Separable {
    std::array::from_fn(|a| times(&f[a], &g[a]))
}

/// `p` along axis `k`, one along the others.
fn along(k: usize, p: Poly) -> Separable {
    let mut f = [[1.0, 0.0, 0.0]; 3];
    f[k] = p;
    f
}

/// `∂N_n/∂x_a` of the cell's trilinear shape function of corner `n`.
fn shape_derivative(n: usize, a: usize, size: [f64; 3]) -> Separable {
    let b = corner(n);
    std::array::from_fn(|axis| match (axis == a, b[axis] == 1) {
        (true, true) => [1.0 / size[a], 0.0, 0.0],
        (true, false) => [-1.0 / size[a], 0.0, 0.0],
        (false, true) => [0.0, 1.0, 0.0],
        (false, false) => [1.0, -1.0, 0.0],
    })
}

/// `K_αα` (9 × 9) and `K_αu` (9 × 24), row-major, of the voxels whose moments per material are
/// `moments` (`(material index, moments)`), `elasticities` indexed by material.
fn bubble_matrices(
    moments: &[(usize, Moments)],
    elasticities: &[[[f64; 6]; 6]],
    size: [f64; 3],
) -> (Vec<f64>, Vec<f64>) {
    let jacobian = size[0] * size[1] * size[2];
    let total: f64 = moments.iter().map(|(_, m)| m[0]).sum();
    // Bubble `3i + k` strains row `r(i, k)` by `g_k(s_k) = 4 (1 − 2 s_k) / h_k`, less its mean
    // over the owned voxels (Taylor's correction).
    let centred: [Poly; 3] = std::array::from_fn(|k| {
        let g = [4.0 / size[k], -8.0 / size[k], 0.0];
        let mean = moments.iter().map(|(_, m)| integrate(m, &along(k, g))).sum::<f64>() / total;
        [g[0] - mean, g[1], 0.0]
    });
    let row = |i: usize, k: usize| if i == k { i } else { shear_row(i, k) };
    let mut k_aa = vec![0.0; 81];
    let mut k_au = vec![0.0; 9 * 24];
    for (m, mom) in moments {
        let d = &elasticities[*m];
        // ∫ g̃_k g̃_l and ∫ g̃_k ∂N_n/∂x_a over this material's voxels.
        let gg: [[f64; 3]; 3] = std::array::from_fn(|k| {
            std::array::from_fn(|l| {
                integrate(mom, &product(&along(k, centred[k]), &along(l, centred[l])))
            })
        });
        let gb: [[[f64; 3]; 8]; 3] = std::array::from_fn(|k| {
            std::array::from_fn(|n| {
                std::array::from_fn(|a| {
                    integrate(mom, &product(&along(k, centred[k]), &shape_derivative(n, a, size)))
                })
            })
        });
        for i in 0..3 {
            for k in 0..3 {
                let (c, r) = (3 * i + k, row(i, k));
                for j in 0..3 {
                    for l in 0..3 {
                        k_aa[c * 9 + 3 * j + l] += jacobian * d[r][row(j, l)] * gg[k][l];
                    }
                }
                // Column (n, j) of the nodal strain: row j holds ∂N_n/∂x_j, row r(a, j) holds
                // ∂N_n/∂x_a for a ≠ j.
                for n in 0..8 {
                    for j in 0..3 {
                        let v: f64 = (0..3).map(|a| d[r][row(a, j)] * gb[k][n][a]).sum();
                        k_au[c * 24 + 3 * n + j] += jacobian * v;
                    }
                }
            }
        }
    }
    (k_aa, k_au)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hex8::{gauss_points, shape_gradient};
    use crate::procedural::from_fn;
    use crate::topology::coords;
    use crate::{LabelVolume, Material, MaterialTable};

    /// `B` (6 × 24): the strain of the element's trilinear field at local point `s`.
    fn strain_of_nodes(s: [f64; 3], size: [f64; 3]) -> [[f64; 24]; 6] {
        let mut b = [[0.0; 24]; 6];
        for n in 0..8 {
            let g = shape_gradient(n, s, size);
            for i in 0..3 {
                b[i][3 * n + i] = g[i];
                for a in 0..3 {
                    if a != i {
                        b[shear_row(a, i)][3 * n + i] = g[a];
                    }
                }
            }
        }
        b
    }

    /// `G` (6 × 9): the strain of bubble `3i + k` at local point `s`.
    fn strain_of_bubbles(s: [f64; 3], size: [f64; 3]) -> [[f64; 9]; 6] {
        let mut g = [[0.0; 9]; 6];
        for i in 0..3 {
            for k in 0..3 {
                let row = if i == k { i } else { shear_row(i, k) };
                g[row][3 * i + k] = 4.0 * (1.0 - 2.0 * s[k]) / size[k];
            }
        }
        g
    }

    /// `K_αα`, `K_αu` by 2 × 2 × 2 Gauss points in every owned voxel: the definition, summed
    /// point by point.
    fn by_quadrature(grid: &BranchedGrid, id: u32) -> (Vec<f64>, Vec<f64>) {
        let materials: Vec<[[f64; 6]; 6]> =
            grid.materials().map(|(_, m)| elasticity(m.youngs_modulus, m.poisson_ratio)).collect();
        let size = grid.element_size();
        let per = 1u32 << grid.top_level();
        let dims = grid.fine().dims();
        let voxel_volume: f64 = grid.spacing().iter().product();
        let mut voxels = Vec::new();
        grid.element_voxels_into(id, &mut voxels);
        let cell = grid.top().cell_coords(grid.top().element(id).unwrap().cell);
        let points: Vec<([f64; 3], f64, usize)> = voxels
            .iter()
            .flat_map(|&v| {
                let c = coords(v, dims);
                let m = usize::from(grid.fine().material(v).unwrap());
                gauss_points().map(|t| {
                    let s: [f64; 3] = std::array::from_fn(|a| {
                        (f64::from(c[a] - cell[a] * per) + t[a]) / f64::from(per)
                    });
                    (s, voxel_volume / 8.0, m)
                })
            })
            .collect();
        let volume: f64 = points.iter().map(|p| p.1).sum();
        let mut mean = [[0.0; 9]; 6];
        for &(s, w, _) in &points {
            let g = strain_of_bubbles(s, size);
            for r in 0..6 {
                for c in 0..9 {
                    mean[r][c] += w * g[r][c] / volume;
                }
            }
        }
        let (mut k_aa, mut k_au) = (vec![0.0; 81], vec![0.0; 216]);
        for &(s, w, m) in &points {
            let d = &materials[m];
            let mut g = strain_of_bubbles(s, size);
            for r in 0..6 {
                for c in 0..9 {
                    g[r][c] -= mean[r][c];
                }
            }
            let b = strain_of_nodes(s, size);
            for a in 0..9 {
                for r in 0..6 {
                    let dg: f64 = (0..6).map(|q| d[r][q] * g[q][a]).sum();
                    for c in 0..9 {
                        k_aa[a * 9 + c] += w * dg * g[r][c];
                    }
                    for c in 0..24 {
                        k_au[a * 24 + c] += w * dg * b[r][c];
                    }
                }
            }
        }
        (k_aa, k_au)
    }

    /// Two materials in a block with a hole and a sloped face: partly filled cells of mixed
    /// material at every level.
    fn mixed_block() -> LabelVolume {
        from_fn([16, 12, 16], [1e-3, 1.5e-3, 2e-3], |x, y, z| {
            let hole = (x + 0.5 - 6.0).powi(2) + (z + 0.5 - 9.0).powi(2) < 8.0;
            if hole || x + 0.5 >= 15.0 - 0.4 * z {
                0
            } else if y < 5.0 {
                1
            } else {
                2
            }
        })
    }

    #[test]
    fn the_moments_give_the_quadratures_matrices() {
        let volume = mixed_block();
        let mut table = MaterialTable::uniform(&[1], Material::new(3e3, 0.45, 1000.0));
        table.insert(2, Material::new(9e3, 0.49, 1000.0));
        for level in 1..=3 {
            let grid = BranchedGrid::build(&volume, &table, level).unwrap();
            let elasticities: Vec<[[f64; 6]; 6]> = grid
                .materials()
                .map(|(_, m)| elasticity(m.youngs_modulus, m.poisson_ratio))
                .collect();
            let mut voxels = Vec::new();
            let mut checked = 0;
            for (id, _) in grid.top().elements() {
                voxels.clear();
                grid.element_voxel_offsets_into(id, &mut voxels);
                let moments = material_moments(&grid, &voxels);
                let (aa, au) = bubble_matrices(&moments, &elasticities, grid.element_size());
                let (qa, qu) = by_quadrature(&grid, id);
                // Both are exact integrals of the same polynomials: they differ by rounding,
                // relative to the largest entry.
                for (x, y) in [(&aa, &qa), (&au, &qu)] {
                    let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    let diff = x.iter().zip(y).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                    assert!(
                        diff <= 1e-12 * scale,
                        "level {level}, element {id}: {diff:e} of {scale:e}"
                    );
                }
                checked += 1;
            }
            assert!(checked > 0);
        }
    }
}
