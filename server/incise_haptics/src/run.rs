//! The haptic thread: wakes on every new pose (event-driven, so a force answers its pose at
//! once) and at least at [`HapticSettings::rate_hz`] (so a silent device's force still fades),
//! renders each tool's force, and hands it to the transports.
//!
//! Everything it touches is fixed-size and shared through [`LoopShared`]: the physics thread
//! writes each tool's [`ToolSnapshot`] into a seqlock cell, the transports write poses into
//! per-tool, per-source cells, and the thread writes each force into the tool's output cell.
//! How the thread waits and where its forces go is its [`LoopIo`]: by default it parks and a
//! pose from another thread unparks it; a transport that can be served from the haptic thread
//! itself (shared memory) instead waits on its own event, takes its poses on the thread and
//! publishes the forces from it, so that a pose reaches its force without crossing threads.
//! No allocation, lock or log on that path: counters are atomics, and the period's jitter goes
//! into a fixed histogram.

use crate::cell::SeqCell;
use crate::render::{HapticSettings, Renderer};
use crate::snapshot::{SnapshotCell, ToolSnapshot};
use incise_protocol::check::{CheckedPose, check_pose};
use incise_protocol::raw::{RawToolForce, RawToolPose};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::Thread;
use std::time::{Duration, Instant};

/// Words of a pose record: the `RawToolPose` (18 words) and the arrival time.
const POSE_WORDS: usize = 19;
/// Words of a force record: the `RawToolForce` (10 words), whether the proxy is given, its
/// position and orientation.
const FORCE_WORDS: usize = 18;

/// A proxy's pose: position (m) and orientation (unit quaternion `w, x, y, z`).
pub type ProxyPose = ([f64; 3], [f64; 4]);

/// A force the loop rendered, and the pose of the tool's proxy in the physics frame it came
/// from (the zenoh transport sends it beside the force; the shared-memory record has no room).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rendered {
    /// The force.
    pub force: RawToolForce,
    /// The proxy's pose, if the tool has one.
    pub proxy: Option<ProxyPose>,
}

/// How many pose sources (transports) may drive one tool.
pub const SOURCES: usize = 2;

/// Wakes the haptic thread from another thread.
pub type Waker = Box<dyn Fn() + Send + Sync>;

#[derive(Default)]
struct WakerCell(std::sync::OnceLock<Waker>);

impl std::fmt::Debug for WakerCell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.get().is_some() { "WakerCell(set)" } else { "WakerCell(unset)" })
    }
}

/// Counters the loop keeps; read by the server's status line and stats.
#[derive(Debug, Default)]
pub struct Counters {
    /// Forces computed.
    pub updates: AtomicU64,
    /// Poses used.
    pub poses: AtomicU64,
    /// Poses refused: not finite, not unit, negative gripper.
    pub invalid: AtomicU64,
    /// Poses refused: timestamp earlier than the tool's last.
    pub backwards: AtomicU64,
    /// Forces sent with the `STALE` flag.
    pub stale: AtomicU64,
    /// Forces clamped or rate-limited.
    pub clamped: AtomicU64,
    /// Poses refused: another session drives the tool.
    pub claimed: AtomicU64,
    /// Times a tool passed to another session after its driver fell silent.
    pub handovers: AtomicU64,
}

/// One tool's pose counts.
#[derive(Debug, Default)]
pub struct ToolCounts {
    /// Poses accepted (checked, in order, from the session driving the tool).
    pub poses: AtomicU64,
    /// Poses missing: gaps in the sequence numbers of a session's accepted stream, i.e. poses
    /// its driver sent that never arrived (dropped by the network, or sent while it was down).
    /// They are counted when the stream goes on, and never used: a pose that turned up after a
    /// newer one would go back in time and be refused.
    pub missing: AtomicU64,
}

