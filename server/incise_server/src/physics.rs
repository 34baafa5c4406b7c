//! The physics thread: steps the simulation in real time with each tool's newest pose, hands
//! the haptic loop every tool's contact linearised at the new frame, publishes the frame's
//! statistics and cuts, and hands the recorder (when recording) each frame's record.

use crate::network::{Outbox, Outgoing};
use incise_convert::frame::{cut_event, frame_record, frame_stats, tool_flags};
use incise_convert::tools::tool_input;
use incise_haptics::{LoopShared, ToolSnapshot};
use incise_protocol::raw::RawToolPose;
use incise_record::{Record, RecordHandle, SurfaceFrame};
use incise_sim::{Frame, Simulation, StepInputs, ToolInput};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// What the physics thread counts (read by the status line and the demo's summary).
#[derive(Debug, Default)]
pub struct PhysicsStats {
    /// Frames stepped.
    pub frames: AtomicU64,
    /// Frames that ended after their wall-clock deadline.
    pub late: AtomicU64,
    /// Steps that failed (logged; the previous state is kept).
    pub step_errors: AtomicU64,
    /// Voxels removed (or tetrahedra) by the tools.
    pub removed: AtomicU64,
    /// The last frame's wall time (µs).
    pub last_frame_us: AtomicU64,
    /// Each tool's last force magnitude (µN) and the largest so far (µN).
    pub tool_force_un: [AtomicU64; 8],
    /// See `tool_force_un`.
    pub max_force_un: AtomicU64,
}

/// The most tools whose force the statistics keep.
const TRACKED: usize = 8;

/// Steps `sim` every `dt` of wall time until `stop`; when recording, hands the recorder every
/// frame and the surface at `geometry`'s times.
pub fn run(
    mut sim: Simulation,
    shared: &LoopShared,
    outbox: &Outbox,
    recorder: Option<(&RecordHandle, GeometryClock)>,
    stats: &PhysicsStats,
    stop: &AtomicBool,
) {
    let (recorder, mut geometry) = recorder.unzip();
    let dt = Duration::from_secs_f64(sim.config().dt());
    let tools = shared.tools();
    let mut next = Instant::now();
    let mut last_warning: Option<Instant> = None;
    let second = Instant::now();
    let mut frames_in_second = (second, 0u64, 0.0f64);
    while !stop.load(Ordering::Acquire) {
        let started = Instant::now();
        let (inputs, used) = newest_poses(shared, tools);
        let inputs = StepInputs { tools: inputs, ..StepInputs::default() };
        match sim.step(&inputs) {
            Ok(frame) => {
                hand_over(&frame, shared, stats);
                let elapsed = started.elapsed();
                stats.last_frame_us.store(elapsed.as_micros() as u64, Ordering::Relaxed);
                let n = stats.frames.fetch_add(1, Ordering::Relaxed) + 1;
                // Frames per second of wall time, over the last second.
                let (since, at, rate) = &mut frames_in_second;
                if since.elapsed() >= Duration::from_secs(1) {
                    *rate = (n - *at) as f64 / since.elapsed().as_secs_f64();
                    (*since, *at) = (Instant::now(), n);
                }
                let frame_stats = frame_stats(&frame, &sim, elapsed, *rate);
                if let Some(recorder) = recorder {
                    let record = frame_record(&frame, &used, frame_stats);
                    recorder.record(Record::Frame(record));
                    record_state(recorder, &sim, &frame);
                    if let Some(surface) =
                        geometry.as_mut().and_then(|clock| clock.surface(&sim, &frame))
                    {
                        recorder.record(Record::Surface(surface));
                    }
                }
                outbox.post(Outgoing::Frame(frame_stats));
                for cut in &frame.surgical.cuts {
                    let cut = cut_event(&frame, cut);
                    if let Some(recorder) = recorder {
                        recorder.record(Record::Cut(cut, frame.time));
                    }
                    outbox.post(Outgoing::Cut(cut));
                }
            }
            Err(e) => {
                stats.step_errors.fetch_add(1, Ordering::Relaxed);
                // At most one message a second: a client that sends bad input every frame must
                // not flood the log.
                if last_warning.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
                    tracing::warn!("physics step refused its inputs: {e}");
                    last_warning = Some(Instant::now());
                }
            }
        }
        next += dt;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            stats.late.fetch_add(1, Ordering::Relaxed);
            // Far behind (a stall): start the schedule again instead of racing to catch up.
            if now - next > 10 * dt {
                next = now;
            }
        }
    }
}

