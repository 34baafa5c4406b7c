//! The deployment of `deploy/`, on loopback: a zenoh router (`incise-router`, run from the
//! shipped configurations), servers of different stations behind it, and clients. Each
//! client gets forces only from its own station; the site router's access control lets a driver
//! publish only its own tool's poses and a viewer publish nothing; its TLS refuses a client
//! without a certificate from the site's authority; and when the router restarts mid-session,
//! servers and clients reconnect by themselves, forces resume, and the poses sent meanwhile are
//! counted missing, never used late.
//!
//! Servers and the router are separate processes (the router is killed and restarted); the
//! clients are this test process, so that what each received can be checked pose by pose.

use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_protocol::v1;
use incise_transport::client::ZenohClient;
use incise_transport::zenoh_link::Endpoints;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::LazyLock;
use std::time::{Duration, Instant};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

fn zenoh_file(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../deploy/zenoh").join(name)
}

/// A child process killed when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `incise-router` and waits for its "routing" line.
fn router(args: &[String]) -> Process {
    let mut child = Command::new(env!("CARGO_BIN_EXE_incise-router"))
        .arg("--stop-with-parent")
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert!(line.contains("routing"), "the router did not start: {line:?}");
    Process(child)
}

/// Starts `incise-server` on its embedded scene as station `name`, with zenoh as `zenoh` says
/// (no iceoryx2: each station is reached through the router).
fn server(name: &str, zenoh: &[String]) -> Process {
    let child = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--name", name, "--no-iceoryx2", "--status-every", "60", "--stop-with-parent"])
        .args(zenoh)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    Process(child)
}

