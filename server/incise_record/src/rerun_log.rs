//! The session in Rerun: an `.rrd` file ([`RerunLog::save`]) and a live stream to a viewer
//! ([`LiveStream`]).
//!
//! | entity | what | when |
//! |---|---|---|
//! | `organ` | `Mesh3D`, vertex colours by tissue label | every surface frame (positions only while the topology holds) |
//! | `tools/<name>` | `Transform3D`: the tool the tissue feels (its proxy; its device's pose when it has none) | every surface frame |
//! | `tools/<name>/outer` | the outer shape (ellipsoid, capsule or box) | once |
//! | `devices/<name>` | `Transform3D` (the device's pose), with a translucent ghost of the outer shape under it | every surface frame |
//! | `couplings/<name>` | `LineStrips3D`: the coupling spring from the device's origin to the proxy's | every surface frame |
//! | `forces/<name>` | `Arrows3D`, 2 cm per newton, from the device's origin | every surface frame |
//! | `plots/force/<name>` | force x, y, z (N) | every frame |
//! | `plots/frame_ms`, `plots/stage/<stage>_ms` | frame and stage wall times | every frame |
//! | `plots/contact_points`, `plots/frame_rate_hz` | | every frame |
//! | `events/cuts` | `TextLog` | every cut |
//!
//! Two timelines: `frame` (the physics frame, from 1) and `sim_time` (simulated time).

use crate::foxglove::ARROW_M_PER_N;
use crate::visual::{SurfaceFrame, SurfaceState, ToolLook, ToolShape, label_colour};
use incise_protocol::v1;
use rerun::RecordingStream;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Duration;

/// The application id every incise recording carries (how the viewer groups them).
pub const APPLICATION_ID: &str = "incise";

/// A recorded pose as a Rerun translation and rotation (the rotation normalised; identity when
/// it cannot be).
fn transform(p: Option<&v1::Vec3>, q: Option<&v1::Quaternion>) -> ([f32; 3], rerun::Quaternion) {
    let p = p.copied().unwrap_or_default();
    let q = q.copied().unwrap_or_default();
    let n = (q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z).sqrt();
    let rotation = if n > 0.0 && n.is_finite() {
        rerun::Quaternion::from_xyzw([q.x, q.y, q.z, q.w].map(|c| (c / n) as f32))
    } else {
        rerun::Quaternion::IDENTITY
    };
    ([p.x as f32, p.y as f32, p.z as f32], rotation)
}

/// How a file's rows are gathered into chunks: a file has no viewer waiting on it, so rows
/// gather for a second (Rerun's default is 200 ms), which makes a fifth as many chunks, each
/// with its own header and compression frame.
const FILE_BATCHING: rerun::log::ChunkBatcherConfig = rerun::log::ChunkBatcherConfig {
    flush_tick: Duration::from_secs(1),
    ..rerun::log::ChunkBatcherConfig::DEFAULT
};

/// A Rerun recording stream and what it needs to draw the session.
pub struct RerunLog {
    stream: RecordingStream,
    tools: Vec<ToolLook>,
    /// The surface as the surface frames so far describe it.
    surface: SurfaceState,
    /// The topology changed since the mesh was last logged whole.
    stale_topology: bool,
    /// Vertices in the mesh last logged whole.
    logged_vertices: usize,
    /// The time series not yet sent.
    series: Series,
    /// Frames of time series gathered before they are sent.
    series_frames: usize,
    /// The session file to index when the stream finishes ([`Self::save_session`]).
    index_on_finish: Option<std::path::PathBuf>,
}

impl RerunLog {
    /// An `.rrd` file at `path` of a bounded length (a rendered recording): it ends with
    /// Rerun's index of every chunk (the footer the viewer seeks with), which the writer holds in
    /// memory until it finishes.
    pub fn save(path: &Path, tools: &[ToolLook]) -> Result<Self, String> {
        Self::file(path, tools, true)
    }

