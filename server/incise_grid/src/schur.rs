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
    // Y = L⁻¹ B, in place; then Bᵀ A⁺ B = Yᵀ Y.
    for col in 0..24 {
        for r in 0..n {
            if null[r] {
                b[r * 24 + col] = 0.0;
                continue;
            }
            let s = b[r * 24 + col] - (0..r).map(|k| a[r * n + k] * b[k * 24 + col]).sum::<f64>();
            b[r * 24 + col] = s / a[r * n + r];
        }
    }
    let mut out = k.clone();
    for i in 0..24 {
        for j in i..24 {
            let s: f64 = (0..n).map(|r| b[r * 24 + i] * b[r * 24 + j]).sum();
            let v = 0.5 * (out.0[i * 24 + j] + out.0[j * 24 + i]) - s;
            out.0[i * 24 + j] = v;
            out.0[j * 24 + i] = v;
        }
    }
    out
}
