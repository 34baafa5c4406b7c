//! The session in Foxglove's schemas: the organ and the tools as a `foxglove.SceneUpdate`, and
//! each tool's device pose and proxy pose as a `foxglove.PoseInFrame`, all in one frame of
//! reference ([`FRAME_ID`], the simulation's grid frame).
//!
//! A tool with a proxy is drawn where its proxy is (the tool the tissue feels: `tool/<name>`),
//! with a translucent ghost of it at the device's pose and a line between the two, the coupling
//! (`device/<name>`). The force arrow starts at the device.

use crate::visual::{Mesh, ToolLook, ToolShape, label_colour};
use incise_protocol::foxglove as fg;
use incise_protocol::v1;

/// The frame of reference every entity and pose is given in.
pub const FRAME_ID: &str = "organ";

/// How long a force arrow is per newton (m/N): a 1 N push draws 2 cm.
pub const ARROW_M_PER_N: f64 = 0.02;

/// Simulated time (s) as a protobuf timestamp.
fn timestamp(sim_time_s: f64) -> prost_types::Timestamp {
    let ns = (sim_time_s.max(0.0) * 1e9).round() as i64;
    prost_types::Timestamp { seconds: ns / 1_000_000_000, nanos: (ns % 1_000_000_000) as i32 }
}

fn vector(v: [f64; 3]) -> fg::Vector3 {
    fg::Vector3 { x: v[0], y: v[1], z: v[2] }
}

fn colour(rgba: [u8; 4]) -> fg::Color {
    let c = |i: usize| f64::from(rgba[i]) / 255.0;
    fg::Color { r: c(0), g: c(1), b: c(2), a: c(3) }
}

/// A pose's orientation as a unit quaternion (a recorded pose is as the client sent it, within
/// the protocol's tolerance of unit length; Foxglove wants it normalised).
fn orientation(q: Option<&v1::Quaternion>) -> fg::Quaternion {
    let Some(q) = q else { return fg::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 } };
    let n = (q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z).sqrt();
    if n > 0.0 && n.is_finite() {
        fg::Quaternion { x: q.x / n, y: q.y / n, z: q.z / n, w: q.w / n }
    } else {
        fg::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

fn position(p: Option<&v1::Vec3>) -> [f64; 3] {
    p.map_or([0.0; 3], |p| [p.x, p.y, p.z])
}

/// A pose (a device's or a proxy's) as Foxglove's `PoseInFrame`.
#[must_use]
pub fn pose_in_frame(
    at: Option<&v1::Vec3>,
    rotation: Option<&v1::Quaternion>,
    sim_time_s: f64,
) -> fg::PoseInFrame {
    fg::PoseInFrame {
        timestamp: Some(timestamp(sim_time_s)),
        frame_id: FRAME_ID.into(),
        pose: Some(fg::Pose {
            position: Some(vector(position(at))),
            orientation: Some(orientation(rotation)),
        }),
    }
}

/// The scene at simulated time `sim_time_s`: the organ `mesh` (one triangle list per tissue
/// label, coloured by [`label_colour`]) and every posed tool of `record` (its outer shape, and
/// an arrow for the force on it).
#[must_use]
pub fn scene_update(
    sim_time_s: f64,
    mesh: &Mesh,
    tools: &[ToolLook],
    record: Option<&v1::FrameRecord>,
) -> fg::SceneUpdate {
    let stamp = Some(timestamp(sim_time_s));
    let entity = |id: String| fg::SceneEntity {
        timestamp: stamp,
        frame_id: FRAME_ID.into(),
        id,
        ..fg::SceneEntity::default()
    };
    let mut organ = entity("organ".into());
    let (triangles, labels) = (&mesh.triangles, &mesh.labels);
    let mut by_label: Vec<u16> = labels.clone();
    by_label.sort_unstable();
    by_label.dedup();
    let point =
        |p: &[f32; 3]| fg::Point3 { x: f64::from(p[0]), y: f64::from(p[1]), z: f64::from(p[2]) };
    for label in by_label {
        // Each label's list holds only the points its triangles use.
        let mut index = vec![u32::MAX; mesh.positions.len()];
        let mut points = Vec::new();
        let mut indices = Vec::new();
        for (t, _) in triangles.iter().zip(labels).filter(|&(_, &l)| l == label) {
            for &v in t {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = points.len() as u32;
                    points.push(point(&mesh.positions[v as usize]));
                }
                indices.push(index[v as usize]);
            }
        }
        organ.triangles.push(fg::TriangleListPrimitive {
            pose: None,
            points,
            color: Some(colour(label_colour(label))),
            colors: Vec::new(),
            indices,
        });
    }
    let mut entities = vec![organ];
    for state in record.map_or(&[][..], |r| &r.tools) {
        let Some(look) = tools.get(state.tool_id as usize) else { continue };
        let Some(pose) = record.and_then(|r| r.poses.iter().find(|p| p.tool_id == state.tool_id))
        else {
            continue;
        };
        let device = (position(pose.position.as_ref()), orientation(pose.orientation.as_ref()));
        // The tool the tissue feels is the proxy; the device's pose is drawn as a ghost of it,
        // tied to it by the coupling's line.
        let felt = state.proxy.as_ref().map_or(device, |p| {
            (position(p.position.as_ref()), orientation(p.orientation.as_ref()))
        });
        let mut tool = entity(format!("tool/{}", look.name));
        draw_shape(&mut tool, look.shape, &felt.0, &felt.1, colour([160, 160, 170, 255]));
        let force = position(state.force.as_ref());
        let magnitude = force.iter().map(|c| c * c).sum::<f64>().sqrt();
        if magnitude > 0.0 {
            let length = magnitude * ARROW_M_PER_N;
            tool.arrows.push(fg::ArrowPrimitive {
                pose: Some(fg::Pose {
                    position: Some(vector(device.0)),
                    orientation: Some(x_onto(force.map(|c| c / magnitude))),
                }),
                shaft_length: length * 0.8,
                shaft_diameter: length * 0.05,
                head_length: length * 0.2,
                head_diameter: length * 0.12,
                color: Some(colour([250, 220, 40, 255])),
            });
        }
        entities.push(tool);
        if state.proxy.is_some() {
            let mut ghost = entity(format!("device/{}", look.name));
            draw_shape(&mut ghost, look.shape, &device.0, &device.1, colour([120, 170, 250, 90]));
            let point = |p: [f64; 3]| fg::Point3 { x: p[0], y: p[1], z: p[2] };
            ghost.lines.push(fg::LinePrimitive {
                r#type: fg::line_primitive::Type::LineStrip as i32,
                pose: None,
                thickness: 2.0,
                scale_invariant: true,
                points: vec![point(device.0), point(felt.0)],
                color: Some(colour([120, 170, 250, 255])),
                colors: Vec::new(),
                indices: Vec::new(),
            });
            entities.push(ghost);
        }
    }
    fg::SceneUpdate { deletions: Vec::new(), entities }
}

