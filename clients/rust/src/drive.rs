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
    /// Round trips of the poses whose force came back (the first force answering each), however
    /// late.
    pub rtt_us: RoundTrips,
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
        self.rtt_us.quantile(q)
    }
}

/// Round trips in a histogram of fixed size, so that a drive of any length holds the same
/// memory (a sorted list of every round trip grew by 8 MB an hour at 1 kHz): 0.1 µs buckets
/// to 100 µs (shared memory's round trips), 1 µs to 10 ms (the network's), 100 µs to 1 s;
/// the largest is kept exactly.
#[derive(Clone, Debug)]
pub struct RoundTrips {
    counts: Vec<u32>,
    count: u64,
    max_us: f64,
}

/// The buckets' edges: (upper end of a range in µs, bucket width in µs).
const RANGES: [(f64, f64); 3] = [(100.0, 0.1), (10_000.0, 1.0), (1_000_000.0, 100.0)];

/// Each range's lower end (µs), bucket width (µs), first bucket and bucket count.
fn ranges() -> impl Iterator<Item = (f64, f64, usize, usize)> {
    RANGES.iter().scan((0.0, 0), |(low, first), &(high, width)| {
        let n = ((high - *low) / width).round() as usize;
        let range = (*low, width, *first, n);
        (*low, *first) = (high, *first + n);
        Some(range)
    })
}

impl Default for RoundTrips {
    fn default() -> Self {
        let buckets: usize = ranges().map(|(.., n)| n).sum();
        // One more for everything past the last range.
        Self { counts: vec![0; buckets + 1], count: 0, max_us: 0.0 }
    }
}

impl RoundTrips {
    /// The bucket `us` falls in.
    fn bucket(us: f64) -> usize {
        let mut past = 0;
        for (low, width, first, n) in ranges() {
            if us < low + n as f64 * width {
                return first + (((us - low).max(0.0) / width) as usize).min(n - 1);
            }
            past = first + n;
        }
        past
    }

    /// The upper edge of bucket `b` (µs).
    fn upper(b: usize) -> f64 {
        ranges()
            .find(|&(_, _, first, n)| b < first + n)
            .map_or(f64::INFINITY, |(low, width, first, _)| low + (b - first + 1) as f64 * width)
    }

    /// Counts a round trip of `us` microseconds.
    pub fn record(&mut self, us: f64) {
        let b = Self::bucket(us);
        self.counts[b] = self.counts[b].saturating_add(1);
        self.count += 1;
        self.max_us = self.max_us.max(us);
    }

    /// The non-empty buckets, `(bucket, count)`: the histogram in a form another process can
    /// read back with [`Self::add_buckets`] (pooling several clients' round trips).
    #[must_use]
    pub fn buckets(&self) -> Vec<(usize, u32)> {
        self.counts.iter().enumerate().filter(|(_, c)| **c > 0).map(|(b, c)| (b, *c)).collect()
    }

    /// Adds another histogram's [`Self::buckets`] and its largest round trip (µs); buckets
    /// out of range are ignored.
    pub fn add_buckets(&mut self, buckets: &[(usize, u32)], max_us: f64) {
        for &(b, c) in buckets {
            if let Some(slot) = self.counts.get_mut(b) {
                *slot = slot.saturating_add(c);
                self.count += u64::from(c);
            }
        }
        self.max_us = self.max_us.max(max_us);
    }

    /// Round trips counted.
    #[must_use]
    pub fn len(&self) -> u64 {
        self.count
    }

    /// No round trip counted.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The `q` quantile (0–1), to its bucket's upper edge and at most the largest round trip
    /// (µs); `None` without any.
    #[must_use]
    pub fn quantile(&self, q: f64) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let rank = ((q * self.count as f64).ceil() as u64).clamp(1, self.count);
        let mut seen = 0;
        for (b, &c) in self.counts.iter().enumerate() {
            seen += u64::from(c);
            if seen >= rank {
                return Some(Self::upper(b).min(self.max_us));
            }
        }
        Some(self.max_us)
    }
}

