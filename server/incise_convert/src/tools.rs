//! The scene's tools as a recording draws them, and a checked pose as the step's input.

use incise_protocol::check::CheckedPose;
use incise_record::{ToolLook, ToolShape};
use incise_sim::config::ShapeSpec;
use incise_sim::{SceneConfig, ToolInput};
use incise_tool::{Primitive, ToolPose};

/// How each of the scene's tools is drawn in a recording: its outer shape (a mesh file's tool
/// as its bounding box).
#[must_use]
pub fn tool_looks(config: &SceneConfig) -> Vec<ToolLook> {
    config
        .tools
        .iter()
        .map(|t| {
            let shape = match &t.outer {
                ShapeSpec::Shape(shape) => match shape.primitive() {
                    Some(Primitive::Sphere { radius }) => {
                        let (lo, hi) = shape.bounds();
                        ToolShape::Sphere {
                            centre: std::array::from_fn(|i| f64::midpoint(lo[i], hi[i])),
                            radius,
                        }
                    }
                    Some(Primitive::Capsule { radius, length }) => {
                        let (lo, _) = shape.bounds();
                        ToolShape::Capsule {
                            start: [lo[0] + radius, lo[1] + radius, lo[2] + radius],
                            radius,
                            length,
                        }
                    }
                    _ => {
                        let (min, max) = shape.bounds();
                        ToolShape::Box { min, max }
                    }
                },
                // Read by the scene reader before a simulation is built; a unit box stands in.
                ShapeSpec::Mesh { offset, .. } => ToolShape::Box {
                    min: offset.map(|c| c - 0.005),
                    max: offset.map(|c| c + 0.005),
                },
            };
            ToolLook { name: t.name.clone(), shape }
        })
        .collect()
}

/// The step's input for a checked pose, without another check: its numbers exactly as the
/// check left them. A replay converts recorded poses with this same function (after checking
/// them, as it reads them from a file), so that it steps with the very inputs the server did.
#[must_use]
pub fn tool_input(pose: &CheckedPose) -> ToolInput {
    let tool_pose = ToolPose::restored(pose.position, pose.orientation, pose.gripper_angle);
    ToolInput { tool: pose.tool_id as usize, pose: tool_pose }
}
