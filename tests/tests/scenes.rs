//! The committed scene files (`deploy/scenes/*.toml`) through `incise_scene::read_scene` and
//! `incise_sim::Simulation`, and the errors a broken scene file gets.

use incise_math::Vec3;
use incise_sim::config::{ElementKind, HexSpec, Level, Model};
use incise_sim::{InputError, SceneConfig, Simulation, StepInputs};
use incise_tests::scene;

fn load(name: &str) -> Simulation {
    let path = scene(name);
    let scene = incise_scene::read_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    Simulation::new(&scene.config, &scene.geometry, &path.display().to_string())
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn every_committed_scene_builds() {
    let dir = scene("");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| {
            std::path::Path::new(n).extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"))
        })
        .collect();
    names.sort();
    assert!(names.len() >= 9, "{names:?}");
    for name in names {
        let sim = load(&name);
        let (elements, nodes) = match (sim.model(), sim.tet()) {
            (Some(m), _) => (m.elements.len(), m.node_count()),
            (None, Some(t)) => (t.topology.live_count(), t.model.vertex_count()),
            (None, None) => unreachable!("a scene is hexahedral or tetrahedral"),
        };
        println!(
            "{name:<22} level {:>2} {elements:>6} elements {nodes:>6} nodes {:>5} fixed",
            sim.config().level().map_or_else(|| "-".to_owned(), |l| l.to_string()),
            sim.fixed().count()
        );
        assert!(sim.fixed().count() > 0, "{name}: nothing is fixed");
    }
}

#[test]
fn scene_b1_steps_deterministically() {
    let mut a = load("b1.toml");
    let mut b = load("b1.toml");
    for _ in 0..50 {
        let (fa, fb) =
            (a.step(&StepInputs::default()).unwrap(), b.step(&StepInputs::default()).unwrap());
        assert_eq!(fa.state_hash, fb.state_hash, "step {}", fa.index);
        assert!(fa.positions.iter().all(|p| p.iter().all(|c| c.is_finite())));
    }
    assert_eq!(a.model().expect("a hexahedral scene").elements.len(), 140);
    assert_eq!(a.model().expect("a hexahedral scene").node_count(), 240);
}

#[test]
fn cantilever_scene_reaches_beam_theory() {
    let mut sim = load("c_80x8x8.toml");
    let frame = sim.step(&StepInputs::default()).unwrap();
    let rest = &sim.model().expect("a hexahedral scene").rest;
    let tip: Vec<f64> = rest
        .iter()
        .zip(&frame.positions)
        .filter(|(p, _)| (p[0] - 0.1).abs() < 1e-9)
        .map(|(p, q)| p[2] - q[2])
        .collect();
    let d = tip.iter().sum::<f64>() / tip.len() as f64;
    assert!((d - 14.715e-3).abs() <= 0.02 * 14.715e-3, "tip deflection {:.3} mm", d * 1e3);
}

/// A 2 × 2 × 2 block hanging from its top face: the smallest valid scene, shared with `incise_sim`'s config tests.
const GOOD: &str = include_str!("../../server/incise_sim/tests/data/minimal_block.toml");