/// What the haptic thread shares with the physics thread and the transports.
#[derive(Debug)]
pub struct LoopShared {
    snapshots: Vec<SnapshotCell>,
    /// Per tool, per source: the newest pose and its arrival (ns since `epoch`).
    poses: Vec<[SeqCell<POSE_WORDS>; SOURCES]>,
    /// Per tool, per source: the newest accepted pose's timestamp (written by the source's
    /// thread only).
    stamps: Vec<[AtomicU64; SOURCES]>,
    /// Per tool: the session driving it ([`driver`]; 0: none yet) and its last pose's arrival.
    drivers: Vec<(AtomicU64, AtomicU64)>,
    /// Per tool, per source: the newest accepted pose's driver and sequence number (written by
    /// the source's thread only), to count the poses a stream lost.
    sequences: Vec<[(AtomicU64, AtomicU64); SOURCES]>,
    /// Per tool: poses accepted, and poses missing from accepted streams.
    pub tool_counts: Vec<ToolCounts>,
    forces: Vec<SeqCell<FORCE_WORDS>>,
    /// The loop's clock's origin.
    epoch: Instant,
    thread: std::sync::OnceLock<Thread>,
    /// Wakes a loop whose [`LoopIo::wait`] does not park (set once, by the server).
    waker: WakerCell,
    stop: AtomicBool,
    /// How long a tool's poses may stop before its stream is over ([`HapticSettings::silence_ns`]).
    silence_ns: u64,
    /// The counters.
    pub counters: Counters,
    jitter: Histogram,
    /// What each update of the loop costs (its compute time, from the poses taken to the forces
    /// written).
    cost: Histogram,
    /// Every force sent, for a recorder ([`Self::log_forces`]).
    force_log: std::sync::OnceLock<Arc<crate::ForceLog>>,
}

impl LoopShared {
    /// Shared state for `tools` tools, for a loop with `settings` (whose staleness windows
    /// the pose hand-off keeps too).
    #[must_use]
    pub fn new(tools: usize, settings: &HapticSettings) -> Arc<Self> {
        Arc::new(Self {
            snapshots: (0..tools).map(|_| SnapshotCell::default()).collect(),
            poses: (0..tools).map(|_| Default::default()).collect(),
            stamps: (0..tools).map(|_| Default::default()).collect(),
            drivers: (0..tools).map(|_| Default::default()).collect(),
            sequences: (0..tools).map(|_| Default::default()).collect(),
            tool_counts: (0..tools).map(|_| ToolCounts::default()).collect(),
            forces: (0..tools).map(|_| SeqCell::default()).collect(),
            epoch: Instant::now(),
            thread: std::sync::OnceLock::new(),
            waker: WakerCell::default(),
            stop: AtomicBool::new(false),
            silence_ns: settings.silence_ns(),
            counters: Counters::default(),
            jitter: Histogram::default(),
            cost: Histogram::default(),
            force_log: std::sync::OnceLock::new(),
        })
    }

    /// The ring of sent forces, once [`Self::log_forces`] has made it.
    #[must_use]
    pub fn force_log(&self) -> Option<&Arc<crate::ForceLog>> {
        self.force_log.get()
    }

    /// From now on, the loop also appends every force it sends to a ring of `capacity` records
    /// for a recorder to take; the ring (the same one on a second call).
    pub fn log_forces(&self, capacity: usize) -> Arc<crate::ForceLog> {
        Arc::clone(self.force_log.get_or_init(|| Arc::new(crate::ForceLog::new(capacity))))
    }

    /// The number of tools.
    #[must_use]
    pub fn tools(&self) -> usize {
        self.snapshots.len()
    }

