//! A tool's rigid pose: where its frame is and how it is turned, as a haptic device reports it.
//!
//! A pose maps the tool frame (where its shapes are defined) to the grid frame the simulation
//! runs in: `p_grid = R q + position`. Poses come from outside (a device driver, a network
//! message, a script), so they are checked before they touch the state: every number finite and
//! the quaternion of unit length within [`UNIT_TOLERANCE`]. A driver that sends a slightly
//! denormalised quaternion (single-precision round trips) is accepted and renormalised; one that
//! sends a scaled or zero quaternion is refused, because guessing its rotation would move the
//! tool somewhere the user did not put it.

use incise_math::Vec3;
use incise_math::mat3::{Mat3, mul_transpose_vec, mul_vec};
use incise_math::rotation::Quat;

/// How far from 1 a pose's quaternion norm may be (single-precision drivers round to ~1e-7).
pub const UNIT_TOLERANCE: f64 = 1e-4;

/// Why a pose was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PoseError {
    /// A coordinate or quaternion component is NaN or infinite.
    #[error("the pose is not finite: position {position:?}, rotation (w, x, y, z) {rotation:?}")]
    NotFinite {
        /// The position given.
        position: Vec3,
        /// The quaternion given, `(w, x, y, z)`.
        rotation: [f64; 4],
    },
    /// The quaternion is not of unit length.
    #[error(
        "the pose's rotation (w, x, y, z) {rotation:?} has norm {norm}; a rotation quaternion has norm 1 (within {UNIT_TOLERANCE:e})"
    )]
    NotUnit {
        /// The quaternion given, `(w, x, y, z)`.
        rotation: [f64; 4],
        /// Its norm.
        norm: f64,
    },
    /// The gripper angle is not finite or negative.
    #[error("the gripper angle {angle} rad is not a finite angle ≥ 0")]
    BadGripper {
        /// The angle given (rad).
        angle: f64,
    },
}

/// A checked rigid pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    position: Vec3,
    rotation: Quat,
    matrix: Mat3,
}

impl Pose {
    /// The tool frame at the grid frame's origin, unrotated.
    pub const IDENTITY: Self = Self {
        position: [0.0; 3],
        rotation: Quat::IDENTITY,
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };

    /// A pose from a position (m, grid frame) and a rotation quaternion `(w, x, y, z)`.
    pub fn new(position: Vec3, rotation: [f64; 4]) -> Result<Self, PoseError> {
        if !position.iter().chain(&rotation).all(|c| c.is_finite()) {
            return Err(PoseError::NotFinite { position, rotation });
        }
        let norm = rotation.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > UNIT_TOLERANCE {
            return Err(PoseError::NotUnit { rotation, norm });
        }
        let [w, x, y, z] = rotation;
        let rotation = Quat { w, v: [x, y, z] }.normalized();
        Ok(Self { position, rotation, matrix: rotation.to_matrix() })
    }

    /// A pose exactly as [`Self::position`] and [`Self::rotation`] gave it: the rotation is not
    /// normalised again, so a restored pose has the same bits as the one saved. Unchecked, like
    /// [`Self::at`].
    #[must_use]
    pub fn restored(position: Vec3, rotation: [f64; 4]) -> Self {
        let [w, x, y, z] = rotation;
        let rotation = Quat { w, v: [x, y, z] };
        Self { position, rotation, matrix: rotation.to_matrix() }
    }

    /// A translation only. Unchecked (for positions the program computes): a NaN or infinite
    /// coordinate makes a pose that `Simulation::step` refuses; a position from outside goes
    /// through [`Self::new`].
    #[must_use]
    pub fn at(position: Vec3) -> Self {
        Self { position, ..Self::IDENTITY }
    }

    /// The position of the tool frame's origin (m).
    #[must_use]
    pub fn position(&self) -> Vec3 {
        self.position
    }

    /// The rotation, `(w, x, y, z)`.
    #[must_use]
    pub fn rotation(&self) -> [f64; 4] {
        [self.rotation.w, self.rotation.v[0], self.rotation.v[1], self.rotation.v[2]]
    }

    /// The rotation matrix `R` (tool axes as columns, in the grid frame).
    #[must_use]
    pub fn matrix(&self) -> &Mat3 {
        &self.matrix
    }

    /// A point of the tool frame in the grid frame.
    #[must_use]
    pub fn grid_from_tool(&self, q: Vec3) -> Vec3 {
        let r = mul_vec(&self.matrix, &q);
        std::array::from_fn(|k| r[k] + self.position[k])
    }

    /// A point of the grid frame in the tool frame.
    #[must_use]
    pub fn tool_from_grid(&self, p: Vec3) -> Vec3 {
        mul_transpose_vec(&self.matrix, &std::array::from_fn(|k| p[k] - self.position[k]))
    }

    /// A direction of the tool frame in the grid frame.
    #[must_use]
    pub fn rotate(&self, d: Vec3) -> Vec3 {
        mul_vec(&self.matrix, &d)
    }

    /// The pose a fraction `t` ∈ [0, 1] of the way from `self` to `to`: positions interpolated
    /// linearly, rotations along the shorter arc (normalised linear interpolation, which is
    /// close enough to the geodesic for the small turns between two frames).
    #[must_use]
    pub fn lerp(&self, to: &Self, t: f64) -> Self {
        let position =
            std::array::from_fn(|k| self.position[k] + t * (to.position[k] - self.position[k]));
        let (a, b) = (self.rotation(), to.rotation());
        let sign = if (0..4).map(|k| a[k] * b[k]).sum::<f64>() < 0.0 { -1.0 } else { 1.0 };
        let q: [f64; 4] = std::array::from_fn(|k| a[k] + t * (sign * b[k] - a[k]));
        let rotation = Quat { w: q[0], v: [q[1], q[2], q[3]] }.normalized();
        Self { position, rotation, matrix: rotation.to_matrix() }
    }

