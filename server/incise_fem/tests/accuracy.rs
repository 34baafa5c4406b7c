//! Accuracy of the hexahedral force fields against known answers: rigid motions, the patch test,
//! linear vs corotational at small load, finite differences of the elastic energy, and the
//! Euler–Bernoulli cantilever of docs/benchmarks.md scene C.

use incise_fem::model::Loads;

use incise_fem::ode::static_solve;
use incise_fem::{FixedNodes, Formulation, HexForceField, HexModel};
use incise_grid::procedural::from_fn;
use incise_grid::{BranchedGrid, Material, MaterialTable};
use incise_math::Vec3;
use incise_math::mat3::{Mat3, axis_angle, mul_vec};

fn block(cells: [usize; 3], size: Vec3, level: u32, material: Material) -> HexModel {
    let n = cells.map(|c| c << level);
    let spacing = std::array::from_fn(|a| size[a] / n[a] as f64);
    let v = from_fn(n, spacing, |_, _, _| 1);
    let grid = BranchedGrid::build(&v, &MaterialTable::uniform(&[1], material), level).unwrap();
    HexModel::from_grid(&grid)
}

fn transformed(model: &HexModel, r: &Mat3, t: Vec3) -> Vec<Vec3> {
    model
        .rest
        .iter()
        .map(|p| {
            let q = mul_vec(r, p);
            [q[0] + t[0], q[1] + t[1], q[2] + t[2]]
        })
        .collect()
}

/// The largest node norm; NaN if any is (`f64::max` would skip it and let a check pass).
fn max_norm(v: &[Vec3]) -> f64 {
    v.iter()
        .map(|x| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt())
        .fold(0.0, |m: f64, n| if m.is_nan() || n.is_nan() { f64::NAN } else { m.max(n) })
}

