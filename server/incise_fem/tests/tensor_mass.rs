//! The tensor-mass family (paper 2) against known answers: the stored tensors give the same forces
//! as a conventional element-by-element assembly, forces are minus the energy gradient, St
//! Venant-Kirchhoff is invariant under rotation while the linear model is not (Fig. 3's point),
//! and removing tetrahedra equals building the mesh without them.

use incise_fem::forcefield::tet::element::Elasticity;
use incise_fem::forcefield::tet::element::Fibre;
use incise_fem::forcefield::tet::{Lame, TensorMassForceField, TetMaterial, TetModel};
use incise_grid::LabelVolume;
use incise_math::Vec3;
use incise_math::mat3::{axis_angle, mul_vec};
use incise_mesh::TetMesh;
use incise_mesh::generate::{cylinder, from_volume};
use incise_mesh::topology::{TetTopology, check_closed, check_manifold};
use proptest::prelude::*;

fn material(_: u32) -> TetMaterial {
    TetMaterial::isotropic(Lame::from_young_poisson(3_000.0, 0.45), 1_000.0)
}

/// Paper 2's cylinder shape (height 3 × radius), 1 cm radius.
fn small_cylinder() -> (TetMesh, TetModel) {
    let mesh = cylinder(0.01, 0.03, 4, 6);
    let model = TetModel::new(&mesh, material);
    (mesh, model)
}

/// A smooth large deformation: bend, twist and stretch of up to about half the size.
fn deformed(rest: &[Vec3]) -> Vec<Vec3> {
    rest.iter()
        .map(|p| {
            let z = p[2] / 0.03;
            let r = axis_angle(&[0.0, 0.0, 1.0], 0.8 * z);
            let q = mul_vec(&r, p);
            [q[0] + 0.012 * z * z, q[1] - 0.004 * z, q[2] * (1.0 + 0.2 * z) + 0.001 * p[0] / 0.01]
        })
        .collect()
}

fn max_abs(f: &[Vec3]) -> f64 {
    f.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()))
}

fn max_diff(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().flatten().zip(b.iter().flatten()).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
}

/// Fibres along z, four times stiffer along them than across.
fn fibred(_: u32) -> TetMaterial {
    let lame = Lame::from_young_poisson(3_000.0, 0.45);
    TetMaterial {
        fibre: Some(Fibre {
            direction: [0.2, 0.0, 1.0],
            lame_along: Lame { lambda: 4.0 * lame.lambda, mu: 4.0 * lame.mu },
        }),
        ..material(0)
    }
}

#[test]
fn tensor_mass_forces_equal_the_element_assembly() {
    let (mesh, isotropic) = small_cylinder();
    let topo = TetTopology::new(&mesh);
    let x = deformed(&isotropic.rest);
    let transverse = TetModel::new(&mesh, fibred);
    for (model, kind, tolerance) in [
        (&isotropic, Elasticity::Linear, 1e-12),
        (&isotropic, Elasticity::StVenantKirchhoff, 1e-10),
        (&transverse, Elasticity::Linear, 1e-12),
        (&transverse, Elasticity::StVenantKirchhoff, 1e-10),
    ] {
        let model = model.clone();
        let tm = TensorMassForceField::new(&model, &topo, kind);
        let mut a = vec![[0.0; 3]; model.vertex_count()];
        tm.add_forces(&model, &x, &mut a);
        let mut b = vec![[0.0; 3]; model.vertex_count()];
        model.add_forces(|_| true, &x, kind, &mut b);
        let rel = max_diff(&a, &b) / max_abs(&b);
        let fibre = if model.fibre[0].is_some() { " (transversely isotropic)" } else { "" };
        println!(
            "{kind:?}{fibre}: tensor-mass vs element assembly, max relative difference {rel:.2e}"
        );
        assert!(rel <= tolerance, "{kind:?}: {rel:e}");
        let (wa, wb) = (tm.energy(&model, &x), model.energy(|_| true, &x, kind));
        assert!((wa - wb).abs() <= tolerance * wb.abs(), "{kind:?} energy {wa} vs {wb}");
    }
}

