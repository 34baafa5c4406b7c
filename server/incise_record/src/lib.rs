//! Recording a session to MCAP.
//!
//! One MCAP file per session ([`McapRecording`]): protobuf channels whose schemas are embedded
//! (the protocol's `FileDescriptorSet`), so any MCAP reader (the `mcap` CLI, Foxglove, the
//! Python and C++ libraries) decodes every message without our code:
//!
//! | topic | message | when |
//! |---|---|---|
//! | `/incise/frame` | `incise.v1.FrameRecord` | every physics frame: the tool poses it used, each tool's force and contact, a hash of the state it left, its statistics |
//! | `/incise/cut` | `incise.v1.CutEvent` | every cut |
//!
//! The scene's TOML is attached (`scene.toml`), and a metadata record `incise` names the incise
//! version, the git revision and the scene's hash. Message log times are simulated time (ns), so
//! the same inputs give the same file.
//!
//! [`Recorder`] is the thread that writes it: the physics thread hands each frame over a
//! bounded queue and waits when the queue is full (a recording never drops a frame; the waits
//! are counted). Chunks are closed (LZ4-compressed, indexed) every [`CHUNK_FRAMES`] frames and
//! at least every [`CHUNK_INTERVAL`], so a crash loses at most the last open chunk.

pub mod mcap_file;
pub mod read;
pub mod recorder;

pub use mcap_file::{CUT_TOPIC, FRAME_TOPIC, McapRecording, RecordError, Session};
pub use read::{Contents, ReadError, read_recording};
pub use recorder::{CHUNK_FRAMES, CHUNK_INTERVAL, Record, RecordHandle, Recorder, RecorderStats};
