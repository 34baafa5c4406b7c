//! The client for async code: the same connection as [`Client`], with forces awaited instead
//! of waited for. It is runtime-agnostic: a small thread of its own blocks on the transport (for
//! iceoryx2, its event; for zenoh, its subscriber) and hands each force to a channel that any
//! executor can await, so a driver written with tokio, async-std or a hand-rolled executor uses
//! it alike and no runtime is started for it.
//!
//! ```no_run
//! # async fn demo() -> anyhow::Result<()> {
//! use incise_client::{AsyncClient, Keys, TransportKind};
//! use incise_client::raw::RawToolPose;
//!
//! let client = AsyncClient::connect(TransportKind::Iceoryx2, &Keys::new("demo_organ")?, 0, "")?;
//! client.send_pose(&RawToolPose { sequence: 1, timestamp_ns: 1, ..RawToolPose::at(0, [0.04, 0.03, 0.05]) })?;
//! while let Some(force) = client.recv_force().await {
//!     if force.pose_sequence == 1 {
//!         println!("{:?} N", force.force);
//!         break;
//!     }
//! }
//! # Ok(())
//! # }
//! ```

use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_transport::zenoh_link::TransportError;
use incise_transport::{Client, TransportKind};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

/// Forces kept for a caller that has not awaited them; past this the oldest are dropped (the
/// newest force is the one a device renders).
const BACKLOG: usize = 256;

/// How often the receiving thread checks whether its client was dropped.
const STOP_CHECK: Duration = Duration::from_millis(50);

/// One tool's connection to a server, for async code.
pub struct AsyncClient {
    client: Arc<Client>,
    forces: flume::Receiver<RawToolForce>,
    stop: Arc<AtomicBool>,
    receiver: Option<JoinHandle<()>>,
}

impl AsyncClient {
    /// Connects as [`Client::connect`] does (a zenoh connection waits for the session to open,
    /// which takes milliseconds; call it from a blocking context if that matters) and starts
    /// the thread that receives the forces.
    pub fn connect(
        kind: TransportKind,
        keys: &Keys,
        tool: u32,
        endpoint: &str,
    ) -> Result<Self, TransportError> {
        let client = Arc::new(Client::connect(kind, keys, tool, endpoint)?);
        let (tx, forces) = flume::bounded(BACKLOG);
        let stop = Arc::new(AtomicBool::new(false));
        let receiver = {
            let (client, stop, oldest) = (Arc::clone(&client), Arc::clone(&stop), forces.clone());
            std::thread::Builder::new()
                .name("incise-client-rx".into())
                .spawn(move || {
                    while !stop.load(Ordering::Acquire) {
                        let Some(mut force) = client.recv_force(STOP_CHECK) else { continue };
                        // Full: drop the oldest to make room for the newest.
                        while let Err(flume::TrySendError::Full(f)) = tx.try_send(force) {
                            let _ = oldest.try_recv();
                            force = f;
                        }
                    }
                })
                .map_err(|e| TransportError(format!("cannot start the receiving thread: {e}")))?
        };
        Ok(Self { client, forces, stop, receiver: Some(receiver) })
    }

    /// Sends a pose; it never waits (both transports publish at once).
    pub fn send_pose(&self, pose: &RawToolPose) -> Result<(), TransportError> {
        self.client.send_pose(pose)
    }

    /// The next force the server sent, in the order they came; `None` once the connection's
    /// receiving thread has ended.
    pub async fn recv_force(&self) -> Option<RawToolForce> {
        self.forces.recv_async().await.ok()
    }

    /// The newest force already received, without waiting (older ones are discarded): what a
    /// device's servo loop renders.
    #[must_use]
    pub fn newest_force(&self) -> Option<RawToolForce> {
        self.forces.try_iter().last()
    }

    /// The blocking connection underneath (its session id, a zenoh client's scene query).
    #[must_use]
    pub fn client(&self) -> &Client {
        &self.client
    }
}

impl Drop for AsyncClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(r) = self.receiver.take() {
            let _ = r.join();
        }
    }
}