/// One line: poses sent and answered, the round trip's p50, p99, p99.9 and max (µs), the largest
/// force.
impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let q = |x: f64| self.quantile(x).map_or("-".into(), |v| format!("{v:.0}"));
        write!(
            f,
            "{} poses, {} answered; round trip p50 {} µs, p99 {} µs, p99.9 {} µs, max {} µs; max force {:.3} N",
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

/// How many recent poses a drive remembers the send time of: a force answering an older one
/// (more than a second late at 1 kHz) is not timed.
const TIMED_POSES: usize = 1024;

/// Sends tool `tool`'s pose `pose_at(t)` (t in seconds from the start) at `rate_hz` for
/// `duration`, waiting after each for forces until the next is due, and never faster than
/// `rate_hz`: a period missed while this process was not running is skipped, not made up. Every pose whose force
/// comes back is timed, however late (the first force answering it: the haptic loop repeats a
/// pose's force until a newer pose arrives), so a loaded machine's round trips are measured,
/// not cut off at the pose period. `on_force` sees every force received.
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
    // When each recent pose was sent, by sequence number modulo the ring's size.
    let mut sent_at = vec![(0u64, start); TIMED_POSES];
    let mut last_timed = 0u64;
    let mut take = |force: &incise_protocol::raw::RawToolForce,
                    report: &mut Report,
                    sent_at: &[(u64, Instant)]| {
        report.forces += 1;
        on_force(force);
        let n = force.force.iter().map(|c| c * c).sum::<f64>().sqrt();
        report.max_force_n = report.max_force_n.max(n);
        if force.flags & incise_protocol::v1::ForceFlag::Cutting as u32 != 0 {
            report.cutting_forces += 1;
        }
        let s = force.pose_sequence;
        let (seq, at) = sent_at[(s % TIMED_POSES as u64) as usize];
        if s > last_timed && seq == s {
            last_timed = s;
            report.rtt_us.record(at.elapsed().as_secs_f64() * 1e6);
        }
    };
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
        next += period;
        sent_at[(sequence % TIMED_POSES as u64) as usize] = (sequence, Instant::now());
        if client.send_pose(&pose).is_ok() {
            report.sent += 1;
        }
        while let Some(left) = next.checked_duration_since(Instant::now()) {
            let Some(force) = client.recv_force(left) else { break };
            take(&force, &mut report, &sent_at);
            if force.pose_sequence == sequence {
                break;
            }
        }
        if let Some(left) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(left);
        } else {
            // Behind (this process was not scheduled in time): the missed periods are dropped
            // and the schedule restarts from now. Catching up would send poses back to back,
            // faster than the device's rate, and the haptic loop answers only the newest of
            // those it finds waiting, so the rest would go unanswered.
            next = Instant::now();
        }
    }
    // The last poses' forces, still on their way.
    let until = Instant::now() + Duration::from_millis(100);
    while let Some(left) = until.checked_duration_since(Instant::now()) {
        let Some(force) = client.recv_force(left) else { break };
        take(&force, &mut report, &sent_at);
        if force.pose_sequence == sequence {
            break;
        }
    }
    report
}

#[cfg(test)]
mod tests {
    use super::RoundTrips;

    /// Each quantile is the exact one rounded up to its bucket's edge: never below it, and
    /// above it by less than the bucket's width there (0.1 µs, 1 µs or 100 µs).
    #[test]
    fn quantiles_are_within_a_bucket_of_the_exact_ones() {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut exact = Vec::new();
        let mut trips = RoundTrips::default();
        for i in 0..20_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let unit = (state >> 11) as f64 / (1u64 << 53) as f64;
            // Spread over every range, the last one's tail included.
            let us = match i % 4 {
                0 => unit * 100.0,
                1 => 100.0 + unit * 9_900.0,
                2 => 10_000.0 + unit * 990_000.0,
                _ => unit * 2_000_000.0,
            };
            exact.push(us);
            trips.record(us);
        }
        exact.sort_by(f64::total_cmp);
        assert_eq!(trips.len(), 20_000);
        for q in [0.0, 0.01, 0.25, 0.5, 0.75, 0.9, 0.99, 0.999, 1.0] {
            let n = exact.len();
            let want = exact[((q * n as f64).ceil() as usize).clamp(1, n) - 1];
            let got = trips.quantile(q).unwrap();
            let width = if want < 100.0 {
                0.1
            } else if want < 10_000.0 {
                1.0
            } else if want < 1_000_000.0 {
                100.0
            } else {
                f64::INFINITY
            };
            assert!(got >= want && got - want <= width + 1e-9, "q {q}: {got} for {want}");
        }
        assert_eq!(trips.quantile(1.0), Some(exact[exact.len() - 1]));
        assert_eq!(RoundTrips::default().quantile(0.5), None);
    }

    /// Two histograms pooled through their buckets give the histogram of both samples.
    #[test]
    fn pooled_buckets_equal_one_histogram_of_everything() {
        let (mut a, mut b, mut both) =
            (RoundTrips::default(), RoundTrips::default(), RoundTrips::default());
        for i in 0..5000 {
            let us = f64::from(i) * 0.37 + f64::from(i % 7) * 900.0;
            if i % 3 == 0 { &mut a } else { &mut b }.record(us);
            both.record(us);
        }
        let mut pooled = RoundTrips::default();
        pooled.add_buckets(&a.buckets(), a.quantile(1.0).unwrap());
        pooled.add_buckets(&b.buckets(), b.quantile(1.0).unwrap());
        assert_eq!(pooled.len(), both.len());
        for q in [0.0, 0.5, 0.9, 0.99, 0.999, 1.0] {
            assert_eq!(pooled.quantile(q), both.quantile(q), "q {q}");
        }
    }
}
