//! Element loops on both cores with a fixed partition: each element's result is computed by
//! exactly one thread and returned in element order, so nothing depends on the thread count.

/// Below this many elements a second thread costs more than it saves.
const PARALLEL_MIN: usize = 512;

use std::sync::atomic::{AtomicUsize, Ordering};

/// 0 = automatic; otherwise the thread count every element loop uses.
static OVERRIDE: AtomicUsize = AtomicUsize::new(0);

/// Forces element loops to `threads` threads (`None` = automatic: up to 2). Results are the same
/// either way; tests use this to prove it.
pub fn set_thread_override(threads: Option<usize>) {
    OVERRIDE.store(threads.unwrap_or(0), Ordering::Relaxed);
}

/// Threads to use: the override, else `INCISE_THREADS`, else up to 2.
fn threads() -> usize {
    match OVERRIDE.load(Ordering::Relaxed) {
        0 => std::env::var("INCISE_THREADS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get().min(2)))
            .max(1),
        n => n,
    }
}

/// `(0..n).map(f)` computed on up to [`threads`] threads, results in index order.
pub(crate) fn map_elements<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let t = threads();
    if t == 1 || n < PARALLEL_MIN {
        return (0..n).map(f).collect();
    }
    let chunk = n.div_ceil(t);
    let f = &f;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..t)
            .map(|i| {
                s.spawn(move || (i * chunk..((i + 1) * chunk).min(n)).map(f).collect::<Vec<T>>())
            })
            .collect();
        handles.into_iter().flat_map(|h| h.join().expect("element loop panicked")).collect()
    })
}
