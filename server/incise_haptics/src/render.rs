//! One tool's haptic force between physics frames (see the crate's documentation for the five
//! steps). A pure function of the poses offered, the snapshots given and a nanosecond clock, so
//! it is tested without threads or sleeps.

use crate::snapshot::ToolSnapshot;
use incise_protocol::check::CheckedPose;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_protocol::v1::ForceFlag;

/// The haptic loop's limits for a device.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HapticSettings {
    /// Updates per second when no pose drives them (Hz).
    pub rate_hz: f64,
    /// The largest force sent (N): the device's continuous maximum.
    pub max_force_n: f64,
    /// The largest torque sent (N·m).
    pub max_torque_nm: f64,
    /// How fast the force may change (N/s).
    pub max_force_rate_n_per_s: f64,
    /// Without a valid pose for this long, the force starts to fade (ms).
    pub stale_after_ms: f64,
    /// And reaches zero this much later (ms). Once it has, the stream is over
    /// ([`Self::silence_ns`]).
    pub fade_ms: f64,
    /// Whether the passivity controller runs.
    pub passivity: bool,
}

impl Default for HapticSettings {
    /// A desktop device (about 8 N continuous); the force is zero at most 50 ms after the last
    /// valid pose.
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            max_force_n: 8.0,
            max_torque_nm: 0.5,
            max_force_rate_n_per_s: 4000.0,
            stale_after_ms: 10.0,
            fade_ms: 40.0,
            passivity: true,
        }
    }
}

impl HapticSettings {
    /// How long a tool's poses may stop before its stream is over (ns): the stale wait and the
    /// fade together. The one window everything that judges a silent driver keeps: by then its
    /// force has faded out, another session may take the tool, and its timestamps may start
    /// again from a new clock.
    #[must_use]
    pub fn silence_ns(&self) -> u64 {
        ((self.stale_after_ms + self.fade_ms) * 1e6) as u64
    }
}

/// One tool's renderer.
#[derive(Clone, Debug)]
pub struct Renderer {
    settings: HapticSettings,
    tool_id: u32,
    /// The newest valid pose and when it arrived (the loop's clock, ns).
    pose: Option<(RawToolPose, u64)>,
    /// The position the passivity observer last saw.
    observed: Option<[f64; 3]>,
    /// Energy the rendered force has taken from the hand (J); kept ≥ 0.
    energy: f64,
    /// The last force and torque sent, and when.
    sent: ([f64; 3], [f64; 3], Option<u64>),
    /// The force and torque when fading began.
    fade_from: ([f64; 3], [f64; 3]),
}

impl Renderer {
    /// A renderer for tool `tool_id`.
    #[must_use]
    pub fn new(tool_id: u32, settings: HapticSettings) -> Self {
        Self {
            settings,
            tool_id,
            pose: None,
            observed: None,
            energy: 0.0,
            sent: ([0.0; 3], [0.0; 3], None),
            fade_from: ([0.0; 3], [0.0; 3]),
        }
    }

    /// The newest valid pose.
    #[must_use]
    pub fn pose(&self) -> Option<&RawToolPose> {
        self.pose.as_ref().map(|p| &p.0)
    }

    /// Takes the tool's newest pose, which arrived at `now_ns`: checked and in order, as
    /// `LoopShared::accept_pose` keeps them.
    pub fn offer(&mut self, now_ns: u64, pose: &CheckedPose) {
        self.pose = Some((*pose.raw(), now_ns));
    }

