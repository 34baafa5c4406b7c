//! Volume contact in the step (`[volume_contact]`): two tissues dropped onto each other come to
//! rest without interpenetrating, and the two halves of a severed bar driven into each other are
//! pushed apart again; on a GPU, against a held tissue too, as on the CPU. Each case runs the same scene without volume contact too, to show what
//! the contact prevents (so the checks can fail).

use incise_grid::{GridEdit, LabelVolume};
use incise_math::Vec3;
use incise_sim::{Frame, SceneConfig, Simulation, StepInputs, ToolInput};
use incise_tool::{Pose, ToolPose};

/// Voxel edge (m).
const H: f64 = 0.005;

/// A scene on a label volume read as a file (stride 1), of tissues 1 (E = 3 kPa) and 2
/// (E = 10 kPa), ν = 0.45, 1000 kg/m³, corotational at level 0, implicit Euler at `dt`, with
/// `body` adding gravity, holds and the contact.
fn config(dt: f64, body: &str) -> SceneConfig {
    let text = format!(
        "name = \"contact\"
level = 0
{body}
[volume]
file = \"two.inr\"
stride = [1, 1, 1]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[[materials]]
label = 2
youngs_modulus = 10000.0
poisson_ratio = 0.45
density = 1000.0
[model]
kind = \"corotational\"
[integrator]
kind = \"implicit-euler\"
dt = {dt:?}
rayleigh_alpha = 2.0
rayleigh_beta = 0.01
[surface]
interfaces = true
"
    );
    SceneConfig::from_toml(&text, "contact.toml").unwrap()
}

/// A `dims` volume of `H` voxels, labelled by `label(i, j, k)`.
fn volume(dims: [usize; 3], label: impl Fn(usize, usize, usize) -> u16) -> LabelVolume {
    let mut labels = Vec::with_capacity(dims.iter().product());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                labels.push(label(i, j, k));
            }
        }
    }
    LabelVolume::new(dims, [H; 3], labels).unwrap()
}

fn step(sim: &mut Simulation, inputs: &StepInputs) -> Frame {
    let frame = sim.step(inputs).unwrap();
    let s = sim.state();
    assert!(
        s.x.iter().chain(&s.v).all(|p| p.iter().all(|c| c.is_finite())),
        "a node is not finite"
    );
    frame
}

/// The deformed positions of the live surface vertices of each tissue (by label), by id.
fn vertices_by_label(sim: &Simulation) -> Vec<(u16, u32, Vec3)> {
    let g = sim.surface_geometry(None, None).unwrap();
    let mut label_of = std::collections::BTreeMap::new();
    for (t, &label) in g.triangles.iter().zip(&g.triangle_labels) {
        for &v in t {
            label_of.insert(v, label);
        }
    }
    g.vertex_ids
        .iter()
        .zip(&g.positions)
        .filter_map(|(v, p)| label_of.get(v).map(|&l| (l, *v, p.map(f64::from))))
        .collect()
}

/// Mean z of the vertices among `ids`.
fn mean_z(sim: &Simulation, ids: &[u32]) -> f64 {
    let all = vertices_by_label(sim);
    let zs: Vec<f64> =
        all.iter().filter(|(_, v, _)| ids.binary_search(v).is_ok()).map(|(_, _, p)| p[2]).collect();
    assert_eq!(zs.len(), ids.len(), "the faces' vertices stay live");
    zs.iter().sum::<f64>() / zs.len() as f64
}

