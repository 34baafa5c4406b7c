//! Hard cases of the tool proxy: a tool pressed deep, jabbed in, pulled in by a spring, and
//! pressed and released many times stays outside the tissue, pushes back harder the deeper its
//! device goes, and gives the hand no energy.

use super::{DOWN_G, block, config, input};
use incise_math::Vec3;
use incise_sim::{Frame, SceneConfig, Simulation, StepInputs};
use incise_tool::proxy::triangle_gap;
use incise_tool::{Pose, Shape};

/// The embedded demo scene's organ, with its two tools.
fn demo() -> Simulation {
    let config = SceneConfig::from_toml(incise_scene::DEMO_SCENE, "demo.toml").unwrap();
    let volume = config.procedural_volume().unwrap();
    Simulation::new(&config, &volume, "demo.toml").unwrap()
}

/// Open jaws: a grasper that only pushes.
const OPEN: f64 = 1.0;

fn posed(tool: usize, position: Vec3, rotation: [f64; 4], gripper: f64) -> StepInputs {
    StepInputs { tools: vec![input(tool, position, rotation, gripper)], ..StepInputs::default() }
}

/// The least signed distance between `shape` at `pose` and the organ's surface as it is now
/// (m; negative: the surface reaches into the shape by that much).
fn surface_gap(sim: &Simulation, shape: &Shape, pose: &Pose) -> f64 {
    let positions = sim.surface_positions().unwrap();
    sim.surface()
        .unwrap()
        .triangle_list()
        .iter()
        .map(|t| {
            let corners = t.map(|v| pose.tool_from_grid(positions[v as usize]));
            triangle_gap(shape, &corners).distance
        })
        .fold(f64::INFINITY, f64::min)
}

/// The highest surface vertex within `r` of the vertical through `(x, y)`, and the lowest.
fn surface_z(sim: &Simulation, x: f64, y: f64, r: f64) -> (f64, f64) {
    let positions = sim.surface_positions().unwrap();
    let near = sim
        .surface()
        .unwrap()
        .live_vertices()
        .iter()
        .map(|&v| positions[v as usize])
        .filter(|p| (p[0] - x).hypot(p[1] - y) < r)
        .map(|p| p[2]);
    near.fold((f64::NEG_INFINITY, f64::INFINITY), |(hi, lo), z| (hi.max(z), lo.min(z)))
}

/// The lowest surface point within `r` of the vertical through `(x, y)` and the outward normal of
/// the surface around it (the triangles within 3 mm, weighted by area).
fn underside(sim: &Simulation, x: f64, y: f64, r: f64) -> (Vec3, Vec3) {
    let positions = sim.surface_positions().unwrap();
    let surface = sim.surface().unwrap();
    let lowest = surface
        .live_vertices()
        .iter()
        .map(|&v| positions[v as usize])
        .filter(|p| (p[0] - x).hypot(p[1] - y) < r)
        .min_by(|a, b| a[2].total_cmp(&b[2]))
        .unwrap();
    let mut n = [0.0; 3];
    for t in surface.triangle_list() {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let centre: Vec3 = std::array::from_fn(|k| (a[k] + b[k] + c[k]) / 3.0);
        if (0..3).map(|k| (centre[k] - lowest[k]).powi(2)).sum::<f64>() < 0.003f64.powi(2) {
            let (u, w): (Vec3, Vec3) =
                (std::array::from_fn(|k| b[k] - a[k]), std::array::from_fn(|k| c[k] - a[k]));
            let cross =
                [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]];
            for k in 0..3 {
                n[k] += cross[k];
            }
        }
    }
    let len = n.iter().map(|c| c * c).sum::<f64>().sqrt();
    (lowest, n.map(|c| c / len))
}

/// What a depth sweep saw.
struct Sweep {
    /// Frames past first contact: device depth below it (m), the force along the outward
    /// normal (N), the proxy's gap to the surface (m), how far the device is past the proxy along
    /// the normal (m: how deep the tool would be in the tissue), and whether going deeper.
    samples: Vec<(f64, f64, f64, f64, bool)>,
    /// The least force along the normal over the whole sweep (N).
    least_along: f64,
}

