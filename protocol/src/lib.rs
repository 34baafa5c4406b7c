//! The incise wire contract: message types, key expressions and service names shared by the
//! server and its clients.
//!
//! Empty for now: the transport issue fills it with the protobuf types (`ToolPose`, `ToolForce`,
//! `FrameStats`, …) and their `#[repr(C)]` twins for iceoryx2. The crate exists so the workspace
//! layout of `ARCHITECTURE.md` is in place from the start.

/// Version of the wire contract, the `v1` in every key expression (`incise/v1/<scene>/…`).
pub const PROTOCOL_VERSION: u32 = 1;
