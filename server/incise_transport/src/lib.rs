//! The transports between `incise-server` and its clients, behind one interface: poses in,
//! forces out, frames out, the scene's description on request.
//!
//! - [`zenoh_link`]: zenoh publish–subscribe over TCP (network; loopback by default), with a
//!   queryable for `SceneInfo`. Multicast scouting is off unless asked for; endpoints are
//!   explicit (`tcp/127.0.0.1:7447`).
//! - [`shm`]: iceoryx2 publish–subscribe in shared memory (same machine, zero copy): the
//!   `#[repr(C)]` records of `incise_protocol::raw`, with iceoryx2 events to wake the receiver.
//!
//! A server runs both at once ([`ServerSide`]), and each tool's client picks either
//! ([`Client`]). Whatever arrives is checked before anyone sees it: oversized or malformed bytes,
//! a pose without position or orientation, a key naming one tool and a message another, a tool
//! the scene lacks; each kind is counted in [`Faults`] and dropped, and the receiving thread goes
//! on. zenoh hands the poses it accepts to a [`PoseHandler`] on its own thread; iceoryx2's
//! [`shm::ShmPorts`] hand theirs to whichever thread holds them (the server's haptic thread).
//! Either way they go into the haptic loop's lock-free cells.

pub mod client;
pub mod shm;
pub mod zenoh_link;

pub use client::Client;

use incise_protocol::raw::{MissingField, RawToolPose};
use incise_protocol::v1;
use prost::Message;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Which transport something came over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TransportKind {
    /// zenoh (network).
    Zenoh,
    /// iceoryx2 (shared memory).
    Iceoryx2,
}

impl TransportKind {
    /// The index of the haptic loop's pose cell this transport writes.
    #[must_use]
    pub fn source(self) -> usize {
        match self {
            Self::Zenoh => 0,
            Self::Iceoryx2 => 1,
        }
    }

    /// `zenoh` or `iceoryx2`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Zenoh => "zenoh",
            Self::Iceoryx2 => "iceoryx2",
        }
    }
}

impl std::str::FromStr for TransportKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "zenoh" => Ok(Self::Zenoh),
            "iceoryx2" => Ok(Self::Iceoryx2),
            _ => Err(format!("unknown transport {s:?}: use zenoh or iceoryx2")),
        }
    }
}

/// Called with every pose a transport accepts, on the transport's receiving thread. It must
/// not block: the server's hands the pose to the haptic loop's cell. Returns false for a tool
/// the scene lacks (counted as [`Faults::unknown_tool`]).
pub type PoseHandler = Arc<dyn Fn(TransportKind, &RawToolPose) -> bool + Send + Sync>;

/// What the transports refused, by kind.
#[derive(Debug, Default)]
pub struct Faults {
    /// Messages longer than [`incise_protocol::MAX_TOOL_MESSAGE_BYTES`].
    pub oversized: AtomicU64,
    /// Bytes that are not a protobuf `ToolPose`.
    pub malformed: AtomicU64,
    /// Poses without a position or an orientation.
    pub incomplete: AtomicU64,
    /// Poses whose key names one tool and whose message another.
    pub mismatched: AtomicU64,
    /// Poses for a tool the scene lacks.
    pub unknown_tool: AtomicU64,
    /// Sends that failed (a transport error; the message is dropped).
    pub send_failed: AtomicU64,
}

impl Faults {
    /// Counts a refused pose.
    pub fn count(&self, bad: &BadPose) {
        let counter = match bad {
            BadPose::Oversized(_) => &self.oversized,
            BadPose::Malformed(_) => &self.malformed,
            BadPose::Incomplete(_) => &self.incomplete,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The counts, in field order.
    #[must_use]
    pub fn snapshot(&self) -> [(&'static str, u64); 6] {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        [
            ("oversized", get(&self.oversized)),
            ("malformed", get(&self.malformed)),
            ("incomplete", get(&self.incomplete)),
            ("mismatched", get(&self.mismatched)),
            ("unknown tool", get(&self.unknown_tool)),
            ("send failed", get(&self.send_failed)),
        ]
    }
}

/// Why bytes were refused as a pose.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BadPose {
    /// Too long to be a `ToolPose`.
    #[error("{0} bytes is too long for a ToolPose")]
    Oversized(usize),
    /// Not a protobuf `ToolPose`.
    #[error("not a ToolPose: {0}")]
    Malformed(String),
    /// Missing a field a pose needs.
    #[error("{0}")]
    Incomplete(MissingField),
}

/// Decodes a `ToolPose` received as bytes, refusing oversized input before decoding it.
pub fn decode_pose(bytes: &[u8]) -> Result<RawToolPose, BadPose> {
    if bytes.len() > incise_protocol::MAX_TOOL_MESSAGE_BYTES {
        return Err(BadPose::Oversized(bytes.len()));
    }
    let pose = v1::ToolPose::decode(bytes).map_err(|e| BadPose::Malformed(e.to_string()))?;
    RawToolPose::try_from(&pose).map_err(BadPose::Incomplete)
}

/// The server's side of every transport it serves.
pub struct ServerSide {
    /// zenoh, when served.
    pub zenoh: Option<zenoh_link::ZenohServer>,
    /// iceoryx2, when served.
    pub iceoryx2: Option<shm::ShmServer>,
}

impl ServerSide {
    /// Wakes the thread that takes iceoryx2's poses (so that a pose from zenoh, or a request to
    /// stop, is seen at once); nothing without iceoryx2.
    pub fn ring(&self) {
        if let Some(s) = &self.iceoryx2 {
            s.ring();
        }
    }

    /// Sends a tool's force over zenoh, with its proxy's pose (iceoryx2's forces go from the
    /// thread holding its [`shm::ShmPorts`]).
    pub fn send_zenoh_force(&self, force: &v1::ToolForce) {
        if let Some(z) = &self.zenoh {
            z.send_tool_force(force);
        }
    }

    /// Publishes a frame's statistics (zenoh only: shared memory carries the tool channel).
    pub fn send_frame(&self, stats: &v1::FrameStats) {
        if let Some(z) = &self.zenoh {
            z.send_frame(stats);
        }
    }

    /// Publishes a cut.
    pub fn send_cut(&self, cut: &v1::CutEvent) {
        if let Some(z) = &self.zenoh {
            z.send_cut(cut);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]
        /// Fuzz-style: any bytes give a pose or one of the three refusals, never a panic.
        #[test]
        fn any_bytes_decode_or_are_refused(bytes in proptest::collection::vec(any::<u8>(), 0..1200)) {
            match decode_pose(&bytes) {
                Ok(_) => prop_assert!(bytes.len() <= incise_protocol::MAX_TOOL_MESSAGE_BYTES),
                Err(BadPose::Oversized(n)) => prop_assert!(n > incise_protocol::MAX_TOOL_MESSAGE_BYTES),
                Err(_) => {}
            }
        }
    }

    #[test]
    fn a_pose_round_trips_and_garbage_is_refused_by_kind() {
        let raw = RawToolPose::at(1, [0.01, 0.02, 0.03]);
        let bytes = v1::ToolPose::from(&raw).encode_to_vec();
        assert_eq!(decode_pose(&bytes).unwrap(), raw);
        assert!(matches!(decode_pose(&[0xff; 600]), Err(BadPose::Oversized(600))));
        assert!(matches!(decode_pose(&[0xff, 0xff, 0xff]), Err(BadPose::Malformed(_))));
        let empty = v1::ToolPose::default().encode_to_vec();
        assert!(matches!(decode_pose(&empty), Err(BadPose::Incomplete(_))));
    }
}