    /// Nanoseconds on the loop's clock.
    #[must_use]
    pub fn now_ns(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    /// The physics thread publishes tool `tool`'s snapshot (one writer: the physics thread).
    pub fn publish_snapshot(&self, tool: usize, snapshot: &ToolSnapshot) {
        if let Some(cell) = self.snapshots.get(tool) {
            cell.write(&snapshot.to_words());
        }
    }

    /// A transport's receiving thread hands over a pose for its tool from source `source` (one
    /// writer per source) and wakes the loop: [`Self::accept_pose`], then [`Self::wake`].
    pub fn offer_pose(&self, source: usize, pose: &RawToolPose) -> bool {
        let known = self.accept_pose(source, pose);
        self.wake();
        known
    }

    /// Stores a pose for its tool from source `source` (one writer per source) without waking
    /// the loop: what the haptic thread itself calls for the poses its [`LoopIo`] receives. The
    /// pose is checked here, where it enters, and only here: on the receiving thread, so that
    /// every refusal is counted even when a newer pose follows before the loop runs. An invalid
    /// one ([`check_pose`]) and one whose timestamp goes back in a live stream are counted and
    /// dropped; the loop and the physics read the [`CheckedPose`]s stored. Returns false for a
    /// tool id the scene lacks or a source out of range.
    pub fn accept_pose(&self, source: usize, pose: &RawToolPose) -> bool {
        let tool = pose.tool_id as usize;
        let (Some(cell), Some(stamp)) = (
            self.poses.get(tool).and_then(|cells| cells.get(source)),
            self.stamps.get(tool).and_then(|stamps| stamps.get(source)),
        ) else {
            return false;
        };
        let Ok(pose) = check_pose(pose) else {
            self.counters.invalid.fetch_add(1, Ordering::Relaxed);
            return true;
        };
        let now = self.now_ns();
        if !self.claim(tool, driver(source, pose.client), now) {
            self.counters.claimed.fetch_add(1, Ordering::Relaxed);
            return true;
        }
        // A live stream's timestamps must go forward; one silent for the whole fade may start
        // again from a new clock (a driver restarted).
        let live = cell.read().is_some_and(|(w, _)| now.saturating_sub(w[18]) < self.silence_ns);
        if live && pose.timestamp_ns < stamp.load(Ordering::Relaxed) {
            self.counters.backwards.fetch_add(1, Ordering::Relaxed);
            return true;
        }
        stamp.store(pose.timestamp_ns, Ordering::Relaxed);
        cell.write(&pose_words(&pose, now));
        self.count_pose(tool, source, driver(source, pose.client), pose.sequence);
        true
    }

    /// Counts an accepted pose and the poses its session's stream lost since its last one. A
    /// lower or equal number, or another session, starts a new stream (a driver restarted or
    /// the tool changed hands): nothing is counted missing for it.
    fn count_pose(&self, tool: usize, source: usize, id: u64, sequence: u64) {
        let counts = &self.tool_counts[tool];
        counts.poses.fetch_add(1, Ordering::Relaxed);
        let (last_id, last) = &self.sequences[tool][source];
        let previous = last.swap(sequence, Ordering::Relaxed);
        if last_id.swap(id, Ordering::Relaxed) == id && previous != 0 && sequence > previous + 1 {
            counts.missing.fetch_add(sequence - previous - 1, Ordering::Relaxed);
        }
    }

    /// Whether session `id` may drive tool `tool` at `now`: it does already, or nobody does,
    /// or its driver has been silent for the stale fade's length ([`HapticSettings::silence_ns`]), in
    /// which case the tool passes to `id`. Two sources may race for a free tool; the
    /// compare-exchange lets exactly one take it.
    fn claim(&self, tool: usize, id: u64, now: u64) -> bool {
        let (owner, seen) = &self.drivers[tool];
        let current = owner.load(Ordering::Acquire);
        if current != id {
            let silent = now.saturating_sub(seen.load(Ordering::Acquire)) >= self.silence_ns;
            if current != 0 && !silent {
                return false;
            }
            if owner.compare_exchange(current, id, Ordering::AcqRel, Ordering::Acquire).is_err() {
                return false;
            }
            if current != 0 {
                self.counters.handovers.fetch_add(1, Ordering::Relaxed);
            }
        }
        seen.fetch_max(now, Ordering::AcqRel);
        true
    }

    /// Wakes the loop: its waker if one is set, and the thread if it parks.
    pub fn wake(&self) {
        if let Some(w) = self.waker.0.get() {
            w();
        }
        if let Some(t) = self.thread.get() {
            t.unpark();
        }
    }

    /// Sets how other threads wake a loop whose [`LoopIo::wait`] does not park; returns false
    /// when one was set already.
    pub fn set_waker(&self, waker: Waker) -> bool {
        self.waker.0.set(waker).is_ok()
    }

    /// Tool `tool`'s newest pose from any source, checked where it entered, and when it
    /// arrived (ns on the loop's clock).
    #[must_use]
    pub fn newest_pose(&self, tool: usize) -> Option<(CheckedPose, u64)> {
        self.poses
            .get(tool)?
            .iter()
            .filter_map(|cell| cell.read().map(|(w, _)| pose_from_words(&w)))
            .max_by_key(|(_, arrived)| *arrived)
    }

    /// Tool `tool`'s newest force and how many have been written (for the transports).
    #[must_use]
    pub fn force(&self, tool: usize) -> Option<(Rendered, u64)> {
        let (w, version) = self.forces.get(tool)?.read()?;
        Some((force_from_words(&w), version))
    }

    /// Asks the loop to stop.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Release);
        self.wake();
    }

