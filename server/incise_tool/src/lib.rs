//! Surgical tools (Jeřábková 2010, §3): a rigid pose carrying an outer shape that pushes the
//! tissue and an inner shape that cuts it.
//!
//! - [`pose`]: checked poses (finite, unit quaternion), frames, interpolation;
//! - [`shape`]: shapes by signed distance: analytic (sphere, capsule, cuboid, blade) or a closed
//!   triangle mesh ([`mesh_shape`]);
//! - [`proxy`]: the tool the tissue feels, a proxy that follows the device but never enters the
//!   tissue, pushing it through the surface's triangles with the coupling's spring (a force
//!   field of `incise_fem`);
//! - [`linearisation`]: a tool's force and torque and their derivative in its pose, for the
//!   haptic loop;
//! - [`cut`]: what the inner shape cuts: the flood from where it enters, and a blade's swept
//!   mid-plane for separation;
//! - [`grasp`]: jaws that hold the surface points between them;
//! - [`path`]: scripted tool paths (waypoints with times);
//! - [`volume_contact`]: the intersection volume of closed surfaces from layered depth images,
//!   and its gradient (organ on organ, organ on tool mesh).
//!
//! Pure: data in, data out; no files, threads or clocks.

pub mod cut;
mod geometry;
pub mod grasp;
pub mod linearisation;
pub mod mesh_shape;
pub mod path;
pub mod pose;
pub mod proxy;
pub mod shape;
pub mod volume_contact;

pub use cut::{SweptBlade, flood};
pub use grasp::{Grasp, GraspEvent, Jaws};
pub use linearisation::Linearisation;
pub use path::{PathError, ToolPath, Waypoint};
pub use pose::{Pose, PoseError, ToolPose};
pub use proxy::{ContactSettings, Coupling};
pub use shape::{Primitive, Shape, ShapeError};
