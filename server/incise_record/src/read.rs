//! Reading a recording back: its frames, cuts, scene and metadata. A file cut short (the server
//! was killed) gives every message before its last complete chunk and says it was truncated;
//! a file that is not MCAP, not incise's, or of another protocol version is refused with a
//! message that says which.

use crate::mcap_file::{
    CUT_TOPIC, EDIT_TOPIC, FORCE_TOPIC, FRAME_TOPIC, KEYFRAME_TOPIC, SURFACE_TOPIC,
};
use incise_protocol::v1;
use prost::Message;
use std::collections::BTreeMap;

/// The largest chunk, uncompressed, a recording may hold: far above what the recorder writes
/// (a quarter second of frames), far below what would exhaust memory.
const MAX_CHUNK: u64 = 256 << 20;

/// What a recording holds.
#[derive(Clone, Debug, Default)]
pub struct Contents {
    /// Every frame record, in order.
    pub frames: Vec<v1::FrameRecord>,
    /// Every cut, with its log time (simulated ns).
    pub cuts: Vec<(v1::CutEvent, u64)>,
    /// Every force the haptic loop sent.
    pub forces: Vec<v1::SentForce>,
    /// Every surface frame, with its log time (simulated ns).
    pub surfaces: Vec<(v1::SurfaceMesh, u64)>,
    /// Every frame's topology change, in order.
    pub edits: Vec<v1::TopologyEdit>,
    /// The frames that have a keyframe, in order.
    pub keyframe_frames: Vec<u64>,
    /// The last keyframe at or before the frame [`read_recording_at`] was asked for (a keyframe
    /// is large, so only that one is kept; `None` from [`read_recording`]).
    pub keyframe: Option<v1::Keyframe>,
    /// The scene's TOML, when attached.
    pub scene_toml: Option<String>,
    /// The files the scene reads, stored beside it (name as the scene writes it, bytes).
    pub files: BTreeMap<String, Vec<u8>>,
    /// The `incise` metadata record.
    pub metadata: BTreeMap<String, String>,
    /// Why reading stopped early, when the file ends mid-record (a crash).
    pub truncated: Option<String>,
}

/// Why a file cannot be read as a recording.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// Not an MCAP file at all.
    #[error("not an MCAP file: {0}")]
    NotMcap(String),
    /// An MCAP file without incise's metadata.
    #[error("an MCAP file, but not an incise recording (it has no `incise` metadata record)")]
    Foreign,
    /// Recorded with another protocol package.
    #[error("recorded with protocol {found:?}; this incise reads {expected:?}")]
    Version {
        /// The recording's.
        found: String,
        /// Ours.
        expected: &'static str,
    },
    /// A chunk that is not what its header says (a damaged file).
    #[error("chunk {index}: {what}; the file is damaged")]
    Damaged {
        /// Its position among the file's chunks.
        index: usize,
        /// What is wrong with it.
        what: String,
    },
    /// A message that does not decode as its channel's schema.
    #[error("message {index} on {topic}: {what}")]
    BadMessage {
        /// Its position among the file's messages.
        index: usize,
        /// Its topic.
        topic: String,
        /// The decoder's complaint.
        what: String,
    },
}

/// Reads `bytes` as a recording (see the module's description of what is refused), keeping no
/// keyframe.
pub fn read_recording(bytes: &[u8]) -> Result<Contents, ReadError> {
    read_recording_at(bytes, None)
}

/// [`read_recording`], keeping the last keyframe at or before frame `seek` (when given) in
/// [`Contents::keyframe`].
pub fn read_recording_at(bytes: &[u8], seek: Option<u64>) -> Result<Contents, ReadError> {
    let options = mcap::read::Options::IgnoreEndMagic.into();
    let records = mcap::read::LinearReader::new_with_options(bytes, options)
        .map_err(|e| ReadError::NotMcap(e.to_string()))?;
    let mut reading = Reading { seek, ..Reading::default() };
    let mut seen_any = false;
    for record in records {
        let record = match record {
            Ok(r) => r,
            Err(e) if !seen_any => return Err(ReadError::NotMcap(e.to_string())),
            Err(e) => {
                reading.contents.truncated =
                    Some(format!("the file ends early (the session was cut short): {e}"));
                break;
            }
        };
        seen_any = true;
        if let mcap::records::Record::Chunk { header, data } = record {
            let index = reading.chunks;
            reading.chunks += 1;
            let chunk =
                unpack(&header, &data).map_err(|what| ReadError::Damaged { index, what })?;
            // Records inside the chunk are bounded by its (checked) length.
            for record in mcap::read::LinearReader::sans_magic(&chunk) {
                match record {
                    Ok(r) => reading.take(r)?,
                    Err(e) => {
                        return Err(ReadError::Damaged { index, what: e.to_string() });
                    }
                }
            }
        } else {
            reading.take(record)?;
        }
    }
    let contents = reading.contents;
    if contents.metadata.is_empty() {
        return Err(ReadError::Foreign);
    }
    match contents.metadata.get("protocol") {
        Some(p) if p == incise_protocol::PACKAGE => Ok(contents),
        found => Err(ReadError::Version {
            found: found.cloned().unwrap_or_default(),
            expected: incise_protocol::PACKAGE,
        }),
    }
}

