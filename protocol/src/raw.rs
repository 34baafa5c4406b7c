//! `#[repr(C)]` twins of `ToolPose` and `ToolForce`: fixed-size, pointer-free records for
//! shared memory (iceoryx2 zero copy) and for C (`include/incise.h` declares the same layout,
//! and the tests compare the two field by field).
//!
//! The layout is part of the contract, like the `.proto` field numbers: fields are never moved
//! or resized; a new field takes reserved space, or the records get a new name.

use crate::v1;

/// A tool pose in shared memory: [`v1::ToolPose`]'s fields, 144 bytes, 8-byte aligned.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RawToolPose {
    /// See [`v1::ToolPose::sequence`].
    pub sequence: u64,
    /// Nanoseconds of the driver's monotonic clock.
    pub timestamp_ns: u64,
    /// The tool's origin (m).
    pub position: [f64; 3],
    /// Unit quaternion `w, x, y, z`.
    pub orientation: [f64; 4],
    /// m/s; meaningful when `has & HAS_LINEAR_VELOCITY`.
    pub linear_velocity: [f64; 3],
    /// rad/s; meaningful when `has & HAS_ANGULAR_VELOCITY`.
    pub angular_velocity: [f64; 3],
    /// rad, ≥ 0.
    pub gripper_angle: f64,
    /// The scene's tool id.
    pub tool_id: u32,
    /// Device buttons, one bit each.
    pub buttons: u32,
    /// Which optional fields are given ([`HAS_LINEAR_VELOCITY`], [`HAS_ANGULAR_VELOCITY`]).
    pub has: u32,
    /// The sending client's session: a random non-zero number its library picks when it
    /// connects (0: not given). See [`v1::ToolPose::client`].
    pub client: u32,
}

/// `RawToolPose::has`: the linear velocity is given.
pub const HAS_LINEAR_VELOCITY: u32 = 1;
/// `RawToolPose::has`: the angular velocity is given.
pub const HAS_ANGULAR_VELOCITY: u32 = 2;

/// A tool force in shared memory: [`v1::ToolForce`]'s fields, 80 bytes, 8-byte aligned.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RawToolForce {
    /// The pose sequence it answers.
    pub pose_sequence: u64,
    /// Nanoseconds of the server's monotonic clock.
    pub timestamp_ns: u64,
    /// N.
    pub force: [f64; 3],
    /// N·m about the tool's origin.
    pub torque: [f64; 3],
    /// N.
    pub gripper_force: f64,
    /// The scene's tool id.
    pub tool_id: u32,
    /// [`v1::ForceFlag`] bits.
    pub flags: u32,
}

impl RawToolPose {
    /// Tool `tool_id` at `position` (m), unrotated, with nothing else set.
    #[must_use]
    pub fn at(tool_id: u32, position: [f64; 3]) -> Self {
        Self { tool_id, position, orientation: [1.0, 0.0, 0.0, 0.0], ..Self::default() }
    }
}

/// A `ToolPose` that lacks a field a pose cannot do without.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MissingField(pub &'static str);

impl std::fmt::Display for MissingField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ToolPose has no {}", self.0)
    }
}

impl std::error::Error for MissingField {}

fn vec3(v: [f64; 3]) -> v1::Vec3 {
    v1::Vec3 { x: v[0], y: v[1], z: v[2] }
}