    /// The force to send at `now_ns`, from the newest pose and `snapshot` (the last physics
    /// frame's, if any).
    pub fn force(&mut self, now_ns: u64, snapshot: Option<&ToolSnapshot>) -> RawToolForce {
        let s = self.settings;
        let mut flags = 0u32;
        let Some((pose, arrived)) = self.pose else {
            return self.out(now_ns, 0, [0.0; 3], [0.0; 3], ForceFlag::Stale as u32);
        };
        let age_ms = now_ns.saturating_sub(arrived) as f64 * 1e-6;
        if age_ms > s.stale_after_ms {
            // Fading: from what was sent when the poses stopped, down to zero; the passivity
            // observer starts afresh with the next pose.
            if self.observed.take().is_some() {
                self.fade_from = (self.sent.0, self.sent.1);
                self.energy = 0.0;
            }
            let left = (1.0 - (age_ms - s.stale_after_ms) / s.fade_ms).clamp(0.0, 1.0);
            let (f, t) = (self.fade_from.0.map(|c| c * left), self.fade_from.1.map(|c| c * left));
            return self.out(now_ns, pose.sequence, f, t, ForceFlag::Stale as u32);
        }
        let (mut f, mut t) = match snapshot {
            Some(snap) => {
                flags |= snap.flags;
                extrapolate(snap, &pose)
            }
            None => ([0.0; 3], [0.0; 3]),
        };
        if clamp_norm(&mut f, s.max_force_n) | clamp_norm(&mut t, s.max_torque_nm) {
            flags |= ForceFlag::Clamped as u32;
        }
        if s.passivity {
            f = self.keep_passive(pose.position, f);
            if clamp_norm(&mut f, s.max_force_n) {
                flags |= ForceFlag::Clamped as u32;
            }
        }
        if let Some(before) = self.sent.2 {
            let dt = now_ns.saturating_sub(before) as f64 * 1e-9;
            let step = s.max_force_rate_n_per_s * dt;
            let mut change: [f64; 3] = std::array::from_fn(|k| f[k] - self.sent.0[k]);
            if clamp_norm(&mut change, step) {
                f = std::array::from_fn(|k| self.sent.0[k] + change[k]);
                flags |= ForceFlag::Clamped as u32;
            }
        }
        self.out(now_ns, pose.sequence, f, t, flags)
    }

    /// The passivity observer and controller. The observer adds up the energy the force sent
    /// over each interval took from the hand, `−F·δx`. The controller looks one interval ahead:
    /// if the new force, acting over a motion like the last one, would bring the total below
    /// zero (the force giving back more than it took), it gains a damping term along the motion
    /// that brings the prediction back to zero.
    fn keep_passive(&mut self, position: [f64; 3], f: [f64; 3]) -> [f64; 3] {
        let Some(before) = self.observed.replace(position) else { return f };
        let dx: [f64; 3] = std::array::from_fn(|k| position[k] - before[k]);
        self.energy = (self.energy - dot(&self.sent.0, &dx)).max(0.0);
        let moved = dot(&dx, &dx);
        let predicted = self.energy - dot(&f, &dx);
        if predicted >= 0.0 || moved == 0.0 {
            return f;
        }
        let gain = predicted / moved;
        std::array::from_fn(|k| f[k] + gain * dx[k])
    }

    fn out(
        &mut self,
        now_ns: u64,
        pose_sequence: u64,
        force: [f64; 3],
        torque: [f64; 3],
        flags: u32,
    ) -> RawToolForce {
        // The inputs are checked and the snapshots finite, but a force is only ever sent finite.
        let finite = force.iter().chain(&torque).all(|c| c.is_finite());
        let (force, torque) = if finite { (force, torque) } else { ([0.0; 3], [0.0; 3]) };
        self.sent = (force, torque, Some(now_ns));
        RawToolForce {
            pose_sequence,
            timestamp_ns: now_ns,
            force,
            torque,
            gripper_force: 0.0,
            tool_id: self.tool_id,
            flags,
        }
    }
}

/// How far from the frame's pose the linearisation is trusted: a pose farther than this (the
/// physics has not caught up with a jump) is evaluated at this distance along the same
/// direction, so a stale frame cannot turn into a large made-up force.
const TRUST_DISTANCE_M: f64 = 0.005;
/// The same for the rotation (rad).
const TRUST_ANGLE_RAD: f64 = 0.1;

/// The snapshot's force and torque at `pose`, to first order; zero where the force would turn
/// against the frame's (the tool has left the contact: a contact only pushes).
fn extrapolate(s: &ToolSnapshot, pose: &RawToolPose) -> ([f64; 3], [f64; 3]) {
    let mut dt: [f64; 3] = std::array::from_fn(|k| pose.position[k] - s.position[k]);
    let mut dtheta = rotation_vector(&pose.orientation, &s.orientation);
    clamp_norm(&mut dt, TRUST_DISTANCE_M);
    clamp_norm(&mut dtheta, TRUST_ANGLE_RAD);
    let d = [dt[0], dt[1], dt[2], dtheta[0], dtheta[1], dtheta[2]];
    let row = |r: usize| (0..6).map(|c| s.jacobian[r][c] * d[c]).sum::<f64>();
    let f: [f64; 3] = std::array::from_fn(|k| s.force[k] + row(k));
    let t: [f64; 3] = std::array::from_fn(|k| s.torque[k] + row(3 + k));
    if dot(&f, &s.force) <= 0.0 { ([0.0; 3], [0.0; 3]) } else { (f, t) }
}