#[test]
fn rigid_motions_give_zero_corotational_force() {
    let model = block([3, 2, 2], [0.03, 0.02, 0.02], 1, Material::new(3e3, 0.45, 1000.0));
    // Force scale: K · (a displacement of the block's size) — what a real deformation would give.
    let scale = model.elements[0].stiffness.frobenius() * 0.03;
    let motions = [
        (axis_angle(&[0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2), [0.01, 0.0, 0.0]),
        (axis_angle(&[1.0, 0.0, 0.0], std::f64::consts::FRAC_PI_2), [0.0, -0.02, 0.0]),
        (axis_angle(&[0.0, 1.0, 0.0], std::f64::consts::PI), [0.0, 0.0, 0.05]),
        (axis_angle(&[0.48, 0.6, 0.64], 2.1), [0.3, -0.1, 0.2]),
    ];
    for (r, t) in motions {
        let x = transformed(&model, &r, t);
        let mut cor = HexForceField::new(&model, Formulation::Corotational);
        cor.update_rotations(&model, &x);
        let mut f = vec![[0.0; 3]; model.node_count()];
        cor.add_forces(&model, &x, &mut f);
        assert!(
            max_norm(&f) <= 1e-10 * scale,
            "corotational force {:e} under a rigid motion",
            max_norm(&f)
        );
        // The linear model's spurious force under the same rotation (Picinbono 2001 Fig. 3's point).
        let lin = HexForceField::new(&model, Formulation::Linear);
        let mut g = vec![[0.0; 3]; model.node_count()];
        lin.add_forces(&model, &x, &mut g);
        assert!(max_norm(&g) > 1e-3 * scale, "linear forces should be spurious under rotation");
    }
}

#[test]
fn patch_test_reproduces_a_uniform_strain() {
    // 3×3×3 elements; boundary nodes displaced by u = G x; the interior nodes must follow exactly.
    let model = block([3, 3, 3], [0.03, 0.03, 0.03], 1, Material::new(5e3, 0.3, 1000.0));
    let g: Mat3 = [[1e-3, 2e-4, 0.0], [2e-4, -5e-4, 1e-4], [0.0, 1e-4, 3e-4]];
    let on_boundary = |p: &Vec3| (0..3).any(|a| p[a].abs() < 1e-12 || (p[a] - 0.03).abs() < 1e-12);
    for formulation in [Formulation::Linear, Formulation::Corotational] {
        let fixed = FixedNodes::by_position(&model.rest, on_boundary);
        let mut x: Vec<Vec3> = model
            .rest
            .iter()
            .map(|p| {
                if on_boundary(p) {
                    let u = mul_vec(&g, p);
                    [p[0] + u[0], p[1] + u[1], p[2] + u[2]]
                } else {
                    *p
                }
            })
            .collect();
        let mut ff = HexForceField::new(&model, formulation);
        let report =
            static_solve(&model, &mut ff, &fixed, &Loads::gravity([0.0; 3]), &mut x, 1e-12, 20);
        assert!(
            report.converged || report.relative_residual.is_nan() || report.newton_iterations > 0
        );
        assert!(
            x.iter().flatten().all(|c| c.is_finite()),
            "{formulation:?}: a position is not finite"
        );
        let mut worst = 0.0f64;
        for (p, xi) in model.rest.iter().zip(&x) {
            let u = mul_vec(&g, p);
            for k in 0..3 {
                worst = worst.max((xi[k] - p[k] - u[k]).abs());
            }
        }
        // Displacements are ~3e-5 m; 1e-12 m is round-off of the CG solve to 1e-12 relative.
        assert!(
            worst <= 1e-12,
            "{formulation:?}: interior differs from the uniform strain by {worst:e} m"
        );
    }
}

/// A deterministic pseudo-random displacement field of amplitude `amp` (m).
fn perturbed(model: &HexModel, amp: f64, seed: u64) -> Vec<Vec3> {
    let mut s = seed | 1;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    model
        .rest
        .iter()
        .map(|p| [p[0] + amp * next(), p[1] + amp * next(), p[2] + amp * next()])
        .collect()
}

/// ‖K d − (−(f(x + hd) − f(x − hd)) / 2h)‖: the stiffness against central differences of forces.
fn stiffness_mismatch(kd: &[Vec3], f_plus: &[Vec3], f_minus: &[Vec3], h: f64) -> f64 {
    kd.iter()
        .zip(f_plus.iter().zip(f_minus))
        .map(|(k, (p, m))| (0..3).map(|a| (k[a] + (p[a] - m[a]) / (2.0 * h)).powi(2)).sum::<f64>())
        .sum::<f64>()
        .sqrt()
}

fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x[0] * y[0] + x[1] * y[1] + x[2] * y[2]).sum()
}

#[test]
fn linear_forces_and_stiffness_match_finite_differences_of_the_energy() {
    // The linear energy is quadratic, so central differences are exact up to round-off:
    // relative error ~ ε·E/(h·|f|) ≈ 1e-16·1e-3/1e-7 — 1e-6 leaves a wide margin.
    let model = block([2, 2, 2], [0.02, 0.02, 0.02], 1, Material::new(3e3, 0.45, 1000.0));
    let ff = HexForceField::new(&model, Formulation::Linear);
    let x = perturbed(&model, 1e-3, 7);
    let dir = perturbed(&model, 1.0, 11)
        .iter()
        .zip(&model.rest)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect::<Vec<_>>();
    let h = 1e-7;
    let shift = |s: f64| {
        x.iter()
            .zip(&dir)
            .map(|(p, d)| [p[0] + s * d[0], p[1] + s * d[1], p[2] + s * d[2]])
            .collect::<Vec<Vec3>>()
    };
    let de = (ff.energy(&model, &shift(h)) - ff.energy(&model, &shift(-h))) / (2.0 * h);
    let mut f = vec![[0.0; 3]; model.node_count()];
    ff.add_forces(&model, &x, &mut f);
    let fd = -dot(&f, &dir);
    assert!((de - fd).abs() <= 1e-6 * fd.abs(), "dE/ds = {de:e}, −f·d = {fd:e}");
    // Jacobian: K d against the difference of forces.
    let mut kd = vec![[0.0; 3]; model.node_count()];
    ff.add_stiffness_times(&model, 1.0, &dir, &mut kd);
    let (mut fp, mut fm) = (vec![[0.0; 3]; model.node_count()], vec![[0.0; 3]; model.node_count()]);
    ff.add_forces(&model, &shift(h), &mut fp);
    ff.add_forces(&model, &shift(-h), &mut fm);
    let err = stiffness_mismatch(&kd, &fp, &fm, h);
    assert!(err <= 1e-6 * dot(&kd, &kd).sqrt(), "K d differs from the force difference by {err:e}");
}