/// Moves `tool` of `sim` (shape `outer`) along `normal` (unit, out of the tissue) from `start`
/// toward the tissue at 2 mm/s until it first touches (the first frame with a force), on 10 mm
/// past that, and back out to where it first touched, 1 ms a frame.
fn depth_sweep(
    sim: &mut Simulation,
    tool: usize,
    outer: &Shape,
    start: Vec3,
    normal: Vec3,
    rotation: [f64; 4],
    gripper: f64,
) -> Sweep {
    let speed = 0.002 * sim.config().dt();
    let at = |s: f64| -> Vec3 { std::array::from_fn(|k| start[k] - s * normal[k]) };
    let mut travel = 0.0;
    let mut contact_at = None;
    let mut sweep = Sweep { samples: Vec::new(), least_along: f64::INFINITY };
    let mut frames = 0;
    let mut going_in = true;
    loop {
        let frame: Frame = sim.step(&posed(tool, at(travel), rotation, gripper)).unwrap();
        frames += 1;
        assert!(frames < 40_000, "the sweep never touched");
        let t = &frame.surgical.tools[tool];
        let along: f64 = (0..3).map(|k| t.force()[k] * normal[k]).sum();
        sweep.least_along = sweep.least_along.min(along);
        if contact_at.is_none() && along > 0.0 {
            contact_at = Some(travel);
        }
        if let Some(c) = contact_at {
            let proxy = t.proxy.expect("a proxy");
            let gap = surface_gap(sim, outer, &proxy);
            let past: Vec3 =
                std::array::from_fn(|k| proxy.position()[k] - t.pose.unwrap().pose().position()[k]);
            let device = (0..3).map(|k| past[k] * normal[k]).sum::<f64>();
            sweep.samples.push((travel - c, along, gap, device, going_in));
            if going_in && travel - c >= 0.01 {
                going_in = false;
            }
            if !going_in && travel <= c {
                break;
            }
        }
        travel += if going_in { speed } else { -speed };
    }
    sweep
}

/// Checks a sweep's invariants: the force along the normal never points into the tissue, is
/// never zero while the device is past the contact (more than 0.01 mm past its proxy, which
/// lies on the tissue, along the normal), does not fall while the device goes deeper (never
/// below the most it reached before by more than 2 % of the sweep's largest force), and the
/// proxy stays within 0.1 mm of the surface.
///
/// The 0.01 mm: a frame finds its contact where the tissue is at its start, so tissue rising
/// toward a device that backs off slowly (the organ springing back behind the tool) meets it
/// within the frame and is pushed from the next; at 2 mm/s that is a few micrometres. The 2 %
/// of the largest force: where the proxy starts pushing, the tissue's nodes take up the device's
/// speed through the coupling (critically damped by default), a transient of a few
/// millinewtons over the first hundredth of a millimetre; the slack is the sweep's, not the
/// transient's own size.
fn check(sweep: &Sweep, what: &str) {
    let peak = sweep.samples.iter().filter(|s| s.4).map(|s| s.1).fold(0.0, f64::max);
    let mut previous: Option<f64> = None;
    let (mut deepest, mut most, mut worst_gap, mut worst_dip) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for &(depth, along, gap, device, deeper) in &sweep.samples {
        if device > 1e-5 {
            assert!(
                along > 0.0,
                "{what}: no force with the device {:.3} mm past its proxy ({:.3} mm past first \
                 contact)",
                device * 1e3,
                depth * 1e3
            );
        }
        if depth > 1e-9 {
            worst_gap = worst_gap.max(gap.abs());
        }
        if deeper {
            if let Some(p) = previous {
                worst_dip = worst_dip.max(p - along);
                assert!(
                    along >= p - 0.02 * peak,
                    "{what}: the force fell from {p} to {along} N going deeper, at {:.3} mm",
                    depth * 1e3
                );
            }
            previous = Some(previous.map_or(along, |p| p.max(along)));
        }
        deepest = deepest.max(depth);
        most = most.max(along);
    }
    println!(
        "{what}: {} frames past contact, {:.2} mm deep, force up to {most:.4} N (largest dip \
         going deeper {:.2e} N), proxy within {:.4} mm of the surface, least force along the \
         normal {:.2e} N",
        sweep.samples.len(),
        deepest * 1e3,
        worst_dip,
        worst_gap * 1e3,
        sweep.least_along
    );
    assert!(sweep.least_along >= 0.0, "{what}: the force pointed into the tissue");
    assert!(worst_gap <= 1e-4, "{what}: the proxy was {worst_gap} m from the surface");
}

