//! What makes a pose usable, for every transport alike: all numbers finite, the orientation a
//! unit quaternion (one within [`UNIT_TOLERANCE`] of unit length is normalised, as a driver's
//! rounding leaves it; any other is refused), and a gripper angle ≥ 0. Whether the timestamps
//! go forward is the receiver's to judge: it needs the tool's previous pose.

use crate::raw::{HAS_ANGULAR_VELOCITY, HAS_LINEAR_VELOCITY, RawToolPose};
use std::fmt;

/// How far from 1 a quaternion's norm may be and still be normalised.
pub const UNIT_TOLERANCE: f64 = 1e-3;

/// Why a pose was refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PoseError {
    /// A number is NaN or infinite.
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// The orientation is not a unit quaternion (within [`UNIT_TOLERANCE`]).
    NotUnit {
        /// Its norm.
        norm: f64,
    },
    /// The gripper angle is negative.
    NegativeGripper {
        /// The angle (rad).
        angle: f64,
    },
}

impl fmt::Display for PoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NotFinite { field } => write!(f, "the pose's {field} is not finite"),
            Self::NotUnit { norm } => {
                write!(f, "the pose's orientation has norm {norm}, not 1 (within {UNIT_TOLERANCE})")
            }
            Self::NegativeGripper { angle } => {
                write!(f, "the pose's gripper angle {angle} rad is negative")
            }
        }
    }
}

impl std::error::Error for PoseError {}

/// A pose [`check_pose`] found usable, its quaternion normalised: what the haptic loop, the
/// physics and (as an `incise_tool::ToolPose`, which it converts to without another check) the
/// simulation take, so that a pose is checked once, where it enters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CheckedPose(RawToolPose);

impl CheckedPose {
    /// The pose's fields.
    #[must_use]
    pub fn raw(&self) -> &RawToolPose {
        &self.0
    }

    /// A pose this program checked before and kept where it can only be read back as it was
    /// written (a shared-memory cell of its own): not checked again.
    #[must_use]
    pub fn restored(pose: RawToolPose) -> Self {
        Self(pose)
    }
}

impl std::ops::Deref for CheckedPose {
    type Target = RawToolPose;

    fn deref(&self) -> &RawToolPose {
        &self.0
    }
}

/// `pose` made usable: its quaternion normalised, or the reason it cannot be used.
pub fn check_pose(pose: &RawToolPose) -> Result<CheckedPose, PoseError> {
    let norm = usable(pose)?;
    let mut checked = *pose;
    checked.orientation = pose.orientation.map(|c| c / norm);
    Ok(CheckedPose(checked))
}

impl CheckedPose {
    /// A pose read from outside that this program checked before it was kept there (a
    /// recording's poses): checked again, but its numbers kept exactly as given, since
    /// normalising an already normalised quaternion may move its last bits.
    pub fn verified(pose: &RawToolPose) -> Result<Self, PoseError> {
        usable(pose)?;
        Ok(Self(*pose))
    }
}

/// Whether `pose` is usable; the norm of its quaternion.
fn usable(pose: &RawToolPose) -> Result<f64, PoseError> {
    let finite = |v: &[f64], field| {
        if v.iter().all(|c| c.is_finite()) { Ok(()) } else { Err(PoseError::NotFinite { field }) }
    };
    finite(&pose.position, "position")?;
    finite(&pose.orientation, "orientation")?;
    finite(&[pose.gripper_angle], "gripper angle")?;
    if pose.has & HAS_LINEAR_VELOCITY != 0 {
        finite(&pose.linear_velocity, "linear velocity")?;
    }
    if pose.has & HAS_ANGULAR_VELOCITY != 0 {
        finite(&pose.angular_velocity, "angular velocity")?;
    }
    let norm = pose.orientation.iter().map(|c| c * c).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > UNIT_TOLERANCE {
        return Err(PoseError::NotUnit { norm });
    }
    if pose.gripper_angle < 0.0 {
        return Err(PoseError::NegativeGripper { angle: pose.gripper_angle });
    }
    Ok(norm)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_unit_quaternions_are_normalised_and_the_rest_refused() {
        let mut p = RawToolPose::at(0, [0.0, 0.1, 0.2]);
        p.orientation = [1.0005, 0.0, 0.0, 0.0];
        let checked = check_pose(&p).unwrap();
        assert!((checked.orientation[0] - 1.0).abs() < 1e-15);
        // Read back as recorded: checked, kept bit for bit.
        let bits = |q: [f64; 4]| q.map(f64::to_bits);
        assert_eq!(bits(CheckedPose::verified(&p).unwrap().orientation), bits(p.orientation));
        let mut bad = p;
        bad.position[0] = f64::NAN;
        assert!(CheckedPose::verified(&bad).is_err());
        p.orientation = [0.9, 0.0, 0.0, 0.0];
        assert!(matches!(check_pose(&p), Err(PoseError::NotUnit { .. })));
        p.orientation = [0.0; 4];
        assert!(matches!(check_pose(&p), Err(PoseError::NotUnit { .. })));
    }

    #[test]
    fn non_finite_numbers_and_negative_grippers_are_refused_naming_the_field() {
        let good = RawToolPose::at(0, [0.0; 3]);
        let mut p = good;
        p.position[1] = f64::NAN;
        assert_eq!(check_pose(&p), Err(PoseError::NotFinite { field: "position" }));
        let mut p = good;
        p.orientation[2] = f64::INFINITY;
        assert_eq!(check_pose(&p), Err(PoseError::NotFinite { field: "orientation" }));
        let mut p = good;
        p.gripper_angle = -0.1;
        assert!(check_pose(&p).unwrap_err().to_string().contains("negative"));
        // A velocity that is not given is not read.
        let mut p = good;
        p.linear_velocity[0] = f64::NAN;
        assert!(check_pose(&p).is_ok());
        p.has = HAS_LINEAR_VELOCITY;
        assert_eq!(check_pose(&p), Err(PoseError::NotFinite { field: "linear velocity" }));
    }
}