/// Simulated time between two whole surfaces in a recording (s): the state keyframes' interval,
/// so a viewer seeking to a time finds the topology where a replay finds the state.
pub use incise_sim::KEYFRAME_INTERVAL_S;

/// The default rate at which a recording takes the organ's surface (Hz of simulated time).
pub const DEFAULT_GEOMETRY_HZ: f64 = 60.0;

/// When a recording takes the organ's surface: whole on the first frame and once a
/// [`KEYFRAME_INTERVAL_S`]; every vertex's position at a rate of simulated time; and each
/// topology change on the frame that made it (its new triangles and vertices, the freed ids).
#[derive(Clone, Debug)]
pub struct GeometryClock {
    /// Simulated seconds between two takes of every position.
    interval: f64,
    /// When the next take of every position, and the next keyframe, are due (simulated s).
    next_positions: f64,
    next_keyframe: f64,
}

impl GeometryClock {
    /// A clock taking every vertex's position `hz` times a second of simulated time (0: only
    /// on keyframes; topology changes are taken all the same).
    #[must_use]
    pub fn new(hz: f64) -> Self {
        let interval = if hz > 0.0 { 1.0 / hz } else { f64::INFINITY };
        Self { interval, next_positions: 0.0, next_keyframe: 0.0 }
    }

    /// The surface frame after `frame`, when one is due.
    pub fn surface(&mut self, sim: &Simulation, frame: &Frame) -> Option<SurfaceFrame> {
        // A microsecond's slack keeps float round-off from slipping a tick by a frame.
        let t = frame.time + 1e-6;
        let changes = &frame.surgical.surface;
        let keyframe = t >= self.next_keyframe;
        // At 0 Hz there is no tick at all (only keyframes and topology changes).
        let tick = self.interval.is_finite() && t >= self.next_positions;
        if !(keyframe || tick || !changes.is_empty()) {
            return None;
        }
        if keyframe {
            self.next_keyframe = (self.next_keyframe + KEYFRAME_INTERVAL_S).max(frame.time);
        }
        if tick {
            self.next_positions = (self.next_positions + self.interval).max(frame.time);
        }
        let g = if keyframe {
            sim.surface_geometry(None, None)?
        } else {
            // Every position on a tick; the new vertices' alone on a change between ticks.
            let vertices = (!tick).then_some(&changes.vertices_added[..]);
            sim.surface_geometry(vertices, Some(&changes.triangles_added))?
        };
        let triangles = g
            .triangle_ids
            .iter()
            .zip(&g.triangles)
            .zip(&g.triangle_labels)
            .map(|((&id, &t), &l)| (id, t, l))
            .collect();
        Some(SurfaceFrame {
            frame: frame.index,
            sim_time_s: frame.time,
            whole: keyframe,
            vertex_ids: g.vertex_ids,
            positions: g.positions,
            triangles,
            removed_triangles: if keyframe {
                Vec::new()
            } else {
                changes.triangles_removed.clone()
            },
            removed_vertices: if keyframe { Vec::new() } else { changes.vertices_removed.clone() },
        })
    }
}

/// Each tool's newest pose (checked where it entered: the haptic loop's hand-off keeps only
/// usable ones), and the poses as received (for the recording).
fn newest_poses(shared: &LoopShared, tools: usize) -> (Vec<ToolInput>, Vec<RawToolPose>) {
    (0..tools)
        .filter_map(|tool| {
            let (pose, _) = shared.newest_pose(tool)?;
            Some((tool_input(&pose), *pose.raw()))
        })
        .unzip()
}