    /// An `.rrd` file at `path` that a live session writes for as long as it runs: Rerun's
    /// chunk index grows by a row (about a kilobyte) per chunk for the whole session, so it is
    /// left out while the session runs, which keeps the session's memory flat, and written by
    /// [`index_rrd`] when the stream finishes. A session that crashed leaves its file without
    /// the index: the viewer still opens it, and `rerun rrd optimize` adds it.
    pub fn save_session(path: &Path, tools: &[ToolLook]) -> Result<Self, String> {
        let mut log = Self::file(path, tools, false)?;
        log.index_on_finish = Some(path.to_owned());
        Ok(log)
    }

    fn file(path: &Path, tools: &[ToolLook], index: bool) -> Result<Self, String> {
        let error = |e: &dyn std::fmt::Display| {
            format!("{}: cannot start the Rerun file: {e}", path.display())
        };
        let options = rerun::sink::FileSinkOptions { write_footer: index };
        let sink = rerun::sink::FileSink::with_options(path, options).map_err(|e| error(&e))?;
        let stream = rerun::RecordingStreamBuilder::new(APPLICATION_ID)
            .batcher_config(FILE_BATCHING)
            .set_sinks((sink,))
            .map_err(|e| error(&e))?;
        let mut log = Self::on(stream, tools);
        log.series_frames = FILE_SERIES_FRAMES;
        Ok(log)
    }

    /// A live stream to the viewer (or proxy) at `url`, e.g.
    /// `rerun+http://127.0.0.1:9876/proxy`.
    pub fn connect(url: &str, tools: &[ToolLook]) -> Result<Self, String> {
        let stream = rerun::RecordingStreamBuilder::new(APPLICATION_ID)
            .connect_grpc_opts(url)
            .map_err(|e| format!("cannot stream to the Rerun viewer at {url}: {e}"))?;
        Ok(Self::on(stream, tools))
    }

    fn on(stream: RecordingStream, tools: &[ToolLook]) -> Self {
        let log = Self {
            stream,
            tools: tools.to_vec(),
            surface: SurfaceState::default(),
            stale_topology: false,
            logged_vertices: 0,
            series: Series::default(),
            series_frames: LIVE_SERIES_FRAMES,
            index_on_finish: None,
        };
        log.tool_shapes();
        log
    }

    /// Each tool's outer shape, in its own frame, once: solid on the tool (its proxy), a
    /// translucent ghost on its device.
    fn tool_shapes(&self) {
        let grey = rerun::Color::from_unmultiplied_rgba(160, 160, 170, 255);
        let ghost = rerun::Color::from_unmultiplied_rgba(120, 170, 250, 90);
        let f = |v: [f64; 3]| v.map(|c| c as f32);
        for look in &self.tools {
            for (path, colour) in [
                (format!("tools/{}/outer", look.name), grey),
                (format!("devices/{}/outer", look.name), ghost),
            ] {
                let result = match look.shape {
                    ToolShape::Sphere { centre, radius } => self.stream.log_static(
                        path,
                        &rerun::Ellipsoids3D::from_centers_and_radii([f(centre)], [radius as f32])
                            .with_colors([colour]),
                    ),
                    ToolShape::Capsule { start, radius, length } => self.stream.log_static(
                        path,
                        &rerun::Capsules3D::from_lengths_and_radii(
                            [length as f32],
                            [radius as f32],
                        )
                        .with_translations([f(start)])
                        .with_colors([colour]),
                    ),
                    ToolShape::Box { min, max } => self.stream.log_static(
                        path,
                        &rerun::Boxes3D::from_mins_and_sizes(
                            [f(min)],
                            [f(std::array::from_fn(|i| max[i] - min[i]))],
                        )
                        .with_colors([colour]),
                    ),
                };
                warn(result);
            }
        }
    }

    fn at(&self, frame: u64, sim_time_s: f64) {
        self.stream.set_time_sequence("frame", frame as i64);
        self.stream.set_duration_secs("sim_time", sim_time_s);
    }

