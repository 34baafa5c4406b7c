//! Hard cases for the surgical frame: a full transection that frees a piece, a tool that jumps
//! 5 cm across a membrane in one frame, cuts through superimposed elements, cutting beside a
//! grasp, a thousand random cuts, a tool pressed into a held region, refused poses, the stiffest
//! contact at a 10 ms step, separation without loss of volume, the linearisation against the
//! next frame, determinism across thread counts, and the tensor-mass family with a cutter.
//!
//! Every case checks that the state stays finite, plus the invariant its doc comment names.

use incise_fem::{Executor, Idle};
use incise_grid::GridEdit;
use incise_grid::canonical::compare_grids;
use incise_grid::procedural::{UTube, u_tube};
use incise_math::Vec3;
use incise_mesh::topology::{check_closed, check_manifold, non_manifold_edges};
use incise_sim::{Frame, InputError, OrganSurface, SceneConfig, Simulation, StepInputs, ToolInput};
use incise_tool::{GraspEvent, Pose, PoseError, ToolPose};

mod proxy;

const G: f64 = 9.81;
const DOWN_G: Vec3 = [0.0, 0.0, -G];
const NO_G: Vec3 = [0.0; 3];
/// A 90° turn about x: the tool's y axis along the grid's z, its z along the grid's −y.
const LAY_FLAT: [f64; 4] =
    [std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0];
/// A half turn about x: the tool's z axis (a grasper's jaws) points down the grid's z.
const POINT_DOWN: [f64; 4] = [0.0, 1.0, 0.0, 0.0];
const BASE: &str = "[[fixed]]\nplane = \"z\"\nvalue = 0.0\n";

/// A soft-tissue block scene (E = 3 kPa, ν = 0.45, 1000 kg/m³, implicit Euler with Rayleigh
/// damping α = 2, β = 0.01) of `voxels` filling `size` at grid `level`; `body` adds the fixed
/// regions and tools.
fn config(
    size: Vec3,
    voxels: [usize; 3],
    level: u32,
    dt: f64,
    gravity: Vec3,
    body: &str,
) -> SceneConfig {
    SceneConfig::from_toml(&text(size, voxels, level, dt, gravity, body), "hard.toml").unwrap()
}

fn text(size: Vec3, voxels: [usize; 3], level: u32, dt: f64, gravity: Vec3, body: &str) -> String {
    format!(
        "name = \"hard\"
level = {level}
gravity = [{:?}, {:?}, {:?}]
[volume]
procedural = \"block\"
size_m = [{:?}, {:?}, {:?}]
voxels = [{}, {}, {}]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[model]
kind = \"corotational\"
[integrator]
kind = \"implicit-euler\"
dt = {dt:?}
rayleigh_alpha = 2.0
rayleigh_beta = 0.01
{body}",
        gravity[0],
        gravity[1],
        gravity[2],
        size[0],
        size[1],
        size[2],
        voxels[0],
        voxels[1],
        voxels[2]
    )
}

/// The scene on its own procedural block.
fn block(config: &SceneConfig) -> Simulation {
    let volume = config.procedural_volume().unwrap();
    Simulation::new(config, &volume, "hard.toml").unwrap()
}

/// The standard 4 cm cube: 16³ voxels of 2.5 mm at level 2, held at its base.
fn cube(dt: f64, tools: &str) -> Simulation {
    block(&config([0.04; 3], [16; 3], 2, dt, DOWN_G, &format!("{BASE}{tools}")))
}

fn input(tool: usize, position: Vec3, rotation: [f64; 4], gripper: f64) -> ToolInput {
    ToolInput { tool, pose: ToolPose::new(position, rotation, gripper).unwrap() }
}

fn drive(sim: &mut Simulation, tools: Vec<ToolInput>) -> Frame {
    let frame = sim.step(&StepInputs { tools, ..StepInputs::default() }).unwrap();
    assert_finite(sim);
    frame
}

fn at(tool: usize, position: Vec3) -> Vec<ToolInput> {
    vec![input(tool, position, [1.0, 0.0, 0.0, 0.0], 0.0)]
}

/// Every node position and velocity, and every live surface vertex, finite.
fn assert_finite(sim: &Simulation) {
    let s = sim.state();
    assert!(
        s.x.iter().chain(&s.v).all(|p| p.iter().all(|c| c.is_finite())),
        "a node is not finite"
    );
    if let (Some(surface), Some(positions)) = (sim.surface(), sim.surface_positions()) {
        assert!(
            surface
                .live_vertices()
                .iter()
                .all(|&v| positions[v as usize].iter().all(|c| c.is_finite())),
            "a surface vertex is not finite"
        );
    }
}

/// The surface is closed, consistently oriented and a manifold.
fn assert_sound_surface(sim: &Simulation, when: &str) {
    let triangles = sim.surface().unwrap().triangle_list();
    assert!(!triangles.is_empty(), "{when}: the surface vanished");
    if let Err(e) = check_closed(&triangles) {
        panic!("{when}: the surface is open at edge {e:?}");
    }
    if let Err(e) = check_manifold(&triangles) {
        panic!("{when}: {e}");
    }
}

