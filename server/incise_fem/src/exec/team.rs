//! Two threads in lockstep for the iterations of one solve. A CG iteration on a mid-sized mesh
//! takes tens of microseconds, and handing each of its loops to the thread pool costs a sleep and
//! a wake-up per loop (in a virtual machine, where every wake-up goes through the hypervisor, two
//! threads were no faster than one). Here the two threads stay awake for the whole solve and meet
//! at spinning barriers, each far cheaper than a wake-up.
//!
//! The work is always cut into the same two parts: with two threads each does one, with one
//! thread it does both in order. A sum over parts is formed from the parts' partial sums in part
//! order ([`Member::sum`]), so the results are bit-identical whatever the thread count.

use std::ops::Range;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

/// The number of parts every team loop is cut into.
pub(crate) const PARTS: usize = 2;

/// Values one [`Member::sum`] can reduce at once.
const MAX_VALUES: usize = 3;

/// The shared state of a team.
struct Team {
    ranks: usize,
    /// How a member waits at a barrier: spinning first, or yielding from the start.
    idle: crate::exec::Idle,
    /// Set when a member panicked: its partner would otherwise wait at the next barrier forever.
    poisoned: std::sync::atomic::AtomicBool,
    arrived: AtomicUsize,
    generation: AtomicUsize,
    /// Partial sums, `[set][value][part]` as `f64` bits; two sets used alternately, so a slow
    /// reader of one reduction is never overwritten by the next.
    partials: [[[AtomicU64; PARTS]; MAX_VALUES]; 2],
}

/// One thread's handle on its team.
pub(crate) struct Member<'a> {
    team: &'a Team,
    rank: usize,
    generation: std::cell::Cell<usize>,
    reductions: std::cell::Cell<usize>,
}

impl Member<'_> {
    /// This thread's index in the team (0 on a team of one).
    pub(crate) fn rank(&self) -> usize {
        self.rank
    }

    /// The parts this thread does, in order.
    pub(crate) fn parts(&self) -> Range<usize> {
        if self.team.ranks == 1 { 0..PARTS } else { self.rank..self.rank + 1 }
    }

    /// Waits until every thread of the team has arrived. Writes before it are visible to every
    /// thread after it.
    pub(crate) fn barrier(&self) {
        let team = self.team;
        if team.ranks == 1 {
            return;
        }
        let generation = self.generation.get();
        self.generation.set(generation + 1);
        if team.arrived.fetch_add(1, Ordering::AcqRel) + 1 == team.ranks {
            team.arrived.store(0, Ordering::Relaxed);
            team.generation.store(generation + 1, Ordering::Release);
            return;
        }
        crate::exec::executor::wait_until(team.idle, || {
            assert!(
                !team.poisoned.load(Ordering::Relaxed),
                "the other thread of the team panicked"
            );
            team.generation.load(Ordering::Acquire) != generation
        });
    }

    /// Sums per-part values over all parts, in part order: `partial(part)` is called for this
    /// thread's parts, and every thread gets the same totals.
    pub(crate) fn sum<const N: usize>(&self, partial: impl Fn(usize) -> [f64; N]) -> [f64; N] {
        const { assert!(N <= MAX_VALUES) };
        let set = self.reductions.get() % 2;
        self.reductions.set(self.reductions.get() + 1);
        let slots = &self.team.partials[set];
        for part in self.parts() {
            for (slot, v) in slots.iter().zip(partial(part)) {
                slot[part].store(v.to_bits(), Ordering::Relaxed);
            }
        }
        self.barrier();
        std::array::from_fn(|k| {
            (0..PARTS)
                .fold(0.0, |acc, part| acc + f64::from_bits(slots[k][part].load(Ordering::Relaxed)))
        })
    }
}

/// Marks the team poisoned if its member's thread unwinds.
struct PoisonOnPanic<'a>(&'a Team);

impl Drop for PoisonOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.poisoned.store(true, Ordering::Relaxed);
        }
    }
}

/// Runs `body` on a team of two threads (the caller and one of `exec`'s workers) when `parallel`
/// and `exec` has two threads, otherwise on the caller alone, and returns rank 0's result. A panic
/// in either thread ends both (the other panics at its next barrier) and reaches the caller.
pub(crate) fn run<R: Send>(
    exec: &crate::exec::Executor,
    parallel: bool,
    body: impl Fn(&Member) -> R + Sync,
) -> R {
    let two = parallel && exec.threads() > 1 && !exec.in_pool();
    let team = Team {
        ranks: if two { 2 } else { 1 },
        idle: exec.idle(),
        poisoned: std::sync::atomic::AtomicBool::new(false),
        arrived: AtomicUsize::new(0),
        generation: AtomicUsize::new(0),
        partials: Default::default(),
    };
    let member = |rank| Member {
        team: &team,
        rank,
        generation: std::cell::Cell::new(0),
        reductions: std::cell::Cell::new(0),
    };
    if !two {
        return body(&member(0));
    }
    let (body, member) = (&body, &member);
    let pending = crate::exec::executor::Pending::new();
    exec.scope(|s| {
        exec.spawn_counted(&pending, s, move || {
            let _poison = PoisonOnPanic(member(1).team);
            body(&member(1));
        });
        let _poison = PoisonOnPanic(&team);
        let result = body(&member(0));
        pending.wait(exec);
        result
    })
}

/// `range` cut into [`PARTS`] consecutive pieces, the cuts at multiples of `align`.
pub(crate) fn split(range: Range<usize>, align: usize) -> [Range<usize>; PARTS] {
    let len = range.end - range.start;
    let cut = (range.start + (len / PARTS).next_multiple_of(align)).min(range.end);
    [range.start..cut, cut..range.end]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_are_the_same_on_one_thread_or_two() {
        let values: Vec<f64> = (0..1000).map(|i| (f64::from(i) * 0.37).sin() * 1e3).collect();
        let parts = split(0..values.len(), 4);
        let exec = crate::exec::Executor::default();
        let total = |parallel| {
            run(&exec, parallel, |m| {
                let mut acc = 0.0;
                for round in 0..50 {
                    let [s] = m.sum(|p| [values[parts[p].clone()].iter().sum::<f64>() + acc]);
                    acc = s * 1e-3 + f64::from(round);
                }
                acc
            })
        };
        assert_eq!(total(false).to_bits(), total(true).to_bits());
    }

    #[test]
    fn a_panic_in_one_thread_ends_the_team() {
        let exec = crate::exec::Executor::new(2, crate::exec::Idle::DEFAULT_SPIN);
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run(&exec, true, |m| {
                assert!(m.rank == 0, "rank 1 fails");
                for _ in 0..3 {
                    m.barrier();
                }
            });
        }));
        // Rank 1 panics and rank 0 leaves its barrier.
        assert!(result.is_err());
    }

    #[test]
    fn split_keeps_every_index_once() {
        for n in [0, 1, 2, 7, 8, 1001] {
            let [a, b] = split(3..3 + n, 2);
            assert_eq!((a.start, a.end, b.start, b.end), (3, a.end, a.end, 3 + n));
            assert!((a.end - 3) % 2 == 0 || a.end == 3 + n);
        }
    }
}
