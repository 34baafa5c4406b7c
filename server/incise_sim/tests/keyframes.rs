//! Keyframes: a simulation rebuilt from its scene, given the topology edits of every frame up to a
//! keyframe and then the keyframe, steps on exactly as the original did (every later frame's
//! state hash and tool forces equal, bit for bit), through cuts, grasps and separations made on
//! either side of the keyframe, in every integrator family a tool can act in.

use incise_sim::config::ShapeSpec;
use incise_sim::{Frame, Keyframe, SceneConfig, Simulation, StepInputs};

/// A 4 × 4 × 2 cm block (2.5 mm voxels) held at its base, with `model` and `integrator` keys, and
/// `tools`.
fn scene(model: &str, integrator: &str, tools: &str) -> String {
    format!(
        r#"name = "keyframes"
level = 2
gravity = [0.0, 0.0, -9.81]

[volume]
procedural = "block"
size_m = [0.04, 0.04, 0.02]
voxels = [16, 16, 8]

[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0

[model]
{model}

[integrator]
{integrator}

[[fixed]]
plane = "z"
value = 0.0

{tools}
"#
    )
}

/// A scalpel that presses into the top (z = 2 cm) at t = 0.3 s and strokes along y until 1.2 s,
/// cutting from a light push on (the soft block yields under a harder one), and a grasper (its
/// jaws turned to reach down) that closes on the top at 0.6 s, lifts, and lets go at 1.8 s.
const CUT_AND_GRASP: &str = r#"
[[tools]]
name = "scalpel"
stiffness = 400.0
cutting = "remove"
cut_force = 0.05
outer = { shape = "capsule", radius = 0.002, length = 0.03 }
inner = { shape = "capsule", radius = 0.0015, length = 0.03 }
[[tools.path]]
time = 0.0
position = [0.01, 0.005, 0.03]
[[tools.path]]
time = 0.3
position = [0.01, 0.005, 0.013]
[[tools.path]]
time = 1.2
position = [0.01, 0.035, 0.013]
[[tools.path]]
time = 1.5
position = [0.01, 0.035, 0.04]

[[tools]]
name = "grasper"
stiffness = 300.0
outer = { shape = "sphere", radius = 0.003 }
[tools.jaws]
length = 0.008
width = 0.004
close_below = 0.05
open_above = 0.4
stiffness = 300.0
[[tools.path]]
time = 0.0
position = [0.03, 0.02, 0.03]
rotation = [0.0, 1.0, 0.0, 0.0]
gripper = 0.6
[[tools.path]]
time = 0.4
position = [0.03, 0.02, 0.0215]
rotation = [0.0, 1.0, 0.0, 0.0]
gripper = 0.6
[[tools.path]]
time = 0.6
position = [0.03, 0.02, 0.0215]
rotation = [0.0, 1.0, 0.0, 0.0]
gripper = 0.0
[[tools.path]]
time = 1.0
position = [0.03, 0.02, 0.027]
rotation = [0.0, 1.0, 0.0, 0.0]
gripper = 0.0
[[tools.path]]
time = 1.8
position = [0.03, 0.02, 0.027]
rotation = [0.0, 1.0, 0.0, 0.0]
gripper = 0.6
"#;

/// A blade laid flat at z = 1.25 cm drawn along y through the block in separation mode.
const SEPARATE: &str = r#"
[[tools]]
name = "separator"
stiffness = 10.0
cutting = "separate"
outer = { shape = "blade", length = 0.06, height = 0.06, thickness = 0.0005 }
inner = { shape = "blade", length = 0.06, height = 0.06, thickness = 0.0005 }
[[tools.path]]
time = 0.0
position = [0.02, -0.005, 0.0125]
rotation = [0.7071067811865476, 0.7071067811865476, 0.0, 0.0]
[[tools.path]]
time = 1.5
position = [0.02, 0.05, 0.0125]
rotation = [0.7071067811865476, 0.7071067811865476, 0.0, 0.0]
"#;

fn build(text: &str) -> Simulation {
    let mut config = SceneConfig::from_toml(text, "keyframes.toml").expect("a valid scene");
    // No file is read here: a mesh shape is a ball of 3 mm (an icosphere of 320 triangles).
    for tool in &mut config.tools {
        if let ShapeSpec::Mesh { .. } = tool.outer {
            let ball = incise_mesh::generate::icosphere([0.0; 3], 0.003, 2);
            tool.outer = ShapeSpec::Shape(incise_tool::Shape::mesh(&ball, [0.0; 3]).unwrap());
        }
    }
    let volume = config.procedural_volume().expect("a procedural block");
    Simulation::new(&config, &volume, "keyframes.toml").expect("the scene builds")
}

/// What a frame gave that a replay compares: the state hash and every tool's force and torque
/// (as bits).
type Outputs = (u64, Vec<[u64; 6]>);

/// A frame's [`Outputs`].
fn outputs(frame: &Frame) -> Outputs {
    let tools = frame
        .surgical
        .tools
        .iter()
        .map(|t| {
            let (f, m) = (t.force(), t.torque());
            [f[0], f[1], f[2], m[0], m[1], m[2]].map(f64::to_bits)
        })
        .collect();
    (frame.state_hash, tools)
}

/// One frame's topology edit, as a recording keeps it.
type Edit = (incise_grid::GridEdit, Vec<usize>);

/// Steps `text`'s scene `frames` times: each frame's outputs and edit, and the keyframes taken at
/// the keyframe frames.
fn session(text: &str, frames: u64) -> (Vec<Outputs>, Vec<Edit>, Vec<Keyframe>) {
    let mut sim = build(text);
    let (mut out, mut edits, mut keyframes) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..frames {
        let frame = sim.step(&StepInputs::default()).expect("a scripted step");
        out.push(outputs(&frame));
        edits.push((frame.surgical.edit.clone(), frame.surgical.tets_removed.clone()));
        if sim.is_keyframe(frame.index) {
            keyframes.push(sim.keyframe());
        }
    }
    (out, edits, keyframes)
}

/// Checks that restoring each keyframe of `text`'s session and stepping on gives the session's
/// outputs for every later frame; returns the voxels removed, links severed and tetrahedra
/// removed in the session before and after the first keyframe, and the points held at it, which
/// the caller checks it meant to exercise.
fn restores_bit_for_bit(text: &str, frames: u64) -> ([[usize; 3]; 2], usize) {
    let (outputs_then, edits, keyframes) = session(text, frames);
    assert!(keyframes.len() >= 2, "the session should pass two keyframes");
    for keyframe in &keyframes {
        let mut sim = build(text);
        for (edit, tets) in &edits[..keyframe.frame as usize] {
            sim.apply_edit(edit, tets).expect("a recorded edit applies");
        }
        sim.restore(keyframe).expect("the keyframe fits");
        assert_eq!(&sim.keyframe(), keyframe, "a restored keyframe is taken again unchanged");
        for expected in &outputs_then[keyframe.frame as usize..] {
            let frame = sim.step(&StepInputs::default()).expect("a scripted step");
            assert_eq!(
                &outputs(&frame),
                expected,
                "frame {} after restoring the keyframe of frame {}",
                frame.index,
                keyframe.frame
            );
        }
    }
    let first = keyframes[0].frame as usize;
    let count = |edits: &[Edit]| {
        let voxels = edits.iter().map(|e| e.0.remove_voxels.len()).sum();
        let links = edits.iter().map(|e| e.0.sever_links.len()).sum();
        let tets = edits.iter().map(|e| e.1.len()).sum();
        [voxels, links, tets]
    };
    let held = keyframes[0].tools.iter().map(|t| t.grasp.held().len()).sum();
    ([count(&edits[..first]), count(&edits[first..])], held)
}

const IMPLICIT: &str =
    "kind = \"implicit-euler\"\ndt = 0.005\nrayleigh_alpha = 2.0\nrayleigh_beta = 0.01";

#[test]
fn corotational_hexahedra_with_cutting_and_grasping_restore_bit_for_bit() {
    let text = scene("kind = \"corotational\"", IMPLICIT, CUT_AND_GRASP);
    // Keyframes every 200 frames of 5 ms: at 1 s (mid-stroke, grasp held) and 2 s.
    let ([before, after], held) = restores_bit_for_bit(&text, 420);
    assert!(before[0] > 0 && after[0] > 0, "voxels cut on both sides of 1 s: {before:?} {after:?}");
    assert!(held > 0, "the grasper holds the tissue at 1 s");
}

#[test]
fn a_grasper_pushing_by_volume_restores_bit_for_bit() {
    // The grasper's ball pushes by volume contact (its overlap with the surface, measured each
    // step) and its jaws close on what lies inside it: nothing of either is carried between
    // steps but the pose and the grasp, which the keyframe holds.
    let tools = CUT_AND_GRASP.replace(
        "name = \"grasper\"\nstiffness = 300.0\nouter = { shape = \"sphere\", radius = 0.003 }",
        "name = \"grasper\"\ncontact = \"volume\"\nouter = { mesh = \"ball.stl\" }",
    );
    assert_ne!(tools, CUT_AND_GRASP);
    let text = scene("kind = \"corotational\"", IMPLICIT, &tools);
    let ([before, after], held) = restores_bit_for_bit(&text, 420);
    assert!(before[0] > 0 && after[0] > 0, "voxels cut on both sides of 1 s: {before:?} {after:?}");
    assert!(held > 0, "the grasper holds the tissue at 1 s");
}

#[test]
fn a_separation_restores_bit_for_bit() {
    let text = scene("kind = \"corotational\"", IMPLICIT, SEPARATE);
    let ([before, after], _) = restores_bit_for_bit(&text, 420);
    assert!(
        before[1] > 0 && after[1] > 0,
        "links severed on both sides of 1 s: {before:?} {after:?}"
    );
}

#[test]
fn explicit_hexahedra_with_cutting_restore_bit_for_bit() {
    let explicit = "kind = \"explicit\"\ndt = 0.001\nrayleigh_alpha = 2.0";
    let text = scene("kind = \"corotational\"", explicit, CUT_AND_GRASP);
    let ([before, after], _) = restores_bit_for_bit(&text, 2100);
    assert!(before[0] > 0 && after[0] > 0, "voxels cut on both sides of 1 s: {before:?} {after:?}");
}

#[test]
fn adaptive_tensor_mass_with_cutting_restores_bit_for_bit() {
    let model = "kind = \"tensor-mass\"\nelasticity = \"svk\"\nadaptive_threshold = 0.0005";
    // Level-2 cells hold 6 tetrahedra of a centimetre: an inner shape that reaches their
    // centroids.
    let tools = CUT_AND_GRASP.replace(
        "inner = { shape = \"capsule\", radius = 0.0015",
        "inner = { shape = \"capsule\", radius = 0.006",
    );
    let text = scene(model, IMPLICIT, &tools);
    let ([before, after], held) = restores_bit_for_bit(&text, 420);
    assert!(
        before[2] > 0 && after[2] > 0,
        "tetrahedra cut on both sides of 1 s: {before:?} {after:?}"
    );
    assert!(held > 0, "the grasper holds the tissue at 1 s");
}

#[test]
fn explicit_tensor_mass_restores_bit_for_bit() {
    // Central differences keep the previous positions. The explicit step well within the mesh's
    // stable step at rest (`Simulation::explicit_stable_dt`): the scalpel's proxy, held on the surface 7 mm above its
    // device, presses one coarse node hard enough that the stretched St Venant-Kirchhoff
    // elements around it stiffen, and a step near the rest limit diverges. The tools' springs
    // soft enough for the step (the couplings' default with an explicit step is as stiff as it
    // keeps stable): they push and grasp without cutting, which would lower that step below dt
    // (the tensor-mass integrator takes no sub-steps).
    let model = "kind = \"tensor-mass\"\nelasticity = \"svk\"\nadaptive_threshold = 0.0005";
    let explicit = "kind = \"explicit\"\ndt = 0.0006\nrayleigh_alpha = 2.0";
    let tools = CUT_AND_GRASP
        .replace("cutting = \"remove\"\ncut_force = 0.05", "cutting = \"off\"")
        .replace("stiffness = 400.0", "stiffness = 20.0")
        .replace("stiffness = 300.0", "stiffness = 20.0");
    let text = scene(model, explicit, &tools);
    // Keyframes every second: at 1 s (grasp held) and 2 s.
    let ([before, after], held) = restores_bit_for_bit(&text, 3400);
    assert_eq!([before, after], [[0; 3]; 2], "nothing cuts");
    assert!(held > 0, "the grasper holds the tissue at 1 s");
}

#[test]
fn a_keyframe_without_the_edits_before_it_is_refused() {
    let text = scene("kind = \"corotational\"", IMPLICIT, CUT_AND_GRASP);
    let (_, edits, keyframes) = session(&text, 200);
    let e = build(&text).restore(&keyframes[0]).expect_err("the cut changed the topology");
    assert!(e.to_string().contains("frame 200") && e.to_string().contains("edits"), "{e}");
    let mut sim = build(&text);
    for (edit, tets) in &edits {
        sim.apply_edit(edit, tets).expect("a recorded edit applies");
    }
    let mut other = keyframes[0].clone();
    other.v[0][0] += 1e-9;
    let e = sim.restore(&other).expect_err("a changed keyframe");
    assert!(e.to_string().contains("hash"), "{e}");
}

#[test]
fn implicit_solvers_that_keep_matrices_between_steps_restore_bit_for_bit() {
    // Without a posed tool the implicit step keeps block-Jacobi blocks, or a Cholesky factor,
    // from the rotations of the step that built them: the keyframe frame drops them.
    for solver in ["jacobi-cg", "cholesky-cg", "cholesky"] {
        let integrator = format!("{IMPLICIT}\nsolver = \"{solver}\"");
        let text = scene("kind = \"corotational\"", &integrator, "");
        let ([before, after], _) = restores_bit_for_bit(&text, 420);
        assert_eq!([before, after], [[0; 3]; 2], "{solver}: nothing cuts");
    }
}