/// Hands the recorder what a replay needs beyond `frame`'s record: the topology change it made,
/// and the keyframe when it is a keyframe frame ([`Simulation::is_keyframe`]).
pub fn record_state(recorder: &RecordHandle, sim: &Simulation, frame: &Frame) {
    if let Some(edit) = incise_convert::keyframe::edit_message(frame) {
        recorder.record(Record::Edit(edit, frame.time));
    }
    if sim.is_keyframe(frame.index) {
        let keyframe = incise_convert::keyframe::keyframe_message(&sim.keyframe());
        recorder.record(Record::Keyframe(Box::new(keyframe), frame.time));
    }
}

/// Every tool's snapshot to the haptic loop, and the tool statistics.
fn hand_over(frame: &Frame, shared: &LoopShared, stats: &PhysicsStats) {
    for (i, tool) in frame.surgical.tools.iter().enumerate() {
        let Some(pose) = tool.pose else { continue };
        let lin = &tool.linearisation;
        let flags = tool_flags(frame, i);
        shared.publish_snapshot(
            i,
            &ToolSnapshot {
                frame: frame.index,
                position: pose.pose().position(),
                orientation: pose.pose().rotation(),
                force: lin.force,
                torque: lin.torque,
                jacobian: lin.jacobian,
                flags,
                proxy: tool.proxy.map(|p| (p.position(), p.rotation())),
            },
        );
        let un = (lin.force.iter().map(|c| c * c).sum::<f64>().sqrt() * 1e6) as u64;
        if i < TRACKED {
            stats.tool_force_un[i].store(un, Ordering::Relaxed);
        }
        stats.max_force_un.fetch_max(un, Ordering::Relaxed);
    }
    let removed = frame.counters.voxels_removed + frame.counters.tets_removed;
    stats.removed.fetch_add(removed as u64, Ordering::Relaxed);
}

#[cfg(test)]
mod tests {
    use super::GeometryClock;
    use incise_sim::{SceneConfig, Simulation, StepInputs};

    /// A 2 cm block with a tool (never posed: the surface is there, nothing changes it).
    const SCENE: &str = r#"name = "clock"
[volume]
procedural = "block"
size_m = [0.02, 0.02, 0.02]
voxels = [2, 2, 2]
[[materials]]
label = 1
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[integrator]
kind = "implicit-euler"
dt = 0.001
[[fixed]]
plane = "z"
value = 0.0
[[tools]]
name = "probe"
stiffness = 100.0
outer = { shape = "sphere", radius = 0.002 }
"#;

    /// The surface frames a clock at `hz` takes over `frames` frames: (frame, whole).
    fn taken(hz: f64, frames: u64) -> Vec<(u64, bool)> {
        let config = SceneConfig::from_toml(SCENE, "clock.toml").unwrap();
        let volume = config.procedural_volume().unwrap();
        let mut sim = Simulation::new(&config, &volume, "clock.toml").unwrap();
        let mut clock = GeometryClock::new(hz);
        (0..frames)
            .filter_map(|_| {
                let frame = sim.step(&StepInputs::default()).unwrap();
                clock.surface(&sim, &frame).map(|s| (s.frame, s.whole))
            })
            .collect()
    }

    #[test]
    fn at_zero_hz_only_the_keyframes_take_the_surface() {
        assert_eq!(taken(0.0, 2100), [(1, true), (1000, true), (2000, true)]);
    }

    #[test]
    fn at_a_rate_the_positions_are_taken_on_its_ticks_and_whole_on_the_keyframes() {
        let taken = taken(100.0, 2100);
        // Ticks every 10 ms from the first frame; the keyframes at 1 s and 2 s fall on ticks.
        let expected: Vec<(u64, bool)> = std::iter::once((1, true))
            .chain((10..=2100).step_by(10).map(|f| (f, f % 1000 == 0)))
            .collect();
        assert_eq!(taken, expected);
    }
}