#[test]
fn forces_are_minus_the_energy_gradient() {
    // Central differences with step h = 1e-7 m: truncation O((h/ℓ)²) with elements ℓ ≈ 2.5 mm,
    // ~1e-9 relative (measured: the error scales as h², 1.4e-6 at h = 1e-6); rounding ε·Σ|terms|/h,
    // where the stored SVK terms cancel heavily at large displacement (their sum is ~1e3 times the
    // energy), ~1e-8. So 1e-6 relative to the largest entry is a real check (a wrong coefficient
    // is off by ~1e-1).
    let (mesh, model) = small_cylinder();
    let topo = TetTopology::new(&mesh);
    let x = deformed(&model.rest);
    let h = 1e-7;
    let transverse = TetModel::new(&mesh, fibred);
    for (model, kind) in [
        (&model, Elasticity::Linear),
        (&model, Elasticity::StVenantKirchhoff),
        (&transverse, Elasticity::StVenantKirchhoff),
    ] {
        let tm = TensorMassForceField::new(model, &topo, kind);
        let mut f = vec![[0.0; 3]; model.vertex_count()];
        tm.add_forces(model, &x, &mut f);
        let scale = max_abs(&f);
        // The tangent stiffness is the Jacobian of the forces: K v = −(f(x + hv) − f(x − hv))/2h,
        // same step and tolerance (relative to the largest entry of K v).
        let dir: Vec<Vec3> = (0..model.vertex_count())
            .map(|i| {
                [((i % 7) as f64 - 3.0) / 3.0, ((i % 5) as f64 - 2.0) / 2.0, 1.0 - (i % 3) as f64]
            })
            .collect();
        let mut kv = vec![[0.0; 3]; model.vertex_count()];
        tm.add_stiffness_times(model, &x, &dir, &mut kv);
        let shifted = |s: f64| -> Vec<Vec3> {
            let xs: Vec<Vec3> =
                x.iter().zip(&dir).map(|(p, d)| std::array::from_fn(|k| p[k] + s * d[k])).collect();
            let mut g = vec![[0.0; 3]; model.vertex_count()];
            tm.add_forces(model, &xs, &mut g);
            g
        };
        let (fp, fm) = (shifted(h), shifted(-h));
        let fd: Vec<Vec3> = fp
            .iter()
            .zip(&fm)
            .map(|(a, b)| std::array::from_fn(|k| -(a[k] - b[k]) / (2.0 * h)))
            .collect();
        let rel = max_diff(&kv, &fd) / max_abs(&kv);
        println!(
            "{kind:?}: stiffness vs finite differences of the forces, max relative difference {rel:.1e}"
        );
        assert!(rel <= 1e-6, "{kind:?}: {rel:e}");
        for n in (0..model.vertex_count()).step_by(13) {
            for k in 0..3 {
                let mut xp = x.clone();
                xp[n][k] += h;
                let mut xm = x.clone();
                xm[n][k] -= h;
                let fd = -(tm.energy(model, &xp) - tm.energy(model, &xm)) / (2.0 * h);
                assert!(
                    (fd - f[n][k]).abs() <= 1e-6 * scale,
                    "{kind:?} node {n} axis {k}: {fd} vs {}",
                    f[n][k]
                );
            }
        }
    }
}