#[test]
fn corotational_forces_match_the_energy_at_small_strain_and_the_stiffness_at_rotated_rest() {
    let model = block([2, 2, 2], [0.02, 0.02, 0.02], 1, Material::new(3e3, 0.45, 1000.0));
    let r = axis_angle(&[0.0, 0.6, 0.8], 0.9);
    let rotated = transformed(&model, &r, [0.01, 0.0, 0.0]);
    // Around a rotated rest state the consistent Jacobian is exactly R K Rᵀ (the force vanishes,
    // so dR/dx contributes nothing): compare K d with central differences of the forces.
    let mut ff = HexForceField::new(&model, Formulation::Corotational);
    let dir = perturbed(&model, 1.0, 5)
        .iter()
        .zip(&model.rest)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect::<Vec<_>>();
    let h = 1e-7;
    let shift = |base: &[Vec3], s: f64| {
        base.iter()
            .zip(&dir)
            .map(|(p, d)| [p[0] + s * d[0], p[1] + s * d[1], p[2] + s * d[2]])
            .collect::<Vec<Vec3>>()
    };
    ff.update_rotations(&model, &rotated);
    let mut kd = vec![[0.0; 3]; model.node_count()];
    ff.add_stiffness_times(&model, 1.0, &dir, &mut kd);
    let force_at = |ff: &mut HexForceField, x: &[Vec3]| {
        ff.update_rotations(&model, x);
        let mut f = vec![[0.0; 3]; model.node_count()];
        ff.add_forces(&model, x, &mut f);
        f
    };
    let (fp, fm) =
        (force_at(&mut ff, &shift(&rotated, h)), force_at(&mut ff, &shift(&rotated, -h)));
    let err = stiffness_mismatch(&kd, &fp, &fm, h);
    // Truncation O(h²·|K|·|d|) and rotation round-off: 1e-5 relative.
    assert!(
        err <= 1e-5 * dot(&kd, &kd).sqrt(),
        "R K Rᵀ d differs from the force difference by {err:e}"
    );

    // At a small strain ε the force omits the dR/dx term of the energy's gradient, which is
    // O(ε) relative to the force: at ε ≈ 1e-4 the mismatch must stay below 1e-3.
    let x = perturbed(&model, 2e-6, 3)
        .iter()
        .zip(&model.rest)
        .map(|(p, q)| {
            let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
            let rq = mul_vec(&r, q);
            let rd = mul_vec(&r, &d);
            [rq[0] + rd[0], rq[1] + rd[1], rq[2] + rd[2]]
        })
        .collect::<Vec<Vec3>>();
    let f = force_at(&mut ff, &x);
    let energy_at = |ff: &mut HexForceField, x: &[Vec3]| {
        ff.update_rotations(&model, x);
        ff.energy(&model, x)
    };
    let h = 1e-9;
    let de = (energy_at(&mut ff, &shift(&x, h)) - energy_at(&mut ff, &shift(&x, -h))) / (2.0 * h);
    let fd = -dot(&f, &dir);
    assert!((de - fd).abs() <= 1e-3 * fd.abs(), "dE/ds = {de:e}, −f·d = {fd:e}");
}

