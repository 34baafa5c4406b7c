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
//! The integrands are polynomials of degree at most two per axis within a voxel, so each voxel's
//! 2 × 2 × 2 Gauss points integrate them exactly, as they do `K_uu`.

use crate::grid::BranchedGrid;
use crate::hex8::{Mat24, gauss_points, shape_gradient};
use crate::topology::coords;

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

/// `B` (6 × 24): the strain of the element's trilinear field at local point `s ∈ [0, 1]³`.
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

/// `G` (6 × 9): the strain of bubble `3i + k` (component `i`, along axis `k`) at local point `s`.
fn strain_of_bubbles(s: [f64; 3], size: [f64; 3]) -> [[f64; 9]; 6] {
    let mut g = [[0.0; 9]; 6];
    for i in 0..3 {
        for k in 0..3 {
            let d = 4.0 * (1.0 - 2.0 * s[k]) / size[k];
            let row = if i == k { i } else { shear_row(i, k) };
            g[row][3 * i + k] = d;
        }
    }
    g
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
/// # Panics
/// Only on a broken grid invariant (a live element without voxels or matrices).
pub fn element_stiffness(grid: &BranchedGrid, id: u32, voxels: &mut Vec<u32>) -> Option<Mat24> {
    let top = grid.top();
    let e = top.element(id)?;
    let k_uu = &grid.matrices(id).expect("live element has matrices").stiffness;
    if grid.top_level() == 0 {
        return Some(k_uu.clone());
    }
    let materials: Vec<[[f64; 6]; 6]> =
        grid.materials().map(|(_, m)| elasticity(m.youngs_modulus, m.poisson_ratio)).collect();
    let size = grid.element_size();
    let per = 1u32 << grid.top_level();
    let dims = grid.fine().dims();
    let voxel_volume: f64 = grid.spacing().iter().product();
    voxels.clear();
    grid.element_voxels_into(id, voxels);
    let cell = top.cell_coords(e.cell);
    // Every Gauss point of every owned voxel: (local point, weight, material).
    let points: Vec<([f64; 3], f64, usize)> = voxels
        .iter()
        .flat_map(|&v| {
            let c = coords(v, dims);
            let m = usize::from(grid.fine().material(v).expect("owned voxel holds material"));
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
    let mut k_aa = [[0.0; 9]; 9];
    let mut k_au = [[0.0; 24]; 9];
    for &(s, w, m) in &points {
        let d = &materials[m];
        let mut g = strain_of_bubbles(s, size);
        for r in 0..6 {
            for c in 0..9 {
                g[r][c] -= mean[r][c];
            }
        }
        let b = strain_of_nodes(s, size);
        let mut dg = [[0.0; 9]; 6];
        for r in 0..6 {
            for c in 0..9 {
                dg[r][c] = (0..6).map(|q| d[r][q] * g[q][c]).sum();
            }
        }
        for a in 0..9 {
            for c in 0..9 {
                k_aa[a][c] += w * (0..6).map(|r| dg[r][a] * g[r][c]).sum::<f64>();
            }
            for c in 0..24 {
                k_au[a][c] += w * (0..6).map(|r| dg[r][a] * b[r][c]).sum::<f64>();
            }
        }
    }
    let flat = |rows: &[[f64; 24]; 9]| rows.iter().flatten().copied().collect::<Vec<f64>>();
    let k_aa: Vec<f64> = k_aa.iter().flatten().copied().collect();
    Some(crate::schur::complement(k_uu, k_aa, flat(&k_au), NULL_PIVOT))
}
