//! The committed scene files (`deploy/scenes/*.toml`) through `incise_io::read_scene` and
//! `incise_sim::Simulation`, and the errors a broken scene file gets.

use incise_sim::{SceneConfig, SceneError, Simulation};
use incise_tests::scene;

fn load(name: &str) -> Simulation {
    let path = scene(name);
    let (config, volume) = incise_io::read_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    Simulation::new(&config, &volume, &path.display().to_string())
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
        println!(
            "{name:<18} level {} {:>6} elements {:>6} nodes {:>5} fixed",
            sim.config().level,
            sim.model().elements.len(),
            sim.model().node_count(),
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
        let (fa, fb) = (a.step(), b.step());
        assert_eq!(fa.state_hash, fb.state_hash, "step {}", fa.index);
        assert!(fa.positions.iter().all(|p| p.iter().all(|c| c.is_finite())));
    }
    assert_eq!(a.model().elements.len(), 140);
    assert_eq!(a.model().node_count(), 240);
}

#[test]
fn cantilever_scene_reaches_beam_theory() {
    let mut sim = load("c_80x8x8.toml");
    let frame = sim.step();
    let rest = &sim.model().rest;
    let tip: Vec<f64> = rest
        .iter()
        .zip(&frame.positions)
        .filter(|(p, _)| (p[0] - 0.1).abs() < 1e-9)
        .map(|(p, q)| p[2] - q[2])
        .collect();
    let d = tip.iter().sum::<f64>() / tip.len() as f64;
    assert!((d - 14.715e-3).abs() <= 0.02 * 14.715e-3, "tip deflection {:.3} mm", d * 1e3);
}

fn error(text: &str) -> SceneError {
    SceneConfig::from_toml(text, "bad.toml").unwrap_err()
}

const GOOD: &str = r#"name = "t"
[volume]
procedural = "block"
size_m = [0.1, 0.1, 0.1]
voxels = [2, 2, 2]
[[materials]]
label = 1
youngs_modulus = 1000.0
poisson_ratio = 0.3
density = 1000.0
[integrator]
kind = "implicit-euler"
dt = 0.001
[[fixed]]
plane = "z"
value = 0.1
"#;

#[test]
fn scene_errors_name_the_key_and_line() {
    assert!(SceneConfig::from_toml(GOOD, "good.toml").is_ok());
    let e = error(&GOOD.replace("dt = 0.001", "dt = -0.001"));
    assert!(
        e.to_string().starts_with("bad.toml:13:") && e.to_string().contains("integrator.dt"),
        "{e}"
    );
    let e = error(&GOOD.replace("density = 1000.0", "density = 1000.0\ndensty = 3.0"));
    assert!(e.to_string().starts_with("bad.toml:11:") && e.to_string().contains("densty"), "{e}");
    let e = error(&GOOD.replace("poisson_ratio = 0.3", "poisson_ratio = 0.5"));
    assert!(
        e.to_string().contains("bad.toml:9:")
            && e.to_string().contains("materials[0].poisson_ratio"),
        "{e}"
    );
    let e = error(&GOOD.replace("plane = \"z\"", "plane = \"w\""));
    assert!(
        e.to_string().contains("bad.toml:15:") && e.to_string().contains("fixed[0].plane"),
        "{e}"
    );
    let e = error(&GOOD.replace("kind = \"implicit-euler\"", "kind = \"rk4\""));
    assert!(e.to_string().contains("integrator.kind") && e.to_string().contains("rk4"), "{e}");
    let e = error("name = ");
    assert!(matches!(e, SceneError::Parse { line: 1, .. }), "{e}");
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
