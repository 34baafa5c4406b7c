//! Peers measured on this machine: the tables `deploy/peers/bench_mujoco.py` (MuJoCo's flex on
//! scene B) and `deploy/peers/bench_newton.py` (Newton's semi-implicit soft mesh, same layout)
//! print, read so that `speed-error --peers FILE` can put them on the speed-vs-error plot at their
//! measured error and compare them with our rows at equal error, in one job.
//!
//! A table starts with a line `# MuJoCo 4.0.0 …` or `# Newton 1.8.0 …` (name and version of the
//! rows after it). A row reads
//! `discrete   S2   3168   756   1889   463.0   462.3   472.0  stable   0.0123  stable   0.0121`:
//! integrator (MuJoCo's `Euler`, `discrete`, or `disc@10ms` for the implicit one timed at 10 ms;
//! Newton's `semi-impl`), scene,
//! tetrahedra, nodes, steps per run, median/min/max steps/s at the row's dt, then for dt = 1 ms
//! and 10 ms a verdict (`stable`, or words such as `blow-up (BADQACC reset)`) and the pulled
//! corner's displacement `|u_c|` (m) after 2 s, `nan` when it blew up.

use anyhow::{Context, bail};
use std::path::Path;

/// One peer configuration: its speed at one dt and where its corner settled.
#[derive(Clone, Debug, PartialEq)]
pub struct PeerPoint {
    /// e.g. `MuJoCo discrete`.
    pub peer: String,
    /// `B1`, `B2` or `B3`.
    pub scene: String,
    /// Time step of the timing (s).
    pub dt: f64,
    /// Median steps per second.
    pub steps_per_s: f64,
    /// `|u_c|` after 2 s at this dt (m), when it stayed stable.
    pub displacement: Option<f64>,
}

/// Reads the peers' tables in `path`.
///
/// # Errors
/// If the file cannot be read or holds no row of a table.
pub fn read_peers(path: &Path) -> anyhow::Result<Vec<PeerPoint>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the peers' table {}", path.display()))?;
    parse_peers(&text).with_context(|| format!("in {}", path.display()))
}

/// The row names each peer's table uses.
const ROWS: [(&str, &[&str]); 2] =
    [("MuJoCo", &["Euler", "discrete", "disc@10ms"]), ("Newton", &["semi-impl"])];

/// Parses `bench_mujoco.py` and `bench_newton.py` tables (several may follow each other). Lines
/// that are not rows (headers, comments, the cantilever lines) are skipped; a line that starts
/// like a row but does not parse is an error naming it.
///
/// # Errors
/// A malformed row (with its line number), or no row at all.
pub fn parse_peers(text: &str) -> anyhow::Result<Vec<PeerPoint>> {
    // (peer, version) of the table the rows belong to; MuJoCo's before any header (older files).
    let mut table: (&str, Option<&str>) = ("MuJoCo", None);
    let mut points = Vec::new();
    for (number, line) in text.lines().enumerate() {
        if let Some(header) = line.strip_prefix("# ") {
            let mut words = header.split_whitespace();
            let first = words.next();
            if let Some((name, _)) = ROWS.iter().find(|(name, _)| first == Some(*name)) {
                table = (name, words.next());
            }
            continue;
        }
        let tokens: Vec<&str> = line.split_whitespace().collect();
        let Some(&integrator) = tokens.first() else { continue };
        let Some((peer, _)) = ROWS.iter().find(|(_, rows)| rows.contains(&integrator)) else {
            continue;
        };
        let point = if *peer == table.0 {
            parse_row(integrator, &tokens, peer, table.1)
        } else {
            Err(anyhow::anyhow!("a {peer} row in the {} table", table.0))
        }
        .with_context(|| format!("line {}: {line:?}", number + 1))?;
        points.push(point);
    }
    if points.is_empty() {
        bail!(
            "no rows of bench_mujoco.py's or bench_newton.py's table (lines starting `Euler`, \
             `discrete`, `disc@10ms` or `semi-impl`)"
        );
    }
    Ok(points)
}