/// A tool's outer shape at the pose (`at`, `q`), in `colour`.
fn draw_shape(
    entity: &mut fg::SceneEntity,
    shape: ToolShape,
    at: &[f64; 3],
    q: &fg::Quaternion,
    colour: fg::Color,
) {
    let (at, q) = (*at, *q);
    let rotate = |v: [f64; 3]| rotate(&q, v);
    match shape {
        ToolShape::Sphere { centre, radius } => entity.spheres.push(fg::SpherePrimitive {
            pose: Some(placed(at, rotate(centre), q)),
            size: Some(vector([2.0 * radius; 3])),
            color: Some(colour),
        }),
        // Foxglove has no capsule: a box around its axis shows where it is.
        ToolShape::Capsule { start, radius, length } => entity.cubes.push(fg::CubePrimitive {
            pose: Some(placed(at, rotate([start[0], start[1], start[2] + length / 2.0]), q)),
            size: Some(vector([2.0 * radius, 2.0 * radius, length + 2.0 * radius])),
            color: Some(colour),
        }),
        ToolShape::Box { min, max } => entity.cubes.push(fg::CubePrimitive {
            pose: Some(placed(
                at,
                rotate(std::array::from_fn(|i| f64::midpoint(min[i], max[i]))),
                q,
            )),
            size: Some(vector(std::array::from_fn(|i| max[i] - min[i]))),
            color: Some(colour),
        }),
    }
}

/// A pose at the tool's position plus `offset` (already rotated), with the tool's rotation.
fn placed(at: [f64; 3], offset: [f64; 3], q: fg::Quaternion) -> fg::Pose {
    fg::Pose {
        position: Some(vector(std::array::from_fn(|i| at[i] + offset[i]))),
        orientation: Some(q),
    }
}

