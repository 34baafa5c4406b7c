//! Element loops on both cores with a fixed partition: each element's result is computed by
//! exactly one thread and returned in element order, so nothing depends on the thread count.

/// Below this many elements (or nodes, for the per-node passes) a second thread costs more than
/// it saves (measured: scene B2, 528 elements, is faster on one thread; B3, 3,960, a third faster
/// on two).
pub(crate) const PARALLEL_MIN: usize = 1_500;

use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// 0 = automatic; otherwise the thread count every element loop uses.
static OVERRIDE: AtomicUsize = AtomicUsize::new(0);

/// Forces element loops to `threads` threads (`None` = automatic: up to 2). Results are the same
/// either way; tests use this to prove it.
pub fn set_thread_override(threads: Option<usize>) {
    OVERRIDE.store(threads.unwrap_or(0), Ordering::Relaxed);
}

/// Threads to use: the override, else `INCISE_THREADS`, else up to 2.
pub(crate) fn threads() -> usize {
    // Read once: `available_parallelism` opens cgroup files on every call (a third of a small
    // scene's step time when it was asked per element loop).
    static AUTOMATIC: OnceLock<usize> = OnceLock::new();
    match OVERRIDE.load(Ordering::Relaxed) {
        0 => *AUTOMATIC.get_or_init(|| {
            std::env::var("INCISE_THREADS")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or_else(|| {
                    std::thread::available_parallelism().map_or(1, |n| n.get().min(2))
                })
                .max(1)
        }),
        n => n,
    }
}

/// The worker threads, started once: spawning threads per element loop cost more than a small
/// scene's whole loop (stack mappings and TLB shootdowns). The calling thread does one share of
/// every loop, so the pool holds one thread fewer than a loop uses: an idle extra worker woken by
/// each loop competed for the two cores with the threads doing the work.
pub(crate) fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads().saturating_sub(1).max(1))
            .thread_name(|i| format!("incise-fem-{i}"))
            .build()
            .expect("the element-loop threads start")
    })
}

/// Jobs handed to the pool and not started yet.
static WAITING: AtomicUsize = AtomicUsize::new(0);

/// Whether a worker is lingering (see [`Pending::spawn`]).
static LINGERING: AtomicBool = AtomicBool::new(false);

/// How long a worker stays awake after its job for the next one: `INCISE_LINGER_US`
/// microseconds, 500 by default (0: sleep at once). A sleeping worker takes tens of microseconds
/// to wake here (a virtual machine), as long as a whole CG solve on a small scene; a step's loops
/// and solves follow each other closer than this. (OpenMP runtimes spin for 200 ms by default.)
fn linger_time() -> std::time::Duration {
    static LINGER: OnceLock<std::time::Duration> = OnceLock::new();
    *LINGER.get_or_init(|| {
        let micros = std::env::var("INCISE_LINGER_US").ok().and_then(|s| s.parse().ok());
        std::time::Duration::from_micros(micros.unwrap_or(500))
    })
}

/// Jobs handed to the pool within one scope and not finished yet. The caller waits for them by
/// spinning ([`Pending::wait`]) before its scope ends: left to the scope, a caller outside the
/// pool that finished its share first blocks on a condition variable, and here (a virtual
/// machine) the wake-up after the job ends costs tens of microseconds, on every element loop.
pub(crate) struct Pending(AtomicUsize);

impl Pending {
    /// No jobs yet.
    pub(crate) fn new() -> Self {
        Self(AtomicUsize::new(0))
    }

    /// Hands `job` to the pool within scope `s`. After it the worker stays awake (see
    /// [`linger_time`], a separate job that spins until more work is handed over), so the next
    /// loop's job starts at once instead of waiting for a wake-up.
    pub(crate) fn spawn<'scope>(
        &'scope self,
        s: &rayon::Scope<'scope>,
        job: impl FnOnce() + Send + 'scope,
    ) {
        self.0.fetch_add(1, Ordering::AcqRel);
        WAITING.fetch_add(1, Ordering::AcqRel);
        s.spawn(move |_| {
            WAITING.fetch_sub(1, Ordering::AcqRel);
            {
                // Counted as finished when it unwinds too: its panic reaches the caller when
                // the scope ends.
                let _finished = Finished(&self.0);
                job();
            }
            if !linger_time().is_zero() && !LINGERING.swap(true, Ordering::AcqRel) {
                pool().spawn(linger);
            }
        });
    }

    /// Spins, then yields, until every job handed over has finished.
    pub(crate) fn wait(&self) {
        wait_until(|| self.0.load(Ordering::Acquire) == 0);
    }
}