/// A 40 × 40 × 20 mm slab of tissue 2 held at its base, and a 20 mm cube of tissue 1 centred
/// 10 mm above it, falling under gravity for `frames` steps of 5 ms. Returns the gap between the
/// cube's bottom face and the slab's top face under it (m, mean z of their rest-face vertices),
/// the fastest node at the end (m/s), and the largest overlap volume measured in the last 100
/// steps (m³).
fn drop_cube(contact: &str, frames: usize) -> (f64, f64, f64) {
    let v = volume([8, 8, 10], |i, j, k| match k {
        0..4 => 2,
        6..10 if (2..6).contains(&i) && (2..6).contains(&j) => 1,
        _ => 0,
    });
    let body =
        format!("gravity = [0.0, 0.0, -9.81]\n[[fixed]]\nplane = \"z\"\nvalue = 0.0\n{contact}");
    let config = config(0.005, &body);
    let mut sim = Simulation::new(&config, &v, "contact.toml").unwrap();
    // Without contact the scene builds no surface of its own.
    sim.enable_surface();
    // The faces at rest: the cube's bottom at z = 30 mm, the slab's top at 20 mm (under the cube).
    let rest = vertices_by_label(&sim);
    let face = |label: u16, z: f64| -> Vec<u32> {
        let mut ids: Vec<u32> = rest
            .iter()
            .filter(|(l, _, p)| {
                *l == label
                    && (p[2] - z).abs() < 1e-9
                    && (0..2).all(|a| (0.01 + 1e-9..0.03 - 1e-9).contains(&p[a]))
            })
            .map(|(_, v, _)| *v)
            .collect();
        ids.sort_unstable();
        assert!(!ids.is_empty(), "a face of tissue {label} at z = {z}");
        ids
    };
    let (bottom, top) = (face(1, 0.030), face(2, 0.020));
    let mut overlap: f64 = 0.0;
    for f in 0..frames {
        let frame = step(&mut sim, &StepInputs::default());
        if f + 100 >= frames {
            overlap = overlap.max(frame.counters.overlap_volume);
        }
    }
    let speed = sim.state().v.iter().map(|v| v.iter().map(|c| c * c).sum::<f64>().sqrt());
    (mean_z(&sim, &bottom) - mean_z(&sim, &top), speed.fold(0.0, f64::max), overlap)
}

#[test]
fn two_tissues_dropped_onto_each_other_come_to_rest_without_interpenetrating() {
    // The cube weighs 8 g over 4 cm² of contact: 196 Pa, which the default pressure of
    // 10 kPa per mm holds at 0.02 mm of depth. Allowed: 0.2 mm (ten times that, 4 % of a
    // voxel), and the cube must have stopped: every node slower than 5 mm/s after 3 s (it hit
    // the slab at about 0.4 m/s).
    let contact = "[volume_contact]\npairs = [[1, 2]]\n";
    let (gap, speed, overlap) = drop_cube(contact, 600);
    let depth = overlap / 4e-4;
    println!(
        "with contact: gap {:.3} mm, fastest node {:.2} mm/s, overlap {:.3e} m³ (depth {:.4} mm)",
        gap * 1e3,
        speed * 1e3,
        overlap,
        depth * 1e3
    );
    assert!(gap > -2e-4, "the cube sank {:.3} mm into the slab", -gap * 1e3);
    assert!(gap < 1e-3, "the cube rests on the slab, not {:.3} mm above it", gap * 1e3);
    assert!(depth < 2e-4, "overlap depth {:.4} mm", depth * 1e3);
    assert!(speed < 5e-3, "still moving at {:.2} mm/s", speed * 1e3);
    // Without it the cube falls into the slab.
    let (gap, _, _) = drop_cube("", 600);
    println!("without: gap {:.1} mm", gap * 1e3);
    assert!(gap < -0.01, "without contact the cube should fall through: gap {gap}");
}

