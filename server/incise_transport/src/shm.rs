//! iceoryx2: the shared-memory transport, for a device driver on the server's machine. Poses
//! and forces travel as the fixed-size records of `incise_protocol::raw` in iceoryx2's shared
//! memory (zero copy); after publishing, each side raises an iceoryx2 event so that the other
//! wakes at once instead of polling: a client raises `…/tool/poses` (one event for every tool),
//! the server `…/tool/<id>/force`.
//!
//! The server's receiving thread owns its subscribers and its listener; its publishers are the
//! thread-safe kind, so the thread that sends forces may be any.

#![allow(unsafe_code, reason = "iceoryx2 payloads are declared shared-memory safe")]

use crate::zenoh_link::TransportError;
use crate::{Faults, PoseHandler, TransportKind};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

/// A pose in shared memory.
#[repr(transparent)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseSample(pub RawToolPose);

/// A force in shared memory.
#[repr(transparent)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ForceSample(pub RawToolForce);

// SAFETY: `RawToolPose` is `#[repr(C)]`, holds only integers and floats (no pointers, handles or
// indices into anything outside it), and has the layout `include/incise.h` declares (a test
// compares them); the type name is the contract's, the same in every language.
unsafe impl ZeroCopySend for PoseSample {
    unsafe fn type_name() -> &'static str {
        "incise.v1.RawToolPose"
    }
}

// SAFETY: as for `PoseSample`: `RawToolForce` is a `#[repr(C)]` record of integers and floats.
unsafe impl ZeroCopySend for ForceSample {
    unsafe fn type_name() -> &'static str {
        "incise.v1.RawToolForce"
    }
}

/// Samples a subscriber keeps before the oldest is overwritten: the newest pose or force is the
/// one that matters.
const BUFFER: usize = 16;

/// How long the receiving thread waits for an event before it checks whether to stop.
const STOP_CHECK: Duration = Duration::from_millis(20);

fn error(what: &str, e: impl std::fmt::Debug) -> TransportError {
    TransportError(format!("iceoryx2: {what}: {e:?}"))
}

fn name(key: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(key).map_err(|e| error(&format!("bad service name {key}"), e))
}

/// A node of service kind `S`.
pub(crate) fn node<S: iceoryx2::service::Service>() -> Result<Node<S>, TransportError> {
    // Without a config file iceoryx2 warns that it uses its defaults, which are ours.
    set_log_level(LogLevel::Error);
    NodeBuilder::new().create::<S>().map_err(|e| error("cannot create a node", e))
}

/// The publish–subscribe service of records `T` on `key`, with the settings every side uses.
pub(crate) fn records<S: iceoryx2::service::Service, T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<S>,
    key: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>, TransportError>
{
    node.service_builder(&name(key)?)
        .publish_subscribe::<T>()
        .subscriber_max_buffer_size(BUFFER)
        .history_size(0)
        .enable_safe_overflow(true)
        .max_publishers(8)
        .max_subscribers(8)
        .open_or_create()
        .map_err(|e| error(&format!("cannot open {key}"), e))
}

/// The event service on `key`.
pub(crate) fn event<S: iceoryx2::service::Service>(
    node: &Node<S>,
    key: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<S>, TransportError> {
    node.service_builder(&name(key)?)
        .event()
        .open_or_create()
        .map_err(|e| error(&format!("cannot open the event {key}"), e))
}

type Shared = ipc_threadsafe::Service;

/// The server's iceoryx2 side.
pub struct ShmServer {
    forces: Vec<(Publisher<Shared, ForceSample, ()>, Notifier<Shared>)>,
    faults: Arc<Faults>,
    stop: Arc<AtomicBool>,
    receiver: Option<JoinHandle<()>>,
    _node: Node<Shared>,
}

impl ShmServer {
    /// Serves `keys`' scene with `tools` tools: a thread receives poses into `handler`.
    pub fn start(
        keys: &Keys,
        tools: usize,
        handler: PoseHandler,
        faults: Arc<Faults>,
    ) -> Result<Self, TransportError> {
        let node = node::<Shared>()?;
        let mut forces = Vec::with_capacity(tools);
        for t in 0..tools as u32 {
            let key = keys.tool_force(t);
            let publisher = records::<Shared, ForceSample>(&node, &key)?
                .publisher_builder()
                .create()
                .map_err(|e| error(&format!("cannot publish on {key}"), e))?;
            let notifier = event(&node, &key)?
                .notifier_builder()
                .create()
                .map_err(|e| error(&format!("cannot notify on {key}"), e))?;
            forces.push((publisher, notifier));
        }
        let stop = Arc::new(AtomicBool::new(false));
        // The receiving thread opens its own ports, and reports whether it could.
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let receiver = {
            let (keys, stop, faults) = (keys.clone(), Arc::clone(&stop), Arc::clone(&faults));
            std::thread::Builder::new()
                .name("incise-shm-rx".into())
                .spawn(move || receive(&keys, tools, &handler, &faults, &stop, &ready_tx))
                .map_err(|e| error("cannot start the receiving thread", e))?
        };
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e),
            Err(_) => return Err(TransportError("iceoryx2: the receiving thread died".into())),
        }
        Ok(Self { forces, faults, stop, receiver: Some(receiver), _node: node })
    }

    /// Publishes a tool's force and wakes its client.
    pub fn send_force(&self, force: &RawToolForce) {
        let Some((publisher, notifier)) = self.forces.get(force.tool_id as usize) else { return };
        let sent = publisher.send_copy(ForceSample(*force)).is_ok() && notifier.notify().is_ok();
        if !sent {
            self.faults.send_failed.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Drop for ShmServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(r) = self.receiver.take() {
            let _ = r.join();
        }
    }
}

/// The receiving thread: wakes on the poses event (or every [`STOP_CHECK`]) and drains every
/// tool's subscriber.
fn receive(
    keys: &Keys,
    tools: usize,
    handler: &PoseHandler,
    faults: &Faults,
    stop: &AtomicBool,
    ready: &std::sync::mpsc::Sender<Result<(), TransportError>>,
) {
    let ports = (|| {
        let node = node::<ipc::Service>()?;
        let subscribers = (0..tools as u32)
            .map(|t| {
                let key = keys.tool_pose(t);
                records::<ipc::Service, PoseSample>(&node, &key)?
                    .subscriber_builder()
                    .buffer_size(BUFFER)
                    .create()
                    .map_err(|e| error(&format!("cannot subscribe to {key}"), e))
            })
            .collect::<Result<Vec<Subscriber<ipc::Service, PoseSample, ()>>, _>>()?;
        let listener: Listener<ipc::Service> = event(&node, &keys.poses_ready())?
            .listener_builder()
            .create()
            .map_err(|e| error("cannot listen for poses", e))?;
        Ok((node, subscribers, listener))
    })();
    let (_node, subscribers, listener) = match ports {
        Ok(p) => {
            let _ = ready.send(Ok(()));
            p
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    while !stop.load(Ordering::Acquire) {
        // Events only wake the thread; the subscribers hold the data.
        let _ = listener.timed_wait(|_| {}, STOP_CHECK);
        for (tool, subscriber) in subscribers.iter().enumerate() {
            while let Ok(Some(sample)) = subscriber.receive() {
                let pose = sample.payload().0;
                if pose.tool_id as usize != tool {
                    faults.mismatched.fetch_add(1, Ordering::Relaxed);
                } else if !handler(TransportKind::Iceoryx2, &pose) {
                    faults.unknown_tool.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}