/// Spins before a waiting thread starts yielding its core (the thread it waits for may have
/// been descheduled, or not have started yet).
const SPINS_BEFORE_YIELD: u32 = 20_000;

/// Spins, then yields, until `done()`: a wait without a sleep and its wake-up.
pub(crate) fn wait_until(done: impl Fn() -> bool) {
    let mut spins = 0u32;
    while !done() {
        if spins < SPINS_BEFORE_YIELD {
            spins += 1;
            std::hint::spin_loop();
        } else {
            std::thread::yield_now();
        }
    }
}

/// Counts its job as finished when dropped.
struct Finished<'a>(&'a AtomicUsize);

impl Drop for Finished<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Spins until a job is handed to the pool or [`linger_time`] has passed.
fn linger() {
    let start = std::time::Instant::now();
    let limit = linger_time();
    while WAITING.load(Ordering::Acquire) == 0 && start.elapsed() < limit {
        for _ in 0..32 {
            std::hint::spin_loop();
        }
    }
    LINGERING.store(false, Ordering::Release);
}

/// Whether the calling thread is one of the element-loop threads (a team started there could
/// wait on a job queued behind itself).
pub(crate) fn in_pool() -> bool {
    pool().current_thread_index().is_some()
}

/// `out[i] = f(i)` for every index, on up to [`threads`] threads (contiguous chunks, one per
/// thread).
pub(crate) fn fill_elements<T: Send>(out: &mut [T], f: impl Fn(usize) -> T + Sync) {
    update_elements(out, |i, o| *o = f(i));
}

/// `f(i, &mut out[i])` for every index, partitioned like [`fill_elements`] (each entry may
/// depend on its old value).
pub(crate) fn update_elements<T: Send>(out: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
    update_runs(out, |start, run| {
        for (k, o) in run.iter_mut().enumerate() {
            f(start + k, o);
        }
    });
}

/// `f(start, run)` for contiguous runs of `out` that cover it, one per thread ([`threads`]);
/// `start` is the index of `run[0]`, always even (an element pass can pair neighbours the same
/// way whatever the thread count), and `f` can compile its whole run for wider instructions.
pub(crate) fn update_runs<T: Send>(out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync) {
    let n = out.len();
    let t = threads();
    if t == 1 || n < PARALLEL_MIN {
        f(0, out);
        return;
    }
    let chunk = n.div_ceil(t).next_multiple_of(2);
    on_chunks(out, chunk, &f);
}

/// `run(start, chunk)` for consecutive chunks of `out`, the first on the calling thread and the
/// others on the pool.
fn on_chunks<T: Send>(out: &mut [T], chunk: usize, run: &(impl Fn(usize, &mut [T]) + Sync)) {
    let (first, rest) = out.split_at_mut(chunk.min(out.len()));
    let pending = Pending::new();
    pool().in_place_scope(|s| {
        for (i, part) in rest.chunks_mut(chunk).enumerate() {
            pending.spawn(s, move || run((i + 1) * chunk, part));
        }
        run(0, first);
        pending.wait();
    });
}

/// `(0..n).map(f)` computed like [`fill_elements`], results in index order.
pub(crate) fn map_elements<T: Send + Default + Clone>(
    n: usize,
    f: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    let mut out = vec![T::default(); n];
    fill_elements(&mut out, f);
    out
}

/// `(a(), b())`, on two threads when `parallel` and more than one thread is allowed. The caller
/// makes the results independent of which thread ran what.
pub(crate) fn join_if<A: Send, B: Send>(
    parallel: bool,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    if !parallel || threads() == 1 {
        return (a(), b());
    }
    let mut second = None;
    let pending = Pending::new();
    let first = pool().in_place_scope(|s| {
        pending.spawn(s, || second = Some(b()));
        let first = a();
        pending.wait();
        first
    });
    (first, second.expect("the scope waited for its job"))
}