    /// The loop's period jitter so far: how far each tick's interval strayed from the period.
    #[must_use]
    pub fn jitter(&self) -> &Histogram {
        &self.jitter
    }

    /// What the loop's updates cost so far: each one's compute time, from taking the poses to
    /// writing the forces.
    #[must_use]
    pub fn cost(&self) -> &Histogram {
        &self.cost
    }
}

/// How the haptic thread waits and where its forces go. Its methods run on the haptic thread,
/// so they must not block (beyond `wait`'s timeout), lock or allocate.
pub trait LoopIo {
    /// Waits up to `timeout` for new poses, handing those it receives itself to
    /// [`LoopShared::accept_pose`]. The default parks: [`LoopShared::offer_pose`] unparks.
    fn wait(&mut self, shared: &LoopShared, timeout: Duration) {
        let _ = shared;
        std::thread::park_timeout(timeout);
    }

    /// The tools flagged in `tools` (bit `i`: tool `i`, the first 64) have new forces in
    /// [`LoopShared::force`].
    fn forces_ready(&mut self, shared: &LoopShared, tools: u64);
}

/// Parks, and sends the forces nowhere (tests, a loop whose forces are read by polling).
impl LoopIo for () {
    fn forces_ready(&mut self, _shared: &LoopShared, _tools: u64) {}
}

/// The haptic thread's state.
pub struct HapticLoop {
    shared: Arc<LoopShared>,
    renderers: Vec<Renderer>,
    /// Per tool, per source: the pose cell version last taken.
    seen: Vec<[u64; SOURCES]>,
    period: Duration,
}

impl HapticLoop {
    /// A loop over `shared`'s tools with `settings`.
    #[must_use]
    pub fn new(shared: Arc<LoopShared>, settings: HapticSettings) -> Self {
        let tools = shared.tools();
        Self {
            renderers: (0..tools).map(|t| Renderer::new(t as u32, settings)).collect(),
            seen: vec![[0; SOURCES]; tools],
            period: Duration::from_secs_f64(1.0 / settings.rate_hz),
            shared,
        }
    }

