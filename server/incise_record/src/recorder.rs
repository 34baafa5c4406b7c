//! The recorder thread: the physics thread hands it every frame over a bounded queue, and it
//! writes them to the session's MCAP file (closing a chunk on a schedule) and `.rrd` file, and
//! offers them to a live viewer.

use crate::mcap_file::{McapRecording, RecordError};
use crate::rerun_log::{LiveItem, LiveStream, RerunLog};
use crate::visual::SurfaceFrame;
use incise_protocol::v1;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Records the physics may hand over before it waits: a quarter second at 1 kHz.
const QUEUE: usize = 256;

/// How long the recorder rests between takes of the queue: 2 ms holds 2 frames at 1 kHz, 10 at
/// the 13k liver's 5 kHz, well within [`QUEUE`].
const PAUSE: Duration = Duration::from_millis(2);

/// A chunk is closed after this many frames...
pub const CHUNK_FRAMES: u64 = 250;
/// ...or this much wall time, whichever comes first.
pub const CHUNK_INTERVAL: Duration = Duration::from_millis(250);

/// What the physics hands the recorder.
#[derive(Clone, Debug)]
pub enum Record {
    /// A frame.
    Frame(v1::FrameRecord),
    /// A cut, made at simulated time `.1`.
    Cut(v1::CutEvent, f64),
    /// The organ's surface at a frame (after that frame's record).
    Surface(SurfaceFrame),
    /// The topology change a frame made, at simulated time `.1`.
    Edit(v1::TopologyEdit, f64),
    /// A keyframe, at simulated time `.1`.
    Keyframe(Box<v1::Keyframe>, f64),
}

/// Where the recorder writes: any of an MCAP file, an `.rrd` file and a live viewer.
#[derive(Default)]
pub struct Sinks {
    /// The session's MCAP file.
    pub mcap: Option<McapRecording>,
    /// The session's `.rrd` file.
    pub rrd: Option<RerunLog>,
    /// A live Rerun viewer.
    pub live: Option<LiveStream>,
    /// The haptic loop's sent forces, for the MCAP file.
    pub forces: Option<Arc<incise_haptics::ForceLog>>,
}

/// What the recorder counts.
#[derive(Debug, Default)]
pub struct RecorderStats {
    /// Frames written.
    pub frames: AtomicU64,
    /// Times the physics found the queue full and waited.
    pub waits: AtomicU64,
    /// Surface frames written.
    pub surfaces: AtomicU64,
    /// Sent forces written.
    pub forces: AtomicU64,
    /// Surface frames the live viewer was too slow for (dropped from the live stream only).
    pub live_dropped_geometry: AtomicU64,
    /// Frame records and cuts dropped from the live stream (its queue was full).
    pub live_dropped_frames: AtomicU64,
    /// Records that could not be handed over because the recorder had stopped (a write error).
    pub lost: AtomicU64,
    /// Chunks closed.
    pub chunks: AtomicU64,
    /// Set once a write failed (the recording then stops; the session goes on).
    pub failed: AtomicBool,
}

/// The physics thread's end of the queue.
#[derive(Clone, Debug)]
pub struct RecordHandle {
    tx: SyncSender<Record>,
    stats: Arc<RecorderStats>,
}

