//! The organ's surface as scenes configure it (one surface, or one per tissue; smoothed), and
//! tools whose shapes are triangle meshes read from files.

use incise_math::Vec3;
use incise_sim::{Simulation, StepInputs, ToolInput};
use incise_tool::{Pose, ToolPose};

/// The 13,648-voxel liver scene's text with `extra` appended.
fn liver_text(extra: &str) -> String {
    let path = incise_tests::scene("liver_13k.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    // The volume path is relative to the scene folder; make it absolute for a scene written
    // elsewhere.
    let data = incise_tests::fixture("liver.inr.gz");
    format!("{}\n{extra}", text.replace("../../tests/data/liver.inr.gz", data.to_str().unwrap()))
}

fn read(text: &str, file: &str, dir: &std::path::Path) -> incise_scene::Scene {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    incise_scene::read_scene(&path).unwrap()
}

#[test]
fn label_interfaces_give_one_closed_surface_per_tissue() {
    let dir = std::env::temp_dir().join(format!("incise-interfaces-{}", std::process::id()));
    let one = read(&liver_text(""), "one.toml", &dir);
    let split = read(&liver_text("[surface]\ninterfaces = true\n"), "split.toml", &dir);
    let mut a = Simulation::new(&one.config, &one.geometry, "one").unwrap();
    let mut b = Simulation::new(&split.config, &split.geometry, "split").unwrap();
    a.enable_surface();
    b.enable_surface();
    let (ta, tb) = (a.surface().unwrap().triangle_list(), b.surface().unwrap().triangle_list());
    // Three tissues: the split surface adds the interfaces between them, twice each.
    println!("one surface: {} triangles; one per tissue: {} triangles", ta.len(), tb.len());
    assert!(tb.len() > ta.len());
    for t in [&ta, &tb] {
        incise_mesh::topology::check_closed(t).unwrap();
        incise_mesh::topology::check_manifold(t).unwrap();
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_smoothed_surface_sits_where_it_was_smoothed_and_still_maps_the_nodes() {
    let dir = std::env::temp_dir().join(format!("incise-smooth-{}", std::process::id()));
    let rough = read(&liver_text(""), "rough.toml", &dir);
    let smooth = read(&liver_text("[surface]\nsmoothing = 10\n"), "smooth.toml", &dir);
    let mut a = Simulation::new(&rough.config, &rough.geometry, "rough").unwrap();
    let mut b = Simulation::new(&smooth.config, &smooth.geometry, "smooth").unwrap();
    a.enable_surface();
    b.enable_surface();
    let (pa, pb) = (a.surface_positions().unwrap(), b.surface_positions().unwrap());
    let live = a.surface().unwrap().live_vertices().to_vec();
    assert_eq!(live, b.surface().unwrap().live_vertices());
    let moved = live
        .iter()
        .map(|&v| {
            (0..3).map(|k| (pa[v as usize][k] - pb[v as usize][k]).powi(2)).sum::<f64>().sqrt()
        })
        .fold(0.0, f64::max);
    let voxel = a.grid().unwrap().spacing().into_iter().fold(0.0, f64::max);
    // Smoothing moves vertices, never farther than its clamp allows (half a voxel past the
    // voxel's box, so at most the box's half-diagonal plus half a voxel from the face centre).
    println!(
        "smoothing moved vertices by up to {:.3} mm (voxel {:.3} mm)",
        moved * 1e3,
        voxel * 1e3
    );
    assert!(moved > 0.0 && moved < 1.5 * voxel);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A closed cube of edge `a` metres centred on the origin, as binary STL.
fn cube_stl(a: f64) -> Vec<u8> {
    let v: Vec<Vec3> =
        (0..8).map(|i| [i & 1, (i >> 1) & 1, i >> 2].map(|b| (f64::from(b) - 0.5) * a)).collect();
    let quads =
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let t: Vec<[u32; 3]> =
        quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    incise_io::encode_stl_binary(&incise_mesh::TriMesh::new(v, t).unwrap())
}

/// A 4 cm cube of soft tissue (16³ voxels, level 2) on a held base, with `extra` appended.
fn block_text(extra: &str) -> String {
    format!(
        "name = \"block\"\nlevel = 2\n[volume]\nprocedural = \"block\"\nsize_m = [0.04, 0.04, 0.04]\n\
         voxels = [16, 16, 16]\n[[materials]]\nlabel = 1\nyoungs_modulus = 3000.0\n\
         poisson_ratio = 0.45\ndensity = 1000.0\n[model]\nkind = \"corotational\"\n\
         [integrator]\nkind = \"implicit-euler\"\ndt = 0.001\nrayleigh_alpha = 2.0\n\
         rayleigh_beta = 0.01\n[[fixed]]\nplane = \"z\"\nvalue = 0.0\n{extra}"
    )
}

#[test]
fn a_tool_shaped_by_an_stl_file_pushes_like_its_analytic_twin() {
    // The same 8 mm cube as a mesh file (in millimetres) and as a box, pressed 2 mm into the
    // block's top: both press it and feel the same force. Not to the last bit: the proxy stops
    // where a face lies flush on the tissue, where every point of the face is equally near and
    // the two shapes' distances, equal but for rounding, pick different ones; the triangles it
    // rests on and the tilt of their normals differ by that. The force, the coupling's pull from
    // device to proxy, agrees within 2 % of its size (a proxy a few micrometres apart).
    let dir = std::env::temp_dir().join(format!("incise-stl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("cube.stl"), cube_stl(8.0)).unwrap();
    let tool =
        |outer: &str| format!("[[tools]]\nname = \"probe\"\nstiffness = 200.0\nouter = {outer}\n");
    let mesh =
        read(&block_text(&tool("{ mesh = \"cube.stl\", unit = \"mm\" }")), "mesh.toml", &dir);
    let boxed = read(
        &block_text(&tool("{ shape = \"box\", half_extents = [0.004, 0.004, 0.004] }")),
        "box.toml",
        &dir,
    );
    let mut forces = Vec::new();
    for scene in [mesh, boxed] {
        let mut sim = Simulation::new(&scene.config, &scene.geometry, "probe").unwrap();
        let pose = |z: f64| ToolPose::from_pose(Pose::at([0.02, 0.02, z]), 0.0).unwrap();
        let mut last = None;
        for i in 0..300 {
            // The top sags to about 3.8 cm; the cube's face is 4 mm below its centre.
            let z = 0.05 - 0.014 * f64::from(i.min(200)) / 200.0;
            let inputs = StepInputs {
                tools: vec![ToolInput { tool: 0, pose: pose(z) }],
                ..StepInputs::default()
            };
            last = Some(sim.step(&inputs).unwrap());
        }
        let frame = last.unwrap();
        forces.push((frame.surgical.tools[0].contact_points, frame.surgical.tools[0].force()));
    }
    println!("mesh: {:?}; box: {:?}", forces[0], forces[1]);
    for (points, force) in &forces {
        assert!(*points > 0 && force[2] > 0.1, "each presses into the top");
    }
    let size = forces[1].1.iter().map(|c| c * c).sum::<f64>().sqrt();
    let apart = (0..3).map(|k| (forces[0].1[k] - forces[1].1[k]).powi(2)).sum::<f64>().sqrt();
    assert!(apart <= 0.02 * size, "{apart} N apart of {size} N");
    std::fs::remove_dir_all(&dir).unwrap();
}