/// The rotation vector (rad, grid frame) of `q · p⁻¹`: the turn from `p` to `q`.
fn rotation_vector(q: &[f64; 4], p: &[f64; 4]) -> [f64; 3] {
    // q · conj(p), both unit, scalar first.
    let (w1, v1) = (q[0], [q[1], q[2], q[3]]);
    let (w2, v2) = (p[0], [-p[1], -p[2], -p[3]]);
    let mut w = w1 * w2 - dot(&v1, &v2);
    let c = [
        v1[1] * v2[2] - v1[2] * v2[1],
        v1[2] * v2[0] - v1[0] * v2[2],
        v1[0] * v2[1] - v1[1] * v2[0],
    ];
    let mut v: [f64; 3] = std::array::from_fn(|k| w1 * v2[k] + w2 * v1[k] + c[k]);
    if w < 0.0 {
        w = -w;
        v = v.map(|x| -x);
    }
    let s = dot(&v, &v).sqrt();
    if s < 1e-12 {
        return v.map(|x| 2.0 * x);
    }
    let angle = 2.0 * s.atan2(w);
    v.map(|x| x / s * angle)
}

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Scales `v` down to length `max`; whether it had to.
fn clamp_norm(v: &mut [f64; 3], max: f64) -> bool {
    let n = dot(v, v).sqrt();
    if n > max {
        let s = max / n;
        *v = v.map(|c| c * s);
        true
    } else {
        false
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "a faded or released force is exactly zero")]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// A flat contact pushing up along z with stiffness 1000 N/m, 2 N at the frame's pose.
    fn floor() -> ToolSnapshot {
        let mut jacobian = [[0.0; 6]; 6];
        jacobian[2][2] = -1000.0;
        ToolSnapshot {
            frame: 1,
            position: [0.0, 0.0, 0.0],
            orientation: [1.0, 0.0, 0.0, 0.0],
            force: [0.0, 0.0, 2.0],
            torque: [0.0; 3],
            jacobian,
            flags: ForceFlag::InContact as u32,
            proxy: None,
        }
    }

    fn pose(seq: u64, ts: u64, z: f64) -> CheckedPose {
        let raw =
            RawToolPose { sequence: seq, timestamp_ns: ts, ..RawToolPose::at(0, [0.0, 0.0, z]) };
        incise_protocol::check::check_pose(&raw).unwrap()
    }

    fn settings() -> HapticSettings {
        HapticSettings {
            max_force_rate_n_per_s: 1e9,
            passivity: false,
            ..HapticSettings::default()
        }
    }

    #[test]
    fn the_force_follows_the_linearisation_and_answers_the_pose() {
        let mut r = Renderer::new(0, settings());
        r.offer(0, &pose(5, 100, -0.001));
        let out = r.force(MS, Some(&floor()));
        assert!((out.force[2] - 3.0).abs() < 1e-12, "{:?}", out.force);
        assert_eq!(out.pose_sequence, 5);
        assert_eq!(out.flags, ForceFlag::InContact as u32);
        // Lifted 3 mm: the linear force would pull (−1 N); a contact does not.
        r.offer(MS, &pose(6, 200, 0.003));
        assert_eq!(r.force(2 * MS, Some(&floor())).force, [0.0; 3]);
    }

    #[test]
    fn a_turned_tool_moves_its_torque_by_the_rotation_columns() {
        let mut snap = floor();
        snap.jacobian[3][3] = -0.5; // N·m per rad about x
        snap.torque = [0.1, 0.0, 0.0];
        let mut r = Renderer::new(0, settings());
        let half = 0.01f64 / 2.0; // 10 mrad about x
        let mut p = *pose(1, 1, 0.0).raw();
        p.orientation = [half.cos(), half.sin(), 0.0, 0.0];
        r.offer(0, &incise_protocol::check::check_pose(&p).unwrap());
        let out = r.force(MS, Some(&snap));
        assert!((out.torque[0] - (0.1 - 0.5 * 0.01)).abs() < 1e-9, "{:?}", out.torque);
    }

    #[test]
    fn a_pose_far_from_the_frame_is_evaluated_at_the_trust_distance() {
        let mut r = Renderer::new(0, settings());
        // 3 cm into the floor: the linear model would say 32 N; it is trusted to 5 mm (7 N).
        r.offer(0, &pose(1, 1, -0.03));
        let out = r.force(MS, Some(&floor()));
        assert!((out.force[2] - 7.0).abs() < 1e-9, "{:?}", out.force);
    }

    #[test]
    fn the_force_is_clamped_and_its_rate_limited_and_both_are_flagged() {
        let s = HapticSettings { max_force_rate_n_per_s: 1000.0, max_force_n: 5.0, ..settings() };
        let mut r = Renderer::new(0, s);
        r.offer(0, &pose(1, 1, -0.0045)); // 6.5 N wanted
        let first = r.force(0, Some(&floor()));
        assert!((first.force[2] - s.max_force_n).abs() < 1e-12);
        assert_ne!(first.flags & ForceFlag::Clamped as u32, 0);
        // Released: the force may fall by 1 N per ms, no faster.
        r.offer(MS, &pose(2, 2, 0.001));
        let next = r.force(MS, Some(&floor()));
        assert!((next.force[2] - (s.max_force_n - 1.0)).abs() < 1e-9, "{:?}", next.force);
        assert_ne!(next.flags & ForceFlag::Clamped as u32, 0);
    }

    #[test]
    fn when_poses_stop_the_force_fades_to_zero_within_50_ms_and_is_flagged_stale() {
        let mut r = Renderer::new(0, settings());
        r.offer(0, &pose(1, 1, -0.002));
        let held = r.force(0, Some(&floor())).force[2];
        assert!((held - 4.0).abs() < 1e-9);
        let mut last = held;
        for ms in 1..=60 {
            let out = r.force(ms * MS, Some(&floor()));
            assert!(out.force[2] <= last + 1e-12, "rose at {ms} ms");
            if ms > 10 {
                assert_ne!(out.flags & ForceFlag::Stale as u32, 0);
            }
            if ms >= 50 {
                assert_eq!(out.force, [0.0; 3], "{ms} ms");
            }
            last = out.force[2];
        }
        // A new pose brings the force back (through the rate limit, here unlimited).
        r.offer(61 * MS, &pose(2, 2, -0.002));
        assert!((r.force(61 * MS, Some(&floor())).force[2] - 4.0).abs() < 1e-9);
    }

    /// A contact whose frames come at 100 Hz while the hand oscillates in and out of it: each
    /// new frame moves the force's reference, and the rendered force gives the hand energy back
    /// (measured with the controller off: the total falls below zero). With the controller on,
    /// the energy taken from the hand, counted with the force actually sent over each interval,
    /// never falls below minus one interval's prediction miss: the controller predicts the next
    /// interval's motion from the last, and misses by `|F|·|δx_{n+1} − δx_n|` at most.
    #[test]
    fn the_passivity_controller_keeps_the_rendered_energy_non_negative() {
        let off = HapticSettings { passivity: false, ..settings() };
        let on = HapticSettings { max_force_rate_n_per_s: 1e9, ..HapticSettings::default() };
        let (worst_off, _, _) = oscillate(off);
        let (worst_on, final_on, miss) = oscillate(on);
        println!(
            "energy taken from the hand: lowest {worst_off:.2e} J without the controller, \
             {worst_on:.2e} J with it (end {final_on:.2e} J; one interval's miss up to {miss:.2e} J)"
        );
        assert!(worst_off < -1e-4, "the scenario does not give energy back: {worst_off}");
        assert!(worst_on >= -miss, "the device gave out {worst_on} J");
        assert!(final_on > 0.0);
    }

    /// The lowest and the final energy taken from the hand over 400 updates, and the largest
    /// `|F|·|δx_{n+1} − δx_n|`.
    fn oscillate(s: HapticSettings) -> (f64, f64, f64) {
        let mut r = Renderer::new(0, s);
        // A stale snapshot (frame at z = −2 mm) rendered while the tool oscillates.
        let mut snap = floor();
        snap.position = [0.0, 0.0, -0.002];
        snap.force = [0.0, 0.0, 4.0];
        let (mut taken, mut worst, mut miss) = (0.0f64, 0.0f64, 0.0f64);
        let mut previous: Option<([f64; 3], f64)> = None;
        let mut last_step: Option<f64> = None;
        for i in 0..400u64 {
            let z = -0.002 - 0.0015 * ((i as f64) * 0.3).sin();
            // The frame jumps to the newest pose every 10 updates (a 100 Hz physics frame).
            if i % 10 == 0 {
                snap.position[2] = z;
                snap.force[2] = 2.0 - 1000.0 * z;
            }
            r.offer(i * MS, &pose(i + 1, i + 1, z));
            let out = r.force(i * MS, Some(&snap));
            if let Some((f, z0)) = previous {
                taken -= f[2] * (z - z0);
                if let Some(step) = last_step {
                    miss = miss.max(f[2].abs() * ((z - z0) - step).abs());
                }
                last_step = Some(z - z0);
            }
            previous = Some((out.force, z));
            worst = worst.min(taken);
        }
        (worst, taken, miss)
    }
}