impl RecordHandle {
    /// Hands a record over; when the queue is full, counts a wait and waits (a recording never
    /// drops a frame). A record for a recorder that has stopped is counted as lost.
    pub fn record(&self, record: Record) {
        let record = match self.tx.try_send(record) {
            Ok(()) => return,
            Err(TrySendError::Full(r)) => {
                self.stats.waits.fetch_add(1, Ordering::Relaxed);
                r
            }
            Err(TrySendError::Disconnected(_)) => {
                self.stats.lost.fetch_add(1, Ordering::Relaxed);
                return;
            }
        };
        if self.tx.send(record).is_err() {
            self.stats.lost.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The recorder thread and its queue.
pub struct Recorder {
    /// `None` once finishing (dropping it closes the queue).
    handle: Option<RecordHandle>,
    stats: Arc<RecorderStats>,
    path: PathBuf,
    thread: Option<JoinHandle<Result<u64, RecordError>>>,
}

impl Recorder {
    /// Starts the thread (`incise-record`) that writes `recording`.
    pub fn start(recording: McapRecording) -> std::io::Result<Self> {
        Self::with_sinks(Sinks { mcap: Some(recording), ..Sinks::default() })
    }

    /// Starts the thread (`incise-record`) that writes to `sinks`.
    pub fn with_sinks(sinks: Sinks) -> std::io::Result<Self> {
        let (tx, rx) = mpsc::sync_channel(QUEUE);
        let stats = Arc::new(RecorderStats::default());
        let path = sinks.mcap.as_ref().map(|m| m.path().to_owned()).unwrap_or_default();
        let thread = {
            let stats = Arc::clone(&stats);
            std::thread::Builder::new()
                .name("incise-record".into())
                .spawn(move || write_all(sinks, &rx, &stats))?
        };
        Ok(Self {
            handle: Some(RecordHandle { tx, stats: Arc::clone(&stats) }),
            stats,
            path,
            thread: Some(thread),
        })
    }

    /// A handle to hand records over with.
    ///
    /// # Panics
    /// Never: the handle is only taken by [`Self::finish`], which consumes the recorder.
    #[must_use]
    pub fn handle(&self) -> RecordHandle {
        self.handle.clone().expect("the recorder is not finishing")
    }

    /// The counters.
    #[must_use]
    pub fn stats(&self) -> &RecorderStats {
        &self.stats
    }

    /// The file being written.
    #[must_use]
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Writes what is queued, closes the file and returns the frames written. Every handle
    /// must be dropped first (the thread ends when the queue closes).
    pub fn finish(mut self) -> Result<u64, RecordError> {
        drop(self.handle.take());
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(RecordError {
                path: self.path.clone(),
                what: "the recorder thread panicked".into(),
            }),
            None => Ok(0),
        }
    }
}

/// The thread: writes every record, closing a chunk every [`CHUNK_FRAMES`] frames or
/// [`CHUNK_INTERVAL`]; on a write error it stops (the session goes on unrecorded).
fn write_all(
    mut sinks: Sinks,
    rx: &mpsc::Receiver<Record>,
    stats: &RecorderStats,
) -> Result<u64, RecordError> {
    let mut chunk_started = Instant::now();
    let mut chunk_frames = 0u64;
    // The last frame's record: the tools of the surface frame that follows it.
    let mut last: Option<Arc<v1::FrameRecord>> = None;
    let result = (|| loop {
        let first = match rx.recv_timeout(CHUNK_INTERVAL) {
            Ok(r) => Some(r),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => {
                // The session is over: the forces sent up to its end are in the log.
                return drain_forces(&mut sinks, last.as_deref(), stats);
            }
        };
        // Take what else is queued, then pause: the physics' sends then seldom find this thread
        // blocked, so they seldom pay for waking it (a wake per frame cost the 13k liver up to
        // ~18 % of its frame rate). The queue holds far more than a pause's frames.
        for record in first.into_iter().chain(std::iter::from_fn(|| rx.try_recv().ok())) {
            match record {
                Record::Frame(f) => {
                    let f = Arc::new(f);
                    if let Some(mcap) = &mut sinks.mcap {
                        mcap.frame(&f)?;
                    }
                    if let Some(rrd) = &mut sinks.rrd {
                        rrd.frame(&f);
                    }
                    if let Some(live) = &sinks.live {
                        live.offer(LiveItem::Frame(Arc::clone(&f)));
                    }
                    last = Some(f);
                    chunk_frames += 1;
                    stats.frames.fetch_add(1, Ordering::Relaxed);
                }
                Record::Cut(c, t) => {
                    if let Some(mcap) = &mut sinks.mcap {
                        mcap.cut(&c, t)?;
                    }
                    if let Some(rrd) = &mut sinks.rrd {
                        rrd.cut(&c, t);
                    }
                    if let Some(live) = &sinks.live {
                        live.offer(LiveItem::Cut(c, t));
                    }
                }
                Record::Edit(e, t) => {
                    if let Some(mcap) = &mut sinks.mcap {
                        mcap.edit(&e, t)?;
                    }
                }
                Record::Keyframe(k, t) => {
                    if let Some(mcap) = &mut sinks.mcap {
                        mcap.keyframe(&k, t)?;
                    }
                }
                Record::Surface(surface) => {
                    let record = last.as_ref().filter(|r| r.frame == surface.frame);
                    if let Some(mcap) = &mut sinks.mcap {
                        mcap.surface(&surface, record.map(|r| &**r))?;
                    }
                    if let Some(rrd) = &mut sinks.rrd {
                        rrd.surface(&surface, record.map(|r| &**r));
                    }
                    if let Some(live) = &sinks.live {
                        live.offer(LiveItem::Surface(Arc::new(surface), record.cloned()));
                        let s = live.stats();
                        stats
                            .live_dropped_geometry
                            .store(s.dropped_geometry.load(Ordering::Relaxed), Ordering::Relaxed);
                        stats
                            .live_dropped_frames
                            .store(s.dropped_frames.load(Ordering::Relaxed), Ordering::Relaxed);
                    }
                    stats.surfaces.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        drain_forces(&mut sinks, last.as_deref(), stats)?;
        if chunk_frames >= CHUNK_FRAMES
            || (chunk_frames > 0 && chunk_started.elapsed() >= CHUNK_INTERVAL)
        {
            if let Some(mcap) = &mut sinks.mcap {
                mcap.close_chunk()?;
            }
            stats.chunks.fetch_add(1, Ordering::Relaxed);
            chunk_frames = 0;
            chunk_started = Instant::now();
        }
        std::thread::sleep(PAUSE);
    })();
    if let Some(live) = sinks.live.take() {
        live.finish();
    }
    if let Some(rrd) = sinks.rrd.take()
        && let Err(e) = rrd.finish()
    {
        tracing::warn!("the Rerun recording: {e}");
    }
    if let Err(e) = result {
        stats.failed.store(true, Ordering::Release);
        return Err(e);
    }
    match sinks.mcap {
        Some(mcap) => mcap.finish(),
        None => Ok(stats.frames.load(Ordering::Relaxed)),
    }
}

/// Writes the forces the haptic loop has sent since the last call, logged at `last`'s time.
fn drain_forces(
    sinks: &mut Sinks,
    last: Option<&v1::FrameRecord>,
    stats: &RecorderStats,
) -> Result<(), RecordError> {
    if let (Some(log), Some(mcap)) = (&sinks.forces, &mut sinks.mcap) {
        let t = last.map_or(0.0, |r| r.sim_time_s);
        while let Some(sent) = log.pop() {
            mcap.sent_force(&sent, t)?;
            stats.forces.fetch_add(1, Ordering::Relaxed);
        }
    }
    Ok(())
}