    /// Runs on the calling thread (name it `incise-haptics`) until [`LoopShared::stop`].
    pub fn run(mut self, io: &mut dyn LoopIo) {
        let shared = Arc::clone(&self.shared);
        let _ = shared.thread.set(std::thread::current());
        // Linux may wake a sleeping thread up to its timer slack late (50 µs by default), which
        // is jitter the period would carry; 1 µs is what a 1 kHz loop can use.
        #[cfg(target_os = "linux")]
        let _ = rustix::thread::set_current_timer_slack(std::num::NonZeroU64::new(1_000));
        let mut next = Instant::now() + self.period;
        let mut last_tick: Option<Instant> = None;
        while !shared.stop.load(Ordering::Acquire) {
            let now = Instant::now();
            let ticked = now >= next;
            if ticked {
                if let Some(last) = last_tick {
                    shared.jitter.record(now.duration_since(last).abs_diff(self.period));
                }
                last_tick = Some(now);
                // Keep to the schedule; after a long stall, start a new one from now.
                next += self.period;
                if next <= now {
                    next = now + self.period;
                }
            }
            let started = Instant::now();
            let updated = self.update(ticked);
            if updated != 0 {
                shared.cost.record(started.elapsed());
            }
            if updated != 0 {
                io.forces_ready(&shared, updated);
            }
            let now = Instant::now();
            if now < next {
                io.wait(&shared, next - now);
            }
        }
    }

    /// Takes new poses and renders: every tool on a tick, else the tools with a new pose.
    /// Returns the tools updated (bit per tool).
    pub fn update(&mut self, tick: bool) -> u64 {
        let shared = &self.shared;
        let now = shared.now_ns();
        let mut updated = 0u64;
        for tool in 0..self.renderers.len() {
            let mut fresh = false;
            for source in 0..SOURCES {
                let cell = &shared.poses[tool][source];
                if cell.version() == self.seen[tool][source] {
                    continue;
                }
                let Some((words, version)) = cell.read() else { continue };
                self.seen[tool][source] = version;
                let (pose, arrived) = pose_from_words(&words);
                self.renderers[tool].offer(arrived, &pose);
                fresh = true;
                shared.counters.poses.fetch_add(1, Ordering::Relaxed);
            }
            if !(tick || fresh) {
                continue;
            }
            let snapshot = shared.snapshots[tool].read().map(|(w, _)| ToolSnapshot::from_words(&w));
            let force = self.renderers[tool].force(now, snapshot.as_ref());
            let flags = force.flags;
            if flags & incise_protocol::v1::ForceFlag::Stale as u32 != 0 {
                shared.counters.stale.fetch_add(1, Ordering::Relaxed);
            }
            if flags & incise_protocol::v1::ForceFlag::Clamped as u32 != 0 {
                shared.counters.clamped.fetch_add(1, Ordering::Relaxed);
            }
            let proxy = snapshot.as_ref().and_then(|s| s.proxy);
            shared.forces[tool].write(&force_words(&Rendered { force, proxy }));
            if let Some(log) = shared.force_log.get() {
                let snapshot_frame = snapshot.as_ref().map_or(0, |s| s.frame);
                log.push(&crate::SentForce { force, snapshot_frame });
            }
            shared.counters.updates.fetch_add(1, Ordering::Relaxed);
            if tool < 64 {
                updated |= 1 << tool;
            }
        }
        updated
    }
}

/// Durations in a fixed histogram of `JITTER_BUCKETS` buckets of a microsecond (the last
/// holds everything beyond): the period's jitter, an update's cost.
#[derive(Debug)]
pub struct Histogram {
    buckets: Box<[AtomicU64]>,
    max_ns: AtomicU64,
}

const JITTER_BUCKETS: usize = 10_000;

impl Default for Histogram {
    fn default() -> Self {
        Self {
            buckets: (0..JITTER_BUCKETS).map(|_| AtomicU64::new(0)).collect(),
            max_ns: AtomicU64::new(0),
        }
    }
}

