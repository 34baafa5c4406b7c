//! Stopping with whoever started the process (`--stop-with-parent`): a test harness, a
//! simulator's front end or a shell script that dies without stopping its children — killed by
//! a signal, so that no destructor ran — would otherwise leave a server or router running,
//! holding its ports and a core. On Linux an orphan is adopted by init or a subreaper, so its
//! parent's process id changes; the main loop asks at each turn. The parent is noted first thing
//! in `main`, before the process can be reached: a parent killed while the server was still
//! starting would otherwise go unnoticed. A process whose parent is already init has no starter
//! left to wait for.

/// The parent this process started under, when it should stop once that parent is gone.
#[derive(Clone, Copy, Debug)]
pub struct ParentWatch(Option<u32>);

impl ParentWatch {
    /// Watches the current parent when `enabled`; otherwise never reports it gone.
    #[must_use]
    pub fn new(enabled: bool) -> Self {
        Self(enabled.then(std::os::unix::process::parent_id))
    }

    /// True once the process has a different parent than it started with, or started as an
    /// orphan already.
    #[must_use]
    pub fn parent_gone(&self) -> bool {
        self.0.is_some_and(|p| p == 1 || std::os::unix::process::parent_id() != p)
    }
}
