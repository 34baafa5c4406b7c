//! A client's side of either transport, for one tool: send poses, receive the forces that
//! answer them, ask for the scene's description.

use crate::TransportKind;
use crate::shm::{ForceSample, PoseSample, event, node, records};
use crate::zenoh_link::{Endpoints, TransportError};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher as ShmPublisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_protocol::v1;
use prost::Message;
use std::time::{Duration, Instant};
use zenoh::Wait;

/// One tool's connection to a server.
#[allow(clippy::large_enum_variant, reason = "one per tool, made once")]
pub enum Client {
    /// Over zenoh.
    Zenoh(ZenohClient),
    /// Over iceoryx2 shared memory.
    Iceoryx2(ShmClient),
}

impl Client {
    /// Connects to the server of `keys`' scene to drive tool `tool`: over zenoh to `endpoint`
    /// (`tcp/HOST:PORT`), or over iceoryx2 on this machine (`endpoint` unused).
    pub fn connect(
        kind: TransportKind,
        keys: &Keys,
        tool: u32,
        endpoint: &str,
    ) -> Result<Self, TransportError> {
        Ok(match kind {
            TransportKind::Zenoh => Self::Zenoh(ZenohClient::connect(keys, tool, endpoint)?),
            TransportKind::Iceoryx2 => Self::Iceoryx2(ShmClient::connect(keys, tool)?),
        })
    }

    /// Connects over zenoh as `endpoints` say (a configuration file, a router) to drive tool
    /// `tool`.
    pub fn connect_zenoh(
        keys: &Keys,
        tool: u32,
        endpoints: &Endpoints,
    ) -> Result<Self, TransportError> {
        Ok(Self::Zenoh(ZenohClient::connect_with(keys, tool, endpoints)?))
    }

    /// Sends a pose, as this connection's session unless the pose names one
    /// ([`RawToolPose::client`]).
    pub fn send_pose(&self, pose: &RawToolPose) -> Result<(), TransportError> {
        match self {
            Self::Zenoh(c) => {
                let pose = stamped(pose, c.session);
                c.send_bytes(&v1::ToolPose::from(&pose).encode_to_vec())
            }
            Self::Iceoryx2(c) => c.send_pose(pose),
        }
    }

    /// This connection's session id: what its poses carry in [`RawToolPose::client`] (the
    /// server lets one session drive a tool at a time).
    #[must_use]
    pub fn session(&self) -> u32 {
        match self {
            Self::Zenoh(c) => c.session,
            Self::Iceoryx2(c) => c.session,
        }
    }

    /// The next force the server sent, waiting up to `timeout`.
    #[must_use]
    pub fn recv_force(&self, timeout: Duration) -> Option<RawToolForce> {
        match self {
            Self::Zenoh(c) => c.recv_force(timeout),
            Self::Iceoryx2(c) => c.recv_force(timeout),
        }
    }
}

/// Messages of one kind a zenoh client watches (frame statistics, cuts): what a viewer shows.
pub struct Watch<M> {
    messages: flume::Receiver<M>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
}

impl<M> Watch<M> {
    /// The messages received and not yet taken (the newest 8,192 when more were not taken).
    pub fn drain(&self) -> impl Iterator<Item = M> + '_ {
        self.messages.try_iter()
    }

    /// The next message, waiting up to `timeout`.
    #[must_use]
    pub fn recv_timeout(&self, timeout: Duration) -> Option<M> {
        self.messages.recv_timeout(timeout).ok()
    }
}

/// Forces a zenoh client holds that it has not read: 1 s of a 1 kHz haptic loop.
const FORCE_QUEUE: usize = 1024;
/// Messages a watch holds that were not taken: 8 s of 1 kHz frame statistics.
const WATCH_QUEUE: usize = 8192;