    /// The same rotation at `position` (m).
    #[must_use]
    pub fn with_position(&self, position: Vec3) -> Self {
        Self { position, ..*self }
    }

    /// The pose moved by a small translation `dt` (m) and a small rotation vector `dtheta`
    /// (rad, grid frame, about the tool's origin): what a haptic loop extrapolates over.
    /// Unchecked like [`Self::at`]: a NaN or infinite translation makes a pose that is not finite.
    #[must_use]
    pub fn moved(&self, dt: Vec3, dtheta: Vec3) -> Self {
        let angle = dtheta.iter().map(|c| c * c).sum::<f64>().sqrt();
        let turn = if angle > 0.0 {
            Quat::from_axis_angle(&dtheta.map(|c| c / angle), angle)
        } else {
            Quat::IDENTITY
        };
        let rotation = turn.mul(&self.rotation).normalized();
        let position = std::array::from_fn(|k| self.position[k] + dt[k]);
        Self { position, rotation, matrix: rotation.to_matrix() }
    }
}

/// A tool's pose with its gripper: what a device sends each frame, checked. The only ways to
/// make one check it ([`Self::new`], [`Self::from_pose`]) or restore one that was
/// ([`Self::restored`]), so whoever takes one (the haptic loop's hand-off, the physics, the
/// simulation) can use it as it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolPose {
    pub(crate) pose: Pose,
    pub(crate) gripper: f64,
}

impl ToolPose {
    /// A checked tool pose (see [`Pose::new`]); the gripper angle must be finite and ≥ 0.
    pub fn new(position: Vec3, rotation: [f64; 4], gripper: f64) -> Result<Self, PoseError> {
        Self::from_pose(Pose::new(position, rotation)?, gripper)
    }

    /// `pose` with `gripper`, checked: a pose the program computed ([`Pose::at`],
    /// [`Pose::moved`]) is refused if any of its numbers is not finite.
    pub fn from_pose(pose: Pose, gripper: f64) -> Result<Self, PoseError> {
        let (position, rotation) = (pose.position(), pose.rotation());
        if !position.iter().chain(&rotation).all(|c| c.is_finite()) {
            return Err(PoseError::NotFinite { position, rotation });
        }
        if !(gripper.is_finite() && gripper >= 0.0) {
            return Err(PoseError::BadGripper { angle: gripper });
        }
        Ok(Self { pose, gripper })
    }

    /// A tool pose exactly as one that was checked gave it ([`Pose::restored`]: its rotation is
    /// not normalised again, so the bits are the same): one read back from where the program
    /// kept it, or one checked by the wire protocol's own check. Not checked again.
    #[must_use]
    pub fn restored(position: Vec3, rotation: [f64; 4], gripper: f64) -> Self {
        Self { pose: Pose::restored(position, rotation), gripper }
    }

    /// Where the tool is.
    #[must_use]
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// The jaws' opening angle (rad); 0 closed. Tools without jaws ignore it.
    #[must_use]
    pub fn gripper(&self) -> f64 {
        self.gripper
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "a renormalised identity is exactly the identity")]
mod tests {
    use super::*;

    #[test]
    fn bad_poses_are_refused_and_near_unit_ones_renormalised() {
        let nan = Pose::new([0.0, f64::NAN, 0.0], [1.0, 0.0, 0.0, 0.0]).unwrap_err();
        assert!(nan.to_string().contains("not finite"), "{nan}");
        let scaled = Pose::new([0.0; 3], [2.0, 0.0, 0.0, 0.0]).unwrap_err();
        assert!(scaled.to_string().contains("norm 2"), "{scaled}");
        assert!(Pose::new([0.0; 3], [0.0; 4]).is_err());
        assert!(ToolPose::new([0.0; 3], [1.0, 0.0, 0.0, 0.0], -0.1).is_err());
        assert!(ToolPose::from_pose(Pose::at([f64::NAN, 0.0, 0.0]), 0.0).is_err());
        assert!(ToolPose::from_pose(Pose::at([0.0; 3]), f64::INFINITY).is_err());
        let near = Pose::new([0.0; 3], [1.0 + 1e-6, 0.0, 0.0, 0.0]).unwrap();
        assert_eq!(near.rotation(), [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn frames_round_trip_and_small_moves_compose() {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let pose = Pose::new([0.1, -0.2, 0.3], [s, 0.0, s, 0.0]).unwrap();
        let q = [0.01, 0.02, -0.03];
        let back = pose.tool_from_grid(pose.grid_from_tool(q));
        assert!((0..3).all(|k| (back[k] - q[k]).abs() < 1e-15));
        // 90° about y: the tool's x axis points along −z.
        let x = pose.rotate([1.0, 0.0, 0.0]);
        assert!((x[2] + 1.0).abs() < 1e-15);
        let moved = pose.moved([1e-3, 0.0, 0.0], [0.0, 0.0, 1e-3]);
        let p = moved.grid_from_tool([0.0; 3]);
        assert!((p[0] - 0.101).abs() < 1e-15);
        assert_eq!(pose.lerp(&moved, 0.0), pose);
        let end = pose.lerp(&moved, 1.0);
        assert!(
            (0..3)
                .all(|r| (0..3).all(|c| (end.matrix()[r][c] - moved.matrix()[r][c]).abs() < 1e-12))
        );
    }
}
