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
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use zenoh::Wait;
use zenoh::qos::{CongestionControl, Priority};

/// A transport that could not be set up.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct TransportError(pub String);

/// Where a zenoh session listens, what it connects to, and the zenoh configuration it starts
/// from.
///
/// Without a file the session is configured here alone: the listen and connect endpoints, and
/// multicast scouting off unless asked for. With [`Endpoints::config_file`] (a zenoh json5
/// file, such as those in `deploy/zenoh/`) the file decides everything it sets, its `mode`
/// included (a station's server behind a site router runs in `client` mode); non-empty
/// `listen` or `connect` lists replace the file's, multicast scouting is turned on only when
/// asked for, and [`Endpoints::settings`] are applied last.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Endpoints {
    /// Endpoints to listen on, such as `tcp/127.0.0.1:7447`.
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// Whether to find peers by UDP multicast (off by default: explicit endpoints only).
    pub multicast_scouting: bool,
    /// A zenoh configuration file (json5) to start from.
    pub config_file: Option<PathBuf>,
    /// `KEY:VALUE` settings over everything else, as zenohd's `--cfg` takes them: a key path
    /// such as `transport/link/tls/connect_certificate` and a json5 value.
    pub settings: Vec<String>,
}

/// The server's default endpoint.
pub const DEFAULT_PORT: u16 = 7447;

impl Endpoints {
    /// A server listening on loopback port `port`.
    #[must_use]
    pub fn listen_loopback(port: u16) -> Self {
        Self { listen: vec![format!("tcp/127.0.0.1:{port}")], ..Self::default() }
    }

    /// A client of the server (or router) at `endpoint` (`tcp/HOST:PORT`).
    #[must_use]
    pub fn connect_to(endpoint: &str) -> Self {
        Self { connect: vec![endpoint.to_owned()], ..Self::default() }
    }

    /// The zenoh configuration of a session in `mode` (`peer`, `client` or `router`; a file's
    /// own `mode` wins).
    pub fn config(&self, mode: &str) -> Result<zenoh::Config, TransportError> {
        let (mut c, from_file) = match &self.config_file {
            Some(path) => {
                let c = zenoh::Config::from_file(path)
                    .map_err(|e| TransportError(format!("zenoh config {}: {e}", path.display())))?;
                (c, true)
            }
            None => (zenoh::Config::default(), false),
        };
        let json = |v: &[String]| {
            format!("[{}]", v.iter().map(|e| format!("{e:?}")).collect::<Vec<_>>().join(","))
        };
        let file_mode = c.get_json("mode").ok().filter(|m| m != "null");
        let mut set = |key: &str, value: &str| {
            c.insert_json5(key, value)
                .map_err(|e| TransportError(format!("zenoh config {key} = {value}: {e}")))
        };
        if file_mode.is_none() {
            set("mode", &format!("{mode:?}"))?;
        }
        if !from_file || !self.listen.is_empty() {
            set("listen/endpoints", &json(&self.listen))?;
        }
        if !from_file || !self.connect.is_empty() {
            set("connect/endpoints", &json(&self.connect))?;
        }
        if !from_file || self.multicast_scouting {
            set(
                "scouting/multicast/enabled",
                if self.multicast_scouting { "true" } else { "false" },
            )?;
        }
        for setting in &self.settings {
            let (key, value) = setting.split_once(':').ok_or_else(|| {
                TransportError(format!(
                    "zenoh setting {setting:?}: write KEY:VALUE, e.g. 'connect/endpoints:[\"tcp/127.0.0.1:7447\"]'"
                ))
            })?;
            set(key.trim(), value.trim())?;
        }
        Ok(c)
    }

