//! The haptic loop: between two physics frames (1–10 ms apart), each tool's force is
//! extrapolated at 1 kHz or faster from its newest pose and the contact the last frame
//! linearised (paper 1 §4: the coupling that "extrapolates the missing collision updates"), then
//! made safe to render:
//!
//! 1. **extrapolated**: `F = F₀ + J·(δt, δθ)`, the frame's force and its 6×6 derivative in the
//!    pose ([`ToolSnapshot`]), at the pose's offset from the one the frame used; a contact
//!    pushes and never pulls, so a force turned against the frame's is zero;
//! 2. **clamped** to the device's maximum ([`HapticSettings::max_force_n`]);
//! 3. **rate-limited**: it changes by at most `max_force_rate_n_per_s × dt` per update, so a new
//!    frame's jump (a cut giving way) reaches the hand as a ramp, not a step;
//! 4. **kept passive** by a passivity observer and controller (Hannaford and Ryu 2002): the
//!    energy the rendered force has taken from the hand, `Σ −F·δx`, may not fall below zero
//!    (a sampled stiff spring can return more than it took); when it would, a damping force
//!    along the motion dissipates the excess;
//! 5. **faded** when poses stop or turn invalid: after [`HapticSettings::stale_after_ms`] without
//!    a valid pose the force ramps down to zero over [`HapticSettings::fade_ms`] (50 ms in all by
//!    default) and carries the `STALE` flag.
//!
//! [`Renderer`] is that computation for one tool, a pure function of its inputs and a clock.
//! [`cell`] holds the lock-free hand-offs the loop reads through (single writer, no allocation,
//! no lock); [`run`] the thread that drives it and measures its period's jitter.

pub mod cell;
pub mod force_log;
pub mod render;
pub mod run;
pub mod snapshot;

pub use force_log::{ForceLog, SentForce};
pub use render::{HapticSettings, Renderer};
pub use run::{HapticLoop, Histogram, LoopIo, LoopShared, ProxyPose, Rendered, ToolCounts, Waker};
pub use snapshot::ToolSnapshot;