    fn scalar(&mut self, path: &str, frame: u64, sim_time_s: f64, values: &[f64]) {
        self.series.push(path, frame, sim_time_s, values);
    }

    /// Sends the buffered time series, a chunk per entity.
    fn send_series(&mut self) {
        for (path, column) in &mut self.series.columns {
            if column.frames.is_empty() {
                continue;
            }
            let rows = column.frames.len();
            let width = column.values.len() / rows;
            let indexes = [
                rerun::TimeColumn::new_sequence("frame", column.frames.drain(..)),
                rerun::TimeColumn::new_duration_secs("sim_time", column.times.drain(..)),
            ];
            let values = rerun::Scalars::new(column.values.drain(..));
            match values.columns(std::iter::repeat_n(width, rows)) {
                Ok(columns) => warn(self.stream.send_columns(path.as_str(), indexes, columns)),
                Err(e) => warn(Err(e.into())),
            }
        }
        self.series.frames = 0;
    }

    /// A frame's time series: each posed tool's force, the frame's and its stages' wall times,
    /// its contact points and the frame rate.
    pub fn frame(&mut self, record: &v1::FrameRecord) {
        let (frame, t) = (record.frame, record.sim_time_s);
        for state in &record.tools {
            let Some(look) = self.tools.get(state.tool_id as usize) else { continue };
            let f = state.force.unwrap_or_default();
            let path = format!("plots/force/{}", look.name);
            self.scalar(&path, frame, t, &[f.x, f.y, f.z]);
        }
        if let Some(s) = &record.stats {
            self.scalar("plots/frame_ms", frame, t, &[s.frame_ms]);
            for (path, ms) in [
                ("plots/stage/contact_ms", s.contact_ms),
                ("plots/stage/cut_ms", s.cut_ms),
                ("plots/stage/grid_ms", s.grid_ms),
                ("plots/stage/remesh_ms", s.remesh_ms),
                ("plots/stage/mechanics_ms", s.mechanics_ms),
            ] {
                self.scalar(path, frame, t, &[ms]);
            }
            self.scalar("plots/contact_points", frame, t, &[f64::from(s.contact_points)]);
            self.scalar("plots/frame_rate_hz", frame, t, &[s.frame_rate_hz]);
        }
        self.series.frames += 1;
        if self.series.frames >= self.series_frames {
            self.send_series();
        }
    }

    /// A cut, as a line of the event log.
    pub fn cut(&mut self, cut: &v1::CutEvent, sim_time_s: f64) {
        self.at(cut.frame, sim_time_s);
        let tool = self.tools.get(cut.tool_id as usize).map_or("?", |t| t.name.as_str());
        let text = format!(
            "{tool} cut: {} voxels removed, {} links severed, {} tetrahedra removed",
            cut.voxels_removed, cut.links_severed, cut.tets_removed
        );
        warn(self.stream.log("events/cuts", &rerun::TextLog::new(text)));
    }

