//! zenoh: the network transport. The server is a zenoh peer listening on explicit TCP
//! endpoints (loopback by default); clients connect to it in client mode. Multicast scouting is
//! off unless asked for, so nothing leaves the machine that was not pointed elsewhere.
//!
//! Poses arrive on `incise/v1/<scene>/tool/*/pose` through a callback on zenoh's own threads;
//! forces, frames and cuts go out through publishers declared once, with congestion control
//! `Drop` and express delivery (a late force is worthless, a queued one worse); `SceneInfo` is a
//! queryable on `…/info`.

use crate::{Faults, PoseHandler, TransportKind, decode_pose};
use incise_protocol::keys::Keys;
use incise_protocol::raw::RawToolForce;
use incise_protocol::v1;
use prost::Message;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use zenoh::Wait;
use zenoh::qos::{CongestionControl, Priority};

/// A transport that could not be set up.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct TransportError(pub String);

/// Where a zenoh session listens and what it connects to.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoints {
    /// Endpoints to listen on, such as `tcp/127.0.0.1:7447`.
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// Whether to find peers by UDP multicast (off by default: explicit endpoints only).
    pub multicast_scouting: bool,
}

/// The server's default endpoint.
pub const DEFAULT_PORT: u16 = 7447;

impl Endpoints {
    /// A server listening on loopback port `port`.
    #[must_use]
    pub fn listen_loopback(port: u16) -> Self {
        Self {
            listen: vec![format!("tcp/127.0.0.1:{port}")],
            connect: Vec::new(),
            multicast_scouting: false,
        }
    }

    /// A client of the server at `endpoint` (`tcp/HOST:PORT`).
    #[must_use]
    pub fn connect_to(endpoint: &str) -> Self {
        Self { listen: Vec::new(), connect: vec![endpoint.to_owned()], multicast_scouting: false }
    }

    fn config(&self, mode: &str) -> Result<zenoh::Config, TransportError> {
        let mut c = zenoh::Config::default();
        let json = |v: &[String]| {
            format!("[{}]", v.iter().map(|e| format!("{e:?}")).collect::<Vec<_>>().join(","))
        };
        let mut set = |key: &str, value: &str| {
            c.insert_json5(key, value)
                .map_err(|e| TransportError(format!("zenoh config {key} = {value}: {e}")))
        };
        set("mode", &format!("{mode:?}"))?;
        set("listen/endpoints", &json(&self.listen))?;
        set("connect/endpoints", &json(&self.connect))?;
        set("scouting/multicast/enabled", if self.multicast_scouting { "true" } else { "false" })?;
        Ok(c)
    }

    /// Opens a session: `peer` for a server, `client` for a client.
    pub fn open(&self, mode: &str) -> Result<zenoh::Session, TransportError> {
        let config = self.config(mode)?;
        zenoh::open(config).wait().map_err(|e| {
            TransportError(format!(
                "zenoh: cannot open a {mode} session (listen {:?}, connect {:?}): {e}",
                self.listen, self.connect
            ))
        })
    }
}

type Publisher = zenoh::pubsub::Publisher<'static>;

fn publisher(session: &zenoh::Session, key: &str) -> Result<Publisher, TransportError> {
    session
        .declare_publisher(key.to_owned())
        .congestion_control(CongestionControl::Drop)
        .priority(Priority::RealTime)
        .express(true)
        .wait()
        .map_err(|e| TransportError(format!("zenoh: cannot publish on {key}: {e}")))
}

/// The server's zenoh side.
pub struct ZenohServer {
    forces: Vec<Publisher>,
    frame: Publisher,
    cut: Publisher,
    _poses: zenoh::pubsub::Subscriber<()>,
    _info: zenoh::query::Queryable<()>,
    faults: Arc<Faults>,
    // Last, so the declarations above are undeclared before the session closes.
    _session: zenoh::Session,
}

impl ZenohServer {
    /// Serves `keys`' scene with `tools` tools on `endpoints`: poses go to `handler`, refusals
    /// to `faults`, and `info` answers queries.
    pub fn start(
        keys: &Keys,
        tools: usize,
        info: &v1::SceneInfo,
        endpoints: &Endpoints,
        handler: PoseHandler,
        faults: Arc<Faults>,
    ) -> Result<Self, TransportError> {
        let session = endpoints.open("peer")?;
        let forces = (0..tools as u32)
            .map(|t| publisher(&session, &keys.tool_force(t)))
            .collect::<Result<Vec<_>, _>>()?;
        let frame = publisher(&session, &keys.frame())?;
        let cut = publisher(&session, &keys.cut())?;
        let poses = {
            let (keys, faults) = (keys.clone(), Arc::clone(&faults));
            session
                .declare_subscriber(keys.any_tool_pose())
                .callback(move |sample| {
                    let bytes = sample.payload().to_bytes();
                    let pose = match decode_pose(&bytes) {
                        Ok(pose) => pose,
                        Err(bad) => {
                            faults.count(&bad);
                            return;
                        }
                    };
                    if keys.tool_of_pose_key(sample.key_expr().as_str()) != Some(pose.tool_id) {
                        faults.mismatched.fetch_add(1, Ordering::Relaxed);
                        return;
                    }
                    if !handler(TransportKind::Zenoh, &pose) {
                        faults.unknown_tool.fetch_add(1, Ordering::Relaxed);
                    }
                })
                .wait()
                .map_err(|e| TransportError(format!("zenoh: cannot subscribe to poses: {e}")))?
        };
        let answer = info.encode_to_vec();
        let info_key = keys.info();
        let info = session
            .declare_queryable(info_key.clone())
            .callback(move |query| {
                // A reply that cannot be sent (the querier left) needs no handling here.
                let _ = query.reply(info_key.clone(), answer.clone()).wait();
            })
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot answer {}: {e}", keys.info())))?;
        Ok(Self { forces, frame, cut, _poses: poses, _info: info, faults, _session: session })
    }

    fn put(&self, publisher: &Publisher, bytes: Vec<u8>) {
        if publisher.put(bytes).wait().is_err() {
            self.faults.send_failed.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Publishes a tool's force.
    pub fn send_force(&self, force: &RawToolForce) {
        if let Some(p) = self.forces.get(force.tool_id as usize) {
            self.put(p, v1::ToolForce::from(force).encode_to_vec());
        }
    }

    /// Publishes a frame's statistics.
    pub fn send_frame(&self, stats: &v1::FrameStats) {
        self.put(&self.frame, stats.encode_to_vec());
    }

    /// Publishes a cut.
    pub fn send_cut(&self, cut: &v1::CutEvent) {
        self.put(&self.cut, cut.encode_to_vec());
    }
}
