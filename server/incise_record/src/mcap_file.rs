//! One session's MCAP file: its schemas, channels, metadata and attachment, then the messages.

use crate::foxglove;
use crate::visual::{SurfaceFrame, SurfaceState, ToolLook};
use incise_protocol::v1;
use prost::Message;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// The topic of every frame's `incise.v1.FrameRecord`.
pub const FRAME_TOPIC: &str = "/incise/frame";
/// The topic of every `incise.v1.CutEvent`.
pub const CUT_TOPIC: &str = "/incise/cut";
/// The topic of every force the haptic loop sent, `incise.v1.SentForce`.
pub const FORCE_TOPIC: &str = "/incise/force";
/// The topic of the organ's surface, `incise.v1.SurfaceMesh`: whole on the first frame and once a
/// second; in between, every vertex's position at the geometry rate, and each topology change
/// (new triangles and vertices, freed ids) on the frame that made it.
pub const SURFACE_TOPIC: &str = "/incise/surface";
/// The topic of every frame's topology change, `incise.v1.TopologyEdit` (frames that cut).
pub const EDIT_TOPIC: &str = "/incise/edit";
/// The topic of the keyframes, `incise.v1.Keyframe`: the whole state once a second of simulated
/// time, where a replay starts in the middle of a session.
pub const KEYFRAME_TOPIC: &str = "/incise/keyframe";
/// The topic of the scene in Foxglove's schema (`foxglove.SceneUpdate`): the organ and the
/// tools with their force arrows.
pub const SCENE_TOPIC: &str = "/foxglove/scene";
/// The topic prefix of each tool's poses in Foxglove's schema (`foxglove.PoseInFrame`):
/// `/foxglove/tools/<name>/pose` (the device's) and `/foxglove/tools/<name>/proxy` (its proxy's).
pub const POSE_TOPIC_PREFIX: &str = "/foxglove/tools/";

/// What went wrong writing a recording, and to which file.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {what}")]
pub struct RecordError {
    /// The recording's file.
    pub path: PathBuf,
    /// What failed.
    pub what: String,
}

/// What a recording says about its session.
#[derive(Clone, Debug)]
pub struct Session {
    /// The scene's name.
    pub scene: String,
    /// The scene file's TOML, stored in the recording so that it replays on its own.
    pub scene_toml: String,
    /// The incise version that recorded it.
    pub version: String,
    /// The git revision it was built from (empty when unknown).
    pub git_revision: String,
    /// How each of the scene's tools is drawn, in scene order.
    pub tools: Vec<ToolLook>,
    /// The files the scene reads (its volume, meshes), as the scene names them, stored so
    /// that the recording replays on its own.
    pub files: Vec<(String, Vec<u8>)>,
    /// Simulated time between two Foxglove scene updates (s); each repeats the whole surface,
    /// so they are sparser than the surface frames.
    pub scene_interval_s: f64,
}

impl Session {
    /// FNV-1a (64 bit) of the scene's TOML: which scene a recording was made on.
    #[must_use]
    pub fn scene_hash(&self) -> u64 {
        self.scene_toml
            .bytes()
            .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
    }
}

/// An MCAP file being written.
pub struct McapRecording {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    frame_channel: u16,
    cut_channel: u16,
    surface_channel: u16,
    force_channel: u16,
    edit_channel: u16,
    keyframe_channel: u16,
    scene_channel: u16,
    /// Each tool's device pose channel and proxy pose channel.
    pose_channels: Vec<(u16, u16)>,
    tools: Vec<ToolLook>,
    scene_interval_s: f64,
    /// When the last scene update was written (simulated s).
    last_scene_s: Option<f64>,
    /// The surface as the surface frames so far describe it.
    surface: SurfaceState,
    sequence: u32,
    frames: u64,
}

