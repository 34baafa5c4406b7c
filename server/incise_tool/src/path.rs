//! A scripted tool path: poses at given times, so that a scene file alone replays a cut.
//!
//! Between waypoints the pose is interpolated ([`Pose::lerp`]) and so is the gripper angle;
//! before the first waypoint the tool waits at it, after the last it stays there.

use crate::pose::{Pose, ToolPose};

/// One waypoint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Waypoint {
    /// When the tool is here (s from the start).
    pub time: f64,
    /// Where it is.
    pub pose: ToolPose,
}

/// Why a path was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PathError {
    /// No waypoints.
    #[error("a tool path needs at least one waypoint")]
    Empty,
    /// Times that do not increase, or are not finite.
    #[error("waypoint {index}: its time must be finite and after the previous waypoint's")]
    Times {
        /// The waypoint whose time is wrong.
        index: usize,
    },
}

/// A checked path: waypoints at increasing times.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolPath {
    waypoints: Vec<Waypoint>,
}

impl ToolPath {
    /// Checks that the times increase strictly.
    pub fn new(waypoints: Vec<Waypoint>) -> Result<Self, PathError> {
        if waypoints.is_empty() {
            return Err(PathError::Empty);
        }
        for (index, w) in waypoints.iter().enumerate() {
            let after = index == 0 || w.time > waypoints[index - 1].time;
            if !w.time.is_finite() || !after {
                return Err(PathError::Times { index });
            }
        }
        Ok(Self { waypoints })
    }

    /// The waypoints.
    #[must_use]
    pub fn waypoints(&self) -> &[Waypoint] {
        &self.waypoints
    }

    /// The time of the last waypoint (s).
    #[must_use]
    pub fn end(&self) -> f64 {
        self.waypoints.last().map_or(0.0, |w| w.time)
    }

    /// The tool pose at time `t` (s).
    #[must_use]
    pub fn at(&self, t: f64) -> ToolPose {
        let w = &self.waypoints;
        let next = w.partition_point(|p| p.time <= t);
        if next == 0 {
            return w[0].pose;
        }
        if next == w.len() {
            return w[w.len() - 1].pose;
        }
        let (a, b) = (&w[next - 1], &w[next]);
        let s = (t - a.time) / (b.time - a.time);
        ToolPose {
            pose: Pose::lerp(&a.pose.pose, &b.pose.pose, s),
            gripper: a.pose.gripper + s * (b.pose.gripper - a.pose.gripper),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, gripper: f64) -> ToolPose {
        ToolPose::from_pose(Pose::at([x, 0.0, 0.0]), gripper).unwrap()
    }

    #[test]
    fn poses_are_interpolated_between_waypoints_and_held_outside() {
        let path = ToolPath::new(vec![
            Waypoint { time: 0.0, pose: at(0.0, 0.5) },
            Waypoint { time: 1.0, pose: at(0.01, 0.0) },
        ])
        .unwrap();
        let mid = path.at(0.25);
        assert!((mid.pose().position()[0] - 0.0025).abs() < 1e-15);
        assert!((mid.gripper() - 0.375).abs() < 1e-15);
        assert!((path.at(-1.0).pose().position()[0]).abs() < 1e-15);
        assert!((path.at(9.0).pose().position()[0] - 0.01).abs() < 1e-15);
        let bad = vec![
            Waypoint { time: 1.0, pose: at(0.0, 0.0) },
            Waypoint { time: 1.0, pose: at(0.0, 0.0) },
        ];
        assert_eq!(ToolPath::new(bad), Err(PathError::Times { index: 1 }));
        assert_eq!(ToolPath::new(vec![]), Err(PathError::Empty));
    }
}
