//! What the physics thread hands the haptic loop for one tool after each frame: the pose the
//! frame used and the contact linearised there.

use crate::cell::SeqCell;

/// One tool's contact at one physics frame, linearised in the tool's pose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolSnapshot {
    /// The physics frame it comes from.
    pub frame: u64,
    /// The tool's position (m) and orientation (unit quaternion `w, x, y, z`) at that frame.
    pub position: [f64; 3],
    /// See `position`.
    pub orientation: [f64; 4],
    /// The force (N) and torque (N·m, about the tool's origin) the tissue put on the tool.
    pub force: [f64; 3],
    /// See `force`.
    pub torque: [f64; 3],
    /// `∂(force, torque)/∂(translation, rotation vector)`, rows force then torque.
    pub jacobian: [[f64; 6]; 6],
    /// `ToolForce` flag bits the frame sets (in contact, cutting).
    pub flags: u32,
    /// The tool's proxy at that frame (position, orientation), if it has one: where the tissue
    /// feels the tool, sent beside each force.
    pub proxy: Option<([f64; 3], [f64; 4])>,
}

/// Words in a snapshot record: frame, position, orientation, force, torque, Jacobian, flags
/// (with whether there is a proxy), the proxy's position and orientation.
pub const SNAPSHOT_WORDS: usize = 1 + 3 + 4 + 3 + 3 + 36 + 1 + 7;

/// The word holding the flags.
const FLAGS: usize = 50;

/// A tool's snapshot cell.
pub type SnapshotCell = SeqCell<SNAPSHOT_WORDS>;

impl ToolSnapshot {
    /// The record's words.
    #[must_use]
    pub fn to_words(&self) -> [u64; SNAPSHOT_WORDS] {
        let mut w = [0u64; SNAPSHOT_WORDS];
        w[0] = self.frame;
        let floats = self
            .position
            .iter()
            .chain(&self.orientation)
            .chain(&self.force)
            .chain(&self.torque)
            .chain(self.jacobian.iter().flatten());
        for (slot, v) in w[1..FLAGS].iter_mut().zip(floats) {
            *slot = v.to_bits();
        }
        w[FLAGS] = u64::from(self.flags) | u64::from(self.proxy.is_some()) << 32;
        if let Some((p, q)) = &self.proxy {
            for (slot, v) in w[FLAGS + 1..].iter_mut().zip(p.iter().chain(q)) {
                *slot = v.to_bits();
            }
        }
        w
    }

    /// The snapshot a record holds.
    #[must_use]
    pub fn from_words(w: &[u64; SNAPSHOT_WORDS]) -> Self {
        let f = |k: usize| f64::from_bits(w[k]);
        Self {
            frame: w[0],
            position: std::array::from_fn(|k| f(1 + k)),
            orientation: std::array::from_fn(|k| f(4 + k)),
            force: std::array::from_fn(|k| f(8 + k)),
            torque: std::array::from_fn(|k| f(11 + k)),
            jacobian: std::array::from_fn(|r| std::array::from_fn(|c| f(14 + 6 * r + c))),
            flags: w[FLAGS] as u32,
            proxy: (w[FLAGS] >> 32 != 0).then(|| {
                (
                    std::array::from_fn(|k| f(FLAGS + 1 + k)),
                    std::array::from_fn(|k| f(FLAGS + 4 + k)),
                )
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_snapshot_survives_its_record() {
        let s = ToolSnapshot {
            frame: 77,
            position: [0.1, -0.2, 0.3],
            orientation: [0.5, 0.5, -0.5, 0.5],
            force: [1.0, 2.0, -3.0],
            torque: [0.01, 0.02, 0.03],
            jacobian: std::array::from_fn(|r| std::array::from_fn(|c| (r * 6 + c) as f64 - 7.5)),
            flags: 3,
            proxy: Some(([0.1, -0.2, 0.29], [0.5, -0.5, 0.5, 0.5])),
        };
        assert_eq!(ToolSnapshot::from_words(&s.to_words()), s);
        let none = ToolSnapshot { proxy: None, ..s };
        assert_eq!(ToolSnapshot::from_words(&none.to_words()), none);
    }
}
