//! The surgical frame on real scenes: tools pressing, cutting and grasping through
//! `Simulation::step`, with the invariants each stage must keep.

use incise_math::Vec3;
use incise_sim::{SceneConfig, Simulation, StepInputs, ToolInput};
use incise_tool::{Pose, ToolPose};

/// A 4 cm cube of soft tissue (16³ voxels of 2.5 mm, level 2) on a fixed base, with one tool
/// given by `tool` (TOML of a `[[tools]]` entry).
fn block(tool: &str, dt: f64) -> Simulation {
    let text = format!(
        "name = \"block\"
level = 2
[volume]
procedural = \"block\"
size_m = [0.04, 0.04, 0.04]
voxels = [16, 16, 16]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[model]
kind = \"corotational\"
[integrator]
kind = \"implicit-euler\"
dt = {dt}
rayleigh_alpha = 2.0
rayleigh_beta = 0.01
[[fixed]]
plane = \"z\"
value = 0.0
{tool}"
    );
    let config = SceneConfig::from_toml(&text, "block.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    Simulation::new(&config, &volume, "block.toml").unwrap()
}

fn posed(tool: usize, position: Vec3) -> StepInputs {
    let pose = ToolPose::from_pose(Pose::at(position), 0.0).unwrap();
    StepInputs { tools: vec![ToolInput { tool, pose }], ..StepInputs::default() }
}

const PROBE: &str = "[[tools]]
name = \"probe\"
stiffness = 200.0
damping = 0.0
outer = { shape = \"sphere\", radius = 0.004 }
";

#[test]
fn a_pressed_probe_is_pushed_back_and_dents_the_surface() {
    let mut sim = block(PROBE, 1e-3);
    let surface = sim.surface().expect("a scene with tools has a surface");
    assert!(surface.triangle_count() > 1000);
    // Lower the probe from 1 cm above the top (z = 4 cm) to 2 mm into it, then hold.
    let mut last = None;
    for i in 0..400 {
        let z = (0.05 - 0.012 * f64::from(i.min(200)) / 200.0).max(0.038);
        last = Some(sim.step(&posed(0, [0.02, 0.02, z])).unwrap());
    }
    let frame = last.unwrap();
    let tool = &frame.surgical.tools[0];
    println!("force {:?} N, {} points", tool.force(), tool.contact_points);
    assert!(tool.contact_points > 0);
    assert!(tool.force()[2] > 0.0, "the tissue pushes the probe up");
}

use incise_sim::config::{CouplingSpec, Cutting, ShapeSpec, ToolContact, ToolSpec};
use incise_tool::{Primitive, Shape};

/// The 13,648-voxel liver with `tools`.
fn liver(tools: Vec<ToolSpec>) -> Simulation {
    let path = incise_tests::scene("liver_13k.toml");
    let mut scene = incise_scene::read_scene(&path).unwrap();
    scene.config.tools = tools;
    Simulation::new(&scene.config, &scene.geometry, "liver_13k.toml").unwrap()
}

fn cutter(name: &str, outer: Primitive, inner_offset_z: f64) -> ToolSpec {
    let Primitive::Cuboid { half_extents } = outer else { unreachable!() };
    ToolSpec {
        name: name.into(),
        outer: ShapeSpec::Shape(Shape::new(outer, [0.0, 0.0, half_extents[2]]).unwrap()),
        inner: Some(ShapeSpec::Shape(
            Shape::new(
                Primitive::Blade { length: 0.02, height: 0.01, thickness: 0.007 },
                [0.0, 0.0, inner_offset_z],
            )
            .unwrap(),
        )),
        contact: ToolContact::Points,
        coupling: CouplingSpec::default(),
        stiffness: 300.0,
        damping: Some(0.0),
        cutting: Cutting::Remove,
        cut_force: 0.5,
        jaws: None,
        path: None,
    }
}

/// What pressing a tool into the liver did.
struct Press {
    /// Travel past the undeformed surface (m) and tool force (N) when the force first reached
    /// the limit, if it did before the first cut.
    reached: Option<(f64, f64)>,
    /// Travel and force when the first voxels were removed, if any were within 3 cm of travel.
    cut: Option<(f64, f64)>,
    /// The largest force before the first cut (N).
    peak: f64,
}

/// Pushes `tool` up into the liver's underside below its centre, 0.05 mm a step from 1 cm below
/// the surface to 3 cm past it, recording when the tissue first pushes back with `limit` N and
/// when the first voxels are removed.
fn press(tool: ToolSpec, limit: f64) -> Press {
    let mut sim = liver(vec![tool]);
    let positions = sim.surface_positions().unwrap();
    let surface = sim.surface().unwrap();
    let (cx, cy) = (0.118, 0.099);
    let bottom = surface
        .live_vertices()
        .iter()
        .map(|&v| positions[v as usize])
        .filter(|p| (p[0] - cx).abs() < 0.01 && (p[1] - cy).abs() < 0.01)
        .map(|p| p[2])
        .fold(f64::INFINITY, f64::min);
    // Tip up: the tool's +z (its shaft) points down.
    let up = [0.0, 1.0, 0.0, 0.0];
    let mut result = Press { reached: None, cut: None, peak: 0.0 };
    for step in 0..800 {
        let travel = -0.01 + 5e-5 * f64::from(step);
        let pose = ToolPose::new([cx, cy, bottom + travel], up, 0.0).unwrap();
        let inputs =
            StepInputs { tools: vec![ToolInput { tool: 0, pose }], ..StepInputs::default() };
        let frame = sim.step(&inputs).unwrap();
        let force = frame.surgical.tools[0].force()[2].abs();
        if frame.counters.voxels_removed > 0 {
            result.cut = Some((travel, force));
            return result;
        }
        result.peak = result.peak.max(force);
        if force >= limit && result.reached.is_none() {
            result.reached = Some((travel, force));
        }
    }
    result
}

#[test]
fn under_the_same_force_a_broad_tool_pushes_and_a_sharp_one_cuts() {
    // Paper 1 Fig. 11: the same blade sits 2 mm inside two outer shapes of the same length
    // (24 mm), one 9 mm wide, one 24 mm wide, pushed into the liver's underside. The narrow one
    // sinks in far enough for its blade to reach voxel centres; the most the tissue pushed back
    // on it before that is the force "at which it cuts". The broad one spreads the same force
    // over more surface: it reaches that force without cutting, and cuts later, if at all.
    let sharp = cutter("sharp", Primitive::Cuboid { half_extents: [0.012, 0.0045, 0.01] }, 0.002);
    let broad = cutter("broad", Primitive::Cuboid { half_extents: [0.012, 0.012, 0.01] }, 0.002);
    let show = |at: Option<(f64, f64)>| {
        at.map_or("never".to_owned(), |(t, f)| {
            format!("at {:.2} mm past the surface, {f:.3} N", t * 1e3)
        })
    };
    let sharp = press(sharp, f64::INFINITY);
    println!(
        "sharp: cutting starts {}; the most force before it {:.3} N",
        show(sharp.cut),
        sharp.peak
    );
    assert!(sharp.cut.is_some(), "the sharp tool never cuts");
    let same = sharp.peak;
    let broad = press(broad, same);
    println!(
        "broad: {same:.3} N reached {}; cutting starts {}",
        show(broad.reached),
        show(broad.cut)
    );
    assert!(
        broad.reached.is_some(),
        "the broad tool cuts before the tissue pushes back with {same} N"
    );
}
