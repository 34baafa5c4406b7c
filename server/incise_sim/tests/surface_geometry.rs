//! `Simulation::surface_geometry`: a few vertices taken by id (how a recording takes a cut's new
//! vertices) sit where the whole surface's deform puts them, and the triangles it names are
//! the live ones with their tissue labels.

use incise_sim::{SceneConfig, Simulation, StepInputs};

const SCENE: &str = r#"name = "sagging_block"
level = 1
gravity = [0.0, 0.0, -9.81]
[volume]
procedural = "block"
size_m = [0.03, 0.02, 0.02]
voxels = [6, 4, 4]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[model]
kind = "corotational"
[integrator]
kind = "implicit-euler"
dt = 0.001
[[fixed]]
plane = "x"
value = 0.0
"#;

#[test]
fn vertices_by_id_sit_where_the_whole_deform_puts_them() {
    let config = SceneConfig::from_toml(SCENE, "sagging_block.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    let mut sim = Simulation::new(&config, &volume, "sagging_block.toml").unwrap();
    sim.enable_surface();
    // Sag under gravity, held at one end, so that the positions differ from the rest ones.
    for _ in 0..50 {
        sim.step(&StepInputs::default()).unwrap();
    }
    let whole = sim.surface_geometry(None, None).unwrap();
    assert!(!whole.vertex_ids.is_empty());
    assert_eq!(whole.triangles.len(), whole.triangle_ids.len());
    assert_eq!(whole.triangles.len(), sim.surface().unwrap().triangle_count());
    assert!(whole.triangle_labels.iter().all(|&l| l == 1), "the block is label 1");
    let some: Vec<u32> = whole.vertex_ids.iter().copied().step_by(7).collect();
    let part = sim.surface_geometry(Some(&some), Some(&[])).unwrap();
    assert_eq!(part.vertex_ids, some);
    assert!(part.triangles.is_empty());
    let mut sagged: f32 = 0.0;
    for (i, &v) in part.vertex_ids.iter().enumerate() {
        let j = whole.vertex_ids.binary_search(&v).unwrap();
        for k in 0..3 {
            // Both sum the same embedding weights in f64, in the same or another order, and
            // round to f32: within a few f32 ulps of 3 cm.
            let (a, b) = (part.positions[i][k], whole.positions[j][k]);
            assert!((a - b).abs() <= 1e-8, "vertex {v}: {a} against {b}");
        }
        sagged = sagged.min(whole.positions[j][2]);
    }
    assert!(sagged < 0.0, "the free end sagged below its rest height");
}