/// Depth sweep: the demo's grasper (a 2 mm ball over 2.5 mm voxels), jaws open, lowered onto the
/// top of the organ (an ellipsoid: at the top its surface is level) at 2 mm/s, 10 mm past first
/// contact and back.
#[test]
fn a_small_ball_pressed_10_mm_deep_stays_on_the_surface_and_pushes_back_harder() {
    let mut sim = demo();
    let grasper = 1;
    let outer = Shape::new(incise_tool::Primitive::Sphere { radius: 0.002 }, [0.0; 3]).unwrap();
    let (x, y) = (0.04, 0.03);
    let (top, _) = surface_z(&sim, x, y, 0.003);
    let sweep = depth_sweep(
        &mut sim,
        grasper,
        &outer,
        [x, y, top + 0.004],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0, 0.0],
        OPEN,
    );
    for (i, s) in sweep.samples.iter().enumerate() {
        if i % 500 == 0 {
            println!("{:.3} mm: {:.5} N, gap {:.2e}, device {:.2e}", s.0 * 1e3, s.1, s.2, s.3);
        }
    }
    check(&sweep, "the demo's grasper");
}

/// The 13,648-voxel liver (the CT at stride 8, 8, 4: 5 mm voxels in 4 cm elements, hanging from
/// its top) with `tools`.
fn liver(tools: &str) -> Simulation {
    let path = incise_tests::scene("liver_13k.toml");
    let text = std::fs::read_to_string(&path).unwrap() + tools;
    let mut scene = incise_scene::read_scene(&path).unwrap();
    scene.config = SceneConfig::from_toml(&text, path.to_str().unwrap()).unwrap();
    Simulation::new(&scene.config, &scene.geometry, "liver_13k.toml").unwrap()
}

/// Steps `sim` untouched until it comes to rest under gravity (6 s: the liver swings down and
/// back for about five).
fn settle(sim: &mut Simulation) {
    for _ in 0..6000 {
        sim.step(&StepInputs::default()).unwrap();
    }
    let v = sim.state().v.iter().map(|v| v.iter().map(|c| c * c).sum::<f64>()).fold(0.0, f64::max);
    assert!(v.sqrt() < 1e-3, "still moving at {} m/s", v.sqrt());
}