/// The vertices around which the triangles form more than one fan (where a non-manifold
/// surface touches itself at a point or along an edge).
fn singular_vertices(triangles: &[[u32; 3]]) -> std::collections::BTreeSet<u32> {
    let mut link: std::collections::BTreeMap<u32, Vec<[u32; 2]>> =
        std::collections::BTreeMap::new();
    for t in triangles {
        for i in 0..3 {
            link.entry(t[i]).or_default().push([t[(i + 1) % 3], t[(i + 2) % 3]]);
        }
    }
    link.into_iter()
        .filter(|(_, edges)| {
            let mut seen = vec![false; edges.len()];
            let mut stack = vec![0];
            seen[0] = true;
            while let Some(i) = stack.pop() {
                for (j, e) in edges.iter().enumerate() {
                    if !seen[j] && e.iter().any(|x| edges[i].contains(x)) {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
            seen.iter().any(|s| !s)
        })
        .map(|(v, _)| v)
        .collect()
}

fn voxel_surface(sim: &Simulation) -> &incise_surface::Surface {
    match sim.surface().unwrap() {
        OrganSurface::Voxels { surface, .. } => surface,
        OrganSurface::Tetrahedra { .. } => panic!("a hexahedral scene has a voxel surface"),
    }
}

fn speed_max(sim: &Simulation) -> f64 {
    sim.state().v.iter().map(|v| norm(*v)).fold(0.0, f64::max)
}

fn norm(v: Vec3) -> f64 {
    v.iter().map(|c| c * c).sum::<f64>().sqrt()
}

fn kinetic(sim: &Simulation) -> f64 {
    let mass = &sim.model().unwrap().lumped_mass;
    sim.state().v.iter().zip(mass).map(|(v, m)| 0.5 * m * norm(*v).powi(2)).sum()
}

/// The mean deformed position of the live surface vertices `keep` selects by their owner voxel's
/// coordinates, and how many there are.
fn centre_of(sim: &Simulation, keep: impl Fn([u32; 3]) -> bool) -> (Vec3, usize) {
    let surface = sim.surface().unwrap();
    let positions = sim.surface_positions().unwrap();
    let dims = sim.grid().unwrap().fine().dims();
    let mut sum = [0.0; 3];
    let mut n = 0;
    for &v in surface.live_vertices() {
        let voxel = surface.owner_voxel(v).unwrap();
        let c = [voxel % dims[0], (voxel / dims[0]) % dims[1], voxel / (dims[0] * dims[1])];
        if keep(c) {
            for k in 0..3 {
                sum[k] += positions[v as usize][k];
            }
            n += 1;
        }
    }
    (sum.map(|s| s / n.max(1) as f64), n)
}

/// The highest deformed surface vertex within `r` of the vertical line through `(x, y)`.
fn top_at(sim: &Simulation, x: f64, y: f64, r: f64) -> f64 {
    let p = sim.surface_positions().unwrap();
    sim.surface()
        .unwrap()
        .live_vertices()
        .iter()
        .map(|&v| p[v as usize])
        .filter(|q| (q[0] - x).hypot(q[1] - y) < r)
        .map(|q| q[2])
        .fold(f64::NEG_INFINITY, f64::max)
}

/// A full transection (a blade laid flat, cutting = "remove", drawn through a 4 cm cube at 2.4 cm
/// above its held base) frees the top piece: the surface falls apart into two closed manifold
/// pieces, the voxels lost are exactly those the frames report, the top piece's centre falls
/// like a free body once the blade is pulled from under it (within 0.3–1.2 × ½gt² after 0.1 s,
/// and within 3 % of free fall under the scene's mass damping α, which is how a rigid piece
/// falls through air thickened by α: z = g/α·(t − (1 − e^(−αt))/α)), the bottom piece stays on
/// its base, and no node ever moves faster than 5 m/s. The slicer is sharp: it cuts from 0.02 N
/// on (`cut_force`), so its 1 mm edge reaches the voxel centres ahead of it instead of pushing
/// the tissue away (pushed harder first, the layer ahead bends up and down, and the cut wanders
/// off the layer and leaves a bridge).
#[test]
fn a_full_transection_frees_the_top_piece_which_falls() {
    let slicer = "[[tools]]
name = \"slicer\"
stiffness = 10.0
cutting = \"remove\"
cut_force = 0.02
outer = { shape = \"blade\", length = 0.06, height = 0.06, thickness = 0.001 }
inner = { shape = \"blade\", length = 0.06, height = 0.06, thickness = 0.001 }
";
    let mut sim = cube(1e-3, slicer);
    let voxels = sim.grid().unwrap().fine().voxel_count();
    // The blade's mid-plane through the centres of voxel layer 9 (z = 23.75 mm); its 1 mm
    // thickness holds one layer of centres. Its edge leads along +y, 0.5 mm a frame, from 5 mm
    // before the block until the blade (6 cm deep) lies under all of it; there it holds the
    // freed piece up (the piece drops the 0.75 mm between the removed layer and the blade).
    let z = 9.5 * 0.0025;
    let mut removed = 0;
    let mut pieces_apart_at = None;
    let mut y = -0.005;
    for i in 0..110 {
        y = -0.005 + 0.0005 * f64::from(i);
        let frame = drive(&mut sim, vec![input(0, [0.02, y, z], LAY_FLAT, 0.0)]);
        removed += frame.counters.voxels_removed;
        if pieces_apart_at.is_none() && voxel_surface(&sim).components() == 2 {
            pieces_apart_at = Some(i);
        }
        assert!(speed_max(&sim) < 5.0, "frame {i}: a node at {} m/s", speed_max(&sim));
    }
    // Let the piece settle on the blade, so that its fall starts from rest.
    for _ in 0..150 {
        drive(&mut sim, vec![input(0, [0.02, y, z], LAY_FLAT, 0.0)]);
    }
    let top = |c: [u32; 3]| c[2] >= 12;
    let bottom = |c: [u32; 3]| c[2] <= 6;
    let (top0, n_top) = centre_of(&sim, top);
    let (bottom0, n_bottom) = centre_of(&sim, bottom);
    assert!(n_top > 0 && n_bottom > 0);
    // The device pulled out sideways in one pose: the blade's proxy slides out from under the
    // piece within a few frames, and the piece is dropped.
    let mut pulled = 0;
    while drive(&mut sim, vec![input(0, [0.02, y + 0.07, z], LAY_FLAT, 0.0)]).surgical.tools[0]
        .contact_points
        > 0
    {
        pulled += 1;
        assert!(pulled < 10, "the blade has not left the block after {pulled} frames");
    }
    println!(
        "{removed} voxels removed (a layer is 256), pieces apart at frame {pieces_apart_at:?}; the \
         top piece rested at {:.3} mm; the blade left it in {} frames",
        top0[2] * 1e3,
        pulled + 1
    );
    assert_eq!(voxel_surface(&sim).components(), 2, "the cut freed one piece");
    assert_sound_surface(&sim, "after the transection");
    let grid = sim.grid().unwrap();
    assert_eq!(grid.fine().voxel_count(), voxels - removed);
    let mut fall_at_100 = 0.0;
    let mut bottom_moved: f64 = 0.0;
    for i in 1..200 {
        drive(&mut sim, Vec::new());
        assert!(speed_max(&sim) < 5.0, "fall frame {i}: a node at {} m/s", speed_max(&sim));
        let (b, _) = centre_of(&sim, bottom);
        bottom_moved = bottom_moved.max((b[2] - bottom0[2]).abs());
        if i == 99 {
            fall_at_100 = top0[2] - centre_of(&sim, top).0[2];
        }
    }
    let free = 0.5 * G * 0.1f64.powi(2);
    let alpha = 2.0;
    let damped = |t: f64| G / alpha * (t - (1.0 - (-alpha * t).exp()) / alpha);
    let fall_at_200 = top0[2] - centre_of(&sim, top).0[2];
    println!(
        "top piece fell {:.2} mm in 0.1 s (½gt² = {:.2} mm, ratio {:.3}; damped free fall {:.2} mm), {:.2} mm in 0.2 s (damped free fall {:.2} mm); the bottom moved at most {:.3} µm; fastest node {:.3} m/s",
        fall_at_100 * 1e3,
        free * 1e3,
        fall_at_100 / free,
        damped(0.1) * 1e3,
        fall_at_200 * 1e3,
        damped(0.2) * 1e3,
        bottom_moved * 1e6,
        speed_max(&sim)
    );
    assert!((0.3 * free..=1.2 * free).contains(&fall_at_100), "fell {fall_at_100} m in 0.1 s");
    for (fall, t) in [(fall_at_100, 0.1), (fall_at_200, 0.2)] {
        assert!((fall / damped(t) - 1.0).abs() < 0.03, "fell {fall} m in {t} s");
    }
    assert!(bottom_moved < 0.0025, "the bottom piece moved {bottom_moved} m");
}

/// A membrane 2.5 mm thick (one voxel, 4 × 4 cm, held on its rim, weightless) and a flat box
/// tool 2 mm thick whose device jumps in one frame from 2.5 cm above it to 2.5 cm below it
/// (52.5 mm in 1 ms), with the scene's usual stiffness damping (β = 0.01): the tool does not
/// tunnel. Its proxy stops on the membrane's top (its bottom face within the contact's tolerance
/// of the surface), the tissue pushes back against the device (the tool's force is up, above the
/// membrane's weight and within the coupling's largest force), the coupling pushes the membrane
/// down, and for the ten
/// frames the device is held there the proxy stays on the membrane's upper side, above every
/// surface vertex under its face. The frames after the jump are printed.
#[test]
fn a_tool_jumping_5_cm_in_one_frame_stops_on_a_membrane_and_pushes_it() {
    let rim = "[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [0.0001, 1.0, 1.0]
[[fixed]]
min = [0.0399, -1.0, -1.0]
max = [1.0, 1.0, 1.0]
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 0.0001, 1.0]
[[fixed]]
min = [-1.0, 0.0399, -1.0]
max = [1.0, 1.0, 1.0]
[[tools]]
name = \"paddle\"
outer = { shape = \"box\", half_extents = [0.005, 0.005, 0.001] }
";
    // Weightless: the rim-held membrane would sag centimetres under gravity; the jump is the case.
    let text = text([0.04, 0.04, 0.0025], [16, 16, 1], 0, 1e-3, NO_G, rim);
    let mut sim = block(&SceneConfig::from_toml(&text, "membrane.toml").unwrap());
    let thickness = 0.0025;
    let rest = sim.surface_positions().unwrap();
    // The top surface's vertices over the inner 8 × 8 mm of the tool's 1 × 1 cm face.
    let under: Vec<u32> = sim
        .surface()
        .unwrap()
        .live_vertices()
        .iter()
        .copied()
        .filter(|&v| {
            let p = rest[v as usize];
            (p[0] - 0.02).abs() < 0.004 && (p[1] - 0.02).abs() < 0.004 && p[2] > 0.5 * thickness
        })
        .collect();
    let highest = |sim: &Simulation| {
        let p = sim.surface_positions().unwrap();
        under.iter().map(|&v| p[v as usize][2]).fold(f64::NEG_INFINITY, f64::max)
    };
    let (above, below) = (thickness + 0.025, -0.025);
    for _ in 0..5 {
        let frame = drive(&mut sim, at(0, [0.02, 0.02, above]));
        assert_eq!(frame.surgical.tools[0].contact_points, 0);
    }
    let before = highest(&sim);
    let jump = drive(&mut sim, at(0, [0.02, 0.02, below]));
    let tool = &jump.surgical.tools[0];
    let proxy = tool.proxy.expect("the paddle has a proxy").position()[2];
    let weight = 1000.0 * 0.04 * 0.04 * thickness * G;
    println!(
        "{} vertices under the tool; jump frame: {} contact points, force {:.3} N ({:.0} × the \
         membrane's weight); the proxy's face stopped {:+.4} mm from the membrane's top",
        under.len(),
        tool.contact_points,
        tool.force()[2],
        tool.force()[2] / weight,
        (proxy - 0.001 - before) * 1e3,
    );
    assert!(tool.contact_points > 0, "the proxy touches nothing");
    assert!((proxy - 0.001 - before).abs() < 1e-5, "the proxy stopped at {proxy} m");
    // The device is 2.5 cm past the membrane: the coupling pulls with its whole largest force,
    // and the tissue yields through the frame's implicit step, so the force left at the frame's
    // end is above the membrane's weight and never above that limit (no kick).
    let limit = incise_sim::config::DEFAULT_MAX_FORCE;
    assert!(tool.force()[2] > weight, "the tissue does not resist the jump");
    assert!(tool.force().iter().map(|f| f * f).sum::<f64>().sqrt() <= limit * (1.0 + 1e-9));
    let mut moved = 0.0;
    for i in 1..=10 {
        let frame = drive(&mut sim, at(0, [0.02, 0.02, below]));
        let face = frame.surgical.tools[0].proxy.unwrap().position()[2] - 0.001;
        let top = highest(&sim);
        moved = before - top;
        if i % 3 == 1 {
            println!(
                "hold {i}: {} points in contact, force {:.3} N, the proxy's face {:+.4} mm from \
                 the highest vertex under it, the membrane {:.3} mm down",
                frame.surgical.tools[0].contact_points,
                frame.surgical.tools[0].force()[2],
                (face - top) * 1e3,
                moved * 1e3
            );
        }
        assert!(
            face >= top - 1e-5,
            "hold {i}: the proxy's face {face} m below the membrane {top} m"
        );
    }
    assert!(moved > 0.0, "the coupling did not push the membrane");
}

/// A U-tube whose arms stand 5 mm apart (2 voxels), so that at level 2 each coarse cell over the
/// gap holds two superimposed elements, one of each arm (Jeřábková 2010, Fig. 3); a spherical
/// cutter drawn down the gap removes voxels of both arms. Invariants: in some frame one coarse
/// cell loses voxels of both of its elements; after every cut the incrementally updated grid
/// equals a grid rebuilt from its fine level (topology exactly, matrices to 1e-12) and the
/// surface is closed and manifold; everything stays finite for 100 more steps.
#[test]
fn cuts_through_superimposed_elements_keep_the_grid_equal_to_a_rebuild() {
    let h = 0.0025;
    let volume = u_tube(UTube::DEFAULT, h);
    let dims = volume.dims();
    // A 5 mm ball wider than the gap: pressed down on the arms' inner edges it cuts, reaching
    // the inner voxel column of both arms (centres 3.75 mm from the gap's middle).
    let gouge = "[[tools]]
name = \"gouge\"
stiffness = 50.0
cutting = \"remove\"
cut_force = 0.05
outer = { shape = \"sphere\", radius = 0.005 }
inner = { shape = \"sphere\", radius = 0.005 }
";
    let size = dims.map(|d| d as f64 * h);
    let config = config(size, dims, 2, 1e-3, DOWN_G, &format!("{BASE}{gouge}"));
    let mut sim = Simulation::new(&config, &volume, "u.toml").unwrap();
    let summary = sim.grid().unwrap().summary();
    let top = summary.last().unwrap();
    assert_eq!(top.level, 2);
    assert!(top.superimposed > 0, "{top:?}");
    let mut cut_frames = 0;
    let mut both_in_one_cell = 0;
    let mut removed = 0;
    let gap_middle = 6.0 * h;
    for i in 0..100 {
        let before = sim.grid().unwrap().clone();
        let z = 0.045 - 0.0002 * f64::from(i);
        let frame = drive(&mut sim, at(0, [gap_middle, 0.005, z]));
        let edit = &frame.surgical.edit.remove_voxels;
        if edit.is_empty() {
            continue;
        }
        cut_frames += 1;
        removed += edit.len();
        let mut by_cell: std::collections::BTreeMap<u32, std::collections::BTreeSet<u32>> =
            std::collections::BTreeMap::new();
        for &v in edit {
            let e = before.voxel_element(v).unwrap();
            by_cell.entry(before.top().element(e).unwrap().cell).or_default().insert(e);
        }
        if by_cell.values().any(|elements| elements.len() >= 2) {
            both_in_one_cell += 1;
        }
        let grid = sim.grid().unwrap();
        if let Err(e) = compare_grids(grid, &grid.rebuild(), 1e-12) {
            panic!("frame {i}: the grid differs from its rebuild: {e}");
        }
        assert_sound_surface(&sim, &format!("frame {i}"));
    }
    let after = sim.grid().unwrap().summary();
    println!(
        "level 2 before: {} elements, {} superimposed; {removed} voxels removed in {cut_frames} frames, {both_in_one_cell} of them cutting both elements of one cell; after: {} elements, {} superimposed",
        top.elements,
        top.superimposed,
        after.last().unwrap().elements,
        after.last().unwrap().superimposed
    );
    assert!(both_in_one_cell > 0, "no frame cut both superimposed elements of a cell");
    for _ in 0..100 {
        drive(&mut sim, Vec::new());
    }
}

/// Bimanual: a grasper closes on the top of the cube and lifts it while a spherical cutter
/// (cutting = "remove") sinks in 1 cm beside it. Invariants: the jaws take hold when they close
/// on the surface and hold every one of those points every frame while the cutter removes
/// voxels beside them (the cut's local re-meshing keeps the held vertices); the held patch rises
/// with the grasper (at least 80 % of its 9 mm lift); the cutter does cut; all finite.
#[test]
fn a_grasper_keeps_its_hold_while_a_second_tool_cuts_beside_it() {
    let tools = "[[tools]]
name = \"grasper\"
stiffness = 200.0
outer = { shape = \"sphere\", radius = 0.002 }
[tools.jaws]
length = 0.01
width = 0.008
close_below = 0.05
open_above = 0.3
stiffness = 300.0
[[tools]]
name = \"cutter\"
stiffness = 50.0
cutting = \"remove\"
outer = { shape = \"sphere\", radius = 0.001 }
inner = { shape = \"sphere\", radius = 0.003 }
";
    let mut sim = cube(1e-3, tools);
    let (gx, gy) = (0.02, 0.02);
    let cutter_away = [0.03, 0.02, 0.045];
    // Lower the open grasper (hinge up, jaws reaching 1 cm down) until it touches.
    let mut hinge = 0.045;
    let mut touched = false;
    for _ in 0..200 {
        let frame = drive(
            &mut sim,
            vec![
                input(0, [gx, gy, hinge], POINT_DOWN, 0.5),
                input(1, cutter_away, [1.0, 0.0, 0.0, 0.0], 0.0),
            ],
        );
        if frame.surgical.tools[0].contact_points > 0 {
            touched = true;
            break;
        }
        hinge -= 5e-5;
    }
    assert!(touched, "the grasper never touched the cube");
    // Press on 1 mm, so that the jaws close on a surface held in contact.
    for _ in 0..20 {
        hinge -= 5e-5;
        let frame = drive(
            &mut sim,
            vec![
                input(0, [gx, gy, hinge], POINT_DOWN, 0.5),
                input(1, cutter_away, [1.0, 0.0, 0.0, 0.0], 0.0),
            ],
        );
        assert!(frame.surgical.tools[0].contact_points > 0);
    }
    let close = drive(
        &mut sim,
        vec![
            input(0, [gx, gy, hinge], POINT_DOWN, 0.0),
            input(1, cutter_away, [1.0, 0.0, 0.0, 0.0], 0.0),
        ],
    );
    let GraspEvent::Closed(held) = close.surgical.tools[0].grasp else {
        panic!("the jaws did not close: {:?}", close.surgical.tools[0].grasp)
    };
    assert!(held > 0, "the jaws closed on nothing");
    // The patch between the jaws: top-surface vertices within the jaws' footprint.
    let positions = sim.surface_positions().unwrap();
    let patch: Vec<u32> = sim
        .surface()
        .unwrap()
        .live_vertices()
        .iter()
        .copied()
        .filter(|&v| {
            let p = positions[v as usize];
            (p[0] - gx).abs() <= 0.004 && (p[1] - gy).abs() <= 0.0015 && p[2] > hinge - 0.01
        })
        .collect();
    let patch_z = |sim: &Simulation| {
        let p = sim.surface_positions().unwrap();
        patch.iter().map(|&v| p[v as usize][2]).sum::<f64>() / patch.len() as f64
    };
    let z0 = patch_z(&sim);
    let (lift, steps) = (0.009, 300);
    let mut removed = 0;
    let mut cut_frames = 0;
    let mut fewest_held = usize::MAX;
    for i in 1..=steps {
        let s = f64::from(i) / f64::from(steps);
        let frame = drive(
            &mut sim,
            vec![
                input(0, [gx, gy, hinge + lift * s], POINT_DOWN, 0.0),
                input(1, [0.03, 0.02, 0.043 - 0.015 * s], [1.0, 0.0, 0.0, 0.0], 0.0),
            ],
        );
        let held_now = frame.surgical.tools[0].held_points;
        fewest_held = fewest_held.min(held_now);
        assert_eq!(held_now, held, "frame {i}: the grasp lost points");
        if frame.counters.voxels_removed > 0 {
            cut_frames += 1;
            removed += frame.counters.voxels_removed;
            assert_sound_surface(&sim, &format!("frame {i}"));
        }
    }
    let rise = patch_z(&sim) - z0;
    println!(
        "held {held} points at closing ({} patch vertices), at least {fewest_held} throughout; the cutter removed {removed} voxels in {cut_frames} frames; the patch rose {:.2} mm of the grasper's {:.1} mm; grasper force {:?} N",
        patch.len(),
        rise * 1e3,
        lift * 1e3,
        sim.step(&StepInputs::default()).unwrap().surgical.tools[0].force()
    );
    assert!(removed > 0, "the cutter cut nothing");
    assert!(rise > 0.8 * lift, "the held patch rose {rise} m");
}

/// `SplitMix64`: a fixed stream of pseudo-random numbers, so every run makes the same cuts.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// The face neighbour of voxel `v` along `axis` (+1), if inside `dims`.
fn neighbour(v: u32, axis: usize, dims: [u32; 3]) -> Option<u32> {
    let c = [v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])];
    let stride = [1, dims[0], dims[0] * dims[1]];
    (c[axis] + 1 < dims[axis]).then(|| v + stride[axis])
}

/// 1,000 random cuts through `Simulation::cut` on a 10³-voxel block (2.5 cm, level 1, held at
/// its base; 10³ rather than 12³ keeps the run near 5 s in the dev profile), a step after each:
/// clusters of 1–3 face-connected voxels removed (40 % of the edits) or 1–4 random links severed
/// (the rest), from a fixed seed. Invariants: no panic and no edit
/// refused; every position finite after every step; the surface closed and manifold after every
/// edit (all 1,000 are checked); the volume accounted exactly: each edit's reported removals equal
/// the drop in the fine voxel count, a sever-only edit never changes it, and the sum over all
/// edits equals the initial count minus the final one.
#[test]
fn a_thousand_random_cuts_keep_the_surface_sound_and_the_volume_exact() {
    let mut sim = block(&config([0.025; 3], [10; 3], 1, 1e-3, DOWN_G, BASE));
    sim.enable_surface();
    let dims = sim.grid().unwrap().fine().dims();
    let count = (dims[0] * dims[1] * dims[2]) as usize;
    let initial = sim.grid().unwrap().fine().voxel_count();
    let mut rng = SplitMix(0x5eed_cafe);
    let (mut removed_total, mut severed_total, mut removal_edits) = (0, 0, 0);
    for i in 0..1000 {
        let mut edit = GridEdit::default();
        if rng.below(10) < 4 {
            let v = rng.below(count) as u32;
            edit.remove_voxels.push(v);
            for _ in 0..rng.below(3) {
                let last = *edit.remove_voxels.last().unwrap();
                if let Some(w) = neighbour(last, rng.below(3), dims) {
                    edit.remove_voxels.push(w);
                }
            }
            removal_edits += 1;
        } else {
            for _ in 0..=rng.below(4) {
                let v = rng.below(count) as u32;
                if let Some(w) = neighbour(v, rng.below(3), dims) {
                    edit.sever_links.push((v, w));
                }
            }
        }
        let before = sim.grid().unwrap().fine().voxel_count();
        let changes = sim.cut(&edit).unwrap_or_else(|e| panic!("edit {i} {edit:?} refused: {e}"));
        let after = sim.grid().unwrap().fine().voxel_count();
        assert_eq!(before - after, changes.voxels_removed, "edit {i}: {edit:?}");
        if edit.remove_voxels.is_empty() {
            assert_eq!(before, after, "edit {i}: severing links changed the voxel count");
        }
        removed_total += changes.voxels_removed;
        severed_total += changes.links_severed;
        drive(&mut sim, Vec::new());
        if after > 0 {
            assert_sound_surface(&sim, &format!("edit {i}"));
        }
    }
    let last = sim.grid().unwrap().fine().voxel_count();
    println!(
        "{removal_edits} removal edits took {removed_total} of {initial} voxels ({last} left); {severed_total} links severed; {} surface pieces; fastest node {:.3} m/s",
        voxel_surface(&sim).components(),
        speed_max(&sim)
    );
    assert_eq!(removed_total, initial - last);
    assert!(severed_total > 0 && removed_total > 0);
}

/// A ball (radius 8 mm) whose device is pressed 5 mm into the side of the cube within its held
/// base (the bottom 2 cm, a `[[fixed]]` box, which holds every node of the elements the contact
/// reaches): the tissue there cannot move, so the proxy stays on the face and the force is the
/// coupling's, stretched by the device's depth. Invariants: the held nodes never move (bit for
/// bit); the tool's force grows with every step of the press (monotone, never decreasing) and
/// points back along the press; everything stays finite.
#[test]
fn a_tool_pressed_into_a_held_region_pushes_back_harder_the_deeper_it_goes() {
    let tools = "[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 0.0201]
[[tools]]
name = \"press\"
stiffness = 1000.0
outer = { shape = \"sphere\", radius = 0.008 }
";
    let mut sim = block(&config([0.04; 3], [16; 3], 2, 1e-3, DOWN_G, tools));
    let fixed: Vec<usize> = (0..sim.state().x.len()).filter(|&n| sim.fixed().is_fixed(n)).collect();
    let rest: Vec<Vec3> = fixed.iter().map(|&n| sim.state().x[n]).collect();
    assert!(!fixed.is_empty());
    let radius = 0.008;
    // From 2 mm off the side x = 0, at mid-height of the held 2 cm, 0.05 mm a step to 5 mm deep.
    let mut forces = Vec::new();
    for i in 0..=140 {
        let depth = -0.002 + 0.00005 * f64::from(i);
        let frame = drive(&mut sim, at(0, [depth - radius, 0.02, 0.01]));
        for (k, &n) in fixed.iter().enumerate() {
            let bits = |p: Vec3| p.map(f64::to_bits);
            assert_eq!(bits(sim.state().x[n]), bits(rest[k]), "step {i}: held node {n} moved");
        }
        let tool = &frame.surgical.tools[0];
        forces.push((depth, tool.force(), tool.contact_points));
    }
    for w in forces.windows(2) {
        assert!(norm(w[1].1) >= norm(w[0].1), "the force fell from {:?} to {:?}", w[0], w[1]);
        assert!(w[1].1[0] <= 0.0, "the force does not push back along the press: {:?}", w[1]);
    }
    for f in forces.iter().skip(40).step_by(40) {
        println!("{:.1} mm deep: {} points, force {:.3} N", f.0 * 1e3, f.2, norm(f.1));
    }
    let (_, force, points) = *forces.last().unwrap();
    println!("{} held nodes; at 5 mm, {points} points push back with {:?} N", fixed.len(), force);
    assert!(norm(force) > 0.0);
}

/// A flat box 4 mm thick (12 × 12 mm face) whose device is pressed 3.5 mm into the side of the
/// cube's held base, past half the box's thickness: a contact that pushed the surface points
/// inside the box out of its nearer face would turn round there and let go; the proxy stays on
/// the face it met. Invariants: the force never falls during the press, points back along it,
/// and at 3.5 mm is larger than at 1.9 mm, just short of half the thickness.
#[test]
fn a_box_pressed_past_half_its_thickness_into_held_tissue_keeps_pushing() {
    let tools = "[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 0.0201]
[[tools]]
name = \"block\"
stiffness = 1000.0
outer = { shape = \"box\", half_extents = [0.002, 0.006, 0.006] }
";
    let mut sim = block(&config([0.04; 3], [16; 3], 2, 1e-3, DOWN_G, tools));
    let half = 0.002;
    let mut forces = Vec::new();
    for i in 0..=110 {
        // From 2 mm off the side x = 0 to 3.5 mm into it, 0.05 mm a step, at mid-height of the
        // held 2 cm.
        let depth = -0.002 + 0.00005 * f64::from(i);
        let frame = drive(&mut sim, at(0, [depth - half, 0.02, 0.01]));
        forces.push((
            depth,
            frame.surgical.tools[0].force(),
            frame.surgical.tools[0].contact_points,
        ));
    }
    for w in forces.windows(2) {
        assert!(norm(w[1].1) >= norm(w[0].1), "the force fell from {:?} to {:?}", w[0], w[1]);
        assert!(w[1].1[0] <= 0.0, "the force does not push back along the press: {:?}", w[1]);
    }
    let at_depth = |d: f64| forces.iter().find(|f| (f.0 - d).abs() < 1e-9).unwrap();
    let (before, after) = (at_depth(0.0019), at_depth(0.0035));
    for f in [before, after] {
        println!("{:.2} mm deep: {} points, force {:.3} N", f.0 * 1e3, f.2, norm(f.1));
    }
    assert!(norm(after.1) > norm(before.1), "no more force past half the thickness");
}

/// Poses that cannot be used are refused where they are made, so none reaches a step:
/// `Pose::new` refuses NaN and non-unit quaternions, `ToolPose::new` a NaN, infinite or negative
/// gripper, and `ToolPose::from_pose` a pose built unchecked (`Pose::at`, `Pose::moved`) from a
/// NaN or infinite number. `step` refuses a tool input that names a tool the scene lacks
/// (`NoSuchTool`), naming the entry, even after a valid entry in the same step. After each
/// refusal the state is bit-identical, the next valid step is step number n + 1, and the run's
/// state hashes equal those of a twin that was never given the bad inputs.
#[test]
fn a_nan_or_non_unit_pose_is_refused_and_the_state_untouched() {
    assert!(matches!(
        Pose::new([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]),
        Err(PoseError::NotFinite { .. })
    ));
    assert!(matches!(
        Pose::new([0.0; 3], [1.0, f64::NAN, 0.0, 0.0]),
        Err(PoseError::NotFinite { .. })
    ));
    assert!(matches!(Pose::new([0.0; 3], [1.0, 1.0, 0.0, 0.0]), Err(PoseError::NotUnit { .. })));
    assert!(matches!(Pose::new([0.0; 3], [0.0; 4]), Err(PoseError::NotUnit { .. })));
    assert!(matches!(
        ToolPose::new([0.0; 3], [1.0, 0.0, 0.0, 0.0], f64::NAN),
        Err(PoseError::BadGripper { .. })
    ));
    assert!(matches!(
        ToolPose::new([0.0; 3], [1.0, 0.0, 0.0, 0.0], -0.1),
        Err(PoseError::BadGripper { .. })
    ));
    assert!(matches!(
        ToolPose::new([0.0; 3], [1.0, 0.0, 0.0, 0.0], f64::INFINITY),
        Err(PoseError::BadGripper { .. })
    ));
    let unchecked = [
        Pose::at([f64::NAN, 0.02, 0.0385]),
        Pose::at([0.02, f64::INFINITY, 0.0385]),
        Pose::at([0.02, 0.02, 0.0385]).moved([0.0, 0.0, f64::NAN], [0.0; 3]),
    ];
    for pose in unchecked {
        assert!(
            matches!(ToolPose::from_pose(pose, 0.0), Err(PoseError::NotFinite { .. })),
            "{pose:?} was taken"
        );
    }

    let tool = "[[tools]]
name = \"probe\"
stiffness = 200.0
outer = { shape = \"sphere\", radius = 0.004 }
";
    let mut sim = cube(1e-3, tool);
    let mut twin = cube(1e-3, tool);
    let pressed = [0.02, 0.02, 0.039];
    for _ in 0..20 {
        let (a, b) = (drive(&mut sim, at(0, pressed)), drive(&mut twin, at(0, pressed)));
        assert_eq!(a.state_hash, b.state_hash);
    }
    let good = input(0, [0.02, 0.02, 0.0385], [1.0, 0.0, 0.0, 0.0], 0.0);
    let refusals: Vec<(Vec<ToolInput>, &str)> = vec![
        (vec![ToolInput { tool: 1, ..good }], "tool 1 of 1"),
        (vec![good, ToolInput { tool: 7, ..good }], "tool 7 after a valid entry"),
    ];
    for (tools, what) in refusals {
        let (x, v) = (sim.state().x.clone(), sim.state().v.clone());
        let index = drive(&mut twin, at(0, pressed)).index;
        let err =
            sim.step(&StepInputs { tools: tools.clone(), ..StepInputs::default() }).unwrap_err();
        let entry = tools.len() - 1;
        match &err {
            InputError::NoSuchTool { entry: e, tools: 1, .. } => {
                assert_eq!(*e, entry, "{what}: {err}");
            }
            _ => panic!("{what}: refused as {err:?}"),
        }
        assert!(
            sim.state()
                .x
                .iter()
                .flatten()
                .zip(x.iter().flatten())
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{what}: the positions changed"
        );
        assert!(
            sim.state()
                .v
                .iter()
                .flatten()
                .zip(v.iter().flatten())
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{what}: the velocities changed"
        );
        let frame = drive(&mut sim, at(0, pressed));
        assert_eq!(frame.index, index, "{what}: the refused step was counted");
        assert_eq!(frame.state_hash, twin_hash(&twin), "{what}: the state differs from the twin's");
    }
}

fn twin_hash(sim: &Simulation) -> u64 {
    // The state hash of a frame is FNV-1a over the positions' and velocities' bits; recomputed
    // here from the state itself so the twin need not step again.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in sim.state().x.iter().chain(&sim.state().v) {
        for c in v {
            for b in c.to_bits().to_le_bytes() {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
    h
}

/// The stiffest contact a scene accepts (1e7 N/m per point) at dt = 10 ms: a ball pressed 2 mm
/// into the top of the cube (settled under its weight first) and held there for 1.5 s.
/// Invariants: all finite; the kinetic energy stays below 1 mJ (the cube's weight lowered by its
/// whole height is 25 mJ) throughout; the tool's force settles: over the last 20 frames it varies
/// by less than 10 % of its mean.
#[test]
fn the_stiffest_contact_at_10_ms_is_stable() {
    let tool = "[[tools]]
name = \"anvil\"
stiffness = 1.0e7
outer = { shape = \"sphere\", radius = 0.004 }
";
    let mut sim = cube(0.01, tool);
    for _ in 0..50 {
        drive(&mut sim, Vec::new());
    }
    let top = top_at(&sim, 0.02, 0.02, 0.004);
    let mut forces = Vec::new();
    let mut peak_energy: f64 = 0.0;
    for i in 0..170 {
        // From 2 mm above the top to 2 mm into it over 20 frames (2 cm/s), then held.
        let z = top + 0.004 + 0.002 - 0.0002 * f64::from(i.min(20));
        let frame = drive(&mut sim, at(0, [0.02, 0.02, z]));
        peak_energy = peak_energy.max(kinetic(&sim));
        forces.push((frame.surgical.tools[0].force()[2], frame.surgical.tools[0].contact_points));
    }
    let last: Vec<f64> = forces[forces.len() - 20..].iter().map(|f| f.0).collect();
    let mean = last.iter().sum::<f64>() / last.len() as f64;
    let (lo, hi) =
        last.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &f| (a.min(f), b.max(f)));
    for (i, f) in forces.iter().enumerate().skip(10).step_by(20) {
        println!("frame {i}: force {:.4} N, {} points", f.0, f.1);
    }
    println!(
        "top settled at {:.3} mm; last 20 frames: force {mean:.4} N, from {lo:.4} to {hi:.4} ({:.2} %); peak kinetic energy {:.3e} J",
        top * 1e3,
        100.0 * (hi - lo) / mean,
        peak_energy
    );
    assert!(peak_energy < 1e-3, "kinetic energy {peak_energy} J");
    assert!(mean > 0.0, "the tissue pushes the tool up");
    assert!(hi - lo < 0.1 * mean, "the force still varies from {lo} to {hi} N");
}

/// Separation (links severed, no voxel removed) keeps the material exactly. An interior slit
/// (`Simulation::cut` severing the 36 links across a 6 × 6-voxel square in the middle of the
/// cube, touching no surface) leaves the volume the rest surface encloses unchanged to 1e-12
/// relative: it only adds two coincident walls facing opposite ways. Then a blade in
/// separation mode (cutting = "separate") drawn 2.2 cm down into the cube over 88 frames, and
/// 200 random link severings: links are severed, the fine voxel count never changes, and the
/// surface stays closed and manifold throughout. (Where a cut opens the outer surface its new
/// rims are chamfered like every edge of the voxel surface, whose vertices sit at voxel face
/// centres, so there the rest volume falls by h³/8 per voxel of rim and side: measured and
/// printed, not an invariant.)
#[test]
fn separation_severs_links_without_losing_volume() {
    let blade = "[[tools]]
name = \"separator\"
stiffness = 100.0
cutting = \"separate\"
outer = { shape = \"blade\", length = 0.06, height = 0.03, thickness = 0.0005 }
inner = { shape = \"blade\", length = 0.06, height = 0.03, thickness = 0.0005 }
";
    let mut sim = cube(1e-3, blade);
    let h3 = 0.0025f64.powi(3);
    let voxels = sim.grid().unwrap().fine().voxel_count();
    let rest_volume = |sim: &Simulation| {
        let surface = voxel_surface(sim);
        surface.enclosed_volume(&surface.rest_positions())
    };
    let volume0 = rest_volume(&sim);
    let check = |sim: &Simulation, when: &str| {
        assert_eq!(sim.grid().unwrap().fine().voxel_count(), voxels, "{when}: voxels lost");
        assert_sound_surface(sim, when);
    };
    let dims = sim.grid().unwrap().fine().dims();
    let index = |x: u32, y: u32, z: u32| x + dims[0] * (y + dims[1] * z);
    let mut slit = GridEdit::default();
    for x in 5..11 {
        for y in 5..11 {
            slit.sever_links.push((index(x, y, 7), index(x, y, 8)));
        }
    }
    let changes = sim.cut(&slit).unwrap();
    assert_eq!((changes.links_severed, changes.voxels_removed), (36, 0));
    drive(&mut sim, Vec::new());
    check(&sim, "the interior slit");
    let slit_change = (rest_volume(&sim) - volume0).abs() / volume0;
    assert!(slit_change <= 1e-12, "the interior slit changed the rest volume by {slit_change:e}");
    // The blade's edge down its mid-plane y = 2 cm (a voxel boundary), from 2 mm above the top.
    let mut severed = 0;
    for i in 0..88 {
        let frame = drive(&mut sim, at(0, [0.02, 0.02, 0.042 - 0.00025 * f64::from(i)]));
        assert_eq!(frame.counters.voxels_removed, 0);
        if frame.counters.links_severed > 0 {
            severed += frame.counters.links_severed;
            check(&sim, &format!("blade frame {i}"));
        }
    }
    let blade_change = rest_volume(&sim) - volume0;
    // Out again along the cut: nothing is left to sever there.
    for i in 0..40 {
        let frame = drive(&mut sim, at(0, [0.02, 0.02, 0.02 + 0.0006 * f64::from(i)]));
        severed += frame.counters.links_severed;
        check(&sim, &format!("withdrawal frame {i}"));
    }
    let by_blade = severed;
    let count = (dims[0] * dims[1] * dims[2]) as usize;
    let mut rng = SplitMix(0xb1ade);
    for i in 0..200 {
        let mut edit = GridEdit::default();
        for _ in 0..=rng.below(4) {
            let v = rng.below(count) as u32;
            if let Some(w) = neighbour(v, rng.below(3), dims) {
                edit.sever_links.push((v, w));
            }
        }
        severed += sim.cut(&edit).unwrap().links_severed;
        drive(&mut sim, Vec::new());
        check(&sim, &format!("edit {i}"));
    }
    println!(
        "interior slit: rest volume changed by {slit_change:.1e} (relative); the blade severed {by_blade} links (rest volume {:+.3} h³), the edits {} more (rest volume {:+.3} h³ in all); {voxels} voxels throughout; {} surface pieces",
        blade_change / h3,
        severed - by_blade,
        (rest_volume(&sim) - volume0) / h3,
        voxel_surface(&sim).components()
    );
    assert!(by_blade > 0 && severed > by_blade);
}

/// The linearisation a frame reports predicts how the next frame's force changes with the pose.
/// A flat box (10 × 10 mm face, undamped coupling and contact) whose device is pressed 1.5 mm
/// into the top of the cube (implicit, dt = 1 ms) and held until the force is steady; two twin
/// simulations, bit-identical so far, then take one more step each, one at the same pose and one
/// eased back 0.1 mm. The force difference between the two full steps is compared with the one
/// `Linearisation::extrapolate` predicts from the last common frame, `J·δ`.
///
/// The proxy rests on the tissue and the coupling spring between it and the device is the force;
/// eased 0.1 mm, the face still touches the same points with the same normals. What the
/// prediction misses is the tissue's motion within the step: the linearisation holds the tissue
/// (and the proxy on it) still, while the step lets the coupling's springs pull it after the
/// device, so the spring stretches less than predicted. In one implicit step the springs (`h²k`
/// each) act against the tissue's `M + (h² + hβ)K`; the surface follows by a fraction of the
/// move, and the actual change is that much smaller. The tolerance keeps the direction and
/// allows the ratio 0.7–1.0: above 1 would be wrong in kind (the tissue can only follow the
/// device, never pull away harder than held still). The damping's share,
/// `Linearisation::damping`, is checked in `incise_tool`'s unit tests.
#[test]
fn the_linearisation_predicts_the_next_frames_force() {
    let tool = "[[tools]]
name = \"flat\"
stiffness = 200.0
damping = 0.0
coupling_damping = 0.0
outer = { shape = \"box\", half_extents = [0.005, 0.005, 0.002] }
";
    let mut a = cube(1e-3, tool);
    let mut b = cube(1e-3, tool);
    // Settled under its weight first (the tool takes no part until it is posed).
    for _ in 0..300 {
        let (fa, fb) = (drive(&mut a, Vec::new()), drive(&mut b, Vec::new()));
        assert_eq!(fa.state_hash, fb.state_hash);
    }
    let surface = top_at(&a, 0.02, 0.02, 0.006);
    let mut last = None;
    for i in 0..700 {
        // The face from 5 mm above the top to 1.5 mm into it over 200 frames, then held.
        let face = surface + 0.005 - 0.0065 * (f64::from(i) / 200.0).min(1.0);
        let pose = at(0, [0.02, 0.02, face + 0.002]);
        let (fa, fb) = (drive(&mut a, pose.clone()), drive(&mut b, pose));
        assert_eq!(fa.state_hash, fb.state_hash, "frame {i}: the twins differ");
        last = Some(fa);
    }
    let last = last.unwrap();
    let lin = last.surgical.tools[0].linearisation;
    let held = [0.02, 0.02, surface - 0.0015 + 0.002];
    let delta = [0.0, 0.0, 1e-4];
    let moved = [held[0], held[1], held[2] + delta[2]];
    let same = drive(&mut a, at(0, held));
    let eased = drive(&mut b, at(0, moved));
    let drift = same.surgical.tools[0].force()[2] - lin.force[2];
    let actual = eased.surgical.tools[0].force()[2] - same.surgical.tools[0].force()[2];
    let predicted = lin.extrapolate(delta, [0.0; 3]).0[2] - lin.force[2];
    println!(
        "steady force {:.5} N on {} points (drift over the last frame {drift:.2e} N); eased 0.1 mm: actual change {actual:.5} N, predicted {predicted:.5} N, ratio {:.3}; contact points {} and {}",
        lin.force[2],
        last.surgical.tools[0].contact_points,
        actual / predicted,
        same.surgical.tools[0].contact_points,
        eased.surgical.tools[0].contact_points
    );
    assert!(drift.abs() < 0.01 * predicted.abs(), "not steady: the force drifts {drift} N a frame");
    assert_eq!(same.surgical.tools[0].contact_points, eased.surgical.tools[0].contact_points);
    let ratio = actual / predicted;
    assert!((0.7..=1.0).contains(&ratio), "actual {actual} N against predicted {predicted} N");
}

/// Determinism across thread counts with tools: two simulations of a 12³-voxel block at level 0
/// (1,728 elements, above the size from which the element loops are split between threads), one
/// on one thread and one on two sleeping workers, driven by the same poses of a spherical cutter
/// (cutting = "remove") and a separating blade, give bit-identical state hashes at each of 100
/// surgical steps, cuts included.
#[test]
fn tools_and_cuts_are_deterministic_across_thread_counts() {
    let tools = "[[tools]]
name = \"cutter\"
stiffness = 100.0
cutting = \"remove\"
outer = { shape = \"sphere\", radius = 0.001 }
inner = { shape = \"sphere\", radius = 0.003 }
[[tools]]
name = \"separator\"
stiffness = 100.0
cutting = \"separate\"
outer = { shape = \"blade\", length = 0.02, height = 0.02, thickness = 0.0005 }
inner = { shape = \"blade\", length = 0.02, height = 0.02, thickness = 0.0005 }
";
    let config = config([0.03; 3], [12; 3], 0, 1e-3, DOWN_G, &format!("{BASE}{tools}"));
    let volume = config.procedural_volume().unwrap();
    let mut one =
        Simulation::with_executor(&config, &volume, "d.toml", &Executor::single_thread()).unwrap();
    let mut two =
        Simulation::with_executor(&config, &volume, "d.toml", &Executor::new(2, Idle::Sleep))
            .unwrap();
    assert!(one.model().unwrap().elements.len() >= 1500);
    let (mut removed, mut severed) = (0, 0);
    for i in 0..100 {
        let s = f64::from(i) / 100.0;
        let tools = vec![
            input(0, [0.01, 0.015, 0.033 - 0.012 * s], [1.0, 0.0, 0.0, 0.0], 0.0),
            input(1, [0.02, 0.015, 0.032 - 0.012 * s], [1.0, 0.0, 0.0, 0.0], 0.0),
        ];
        let (fa, fb) = (drive(&mut one, tools.clone()), drive(&mut two, tools));
        assert_eq!(fa.state_hash, fb.state_hash, "step {i}: one thread and two differ");
        assert_eq!(fa.surgical, fb.surgical, "step {i}");
        removed += fa.counters.voxels_removed;
        severed += fa.counters.links_severed;
    }
    println!("{removed} voxels removed, {severed} links severed; 100 identical hashes");
    assert!(removed > 0 && severed > 0);
}

/// The tensor-mass family (paper 2: the liver as about 12,700 tetrahedra, SVK with the
/// incompressibility penalty, explicit central differences at 0.2 ms) with a spherical cutter
/// (cutting = "remove") pushed up into the liver's underside. Invariants: the tool meets the
/// boundary (contact points, a force pushing it back), tetrahedra are removed
/// (`counters.tets_removed` > 0, the removed ones listed in the frame and dead in the topology,
/// the live count down by as many), the boundary surface stays closed and gains no non-manifold
/// edge or vertex after every frame that removed some, and everything stays finite.
#[test]
fn tensor_mass_tetrahedra_are_pushed_and_cut() {
    use incise_sim::config::{
        CouplingSpec, Cutting, DEFAULT_CUT_FORCE, ShapeSpec, ToolContact, ToolSpec,
    };
    use incise_tool::{Primitive, Shape};
    let path = incise_tests::scene("liver_tensor_mass.toml");
    let mut scene = incise_scene::read_scene(&path).unwrap();
    scene.config.tools = vec![ToolSpec {
        name: "cutter".into(),
        outer: ShapeSpec::Shape(Shape::new(Primitive::Sphere { radius: 0.008 }, [0.0; 3]).unwrap()),
        inner: Some(ShapeSpec::Shape(
            Shape::new(Primitive::Sphere { radius: 0.01 }, [0.0; 3]).unwrap(),
        )),
        contact: ToolContact::Points,
        coupling: CouplingSpec::default(),
        stiffness: 100.0,
        damping: None,
        cutting: Cutting::Remove,
        cut_force: DEFAULT_CUT_FORCE,
        jaws: None,
        path: None,
    }];
    let mut sim =
        Simulation::new(&scene.config, &scene.geometry, "liver_tensor_mass.toml").unwrap();
    let tets = sim.tet().unwrap().topology.live_count();
    // The liver's tetrahedra as generated (6 per level-1 cell) already meet along edges alone
    // where cells of the volume touch diagonally (2 edges, 1 vertex, measured): the boundary is
    // closed but not a manifold there. The cuts must keep it closed and add no such place.
    let triangles = sim.surface().unwrap().triangle_list();
    check_closed(&triangles).unwrap();
    let edges0: std::collections::BTreeSet<[u32; 2]> =
        non_manifold_edges(&triangles).into_iter().collect();
    let vertices0 = singular_vertices(&triangles);
    println!(
        "as built: {} non-manifold edges, {} singular vertices",
        edges0.len(),
        vertices0.len()
    );
    let (cx, cy) = (0.118, 0.099);
    let bottom = {
        let p = sim.surface_positions().unwrap();
        sim.surface()
            .unwrap()
            .live_vertices()
            .iter()
            .map(|&v| p[v as usize])
            .filter(|q| (q[0] - cx).hypot(q[1] - cy) < 0.005)
            .map(|q| q[2])
            .fold(f64::INFINITY, f64::min)
    };
    let (mut removed, mut cut_frames, mut most_points, mut strongest) = (0, 0, 0, 0.0f64);
    // From 5 mm below the underside, 0.05 mm a frame (0.25 m/s), to 10 mm into it.
    for i in 0..600 {
        let z = bottom - 0.01 + 5e-5 * f64::from(i);
        let frame = drive(&mut sim, at(0, [cx, cy, z]));
        let tool = &frame.surgical.tools[0];
        most_points = most_points.max(tool.contact_points);
        strongest = strongest.min(tool.force()[2]);
        if frame.counters.tets_removed > 0 {
            assert_eq!(frame.counters.tets_removed, frame.surgical.tets_removed.len());
            let topology = &sim.tet().unwrap().topology;
            assert!(frame.surgical.tets_removed.iter().all(|&t| !topology.is_alive(t)));
            removed += frame.counters.tets_removed;
            cut_frames += 1;
            let triangles = sim.surface().unwrap().triangle_list();
            if let Err(e) = check_closed(&triangles) {
                panic!("frame {i}: the boundary is open at {e:?}");
            }
            let edges: std::collections::BTreeSet<[u32; 2]> =
                non_manifold_edges(&triangles).into_iter().collect();
            assert!(
                edges.is_subset(&edges0),
                "frame {i}: new non-manifold edges {:?}",
                edges.difference(&edges0).collect::<Vec<_>>()
            );
            let vertices = singular_vertices(&triangles);
            assert!(
                vertices.is_subset(&vertices0),
                "frame {i}: new singular vertices {:?}",
                vertices.difference(&vertices0).collect::<Vec<_>>()
            );
        }
    }
    let live = sim.tet().unwrap().topology.live_count();
    println!(
        "{tets} tetrahedra; {removed} removed in {cut_frames} frames ({live} live); up to {most_points} points in contact, force down to {strongest:.3} N"
    );
    assert!(most_points > 0 && strongest < 0.0, "the tissue never pushed the tool back");
    assert!(removed > 0);
    assert_eq!(tets - live, removed);
}

/// A small tensor-mass block (4 cm, 8³ cells split into 3,072 tetrahedra, SVK, explicit at
/// 0.2 ms, held at its base), whose generated boundary is a closed manifold, cut from the top by
/// a spherical cutter (cutting = "remove", cutting from 0.1 N on: the soft block yields to a
/// harder push) whose device sinks 1 cm in. Invariants: contact, tetrahedra removed
/// (and the live count down by as many), the boundary closed and manifold after every frame
/// that removed some, all finite.
#[test]
fn a_tensor_mass_block_stays_a_closed_manifold_when_cut() {
    let text = "name = \"tm\"
level = 0
[volume]
procedural = \"block\"
size_m = [0.04, 0.04, 0.04]
voxels = [8, 8, 8]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[model]
kind = \"tensor-mass\"
[integrator]
kind = \"explicit\"
dt = 0.0002
rayleigh_alpha = 5.0
[[fixed]]
plane = \"z\"
value = 0.0
[[tools]]
name = \"cutter\"
stiffness = 100.0
cutting = \"remove\"
cut_force = 0.1
outer = { shape = \"sphere\", radius = 0.005 }
inner = { shape = \"sphere\", radius = 0.006 }
";
    let mut sim = block(&SceneConfig::from_toml(text, "tm.toml").unwrap());
    assert_sound_surface(&sim, "as built");
    let tets = sim.tet().unwrap().topology.live_count();
    let (mut removed, mut cut_frames, mut most_points) = (0, 0, 0);
    // The sphere's bottom from 1 cm above the top, 0.05 mm a frame (0.25 m/s), to 1 cm into it.
    for i in 0..400 {
        let z = 0.05 + 0.005 - 5e-5 * f64::from(i);
        let frame = drive(&mut sim, at(0, [0.021, 0.019, z]));
        most_points = most_points.max(frame.surgical.tools[0].contact_points);
        if frame.counters.tets_removed > 0 {
            removed += frame.counters.tets_removed;
            cut_frames += 1;
            assert_sound_surface(&sim, &format!("frame {i}"));
        }
    }
    let live = sim.tet().unwrap().topology.live_count();
    println!(
        "{tets} tetrahedra; {removed} removed in {cut_frames} frames; up to {most_points} points in contact"
    );
    assert!(most_points > 0 && removed > 0);
    assert_eq!(tets - live, removed);
}
