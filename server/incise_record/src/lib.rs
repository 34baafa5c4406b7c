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
//! | `/incise/force` | `incise.v1.SentForce` | every force the haptic loop sent, with the frame of the snapshot it extrapolated |
//! | `/incise/edit` | `incise.v1.TopologyEdit` | every frame that cut: the voxels removed, links severed or tetrahedra removed |
//! | `/incise/keyframe` | `incise.v1.Keyframe` | once a second of simulated time: the whole state a replay restores to start there (with the edits before it) |
//! | `/incise/surface` | `incise.v1.SurfaceMesh` | the organ's surface: whole on the first frame and once a second (keyframes); every vertex's position at the geometry rate; each topology change on the frame that made it |
//! | `/foxglove/scene` | `foxglove.SceneUpdate` | the organ (a triangle list per tissue label) and the tools (each at its proxy, with a ghost at its device and the coupling between) with their force arrows, every [`Session::scene_interval_s`] of simulated time |
//! | `/foxglove/tools/<name>/pose` | `foxglove.PoseInFrame` | every frame's device pose of each tool |
//! | `/foxglove/tools/<name>/proxy` | `foxglove.PoseInFrame` | every frame's proxy pose of each tool that has one |
//!
//! The `foxglove.*` channels use Foxglove's published schemas, so Foxglove draws the session
//! without a plugin.
//!
//! The scene's TOML is attached (`scene.toml`), and a metadata record `incise` names the incise
//! version, the git revision and the scene's hash. Message log times are simulated time (ns), so
//! the same inputs give the same file.
//!
//! [`Recorder`] is the thread that writes it: the physics thread hands each frame over a
//! bounded queue and waits when the queue is full (a recording never drops a frame; the waits
//! are counted). Chunks are closed (LZ4-compressed, indexed) every [`CHUNK_FRAMES`] frames and
//! at least every [`CHUNK_INTERVAL`], so a crash loses at most the last open chunk.
//!
//! The same thread writes the session's `.rrd` file ([`RerunLog`]) and feeds a live Rerun
//! viewer ([`LiveStream`]), which drops surface frames rather than make anyone wait.

pub mod foxglove;
pub mod mcap_file;
pub mod read;
pub mod recorder;
pub mod rerun_log;
pub mod visual;

pub use mcap_file::{
    CUT_TOPIC, EDIT_TOPIC, FORCE_TOPIC, FRAME_TOPIC, KEYFRAME_TOPIC, McapRecording,
    POSE_TOPIC_PREFIX, RecordError, SCENE_TOPIC, SURFACE_TOPIC, Session,
};
pub use read::{Contents, ReadError, read_recording, read_recording_at};
pub use recorder::{
    CHUNK_FRAMES, CHUNK_INTERVAL, Record, RecordHandle, Recorder, RecorderStats, Sinks,
};
pub use rerun_log::{IndexedRrd, LiveStream, RerunLog, index_rrd};
pub use visual::{Mesh, SurfaceFrame, SurfaceState, ToolLook, ToolShape};