    /// The organ's surface, and each posed tool's pose and force arrow, at `surface`'s frame
    /// (`record`: that frame's record).
    pub fn surface(&mut self, surface: &SurfaceFrame, record: Option<&v1::FrameRecord>) {
        self.at(surface.frame, surface.sim_time_s);
        self.surface.apply(surface);
        self.stale_topology |= surface.changes_topology();
        // A frame taken for a topology change alone carries only the new vertices' positions:
        // the mesh is logged whole on the next frame that has them all (at most one geometry
        // tick later), not on every cutting frame.
        let all_positions =
            surface.whole || surface.vertex_ids.len() >= self.surface.vertex_count();
        if !all_positions {
            return;
        }
        if self.stale_topology {
            self.stale_topology = false;
            let mesh = self.surface.mesh();
            let mut colours = vec![
                rerun::Color::from_unmultiplied_rgba(200, 200, 200, 255);
                mesh.positions.len()
            ];
            for (t, &l) in mesh.triangles.iter().zip(&mesh.labels) {
                let [r, g, b, a] = label_colour(l);
                for &v in t {
                    colours[v as usize] = rerun::Color::from_unmultiplied_rgba(r, g, b, a);
                }
            }
            warn(
                self.stream.log(
                    "organ",
                    &rerun::Mesh3D::new(mesh.positions)
                        .with_triangle_indices(mesh.triangles)
                        .with_vertex_colors(colours),
                ),
            );
        } else if self.logged_vertices == self.surface.vertex_count() {
            // The topology holds: only the positions change.
            warn(self.stream.log(
                "organ",
                &rerun::Mesh3D::update_fields().with_vertex_positions(self.surface.positions()),
            ));
        }
        let Some(record) = record else { return };
        for state in &record.tools {
            let Some(look) = self.tools.get(state.tool_id as usize) else { continue };
            let Some(pose) = record.poses.iter().find(|p| p.tool_id == state.tool_id) else {
                continue;
            };
            let device = transform(pose.position.as_ref(), pose.orientation.as_ref());
            // Without a proxy the tool is where its device is.
            let felt = state
                .proxy
                .as_ref()
                .map_or(device, |p| transform(p.position.as_ref(), p.orientation.as_ref()));
            warn(self.stream.log(
                format!("tools/{}", look.name),
                &rerun::Transform3D::from_translation_rotation(felt.0, felt.1),
            ));
            warn(self.stream.log(
                format!("devices/{}", look.name),
                &rerun::Transform3D::from_translation_rotation(device.0, device.1),
            ));
            warn(
                self.stream.log(
                    format!("couplings/{}", look.name),
                    &rerun::LineStrips3D::new([[device.0, felt.0]])
                        .with_colors([rerun::Color::from_unmultiplied_rgba(120, 170, 250, 255)]),
                ),
            );
            let at = device.0;
            let f = state.force.unwrap_or_default();
            let arrow = [f.x, f.y, f.z].map(|c| (c * ARROW_M_PER_N) as f32);
            warn(
                self.stream.log(
                    format!("forces/{}", look.name),
                    &rerun::Arrows3D::from_vectors([arrow])
                        .with_origins([at])
                        .with_colors([rerun::Color::from_unmultiplied_rgba(250, 220, 40, 255)]),
                ),
            );
        }
    }

    /// Writes what is buffered and waits until the sink has taken it (at most `timeout`).
    pub fn flush(&mut self, timeout: Duration) -> Result<(), String> {
        self.send_series();
        self.stream.flush_with_timeout(timeout).map_err(|e| e.to_string())
    }

    /// Flushes and closes the stream; a session's file then gets its index ([`index_rrd`]).
    pub fn finish(mut self) -> Result<(), String> {
        self.send_series();
        self.stream.flush_blocking().map_err(|e| e.to_string())?;
        // Dropping the stream closes the file (its writer thread ends).
        let Self { stream, index_on_finish, .. } = self;
        drop(stream);
        if let Some(path) = index_on_finish {
            let start = std::time::Instant::now();
            let done = index_rrd(&path)?;
            tracing::info!(
                "{}: indexed for the viewer ({} messages, {:.1} MB) in {:.2} s",
                path.display(),
                done.messages,
                done.bytes_after as f64 / 1e6,
                start.elapsed().as_secs_f64()
            );
        }
        Ok(())
    }
}

/// What [`index_rrd`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IndexedRrd {
    /// Messages re-written.
    pub messages: u64,
    /// The file's size with its index (bytes).
    pub bytes_after: u64,
}