/// `v` rotated by the unit quaternion `q`.
fn rotate(q: &fg::Quaternion, v: [f64; 3]) -> [f64; 3] {
    // v + 2 w (u × v) + 2 u × (u × v), u the quaternion's vector part.
    let u = [q.x, q.y, q.z];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    };
    let t = cross(u, v).map(|c| 2.0 * c);
    let ut = cross(u, t);
    std::array::from_fn(|i| v[i] + q.w * t[i] + ut[i])
}

/// The shortest rotation taking `+x` onto the unit vector `d` (Foxglove's arrows point along
/// their pose's `+x`).
fn x_onto(d: [f64; 3]) -> fg::Quaternion {
    // Half-way quaternion: (1 + x·d, x × d), normalised; x × d = (0, -d_z, d_y).
    let w = 1.0 + d[0];
    if w < 1e-9 {
        // d = -x: half a turn about z.
        return fg::Quaternion { x: 0.0, y: 0.0, z: 1.0, w: 0.0 };
    }
    let (x, y, z) = (0.0, -d[2], d[1]);
    let n = (w * w + y * y + z * z).sqrt();
    fg::Quaternion { x: x / n, y: y / n, z: z / n, w: w / n }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_arrow_along_d_points_along_d() {
        for d in
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.6, 0.0, 0.8]]
        {
            let got = rotate(&x_onto(d), [1.0, 0.0, 0.0]);
            for i in 0..3 {
                assert!((got[i] - d[i]).abs() < 1e-12, "{d:?} → {got:?}");
            }
        }
    }

    #[test]
    fn each_label_gets_a_triangle_list_of_its_own_points() {
        let mesh = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            labels: vec![1, 2],
        };
        let update = scene_update(0.5, &mesh, &[], None);
        let organ = &update.entities[0];
        assert_eq!(organ.triangles.len(), 2);
        for (list, want) in organ.triangles.iter().zip([[0usize, 1, 2], [1, 3, 2]]) {
            assert_eq!(list.indices, vec![0, 1, 2]);
            for (i, &v) in list.indices.iter().zip(&want) {
                let p = &list.points[*i as usize];
                // Widened exactly: the same bits.
                assert_eq!(
                    [p.x, p.y, p.z].map(f64::to_bits),
                    mesh.positions[v].map(|c| f64::from(c).to_bits())
                );
            }
        }
    }

    #[test]
    fn a_tool_is_drawn_at_its_proxy_with_a_ghost_at_its_device() {
        let v = |x: f64, y: f64, z: f64| Some(v1::Vec3 { x, y, z });
        let record = v1::FrameRecord {
            poses: vec![v1::ToolPose {
                tool_id: 0,
                position: v(0.0, 0.0, -0.01),
                ..v1::ToolPose::default()
            }],
            tools: vec![v1::ToolState {
                tool_id: 0,
                force: v(0.0, 0.0, 2.0),
                proxy: Some(v1::Pose { position: v(0.0, 0.0, 0.005), orientation: None }),
                ..v1::ToolState::default()
            }],
            ..v1::FrameRecord::default()
        };
        let look = ToolLook {
            name: "probe".into(),
            shape: ToolShape::Sphere { centre: [0.0; 3], radius: 0.002 },
        };
        let mesh = Mesh { positions: Vec::new(), triangles: Vec::new(), labels: Vec::new() };
        let update = scene_update(0.0, &mesh, &[look], Some(&record));
        let ids: Vec<&str> = update.entities.iter().map(|e| e.id.as_str()).collect();
        assert_eq!(ids, ["organ", "tool/probe", "device/probe"]);
        // The poses are copied, not computed: bit for bit.
        let z =
            |pose: &Option<fg::Pose>| pose.as_ref().unwrap().position.as_ref().unwrap().z.to_bits();
        let (tool, ghost) = (&update.entities[1], &update.entities[2]);
        assert_eq!(z(&tool.spheres[0].pose), 0.005f64.to_bits());
        assert_eq!(z(&tool.arrows[0].pose), (-0.01f64).to_bits(), "the force is the device's");
        assert_eq!(z(&ghost.spheres[0].pose), (-0.01f64).to_bits());
        let line: Vec<f64> = ghost.lines[0].points.iter().map(|p| p.z).collect();
        assert_eq!(line, [-0.01, 0.005]);
    }

    #[test]
    fn timestamps_split_seconds_and_nanoseconds() {
        let t = timestamp(2.5);
        assert_eq!((t.seconds, t.nanos), (2, 500_000_000));
    }
}