/// A chunk's records, decompressed and checked against its header before any is parsed. The
/// mcap crate's own chunk reader allocates whatever a record's length inside the chunk claims,
/// which a damaged chunk turns into an out-of-memory abort; here the length is checked first
/// (LZ4 and zstd expand at most ~255×), the data decompressed no further than it, and its CRC
/// compared.
fn unpack(header: &mcap::records::ChunkHeader, data: &[u8]) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let size = header.uncompressed_size;
    let limit = header.compressed_size.saturating_mul(255).saturating_add(64).min(MAX_CHUNK);
    if size > limit {
        return Err(format!("{size} bytes uncompressed claimed from {}", header.compressed_size));
    }
    let size = size as usize;
    let chunk = match header.compression.as_str() {
        "" => data.to_vec(),
        "lz4" => {
            let mut out = Vec::with_capacity(size);
            lz4::Decoder::new(data)
                .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                .map_err(|e| format!("LZ4: {e}"))?;
            out
        }
        other => return Err(format!("compression {other:?}, which incise does not write")),
    };
    if chunk.len() != size {
        return Err(format!("{} bytes uncompressed, its header says {size}", chunk.len()));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(&chunk) != header.uncompressed_crc {
        return Err("its CRC does not match".into());
    }
    Ok(chunk)
}

/// A read in progress: what has been taken, and the channels' topics by id.
#[derive(Default)]
struct Reading {
    contents: Contents,
    topics: BTreeMap<u16, String>,
    messages: usize,
    chunks: usize,
    seek: Option<u64>,
}

/// A keyframe's frame number alone: decoding it skips the state.
#[derive(Clone, PartialEq, prost::Message)]
struct KeyframeHead {
    #[prost(uint64, tag = "1")]
    frame: u64,
}

impl Reading {
    /// Takes one record (outside a chunk or from one).
    fn take(&mut self, record: mcap::records::Record<'_>) -> Result<(), ReadError> {
        use mcap::records::Record;
        match record {
            Record::Channel(c) => {
                self.topics.insert(c.id, c.topic);
            }
            Record::Message { header, data } => {
                let index = self.messages;
                self.messages += 1;
                let topic = self.topics.get(&header.channel_id).map_or("", String::as_str);
                let bad =
                    |what: String| ReadError::BadMessage { index, topic: topic.to_owned(), what };
                match topic {
                    FRAME_TOPIC => self
                        .contents
                        .frames
                        .push(v1::FrameRecord::decode(&*data).map_err(|e| bad(e.to_string()))?),
                    CUT_TOPIC => self.contents.cuts.push((
                        v1::CutEvent::decode(&*data).map_err(|e| bad(e.to_string()))?,
                        header.log_time,
                    )),
                    FORCE_TOPIC => self
                        .contents
                        .forces
                        .push(v1::SentForce::decode(&*data).map_err(|e| bad(e.to_string()))?),
                    SURFACE_TOPIC => self.contents.surfaces.push((
                        v1::SurfaceMesh::decode(&*data).map_err(|e| bad(e.to_string()))?,
                        header.log_time,
                    )),
                    EDIT_TOPIC => self
                        .contents
                        .edits
                        .push(v1::TopologyEdit::decode(&*data).map_err(|e| bad(e.to_string()))?),
                    KEYFRAME_TOPIC => {
                        let head = KeyframeHead::decode(&*data).map_err(|e| bad(e.to_string()))?;
                        self.contents.keyframe_frames.push(head.frame);
                        if self.seek.is_some_and(|seek| head.frame <= seek) {
                            self.contents.keyframe =
                                Some(v1::Keyframe::decode(&*data).map_err(|e| bad(e.to_string()))?);
                        }
                    }
                    // Channels a later version adds are not ours to refuse.
                    _ => {}
                }
            }
            Record::Metadata(m) if m.name == "incise" => self.contents.metadata = m.metadata,
            Record::Attachment { header, data, .. } if header.name == "scene.toml" => {
                self.contents.scene_toml = Some(String::from_utf8_lossy(&data).into_owned());
            }
            Record::Attachment { header, data, .. } => {
                self.contents.files.insert(header.name, data.into_owned());
            }
            _ => {}
        }
        Ok(())
    }
}