/// Gives a session's `.rrd` file ([`RerunLog::save_session`]) Rerun's chunk index, which the
/// viewer seeks with and `rerun rrd verify` requires: the file is decoded and written again
/// with the index (`<file>.indexing` beside it, then renamed over it), so the index's memory is
/// held only while this runs.
///
/// # Errors
/// When the file cannot be read, does not decode to its end (a file cut short by a crash) or
/// the new one cannot be written; the original is then left as it was.
pub fn index_rrd(path: &Path) -> Result<IndexedRrd, String> {
    use std::io::{BufReader, BufWriter, Write as _};
    let err = |what: &str, e: &dyn std::fmt::Display| format!("{}: {what}: {e}", path.display());
    let input = std::fs::File::open(path).map_err(|e| err("cannot read", &e))?;
    let temp = path.with_extension("rrd.indexing");
    let result = (|| {
        let output = std::fs::File::create(&temp).map_err(|e| err("cannot write", &e))?;
        let mut encoder = re_log_encoding::Encoder::new_eager(
            re_log_encoding::CrateVersion::LOCAL,
            re_log_encoding::EncodingOptions::PROTOBUF_COMPRESSED,
            BufWriter::new(output),
        )
        .map_err(|e| err("cannot write", &e))?;
        let mut messages = 0;
        let decoder =
            re_log_encoding::DecoderApp::decode_lazy(BufReader::with_capacity(1 << 20, input));
        for message in decoder {
            let message = message.map_err(|e| err("cannot decode", &e))?;
            encoder.append(&message).map_err(|e| err("cannot write", &e))?;
            messages += 1;
        }
        encoder.finish().map_err(|e| err("cannot write its index", &e))?;
        let mut writer = encoder.into_inner().map_err(|e| err("cannot write", &e))?;
        writer.flush().map_err(|e| err("cannot write", &e))?;
        drop(writer);
        std::fs::rename(&temp, path).map_err(|e| err("cannot replace", &e))?;
        Ok(messages)
    })();
    match result {
        Ok(messages) => {
            let bytes_after = std::fs::metadata(path).map_or(0, |m| m.len());
            Ok(IndexedRrd { messages, bytes_after })
        }
        Err(e) => {
            let _ = std::fs::remove_file(&temp);
            Err(e)
        }
    }
}

/// Frames of time series gathered before they are sent to a viewer: 0.1 s of a 1 kHz session.
const LIVE_SERIES_FRAMES: usize = 100;
/// Frames of time series gathered before they are written to a file: 1 s of a 1 kHz session,
/// a tenth as many chunks as a viewer's (each is a row of the file's index).
const FILE_SERIES_FRAMES: usize = 1000;

/// Time series gathered frame by frame and sent as columns ([`RecordingStream::send_columns`]):
/// a dozen series at 1 kHz, logged a row at a time, are more rows than Rerun's batcher keeps
/// up with on a shared core, and its queue (up to 100 MB) grows for the whole session.
#[derive(Default)]
struct Series {
    /// By entity path, in the order first logged.
    columns: Vec<(String, Column)>,
    /// Frames gathered since the last send.
    frames: usize,
}

/// One entity's rows: `values` holds `values.len() / frames.len()` scalars per row.
#[derive(Default)]
struct Column {
    frames: Vec<i64>,
    times: Vec<f64>,
    values: Vec<f64>,
}

impl Series {
    fn push(&mut self, path: &str, frame: u64, sim_time_s: f64, values: &[f64]) {
        let i = self.columns.iter().position(|(p, _)| p == path).unwrap_or_else(|| {
            self.columns.push((path.to_owned(), Column::default()));
            self.columns.len() - 1
        });
        let column = &mut self.columns[i].1;
        column.frames.push(i64::try_from(frame).unwrap_or(i64::MAX));
        column.times.push(sim_time_s);
        column.values.extend_from_slice(values);
    }
}

/// What the live stream is handed.
#[derive(Clone, Debug)]
pub enum LiveItem {
    /// A frame's record.
    Frame(Arc<v1::FrameRecord>),
    /// A cut at a simulated time.
    Cut(v1::CutEvent, f64),
    /// A surface frame, with its frame's record.
    Surface(Arc<SurfaceFrame>, Option<Arc<v1::FrameRecord>>),
}

