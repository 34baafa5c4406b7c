//! iceoryx2: the shared-memory transport, for a device driver on the server's machine. Poses
//! and forces travel as the fixed-size records of `incise_protocol::raw` in iceoryx2's shared
//! memory (zero copy); after publishing, each side raises an iceoryx2 event so that the other
//! wakes at once instead of polling: a client raises `…/tool/poses` (one event for every tool),
//! the server `…/tool/<id>/force`.
//!
//! The server's ports ([`ShmPorts`]) are bound to the thread that opens them: the server opens
//! them on its haptic thread, which waits on the poses event, takes the poses, and publishes
//! each force as it computes it, so a pose reaches its force without crossing a thread. Other
//! threads wake that thread through [`ShmServer::ring`] (the same event a client raises).

#![allow(unsafe_code, reason = "iceoryx2 payloads are declared shared-memory safe")]

use crate::Faults;
use crate::zenoh_link::TransportError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use std::sync::Arc;
use std::sync::atomic::Ordering;
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

/// Waits up to `timeout` for `listener`'s event, to within the thread's timer slack, and
/// consumes what it holds. iceoryx2's own timed wait sets a socket timeout, which Linux rounds
/// up to the next scheduler tick (up to 4 ms late at 250 Hz); instead the listener's socket is
/// polled with `ppoll`, whose timeout is a high-resolution timer, then drained without blocking.
pub(crate) fn wait_for_event<S: iceoryx2::service::Service>(
    listener: &Listener<S>,
    timeout: Duration,
) where
    Listener<S>: FileDescriptorBased,
{
    #[cfg(unix)]
    if let Ok(timeout) = rustix::event::Timespec::try_from(timeout) {
        // SAFETY: the descriptor is the listener's socket, which `listener` owns and keeps open
        // for the whole borrow (this call).
        let fd = unsafe {
            std::os::fd::BorrowedFd::borrow_raw(listener.file_descriptor().native_handle())
        };
        let mut fds = [rustix::event::PollFd::new(&fd, rustix::event::PollFlags::IN)];
        let _ = rustix::event::poll(&mut fds, Some(&timeout));
    }
    #[cfg(not(unix))]
    if timeout >= Duration::from_micros(1) {
        let _ = listener.timed_wait(|_| {}, timeout);
    }
    let _ = listener.try_wait(|_| {});
}

/// The server's iceoryx2 side: what any thread may hold. The ports themselves are opened by
/// [`Self::open_ports`] on the thread that uses them.
pub struct ShmServer {
    keys: Keys,
    tools: usize,
    faults: Arc<Faults>,
    doorbell: Notifier<Shared>,
    _node: Node<Shared>,
}

impl ShmServer {
    /// Serves `keys`' scene with `tools` tools, counting refusals in `faults`. This opens the
    /// poses event (so a missing `/dev/shm` is reported here); [`Self::open_ports`] the rest.
    pub fn start(keys: &Keys, tools: usize, faults: Arc<Faults>) -> Result<Self, TransportError> {
        let node = node::<Shared>()?;
        let doorbell = event(&node, &keys.poses_ready())?
            .notifier_builder()
            .create()
            .map_err(|e| error("cannot raise the poses event", e))?;
        Ok(Self { keys: keys.clone(), tools, faults, doorbell, _node: node })
    }

    /// Wakes the thread that holds the ports (from a pose that came another way, or to stop).
    pub fn ring(&self) {
        let _ = self.doorbell.notify();
    }

    /// Opens the server's ports, bound to the calling thread: a subscriber to every tool's
    /// poses, a listener on the poses event, and every tool's force publisher and notifier.
    pub fn open_ports(&self) -> Result<ShmPorts, TransportError> {
        let node = node::<ipc::Service>()?;
        let mut poses = Vec::with_capacity(self.tools);
        let mut forces = Vec::with_capacity(self.tools);
        for t in 0..self.tools as u32 {
            let key = self.keys.tool_pose(t);
            poses.push(
                records::<ipc::Service, PoseSample>(&node, &key)?
                    .subscriber_builder()
                    .buffer_size(BUFFER)
                    .create()
                    .map_err(|e| error(&format!("cannot subscribe to {key}"), e))?,
            );
            let key = self.keys.tool_force(t);
            let publisher = records::<ipc::Service, ForceSample>(&node, &key)?
                .publisher_builder()
                .create()
                .map_err(|e| error(&format!("cannot publish on {key}"), e))?;
            let notifier = event(&node, &key)?
                .notifier_builder()
                .create()
                .map_err(|e| error(&format!("cannot notify on {key}"), e))?;
            forces.push((publisher, notifier));
        }
        let listener = event(&node, &self.keys.poses_ready())?
            .listener_builder()
            .create()
            .map_err(|e| error("cannot listen for poses", e))?;
        Ok(ShmPorts { poses, listener, forces, faults: Arc::clone(&self.faults), _node: node })
    }
}

/// The server's iceoryx2 ports, bound to the thread that opened them ([`ShmServer::open_ports`]).
/// Receiving and publishing take no lock: the subscriber and publisher queues are lock-free in
/// shared memory, and an event is one datagram on a non-blocking socket.
pub struct ShmPorts {
    poses: Vec<Subscriber<ipc::Service, PoseSample, ()>>,
    listener: Listener<ipc::Service>,
    forces: Vec<(Publisher<ipc::Service, ForceSample, ()>, Notifier<ipc::Service>)>,
    faults: Arc<Faults>,
    _node: Node<ipc::Service>,
}

impl ShmPorts {
    /// Waits up to `timeout` for the poses event (a client's, or [`ShmServer::ring`]).
    pub fn wait(&self, timeout: Duration) {
        wait_for_event(&self.listener, timeout);
    }

    /// Hands every pose received since the last call to `accept` (which returns false for a
    /// tool the scene lacks); a pose on another tool's service, and an unknown tool, are counted
    /// in the faults and dropped.
    pub fn receive(&self, mut accept: impl FnMut(&RawToolPose) -> bool) {
        for (tool, subscriber) in self.poses.iter().enumerate() {
            while let Ok(Some(sample)) = subscriber.receive() {
                let pose = sample.payload().0;
                if pose.tool_id as usize != tool {
                    self.faults.mismatched.fetch_add(1, Ordering::Relaxed);
                } else if !accept(&pose) {
                    self.faults.unknown_tool.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
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