#[test]
fn svk_is_rotation_invariant_and_the_linear_model_is_not() {
    let (mesh, model) = small_cylinder();
    let topo = TetTopology::new(&mesh);
    // The force scale: a 10 % stretch.
    let stretched: Vec<Vec3> = model.rest.iter().map(|p| [p[0], p[1], 1.1 * p[2]]).collect();
    println!("rotation (deg) | linear |f| / |f(10 % stretch)| | SVK");
    for degrees in [10.0f64, 45.0, 90.0] {
        let r = axis_angle(&[1.0, 0.0, 0.0], degrees.to_radians());
        let rotated: Vec<Vec3> = model.rest.iter().map(|p| mul_vec(&r, p)).collect();
        let mut ratios = [0.0; 2];
        for (i, kind) in [Elasticity::Linear, Elasticity::StVenantKirchhoff].into_iter().enumerate()
        {
            let tm = TensorMassForceField::new(&model, &topo, kind);
            let mut reference = vec![[0.0; 3]; model.vertex_count()];
            tm.add_forces(&model, &stretched, &mut reference);
            let mut f = vec![[0.0; 3]; model.vertex_count()];
            tm.add_forces(&model, &rotated, &mut f);
            ratios[i] = max_abs(&f) / max_abs(&reference);
        }
        println!("{degrees:>14} | {:>34.3} | {:.1e}", ratios[0], ratios[1]);
        // SVK: zero to rounding (the displacement is of the order of the size, forces cancel).
        assert!(ratios[1] < 1e-9, "SVK under a rigid rotation: {}", ratios[1]);
        // Linear: a rigid rotation strains it like a stretch of comparable size.
        assert!(ratios[0] > 0.05, "linear under a rigid rotation: {}", ratios[0]);
    }
}

/// A random label volume (foreground where `bits` says) tetrahedralised at level 0.
fn random_mesh(dims: [usize; 3], bits: &[bool]) -> Option<TetMesh> {
    let labels: Vec<u16> = bits.iter().map(|&b| u16::from(b)).collect();
    let v = LabelVolume::new(dims, [0.01; 3], labels).ok()?;
    from_volume(&v, 0).ok()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn removing_tetrahedra_equals_building_without_them(
        bits in proptest::collection::vec(prop::bool::weighted(0.8), 27),
        order in proptest::collection::vec(any::<prop::sample::Index>(), 1..40),
        svk in any::<bool>(),
    ) {
        let Some(mesh) = random_mesh([3, 3, 3], &bits) else { return Ok(()) };
        let kind = if svk { Elasticity::StVenantKirchhoff } else { Elasticity::Linear };
        let model = TetModel::new(&mesh, material);
        let mut topo = TetTopology::new(&mesh);
        let mut tm = TensorMassForceField::new(&model, &topo, kind);
        let x: Vec<Vec3> = model.rest.iter().enumerate()
            .map(|(i, p)| [p[0] + 0.002 * ((i % 5) as f64 - 2.0), p[1] * 1.1, p[2] - 0.003 * ((i % 3) as f64)])
            .collect();
        for idx in &order {
            let t = idx.index(mesh.tets().len());
            let removed = tm.remove_tet(&model, &mut topo, t);
            prop_assert!(removed.is_empty() || removed[0] == t);
            prop_assert!(check_closed(&topo.boundary()).is_ok());
        }
        let fresh = TensorMassForceField::new(&model, &topo, kind);
        let mut a = vec![[0.0; 3]; model.vertex_count()];
        tm.add_forces(&model, &x, &mut a);
        let mut b = vec![[0.0; 3]; model.vertex_count()];
        fresh.add_forces(&model, &x, &mut b);
        let mut c = vec![[0.0; 3]; model.vertex_count()];
        model.add_forces(|t| topo.is_alive(t), &x, kind, &mut c);
        let scale = max_abs(&c).max(f64::MIN_POSITIVE);
        // Subtraction leaves rounding of the removed terms' size: 1e-12 of the force scale.
        prop_assert!(max_diff(&a, &b) <= 1e-12 * scale, "{} vs {}", max_diff(&a, &b), scale);
        prop_assert!(max_diff(&a, &c) <= 1e-10 * scale, "{} vs {}", max_diff(&a, &c), scale);
    }

    #[test]
    fn cuts_keep_a_manifold_boundary_manifold(
        order in proptest::collection::vec(any::<prop::sample::Index>(), 1..80),
    ) {
        // A full 4 × 3 × 3 block: its boundary starts manifold, and every cut (with the
        // tetrahedra it leaves hanging by an edge or a vertex, or ringed around a tunnel through a
        // vertex) keeps it a closed manifold: every edge in exactly two triangles, the triangles
        // around every vertex one fan, no group of tetrahedra joined to the rest by a vertex.
        let v = LabelVolume::new([4, 3, 3], [0.01; 3], vec![1; 36]).unwrap();
        let mesh = from_volume(&v, 0).unwrap();
        let mut topo = TetTopology::new(&mesh);
        prop_assert!(check_manifold(&topo.boundary()).is_ok());
        for idx in &order {
            topo.cut(idx.index(mesh.tets().len()));
            let surface = topo.boundary();
            prop_assert!(check_closed(&surface).is_ok());
            prop_assert!(check_manifold(&surface).is_ok(), "{:?}", check_manifold(&surface));
            for v in 0..topo.vertex_count() as u32 {
                prop_assert!(topo.vertex_groups(v) <= 1, "vertex {v} joins groups by itself");
            }
        }
    }
}