fn parse_row(
    integrator: &str,
    tokens: &[&str],
    peer: &str,
    version: Option<&str>,
) -> anyhow::Result<PeerPoint> {
    if tokens.len() < 10 {
        bail!("expected at least 10 columns, found {}", tokens.len());
    }
    let scene = match tokens[1] {
        "S1" => "B1",
        "S2" => "B2",
        "S3" => "B3",
        other => bail!("unknown scene {other:?} (expected S1, S2 or S3)"),
    };
    let number = |k: usize, what: &str| -> anyhow::Result<f64> {
        tokens[k]
            .parse::<f64>()
            .with_context(|| format!("column {} ({what}) is {:?}", k + 1, tokens[k]))
    };
    let steps_per_s = number(5, "median steps/s")?;
    if !(steps_per_s.is_finite() && steps_per_s >= 0.0) {
        bail!("median steps/s {steps_per_s} is not a rate");
    }
    // The rest: verdict words then |u_c|, twice (dt = 1 ms, then 10 ms).
    let mut verdicts = Vec::new();
    let mut words = Vec::new();
    for &t in &tokens[8..] {
        if let Ok(u) = t.parse::<f64>() {
            verdicts.push((words.join(" "), u));
            words.clear();
        } else {
            words.push(t);
        }
    }
    if verdicts.len() != 2 {
        bail!("expected two verdicts with |u_c| (dt = 1 ms and 10 ms), found {}", verdicts.len());
    }
    let (verdict, u) = if integrator == "disc@10ms" { &verdicts[1] } else { &verdicts[0] };
    let displacement = (verdict == "stable" && u.is_finite()).then_some(*u);
    let name = match integrator {
        "Euler" => "explicit (Euler)",
        "semi-impl" => "semi-implicit",
        _ => "implicit (discrete)",
    };
    Ok(PeerPoint {
        peer: format!("{peer} {}{name}", version.map_or(String::new(), |v| format!("{v} "))),
        scene: scene.to_owned(),
        dt: if integrator == "disc@10ms" { 1e-2 } else { 1e-3 },
        steps_per_s,
        displacement,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const TABLE: &str = "\
# MuJoCo 4.0.0 flexcomp dim=3 dof=full (linear tets, StVK), damping=0.001s; loadavg before 0.94, after 1.00
(rows time dt = 1 ms unless the integrator says @10ms; stability columns are per scene)
integrator scene   tets  nodes steps/run    median       min       max  dt=1ms                    |u_c|@2s  dt=10ms                   |u_c|@2s
Euler      S1       840    240      2000    7867.4    7777.1    7910.4  stable                      0.0103  blow-up (BADQACC reset)        nan
Euler      S3     23760   4784      1085     275.1     274.4     278.2  blow-up (BADQACC reset)        nan  blow-up (BADQACC reset)        nan
discrete   S2      3168    756      1889     463.0     462.3     472.0  stable                      0.0123  stable                      0.0121
disc@10ms  S2      3168    756      1131     430.3     363.0     434.9  stable                      0.0123  stable                      0.0121
cantilever (discrete, dt=1ms, 480 tets, grid (20, 2, 2)): tip deflection 7.4 mm
# Newton 1.8.0 (Warp 1.19.0, CPU) soft mesh, semi-implicit Euler; loadavg before 1.41, after 1.32
(rows time dt = 1 ms; stability columns are per scene)
integrator scene   tets  nodes steps/run    median       min       max  dt=1ms                     |u_c|@2s  dt=10ms                    |u_c|@2s
semi-impl  S3     23760   4784      1939     961.6     954.7     968.9  stable                       0.0144  blow-up (|u|max=994.48 m)  994.4776
";

    #[test]
    fn the_table_is_read_with_each_rows_own_dt_and_verdict() {
        let points = parse_peers(TABLE).unwrap();
        assert_eq!(points.len(), 5);
        assert_eq!(points[0].peer, "MuJoCo 4.0.0 explicit (Euler)");
        assert_eq!((points[0].scene.as_str(), points[0].dt), ("B1", 1e-3));
        assert_eq!(points[0].displacement, Some(0.0103));
        assert_eq!(points[1].displacement, None, "blew up at 1 ms");
        assert_eq!(points[2].peer, "MuJoCo 4.0.0 implicit (discrete)");
        assert_eq!(
            (points[3].dt, points[3].steps_per_s, points[3].displacement),
            (1e-2, 430.3, Some(0.0121))
        );
        assert_eq!(points[4].peer, "Newton 1.8.0 semi-implicit");
        assert_eq!(
            (points[4].scene.as_str(), points[4].dt, points[4].steps_per_s),
            ("B3", 1e-3, 961.6)
        );
        assert_eq!(points[4].displacement, Some(0.0144));
    }

    #[test]
    fn bad_tables_say_what_and_where() {
        let e = format!("{:#}", parse_peers("hello\n").unwrap_err());
        assert!(e.contains("no rows"), "{e}");
        let e = format!(
            "{:#}",
            parse_peers("discrete S9 1 2 3 4 5 6 stable 0.1 stable 0.1\n").unwrap_err()
        );
        assert!(e.contains("line 1") && e.contains("S9"), "{e}");
        let e = format!(
            "{:#}",
            parse_peers("discrete S1 1 2 3 fast 5 6 stable 0.1 stable 0.1\n").unwrap_err()
        );
        assert!(e.contains("median") && e.contains("fast"), "{e}");
        let e = format!("{:#}", parse_peers("Euler S1 1 2 3 4 5 6 stable 0.1\n").unwrap_err());
        assert!(e.contains("two verdicts"), "{e}");
        let e = format!(
            "{:#}",
            parse_peers("semi-impl S1 1 2 3 4 5 6 stable 0.1 stable 0.1\n").unwrap_err()
        );
        assert!(e.contains("line 1") && e.contains("Newton row in the MuJoCo table"), "{e}");
    }

    proptest! {
        /// Damaged tables are errors or rows, never a panic.
        #[test]
        fn damaged_tables_never_panic(cut in 0usize..2000, flip in 0usize..2000, byte in any::<u8>()) {
            let mut bytes = TABLE.as_bytes().to_vec();
            let at = flip % bytes.len();
            bytes[at] = byte;
            bytes.truncate(cut % (bytes.len() + 1));
            let _ = parse_peers(&String::from_utf8_lossy(&bytes));
        }

        /// Random lines that start like rows never panic either.
        #[test]
        fn random_rows_never_panic(words in proptest::collection::vec("[a-zA-Z0-9.@()-]{0,8}", 0..16)) {
            let _ = parse_peers(&format!("discrete {}\n", words.join(" ")));
        }
    }
}
