//! The tool the tissue feels: a proxy that follows the device's pose but never enters the
//! tissue (the god-object of Zilles & Salisbury 1995, a finite shape as in Ruspini et al. 1997,
//! 6-DOF as in Ortega et al. 2007), coupled to the device by a spring-damper (virtual coupling,
//! Colgate et al. 1995).
//!
//! Each physics step, for each tool:
//! 1. [`motion`]: the proxy moves from its last pose toward the device's, stops where its outer
//!    shape meets the deformed tissue's surface triangles (or would enter its volume), and
//!    slides along them, with friction if the scene gives one;
//! 2. [`touches`]: the triangles it touches, each at the point nearest to the shape ([`gap`]);
//! 3. [`push`](mod@push): the coupling's pull shared over those points as springs, and a penalty on any
//!    tissue overlapping the proxy; they are solved implicitly with the tissue, so the tissue
//!    yields to the device's push, and the force the device feels is theirs.
//!
//! Only cutting lets a proxy into tissue: past its tool's threshold, the inner shape removes the
//! material ahead of it and the proxy is moved into the space opened (`incise_sim` does that, as
//! it owns the grid).

pub mod gap;
pub mod motion;
pub mod push;

pub use gap::{Gap, Reach, gap_at_least, surely_at_least, triangle_gap};
pub use motion::{Facet, Motion, Obstacles, PENETRATION_TOLERANCE, advance, place, slide, travel};
pub use push::{ContactSettings, Coupling, Push, Touch, push, touches};