#[test]
fn the_full_corotational_tangent_matches_finite_differences_under_large_strain() {
    // A stretched, sheared and rotated block, one with full cells and one with a hole so that
    // partly filled cells (rotations taken off the cell's centre) are covered too. There the
    // force is far from zero, so `R K Rᵀ` alone misses the rotation's derivative by a part of
    // the order of the strain; with `RotationTangent` the product must match central
    // differences of the forces to truncation and rotation round-off: 1e-6 relative (h = 1e-7
    // on a 2 cm block: O(h²) truncation ~1e-10, round-off ~1e-16·|f|/h ~1e-9 of |K d|).
    use incise_fem::forcefield::hex::tangent::RotationTangent;
    let material = Material::new(3e3, 0.45, 1000.0);
    let holed = {
        let v = from_fn([4, 4, 4], [0.005; 3], |x, y, z| {
            u16::from(!((1.0..2.0).contains(&x) && y > 1.0 && (2.0..3.0).contains(&z)))
        });
        let grid = BranchedGrid::build(&v, &MaterialTable::uniform(&[1], material), 1).unwrap();
        HexModel::from_grid(&grid)
    };
    for (name, model) in [("full", block([2, 2, 2], [0.02; 3], 1, material)), ("holed", holed)] {
        let r = axis_angle(&[0.48, 0.6, 0.64], 1.1);
        let x: Vec<Vec3> = perturbed(&model, 4e-3, 13)
            .iter()
            .map(|p| mul_vec(&r, &[1.3 * p[0] + 0.2 * p[2], 0.9 * p[1], p[2]]))
            .collect();
        let dir: Vec<Vec3> = perturbed(&model, 1.0, 17)
            .iter()
            .zip(&model.rest)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
            .collect();
        let h = 1e-7;
        let shifted = |s: f64| -> Vec<Vec3> {
            x.iter().zip(&dir).map(|(p, d)| std::array::from_fn(|k| p[k] + s * d[k])).collect()
        };
        let mut ff = HexForceField::new(&model, Formulation::Corotational);
        let mut force_at = |x: &[Vec3]| {
            ff.update_rotations(&model, x);
            let mut f = vec![[0.0; 3]; model.node_count()];
            ff.add_forces(&model, x, &mut f);
            f
        };
        let (fp, fm) = (force_at(&shifted(h)), force_at(&shifted(-h)));
        ff.update_rotations(&model, &x);
        let mut kd = vec![[0.0; 3]; model.node_count()];
        ff.add_stiffness_times(&model, 1.0, &dir, &mut kd);
        let without = stiffness_mismatch(&kd, &fp, &fm, h) / dot(&kd, &kd).sqrt();
        RotationTangent::at(&model, &ff, &x).add_times(&model, &ff, 1.0, &dir, &mut kd);
        let with = stiffness_mismatch(&kd, &fp, &fm, h) / dot(&kd, &kd).sqrt();
        println!("{name}: relative mismatch R K Rᵀ alone {without:.2e}, with ∂R/∂x {with:.2e}");
        assert!(without > 1e-2, "{name}: the state must be loaded enough to tell ({without:e})");
        assert!(with <= 1e-6, "{name}: full tangent differs from the force difference by {with:e}");
    }
}

#[test]
fn linear_and_corotational_agree_for_small_loads() {
    let model = block([4, 2, 2], [0.04, 0.02, 0.02], 1, Material::new(3e3, 0.45, 1000.0));
    let fixed = FixedNodes::plane(&model.rest, 0, 0.0, 1e-12);
    let mut nodal = vec![[0.0; 3]; model.node_count()];
    for (n, p) in model.rest.iter().enumerate() {
        if (p[0] - 0.04).abs() < 1e-12 {
            nodal[n] = [0.0, 0.0, -1e-5];
        }
    }
    let loads = Loads { gravity: [0.0; 3], nodal };
    let mut results = Vec::new();
    for formulation in [Formulation::Linear, Formulation::Corotational] {
        let mut ff = HexForceField::new(&model, formulation);
        let mut x = model.rest.clone();
        let report = static_solve(&model, &mut ff, &fixed, &loads, &mut x, 1e-10, 30);
        assert!(report.converged, "{formulation:?}: {report:?}");
        results.push(x);
    }
    let u: Vec<f64> = results
        .iter()
        .map(|x| x.iter().zip(&model.rest).map(|(a, b)| (b[2] - a[2]).abs()).fold(0.0, f64::max))
        .collect();
    assert!(u[0] > 1e-7, "the load deflects the beam ({:e} m)", u[0]);
    // The deflection/length ratio is ~1e-5 here: geometric effects are O(1e-5) relative.
    assert!((u[0] - u[1]).abs() <= 1e-3 * u[0], "linear {:e} vs corotational {:e}", u[0], u[1]);
}