/// Queues `item`, first dropping the oldest one held when the queue is full: a client that
/// never reads (a viewer's connection, which has a tool's forces too) or stops reading holds a
/// bounded queue of the newest messages, not the whole session's.
fn keep_newest<T>(tx: &flume::Sender<T>, rx: &flume::Receiver<T>, item: T) {
    let mut item = item;
    loop {
        match tx.try_send(item) {
            Ok(()) | Err(flume::TrySendError::Disconnected(_)) => return,
            Err(flume::TrySendError::Full(back)) => {
                item = back;
                let _ = rx.try_recv();
            }
        }
    }
}

/// A random non-zero session id for a new connection.
fn new_session() -> u32 {
    use std::hash::BuildHasher;
    let seed = (std::process::id(), std::time::SystemTime::now(), Instant::now());
    let id = std::collections::hash_map::RandomState::new().hash_one(seed) as u32;
    id.max(1)
}

/// `pose` as session `session`'s, unless it names its own.
fn stamped(pose: &RawToolPose, session: u32) -> RawToolPose {
    RawToolPose { client: if pose.client == 0 { session } else { pose.client }, ..*pose }
}

/// A zenoh client.
pub struct ZenohClient {
    session: u32,
    pose: zenoh::pubsub::Publisher<'static>,
    forces: flume::Receiver<RawToolForce>,
    _forces: zenoh::pubsub::Subscriber<()>,
    info: String,
    stats: String,
    zenoh: zenoh::Session,
}

impl ZenohClient {
    /// Connects to `endpoint` for tool `tool`.
    pub fn connect(keys: &Keys, tool: u32, endpoint: &str) -> Result<Self, TransportError> {
        Self::connect_with(keys, tool, &Endpoints::connect_to(endpoint))
    }

    /// Connects as `endpoints` say (a zenoh configuration file with TLS certificates, a
    /// router to go through) for tool `tool`.
    pub fn connect_with(
        keys: &Keys,
        tool: u32,
        endpoints: &Endpoints,
    ) -> Result<Self, TransportError> {
        let session = endpoints.open("client")?;
        let key = keys.tool_pose(tool);
        let pose = session
            .declare_publisher(key.clone())
            .congestion_control(zenoh::qos::CongestionControl::Drop)
            .priority(zenoh::qos::Priority::RealTime)
            .express(true)
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot publish on {key}: {e}")))?;
        let (tx, forces) = flume::bounded(FORCE_QUEUE);
        let oldest = forces.clone();
        let force_key = keys.tool_force(tool);
        let subscriber = session
            .declare_subscriber(force_key.clone())
            .callback(move |sample| {
                if let Ok(f) = v1::ToolForce::decode(&*sample.payload().to_bytes()) {
                    keep_newest(&tx, &oldest, RawToolForce::from(&f));
                }
            })
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot subscribe to {force_key}: {e}")))?;
        Ok(Self {
            session: new_session(),
            pose,
            forces,
            _forces: subscriber,
            info: keys.info(),
            stats: keys.stats(),
            zenoh: session,
        })
    }

