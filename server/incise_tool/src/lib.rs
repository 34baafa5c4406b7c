//! Surgical tools (Jeřábková 2010, §3): a rigid pose carrying an outer shape that pushes the
//! tissue and an inner shape that cuts it.
//!
//! - [`pose`]: checked poses (finite, unit quaternion), frames, interpolation;
//! - [`shape`]: shapes by signed distance: analytic (sphere, capsule, cuboid, blade) or a closed
//!   triangle mesh ([`mesh_shape`]);
//! - [`contact`]: penalty contact of the outer shape with the surface, as springs on embedded
//!   points (a force field of `incise_fem`), swept so a fast tool does not tunnel, and its
//!   linearisation with respect to the pose for the haptic loop;
//! - [`cut`]: what the inner shape cuts: the flood from where it enters, and a blade's swept
//!   mid-plane for separation;
//! - [`grasp`]: jaws that hold the surface points between them;
//! - [`path`]: scripted tool paths (waypoints with times);
//! - [`volume_contact`]: the intersection volume of closed surfaces from layered depth images,
//!   and its gradient (organ on organ, organ on tool mesh).
//!
//! Pure: data in, data out; no files, threads or clocks.

pub mod contact;
pub mod cut;
pub mod grasp;
pub mod mesh_shape;
pub mod path;
pub mod pose;
pub mod shape;
pub mod volume_contact;

pub use contact::{Contact, ContactMemory, ContactPoint, ContactSettings, Linearisation, detect};
pub use cut::{SweptBlade, flood};
pub use grasp::{Grasp, GraspEvent, Jaws};
pub use path::{PathError, ToolPath, Waypoint};
pub use pose::{Pose, PoseError, ToolPose};
pub use shape::{Primitive, Shape, ShapeError};
