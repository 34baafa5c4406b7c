//! Driving a tool at a fixed rate and timing every round trip.

use incise_protocol::raw::RawToolPose;
use incise_transport::Client;
use std::time::{Duration, Instant};

/// A tool pose a trajectory gives at a time: position (m), unit quaternion `w, x, y, z`,
/// gripper angle (rad).
pub type PoseAt = ([f64; 3], [f64; 4], f64);

/// What a drive measured.
#[derive(Clone, Debug, Default)]
pub struct Report {
    /// Poses sent.
    pub sent: u64,
    /// Round trips (µs) of the poses whose own force came back before the next pose was due,
    /// sorted.
    pub rtt_us: Vec<f64>,
    /// The largest force received (N).
    pub max_force_n: f64,
    /// Forces received (any pose's).
    pub forces: u64,
    /// Voxels the tool's forces said it cut in (frames flagged `CUTTING`).
    pub cutting_forces: u64,
}

impl Report {
    /// The `q` quantile (0–1) of the round trips (µs); `None` without any.
    #[must_use]
    pub fn quantile(&self, q: f64) -> Option<f64> {
        let n = self.rtt_us.len();
        (n > 0).then(|| self.rtt_us[((q * n as f64).ceil() as usize).clamp(1, n) - 1])
    }
}

/// One line: poses sent and answered, the round trip's p50, p99, p99.9 and max (µs), the largest
/// force.
impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let q = |x: f64| self.quantile(x).map_or("-".into(), |v| format!("{v:.0}"));
        write!(
            f,
            "{} poses, {} answered before the next was due; round trip p50 {} µs, p99 {} µs, p99.9 {} µs, max {} µs; max force {:.3} N",
            self.sent,
            self.rtt_us.len(),
            q(0.5),
            q(0.99),
            q(0.999),
            q(1.0),
            self.max_force_n
        )
    }
}

/// Sends tool `tool`'s pose `pose_at(t)` (t in seconds from the start) at `rate_hz` for
/// `duration`, waiting after each for the force that answers it until the next is due.
/// `on_force` sees every force received.
pub fn drive(
    client: &Client,
    tool: u32,
    rate_hz: f64,
    duration: Duration,
    mut pose_at: impl FnMut(f64) -> PoseAt,
    mut on_force: impl FnMut(&incise_protocol::raw::RawToolForce),
) -> Report {
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let start = Instant::now();
    let mut next = start;
    let mut report = Report::default();
    let mut sequence = 0u64;
    while start.elapsed() < duration {
        sequence += 1;
        let (position, orientation, gripper_angle) = pose_at(start.elapsed().as_secs_f64());
        let pose = RawToolPose {
            sequence,
            timestamp_ns: start.elapsed().as_nanos() as u64,
            orientation,
            gripper_angle,
            ..RawToolPose::at(tool, position)
        };
        let sent = Instant::now();
        next += period;
        if client.send_pose(&pose).is_ok() {
            report.sent += 1;
            while let Some(left) = next.checked_duration_since(Instant::now()) {
                let Some(force) = client.recv_force(left) else { break };
                report.forces += 1;
                on_force(&force);
                let n = force.force.iter().map(|c| c * c).sum::<f64>().sqrt();
                report.max_force_n = report.max_force_n.max(n);
                if force.flags & incise_protocol::v1::ForceFlag::Cutting as u32 != 0 {
                    report.cutting_forces += 1;
                }
                if force.pose_sequence == sequence {
                    report.rtt_us.push(sent.elapsed().as_secs_f64() * 1e6);
                    break;
                }
            }
        }
        if let Some(left) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(left);
        } else if next.elapsed() > 10 * period {
            // Far behind (a stall): a new schedule from now, not a burst to catch up.
            next = Instant::now();
        }
    }
    report.rtt_us.sort_by(f64::total_cmp);
    report
}