mod explicit {
    use super::*;
    use incise_fem::FixedNodes;
    use incise_fem::forcefield::tet::incompressible::Incompressibility;
    use incise_fem::ode::central_difference::{CentralDifference, StepTooLarge};

    #[test]
    fn a_step_above_the_stable_one_is_refused() {
        let (mesh, model) = small_cylinder();
        let topo = TetTopology::new(&mesh);
        let ff = TensorMassForceField::new(&model, &topo, Elasticity::StVenantKirchhoff);
        let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-9);
        let ok = CentralDifference::new(&model, &ff, &fixed, &model.rest, 1e-5, 0.0).unwrap();
        println!("stable explicit step: {:.3e} s", ok.stable_dt);
        let err: StepTooLarge =
            CentralDifference::new(&model, &ff, &fixed, &model.rest, 10.0 * ok.stable_dt, 0.0)
                .unwrap_err();
        assert!(err.to_string().contains("above the stable explicit step"), "{err}");
    }

    /// Total energy over 10⁴ undamped steps at the stable step, released from a 10 % stretch with
    /// a sideways bend; returns the largest relative deviation from the start.
    fn energy_deviation(kind: Elasticity, penalty: Option<Incompressibility>) -> f64 {
        let mesh = cylinder(0.01, 0.03, 2, 3);
        let model = TetModel::new(&mesh, material);
        let topo = TetTopology::new(&mesh);
        let ff = TensorMassForceField::new(&model, &topo, kind);
        let fixed = FixedNodes::plane(&model.rest, 2, 0.0, 1e-9);
        let mut x: Vec<Vec3> = model
            .rest
            .iter()
            .map(|p| [p[0] + 0.1 * p[2] * p[2] / 0.03, p[1], 1.1 * p[2]])
            .collect();
        let stable = incise_fem::ode::central_difference::stable_dt(&model, &ff, &fixed);
        let mut cd = CentralDifference::new(&model, &ff, &fixed, &x, stable, 0.0).unwrap();
        let energy = |x: &[Vec3], cd: &CentralDifference| {
            let v = cd.velocities(x);
            let kinetic: f64 = v
                .iter()
                .zip(&model.lumped_mass)
                .map(|(v, m)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
                .sum();
            let pen = penalty.map_or(0.0, |p| p.energy(&model, |_| true, x));
            kinetic + ff.energy(&model, x) + pen
        };
        let e0 = energy(&x, &cd);
        let mut worst = 0.0f64;
        for _ in 0..10_000 {
            cd.step(&model, &topo, &ff, penalty.as_ref(), &fixed, &[], &mut x);
            let e = energy(&x, &cd);
            assert!(e.is_finite(), "{kind:?}: non-finite energy");
            worst = worst.max((e - e0).abs() / e0);
        }
        println!(
            "{kind:?}{}: 10^4 steps at dt = {stable:.3e} s, largest energy deviation {:.2} %",
            if penalty.is_some() { " + incompressibility" } else { "" },
            100.0 * worst
        );
        worst
    }

    #[test]
    fn undamped_energy_stays_bounded_over_ten_thousand_steps() {
        // Central differences conserve a shadow energy; the energy measured with the backward
        // velocity oscillates around it by O(ω dt), tens of percent near the stability limit, but
        // does not grow: an instability multiplies it within a few hundred steps.
        let linear = energy_deviation(Elasticity::Linear, None);
        assert!(linear < 0.5, "linear: {linear}");
        let svk = energy_deviation(
            Elasticity::StVenantKirchhoff,
            Some(Incompressibility { kappa: 3_000.0 }),
        );
        assert!(svk < 0.5, "SVK + incompressibility: {svk}");
    }

    #[test]
    fn the_penalty_is_minus_the_gradient_of_its_energy() {
        let (mesh, model) = small_cylinder();
        let _ = mesh;
        let penalty = Incompressibility { kappa: 5_000.0 };
        let x = deformed(&model.rest);
        let mut f = vec![[0.0; 3]; model.vertex_count()];
        penalty.add_forces(&model, |_| true, &x, &mut f);
        let scale = max_abs(&f);
        let h = 1e-7;
        for n in (0..model.vertex_count()).step_by(11) {
            for k in 0..3 {
                let (mut xp, mut xm) = (x.clone(), x.clone());
                xp[n][k] += h;
                xm[n][k] -= h;
                let fd = -(penalty.energy(&model, |_| true, &xp)
                    - penalty.energy(&model, |_| true, &xm))
                    / (2.0 * h);
                assert!(
                    (fd - f[n][k]).abs() <= 1e-6 * scale,
                    "node {n} axis {k}: {fd} vs {}",
                    f[n][k]
                );
            }
        }
    }
}