/// A client of station `name`'s tool `tool`, once the station answers through the router.
fn client(name: &str, tool: u32, endpoints: &Endpoints) -> ZenohClient {
    let keys = Keys::new(name).unwrap();
    let until = Instant::now() + Duration::from_mins(1);
    loop {
        if let Ok(c) = ZenohClient::connect_with(&keys, tool, endpoints)
            && c.scene_info(Duration::from_millis(500)).is_ok()
        {
            return c;
        }
        assert!(Instant::now() < until, "station {name} did not answer through the router");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A connection for station `name`'s tool `tool` that the router may refuse to answer (so no
/// scene description to wait for), retried while a loaded machine's TLS handshake times out.
fn connection(name: &str, tool: u32, endpoints: &Endpoints) -> ZenohClient {
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        match ZenohClient::connect_with(&Keys::new(name).unwrap(), tool, endpoints) {
            Ok(c) => return c,
            Err(e) => assert!(Instant::now() < until, "cannot connect: {e}"),
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The station's statistics, asked through `via`.
fn stats(via: &ZenohClient) -> v1::ServerStats {
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        match via.server_stats(Duration::from_secs(2)) {
            Ok(s) => return s,
            Err(e) => assert!(Instant::now() < until, "no statistics: {e}"),
        }
    }
}

fn refused(s: &v1::ServerStats) -> u64 {
    s.refused.iter().map(|r| r.count).sum()
}

/// What a client received while it drove.
#[derive(Default)]
struct Drive {
    /// Sequence numbers sent, with when each was sent.
    sent: Vec<(u64, Instant)>,
    /// Forces received, with when.
    forces: Vec<(RawToolForce, Instant)>,
}

/// Just above the middle of the organ's top, from the scene's description.
fn above_organ(c: &ZenohClient) -> [f64; 3] {
    let info = c.scene_info(Duration::from_secs(5)).unwrap();
    [
        0.5 * (info.bounds_min_x + info.bounds_max_x),
        0.5 * (info.bounds_min_y + info.bounds_max_y),
        info.bounds_max_z + 0.002,
    ]
}

/// Sends tool `tool`'s pose at `at` at 1 kHz, numbered from `first`, for `duration`,
/// collecting every force that comes back; `go_on` is asked before each pose, with the time
/// since the start and what came back so far, and ends the drive early by returning false.
fn drive(
    c: &ZenohClient,
    tool: u32,
    first: u64,
    at: [f64; 3],
    duration: Duration,
    mut go_on: impl FnMut(Duration, &Drive) -> bool,
) -> Drive {
    let mut d = Drive::default();
    let start = Instant::now();
    let mut sequence = first;
    while start.elapsed() < duration && go_on(start.elapsed(), &d) {
        let pose = RawToolPose {
            sequence,
            timestamp_ns: start.elapsed().as_nanos() as u64 + 1,
            client: 7,
            ..RawToolPose::at(tool, at)
        };
        let bytes = prost::Message::encode_to_vec(&v1::ToolPose::from(&pose));
        c.send_bytes(&bytes).unwrap();
        d.sent.push((sequence, Instant::now()));
        sequence += 1;
        let next = Instant::now() + Duration::from_millis(1);
        while let Some(left) = next.checked_duration_since(Instant::now()) {
            let Some(f) = c.recv_force(left) else { break };
            d.forces.push((f, Instant::now()));
        }
    }
    d
}

#[test]
fn one_router_serves_two_stations_and_each_client_gets_only_its_own_forces() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let _router = router(&[
        "--config".into(),
        zenoh_file("router-single-host.json5").display().to_string(),
        "--listen".into(),
        endpoint.clone(),
    ]);
    let connect = ["--connect".to_owned(), endpoint.clone()];
    let _a = server("station-a", &connect);
    let _b = server("station-b", &connect);
    let via = Endpoints::connect_to(&endpoint);
    let (a, b) = (client("station-a", 0, &via), client("station-b", 0, &via));
    // Both at once, numbered apart: A's from 1, B's from 1,000,000.
    let (at_a, at_b) = (above_organ(&a), above_organ(&b));
    let two = Duration::from_secs(2);
    let (da, db) = std::thread::scope(|s| {
        let ta = s.spawn(|| drive(&a, 0, 1, at_a, two, |_, _| true));
        let tb = s.spawn(|| drive(&b, 0, 1_000_000, at_b, two, |_, _| true));
        (ta.join().unwrap(), tb.join().unwrap())
    });
    for (name, d, own) in [("A", &da, 1..1_000_000), ("B", &db, 1_000_000..2_000_000)] {
        assert!(d.forces.len() > 100, "{name} got {} forces", d.forces.len());
        let foreign: Vec<u64> = d
            .forces
            .iter()
            .map(|(f, _)| f.pose_sequence)
            .filter(|s| !own.contains(s) && *s != 0)
            .collect();
        assert!(
            foreign.is_empty(),
            "{name} got forces answering another station's poses: {foreign:?}"
        );
    }
    let (sa, sb) = (stats(&a), stats(&b));
    assert_eq!((sa.scene.as_str(), sb.scene.as_str()), ("station-a", "station-b"));
    for (s, d) in [(&sa, &da), (&sb, &db)] {
        assert!(s.poses[0] > 0 && s.poses[0] <= d.sent.len() as u64, "{s:?}");
        assert_eq!(s.poses[1], 0, "nobody drove tool 1: {s:?}");
        assert_eq!(refused(s), 0, "{s:?}");
    }
}

/// The site's certificates, made once for every test here: an authority, the router's (for
/// 127.0.0.1), and a client certificate per common name the site router's rules name; plus a
/// rogue authority's certificate carrying a driver's name.
struct Certificates {
    dir: PathBuf,
}

static CERTIFICATES: LazyLock<Certificates> = LazyLock::new(|| {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
    // Under the build's scratch directory, one folder per test process. A static is never
    // dropped, so each run leaves its folder behind; those of processes that are gone are
    // removed here.
    let root = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("deploy-tls");
    for stale in std::fs::read_dir(&root).into_iter().flatten().flatten() {
        if !std::path::Path::new("/proc").join(stale.file_name()).exists() {
            let _ = std::fs::remove_dir_all(stale.path());
        }
    }
    let dir = root.join(std::process::id().to_string());
    std::fs::create_dir_all(&dir).unwrap();
    let authority = |name: &str| {
        let mut p = CertificateParams::new(Vec::<String>::new()).unwrap();
        p.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        p.distinguished_name.push(DnType::CommonName, name);
        CertifiedIssuer::self_signed(p, KeyPair::generate().unwrap()).unwrap()
    };
    let ca = authority("incise test site");
    std::fs::write(dir.join("ca.crt"), ca.pem()).unwrap();
    let issue = |ca: &CertifiedIssuer<'_, KeyPair>, file: &str, cn: &str, names: Vec<String>| {
        let mut p = CertificateParams::new(names).unwrap();
        p.distinguished_name.push(DnType::CommonName, cn);
        let key = KeyPair::generate().unwrap();
        let cert = p.signed_by(&key, ca).unwrap();
        std::fs::write(dir.join(format!("{file}.crt")), cert.pem()).unwrap();
        std::fs::write(dir.join(format!("{file}.key")), key.serialize_pem()).unwrap();
    };
    issue(&ca, "router", "incise-router", vec!["127.0.0.1".into(), "localhost".into()]);
    for cn in [
        "server.station-a",
        "server.station-b",
        "driver.station-a.tool-0",
        "driver.station-b.tool-0",
        "viewer",
    ] {
        issue(&ca, cn, cn, Vec::new());
    }
    issue(&authority("rogue"), "rogue", "driver.station-a.tool-0", Vec::new());
    Certificates { dir }
});

impl Certificates {
    fn path(&self, file: &str) -> String {
        self.dir.join(file).display().to_string()
    }

    /// `KEY:VALUE` settings that present `name`'s certificate to the router.
    fn client_settings(&self, name: &str) -> Vec<String> {
        vec![
            format!("transport/link/tls/root_ca_certificate:{:?}", self.path("ca.crt")),
            format!(
                "transport/link/tls/connect_certificate:{:?}",
                self.path(&format!("{name}.crt"))
            ),
            format!(
                "transport/link/tls/connect_private_key:{:?}",
                self.path(&format!("{name}.key"))
            ),
        ]
    }
}

/// The site router of `deploy/zenoh/router-site.json5` on a loopback TLS port, with the test's
/// certificates; its endpoint.
fn site_router() -> (Process, String) {
    let c = &*CERTIFICATES;
    let endpoint = format!("tls/127.0.0.1:{}", free_port());
    let cfg = |key: &str, file: &str| format!("transport/link/tls/{key}:{:?}", c.path(file));
    let mut args = vec![
        "--config".to_owned(),
        zenoh_file("router-site.json5").display().to_string(),
        "--listen".to_owned(),
        endpoint.clone(),
    ];
    for setting in [
        cfg("root_ca_certificate", "ca.crt"),
        cfg("listen_certificate", "router.crt"),
        cfg("listen_private_key", "router.key"),
    ] {
        args.extend(["--cfg".to_owned(), setting]);
    }
    (router(&args), endpoint)
}

/// Station `name`'s server behind the site router, as `deploy/zenoh/server.json5` has it.
fn site_server(name: &str, endpoint: &str) -> Process {
    let mut args = vec![
        "--zenoh-config".to_owned(),
        zenoh_file("server.json5").display().to_string(),
        "--connect".to_owned(),
        endpoint.to_owned(),
    ];
    for setting in CERTIFICATES.client_settings(&format!("server.{name}")) {
        args.extend(["--zenoh-cfg".to_owned(), setting]);
    }
    server(name, &args)
}

/// A client's connection as `deploy/zenoh/<file>` has it, presenting `name`'s certificate.
fn site_client(file: &str, name: &str, endpoint: &str) -> Endpoints {
    Endpoints {
        connect: vec![endpoint.to_owned()],
        config_file: Some(zenoh_file(file)),
        settings: CERTIFICATES.client_settings(name),
        ..Endpoints::default()
    }
}

#[test]
fn the_site_router_lets_a_driver_drive_only_its_tool_and_a_viewer_only_watch() {
    let (_router, endpoint) = site_router();
    let _a = site_server("station-a", &endpoint);
    let _b = site_server("station-b", &endpoint);
    let driver = site_client("driver.json5", "driver.station-a.tool-0", &endpoint);
    let viewer = site_client("viewer.json5", "viewer", &endpoint);
    let a0 = client("station-a", 0, &driver);
    let a1_viewer = client("station-a", 1, &viewer);
    let b0_viewer = client("station-b", 0, &viewer);
    let at = above_organ(&a0);
    let frames =
        a1_viewer.watch::<v1::FrameStats>(&Keys::new("station-a").unwrap().frame()).unwrap();
    let second = Duration::from_secs(1);
    // Its own tool: answered.
    let own = drive(&a0, 0, 1, at, second, |_, _| true);
    assert!(own.forces.len() > 100, "the driver got {} forces", own.forces.len());
    // Another station's tool, with the same credentials: dropped at the router.
    let b0_driver = connection("station-b", 0, &driver);
    let other = drive(&b0_driver, 0, 1, at, second, |_, _| true);
    assert_eq!(other.forces.len(), 0, "forces came back for another station's tool");
    // Another tool of its own station: dropped too.
    let a1_driver = connection("station-a", 1, &driver);
    drive(&a1_driver, 1, 1, at, second, |_, _| true);
    // A viewer's poses: dropped.
    drive(&a1_viewer, 1, 1, at, second, |_, _| true);
    // The viewer sees the frames, and both stations' statistics.
    assert!(frames.drain().count() > 10, "the viewer got no frames");
    let (sa, sb) = (stats(&a1_viewer), stats(&b0_viewer));
    assert!(sa.poses[0] > 0, "{sa:?}");
    assert_eq!(sa.poses[1], 0, "station-a's tool 1 took poses it should not have: {sa:?}");
    assert_eq!(sb.poses, vec![0, 0], "station-b took poses it should not have: {sb:?}");
    assert_eq!((refused(&sa), refused(&sb)), (0, 0), "the router let refused poses through");
}

#[test]
fn the_site_router_refuses_clients_without_the_sites_certificate() {
    let (_router, endpoint) = site_router();
    let _a = site_server("station-a", &endpoint);
    let keys = Keys::new("station-a").unwrap();
    // A valid certificate: round trips.
    let valid = site_client("driver.json5", "driver.station-a.tool-0", &endpoint);
    let c = client("station-a", 0, &valid);
    let d = drive(&c, 0, 1, above_organ(&c), Duration::from_millis(500), |_, _| true);
    let answered = d.forces.iter().filter(|(f, _)| f.pose_sequence != 0).count();
    assert!(answered > 50, "{answered} forces answered poses");
    // The right name from another authority; no certificate at all; plain TCP on the TLS port.
    let rogue = site_client("driver.json5", "rogue", &endpoint);
    let mut none = site_client("driver.json5", "driver.station-a.tool-0", &endpoint);
    none.settings.truncate(1);
    none.config_file = None;
    let plain = Endpoints::connect_to(&endpoint.replace("tls/", "tcp/"));
    for (what, endpoints) in
        [("a rogue certificate", rogue), ("no certificate", none), ("plain TCP", plain)]
    {
        match ZenohClient::connect_with(&keys, 0, &endpoints) {
            Err(_) => {}
            Ok(c) => assert!(
                c.scene_info(Duration::from_secs(2)).is_err(),
                "a client with {what} got through"
            ),
        }
    }
}

#[test]
fn after_a_router_restart_forces_resume_and_the_lost_poses_count_as_missing() {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router_args = [
        "--config".to_owned(),
        zenoh_file("router-single-host.json5").display().to_string(),
        "--listen".to_owned(),
        endpoint.clone(),
    ];
    let mut first_router = Some(router(&router_args));
    let mut second_router = None;
    let mut station = server("station-a", &["--connect".to_owned(), endpoint.clone()]);
    let c = client("station-a", 0, &Endpoints::connect_to(&endpoint));
    let at = above_organ(&c);
    // Sequence numbers: the first sent with the router gone, the first sent after it restarted.
    let (mut killed, mut restarted) = (None, None);
    let d = drive(&c, 0, 1, at, Duration::from_mins(1), |t, d| {
        let next = d.sent.last().map_or(1, |(s, _)| s + 1);
        if killed.is_none() && t >= Duration::from_secs(1) {
            let mut r = first_router.take().unwrap();
            r.0.kill().unwrap();
            r.0.wait().unwrap();
            killed = Some(next);
        }
        if restarted.is_none() && t >= Duration::from_secs(2) {
            second_router = Some(router(&router_args));
            restarted = Some(next);
        }
        // Go on until a second's worth of poses sent after the restart have been answered.
        restarted
            .is_none_or(|r| d.forces.iter().filter(|(f, _)| f.pose_sequence >= r).count() < 1000)
    });
    let (killed, restarted) = (killed.unwrap(), restarted.unwrap());
    let after = d.forces.iter().filter(|(f, _)| f.pose_sequence >= restarted).count();
    assert!(after >= 1000, "forces did not resume: {after} answered poses sent after the restart");
    // Nothing sent while the router was down was ever answered: those poses never arrived.
    let late: Vec<u64> = d
        .forces
        .iter()
        .map(|(f, _)| f.pose_sequence)
        .filter(|s| (killed..restarted).contains(s))
        .collect();
    assert!(late.is_empty(), "forces answered poses sent during the outage: {late:?}");
    assert!(station.0.try_wait().unwrap().is_none(), "the server stopped");
    let s = stats(&c);
    let sent = d.sent.len() as u64;
    assert!(
        s.missing_poses[0] >= restarted - killed,
        "{} poses were sent with the router down, {} counted missing",
        restarted - killed,
        s.missing_poses[0]
    );
    assert!(s.poses[0] + s.missing_poses[0] <= sent, "{s:?}, {sent} sent");
    assert!(s.uptime_s > d.sent[0].1.elapsed().as_secs_f64(), "the server restarted: {s:?}");
    let back =
        d.forces.iter().find(|(f, _)| f.pose_sequence >= restarted).map(|(_, t)| *t).unwrap();
    let restart_sent = d.sent.iter().find(|(s, _)| *s == restarted).unwrap().1;
    println!(
        "router down for poses {killed}..{restarted} ({} poses); forces resumed {:.0} ms after the restart; \
         the server counted {} missing, accepted {} of {sent} sent",
        restarted - killed,
        (back - restart_sent).as_secs_f64() * 1e3,
        s.missing_poses[0],
        s.poses[0]
    );
    drop(second_router);
}

/// What `deploy/` ships agrees with the code: every zenoh configuration reads as one, the
/// container's build steps are the README's commands and it copies binaries the workspace
/// builds, on the toolchain the repository pins, and the units use flags the programs have.
#[test]
fn the_deploy_files_agree_with_the_programs_and_the_readme() {
    let deploy = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../deploy");
    let read =
        |p: PathBuf| std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    for entry in std::fs::read_dir(deploy.join("zenoh")).unwrap() {
        let path = entry.unwrap().path();
        let endpoints = Endpoints { config_file: Some(path.clone()), ..Endpoints::default() };
        if let Err(e) = endpoints.config("peer") {
            panic!("{}: {e}", path.display());
        }
    }
    let containerfile = read(deploy.join("Containerfile"));
    let readmes = read(deploy.join("../README.md")) + &read(deploy.join("README.md"));
    let runs: Vec<&str> = containerfile
        .lines()
        .filter_map(|l| l.strip_prefix("RUN "))
        .filter(|l| l.starts_with("cargo "))
        .collect();
    assert!(!runs.is_empty(), "the Containerfile builds nothing with cargo");
    for run in runs {
        assert!(readmes.contains(run), "the Containerfile runs `{run}`, which no README gives");
    }
    let toolchain = read(deploy.join("../rust-toolchain.toml"));
    let channel =
        toolchain.lines().find_map(|l| l.strip_prefix("channel = ")).unwrap().trim_matches('"');
    assert!(
        containerfile.contains(&format!("FROM rust:{channel}-")),
        "the Containerfile's Rust is not the pinned {channel}"
    );
    let bins: Vec<String> =
        ["server/incise_server", "server/incise_replay", "server/incise_bench", "clients/rust"]
            .iter()
            .flat_map(|c| {
                read(deploy.join("..").join(c).join("Cargo.toml"))
                    .lines()
                    .filter_map(|l| {
                        l.strip_prefix("name = \"incise-")
                            .map(|n| format!("incise-{}", n.trim_end_matches('"')))
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
    let copy = containerfile.lines().find(|l| l.starts_with("COPY --from=build")).unwrap();
    for word in copy.split_whitespace().filter(|w| w.contains("/target/release/")) {
        let bin = word.rsplit('/').next().unwrap();
        assert!(
            bins.iter().any(|b| b == bin),
            "the Containerfile copies {bin}, which nothing builds"
        );
    }
    // Each flag a unit passes is one its program takes.
    for (unit, exe) in [
        ("incise-server@.service", env!("CARGO_BIN_EXE_incise-server")),
        ("incise-router.service", env!("CARGO_BIN_EXE_incise-router")),
    ] {
        let text = read(deploy.join("systemd").join(unit));
        let help =
            String::from_utf8(Command::new(exe).arg("--help").output().unwrap().stdout).unwrap();
        let exec = text.replace("\\\n", " ");
        let exec = exec.lines().find_map(|l| l.strip_prefix("ExecStart=")).unwrap();
        for flag in exec.split_whitespace().filter(|w| w.starts_with("--")) {
            assert!(help.contains(flag), "{unit} passes {flag}, which {exe} does not take");
        }
    }
}

/// Whether process `pid` has ended (gone, or a zombie its new parent has not reaped yet).
fn ended(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Err(_) => true,
        // `pid (comm) S …`: the state follows the last parenthesis.
        Ok(stat) => {
            stat.rsplit_once(')').is_some_and(|(_, rest)| rest.trim_start().starts_with('Z'))
        }
    }
}

#[test]
fn a_router_and_a_server_started_with_stop_with_parent_end_when_their_parent_is_killed() {
    // A shell starts both in the background and is then killed with SIGKILL, so nothing stops
    // them: they notice that they were orphaned and end by themselves.
    let port = free_port();
    let script = format!(
        "{router} --stop-with-parent --listen tcp/127.0.0.1:{port} >/dev/null 2>&1 & echo $!; \
         {server} --stop-with-parent --no-iceoryx2 --connect tcp/127.0.0.1:{port} \
         --name orphan >/dev/null 2>&1 & echo $!; wait",
        router = env!("CARGO_BIN_EXE_incise-router"),
        server = env!("CARGO_BIN_EXE_incise-server"),
    );
    // Killed on drop as well, so a failure below also leaves nothing running.
    let mut shell =
        Process(Command::new("sh").args(["-c", &script]).stdout(Stdio::piped()).spawn().unwrap());
    let mut out = BufReader::new(shell.0.stdout.take().unwrap());
    let mut pids = Vec::new();
    for _ in 0..2 {
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        pids.push(line.trim().parse::<u32>().unwrap());
    }
    // Both running first (a server that failed to start would pass the test for nothing).
    let endpoints =
        Endpoints { connect: vec![format!("tcp/127.0.0.1:{port}")], ..Endpoints::default() };
    drop(client("orphan", 0, &endpoints));
    assert!(pids.iter().all(|&p| !ended(p)), "both started: {pids:?}");
    drop(shell);
    let until = Instant::now() + Duration::from_secs(30);
    while !pids.iter().all(|&p| ended(p)) {
        assert!(Instant::now() < until, "still running after their parent was killed: {pids:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The README's quick start, `cargo run --release -p incise_server -- --demo`, starts the server:
/// with more than one binary in the package, cargo runs one only when told which (`--bin`) or
/// when the package names its `default-run`; otherwise it stops before running anything.
#[test]
fn the_readmes_quick_start_runs_the_server() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let read =
        |p: PathBuf| std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let readme = read(root.join("README.md"));
    let manifest = read(root.join("server/incise_server/Cargo.toml"));
    let run = readme
        .lines()
        .find(|l| l.starts_with("cargo run") && l.contains("-p incise_server"))
        .expect("the README's quick start runs incise_server");
    let picks_server = run.contains("--bin incise-server")
        || manifest.matches("[[bin]]").count() <= 1
        || manifest.lines().any(|l| l.trim() == r#"default-run = "incise-server""#);
    assert!(picks_server, "`{run}` leaves cargo to choose among incise_server's binaries");
}