impl Histogram {
    fn record(&self, d: Duration) {
        let ns = u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        let bucket = ((ns / 1000) as usize).min(JITTER_BUCKETS - 1);
        self.buckets[bucket].fetch_add(1, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// Durations recorded.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.buckets.iter().map(|b| b.load(Ordering::Relaxed)).sum()
    }

    /// The `q` quantile (0–1) of the durations (µs, to the bucket's upper edge); `None` before
    /// the first.
    #[must_use]
    pub fn quantile_us(&self, q: f64) -> Option<f64> {
        let total = self.count();
        if total == 0 {
            return None;
        }
        let rank = ((q * total as f64).ceil() as u64).clamp(1, total);
        let mut seen = 0;
        for (i, b) in self.buckets.iter().enumerate() {
            seen += b.load(Ordering::Relaxed);
            if seen >= rank {
                return Some((i + 1) as f64);
            }
        }
        None
    }

    /// The largest duration (µs).
    #[must_use]
    pub fn max_us(&self) -> f64 {
        self.max_ns.load(Ordering::Relaxed) as f64 / 1000.0
    }
}

/// Who drives a tool: the pose's session and the transport it came over (never 0), so that
/// two clients without a session id on different transports are still told apart.
fn driver(source: usize, client: u32) -> u64 {
    u64::from(client) << 8 | (source as u64 + 1)
}

fn pose_words(p: &RawToolPose, arrived: u64) -> [u64; POSE_WORDS] {
    let mut w = [0u64; POSE_WORDS];
    w[0] = p.sequence;
    w[1] = p.timestamp_ns;
    let floats = p
        .position
        .iter()
        .chain(&p.orientation)
        .chain(&p.linear_velocity)
        .chain(&p.angular_velocity)
        .chain(std::iter::once(&p.gripper_angle));
    for (slot, v) in w[2..16].iter_mut().zip(floats) {
        *slot = v.to_bits();
    }
    w[16] = u64::from(p.tool_id) | u64::from(p.buttons) << 32;
    w[17] = u64::from(p.has) | u64::from(p.client) << 32;
    w[18] = arrived;
    w
}

/// A pose record as [`LoopShared::accept_pose`] wrote it: checked there.
fn pose_from_words(w: &[u64; POSE_WORDS]) -> (CheckedPose, u64) {
    let f = |k: usize| f64::from_bits(w[k]);
    let pose = RawToolPose {
        sequence: w[0],
        timestamp_ns: w[1],
        position: std::array::from_fn(|k| f(2 + k)),
        orientation: std::array::from_fn(|k| f(5 + k)),
        linear_velocity: std::array::from_fn(|k| f(9 + k)),
        angular_velocity: std::array::from_fn(|k| f(12 + k)),
        gripper_angle: f(15),
        tool_id: w[16] as u32,
        buttons: (w[16] >> 32) as u32,
        has: w[17] as u32,
        client: (w[17] >> 32) as u32,
    };
    (CheckedPose::restored(pose), w[18])
}

fn force_words(r: &Rendered) -> [u64; FORCE_WORDS] {
    let f = &r.force;
    let mut w = [0u64; FORCE_WORDS];
    w[0] = f.pose_sequence;
    w[1] = f.timestamp_ns;
    let floats = f.force.iter().chain(&f.torque).chain(std::iter::once(&f.gripper_force));
    for (slot, v) in w[2..9].iter_mut().zip(floats) {
        *slot = v.to_bits();
    }
    w[9] = u64::from(f.tool_id) | u64::from(f.flags) << 32;
    if let Some((p, q)) = &r.proxy {
        w[10] = 1;
        for (slot, v) in w[11..].iter_mut().zip(p.iter().chain(q)) {
            *slot = v.to_bits();
        }
    }
    w
}

fn force_from_words(w: &[u64; FORCE_WORDS]) -> Rendered {
    let f = |k: usize| f64::from_bits(w[k]);
    let force = RawToolForce {
        pose_sequence: w[0],
        timestamp_ns: w[1],
        force: std::array::from_fn(|k| f(2 + k)),
        torque: std::array::from_fn(|k| f(5 + k)),
        gripper_force: f(8),
        tool_id: w[9] as u32,
        flags: (w[9] >> 32) as u32,
    };
    let proxy = (w[10] != 0)
        .then(|| (std::array::from_fn(|k| f(11 + k)), std::array::from_fn(|k| f(14 + k))));
    Rendered { force, proxy }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "a faded or released force is exactly zero")]
