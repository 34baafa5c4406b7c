//! The executor: the threads a simulation's element loops and solves run on, handed to it as a
//! value. Two simulations in one process each get their own (or share one on purpose, by cloning
//! it); nothing here is global.
//!
//! Every loop is cut into a fixed partition whose pieces are computed by exactly one thread and
//! combined in piece order, so results are bit-identical whatever the thread count.
//!
//! How idle workers wait matters on a small machine. A sleeping worker takes tens of
//! microseconds to wake in a virtual machine, as long as a whole CG solve on a small scene, so by
//! default a worker stays awake ([`Idle::Spin`]) for 0.5 ms after a job for the next one. But a
//! spinning worker holds its core: where another real-time thread (the 1 kHz haptic loop) needs
//! that core, [`Idle::Sleep`] gives it back at once, and `incise-bench coexist` measures what
//! each choice costs both sides.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

/// Below this many elements (or nodes, for the per-node passes) a second thread costs more than
/// it saves: scene B2 (528 elements) runs faster on one thread, B3 (3,960) faster on two.
pub(crate) const PARALLEL_MIN: usize = 1_500;

/// How an idle worker (and a thread waiting for a worker) passes the time between jobs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Idle {
    /// Stay awake this long after a job, spinning, so the next job starts without a wake-up.
    Spin(Duration),
    /// Go to sleep at once: the core is free for other threads, and each job pays a wake-up.
    Sleep,
}

impl Idle {
    /// The default: spin for 0.5 ms (a step's loops and solves follow each other closer than
    /// that; OpenMP runtimes spin for 200 ms by default).
    pub const DEFAULT_SPIN: Self = Self::Spin(Duration::from_micros(500));

    fn linger(self) -> Duration {
        match self {
            Self::Spin(d) => d,
            Self::Sleep => Duration::ZERO,
        }
    }
}

/// The threads a simulation runs on: a count, how idle workers wait, and (created on first use)
/// the worker pool. Cloning shares the pool.
#[derive(Clone)]
pub struct Executor {
    inner: Arc<Inner>,
}

struct Inner {
    threads: usize,
    idle: Idle,
    /// The workers, started on first use: spawning threads per element loop cost more than a
    /// small scene's whole loop (stack mappings and TLB shootdowns). The calling thread does one
    /// share of every loop, so the pool holds one thread fewer than a loop uses.
    pool: OnceLock<rayon::ThreadPool>,
    /// Jobs handed to the pool and not started yet.
    waiting: AtomicUsize,
    /// Whether a worker is lingering (see [`Pending::spawn`]).
    lingering: AtomicBool,
}

impl std::fmt::Debug for Executor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Executor")
            .field("threads", &self.inner.threads)
            .field("idle", &self.inner.idle)
            .finish_non_exhaustive()
    }
}

impl Default for Executor {
    /// Up to two threads (the machine's cores, at most two), spinning idle workers: the fastest
    /// physics where nothing else needs the cores. Beside a real-time thread use
    /// [`Executor::beside_realtime_thread`].
    fn default() -> Self {
        Self::new(Self::available_threads(), Idle::DEFAULT_SPIN)
    }
}

impl Executor {
    /// An executor of `threads` threads (at least one; the caller's thread counts as one) whose
    /// idle workers behave as `idle` says.
    #[must_use]
    pub fn new(threads: usize, idle: Idle) -> Self {
        Self {
            inner: Arc::new(Inner {
                threads: threads.max(1),
                idle,
                pool: OnceLock::new(),
                waiting: AtomicUsize::new(0),
                lingering: AtomicBool::new(false),
            }),
        }
    }

    /// The executor for a process that also runs a 1 kHz real-time thread (the server's haptic
    /// loop): one thread fewer than the cores, at least one, and workers that sleep when idle,
    /// so that thread always finds a core: on two cores, a probe thread waking every millisecond
    /// beside the physics on one thread keeps a period jitter close to its jitter alone, and
    /// several times worse beside the physics on two, for a physics only somewhat slower on one
    /// (`incise-bench coexist`; figures in `docs/benchmarks.md`).
    #[must_use]
    pub fn beside_realtime_thread() -> Self {
        let cores = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
        Self::new(cores.saturating_sub(1).clamp(1, 2), Idle::Sleep)
    }

    /// Everything on the calling thread: no worker is ever started.
    #[must_use]
    pub fn single_thread() -> Self {
        Self::new(1, Idle::Sleep)
    }

    /// `threads` and `idle` where given, else the defaults ([`Self::available_threads`],
    /// [`Idle::DEFAULT_SPIN`]).
    #[must_use]
    pub fn configured(threads: Option<usize>, idle: Option<Idle>) -> Self {
        Self::new(
            threads.unwrap_or_else(Self::available_threads),
            idle.unwrap_or(Idle::DEFAULT_SPIN),
        )
    }