/// Depth sweep: a 1 mm-radius ball (a fifth of a voxel) pushed up into the liver's underside at
/// its lowest point below its middle, where it hangs free (settled under gravity first), along
/// the surface's normal there at 2 mm/s, 10 mm past first contact and back.
#[test]
fn a_ball_a_fifth_of_a_voxel_pressed_10_mm_into_the_liver_stays_on_its_surface() {
    let mut sim = liver(
        "[[tools]]
name = \"probe\"
outer = { shape = \"sphere\", radius = 0.001 }
",
    );
    let outer = Shape::new(incise_tool::Primitive::Sphere { radius: 0.001 }, [0.0; 3]).unwrap();
    settle(&mut sim);
    let (point, normal) = underside(&sim, 0.118, 0.099, 0.01);
    println!("pressed at {point:?} along the normal {normal:?}");
    let start = std::array::from_fn(|k| point[k] + 0.003 * normal[k]);
    let sweep = depth_sweep(&mut sim, 0, &outer, start, normal, [1.0, 0.0, 0.0, 0.0], 0.0);
    check(&sweep, "a 1 mm ball on the liver");
}

/// The number of the tissue's fine voxels that are inverted: where, at the voxel's centre, the
/// trilinear map of the element that owns it no longer keeps its orientation (the Jacobian's
/// determinant is not positive). Voxels, not element corners: an element of a branched grid may
/// hold material in part of its cell only, and its empty corners carry nothing.
fn inverted(sim: &Simulation) -> usize {
    let (Some(grid), Some(model)) = (sim.grid(), sim.model()) else { return 0 };
    let x = &sim.state().x;
    let mut by_grid =
        vec![[0.0; 3]; model.grid_node.iter().map(|&g| g as usize + 1).max().unwrap()];
    for (p, &g) in x.iter().zip(&model.grid_node) {
        by_grid[g as usize] = *p;
    }
    let (size, h, dims) = (grid.element_size(), grid.spacing(), grid.fine().dims());
    let mut count = 0;
    for (id, e) in grid.top().elements() {
        let corners = e.nodes.map(|n| by_grid[n as usize]);
        let cell = grid.top().cell_coords(e.cell);
        for v in grid.element_voxels(id) {
            let c = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
            let xi: Vec3 = std::array::from_fn(|a| {
                ((f64::from(c[a]) + 0.5) * h[a] - f64::from(cell[a]) * size[a]) / size[a]
            });
            let mut j = [[0.0; 3]; 3];
            for (n, p) in corners.iter().enumerate() {
                let f = |a: usize| if n >> a & 1 == 1 { xi[a] } else { 1.0 - xi[a] };
                let d = |a: usize| if n >> a & 1 == 1 { 1.0 } else { -1.0 };
                let g = [d(0) * f(1) * f(2), f(0) * d(1) * f(2), f(0) * f(1) * d(2)];
                for r in 0..3 {
                    for s in 0..3 {
                        j[r][s] += p[r] * g[s];
                    }
                }
            }
            let det = j[0][0] * (j[1][1] * j[2][2] - j[1][2] * j[2][1])
                - j[0][1] * (j[1][0] * j[2][2] - j[1][2] * j[2][0])
                + j[0][2] * (j[1][0] * j[2][1] - j[1][1] * j[2][0]);
            if det <= 0.0 {
                count += 1;
            }
        }
    }
    count
}

/// Jab: a 2 mm ball 3 mm below the liver's underside (settled under gravity, where it hangs
/// free), its device jumps 5 cm up into the liver in one pose, stays there for 0.3 s, then
/// jumps back out. The proxy stays outside the tissue every frame (its ball clear of the surface
/// by no less than the contact's tolerance), no hexahedron inverts, and the force on the frame
/// the device leaves is no larger than the force held just before.
#[test]
fn a_jab_5_cm_into_the_liver_leaves_the_proxy_outside_and_no_kick() {
    let mut sim = liver(
        "[[tools]]
name = \"probe\"
outer = { shape = \"sphere\", radius = 0.002 }
",
    );
    let ball = Shape::new(incise_tool::Primitive::Sphere { radius: 0.002 }, [0.0; 3]).unwrap();
    settle(&mut sim);
    assert_eq!(inverted(&sim), 0, "at rest");
    let (point, normal) = underside(&sim, 0.118, 0.099, 0.01);
    let out: Vec3 = std::array::from_fn(|k| point[k] + 0.005 * normal[k]);
    let inside: Vec3 = std::array::from_fn(|k| out[k] - 0.05 * normal[k]);
    let unturned = [1.0, 0.0, 0.0, 0.0];
    for _ in 0..20 {
        sim.step(&posed(0, out, unturned, 0.0)).unwrap();
    }
    let mut held = 0.0f64;
    let mut least_gap = f64::INFINITY;
    for i in 0..300 {
        let frame = sim.step(&posed(0, inside, unturned, 0.0)).unwrap();
        let tool = &frame.surgical.tools[0];
        let proxy = tool.proxy.expect("a proxy");
        least_gap = least_gap.min(surface_gap(&sim, &ball, &proxy));
        assert_eq!(inverted(&sim), 0, "frame {i}: an element inverted");
        held = tool.force().iter().map(|c| c * c).sum::<f64>().sqrt();
        if i % 50 == 0 {
            let moved: f64 = (0..3).map(|k| (proxy.position()[k] - out[k]) * -normal[k]).sum();
            println!(
                "held {i} ms: force {held:.3} N, the proxy {:.2} mm in from the start",
                moved * 1e3
            );
        }
    }
    let exit = sim.step(&posed(0, out, unturned, 0.0)).unwrap().surgical.tools[0].force();
    let exit = exit.iter().map(|c| c * c).sum::<f64>().sqrt();
    println!(
        "held force {held:.3} N; on the frame the device left {exit:.3} N; the proxy's least gap \
         to the surface {:.4} mm",
        least_gap * 1e3
    );
    assert!(least_gap > -2e-6, "the proxy went {least_gap} m into the tissue");
    assert!(held > 0.0, "no force held");
    assert!(exit <= held, "the exit kicked: {exit} N after {held} N held");
}

/// A haptic device on one axis, held by a hand that pulls it toward `target` with a spring of
/// 8 N per centimetre that gives at most 8 N: a 50 g stylus damped by the hand's 2 N·s/m,
/// rendering the frame's force; semi-implicit Euler at the physics step.
struct Hand {
    position: f64,
    velocity: f64,
    target: f64,
}

impl Hand {
    const MASS: f64 = 0.05;
    const DAMPING: f64 = 2.0;

    /// One step of `dt` under the hand's pull and the `rendered` force along the axis.
    fn step(&mut self, rendered: f64, dt: f64) {
        let pull = 8.0 * ((self.target - self.position) / 0.01).clamp(-1.0, 1.0);
        let f = pull + rendered - Self::DAMPING * self.velocity;
        self.velocity += dt * f / Self::MASS;
        self.position += dt * self.velocity;
    }
}

/// Hand spring: a device pulled into tissue by an 8 N spring ([`Hand`]) for 1 s.
///
/// A ball (8 mm) pulled toward a point 5 cm inside the side of the 4 cm cube's held base (its
/// bottom 2 cm, which cannot give: the contact is pure geometry) presses with the spring's full
/// 8 N and does not enter: its proxy stays on the surface (within the contact's tolerance), the
/// coupling holds the pull (8 N, its largest force), and the held nodes never move. A scalpel (a
/// blade inside a box, `cut_force` = 2 N) pulled the same way into the same held face, edge
/// first, cuts, and its proxy enters the tissue: its edge goes more than 5 mm past the face.
#[test]
fn a_tool_pulled_in_by_an_8_n_spring_presses_and_enters_only_by_cutting() {
    let dt = 1e-3;
    let cube = |body: &str| block(&config([0.04; 3], [16; 3], 2, dt, DOWN_G, body));
    // The ball, along +x into the face x = 0 at mid-height of the held 2 cm.
    let mut sim = cube(
        "[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 0.0201]
[[tools]]
name = \"ball\"
outer = { shape = \"sphere\", radius = 0.008 }
",
    );
    let ball = Shape::new(incise_tool::Primitive::Sphere { radius: 0.008 }, [0.0; 3]).unwrap();
    let held: Vec<usize> = (0..sim.state().x.len()).filter(|&n| sim.fixed().is_fixed(n)).collect();
    let rest: Vec<Vec3> = held.iter().map(|&n| sim.state().x[n]).collect();
    let mut hand = Hand { position: -0.010, velocity: 0.0, target: 0.05 };
    let (mut least_gap, mut force) = (f64::INFINITY, 0.0);
    for _ in 0..1000 {
        let frame =
            sim.step(&posed(0, [hand.position, 0.02, 0.01], [1.0, 0.0, 0.0, 0.0], 0.0)).unwrap();
        let tool = &frame.surgical.tools[0];
        force = tool.force()[0];
        if let Some(proxy) = tool.proxy {
            least_gap = least_gap.min(surface_gap(&sim, &ball, &proxy));
        }
        hand.step(force, dt);
    }
    for (k, &n) in held.iter().enumerate() {
        let bits = |p: [f64; 3]| p.map(f64::to_bits);
        assert_eq!(bits(sim.state().x[n]), bits(rest[k]), "held node {n} moved");
    }
    println!(
        "ball: the device settled {:.2} mm past the surface, pushed back with {:.3} N; the \
         proxy's least gap to the surface {:.4} mm",
        (hand.position + 0.008) * 1e3,
        -force,
        least_gap * 1e3
    );
    assert!(least_gap > -2e-6, "the ball's proxy entered the held tissue by {least_gap} m");
    assert!((force + 8.0).abs() < 0.05, "the ball is pushed back with {force} N, not 8 N");

    // The scalpel, edge first along +x into the same face: its shaft (+z) turned to −x, its
    // blade's length along z.
    let mut sim = cube(
        "[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 0.0201]
[[tools]]
name = \"scalpel\"
cutting = \"remove\"
cut_force = 2.0
outer = { shape = \"box\", half_extents = [0.006, 0.002, 0.008], offset = [0.0, 0.0, 0.008] }
inner = { shape = \"blade\", length = 0.012, height = 0.014, thickness = 0.0035, offset = [0.0, 0.0, 0.0005] }
",
    );
    let edge_in = [std::f64::consts::FRAC_1_SQRT_2, 0.0, -std::f64::consts::FRAC_1_SQRT_2, 0.0];
    let mut hand = Hand { position: -0.005, velocity: 0.0, target: 0.05 };
    let (mut removed, mut deepest) = (0, f64::NEG_INFINITY);
    for _ in 0..1000 {
        let frame = sim.step(&posed(0, [hand.position, 0.02, 0.01], edge_in, 0.0)).unwrap();
        let tool = &frame.surgical.tools[0];
        removed += frame.counters.voxels_removed;
        if let Some(proxy) = tool.proxy {
            deepest = deepest.max(proxy.position()[0]);
        }
        hand.step(tool.force()[0], dt);
    }
    println!(
        "scalpel: {removed} voxels removed, its proxy's edge reached {:.2} mm past the face",
        deepest * 1e3
    );
    assert!(removed > 0, "the scalpel never cut");
    assert!(deepest > 0.005, "the scalpel's proxy did not enter: its edge reached {deepest} m");
}

/// Passivity: the demo's grasper, jaws open, pressed 5 mm into the top of the organ and
/// released, 20 times (each cycle: 100 ms in, 50 ms held, 100 ms out, 50 ms clear of it). The
/// energy the device receives, `Σ Fₖ · (xₖ₊₁ − xₖ)` (each frame's force held while the device
/// moves to its next pose, as a device renders it), is not positive: the hand does the work,
/// within 1 % of the work it does in all (`Σ |Fₖ · (xₖ₊₁ − xₖ)|`).
#[test]
fn twenty_press_hold_release_cycles_give_the_hand_no_energy() {
    let mut sim = demo();
    let grasper = 1;
    let (x, y) = (0.04, 0.03);
    let (top, _) = surface_z(&sim, x, y, 0.003);
    let clear = top + 0.002 + 0.001;
    let depth = 0.005 + 0.001;
    let down = [1.0, 0.0, 0.0, 0.0];
    let height = |ms: usize| {
        let t = (ms % 300) as f64;
        let s = if t < 100.0 {
            t / 100.0
        } else if t < 150.0 {
            1.0
        } else if t < 250.0 {
            1.0 - (t - 150.0) / 100.0
        } else {
            0.0
        };
        clear - depth * s
    };
    let (mut received, mut total) = (0.0f64, 0.0f64);
    let mut previous: Option<(f64, f64)> = None;
    for ms in 0..20 * 300 {
        let z = height(ms);
        if let Some((f, z0)) = previous {
            let w = f * (z - z0);
            received += w;
            total += w.abs();
        }
        let frame = sim.step(&posed(grasper, [x, y, z], down, OPEN)).unwrap();
        previous = Some((frame.surgical.tools[grasper].force()[2], z));
    }
    println!(
        "20 cycles: the device received {received:.3e} J of {total:.3e} J exchanged ({:.2} %)",
        100.0 * received / total
    );
    assert!(total > 0.0, "no force was ever rendered");
    assert!(received <= 0.01 * total, "the device received {received} J of {total} J");
}

/// The demo's scalpel, pressed 6 mm past the surface and drawn 2 cm along the organ, cuts along
/// its whole stroke: the proxy follows the blade through the opening it makes (at least one
/// 2.5 mm voxel per 2.5 mm travelled) instead of riding over the top.
#[test]
fn the_demo_scalpel_drawn_2_cm_cuts_along_its_stroke() {
    let mut sim = demo();
    for _ in 0..800 {
        sim.step(&StepInputs::default()).unwrap();
    }
    let (x, y) = (0.035, 0.03);
    let (top, _) = surface_z(&sim, x, y, 0.003);
    let (mut removed, mut travelled) = (0, 0.0f64);
    for i in 0..1000 {
        let z = top + 0.005 - 0.011 * (f64::from(i) / 500.0).min(1.0);
        let dx = 0.02 * ((f64::from(i) - 600.0) / 300.0).clamp(0.0, 1.0);
        let frame = sim.step(&posed(0, [x + dx, y, z], [1.0, 0.0, 0.0, 0.0], 0.0)).unwrap();
        removed += frame.surgical.edit.remove_voxels.len();
        let proxy = frame.surgical.tools[0].proxy.expect("the scalpel has a proxy");
        travelled = travelled.max(proxy.position()[0] - x);
        assert!(
            top - proxy.position()[2] < 0.0075,
            "step {i}: the proxy is {} mm below the surface, deeper than the device",
            (top - proxy.position()[2]) * 1e3
        );
    }
    println!("removed {removed} voxels, the proxy travelled {:.1} mm", travelled * 1e3);
    assert!(travelled > 0.015, "the proxy travelled only {} mm along the stroke", travelled * 1e3);
    assert!(removed >= 8, "a 2 cm stroke removed only {removed} voxels");
}
