//! Grasping: jaws that, closed on the tissue, hold the surface points between them.
//!
//! The jaws open in the tool's `y` direction, hinged at the tool's origin and reaching `length`
//! along `+z`, `width` wide in `x`; the device's gripper angle opens them. They close (the
//! gripper angle falls below `close_below`) and, if the tool's outer shape touches the tissue
//! at that moment, every surface point in the space the jaws swept while closing (their
//! opening at `open_above`) is held: a spring of stiffness `k I` pulls it toward where it was in
//! the tool's frame when the jaws closed, so the tissue moves with the tool. The grasp lets go
//! when the angle rises above `open_above`. The two thresholds differ so that a trembling hand
//! on the gripper does not grab and drop the tissue at every frame. The springs are tissue
//! forces like the contact's, damped (`c I`) relative to the jaws' motion, and their negated sum
//! is part of the tool's force.

use crate::pose::Pose;
use incise_fem::forcefield::springs::{EmbeddedPoint, EmbeddedSpring};
use incise_math::Vec3;

/// A tool's jaws.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Jaws {
    /// How far the jaws reach along `+z` from the hinge at the tool's origin (m).
    pub length: f64,
    /// Their width along `x` (m).
    pub width: f64,
    /// The gripper angle below which they close (rad).
    pub close_below: f64,
    /// The angle above which they open again (rad); greater than `close_below`.
    pub open_above: f64,
    /// The holding springs' stiffness per point (N/m).
    pub stiffness: f64,
}

impl Jaws {
    /// Whether tool-frame point `q` lies between the jaws opened to `angle`.
    #[must_use]
    pub fn between(&self, q: Vec3, angle: f64) -> bool {
        let gap = 2.0 * self.length * (0.5 * angle).sin();
        q[0].abs() <= 0.5 * self.width
            && q[1].abs() <= 0.5 * gap
            && (0.0..=self.length).contains(&q[2])
    }
}

/// A point held by the jaws.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Held {
    /// The surface vertex.
    pub id: u32,
    /// Where it is held, in the tool frame (m).
    pub anchor: Vec3,
}

/// What a grasp did this frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GraspEvent {
    /// Nothing changed.
    None,
    /// The jaws closed and took hold of this many points (0: they closed on nothing).
    Closed(usize),
    /// The jaws opened and let go of this many points.
    Opened(usize),
}

/// The state of a tool's jaws.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Grasp {
    closed: bool,
    held: Vec<Held>,
}

impl Grasp {
    /// Whether the jaws are closed.
    #[must_use]
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// Jaws `closed` or not, holding `held` (as [`Self::is_closed`] and [`Self::held`] gave
    /// them: a snapshot of the state).
    #[must_use]
    pub fn restored(closed: bool, held: Vec<Held>) -> Self {
        Self { closed, held }
    }

    /// The points held, in the order they were taken.
    #[must_use]
    pub fn held(&self) -> &[Held] {
        &self.held
    }

    /// Follows the gripper angle: closes (taking hold of the points between the jaws if
    /// `touching`), or opens (letting go). `points` are the surface vertices' ids and deformed
    /// positions at this frame.
    pub fn update(
        &mut self,
        jaws: &Jaws,
        pose: &Pose,
        gripper: f64,
        touching: bool,
        points: impl IntoIterator<Item = (u32, Vec3)>,
    ) -> GraspEvent {
        if !self.closed && gripper < jaws.close_below {
            self.closed = true;
            if touching {
                self.held = points
                    .into_iter()
                    .filter_map(|(id, p)| {
                        let q = pose.tool_from_grid(p);
                        jaws.between(q, jaws.open_above).then_some(Held { id, anchor: q })
                    })
                    .collect();
            }
            return GraspEvent::Closed(self.held.len());
        }
        if self.closed && gripper > jaws.open_above {
            self.closed = false;
            return GraspEvent::Opened(std::mem::take(&mut self.held).len());
        }
        GraspEvent::None
    }

    /// Forgets held points that no longer exist (a cut removed their surface vertex).
    pub fn retain(&mut self, exists: impl Fn(u32) -> bool) {
        self.held.retain(|h| exists(h.id));
    }

    /// The holding springs at `pose`, damped by `damping` (N·s/m per point) relative to the
    /// anchors' motion since `previous` (the pose `dt` seconds before; `None`: at rest);
    /// `embedding` gives a held vertex's embedding.
    #[must_use]
    pub fn springs(
        &self,
        jaws: &Jaws,
        pose: &Pose,
        previous: Option<(&Pose, f64)>,
        damping: f64,
        embedding: impl Fn(u32) -> Option<EmbeddedPoint>,
    ) -> Vec<EmbeddedSpring> {
        let diagonal = |c: f64| [[c, 0.0, 0.0], [0.0, c, 0.0], [0.0, 0.0, c]];
        let (stiffness, damping) = (diagonal(jaws.stiffness), diagonal(damping));
        self.held
            .iter()
            .filter_map(|h| {
                let point = embedding(h.id)?;
                let target = pose.grid_from_tool(h.anchor);
                let velocity = match previous {
                    Some((before, dt)) if dt > 0.0 => {
                        let was = before.grid_from_tool(h.anchor);
                        std::array::from_fn(|k| (target[k] - was[k]) / dt)
                    }
                    _ => [0.0; 3],
                };
                Some(EmbeddedSpring::new(point, stiffness, target).damped(damping, velocity))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const JAWS: Jaws =
        Jaws { length: 0.01, width: 0.004, close_below: 0.05, open_above: 0.3, stiffness: 100.0 };

    fn points() -> Vec<(u32, Vec3)> {
        (0..50).map(|i| (i, [0.0, 0.0004 * (f64::from(i) - 25.0), 0.005])).collect()
    }

    #[test]
    fn jaws_hold_what_is_between_them_until_they_open() {
        let mut grasp = Grasp::default();
        let pose = Pose::IDENTITY;
        // Open: nothing happens.
        assert_eq!(grasp.update(&JAWS, &pose, 0.6, true, points()), GraspEvent::None);
        // Closing on the tissue: the points within the 0.3 rad opening (±1.49 mm) are held.
        let GraspEvent::Closed(n) = grasp.update(&JAWS, &pose, 0.01, true, points()) else {
            panic!("the jaws should close")
        };
        assert_eq!(n, 7);
        // Between the thresholds nothing changes (hysteresis).
        assert_eq!(grasp.update(&JAWS, &pose, 0.2, true, points()), GraspEvent::None);
        // Moving the tool drags the anchors with it.
        let moved = Pose::at([0.001, 0.0, 0.0]);
        let springs = grasp.springs(&JAWS, &moved, None, 0.0, |id| Some(EmbeddedPoint::node(id)));
        assert_eq!(springs.len(), 7);
        assert!(springs.iter().all(|s| (s.target[0] - 0.001).abs() < 1e-15));
        assert_eq!(grasp.update(&JAWS, &pose, 0.4, true, points()), GraspEvent::Opened(7));
        assert!(grasp.held().is_empty());
        // Closing in the air takes nothing.
        assert_eq!(grasp.update(&JAWS, &pose, 0.0, false, points()), GraspEvent::Closed(0));
    }
}