mod adaptive {
    use super::*;

    fn forces(tm: &TensorMassForceField, model: &TetModel, x: &[Vec3]) -> Vec<u64> {
        let mut f = vec![[0.0; 3]; model.vertex_count()];
        tm.add_forces(model, x, &mut f);
        f.iter().flatten().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn thresholds_at_the_limits_give_the_full_models() {
        let (mesh, model) = small_cylinder();
        let topo = TetTopology::new(&mesh);
        // Every vertex moves, so at threshold 0 every tetrahedron is non-linear.
        let x: Vec<Vec3> =
            deformed(&model.rest).iter().map(|p| [p[0] + 1e-6, p[1], p[2]]).collect();
        let svk = TensorMassForceField::new(&model, &topo, Elasticity::StVenantKirchhoff);
        let linear = TensorMassForceField::new(&model, &topo, Elasticity::Linear);
        let mut all = svk.clone();
        all.enable_adaptive(&model, 0.0, 0.1);
        assert_eq!(all.update_adaptive(&model, &topo, &x), model.vertex_count());
        let mut none = svk.clone();
        none.enable_adaptive(&model, 1.0, 0.1);
        assert_eq!(none.update_adaptive(&model, &topo, &x), 0);
        assert_eq!(none.nonlinear_count(), 0);
        // All non-linear: the tables are rebuilt tetrahedron by tetrahedron in another order, so
        // equal to rounding; none: only the linear tensors remain, bit for bit.
        let (a, b) = (forces_of(&all, &model, &x), forces_of(&svk, &model, &x));
        assert!(max_diff(&a, &b) <= 1e-12 * max_abs(&b), "{}", max_diff(&a, &b) / max_abs(&b));
        assert_eq!(forces(&none, &model, &x), forces(&linear, &model, &x));
    }

    fn forces_of(tm: &TensorMassForceField, model: &TetModel, x: &[Vec3]) -> Vec<Vec3> {
        let mut f = vec![[0.0; 3]; model.vertex_count()];
        tm.add_forces(model, x, &mut f);
        f
    }

    #[test]
    fn an_adaptive_pull_stays_stable_and_close_to_full_svk() {
        // The top centre of the cylinder pulled sideways by a quarter of the height; threshold
        // 2 mm (7 % of the height). The mixed model is conservative, so it is as stable as SVK.
        let mesh = cylinder(0.01, 0.03, 4, 12);
        let model = TetModel::new(&mesh, material);
        let topo = TetTopology::new(&mesh);
        let top = incise_mesh::generate::cylinder_top_centre(&mesh);
        let fixed = incise_fem::FixedNodes::plane(&model.rest, 2, 0.0, 1e-12).with(top);
        let run = |adaptive: bool| -> (Vec<Vec3>, usize) {
            let mut ff = TensorMassForceField::new(&model, &topo, Elasticity::StVenantKirchhoff);
            if adaptive {
                ff.enable_adaptive(&model, 0.002, 0.2);
            }
            let dt = incise_fem::ode::central_difference::stable_dt(&model, &ff, &fixed);
            let mut x = model.rest.clone();
            let mut cd = incise_fem::ode::central_difference::CentralDifference::new(
                &model, &ff, &fixed, &x, dt, 5.0,
            )
            .unwrap();
            let mut count = 0;
            for step in 1..=6_000 {
                x[top][0] = model.rest[top][0] + 0.0075 * (f64::from(step) / 6_000.0);
                count = ff.update_adaptive(&model, &topo, &x);
                cd.step(&model, &topo, &ff, None, &fixed, &[], &mut x);
            }
            (x, count)
        };
        let (full, _) = run(false);
        let (adaptive, count) = run(true);
        assert!(adaptive.iter().flatten().all(|c| c.is_finite()));
        let err = max_diff(&full, &adaptive) / 0.0075;
        println!(
            "adaptive pull: {count} of {} vertices non-linear, max difference {:.2} % of the pull",
            model.vertex_count(),
            100.0 * err
        );
        assert!(count > 0 && count < model.vertex_count());
        // The linear tetrahedra move less than the threshold, where SVK and linear differ by
        // a few percent of their displacement.
        assert!(err < 0.05, "{err}");
    }

    #[test]
    fn hysteresis_keeps_a_vertex_from_flickering() {
        let (mesh, model) = small_cylinder();
        let topo = TetTopology::new(&mesh);
        let mut tm = TensorMassForceField::new(&model, &topo, Elasticity::StVenantKirchhoff);
        tm.enable_adaptive(&model, 1e-3, 0.2);
        let at = |d: f64| -> Vec<Vec3> {
            let mut x = model.rest.clone();
            x[5][0] += d;
            x
        };
        assert_eq!(
            tm.update_adaptive(&model, &topo, &at(0.9e-3)),
            0,
            "below the threshold: linear"
        );
        assert_eq!(tm.update_adaptive(&model, &topo, &at(1.1e-3)), 1, "above: non-linear");
        assert_eq!(
            tm.update_adaptive(&model, &topo, &at(0.9e-3)),
            1,
            "inside the band: stays non-linear"
        );
        assert_eq!(tm.update_adaptive(&model, &topo, &at(0.7e-3)), 0, "below 80 %: linear again");
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        // Large enough for the two-thread path (≥ 20,000 cubic and quartic terms).
        let mesh = cylinder(0.01, 0.03, 6, 9);
        let model = TetModel::new(&mesh, material);
        let topo = TetTopology::new(&mesh);
        let field = |threads| {
            TensorMassForceField::new(&model, &topo, Elasticity::StVenantKirchhoff)
                .with_executor(incise_fem::Executor::new(threads, incise_fem::Idle::DEFAULT_SPIN))
        };
        let (one, two) = (field(1), field(2));
        let (_, _, cubic, quartic) = one.term_counts();
        assert!(cubic + quartic >= 20_000, "{cubic} + {quartic}");
        let x = deformed(&model.rest);
        assert_eq!(forces(&one, &model, &x), forces(&two, &model, &x));
    }
}
