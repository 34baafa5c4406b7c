//! `incise-server`: owns a scene, steps its physics in real time, runs the 1 kHz haptic loop,
//! and serves tool poses and forces over zenoh and iceoryx2 at once.
//!
//! Threads (see `ARCHITECTURE.md`):
//! - `incise-physics` steps the simulation every `dt` of wall time with each tool's newest pose,
//!   then hands every tool's linearised contact to the haptic loop ([`physics`]);
//! - `incise-haptics` renders each tool's force from its newest pose and that snapshot, on every
//!   pose and at least at 1 kHz (`incise_haptics`);
//! - `incise-forces` sends the forces the haptic loop produced on the transports;
//! - the transports' own threads receive poses (zenoh's runtime, `incise-shm-rx`);
//! - the main thread prints a status line and waits for SIGINT/SIGTERM or the demo's end.

pub mod demo;
pub mod physics;
pub mod scene;
pub mod server;