    /// The machine's cores, at most two (what the element loops are cut for).
    #[must_use]
    pub fn available_threads() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get().min(2))
    }

    /// Threads every loop uses (the caller's included).
    #[must_use]
    pub fn threads(&self) -> usize {
        self.inner.threads
    }

    /// How idle workers wait.
    #[must_use]
    pub fn idle(&self) -> Idle {
        self.inner.idle
    }

    fn pool(&self) -> &rayon::ThreadPool {
        self.inner.pool.get_or_init(|| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(self.inner.threads.saturating_sub(1).max(1))
                .thread_name(|i| format!("incise-fem-{i}"))
                .build()
                .expect("the element-loop threads start")
        })
    }

    /// Whether the calling thread is one of this executor's workers (a team started there could
    /// wait on a job queued behind itself).
    pub(crate) fn in_pool(&self) -> bool {
        self.inner.pool.get().is_some_and(|p| p.current_thread_index().is_some())
    }

    /// Spins (if idle workers spin), then yields, until `done()`.
    pub(crate) fn wait_until(&self, done: impl Fn() -> bool) {
        wait_until(self.inner.idle, done);
    }

    /// `out[i] = f(i)` for every index, on up to [`Self::threads`] threads (contiguous chunks,
    /// one per thread).
    pub(crate) fn fill_elements<T: Send>(&self, out: &mut [T], f: impl Fn(usize) -> T + Sync) {
        self.update_elements(out, |i, o| *o = f(i));
    }

    /// `f(i, &mut out[i])` for every index, partitioned like [`Self::fill_elements`] (each entry
    /// may depend on its old value).
    pub(crate) fn update_elements<T: Send>(&self, out: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
        self.update_runs(out, |start, run| {
            for (k, o) in run.iter_mut().enumerate() {
                f(start + k, o);
            }
        });
    }

    /// `f(start, run)` for contiguous runs of `out` that cover it, one per thread; `start` is the
    /// index of `run[0]`, always even (an element pass can pair neighbours the same way whatever
    /// the thread count), and `f` can compile its whole run for wider instructions.
    pub(crate) fn update_runs<T: Send>(&self, out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync) {
        let n = out.len();
        let t = self.threads();
        if t == 1 || n < PARALLEL_MIN {
            f(0, out);
            return;
        }
        let chunk = n.div_ceil(t).next_multiple_of(2);
        let (first, rest) = out.split_at_mut(chunk.min(n));
        let pending = Pending::new();
        let f = &f;
        self.pool().in_place_scope(|s| {
            for (i, part) in rest.chunks_mut(chunk).enumerate() {
                pending.spawn(self, s, move || f((i + 1) * chunk, part));
            }
            f(0, first);
            pending.wait(self);
        });
    }

    /// `(0..n).map(f)` computed like [`Self::fill_elements`], results in index order.
    pub(crate) fn map_elements<T: Send + Default + Clone>(
        &self,
        n: usize,
        f: impl Fn(usize) -> T + Sync,
    ) -> Vec<T> {
        let mut out = vec![T::default(); n];
        self.fill_elements(&mut out, f);
        out
    }

    /// `(a(), b())`, on two threads when `parallel` and more than one thread is allowed. The
    /// caller makes the results independent of which thread ran what.
    pub(crate) fn join_if<A: Send, B: Send>(
        &self,
        parallel: bool,
        a: impl FnOnce() -> A + Send,
        b: impl FnOnce() -> B + Send,
    ) -> (A, B) {
        if !parallel || self.threads() == 1 {
            return (a(), b());
        }
        let mut second = None;
        let pending = Pending::new();
        let first = self.pool().in_place_scope(|s| {
            pending.spawn(self, s, || second = Some(b()));
            let first = a();
            pending.wait(self);
            first
        });
        (first, second.expect("the scope waited for its job"))
    }

    /// Runs `job` on a worker within scope `s`, counted by `pending`.
    pub(crate) fn spawn_counted<'scope>(
        &'scope self,
        pending: &'scope Pending,
        s: &rayon::Scope<'scope>,
        job: impl FnOnce() + Send + 'scope,
    ) {
        pending.spawn(self, s, job);
    }

    /// The pool's `in_place_scope`, for a caller that hands it jobs itself.
    pub(crate) fn scope<'scope, R>(&self, body: impl FnOnce(&rayon::Scope<'scope>) -> R) -> R {
        self.pool().in_place_scope(body)
    }
}

/// Spins before a waiting thread starts yielding its core (the thread it waits for may have
/// been descheduled, or not have started yet).
const SPINS_BEFORE_YIELD: u32 = 20_000;

