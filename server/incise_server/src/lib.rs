//! `incise-server`: owns a scene, steps its physics in real time, runs the 1 kHz haptic loop,
//! and serves tool poses and forces over zenoh and iceoryx2 at once.
//!
//! Threads (see `ARCHITECTURE.md`):
//! - `incise-physics` steps the simulation every `dt` of wall time with each tool's newest pose,
//!   then hands every tool's linearised contact to the haptic loop ([`physics`]) and each
//!   frame's statistics and cuts to the network ([`network`]);
//! - `incise-haptics` renders each tool's force from its newest pose and that snapshot, on every
//!   pose and at least at 1 kHz (`incise_haptics`); it also waits on iceoryx2's poses event,
//!   takes those poses and publishes their forces itself;
//! - `incise-forces` sends the forces over zenoh (woken by the haptic thread);
//! - `incise-net`, a one-worker tokio runtime, publishes the frames and cuts ([`network`]);
//! - zenoh's own runtime receives its poses and answers scene queries;
//! - the main thread prints a status line and waits for SIGINT/SIGTERM, the demo's end or, with
//!   `--stop-with-parent`, the end of the process that started it ([`lifetime`]).

pub mod demo;
pub mod lifetime;
pub mod network;
pub mod physics;
pub mod scene;
pub mod server;
