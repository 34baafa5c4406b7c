//! The network side: a tokio runtime of one worker thread (`incise-net`) that publishes what the
//! physics thread hands over (each frame's statistics, its cuts), so that the physics never
//! waits on a socket. The physics thread posts into a bounded queue without waiting
//! ([`Outbox::post`]); when the network falls behind, messages are dropped and counted rather
//! than slowing the physics.
//!
//! Two paths stay off this runtime on purpose. Poses arrive on zenoh's own runtime and
//! iceoryx2's event, straight into the haptic loop's cells. Forces leave from the haptic thread
//! (iceoryx2) or from a plain thread it unparks (zenoh): waking a task on a tokio runtime takes
//! the runtime's scheduling lock, which the haptic thread must never wait on.

use incise_protocol::v1;
use incise_transport::ServerSide;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::sync::mpsc;

/// Messages the physics thread may have waiting for the network: a few seconds of frames.
const QUEUE: usize = 4096;

/// What the physics thread hands to the network.
#[derive(Clone, Debug)]
pub enum Outgoing {
    /// A frame's statistics.
    Frame(v1::FrameStats),
    /// A cut.
    Cut(v1::CutEvent),
}

/// The physics thread's end of the queue.
#[derive(Clone, Debug)]
pub struct Outbox {
    tx: mpsc::Sender<Outgoing>,
    dropped: Arc<AtomicU64>,
}

impl Outbox {
    /// Queues a message without waiting; a full queue drops it (counted in
    /// [`Network::dropped`]).
    pub fn post(&self, message: Outgoing) {
        if self.tx.try_send(message).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The network runtime and its queue.
pub struct Network {
    runtime: tokio::runtime::Runtime,
    outbox: Outbox,
}

impl Network {
    /// Starts the runtime and the task that publishes the queue on `transports`.
    pub fn start(transports: Arc<ServerSide>) -> std::io::Result<Self> {
        // Multi-thread with one worker: zenoh's blocking calls may run inside it (a
        // current-thread runtime would refuse them).
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("incise-net")
            .build()?;
        let (tx, mut rx) = mpsc::channel(QUEUE);
        runtime.spawn(async move {
            while let Some(message) = rx.recv().await {
                match message {
                    Outgoing::Frame(stats) => transports.send_frame(&stats),
                    Outgoing::Cut(cut) => transports.send_cut(&cut),
                }
            }
        });
        Ok(Self { runtime, outbox: Outbox { tx, dropped: Arc::new(AtomicU64::new(0)) } })
    }

    /// A handle to post messages with.
    #[must_use]
    pub fn outbox(&self) -> Outbox {
        self.outbox.clone()
    }

    /// Messages dropped because the queue was full.
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.outbox.dropped.load(Ordering::Relaxed)
    }

    /// Stops the runtime, giving what is queued a moment to go out.
    pub fn stop(self) {
        drop(self.outbox);
        self.runtime.shutdown_timeout(Duration::from_millis(200));
    }
}
