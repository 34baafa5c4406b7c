//! The protocol's messages (`incise_protocol::v1`) made from the simulation's values
//! (`incise_sim`) and back. The server publishes and records with these functions and a replay
//! reads with them, so that a replay steps with the very inputs the server did and compares
//! what the server recorded with what it computes the same way.
//!
//! - [`frame`]: a stepped frame's record, statistics and cut events;
//! - [`keyframe`]: a frame's topology edit and the keyframes, both ways;
//! - [`tools`]: how a recording draws the scene's tools, and a checked pose as a step's input.

pub mod frame;
pub mod keyframe;
pub mod tools;
