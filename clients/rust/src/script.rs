//! Trajectories for a scripted tool: press, press and cut, circle, or poses from a CSV file.
//! Times are fractions of the run (the scripted ones) or seconds (a CSV file's).

use crate::drive::PoseAt;

/// Unrotated: the tool's shaft (+z) up, its edge or tip down.
pub const UPRIGHT: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

/// A trajectory.
#[derive(Clone, Debug, PartialEq)]
pub enum Script {
    /// Down onto the surface point `at` from 1 cm above, pressed `depth` (m) in, held, lifted.
    Press {
        /// The surface point (m).
        at: [f64; 3],
        /// How far in (m).
        depth: f64,
    },
    /// As `Press`, then drawn `stroke` (m) along x while pressed, then lifted.
    PressCut {
        /// The surface point (m).
        at: [f64; 3],
        /// How far in (m).
        depth: f64,
        /// How far along x (m).
        stroke: f64,
    },
    /// A horizontal circle of `radius` (m) about `at`, `depth` (m) below it, one turn per
    /// `period` (s).
    Circle {
        /// The centre's surface point (m).
        at: [f64; 3],
        /// The circle's radius (m).
        radius: f64,
        /// How far in (m).
        depth: f64,
        /// Seconds per turn.
        period: f64,
    },
    /// Poses from a CSV file, interpolated in time.
    Csv(Vec<Row>),
}

/// One row of a pose file: `t, x, y, z, qw, qx, qy, qz, gripper` (s, m, unit quaternion, rad).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Row {
    /// Seconds from the start; rows in increasing order.
    pub t: f64,
    /// The tool's pose then.
    pub pose: PoseAt,
}

/// A piecewise-linear ramp through key frames `(t, value)`, held before the first and after the
/// last: the scripts' building block.
#[must_use]
pub fn ramp(keys: &[(f64, f64)], t: f64) -> f64 {
    match keys.iter().position(|&(k, _)| k > t) {
        None => keys.last().map_or(0.0, |k| k.1),
        Some(0) => keys[0].1,
        Some(i) => {
            let ((t0, a), (t1, b)) = (keys[i - 1], keys[i]);
            a + (b - a) * (t - t0) / (t1 - t0)
        }
    }
}

impl Script {
    /// The pose at `t` seconds of a run `duration` seconds long.
    #[must_use]
    pub fn pose_at(&self, t: f64, duration: f64) -> PoseAt {
        let f = (t / duration).clamp(0.0, 1.0);
        match self {
            Self::Press { at, depth } => {
                let z =
                    ramp(&[(0.0, 0.01), (0.2, 0.0), (0.5, -depth), (0.8, -depth), (1.0, 0.01)], f);
                ([at[0], at[1], at[2] + z], UPRIGHT, 0.0)
            }
            Self::PressCut { at, depth, stroke } => {
                let z = ramp(
                    &[(0.0, 0.01), (0.15, 0.0), (0.35, -depth), (0.75, -depth), (0.9, 0.01)],
                    f,
                );
                let x = ramp(&[(0.35, 0.0), (0.75, *stroke)], f);
                ([at[0] + x, at[1], at[2] + z], UPRIGHT, 0.0)
            }
            Self::Circle { at, radius, depth, period } => {
                let a = std::f64::consts::TAU * t / period;
                let z = ramp(&[(0.0, 0.01), (0.1, -depth), (0.9, -depth), (1.0, 0.01)], f);
                ([at[0] + radius * a.cos(), at[1] + radius * a.sin(), at[2] + z], UPRIGHT, 0.0)
            }
            Self::Csv(rows) => csv_pose(rows, t),
        }
    }
}

/// The pose at `t`: positions and gripper interpolated linearly between rows, the orientation
/// of the row at or before `t`; held before the first row and after the last.
fn csv_pose(rows: &[Row], t: f64) -> PoseAt {
    let Some(first) = rows.first() else { return ([0.0; 3], UPRIGHT, 0.0) };
    match rows.iter().position(|r| r.t > t) {
        None => rows.last().map_or(first.pose, |r| r.pose),
        Some(0) => first.pose,
        Some(i) => {
            let (a, b) = (rows[i - 1], rows[i]);
            let s = (t - a.t) / (b.t - a.t);
            let p = std::array::from_fn(|k| a.pose.0[k] + s * (b.pose.0[k] - a.pose.0[k]));
            (p, a.pose.1, a.pose.2 + s * (b.pose.2 - a.pose.2))
        }
    }
}