/// Waits until `done()`: with spinning workers, spins and then yields (a wait without a sleep
/// and its wake-up); with sleeping ones, yields from the start, so a thread that needs this core
/// gets it.
pub(crate) fn wait_until(idle: Idle, done: impl Fn() -> bool) {
    let spin_limit = if matches!(idle, Idle::Sleep) { 0 } else { SPINS_BEFORE_YIELD };
    let mut spins = 0u32;
    while !done() {
        if spins < spin_limit {
            spins += 1;
            std::hint::spin_loop();
        } else {
            std::thread::yield_now();
        }
    }
}

/// Jobs handed to the pool within one scope and not finished yet. The caller waits for them
/// ([`Pending::wait`]) before its scope ends: left to the scope, a caller outside the pool that
/// finished its share first blocks on a condition variable, and here (a virtual machine) the
/// wake-up after the job ends costs tens of microseconds, on every element loop.
pub(crate) struct Pending(AtomicUsize);

impl Pending {
    /// No jobs yet.
    pub(crate) fn new() -> Self {
        Self(AtomicUsize::new(0))
    }

    /// Hands `job` to `exec`'s pool within scope `s`. After it a spinning worker stays awake (a
    /// separate job that spins until more work is handed over or the linger time passes), so
    /// the next loop's job starts at once instead of waiting for a wake-up.
    fn spawn<'scope>(
        &'scope self,
        exec: &'scope Executor,
        s: &rayon::Scope<'scope>,
        job: impl FnOnce() + Send + 'scope,
    ) {
        let inner = &*exec.inner;
        self.0.fetch_add(1, Ordering::AcqRel);
        inner.waiting.fetch_add(1, Ordering::AcqRel);
        s.spawn(move |_| {
            inner.waiting.fetch_sub(1, Ordering::AcqRel);
            {
                // Counted as finished when it unwinds too: its panic reaches the caller when
                // the scope ends.
                let _finished = Finished(&self.0);
                job();
            }
            let linger = inner.idle.linger();
            if !linger.is_zero() && !inner.lingering.swap(true, Ordering::AcqRel) {
                let inner = Arc::clone(&exec.inner);
                exec.pool().spawn(move || linger_for(&inner, linger));
            }
        });
    }

    /// Waits until every job handed over has finished.
    pub(crate) fn wait(&self, exec: &Executor) {
        exec.wait_until(|| self.0.load(Ordering::Acquire) == 0);
    }
}

/// Counts its job as finished when dropped.
struct Finished<'a>(&'a AtomicUsize);

impl Drop for Finished<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Spins until a job is handed to the pool or `limit` has passed.
fn linger_for(inner: &Inner, limit: Duration) {
    let start = std::time::Instant::now();
    while inner.waiting.load(Ordering::Acquire) == 0 && start.elapsed() < limit {
        for _ in 0..32 {
            std::hint::spin_loop();
        }
    }
    inner.lingering.store(false, Ordering::Release);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loops_give_the_same_results_on_one_thread_or_two_and_sleeping_or_spinning() {
        let n = 4 * PARALLEL_MIN + 3;
        let f = |i: usize| (i as f64 * 0.37).sin();
        let one = Executor::single_thread().map_elements(n, f);
        for idle in [Idle::Sleep, Idle::DEFAULT_SPIN] {
            let exec = Executor::new(2, idle);
            assert_eq!(exec.map_elements(n, f), one);
            let (a, b) = exec.join_if(true, || f(1), || f(2));
            assert_eq!((a, b), (f(1), f(2)));
        }
    }

    #[test]
    fn beside_a_realtime_thread_the_physics_leaves_a_core_and_sleeps() {
        let exec = Executor::beside_realtime_thread();
        let cores = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
        assert_eq!(exec.idle(), Idle::Sleep);
        assert!(exec.threads() >= 1);
        assert!(
            cores == 1 || exec.threads() < cores,
            "{} threads on {cores} cores",
            exec.threads()
        );
    }

    #[test]
    fn two_executors_have_their_own_threads() {
        let a = Executor::new(2, Idle::Sleep);
        let b = Executor::new(1, Idle::Sleep);
        assert_eq!((a.threads(), b.threads()), (2, 1));
        let names = a.map_elements(2 * PARALLEL_MIN, |_| {
            std::thread::current().name().unwrap_or_default().to_owned()
        });
        assert!(
            names.iter().any(|n| n.starts_with("incise-fem-")),
            "the second half ran on a worker"
        );
        let _ = b.map_elements(2 * PARALLEL_MIN, |i| i);
        let _ = b.join_if(true, || 1, || 2);
        assert!(b.inner.pool.get().is_none(), "a one-thread executor starts no worker");
        let c = a.clone();
        assert!(Arc::ptr_eq(&a.inner, &c.inner), "a clone shares the pool");
    }
}
