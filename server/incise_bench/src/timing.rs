//! Repeated timings and their median / min / max.

use std::time::Instant;

/// Timings of one measured operation, in milliseconds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Timing {
    pub median_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
    pub repeats: usize,
}

/// Runs `prepare` (untimed) then `f` (timed) `repeats` times; returns the timings and the last
/// result of `f`.
pub fn measure<S, T>(
    repeats: usize,
    mut prepare: impl FnMut() -> S,
    mut f: impl FnMut(S) -> T,
) -> (Timing, T) {
    let mut times = Vec::with_capacity(repeats);
    let mut last = None;
    for _ in 0..repeats.max(1) {
        // Free the previous result first so its memory does not crowd the next measurement.
        drop(last.take());
        let input = prepare();
        let start = Instant::now();
        let out = f(input);
        times.push(start.elapsed().as_secs_f64() * 1e3);
        last = Some(out);
    }
    times.sort_by(f64::total_cmp);
    let timing = Timing {
        median_ms: times[times.len() / 2],
        min_ms: times[0],
        max_ms: times[times.len() - 1],
        repeats: times.len(),
    };
    (timing, last.expect("at least one repeat"))
}

/// The `q`-quantile (0 ≤ q ≤ 1) of ascending `sorted` values, the nearest sample; 0 when empty.
#[must_use]
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}