/// A 60 × 20 × 20 mm bar of tissue 1, no gravity, nothing held, severed across its middle
/// (x = 30 mm), and with `opened`, the 5 mm layer of voxels beyond the cut removed too. For the first 40 steps of 1 ms each half is pushed toward the other (0.1 N on
/// its nodes more than 1 mm from the cut, in all); then nothing pushes, for `frames` steps in
/// all. Returns the gap between the walls of the cut (mean x of the right wall's vertices minus
/// the left's) and the left half's mean velocity along x at the end, and the deepest overlap
/// seen (m³).
fn collide_halves(contact: &str, frames: usize, opened: bool) -> (f64, f64, f64) {
    let v = volume([12, 4, 4], |_, _, _| 1);
    let config = config(0.001, &format!("gravity = [0.0, 0.0, 0.0]\n{contact}"));
    let mut sim = Simulation::new(&config, &v, "contact.toml").unwrap();
    if let Some(gpu) = incise_scene::attach_gpu(&mut sim) {
        println!("{gpu}");
    }
    sim.enable_surface();
    let before: Vec<u32> = sim.surface().unwrap().live_vertices().to_vec();
    let links: Vec<(u32, u32)> = (0..16u32).map(|jk| (jk * 12 + 5, jk * 12 + 6)).collect();
    let remove_voxels =
        if opened { (0..16u32).map(|jk| jk * 12 + 6).collect() } else { Vec::new() };
    sim.cut(&GridEdit { remove_voxels, sever_links: links }).unwrap();
    let surface = sim.surface().unwrap();
    let walls: Vec<u32> = surface
        .live_vertices()
        .iter()
        .copied()
        .filter(|v| before.binary_search(v).is_err())
        .collect();
    // A wall vertex's owner voxel is on its side of the cut (voxel columns 0–5 and 6–11).
    let on_left = |x: u32| surface.owner_voxel(x).unwrap() % 12 < 6;
    let (left, right): (Vec<u32>, Vec<u32>) = walls.iter().partition(|&&w| on_left(w));
    assert!(!left.is_empty() && !right.is_empty(), "the cut made both walls");
    let rest = sim.state().x.clone();
    let pushed: Vec<(usize, f64)> = rest
        .iter()
        .enumerate()
        .filter(|(_, p)| (p[0] - 0.03).abs() > 1e-3)
        .map(|(n, p)| (n, if p[0] < 0.03 { 1.0 } else { -1.0 }))
        .collect();
    let per_node = 0.1 / (pushed.len() as f64 / 2.0);
    let mut deepest: f64 = 0.0;
    for f in 0..frames {
        let node_forces = if f < 40 {
            pushed.iter().map(|&(n, s)| (n, [s * per_node, 0.0, 0.0])).collect()
        } else {
            Vec::new()
        };
        let frame = step(&mut sim, &StepInputs { node_forces, ..StepInputs::default() });
        deepest = deepest.max(frame.counters.overlap_volume);
    }
    let g = sim.surface_geometry(None, None).unwrap();
    let mean_x = |ids: &[u32]| -> f64 {
        let xs: Vec<f64> = g
            .vertex_ids
            .iter()
            .zip(&g.positions)
            .filter(|(v, _)| ids.contains(v))
            .map(|(_, p)| f64::from(p[0]))
            .collect();
        xs.iter().sum::<f64>() / xs.len() as f64
    };
    let v = &sim.state().v;
    let left_nodes: Vec<usize> = (0..rest.len()).filter(|&n| rest[n][0] < 0.03 - 1e-3).collect();
    let left_v = left_nodes.iter().map(|&n| v[n][0]).sum::<f64>() / left_nodes.len() as f64;
    (mean_x(&right) - mean_x(&left), left_v, deepest)
}

#[test]
fn a_severed_organs_halves_driven_into_each_other_are_pushed_apart_again() {
    // The walls of a cut overlap the moment the halves move into each other. With
    // `self = true` the overlap around the cut is pushed apart: after the push stops, the walls
    // end apart or touching (gap above −0.2 mm) and the left half moves away from the right (or
    // rests). Without it the halves pass into each other and keep going.
    let (gap, left_v, deepest) = collide_halves("[volume_contact]\nself = true\n", 300, false);
    println!(
        "with contact: gap {:.3} mm, left half {:.2} mm/s, deepest overlap {:.3e} m³",
        gap * 1e3,
        left_v * 1e3,
        deepest
    );
    assert!(deepest > 0.0, "the walls overlapped while pushed");
    assert!(gap > -2e-4, "the walls overlap by {:.3} mm", -gap * 1e3);
    assert!(left_v <= 1e-4, "the left half still moves into the right at {:.2} mm/s", left_v * 1e3);
    let (gap, left_v, _) = collide_halves("", 300, false);
    println!("without: gap {:.2} mm, left half {:.2} mm/s", gap * 1e3, left_v * 1e3);
    assert!(gap < -1e-3, "without contact the halves pass into each other: gap {gap}");
}