    /// Watches the messages of type `M` published on `key` (such as `Keys::frame` with
    /// `v1::FrameStats`, or `Keys::cut` with `v1::CutEvent`); messages that do not decode as
    /// `M` are skipped.
    pub fn watch<M: Message + Default + Send + 'static>(
        &self,
        key: &str,
    ) -> Result<Watch<M>, TransportError> {
        let (tx, messages) = flume::bounded(WATCH_QUEUE);
        let oldest = messages.clone();
        let subscriber = self
            .zenoh
            .declare_subscriber(key.to_owned())
            .callback(move |sample| {
                if let Ok(m) = M::decode(&*sample.payload().to_bytes()) {
                    keep_newest(&tx, &oldest, m);
                }
            })
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot subscribe to {key}: {e}")))?;
        Ok(Watch { messages, _subscriber: subscriber })
    }

    /// Publishes `bytes` on the tool's pose key, whatever they are (a test of the server's
    /// defences sends garbage this way).
    pub fn send_bytes(&self, bytes: &[u8]) -> Result<(), TransportError> {
        self.pose
            .put(bytes.to_vec())
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot send a pose: {e}")))
    }

    /// The next force the server sent, waiting up to `timeout`.
    #[must_use]
    pub fn recv_force(&self, timeout: Duration) -> Option<RawToolForce> {
        self.forces.recv_timeout(timeout).ok()
    }

    /// Asks the server for its scene's description.
    pub fn scene_info(&self, timeout: Duration) -> Result<v1::SceneInfo, TransportError> {
        self.ask(&self.info, timeout)
    }

    /// Asks the server how it is doing.
    pub fn server_stats(&self, timeout: Duration) -> Result<v1::ServerStats, TransportError> {
        self.ask(&self.stats, timeout)
    }

    /// Queries `key` and decodes the first reply as an `M`.
    fn ask<M: Message + Default>(&self, key: &str, timeout: Duration) -> Result<M, TransportError> {
        let replies = self
            .zenoh
            .get(key.to_owned())
            .timeout(timeout)
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot ask {key}: {e}")))?;
        let reply = replies
            .recv_timeout(timeout)
            .map_err(|e| TransportError(format!("zenoh: {key}: {e}")))?
            .ok_or_else(|| TransportError(format!("no server answered {key}")))?;
        let sample =
            reply.result().map_err(|e| TransportError(format!("{key}: an error reply: {e:?}")))?;
        M::decode(&*sample.payload().to_bytes()).map_err(|e| {
            TransportError(format!("{key}: not a {}: {e}", std::any::type_name::<M>()))
        })
    }
}

type Shared = ipc_threadsafe::Service;

/// An iceoryx2 client.
pub struct ShmClient {
    session: u32,
    pose: ShmPublisher<Shared, PoseSample, ()>,
    ready: Notifier<Shared>,
    forces: Subscriber<Shared, ForceSample, ()>,
    listener: Listener<Shared>,
    _node: Node<Shared>,
}

impl ShmClient {
    /// Opens tool `tool`'s services of `keys`' scene.
    pub fn connect(keys: &Keys, tool: u32) -> Result<Self, TransportError> {
        let err = |what: String| {
            move |e: &dyn std::fmt::Debug| TransportError(format!("iceoryx2: {what}: {e:?}"))
        };
        let node = node::<Shared>()?;
        let pose_key = keys.tool_pose(tool);
        let pose = records::<Shared, PoseSample>(&node, &pose_key)?
            .publisher_builder()
            .create()
            .map_err(|e| err(format!("cannot publish on {pose_key}"))(&e))?;
        let ready = event(&node, &keys.poses_ready())?
            .notifier_builder()
            .create()
            .map_err(|e| err("cannot raise the poses event".into())(&e))?;
        let force_key = keys.tool_force(tool);
        let forces = records::<Shared, ForceSample>(&node, &force_key)?
            .subscriber_builder()
            .create()
            .map_err(|e| err(format!("cannot subscribe to {force_key}"))(&e))?;
        let listener = event(&node, &force_key)?
            .listener_builder()
            .create()
            .map_err(|e| err(format!("cannot listen on {force_key}"))(&e))?;
        Ok(Self { session: new_session(), pose, ready, forces, listener, _node: node })
    }

    /// Publishes a pose and wakes the server.
    pub fn send_pose(&self, pose: &RawToolPose) -> Result<(), TransportError> {
        self.pose
            .send_copy(PoseSample(stamped(pose, self.session)))
            .map_err(|e| TransportError(format!("iceoryx2: cannot send a pose: {e:?}")))?;
        self.ready
            .notify()
            .map_err(|e| TransportError(format!("iceoryx2: cannot wake the server: {e:?}")))?;
        Ok(())
    }

    /// The next force, waiting up to `timeout`.
    #[must_use]
    pub fn recv_force(&self, timeout: Duration) -> Option<RawToolForce> {
        let until = Instant::now() + timeout;
        loop {
            if let Ok(Some(sample)) = self.forces.receive() {
                return Some(sample.payload().0);
            }
            let left = until.checked_duration_since(Instant::now())?;
            // Under a microsecond the socket's timeout would be zero, which means "forever".
            if left < Duration::from_micros(1) {
                return None;
            }
            let _ = self.listener.timed_wait(|_| {}, left);
        }
    }
}