fn array(v: &v1::Vec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl From<&RawToolPose> for v1::ToolPose {
    fn from(r: &RawToolPose) -> Self {
        let [w, x, y, z] = r.orientation;
        Self {
            tool_id: r.tool_id,
            sequence: r.sequence,
            timestamp_ns: r.timestamp_ns,
            position: Some(vec3(r.position)),
            orientation: Some(v1::Quaternion { w, x, y, z }),
            linear_velocity: (r.has & HAS_LINEAR_VELOCITY != 0).then(|| vec3(r.linear_velocity)),
            angular_velocity: (r.has & HAS_ANGULAR_VELOCITY != 0).then(|| vec3(r.angular_velocity)),
            buttons: r.buttons,
            gripper_angle: r.gripper_angle,
            client: r.client,
        }
    }
}

impl TryFrom<&v1::ToolPose> for RawToolPose {
    type Error = MissingField;

    /// A pose needs its position and orientation; the velocities are optional.
    fn try_from(p: &v1::ToolPose) -> Result<Self, MissingField> {
        let position = p.position.as_ref().ok_or(MissingField("position"))?;
        let q = p.orientation.as_ref().ok_or(MissingField("orientation"))?;
        let mut has = 0;
        let mut velocity = |v: &Option<v1::Vec3>, bit: u32| {
            v.as_ref().map_or([0.0; 3], |v| {
                has |= bit;
                array(v)
            })
        };
        let linear_velocity = velocity(&p.linear_velocity, HAS_LINEAR_VELOCITY);
        let angular_velocity = velocity(&p.angular_velocity, HAS_ANGULAR_VELOCITY);
        Ok(Self {
            sequence: p.sequence,
            timestamp_ns: p.timestamp_ns,
            position: array(position),
            orientation: [q.w, q.x, q.y, q.z],
            linear_velocity,
            angular_velocity,
            gripper_angle: p.gripper_angle,
            tool_id: p.tool_id,
            buttons: p.buttons,
            has,
            client: p.client,
        })
    }
}

impl From<&RawToolForce> for v1::ToolForce {
    /// The shared-memory record does not carry the proxy's pose: `proxy` is absent (a sender
    /// that has it sets it, [`v1::ToolForce::with_proxy`]).
    fn from(r: &RawToolForce) -> Self {
        Self {
            tool_id: r.tool_id,
            pose_sequence: r.pose_sequence,
            timestamp_ns: r.timestamp_ns,
            force: Some(vec3(r.force)),
            torque: Some(vec3(r.torque)),
            gripper_force: r.gripper_force,
            flags: r.flags,
            proxy: None,
        }
    }
}

impl v1::Pose {
    /// A pose at `position` (m) turned by the unit quaternion `orientation` (`w, x, y, z`).
    #[must_use]
    pub fn of(position: [f64; 3], orientation: [f64; 4]) -> Self {
        let [w, x, y, z] = orientation;
        Self { position: Some(vec3(position)), orientation: Some(v1::Quaternion { w, x, y, z }) }
    }

    /// Its position and orientation, when both are given.
    #[must_use]
    pub fn parts(&self) -> Option<([f64; 3], [f64; 4])> {
        let (p, q) = (self.position.as_ref()?, self.orientation.as_ref()?);
        Some((array(p), [q.w, q.x, q.y, q.z]))
    }
}

impl v1::ToolForce {
    /// The same force with the proxy's pose (`position`, `orientation`) beside it.
    #[must_use]
    pub fn with_proxy(self, proxy: Option<([f64; 3], [f64; 4])>) -> Self {
        Self { proxy: proxy.map(|(p, q)| v1::Pose::of(p, q)), ..self }
    }
}

impl From<&v1::ToolForce> for RawToolForce {
    /// An absent force or torque is zero.
    fn from(f: &v1::ToolForce) -> Self {
        Self {
            pose_sequence: f.pose_sequence,
            timestamp_ns: f.timestamp_ns,
            force: f.force.as_ref().map_or([0.0; 3], array),
            torque: f.torque.as_ref().map_or([0.0; 3], array),
            gripper_force: f.gripper_force,
            tool_id: f.tool_id,
            flags: f.flags,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::mem::{align_of, offset_of, size_of};

    /// The layout `include/incise.h` declares (the C side is compared in `tests/c_layout.rs`).
    #[test]
    fn the_records_have_the_documented_layout() {
        assert_eq!((size_of::<RawToolPose>(), align_of::<RawToolPose>()), (144, 8));
        let pose = [
            offset_of!(RawToolPose, sequence),
            offset_of!(RawToolPose, timestamp_ns),
            offset_of!(RawToolPose, position),
            offset_of!(RawToolPose, orientation),
            offset_of!(RawToolPose, linear_velocity),
            offset_of!(RawToolPose, angular_velocity),
            offset_of!(RawToolPose, gripper_angle),
            offset_of!(RawToolPose, tool_id),
            offset_of!(RawToolPose, buttons),
            offset_of!(RawToolPose, has),
            offset_of!(RawToolPose, client),
        ];
        assert_eq!(pose, [0, 8, 16, 40, 72, 96, 120, 128, 132, 136, 140]);
        assert_eq!((size_of::<RawToolForce>(), align_of::<RawToolForce>()), (80, 8));
        let force = [
            offset_of!(RawToolForce, pose_sequence),
            offset_of!(RawToolForce, timestamp_ns),
            offset_of!(RawToolForce, force),
            offset_of!(RawToolForce, torque),
            offset_of!(RawToolForce, gripper_force),
            offset_of!(RawToolForce, tool_id),
            offset_of!(RawToolForce, flags),
        ];
        assert_eq!(force, [0, 8, 16, 40, 64, 72, 76]);
    }

    fn finite() -> impl Strategy<Value = f64> {
        -1e6..1e6f64
    }

    fn triple() -> impl Strategy<Value = [f64; 3]> {
        [finite(), finite(), finite()]
    }

    prop_compose! {
        fn raw_pose()(
            sequence in any::<u64>(), timestamp_ns in any::<u64>(), position in triple(),
            orientation in [finite(), finite(), finite(), finite()], linear in triple(),
            angular in triple(), gripper_angle in finite(), tool_id in any::<u32>(),
            buttons in any::<u32>(), has in 0u32..4, client in any::<u32>(),
        ) -> RawToolPose {
            // Absent velocities are zero in the record.
            let linear_velocity = if has & HAS_LINEAR_VELOCITY != 0 { linear } else { [0.0; 3] };
            let angular_velocity = if has & HAS_ANGULAR_VELOCITY != 0 { angular } else { [0.0; 3] };
            RawToolPose {
                sequence, timestamp_ns, position, orientation, linear_velocity, angular_velocity,
                gripper_angle, tool_id, buttons, has, client,
            }
        }
    }

    prop_compose! {
        fn raw_force()(
            pose_sequence in any::<u64>(), timestamp_ns in any::<u64>(), force in triple(),
            torque in triple(), gripper_force in finite(), tool_id in any::<u32>(),
            flags in any::<u32>(),
        ) -> RawToolForce {
            RawToolForce { pose_sequence, timestamp_ns, force, torque, gripper_force, tool_id, flags }
        }
    }

    proptest! {
        /// Record → message → bytes → message → record is the identity, and so is the other
        /// way round from a message with every field present.
        #[test]
        fn poses_convert_both_ways_through_the_wire(raw in raw_pose()) {
            use prost::Message;
            let message = v1::ToolPose::from(&raw);
            let decoded = v1::ToolPose::decode(message.encode_to_vec().as_slice()).unwrap();
            prop_assert_eq!(&decoded, &message);
            prop_assert_eq!(RawToolPose::try_from(&decoded).unwrap(), raw);
            prop_assert_eq!(v1::ToolPose::from(&RawToolPose::try_from(&message).unwrap()), message);
        }

        #[test]
        fn forces_convert_both_ways_through_the_wire(raw in raw_force()) {
            use prost::Message;
            let message = v1::ToolForce::from(&raw);
            let decoded = v1::ToolForce::decode(message.encode_to_vec().as_slice()).unwrap();
            prop_assert_eq!(RawToolForce::from(&decoded), raw);
            prop_assert_eq!(v1::ToolForce::from(&RawToolForce::from(&message)), message);
        }
    }

    #[test]
    fn a_pose_without_position_or_orientation_is_refused_and_velocities_are_optional() {
        let full = v1::ToolPose::from(&RawToolPose::at(2, [0.1, 0.2, 0.3]));
        assert_eq!(
            RawToolPose::try_from(&v1::ToolPose { position: None, ..full }).unwrap_err(),
            MissingField("position")
        );
        assert_eq!(
            RawToolPose::try_from(&v1::ToolPose { orientation: None, ..full }).unwrap_err(),
            MissingField("orientation")
        );
        let raw = RawToolPose::try_from(&full).unwrap();
        assert_eq!(raw.has, 0);
        assert!(full.linear_velocity.is_none() && full.angular_velocity.is_none());
    }

    #[test]
    fn the_largest_messages_fit_the_receive_limit() {
        use prost::Message;
        let big = RawToolPose {
            sequence: u64::MAX,
            timestamp_ns: u64::MAX,
            position: [1.5e300; 3],
            orientation: [1.5e300; 4],
            linear_velocity: [1.5e300; 3],
            angular_velocity: [1.5e300; 3],
            gripper_angle: 1.5e300,
            tool_id: u32::MAX,
            buttons: u32::MAX,
            has: 3,
            client: u32::MAX,
        };
        let n = v1::ToolPose::from(&big).encoded_len();
        assert!(n < 200, "{n} bytes");
        const { assert!(200 <= crate::MAX_TOOL_MESSAGE_BYTES) };
        let force = RawToolForce {
            pose_sequence: u64::MAX,
            timestamp_ns: u64::MAX,
            force: [1.5e300; 3],
            torque: [1.5e300; 3],
            gripper_force: 1.5e300,
            tool_id: u32::MAX,
            flags: u32::MAX,
        };
        assert!(v1::ToolForce::from(&force).encoded_len() < 200);
    }
}
