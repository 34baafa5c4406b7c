//! A Rust client of `incise-server`: what a haptic device driver written in Rust links.
//!
//! ```no_run
//! use incise_client::{Client, Keys, TransportKind};
//! use incise_client::raw::RawToolPose;
//! use std::time::Duration;
//!
//! let keys = Keys::new("demo_organ")?;
//! // Tool 0 over shared memory (same machine); `TransportKind::Zenoh` with an endpoint such
//! // as "tcp/127.0.0.1:7447" reaches a server over the network.
//! let client = Client::connect(TransportKind::Iceoryx2, &keys, 0, "")?;
//! let pose = RawToolPose { sequence: 1, timestamp_ns: 1, ..RawToolPose::at(0, [0.04, 0.03, 0.05]) };
//! client.send_pose(&pose)?;
//! if let Some(force) = client.recv_force(Duration::from_millis(1)) {
//!     println!("{:?} N answering pose {}", force.force, force.pose_sequence);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! In async code, [`AsyncClient`] is the same connection with forces awaited (on any executor:
//! it needs no runtime of its own).
//!
//! [`drive`] sends a trajectory at a fixed rate and times every pose's round trip to the force
//! that answers it; [`script`] holds the trajectories `incise-tool` offers (press, press and
//! cut, circle, a CSV file of poses).

pub mod asynchronous;
pub mod drive;
pub mod script;

pub use asynchronous::AsyncClient;
pub use incise_protocol::keys::Keys;
pub use incise_protocol::{raw, v1};
pub use incise_transport::{Client, TransportKind};