mod tests {
    use super::*;
    use incise_protocol::v1::ForceFlag;

    #[test]
    fn poses_and_forces_survive_their_records() {
        let mut p = RawToolPose::at(7, [0.1, 0.2, 0.3]);
        p.sequence = 9;
        p.timestamp_ns = 11;
        p.linear_velocity = [1.0, 2.0, 3.0];
        p.gripper_angle = 0.4;
        p.buttons = 0xdead_beef;
        p.has = 1;
        assert_eq!(pose_from_words(&pose_words(&p, 42)), (CheckedPose::restored(p), 42));
        let force = RawToolForce {
            pose_sequence: 3,
            timestamp_ns: 4,
            force: [1.0, -2.0, 3.5],
            torque: [0.1, 0.2, 0.3],
            gripper_force: 0.7,
            tool_id: 2,
            flags: 5,
        };
        for proxy in [None, Some(([0.1, 0.2, 0.3], [0.5, 0.5, -0.5, 0.5]))] {
            let r = Rendered { force, proxy };
            assert_eq!(force_from_words(&force_words(&r)), r);
        }
    }

    /// One session drives a tool at a time: a second session's poses are refused and counted
    /// while the first's keep coming, on either transport; once the first has been silent for
    /// the fade, the tool passes to the second, whose poses are then the ones stored.
    #[test]
    fn a_second_session_cannot_take_a_driven_tool_until_its_driver_falls_silent() {
        let shared = LoopShared::new(1, &HapticSettings::default());
        let pose = |client, seq: u64| RawToolPose {
            sequence: seq,
            timestamp_ns: seq,
            client,
            ..RawToolPose::at(0, [0.0, 0.0, seq as f64 * 1e-3])
        };
        let newest = |shared: &LoopShared| shared.newest_pose(0).unwrap().0.sequence;
        assert!(shared.accept_pose(0, &pose(11, 1)));
        assert!(shared.accept_pose(0, &pose(22, 2)), "a known tool, though refused");
        assert!(shared.accept_pose(1, &pose(22, 3)), "nor over the other transport");
        assert_eq!(newest(&shared), 1);
        assert_eq!(shared.counters.claimed.load(Ordering::Relaxed), 2);
        assert!(shared.accept_pose(0, &pose(11, 4)));
        assert_eq!(newest(&shared), 4, "the driver goes on");
        // Session 11 falls silent for longer than the fade: 22 takes the tool.
        std::thread::sleep(Duration::from_nanos(shared.silence_ns) + Duration::from_millis(10));
        assert!(shared.accept_pose(1, &pose(22, 5)));
        assert_eq!(newest(&shared), 5);
        assert_eq!(shared.counters.handovers.load(Ordering::Relaxed), 1);
        assert!(shared.accept_pose(0, &pose(11, 6)));
        assert_eq!(newest(&shared), 5, "the old driver is now the second session");
        assert_eq!(shared.counters.claimed.load(Ordering::Relaxed), 3);
    }

    /// The thread answers each pose with a force that names it, renders the snapshot, fades
    /// when the poses stop, and counts refused poses; its ticks keep the period (the jitter is
    /// measured and printed, not asserted).
    #[test]
    fn gaps_in_a_stream_count_as_missing_and_a_new_stream_does_not() {
        let shared = LoopShared::new(1, &HapticSettings::default());
        let pose = |client, seq: u64, ts: u64| RawToolPose {
            sequence: seq,
            timestamp_ns: ts,
            client,
            ..RawToolPose::at(0, [0.0; 3])
        };
        let counts = |s: &LoopShared| {
            let c = &s.tool_counts[0];
            (c.poses.load(Ordering::Relaxed), c.missing.load(Ordering::Relaxed))
        };
        for seq in 1..=3 {
            shared.accept_pose(0, &pose(5, seq, seq));
        }
        assert_eq!(counts(&shared), (3, 0));
        // Poses 4 to 9 never arrived.
        shared.accept_pose(0, &pose(5, 10, 10));
        assert_eq!(counts(&shared), (4, 6));
        // A late one goes back in time: refused, not counted as arrived.
        shared.accept_pose(0, &pose(5, 7, 7));
        assert_eq!(counts(&shared), (4, 6));
        // A restarted driver (a new session, once the old one fell silent) numbers from 1.
        std::thread::sleep(Duration::from_nanos(shared.silence_ns + 1_000_000));
        shared.accept_pose(0, &pose(6, 1, 1));
        shared.accept_pose(0, &pose(6, 2, 2));
        assert_eq!(counts(&shared), (6, 6));
    }

