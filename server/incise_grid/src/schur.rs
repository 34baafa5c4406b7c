//! The Schur complement both enriched element kinds end with: internal unknowns condensed out of
//! an element's stiffness.

use crate::hex8::Mat24;

/// `K − Bᵀ A⁺ B` for the symmetric positive semi-definite `a` (`n × n`, row-major) and `b`
/// (`n × 24`, row-major), by a Cholesky factor of `a`. A pivot below `null_pivot` times its
/// diagonal entry marks a direction the internal unknowns move in without energy; as the whole
/// matrix is semi-definite, `b` has no component along it, so it is dropped (any generalised
/// inverse gives the same complement). The result is symmetrised.
pub(crate) fn complement(k: &Mat24, mut a: Vec<f64>, mut b: Vec<f64>, null_pivot: f64) -> Mat24 {
    let n = b.len() / 24;
    debug_assert_eq!(a.len(), n * n);
    let diag: Vec<f64> = (0..n).map(|r| a[r * n + r]).collect();
    let mut null = vec![false; n];
    for j in 0..n {
        let d = a[j * n + j] - (0..j).map(|k| a[j * n + k] * a[j * n + k]).sum::<f64>();
        if d <= null_pivot * diag[j] || d <= 0.0 {
            null[j] = true;
            for r in j..n {
                a[r * n + j] = 0.0;
            }
            continue;
        }
        let l = d.sqrt();
        a[j * n + j] = l;
        for r in j + 1..n {
            let s = a[r * n + j] - (0..j).map(|k| a[r * n + k] * a[j * n + k]).sum::<f64>();
            a[r * n + j] = s / l;
        }
    }
    // Y = L⁻¹ B, in place, a row at a time so that the inner loops run along the 24 columns.
    // Each sum starts from −0.0 and adds in the order of `k`, as `Iterator::sum` would.
    for r in 0..n {
        let (done, rest) = b.split_at_mut(r * 24);
        let row = &mut rest[..24];
        if null[r] {
            row.fill(0.0);
            continue;
        }
        let mut acc = [-0.0; 24];
        for (k, above) in done.chunks_exact(24).enumerate() {
            let l = a[r * n + k];
            for (s, y) in acc.iter_mut().zip(above) {
                *s += l * y;
            }
        }
        let pivot = a[r * n + r];
        for (y, s) in row.iter_mut().zip(&acc) {
            *y = (*y - s) / pivot;
        }
    }
    // Bᵀ A⁺ B = Yᵀ Y, its upper triangle summed row of Y by row of Y.
    let mut yty = [-0.0; 576];
    for y in b.chunks_exact(24) {
        for i in 0..24 {
            let yi = y[i];
            for (s, yj) in yty[i * 24 + i..i * 24 + 24].iter_mut().zip(&y[i..]) {
                *s += yi * yj;
            }
        }
    }
    let mut out = k.clone();
    for i in 0..24 {
        for j in i..24 {
            let v = 0.5 * (out.0[i * 24 + j] + out.0[j * 24 + i]) - yty[i * 24 + j];
            out.0[i * 24 + j] = v;
            out.0[j * 24 + i] = v;
        }
    }
    out
}
