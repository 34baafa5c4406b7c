//! The implicit step's starting guess: the last steps' velocity changes extrapolated by the
//! polynomial that would have predicted the latest one best.

use crate::exec::Executor;
use incise_math::Vec3;

/// The highest order of the starting guess's extrapolation (cubic).
const MAX_ORDER: usize = 3;

/// Velocity changes kept: the cubic's four, and one more to judge the cubic's last prediction.
pub(crate) const HISTORY: usize = MAX_ORDER + 2;

/// Weights of the polynomial of order `k` through the `k + 1` most recent values (one step
/// apart), evaluated one step ahead.
const WEIGHTS: [&[f64]; MAX_ORDER + 1] =
    [&[1.0], &[2.0, -1.0], &[3.0, -3.0, 1.0], &[4.0, -6.0, 4.0, -1.0]];

/// CG's starting guess from the last steps' velocity changes (`history`, the most recent first):
/// the polynomial of the order that would have predicted the most recent one best from those
/// before it, extrapolated one step (zero with no history; linear before there is a choice).
/// A smooth motion's acceleration changes slowly, and at 1 ms from rest the cubic wins (about
/// half the CG iterations of the linear guess on B2 and B3). At 10 ms, where the motion is not
/// smooth on the step's scale, a lower order wins. The choice uses vector sums
/// only (no operator product), is made the same way every run, and changes where CG starts, not
/// where it stops.
pub(crate) fn starting_guess(exec: &Executor, history: &[Vec<Vec3>], guess: &mut [Vec3]) {
    let n = guess.len();
    let Some((latest, older)) = history.split_first() else {
        guess.fill([0.0; 3]);
        return;
    };
    let judged = older.len().min(MAX_ORDER + 1);
    let order = if judged < 2 {
        usize::from(judged == 1)
    } else {
        // Two fixed halves of the entries (on two threads where allowed), their sums added:
        // the same bits on one thread.
        let entries = 3 * n;
        let half = entries / 2;
        let zeros = if judged <= MAX_ORDER { vec![0.0; entries] } else { Vec::new() };
        let olders: [&[f64]; MAX_ORDER + 1] =
            std::array::from_fn(|j| older.get(j).map_or(&zeros[..], |v| v.as_flattened()));
        let latest = latest.as_flattened();
        let (first, second) = exec.join_if(
            n >= crate::exec::PARALLEL_MIN,
            || misses(&latest[..half], &olders.map(|o| &o[..half])),
            || misses(&latest[half..], &olders.map(|o| &o[half..])),
        );
        let miss: [f64; MAX_ORDER + 1] = std::array::from_fn(|j| first[j] + second[j]);
        (0..judged).min_by(|&a, &b| miss[a].total_cmp(&miss[b])).unwrap_or(0)
    };
    let order = order.min(history.len() - 1);
    exec.update_runs(guess.as_flattened_mut(), |start, run| {
        // The order's weights are at most as many as the history's entries.
        let values: [&[f64]; HISTORY] = std::array::from_fn(|j| {
            history.get(j).map_or(&[][..], |h| &h.as_flattened()[start..start + run.len()])
        });
        for (g, i) in run.iter_mut().zip(0..) {
            *g = WEIGHTS[order].iter().zip(&values).fold(0.0, |acc, (w, v)| acc + w * v[i]);
        }
    });
}

/// How far each order's prediction of `latest` from `older` (the values before it, most recent
/// first) misses, summed over the entries: order k's prediction is order k − 1's plus the k-th
/// backward difference. Four lanes of partial sums, added in lane order at the end: a loop the
/// compiler vectorises.
fn misses(latest: &[f64], older: &[&[f64]; MAX_ORDER + 1]) -> [f64; MAX_ORDER + 1] {
    let mut lanes = [[0.0f64; 4]; MAX_ORDER + 1];
    for (i, &value) in latest.iter().enumerate() {
        let d: [f64; MAX_ORDER + 1] = std::array::from_fn(|j| older[j][i]);
        let differences =
            [d[0], d[0] - d[1], d[0] - 2.0 * d[1] + d[2], d[0] - 3.0 * d[1] + 3.0 * d[2] - d[3]];
        let mut error = value;
        for (lane, delta) in lanes.iter_mut().zip(differences) {
            error -= delta;
            lane[i % 4] += error * error;
        }
    }
    lanes.map(|l| ((l[0] + l[1]) + l[2]) + l[3])
}

#[cfg(test)]
mod guess_tests {
    use super::*;

    /// [`starting_guess`] for `n` nodes.
    fn guessed(history: &[Vec<Vec3>], n: usize) -> Vec<Vec3> {
        let mut guess = vec![[f64::NAN; 3]; n];
        starting_guess(&Executor::default(), history, &mut guess);
        guess
    }

    /// Histories (most recent first) of a two-node field sampled at steps `t = 0, -1, -2, …`.
    fn history(f: impl Fn(f64) -> f64, len: usize) -> Vec<Vec<Vec3>> {
        (0..len)
            .map(|j| {
                let t = -(j as f64);
                vec![[f(t), 2.0 * f(t), -f(t)], [0.5 * f(t), 0.0, f(t)]]
            })
            .collect()
    }

    #[test]
    fn a_cubic_motion_is_predicted_exactly() {
        let f = |t: f64| 0.3 + 0.2 * t - 0.05 * t * t + 0.01 * t * t * t;
        let guess = guessed(&history(f, HISTORY), 2);
        let want = history(|t| f(t + 1.0), 1);
        for (g, w) in guess.iter().zip(&want[0]) {
            for k in 0..3 {
                assert!((g[k] - w[k]).abs() < 1e-12, "{guess:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn an_oscillation_on_the_step_scale_falls_back_to_the_last_value() {
        // +1, −1, +1, … : every extrapolation of higher order overshoots further.
        let f = |t: f64| if (t as i64) % 2 == 0 { 1.0 } else { -1.0 };
        let h = history(f, HISTORY);
        assert_eq!(guessed(&h, 2), h[0]);
    }

    #[test]
    fn short_histories_use_what_there_is() {
        let f = |t: f64| 1.0 + t;
        assert_eq!(guessed(&[], 2), vec![[0.0; 3]; 2]);
        assert_eq!(guessed(&history(f, 1), 2), history(f, 1)[0]);
        // Two values: linear, before any order could be judged.
        assert_eq!(guessed(&history(f, 2), 2), history(|t| f(t + 1.0), 1)[0]);
    }
}