/// What the live stream counts.
#[derive(Debug, Default)]
pub struct LiveStats {
    /// Surface frames dropped because the viewer was behind.
    pub dropped_geometry: AtomicU64,
    /// Frame records and cuts dropped because the stream's queue was full.
    pub dropped_frames: AtomicU64,
    /// Surface frames sent.
    pub sent_geometry: AtomicU64,
}

/// Says once that Rerun refused a log call (each would fail the same way, every frame).
fn warn(result: Result<(), rerun::RecordingStreamError>) {
    static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if let Err(e) = result
        && !SAID.swap(true, Ordering::Relaxed)
    {
        tracing::warn!("rerun refused a log call (further refusals are not reported): {e}");
    }
}

/// Items queued before the live stream drops frame records too.
const LIVE_QUEUE: usize = 1024;
/// Items queued above which a surface frame is dropped rather than queued.
const LIVE_GEOMETRY_BACKLOG: u64 = 16;

/// A thread (`incise-rerun-live`) that streams the session to a viewer. It never makes its
/// caller wait: when the viewer falls behind (each surface frame is flushed through before the
/// next is taken), surface frames are dropped first and counted, then frame records.
pub struct LiveStream {
    tx: Option<SyncSender<LiveItem>>,
    queued: Arc<AtomicU64>,
    stats: Arc<LiveStats>,
    thread: Option<JoinHandle<()>>,
}

impl LiveStream {
    /// Starts streaming through `log` (a [`RerunLog::connect`]).
    pub fn start(log: RerunLog) -> std::io::Result<Self> {
        let (tx, rx) = mpsc::sync_channel(LIVE_QUEUE);
        let queued = Arc::new(AtomicU64::new(0));
        let stats = Arc::new(LiveStats::default());
        let thread = {
            let (queued, stats) = (Arc::clone(&queued), Arc::clone(&stats));
            std::thread::Builder::new()
                .name("incise-rerun-live".into())
                .spawn(move || stream_live(log, &rx, &queued, &stats))?
        };
        Ok(Self { tx: Some(tx), queued, stats, thread: Some(thread) })
    }

    /// Offers an item; drops it (counted) when the viewer is behind.
    pub fn offer(&self, item: LiveItem) {
        let Some(tx) = &self.tx else { return };
        let geometry = matches!(item, LiveItem::Surface(..));
        if geometry && self.queued.load(Ordering::Acquire) > LIVE_GEOMETRY_BACKLOG {
            self.stats.dropped_geometry.fetch_add(1, Ordering::Relaxed);
            return;
        }
        self.queued.fetch_add(1, Ordering::AcqRel);
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = tx.try_send(item) {
            self.queued.fetch_sub(1, Ordering::AcqRel);
            let counter =
                if geometry { &self.stats.dropped_geometry } else { &self.stats.dropped_frames };
            counter.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The counters.
    #[must_use]
    pub fn stats(&self) -> &LiveStats {
        &self.stats
    }

    /// Streams what is queued and closes the stream.
    pub fn finish(mut self) {
        drop(self.tx.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn stream_live(mut log: RerunLog, rx: &Receiver<LiveItem>, queued: &AtomicU64, stats: &LiveStats) {
    while let Ok(item) = rx.recv() {
        queued.fetch_sub(1, Ordering::AcqRel);
        match item {
            LiveItem::Frame(record) => log.frame(&record),
            LiveItem::Cut(cut, t) => log.cut(&cut, t),
            LiveItem::Surface(surface, record) => {
                log.surface(&surface, record.as_deref());
                stats.sent_geometry.fetch_add(1, Ordering::Relaxed);
                // Hold the queue here until the viewer has the surface: a slow viewer then
                // shows as a backlog, and the next surface frames are dropped.
                if let Err(e) = log.flush(Duration::from_secs(2)) {
                    tracing::debug!("rerun live stream: {e}");
                }
            }
        }
    }
    if let Err(e) = log.finish() {
        tracing::warn!("rerun live stream: {e}");
    }
}