impl McapRecording {
    /// Creates `path` and writes the header, the schemas and channels, the session's metadata
    /// and the scene as an attachment.
    pub fn create(path: &Path, session: &Session) -> Result<Self, RecordError> {
        let err = |what: String| RecordError { path: path.to_owned(), what };
        let file = File::create(path).map_err(|e| err(format!("cannot create: {e}")))?;
        let mut writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .profile("")
            .library(format!("incise {}", session.version))
            // Chunks are closed by the recorder's schedule, not by size.
            .chunk_size(None)
            .create(BufWriter::new(file))
            .map_err(|e| err(format!("cannot start the MCAP file: {e}")))?;
        let mcap = |e: mcap::McapError| err(format!("cannot write: {e}"));
        let mut channel = |message: &str, topic: &str| -> Result<u16, RecordError> {
            // The same schema added twice is stored once.
            let schema = writer
                .add_schema(message, "protobuf", incise_protocol::DESCRIPTOR_SET)
                .map_err(mcap)?;
            writer.add_channel(schema, topic, "protobuf", &BTreeMap::new()).map_err(mcap)
        };
        let frame_channel = channel("incise.v1.FrameRecord", FRAME_TOPIC)?;
        let cut_channel = channel("incise.v1.CutEvent", CUT_TOPIC)?;
        let surface_channel = channel("incise.v1.SurfaceMesh", SURFACE_TOPIC)?;
        let force_channel = channel("incise.v1.SentForce", FORCE_TOPIC)?;
        let edit_channel = channel("incise.v1.TopologyEdit", EDIT_TOPIC)?;
        let keyframe_channel = channel("incise.v1.Keyframe", KEYFRAME_TOPIC)?;
        let scene_channel = channel("foxglove.SceneUpdate", SCENE_TOPIC)?;
        let pose_channels = session
            .tools
            .iter()
            .map(|t| {
                let topic = |what: &str| format!("{POSE_TOPIC_PREFIX}{}/{what}", t.name);
                Ok((
                    channel("foxglove.PoseInFrame", &topic("pose"))?,
                    channel("foxglove.PoseInFrame", &topic("proxy"))?,
                ))
            })
            .collect::<Result<Vec<_>, RecordError>>()?;
        let metadata = BTreeMap::from([
            ("incise_version".to_owned(), session.version.clone()),
            ("git_revision".to_owned(), session.git_revision.clone()),
            ("scene".to_owned(), session.scene.clone()),
            ("scene_hash".to_owned(), format!("{:016x}", session.scene_hash())),
            ("protocol".to_owned(), incise_protocol::PACKAGE.to_owned()),
        ]);
        writer
            .write_metadata(&mcap::records::Metadata { name: "incise".into(), metadata })
            .map_err(mcap)?;
        writer
            .attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: "scene.toml".into(),
                media_type: "application/toml".into(),
                data: session.scene_toml.as_bytes().into(),
            })
            .map_err(mcap)?;
        for (name, data) in &session.files {
            writer
                .attach(&mcap::Attachment {
                    log_time: 0,
                    create_time: 0,
                    name: name.clone(),
                    media_type: "application/octet-stream".into(),
                    data: data.as_slice().into(),
                })
                .map_err(mcap)?;
        }
        Ok(Self {
            path: path.to_owned(),
            writer,
            frame_channel,
            cut_channel,
            surface_channel,
            force_channel,
            edit_channel,
            keyframe_channel,
            scene_channel,
            pose_channels,
            tools: session.tools.clone(),
            scene_interval_s: session.scene_interval_s,
            last_scene_s: None,
            surface: SurfaceState::default(),
            sequence: 0,
            frames: 0,
        })
    }

    /// The file's path.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames written so far.
    #[must_use]
    pub fn frames(&self) -> u64 {
        self.frames
    }

    fn write(&mut self, channel: u16, sim_time_s: f64, bytes: &[u8]) -> Result<(), RecordError> {
        // Simulated time (ns): the same inputs give the same file.
        let time = (sim_time_s.max(0.0) * 1e9).round() as u64;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: time,
            publish_time: time,
        };
        self.writer.write_to_known_channel(&header, bytes).map_err(|e| self.error(&e))
    }

    fn error(&self, e: &dyn std::fmt::Display) -> RecordError {
        RecordError { path: self.path.clone(), what: format!("cannot write: {e}") }
    }

    /// Writes a frame's record, and each of its device poses and proxy poses as a
    /// `foxglove.PoseInFrame`.
    pub fn frame(&mut self, record: &v1::FrameRecord) -> Result<(), RecordError> {
        let t = record.sim_time_s;
        self.write(self.frame_channel, t, &record.encode_to_vec())?;
        for pose in &record.poses {
            if let Some(&(channel, _)) = self.pose_channels.get(pose.tool_id as usize) {
                let message =
                    foxglove::pose_in_frame(pose.position.as_ref(), pose.orientation.as_ref(), t);
                self.write(channel, t, &message.encode_to_vec())?;
            }
        }
        for state in &record.tools {
            if let (Some(&(_, channel)), Some(proxy)) =
                (self.pose_channels.get(state.tool_id as usize), &state.proxy)
            {
                let message =
                    foxglove::pose_in_frame(proxy.position.as_ref(), proxy.orientation.as_ref(), t);
                self.write(channel, t, &message.encode_to_vec())?;
            }
        }
        self.frames += 1;
        Ok(())
    }

    /// Writes a surface frame, and a Foxglove scene update when one is due (`record`: the
    /// surface's frame, for the tools).
    pub fn surface(
        &mut self,
        surface: &SurfaceFrame,
        record: Option<&v1::FrameRecord>,
    ) -> Result<(), RecordError> {
        let t = surface.sim_time_s;
        self.write(self.surface_channel, t, &surface.to_message().encode_to_vec())?;
        self.surface.apply(surface);
        // Each update repeats the whole surface, so a topology change waits for the next one.
        let due = self.last_scene_s.is_none_or(|last| t - last >= self.scene_interval_s - 1e-9);
        if due {
            let update = foxglove::scene_update(t, &self.surface.mesh(), &self.tools, record);
            self.write(self.scene_channel, t, &update.encode_to_vec())?;
            self.last_scene_s = Some(t);
        }
        Ok(())
    }

    /// Writes a force the haptic loop sent, logged at simulated time `sim_time_s` (the newest
    /// frame's when the recorder took it).
    pub fn sent_force(
        &mut self,
        sent: &incise_haptics::SentForce,
        sim_time_s: f64,
    ) -> Result<(), RecordError> {
        let message = v1::SentForce {
            force: Some(v1::ToolForce::from(&sent.force)),
            snapshot_frame: sent.snapshot_frame,
        };
        self.write(self.force_channel, sim_time_s, &message.encode_to_vec())
    }

    /// Writes a cut, made at simulated time `sim_time_s`.
    pub fn cut(&mut self, cut: &v1::CutEvent, sim_time_s: f64) -> Result<(), RecordError> {
        self.write(self.cut_channel, sim_time_s, &cut.encode_to_vec())
    }

    /// Writes the topology change a frame made, at simulated time `sim_time_s`.
    pub fn edit(&mut self, edit: &v1::TopologyEdit, sim_time_s: f64) -> Result<(), RecordError> {
        self.write(self.edit_channel, sim_time_s, &edit.encode_to_vec())
    }

    /// Writes a keyframe, at simulated time `sim_time_s`.
    pub fn keyframe(
        &mut self,
        keyframe: &v1::Keyframe,
        sim_time_s: f64,
    ) -> Result<(), RecordError> {
        self.write(self.keyframe_channel, sim_time_s, &keyframe.encode_to_vec())
    }

    /// Closes the open chunk and flushes it to the file: what is written survives a crash.
    pub fn close_chunk(&mut self) -> Result<(), RecordError> {
        self.writer.flush().map_err(|e| self.error(&e))
    }

    /// Writes the summary (indexes, statistics) and closes the file; the frames written.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.writer.finish().map_err(|e| self.error(&e))?;
        Ok(self.frames)
    }
}