/// Reads a pose file: one row per line, `t, x, y, z, qw, qx, qy, qz, gripper`, a first line of
/// column names allowed, `#` comments and blank lines skipped. Every error names the line.
pub fn parse_csv(text: &str, file: &str) -> Result<Vec<Row>, String> {
    let mut rows: Vec<Row> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if rows.is_empty() && cells.first().is_some_and(|c| c.parse::<f64>().is_err()) {
            continue; // the header
        }
        if cells.len() != 9 {
            return Err(format!(
                "{file}:{n}: {} columns; a row is t, x, y, z, qw, qx, qy, qz, gripper",
                cells.len()
            ));
        }
        let mut v = [0.0; 9];
        for (k, c) in cells.iter().enumerate() {
            v[k] = c.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| {
                format!("{file}:{n}: column {} is {c:?}, not a finite number", k + 1)
            })?;
        }
        if let Some(last) = rows.last()
            && v[0] <= last.t
        {
            return Err(format!("{file}:{n}: time {} does not follow {}", v[0], last.t));
        }
        let q = [v[4], v[5], v[6], v[7]];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > incise_protocol::check::UNIT_TOLERANCE {
            return Err(format!("{file}:{n}: the quaternion has norm {norm}, not 1"));
        }
        if v[8] < 0.0 {
            return Err(format!("{file}:{n}: the gripper angle {} is negative", v[8]));
        }
        rows.push(Row { t: v[0], pose: ([v[1], v[2], v[3]], q.map(|c| c / norm), v[8]) });
    }
    if rows.is_empty() {
        return Err(format!("{file}: no pose rows"));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_pose_file_is_read_and_interpolated() {
        let text = "t,x,y,z,qw,qx,qy,qz,gripper\n# a comment\n0,0,0,0.05,1,0,0,0,0.5\n1,0.01,0,0.04,1,0,0,0,0\n";
        let rows = parse_csv(text, "p.csv").unwrap();
        assert_eq!(rows.len(), 2);
        let (p, q, g) = Script::Csv(rows).pose_at(0.5, 10.0);
        assert!((p[0] - 0.005).abs() < 1e-15 && (p[2] - 0.045).abs() < 1e-15);
        assert!(q.iter().zip(UPRIGHT).all(|(a, b)| (a - b).abs() < 1e-15));
        assert!((g - 0.25).abs() < 1e-15);
    }

    #[test]
    fn bad_pose_files_name_the_line() {
        for (text, wanted) in [
            ("0,0,0,0,1,0,0,0\n", "p.csv:1: 8 columns"),
            ("0,0,0,x,1,0,0,0,0\n", "p.csv:1: column 4"),
            ("0,0,0,0,1,0,0,0,0\n0,0,0,0,1,0,0,0,0\n", "p.csv:2: time 0 does not follow 0"),
            ("0,0,0,0,2,0,0,0,0\n", "p.csv:1: the quaternion has norm 2"),
            ("0,0,0,0,1,0,0,0,-1\n", "p.csv:1: the gripper angle -1"),
            ("0,0,0,nan,1,0,0,0,0\n", "p.csv:1: column 4"),
            ("\n# nothing\n", "p.csv: no pose rows"),
        ] {
            let err = parse_csv(text, "p.csv").unwrap_err();
            assert!(err.starts_with(wanted), "{err}");
        }
    }

    proptest! {
        /// Fuzz-style: any text is read or refused, never a panic.
        #[test]
        fn any_text_is_read_or_refused(text in "[0-9a-z,.#\\n -]{0,200}") {
            let _ = parse_csv(&text, "f.csv");
        }
    }

    #[test]
    fn the_scripts_start_above_and_go_in() {
        let at = [0.04, 0.03, 0.05];
        for s in [
            Script::Press { at, depth: 0.003 },
            Script::PressCut { at, depth: 0.005, stroke: 0.02 },
            Script::Circle { at, radius: 0.005, depth: 0.002, period: 1.0 },
        ] {
            assert!(s.pose_at(0.0, 4.0).0[2] > at[2]);
            assert!((0..40).any(|i| s.pose_at(f64::from(i) * 0.1, 4.0).0[2] < at[2]), "{s:?}");
        }
    }
}