#[test]
fn a_static_scene_solves_with_the_solver_it_names() {
    let text = GOOD
        .replace("kind = \"implicit-euler\"", "kind = \"static\"\ncg_tolerance = 1e-10")
        .replace("voxels = [2, 2, 2]", "voxels = [4, 3, 3]");
    let solve = |solver: &str| {
        let config = SceneConfig::from_toml(
            &text.replace("cg_tolerance", &format!("solver = \"{solver}\"\ncg_tolerance")),
            "s.toml",
        )
        .unwrap();
        let volume = config.procedural_volume().unwrap();
        let mut sim = Simulation::new(&config, &volume, "s.toml").unwrap();
        let frame = sim.step(&StepInputs::default()).unwrap();
        let iterations = frame.counters.solver_iterations;
        (frame.positions, iterations)
    };
    let (jacobi, jacobi_iterations) = solve("jacobi-cg");
    let (cholesky, cholesky_iterations) = solve("cholesky");
    // Both converge to 1e-10 of the load's residual: positions agree far below the sag (~mm).
    let sag = jacobi.iter().zip(&cholesky).map(|(a, b)| (a[2] - b[2]).abs()).fold(0.0, f64::max);
    assert!(sag < 1e-9, "jacobi and cholesky differ by {sag:e} m");
    // The factorisation preconditions: far fewer CG iterations than block-Jacobi.
    assert!(
        cholesky_iterations * 3 < jacobi_iterations,
        "{cholesky_iterations} vs {jacobi_iterations} iterations"
    );
    // Nothing held: the stiffness is singular and cannot be factorised. The step falls back to
    // block-Jacobi, does not converge (a free body under gravity has no equilibrium), and returns.
    let free = text
        .replace("[[fixed]]\nplane = \"z\"\nvalue = 0.1\n", "")
        .replace("cg_tolerance", "solver = \"cholesky\"\ncg_tolerance");
    let config = SceneConfig::from_toml(&free, "free.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut sim = Simulation::new(&config, &volume, "free.toml").unwrap();
    let frame = sim.step(&StepInputs::default()).unwrap();
    println!("free static step: {:?}", frame.counters);
    assert!(frame.counters.solver_residual > 1e-10, "{:?}", frame.counters);
    // Block-Jacobi ran (a factor would have taken a handful of iterations per Newton step).
    assert!(frame.counters.solver_iterations > 10 * cholesky_iterations, "{:?}", frame.counters);
}

#[test]
fn a_step_is_driven_by_its_inputs_and_refuses_bad_ones() {
    // B1 (gravity and its corner pull) twice: once with a push on a bottom corner, once without.
    let text = std::fs::read_to_string(scene("b1.toml")).unwrap();
    let config = SceneConfig::from_toml(&text, "b1.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut pushed = Simulation::new(&config, &volume, "b1.toml").unwrap();
    let mut still = Simulation::new(&config, &volume, "b1.toml").unwrap();
    let rest = pushed.model().unwrap().rest.clone();
    // The bottom corner at x = 0, y = 0 (the top face is held, the pull is at the far corner).
    let corner = (0..rest.len())
        .min_by(|&a, &b| {
            let key = |p: Vec3| p[0] + p[1] + p[2];
            key(rest[a]).total_cmp(&key(rest[b]))
        })
        .unwrap();
    let push = StepInputs {
        node_forces: vec![(corner, [0.0, 2.0, 0.0]), (corner, [0.0, 1.0, 0.0])],
        ..StepInputs::default()
    };
    let none = StepInputs::default();
    for _ in 0..20 {
        let a = pushed.step(&push).unwrap();
        let b = still.step(&none).unwrap();
        assert_eq!(a.index, b.index);
    }
    let a = pushed.step(&none).unwrap();
    let b = still.step(&none).unwrap();
    // 3 N along +y for 20 ms: the corner moved along +y, and only the input made it move so.
    let dy = a.positions[corner][1] - b.positions[corner][1];
    assert!(dy > 1e-5, "the pushed corner moved {dy:e} m along y");
    // The same inputs again give the same bits.
    let mut again = Simulation::new(&config, &volume, "b1.toml").unwrap();
    let mut last = None;
    for _ in 0..20 {
        last = Some(again.step(&push).unwrap());
    }
    let replay = again.step(&none).unwrap();
    assert_eq!(replay.state_hash, a.state_hash);
    assert!(last.is_some());

    // Bad inputs are refused with what and where, and take no step: the refused simulation
    // goes on exactly as a twin that was never given them.
    let mut twin = Simulation::new(&config, &volume, "b1.toml").unwrap();
    for _ in 0..20 {
        twin.step(&push).unwrap();
    }
    twin.step(&none).unwrap();
    let before = pushed.step(&none).unwrap();
    assert_eq!(twin.step(&none).unwrap().state_hash, before.state_hash);
    let nodes = rest.len();
    let e = pushed.step(&StepInputs {
        node_forces: vec![(0, [0.0; 3]), (nodes, [1.0, 0.0, 0.0])],
        ..StepInputs::default()
    });
    assert_eq!(e, Err(InputError::NoSuchNode { entry: 1, node: nodes, nodes }));
    assert!(e.unwrap_err().to_string().contains("node_forces[1]"));
    let e = pushed
        .step(&StepInputs { node_forces: vec![(3, [0.0, f64::NAN, 0.0])], ..StepInputs::default() })
        .unwrap_err();
    assert!(matches!(e, InputError::NotFinite { entry: 0, node: 3, .. }), "{e}");
    assert!(e.to_string().contains("not finite"), "{e}");
    let after = pushed.step(&none).unwrap();
    assert_eq!(after.index, before.index + 1, "a refused step is not counted");
    assert_eq!(
        after.state_hash,
        twin.step(&none).unwrap().state_hash,
        "nor does it change the state"
    );
}

#[test]
fn explicit_scene_above_its_stability_limit_is_refused() {
    let text = GOOD
        .replace("kind = \"implicit-euler\"", "kind = \"explicit\"")
        .replace("dt = 0.001", "dt = 0.5");
    let config = SceneConfig::from_toml(&text, "x.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let err = Simulation::new(&config, &volume, "x.toml").err().expect("refused");
    assert!(err.to_string().contains("stability limit"), "{err}");
}

#[test]
fn auto_model_runs_on_the_coarsest_level_within_its_error() {
    let sim = load("liver_auto.toml");
    let c = sim.calibration().expect("auto scenes calibrate");
    for l in &c.levels {
        println!(
            "level {} {:<12} {:>6} elements {:>6} dofs  estimated error {:6.2} %",
            l.level,
            l.element.name(),
            l.elements,
            l.dofs,
            100.0 * l.error
        );
    }
    println!(
        "chosen level {} with {} elements (max_error {} %)",
        c.chosen,
        c.chosen_element.name(),
        100.0 * c.max_error
    );
    assert_eq!(c.reference_level, 0, "level 0 of the 13k liver is affordable");
    assert!(c.chosen > 0, "the scene's 40 % bound admits a coarser level");
    assert_eq!(sim.config().level(), Some(c.chosen));
    let Model::Hexahedra(hex) = &sim.config().model else { panic!("hexahedra") };
    assert_eq!(hex.element, c.chosen_element, "the scene runs the chosen kind");
    // Every kind at every coarse level, one model at level 0 (the kinds coincide there).
    for level in 1..=3 {
        let kinds: Vec<_> =
            c.levels.iter().filter(|l| l.level == level).map(|l| l.element).collect();
        assert_eq!(kinds, ElementKind::ALL, "level {level}");
    }
    let chosen =
        c.levels.iter().find(|l| (l.level, l.element) == (c.chosen, c.chosen_element)).unwrap();
    assert!(chosen.error <= c.max_error);
    // The coarsest within the error: every kind at every coarser level misses it, and so does
    // every kind before the chosen one at its level (the cheaper ones to cut).
    assert!(c.levels.iter().filter(|l| l.level > c.chosen).all(|l| l.error > c.max_error));
    let before = ElementKind::ALL.iter().position(|&k| k == c.chosen_element).unwrap();
    assert!(
        c.levels
            .iter()
            .filter(|l| l.level == c.chosen && ElementKind::ALL[..before].contains(&l.element))
            .all(|l| l.error > c.max_error)
    );
    assert!(c.levels.iter().any(|l| l.level == 0 && l.error == 0.0));
    // A looser bound never picks a finer level.
    let path = scene("liver_auto.toml");
    let incise_scene::Scene { mut config, geometry, .. } = incise_scene::read_scene(&path).unwrap();
    let mut bound = |max_error: f64| {
        let Model::Hexahedra(HexSpec { level: Level::Auto(auto), .. }) = &mut config.model else {
            panic!("liver_auto.toml chooses its level")
        };
        auto.max_error = max_error;
        let sim = Simulation::new(&config, &geometry, &path.display().to_string()).unwrap();
        let Model::Hexahedra(hex) = &sim.config().model else { panic!("hexahedra") };
        (sim.config().level().unwrap(), hex.element)
    };
    assert!(bound(0.95).0 >= c.chosen);
    // A bound that at some level only an enriched kind meets, and no coarser level does: the
    // scene runs that kind there.
    let error_of = |level: u32, kind: ElementKind| {
        c.levels.iter().find(|l| (l.level, l.element) == (level, kind)).unwrap().error
    };
    let (level, kind, error) = (1..=3)
        .rev()
        .flat_map(|level| {
            ElementKind::ALL[1..].iter().map(move |&kind| (level, kind, error_of(level, kind)))
        })
        .find(|&(level, _, error)| {
            error < error_of(level, ElementKind::Condensed)
                && c.levels.iter().filter(|l| l.level > level).all(|l| l.error > error)
        })
        .expect("an enriched kind beats the condensed one somewhere");
    assert_eq!(bound(error), (level, kind), "bound {error}");
    println!("max_error {:.2} % runs level {level} with {} elements", 100.0 * error, kind.name());
    // And a tight one runs on the reference level.
    assert_eq!(bound(1e-3).0, 0);
}

#[test]
fn an_auto_scene_without_a_support_is_refused() {
    // Without a support there is no static solve to calibrate with.
    let free = GOOD
        .replace("[integrator]", "[model]\nkind = \"auto\"\n[integrator]")
        .replace("[[fixed]]\nplane = \"z\"\nvalue = 0.1\n", "");
    let config = SceneConfig::from_toml(&free, "free.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let err = Simulation::new(&config, &volume, "free.toml").err().expect("refused");
    assert!(err.to_string().contains("fixed"), "{err}");
}

/// `GOOD` as a tensor-mass scene (48 tetrahedra on 2 × 2 × 2 voxels).
fn tensor_mass_scene(model_keys: &str, dt: &str) -> String {
    GOOD.replace(
        "[integrator]\nkind = \"implicit-euler\"\ndt = 0.001",
        &format!("[model]\nkind = \"tensor-mass\"\n{model_keys}[integrator]\nkind = \"explicit\"\ndt = {dt}"),
    )
}

#[test]
fn a_tensor_mass_step_is_driven_by_its_inputs_too() {
    let text = tensor_mass_scene("elasticity = \"linear\"\n", "0.0001");
    let config = SceneConfig::from_toml(&text, "tm.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut pushed = Simulation::new(&config, &volume, "tm.toml").unwrap();
    let mut still = Simulation::new(&config, &volume, "tm.toml").unwrap();
    let rest = pushed.tet().unwrap().model.rest.clone();
    // The vertex at the origin: on the bottom face, away from the held top (z = 0.1).
    let vertex = (0..rest.len()).find(|&v| rest[v] == [0.0, 0.0, 0.0]).unwrap();
    let push = StepInputs { node_forces: vec![(vertex, [0.0, 0.5, 0.0])], ..StepInputs::default() };
    let none = StepInputs::default();
    for _ in 0..20 {
        pushed.step(&push).unwrap();
        still.step(&none).unwrap();
    }
    // 0.5 N for 2 ms on a vertex of a few grams: micrometres, far above rounding.
    let dy = pushed.state().x[vertex][1] - still.state().x[vertex][1];
    assert!(dy > 1e-7, "the pushed vertex moved {dy:e} m along y");
    let e = pushed
        .step(&StepInputs { node_forces: vec![(rest.len(), [0.0; 3])], ..StepInputs::default() })
        .unwrap_err();
    assert!(matches!(e, InputError::NoSuchNode { node, .. } if node == rest.len()), "{e}");
    let e = pushed.step(&StepInputs {
        node_forces: vec![(vertex, [f64::INFINITY, 0.0, 0.0])],
        ..StepInputs::default()
    });
    assert!(matches!(e, Err(InputError::NotFinite { node, .. }) if node == vertex), "{e:?}");
    // Neither refusal changed anything: both go on with the same step on the same state.
    let (a, b) = (pushed.step(&none).unwrap(), still.step(&none).unwrap());
    assert_eq!(a.index, b.index);
    let mut twin = Simulation::new(&config, &volume, "tm.toml").unwrap();
    for _ in 0..20 {
        twin.step(&push).unwrap();
    }
    assert_eq!(twin.step(&none).unwrap().state_hash, a.state_hash);
}

/// Paper 2's explicit scheme cannot step tensor-mass tetrahedra at 10 ms; implicit Euler through
/// the same force-field interface as the hexahedra can, and comes to rest where the explicit
/// scheme does (both settle on the static equilibrium: the implicit step's force balance holds to
/// its CG tolerance, 1e-9 here, and the explicit run's motion has decayed by e⁻⁸⁰).
#[test]
fn implicit_tensor_mass_is_stable_at_10_ms_and_settles_where_the_explicit_scheme_does() {
    let scene = |kind: &str, dt: &str| {
        tensor_mass_scene("elasticity = \"svk\"\nincompressibility = 1e5\n", dt)
            .replace("youngs_modulus = 1000.0", "youngs_modulus = 100000.0")
            .replace("kind = \"explicit\"", &format!("kind = \"{kind}\""))
            .replace(&format!("dt = {dt}"), &format!("dt = {dt}\nrayleigh_alpha = 40.0"))
    };
    let build = |text: &str| {
        let config = SceneConfig::from_toml(text, "tm.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        Simulation::new(&config, &volume, "tm.toml")
    };
    let err = build(&scene("explicit", "0.01")).err().expect("10 ms is above the stable step");
    assert!(err.to_string().contains("stable explicit step"), "{err}");
    let settle = |sim: &mut Simulation, steps: usize| {
        let mut peak = 0.0f64;
        for _ in 0..steps {
            let frame = sim.step(&StepInputs::default()).unwrap();
            assert!(frame.positions.iter().flatten().all(|c| c.is_finite()));
            let rest = &sim.tet().unwrap().model.rest;
            for (p, q) in frame.positions.iter().zip(rest) {
                peak = peak.max((0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt());
            }
        }
        (sim.state().x.clone(), peak)
    };
    let mut implicit = build(
        &scene("implicit-euler", "0.01")
            .replace("rayleigh_alpha = 40.0", "rayleigh_alpha = 40.0\ncg_tolerance = 1e-9"),
    )
    .unwrap();
    assert_eq!(implicit.explicit_stable_dt(), None);
    let (x_implicit, peak) = settle(&mut implicit, 200);
    let mut explicit = build(&scene("explicit", "0.0001")).unwrap();
    let (x_explicit, _) = settle(&mut explicit, 20_000);
    let rest = &implicit.tet().unwrap().model.rest;
    let sag = x_explicit.iter().zip(rest).map(|(p, q)| (q[2] - p[2]).abs()).fold(0.0, f64::max);
    let gap = x_implicit
        .iter()
        .zip(&x_explicit)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    println!(
        "sag {:.3} mm, implicit vs explicit at rest {gap:.2e} m, implicit peak {:.3} mm",
        sag * 1e3,
        peak * 1e3
    );
    assert!(sag > 1e-4, "the block sags under its weight ({sag:e} m)");
    assert!(gap <= 1e-6 * sag, "implicit and explicit rest {gap:e} m apart (sag {sag:e} m)");
    // Bounded: a 10 ms step that overshoots a little is fine, one that blows up is not.
    assert!(peak <= 3.0 * sag, "peak displacement {peak:e} m against a sag of {sag:e} m");
}

#[test]
fn a_tensor_mass_step_above_its_stable_step_is_refused() {
    let config = SceneConfig::from_toml(&tensor_mass_scene("", "0.5"), "tm.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let err = Simulation::new(&config, &volume, "tm.toml").err().expect("refused");
    assert!(
        err.to_string().contains("integrator.dt")
            && err.to_string().contains("stable explicit step"),
        "{err}"
    );
}

#[test]
fn a_tensor_mass_scene_steps_cuts_and_reports_non_linear_vertices() {
    let text = tensor_mass_scene("incompressibility = 1e5\nadaptive_threshold = 1e-4\n", "1e-4");
    let config = SceneConfig::from_toml(&text, "tm.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut a = Simulation::new(&config, &volume, "tm.toml").unwrap();
    let mut b = Simulation::new(&config, &volume, "tm.toml").unwrap();
    let tet = a.tet().expect("a tensor-mass scene");
    assert_eq!(tet.topology.live_count(), 48);
    println!("stable explicit step of the 48-tetrahedron block: {:.3e} s", tet.stable_dt);
    assert!(a.model().is_none() && a.grid().is_none());
    let mut last = None;
    for _ in 0..200 {
        let (fa, fb) =
            (a.step(&StepInputs::default()).unwrap(), b.step(&StepInputs::default()).unwrap());
        assert_eq!(fa.state_hash, fb.state_hash, "step {}", fa.index);
        assert!(fa.positions.iter().flatten().all(|c| c.is_finite()));
        last = Some(fa);
    }
    let last = last.unwrap();
    // Hanging under gravity, the bottom moves more than the 0.1 mm threshold.
    assert!(last.counters.nonlinear_vertices > 0, "{:?}", last.counters);
    assert!(last.counters.nonlinear_vertices < a.tet().unwrap().model.vertex_count());
    // Removing voxel 0 removes its cell's 6 tetrahedra; an index beyond the volume is refused.
    let edit = incise_grid::GridEdit { remove_voxels: vec![0], sever_links: vec![] };
    a.cut(&edit).unwrap();
    assert_eq!(a.tet().unwrap().topology.live_count(), 42);
    let bad = incise_grid::GridEdit { remove_voxels: vec![8], sever_links: vec![] };
    assert!(a.cut(&bad).is_err());
    for _ in 0..50 {
        assert!(
            a.step(&StepInputs::default())
                .unwrap()
                .positions
                .iter()
                .flatten()
                .all(|c| c.is_finite())
        );
    }
}

#[test]
fn the_liver_tensor_mass_scene_runs() {
    let mut sim = load("liver_tensor_mass.toml");
    let tet = sim.tet().expect("a tensor-mass scene");
    println!(
        "liver_tensor_mass: {} tetrahedra, {} vertices, stable step {:.3e} s",
        tet.topology.live_count(),
        tet.model.vertex_count(),
        tet.stable_dt
    );
    for _ in 0..20 {
        let f = sim.step(&StepInputs::default()).unwrap();
        assert!(f.positions.iter().flatten().all(|c| c.is_finite()));
    }
}

/// GOOD with its plane support replaced by `fixed`.
fn held_by(fixed: &str) -> String {
    GOOD.replace("[[fixed]]\nplane = \"z\"\nvalue = 0.1\n", &format!("[[fixed]]\n{fixed}\n"))
}

#[test]
fn label_holds_hold_what_the_volume_has() {
    // A material the volume does not contain holds nothing: refused when the scene is built.
    let text = held_by("label = 2").replace(
        "[integrator]",
        "[[materials]]\nlabel = 2\nyoungs_modulus = 1000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n[integrator]",
    );
    let config = SceneConfig::from_toml(&text, "t.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let err = Simulation::new(&config, &volume, "t.toml").err().expect("refused");
    assert!(
        err.to_string().contains("fixed[0].label") && err.to_string().contains("label 2"),
        "{err}"
    );
    // Every voxel of the block has label 1: every node (hexahedra) or vertex (tetrahedra) is held.
    for text in [
        held_by("label = 1"),
        tensor_mass_scene("", "1e-4")
            .replace("[[fixed]]\nplane = \"z\"\nvalue = 0.1\n", "[[fixed]]\nlabel = 1\n"),
    ] {
        let config = SceneConfig::from_toml(&text, "t.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        let sim = Simulation::new(&config, &volume, "t.toml").unwrap();
        let nodes = sim.model().map_or_else(
            || sim.tet().unwrap().model.vertex_count(),
            incise_fem::HexModel::node_count,
        );
        assert_eq!(sim.fixed().count(), nodes);
    }
}

#[test]
fn the_liver_hangs_from_its_gallbladder() {
    // liver_13k.toml with its box support replaced by the gallbladder's label (85).
    let text = std::fs::read_to_string(scene("liver_13k.toml")).unwrap();
    let box_support = "[[fixed]]\nmin = [-1.0, -1.0, 0.17]\nmax = [1.0, 1.0, 1.0]";
    assert!(text.contains(box_support));
    let fixture = incise_tests::fixture("liver.inr.gz");
    let text = text
        .replace(box_support, "[[fixed]]\nlabel = 85")
        .replace("../../tests/data/liver.inr.gz", &fixture.display().to_string());
    let dir = std::env::temp_dir().join(format!("incise-label-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("liver_gallbladder.toml");
    std::fs::write(&path, text).unwrap();
    let scene = incise_scene::read_scene(&path).unwrap();
    let mut sim =
        Simulation::new(&scene.config, &scene.geometry, &path.display().to_string()).unwrap();
    // Held: exactly the nodes of the elements holding a gallbladder voxel.
    let (grid, model) = (sim.grid().unwrap(), sim.model().unwrap());
    let labels = grid.fine_labels();
    let mut expected = vec![false; model.node_count()];
    for e in &model.elements {
        if grid.element_voxels(e.grid_id).iter().any(|&v| labels[v as usize] == 85) {
            for &n in &e.nodes {
                expected[n as usize] = true;
            }
        }
    }
    let (held, nodes) = (expected.iter().filter(|&&f| f).count(), model.node_count());
    assert!(held > 0 && held < nodes);
    assert!((0..nodes).all(|n| sim.fixed().is_fixed(n) == expected[n]));
    // The centre of mass drops (node motion itself is no measure: an empty corner of a partly
    // filled coarse cell has almost no mass and swings with its cell).
    let mass = sim.model().unwrap().lumped_mass.clone();
    let total: f64 = mass.iter().sum();
    let first = sim.step(&StepInputs::default()).unwrap().positions.clone();
    let mut drop = 0.0;
    for _ in 0..30 {
        let frame = sim.step(&StepInputs::default()).unwrap();
        assert!(frame.positions.iter().flatten().all(|c| c.is_finite()));
        drop = frame
            .positions
            .iter()
            .zip(&first)
            .zip(&mass)
            .map(|((p, q), m)| m * (q[2] - p[2]))
            .sum::<f64>()
            / total;
    }
    assert!(drop > 1e-4, "the liver sags from its gallbladder (centre of mass {drop:e} m)");
    println!(
        "liver held by its gallbladder: {held} of {nodes} nodes held, centre of mass down {:.2} mm over 30 steps",
        drop * 1e3
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_explicit_scene_reports_its_stable_step() {
    let build = |text: &str| {
        let config = SceneConfig::from_toml(text, "t.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        Simulation::new(&config, &volume, "t.toml")
    };
    assert_eq!(build(GOOD).unwrap().explicit_stable_dt(), None, "implicit: no limit");
    let explicit =
        GOOD.replace("kind = \"implicit-euler\"\ndt = 0.001", "kind = \"explicit\"\ndt = 1e-4");
    let mut sim = build(&explicit).unwrap();
    let limit = sim.explicit_stable_dt().expect("explicit: its limit");
    assert!(limit >= 1e-4, "dt is within the limit it was checked against ({limit:e})");
    // After a cut the cut mesh's limit is estimated again.
    sim.cut(&incise_grid::GridEdit { remove_voxels: vec![0], sever_links: vec![] }).unwrap();
    let after = sim.explicit_stable_dt().expect("still explicit");
    assert!(after.is_finite() && after > 0.0 && after.to_bits() != limit.to_bits(), "{after:e}");
    // Above the limit the scene is refused, and the message gives the limit.
    let err =
        build(&explicit.replace("dt = 1e-4", &format!("dt = {}", 2.0 * limit))).err().unwrap();
    assert!(err.to_string().contains(&format!("{limit:.3e}")), "{err}");
    let tm = build(&tensor_mass_scene("", "1e-4")).unwrap();
    assert!(tm.explicit_stable_dt().is_some_and(|l| l >= 1e-4));
}

#[test]
fn an_explicit_scene_takes_smaller_steps_when_a_cut_lowers_its_limit() {
    // A 4×4×4-voxel block at level 1 (2×2×2 cells) of stiffer tissue (small strains, so the rest
    // stiffness's limit is the one that matters), held at its top and lightly damped, stepping
    // at 0.99 of its stable step. Cutting a bottom cell down to one voxel that still joins the
    // block leaves light corners tied by a sliver: the mesh's limit falls below the scene's dt.
    let text = GOOD
        .replace("voxels = [2, 2, 2]", "voxels = [4, 4, 4]")
        .replace("youngs_modulus = 1000.0", "youngs_modulus = 100000.0")
        .replace(
            "kind = \"implicit-euler\"\ndt = 0.001",
            "kind = \"explicit\"\ndt = DT\nrayleigh_alpha = 1.0",
        )
        .replace("name = \"t\"", "name = \"t\"\nlevel = 1");
    let build = |dt: f64| {
        let config =
            SceneConfig::from_toml(&text.replace("DT", &dt.to_string()), "t.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        Simulation::new(&config, &volume, "t.toml").unwrap()
    };
    let limit = build(1e-6).explicit_stable_dt().unwrap();
    let dt = 0.99 * limit;
    let mut sim = build(dt);
    let none = StepInputs::default();
    assert_eq!(sim.step(&none).unwrap().counters.substeps, 1);
    // Keep only voxel (1, 1, 1) of the cell at the origin: still joined to the block through
    // its faces with the neighbouring cells.
    let cell: Vec<u32> = (0..2u32)
        .flat_map(|z| (0..2u32).flat_map(move |y| (0..2u32).map(move |x| x + 4 * (y + 4 * z))))
        .filter(|&v| v != 1 + 4 * (1 + 4))
        .collect();
    sim.cut(&incise_grid::GridEdit { remove_voxels: cell, sever_links: vec![] }).unwrap();
    let after = sim.explicit_stable_dt().unwrap();
    let frame = sim.step(&none).unwrap();
    println!(
        "stable dt {limit:.3e} s before the cut, {after:.3e} s after; dt {dt:.3e} s: {} substeps",
        frame.counters.substeps
    );
    assert!(after < dt, "the cut must lower the limit below dt: {after:e} against {dt:e}");
    assert_eq!(frame.counters.substeps, (dt / after).ceil() as usize);
    // 2,000 frames: bounded (the block is 0.1 m; it sags by millimetres).
    for k in 0..2000 {
        let frame = sim.step(&none).unwrap();
        let far = frame.positions.iter().flatten().fold(0.0f64, |m, c| m.max(c.abs()));
        assert!(far < 0.2, "frame {k}: a node at {far:e} m");
    }
}

#[test]
fn a_scene_with_the_consistent_mass_steps() {
    let consistent = GOOD.replace("dt = 0.001", "dt = 0.001\nmass = \"consistent\"");
    let config = SceneConfig::from_toml(&consistent, "t.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut sim = Simulation::new(&config, &volume, "t.toml").unwrap();
    for _ in 0..5 {
        let frame = sim.step(&StepInputs::default()).unwrap();
        assert!(frame.positions.iter().flatten().all(|c| c.is_finite()));
        assert!(frame.counters.solver_residual <= 1e-6, "{:?}", frame.counters);
    }
}

#[test]
fn the_corotational_liver_comes_to_rest_at_level_3() {
    // Corners of nearly empty cells, tied to a few voxels in the far corner, used to steer their
    // element's rotation (taken at the cell's centre): they swung metres away at hundreds of
    // m/s and the organ never came to rest. With the rotation taken at the material's centre of
    // mass, its motion dies down under gravity and damping and it hangs where it will stay.
    let mut sim = load("liver_13k.toml");
    let norm = |v: &[f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    // The motion (the sum of the nodes' squared speeds, the kinetic energy for equal masses)
    // and the largest distance of a node from its rest place.
    let measure = |sim: &Simulation| {
        let state = sim.state();
        let rest = &sim.model().expect("a hexahedral scene").rest;
        let motion: f64 = state.v.iter().map(|v| v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sum();
        let farthest = state
            .x
            .iter()
            .zip(rest)
            .map(|(x, r)| norm(&[x[0] - r[0], x[1] - r[1], x[2] - r[2]]))
            .fold(0.0, f64::max);
        (motion, farthest)
    };
    let mut at = Vec::new();
    for step in 1..=1500 {
        sim.step(&StepInputs::default()).unwrap();
        if step % 250 == 0 {
            at.push(measure(&sim));
        }
    }
    let fastest = sim.state().v.iter().map(norm).fold(0.0, f64::max);
    println!(
        "every 0.25 s (motion, farthest): {at:?}; after 1.5 s the fastest node {fastest:.3e} m/s"
    );
    // Coming to rest: between 0.5 s and 1.5 s the motion falls to under a hundredth (measured:
    // a 465th), and over the last quarter second the farthest node's distance from its rest place
    // changes by under 2 % (measured 0.7 %): it hangs where it will stay. With the rotation at
    // the cell's centre, nodes swung metres away at hundreds of m/s and did neither.
    let (early, late) = (at[1].0, at[5].0);
    assert!(late < 0.01 * early, "the motion fell from {early} only to {late}: {at:?}");
    let (before, last) = (at[4].1, at[5].1);
    assert!((last - before).abs() < 0.02 * last, "the farthest node still moves: {at:?}");
}

#[test]
fn a_cut_that_takes_one_patch_keeps_the_other_pulling() {
    // Two patches of one node each: the corner node (0, 0, 0), which only voxel 0 holds, and the
    // opposite corner. Cutting voxel 0 removes the first patch's node.
    let text = format!(
        "{GOOD}[[loads]]\ncentre = [0.0, 0.0, 0.0]\nradius = 0.01\nforce = [1.0, 0.0, 0.0]\n\
         [[loads]]\ncentre = [0.1, 0.1, 0.1]\nradius = 0.01\nforce = [0.0, 2.0, 0.0]\n"
    );
    let config = SceneConfig::from_toml(&text, "t.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut sim = Simulation::new(&config, &volume, "t.toml").unwrap();
    // The total force on the nodes, against the expected one (sums of one share each: exact).
    let off = |sim: &Simulation, want: [f64; 3]| {
        let nodal = &sim.loads().expect("a hexahedral scene").nodal;
        (0..3).map(|a| (nodal.iter().map(|f| f[a]).sum::<f64>() - want[a]).abs()).sum::<f64>()
    };
    assert!(off(&sim, [1.0, 2.0, 0.0]) < 1e-12);
    sim.cut(&incise_grid::GridEdit { remove_voxels: vec![0], sever_links: vec![] }).unwrap();
    assert!(off(&sim, [0.0, 2.0, 0.0]) < 1e-12, "the second patch still pulls");
    assert!(
        sim.step(&StepInputs::default()).unwrap().positions.iter().flatten().all(|c| c.is_finite())
    );
}

#[test]
fn holds_that_hold_nothing_are_refused() {
    // A plane or a box that holds no node: the scene builds no body that would fall for ever.
    let build = |text: &str| {
        let config = SceneConfig::from_toml(text, "t.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        Simulation::new(&config, &volume, "t.toml")
    };
    assert!(build(GOOD).is_ok());
    let err = build(&GOOD.replace("value = 0.1", "value = 0.12")).err().expect("refused");
    assert!(
        err.to_string().contains("fixed[0]") && err.to_string().contains("plane z = 0.12"),
        "{err}"
    );
    let far =
        GOOD.replace("plane = \"z\"\nvalue = 0.1", "min = [1.0, 1.0, 1.0]\nmax = [2.0, 2.0, 2.0]");
    let err = build(&far).err().expect("refused");
    assert!(err.to_string().contains("fixed[0]: no node lies in the box"), "{err}");
}

#[test]
fn an_implicit_step_reports_its_stage_times() {
    let mut sim = load("b1.toml");
    for _ in 0..3 {
        let c = sim.step(&StepInputs::default()).unwrap().counters;
        assert!(c.rotations_ns > 0 && c.solve_ns > 0, "{c:?}");
        assert!(
            c.rotations_ns + c.solve_ns + c.update_ns <= c.step_ns,
            "stages within the step: {c:?}"
        );
    }
}

/// Paper 2's cylinder (r = 1 cm, h = 3 cm) as `deploy/scenes/meshes/cylinder.vtu` holds it: in
/// millimetres, region 1.
fn cylinder_in_millimetres() -> incise_mesh::TetMesh {
    let mesh = incise_mesh::generate::cylinder(0.01, 0.03, 4, 6);
    let vertices = mesh.vertices().iter().map(|p| p.map(|c| 1000.0 * c)).collect();
    incise_mesh::TetMesh::new(vertices, mesh.tets().to_vec(), mesh.regions().to_vec()).unwrap()
}

#[test]
fn the_committed_cylinder_mesh_is_paper_2s_cylinder_in_millimetres() {
    let path = scene("meshes/cylinder.vtu");
    let written = incise_io::encode_vtu(&cylinder_in_millimetres());
    // `INCISE_WRITE_MESHES=1 cargo test --test scenes` writes the file again.
    if std::env::var_os("INCISE_WRITE_MESHES").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &written).unwrap();
    }
    assert_eq!(std::fs::read_to_string(&path).unwrap(), written);
}

#[test]
fn a_tensor_mass_scene_reads_its_tetrahedra_from_a_mesh_file() {
    let path = scene("cylinder_mesh.toml");
    let scene_file = incise_scene::read_scene(&path).unwrap();
    let mesh = scene_file.geometry.mesh().expect("the scene names a mesh file");
    assert_eq!(mesh, &cylinder_in_millimetres());
    let text = std::fs::read_to_string(&path).unwrap();
    for kind in ["explicit", "implicit-euler"] {
        let config = if kind == "explicit" {
            scene_file.config.clone()
        } else {
            let implicit = text.replace("kind = \"explicit\"", "kind = \"implicit-euler\"");
            SceneConfig::from_toml(&implicit, "cylinder_mesh.toml").unwrap()
        };
        let mut sim = Simulation::new(&config, &scene_file.geometry, "cylinder_mesh.toml").unwrap();
        let tet = sim.tet().expect("a tensor-mass scene");
        let (count, limit) = (tet.topology.live_count(), tet.stable_dt);
        assert_eq!(count, mesh.tets().len());
        // Read in millimetres, built in metres: the cylinder is 3 cm tall, its base held.
        let top = tet.model.rest.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
        assert!((top - 0.03).abs() < 1e-15, "top at {top} m");
        let held = sim.fixed().count();
        assert!(held > 0 && held < tet.model.vertex_count());
        let mut last = None;
        for _ in 0..100 {
            last = Some(sim.step(&StepInputs::default()).unwrap());
        }
        let last = last.unwrap();
        let rest = &sim.tet().unwrap().model.rest;
        let moved = last
            .positions
            .iter()
            .zip(rest)
            .map(|(p, q)| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        println!(
            "{kind}: {count} tetrahedra, {held} held, stable explicit step {limit:.3e} s, moved {:.3} mm",
            moved * 1e3
        );
        assert!(moved > 1e-5 && moved < 0.01, "{kind}: moved {moved:e} m");
        // No voxels to cut by; tetrahedra are removed by index, with those left hanging.
        let voxels = incise_grid::GridEdit { remove_voxels: vec![0], sever_links: vec![] };
        assert_eq!(sim.cut(&voxels), Err(incise_sim::CutError::NoVoxels));
        assert_eq!(
            sim.remove_tets(&[count]),
            Err(incise_sim::CutError::NoSuchTet { tet: count, count })
        );
        let removed = sim.remove_tets(&[count - 1, count - 2]).unwrap();
        assert!(removed.contains(&(count - 1)) && removed.contains(&(count - 2)), "{removed:?}");
        assert_eq!(sim.tet().unwrap().topology.live_count(), count - removed.len());
        assert_eq!(sim.remove_tets(&[count - 1]).unwrap(), Vec::<usize>::new());
        for _ in 0..50 {
            let frame = sim.step(&StepInputs::default()).unwrap();
            assert!(frame.positions.iter().flatten().all(|c| c.is_finite()));
        }
    }
    // A hexahedral scene has no tetrahedra to remove.
    assert_eq!(load("b1.toml").remove_tets(&[0]), Err(incise_sim::CutError::NotTetrahedra));
}

#[test]
fn a_mesh_scene_names_its_region_array_and_is_told_what_was_skipped() {
    // meshio's fixture: twelve tetrahedra in physical groups 11 and 12, elementary entities 1
    // and 2, and two boundary triangles. The scene asks for the entities.
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../server/incise_io/tests/data/foreign/meshio_ascii.vtu");
    let dir = std::env::temp_dir().join(format!("incise-region-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(&fixture, dir.join("organ.vtu")).unwrap();
    let material = |label: u32| {
        format!(
            "[[materials]]\nlabel = {label}\nyoungs_modulus = 3000.0\npoisson_ratio = 0.3\n\
             density = 1000.0\n"
        )
    };
    let write = |region: &str| {
        let text = format!(
            "name = \"region\"\n[volume]\nmesh = \"organ.vtu\"\nunit = \"mm\"\n{region}\n{}{}\
             [model]\nkind = \"tensor-mass\"\nelasticity = \"linear\"\n\
             [integrator]\nkind = \"implicit-euler\"\ndt = 0.01\n\
             [[fixed]]\nplane = \"z\"\nvalue = 0.0005\n",
            material(1),
            material(2)
        );
        let path = dir.join("scene.toml");
        std::fs::write(&path, text).unwrap();
        path
    };
    let path = write("region = \"gmsh:geometrical\"");
    let read = incise_scene::read_scene(&path).unwrap();
    let mesh = read.geometry.mesh().unwrap();
    let regions: Vec<u32> = [1; 6].into_iter().chain([2; 6]).collect();
    assert_eq!(mesh.regions(), &regions[..]);
    let [source, skipped] = &read.notes[..] else { panic!("{:?}", read.notes) };
    assert!(
        source.ends_with("organ.vtu: regions from cell array \"gmsh:geometrical\""),
        "{source}"
    );
    assert!(skipped.ends_with("skipped 2 cells that are not tetrahedra (2 triangle)"), "{skipped}");
    let mut sim = Simulation::new(&read.config, &read.geometry, "scene.toml").unwrap();
    sim.step(&StepInputs::default()).unwrap();

    // Without the key the physical groups 11 and 12 are the regions, which have no material.
    let e = incise_scene::read_scene(&write(""))
        .map(|s| Simulation::new(&s.config, &s.geometry, "scene.toml").map(|_| ()))
        .unwrap();
    assert!(e.is_err_and(|e| e.to_string().contains("11")));
    // A name the file lacks: the error says which arrays it has.
    let e = incise_scene::read_scene(&write("region = \"tissue\"")).unwrap_err().to_string();
    assert!(e.contains("region array") && e.contains("\"gmsh:physical\""), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_block_cut_scene_alone_reproduces_its_cut() {
    // Its scalpel follows the scene's waypoints: it touches the top and presses without cutting
    // until 0.4 s, is pushed in until its blade bites, and is drawn across.
    let run = || {
        let path = scene("block_cut.toml");
        let scene_file = incise_scene::read_scene(&path).unwrap();
        let mut sim =
            Simulation::new(&scene_file.config, &scene_file.geometry, "block_cut").unwrap();
        let (mut pressed, mut cut_early, mut removed) = (0.0f64, 0usize, 0usize);
        let mut last = 0;
        for _ in 0..1300 {
            let frame = sim.step(&StepInputs::default()).unwrap();
            let force = frame.surgical.tools[0].force()[2];
            if frame.time <= 0.4 {
                pressed = pressed.max(force);
                cut_early += frame.counters.voxels_removed;
            }
            removed += frame.counters.voxels_removed;
            last = frame.state_hash;
        }
        let triangles = sim.surface().unwrap().triangle_list();
        incise_mesh::topology::check_closed(&triangles).unwrap();
        incise_mesh::topology::check_manifold(&triangles).unwrap();
        (pressed, cut_early, removed, last)
    };
    let (pressed, cut_early, removed, hash) = run();
    println!("pressed with {pressed:.4} N without cutting; {removed} voxels cut");
    assert!(pressed > 0.005, "the scalpel touches the top before 0.4 s");
    assert_eq!(cut_early, 0, "no cut while it only presses");
    assert!(removed > 50, "the stroke cuts");
    assert_eq!(run().3, hash, "the scene replays bit for bit");
}

#[test]
fn a_scene_runs_and_cuts_with_each_element_kind() {
    let text = GOOD
        .replace("voxels = [2, 2, 2]", "voxels = [8, 8, 8]")
        .replace("[volume]", "level = 2\n[volume]");
    let mut sags = Vec::new();
    for kind in ElementKind::ALL {
        let text = text.replace(
            "[integrator]",
            &format!(
                "[model]\nkind = \"corotational\"\nelement = \"{}\"\n[integrator]",
                kind.name()
            ),
        );
        let config = SceneConfig::from_toml(&text, "k.toml").unwrap_or_else(|e| panic!("{e}"));
        let volume = config.procedural_volume().unwrap();
        let mut sim = Simulation::new(&config, &volume, "k.toml").unwrap();
        let same_stiffness = |sim: &Simulation| {
            let rebuilt = incise_fem::HexModel::from_grid_of_kind(sim.grid().unwrap(), kind);
            let model = sim.model().unwrap();
            assert_eq!(model.element, kind);
            model.elements.len() == rebuilt.elements.len()
                && model.elements.iter().zip(&rebuilt.elements).all(|(a, b)| {
                    a.stiffness
                        .0
                        .iter()
                        .zip(&b.stiffness.0)
                        .all(|(x, y)| x.to_bits() == y.to_bits())
                })
        };
        assert!(same_stiffness(&sim), "{}", kind.name());
        for _ in 0..20 {
            sim.step(&StepInputs::default()).unwrap();
        }
        // A slab off one corner: re-condenses the elements it crosses.
        let dims = sim.grid().unwrap().fine().dims();
        let slab: Vec<u32> = (0..dims[2])
            .flat_map(|z| {
                (0..3).flat_map(move |y| (0..2).map(move |x| x + dims[0] * (y + dims[1] * z)))
            })
            .collect();
        let changes =
            sim.cut(&incise_grid::GridEdit { remove_voxels: slab, sever_links: vec![] }).unwrap();
        assert!(changes.voxels_removed > 0);
        assert!(same_stiffness(&sim), "{} after the cut", kind.name());
        for _ in 0..20 {
            sim.step(&StepInputs::default()).unwrap();
        }
        let model = sim.model().unwrap();
        let sag = model.centre_of_mass_shift(&sim.state().x)[2];
        assert!(sag.is_finite() && sag < 0.0, "{}: {sag}", kind.name());
        sags.push(sag);
    }
    // The kinds are different models: the enriched ones are softer than the condensed one.
    println!("centre of mass after 40 ms (condensed, incompatible, composite): {sags:?}");
    assert!(sags[1] < sags[0] && sags[2] < sags[0], "{sags:?}");
}