    /// Opens a session: `peer` for a server, `client` for a client, `router` for a router
    /// (unless a configuration file names the mode).
    pub fn open(&self, mode: &str) -> Result<zenoh::Session, TransportError> {
        let config = self.config(mode)?;
        zenoh::open(config).wait().map_err(|e| {
            let file = self
                .config_file
                .as_ref()
                .map_or(String::new(), |p| format!(", config {}", p.display()));
            TransportError(format!(
                "zenoh: cannot open a {mode} session (listen {:?}, connect {:?}{file}): {e}",
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
    stats: Option<zenoh::query::Queryable<()>>,
    faults: Arc<Faults>,
    // Last, so the declarations above are undeclared before the session closes.
    session: zenoh::Session,
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
        Ok(Self { forces, frame, cut, _poses: poses, _info: info, stats: None, faults, session })
    }

    /// Answers queries on `keys`' stats key with what `stats` says at the time of each query.
    pub fn serve_stats(
        &mut self,
        keys: &Keys,
        stats: impl Fn() -> v1::ServerStats + Send + Sync + 'static,
    ) -> Result<(), TransportError> {
        let key = keys.stats();
        let reply_key = key.clone();
        let queryable = self
            .session
            .declare_queryable(key.clone())
            .callback(move |query| {
                // A reply that cannot be sent (the querier left) needs no handling here.
                let _ = query.reply(reply_key.clone(), stats().encode_to_vec()).wait();
            })
            .wait()
            .map_err(|e| TransportError(format!("zenoh: cannot answer {key}: {e}")))?;
        self.stats = Some(queryable);
        Ok(())
    }

    fn put(&self, publisher: &Publisher, bytes: Vec<u8>) {
        if publisher.put(bytes).wait().is_err() {
            self.faults.send_failed.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Publishes a tool's force.
    pub fn send_force(&self, force: &RawToolForce) {
        self.send_tool_force(&v1::ToolForce::from(force));
    }

    /// Publishes a tool's force as a message (with what the shared-memory record lacks: the
    /// proxy's pose).
    pub fn send_tool_force(&self, force: &v1::ToolForce) {
        if let Some(p) = self.forces.get(force.tool_id as usize) {
            self.put(p, force.encode_to_vec());
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

#[cfg(test)]
mod tests {
    use super::*;

    fn get(c: &zenoh::Config, key: &str) -> String {
        c.get_json(key).unwrap()
    }

    /// A file decides what it sets (its mode included); explicit endpoints replace its own,
    /// and settings go over everything.
    #[test]
    fn a_file_is_the_base_and_explicit_choices_go_over_it() {
        let file = std::env::temp_dir().join(format!("incise-zenoh-{}.json5", std::process::id()));
        std::fs::write(
            &file,
            r#"{ mode: "client", connect: { endpoints: ["tcp/10.0.0.2:7447"] },
                 scouting: { multicast: { enabled: false } } }"#,
        )
        .unwrap();
        let from_file = Endpoints { config_file: Some(file.clone()), ..Endpoints::default() };
        let c = from_file.config("peer").unwrap();
        assert_eq!(get(&c, "mode"), "\"client\"");
        assert_eq!(get(&c, "connect/endpoints"), r#"["tcp/10.0.0.2:7447"]"#);
        let over = Endpoints {
            connect: vec!["tcp/127.0.0.1:9".into()],
            settings: vec!["scouting/multicast/enabled: true".into()],
            ..from_file.clone()
        };
        let c = over.config("peer").unwrap();
        assert_eq!(get(&c, "connect/endpoints"), r#"["tcp/127.0.0.1:9"]"#);
        assert_eq!(get(&c, "scouting/multicast/enabled"), "true");
        // Without a file: the mode asked for, and no multicast.
        let c = Endpoints::connect_to("tcp/127.0.0.1:9").config("client").unwrap();
        assert_eq!(get(&c, "mode"), "\"client\"");
        assert_eq!(get(&c, "scouting/multicast/enabled"), "false");
        // Broken input says what and where.
        let bad = Endpoints { settings: vec!["no-colon".into()], ..Endpoints::default() };
        assert!(bad.config("peer").unwrap_err().0.contains("KEY:VALUE"));
        let missing = Endpoints {
            config_file: Some("/nonexistent/zenoh.json5".into()),
            ..Endpoints::default()
        };
        assert!(missing.config("peer").unwrap_err().0.contains("/nonexistent/zenoh.json5"));
        std::fs::remove_file(file).unwrap();
    }
}