    #[test]
    fn the_thread_answers_poses_and_fades_when_they_stop() {
        // Staleness is measured on the wall clock: a test thread descheduled for longer than
        // the default staleness window between two poses (a loaded machine) would see the
        // answer to the next one fading. Half a second keeps every answer whole; the fade is checked after it.
        let settings = HapticSettings {
            max_force_rate_n_per_s: 1e9,
            stale_after_ms: 500.0,
            ..HapticSettings::default()
        };
        let shared = LoopShared::new(1, &settings);
        let mut snap = ToolSnapshot {
            frame: 1,
            position: [0.0; 3],
            orientation: [1.0, 0.0, 0.0, 0.0],
            force: [0.0, 0.0, 1.0],
            torque: [0.0; 3],
            jacobian: [[0.0; 6]; 6],
            flags: ForceFlag::InContact as u32,
            proxy: Some(([0.0, 0.0, 0.002], [1.0, 0.0, 0.0, 0.0])),
        };
        snap.jacobian[2][2] = -500.0;
        shared.publish_snapshot(0, &snap);
        let handle = {
            let shared = Arc::clone(&shared);
            std::thread::Builder::new()
                .name("incise-haptics".into())
                .spawn(move || HapticLoop::new(shared, settings).run(&mut ()))
                .unwrap()
        };
        while shared.thread.get().is_none() {
            std::thread::sleep(Duration::from_millis(1));
        }
        for seq in 1..=20u64 {
            let mut p = RawToolPose::at(0, [0.0, 0.0, -0.001]);
            (p.sequence, p.timestamp_ns) = (seq, seq);
            assert!(shared.offer_pose(0, &p));
            let deadline = Instant::now() + Duration::from_secs(2);
            loop {
                if let Some((r, _)) = shared.force(0)
                    && r.force.pose_sequence == seq
                {
                    assert!((r.force.force[2] - 1.5).abs() < 1e-9, "{r:?}");
                    assert_eq!(r.proxy, snap.proxy, "the frame's proxy beside the force");
                    break;
                }
                assert!(Instant::now() < deadline, "pose {seq} never answered");
                std::thread::yield_now();
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut bad = RawToolPose::at(0, [f64::NAN, 0.0, 0.0]);
        bad.timestamp_ns = 100;
        assert!(shared.offer_pose(1, &bad));
        assert!(!shared.offer_pose(0, &RawToolPose::at(5, [0.0; 3])), "no tool 5");
        std::thread::sleep(Duration::from_millis(600));
        let (Rendered { force: f, .. }, _) = shared.force(0).unwrap();
        assert_eq!(f.force, [0.0; 3], "not faded 600 ms after the last pose: {f:?}");
        assert_ne!(f.flags & ForceFlag::Stale as u32, 0);
        shared.stop();
        handle.join().unwrap();
        assert_eq!(shared.counters.invalid.load(Ordering::Relaxed), 1);
        assert!(shared.counters.poses.load(Ordering::Relaxed) >= 20);
        let j = shared.jitter();
        println!(
            "{} ticks; period deviation p50 {:?} µs, p99 {:?} µs, max {:.0} µs",
            j.count(),
            j.quantile_us(0.5),
            j.quantile_us(0.99),
            j.max_us()
        );
        assert!(j.count() > 50);
    }
}