#[test]
fn on_a_gpu_the_halves_are_pushed_apart_as_on_the_cpu() {
    // `gpu = "on"` takes any adapter (a software one here). The device's overlap volumes are
    // f32, a relative 1e-7 of the CPU's (incise_gpu's parity tests). The halves start 5 mm apart
    // (a layer of voxels removed at the cut), so every overlap either run sees is made by the
    // halves' motion; walls that start coincident would leave which zero-thickness intervals a
    // ray sees, and so the first frames' contact, to rounding. Measured: 0.06 µm of gap apart,
    // deepest overlaps equal to 5 digits. Required: the same outcome as the CPU's test (walls
    // apart or touching, the halves not moving into each other), within 1 µm of gap and 0.1 %
    // of the deepest overlap of the CPU's run.
    let contact = "gpu = \"on\"\n[volume_contact]\nself = true\n";
    let (gap_gpu, v_gpu, deep_gpu) = collide_halves(contact, 300, true);
    let (gap_cpu, v_cpu, deep_cpu) = collide_halves("[volume_contact]\nself = true\n", 300, true);
    println!(
        "GPU: gap {:.6} mm, left half {:.4} mm/s, deepest {deep_gpu:.6e} m³; CPU: {:.6} mm, {:.4} mm/s, {deep_cpu:.6e} m³",
        gap_gpu * 1e3,
        v_gpu * 1e3,
        gap_cpu * 1e3,
        v_cpu * 1e3
    );
    assert!(deep_cpu > 0.0, "the halves met");
    assert!(gap_gpu > -2e-4 && v_gpu <= 1e-4, "on the GPU the walls overlap or close");
    assert!((gap_gpu - gap_cpu).abs() < 1e-6, "gap {gap_gpu} against {gap_cpu}");
    assert!(
        (deep_gpu - deep_cpu).abs() <= 1e-3 * deep_cpu,
        "deepest {deep_gpu} against {deep_cpu}"
    );
}

fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// A 40 × 40 × 15 mm slab of tissue 1 held at its bottom, no gravity, pressed from above by a
/// flat punch: a 20 × 20 × 10 mm box mesh (12 triangles) whose bottom face is at the tool's
/// origin, pushing by volume contact. It is lowered to `depth` (m) below the slab's top over
/// 100 steps of 1 ms, then held 200. Returns the last frame's tool force, the overlap volume
/// and the surface points bounding it, and the least and the mean the slab's top sank under
/// the punch (m, over its vertices more than 1 mm inside the punch's footprint).
fn press_punch(depth: f64) -> (Vec3, f64, usize, (f64, f64)) {
    use incise_sim::config::ShapeSpec;
    use incise_tool::Shape;
    let v = volume([8, 8, 3], |_, _, _| 1);
    let body = "gravity = [0.0, 0.0, 0.0]
[[fixed]]
plane = \"z\"
value = 0.0
[[tools]]
name = \"punch\"
contact = \"volume\"
outer = { mesh = \"punch.stl\" }
";
    let mut config = config(0.001, body);
    let half = 0.01;
    let corners: Vec<Vec3> = (0..8)
        .map(|i| {
            let at = |bit: usize, lo: f64, hi: f64| if i >> bit & 1 == 1 { hi } else { lo };
            [at(0, -half, half), at(1, -half, half), at(2, 0.0, 0.01)]
        })
        .collect();
    let faces =
        [[0, 2, 6, 4], [1, 3, 7, 5], [0, 1, 5, 4], [2, 3, 7, 6], [0, 1, 3, 2], [4, 5, 7, 6]];
    // Each triangle turned to face away from the box's centre.
    let triangles = faces
        .iter()
        .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
        .map(|t: [u32; 3]| {
            let p = t.map(|i| corners[i as usize]);
            let (u, w) = (sub(p[1], p[0]), sub(p[2], p[0]));
            let n =
                [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
            let out = [p[0][0], p[0][1], p[0][2] - 0.005];
            if (0..3).map(|k| n[k] * out[k]).sum::<f64>() < 0.0 { [t[0], t[2], t[1]] } else { t }
        })
        .collect();
    let punch = incise_mesh::TriMesh::new(corners, triangles).unwrap();
    config.tools[0].outer = ShapeSpec::Shape(Shape::mesh(&punch, [0.0; 3]).unwrap());
    let mut sim = Simulation::new(&config, &v, "contact.toml").unwrap();
    let (top, centre) = (0.015, [0.0203, 0.0197]);
    let mut last = None;
    for i in 0..300 {
        let lowered = depth * (f64::from(i.min(100)) / 100.0);
        let pose =
            ToolPose::from_pose(Pose::at([centre[0], centre[1], top - lowered]), 0.0).unwrap();
        let inputs =
            StepInputs { tools: vec![ToolInput { tool: 0, pose }], ..StepInputs::default() };
        last = Some(step(&mut sim, &inputs));
    }
    let frame = last.unwrap();
    let tool = &frame.surgical.tools[0];
    let g = sim.surface_geometry(None, None).unwrap();
    let sunk: Vec<f64> = g
        .positions
        .iter()
        .filter(|p| {
            f64::from(p[2]) > 0.5 * top
                && (0..2).all(|a| (f64::from(p[a]) - centre[a]).abs() < half - 0.001)
        })
        .map(|p| top - f64::from(p[2]))
        .collect();
    assert!(sunk.len() >= 9, "vertices under the punch: {sunk:?}");
    let least = sunk.iter().copied().fold(f64::INFINITY, f64::min);
    let mean = sunk.iter().sum::<f64>() / sunk.len() as f64;
    (tool.force(), tool.overlap_volume, tool.contact_points, (least, mean))
}

#[test]
fn a_tool_mesh_pressed_into_an_organ_is_pushed_back_by_the_overlap_volume() {
    // With contact = "volume" the punch's mesh is measured against the slab's surface by
    // layered depth images, as an organ against an organ: the slab is pushed down, the punch
    // up. Under a flat punch both sides of the overlap are flat faces of the same area `a`, so
    // the penalty's area is `a`, and its force is `k_p V` (pressure × overlap volume): the
    // known answer the force is checked against (within 5 %: the volume reported is the
    // step's start, the force its end, and the frames are at rest to well under that). The
    // punch is pushed straight up (sideways under 1 % of it), harder the deeper it goes
    // (1, 2, 3 mm), and the slab's top under it sinks on average by the press less the
    // penalty's depth `V / a` (within 0.1 mm, a fiftieth of the 5 mm triangles the mean is
    // sampled on). The penalty presses each connected overlap with one pressure (its volume's
    // gradient), so the surface under the punch takes the slab's shape under a uniform load,
    // not the punch's flat face: single vertices sink unequally, and each must sink by at
    // least 80 % of the press. A contact that did not push would leave the slab unmoved.
    let pressure = 1e7;
    let area = 0.02 * 0.02;
    let mut previous = 0.0;
    for depth in [0.001, 0.002, 0.003] {
        let (force, overlap, points, (least, mean)) = press_punch(depth);
        let penalty_depth = overlap / area;
        println!(
            "pressed {:.0} mm: force {:?} N (k_p V = {:.4} N) over {points} surface points; \
             top sunk {:.3} mm on average, {:.3} mm at least, press less penalty depth {:.3} mm",
            depth * 1e3,
            force,
            pressure * overlap,
            mean * 1e3,
            least * 1e3,
            (depth - penalty_depth) * 1e3
        );
        assert!(points > 0 && overlap > 0.0, "the punch touches the slab");
        assert!(force[2] > previous, "the punch is pushed up, harder when deeper: {force:?}");
        assert!(force[0].hypot(force[1]) < 0.01 * force[2], "pushed straight back: {force:?}");
        let expected = pressure * overlap;
        assert!(
            (force[2] - expected).abs() < 0.05 * expected,
            "force {} N, k_p V {expected} N",
            force[2]
        );
        assert!((mean - (depth - penalty_depth)).abs() < 1e-4, "the top sank {mean} m on average");
        assert!(least > 0.8 * depth, "a vertex under the punch sank only {least} m");
        previous = force[2];
    }
}

/// The voxels a spherical cutter (radius 7.3 mm) drawn through the 60 × 20 × 20 mm bar along
/// x removes over 50 steps, with `gpu` the scene's key and the device's marks checked against
/// the CPU's; also the voxels the two disagreed on and the adapter, if one was used.
fn cut_through_bar(gpu: &str) -> (Vec<u32>, usize, Option<String>) {
    let v = volume([12, 4, 4], |_, _, _| 1);
    let body = format!(
        "gravity = [0.0, 0.0, 0.0]
gpu = \"{gpu}\"
[volume_contact]
self = true
[[tools]]
name = \"cutter\"
stiffness = 100.0
cutting = \"remove\"
outer = {{ shape = \"sphere\", radius = 0.0075 }}
inner = {{ shape = \"sphere\", radius = 0.0073 }}
"
    );
    let mut sim = Simulation::new(&config(0.001, &body), &v, "contact.toml").unwrap();
    incise_scene::attach_gpu(&mut sim);
    sim.check_gpu(true);
    let (mut removed, mut mismatches) = (Vec::new(), 0);
    for i in 0..50 {
        let position = [0.004 + 0.001 * f64::from(i), 0.0103, 0.0121];
        let pose = ToolPose::from_pose(Pose::at(position), 0.0).unwrap();
        let inputs =
            StepInputs { tools: vec![ToolInput { tool: 0, pose }], ..StepInputs::default() };
        let frame = step(&mut sim, &inputs);
        removed.extend_from_slice(&frame.surgical.edit.remove_voxels);
        mismatches += frame.counters.gpu_cpu_cut_mismatches;
    }
    removed.sort_unstable();
    (removed, mismatches, sim.gpu())
}

#[test]
fn on_a_gpu_a_cutter_removes_the_voxels_it_removes_on_the_cpu() {
    // The device tests the voxel centres near the cutter in f32, a few 1e-9 m from the CPU's
    // f64 on a 6 cm bar: only a centre that close to the sphere could come out differently.
    // The path runs off the voxel lattice, so none does; the runs are deterministic, and the
    // two must agree on every voxel tested, and so on the cut.
    let (gpu_cut, mismatches, adapter) = cut_through_bar("on");
    let (cpu_cut, _, none) = cut_through_bar("off");
    println!(
        "{} voxels removed on {adapter:?}, {} on the CPU; {mismatches} marked differently",
        gpu_cut.len(),
        cpu_cut.len()
    );
    assert!(none.is_none() && adapter.is_some(), "a device on \"on\" (a software one here)");
    assert!(cpu_cut.len() > 20, "the cutter cut through the bar: {cpu_cut:?}");
    assert_eq!(mismatches, 0, "the device's marks are the CPU's");
    assert_eq!(gpu_cut, cpu_cut);
}

#[test]
fn the_gpu_key_never_fails_a_scene_and_auto_takes_no_software_adapter() {
    let v = volume([4, 4, 4], |_, _, _| 1);
    let build = |body: &str| {
        let mut sim = Simulation::new(&config(0.001, body), &v, "contact.toml").unwrap();
        let said = incise_scene::attach_gpu(&mut sim);
        (sim, said)
    };
    // No volume contact: no device, whatever the key says.
    let (sim, said) = build("gpu = \"on\"\n");
    assert_eq!((sim.gpu(), said), (None, None));
    // "auto": a hardware adapter or the CPU, never a software one, and never an error.
    let (mut sim, said) = build("gpu = \"auto\"\n[volume_contact]\nself = true\n");
    let said = said.expect("auto says what it chose");
    println!("{said}");
    match sim.gpu() {
        Some(name) => assert!(!name.contains("(Cpu,"), "auto took a software adapter: {name}"),
        None => assert!(said.contains("on the CPU"), "{said}"),
    }
    step(&mut sim, &StepInputs::default());
    // "off" asks for nothing.
    let (sim, said) = build("gpu = \"off\"\n[volume_contact]\nself = true\n");
    assert_eq!((sim.gpu(), said), (None, None));
}

#[test]
fn every_ray_crosses_the_liver_and_kidney_surfaces_as_often_in_as_out() {
    // A voxel surface's vertical walls, seen along an axis, put a wall's vertices onto the same
    // projected points, and the CT's lattice puts pixel centres onto those lines at some
    // resolutions. The rasteriser's tie rule must still count every crossing once: a ray that
    // enters a closed surface more often than it leaves breaks every interval behind it. Here
    // the liver-on-kidney scene's two surfaces at rest, over each surface's box and the pair's
    // common box, at resolutions up to 512 per side.
    use incise_tool::volume_contact::{Ldi, TriangleSurface, View};
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/scenes/liver_kidney.toml");
    let scene = incise_scene::read_scene(&path).unwrap();
    let sim = Simulation::new(&scene.config, &scene.geometry, "liver_kidney").unwrap();
    let surface = sim.surface().expect("the scene has a surface");
    let positions = sim.surface_positions().unwrap();
    let groups = surface.triangles_by_group();
    let sides: Vec<TriangleSurface<'_>> = groups
        .iter()
        .filter(|g| !g.is_empty())
        .map(|triangles| TriangleSurface { positions: &positions, triangles })
        .collect();
    assert!(sides.len() >= 2, "liver and kidney surfaces");
    let bounds: Vec<(Vec3, Vec3)> = sides.iter().map(|s| s.bounds().unwrap()).collect();
    let common: (Vec3, Vec3) = (
        std::array::from_fn(|k| bounds.iter().map(|b| b.0[k]).fold(f64::MIN, f64::max)),
        std::array::from_fn(|k| bounds.iter().map(|b| b.1[k]).fold(f64::MAX, f64::min)),
    );
    let (mut rays, mut broken) = (0usize, Vec::new());
    for (s, side) in sides.iter().enumerate() {
        for region in [bounds[s], common] {
            for resolution in [64, 100, 128, 250, 256, 384, 500, 512] {
                for axis in 0..3 {
                    let view = View::covering(axis, region.0, region.1, resolution);
                    let ldi = Ldi::rasterize(side, &view);
                    for p in 0..ldi.pixel_count() {
                        let winding: i32 =
                            ldi.pixel(p).iter().map(|f| if f.entering { 1 } else { -1 }).sum();
                        rays += 1;
                        if winding != 0 {
                            broken.push((s, resolution, axis, p, winding));
                        }
                    }
                }
            }
        }
    }
    println!("{rays} rays, {} with a non-zero winding past the surface", broken.len());
    assert!(broken.is_empty(), "(surface, resolution, axis, pixel, winding): {broken:?}");
}

/// A cube of tissue 1 resting on a slab of tissue 2 held whole, `frames` steps of 5 ms under
/// gravity with the device's passes checked against the CPU's at `resolution`: the largest
/// relative difference of a pass's overlap volume, and the largest overlap volume (m³).
fn cube_on_held_slab(resolution: usize, frames: usize) -> (f64, f64) {
    let v = volume([8, 8, 8], |i, j, k| match k {
        0..4 => 2,
        4..7 if (2..6).contains(&i) && (2..6).contains(&j) => 1,
        _ => 0,
    });
    let body = format!(
        "gravity = [0.0, 0.0, -9.81]
gpu = \"on\"
[[fixed]]
label = 2
[volume_contact]
pairs = [[1, 2]]
resolution = {resolution}
"
    );
    let mut sim = Simulation::new(&config(0.005, &body), &v, "contact.toml").unwrap();
    incise_scene::attach_gpu(&mut sim);
    sim.check_gpu(true);
    let (mut diff, mut overlap): (f64, f64) = (0.0, 0.0);
    for _ in 0..frames {
        let frame = step(&mut sim, &StepInputs::default());
        diff = diff.max(frame.counters.gpu_cpu_volume_diff);
        overlap = overlap.max(frame.counters.overlap_volume);
    }
    (diff, overlap)
}

#[test]
fn against_a_held_tissue_the_device_measures_the_overlap_as_the_cpu_does() {
    // The pair is looked at over the held slab's own box (grown off the voxel lattice), the CPU
    // reusing the slab's images from step to step; the device draws both surfaces every step.
    // Its depths are f32: a relative 1e-7 of these 5 mm voxels, and an overlap a fraction of a
    // millimetre thick is then measured to some 1e-5. Measured 1e-5 to 3e-5; allowed 1e-4, the
    // parity tests' tolerance.
    for resolution in [8, 32] {
        let (diff, overlap) = cube_on_held_slab(resolution, 60);
        println!("resolution {resolution}: overlap up to {overlap:.3e} m³, GPU/CPU {diff:.2e}");
        assert!(overlap > 0.0, "the cube sinks into the slab");
        assert!(diff <= 1e-4, "at {resolution} per side the device's volume is {diff:.1e} off");
    }
}
