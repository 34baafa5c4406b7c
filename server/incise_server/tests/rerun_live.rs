//! `incise-server --rerun-connect URL` streams the session live to a Rerun endpoint nobody here
//! wrote: Rerun's own `rerun --save` (from `rerun-sdk`), listening on loopback, receives it and
//! writes what it got, and `rerun rrd print` finds the organ, the tools, their forces, the time
//! series and the cuts in it.

mod common;

use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A receiver's process group, killed when dropped.
struct Receiver(std::process::Child);

impl Drop for Receiver {
    fn drop(&mut self) {
        let group = format!("-{}", self.0.id());
        let _ = Command::new("kill").args(["-KILL", "--", &group]).status();
        let _ = self.0.wait();
    }
}

#[test]
fn a_live_stream_reaches_a_rerun_endpoint() {
    let dir = std::env::temp_dir().join(format!("incise_rerun_live_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let python = common::python("python-venv-rerun", "tools/rerun-check/requirements.txt");
    let rerun = python.with_file_name("rerun");
    // No usage reports leave the machine.
    assert!(Command::new(&rerun).args(["analytics", "disable"]).output().unwrap().status.success());
    let port = free_port();
    let saved = dir.join("live.rrd");
    // `rerun` is a Python script that runs Rerun's own binary as a child: the receiver gets a
    // process group of its own, and the whole group is killed (also when the test fails).
    let receiver = Receiver(
        Command::new(&rerun)
            .args(["--bind", "127.0.0.1", "--port", &port.to_string(), "--save"])
            .arg(&saved)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .unwrap(),
    );
    let until = Instant::now() + Duration::from_mins(1);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < until, "rerun never listened on {port}");
        std::thread::sleep(Duration::from_millis(100));
    }
    // zenoh only, on a port of its own: the other tests' demo_organ servers serve iceoryx2.
    let out = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--demo", "--duration", "3", "--no-record", "--no-iceoryx2", "--listen"])
        .arg(format!("tcp/127.0.0.1:{}", free_port()))
        .arg("--rerun-connect")
        .arg(format!("rerun+http://127.0.0.1:{port}/proxy"))
        .output()
        .unwrap();
    let said =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{said}");
    assert!(out.status.success(), "{said}");
    assert!(said.contains("streamed"), "{said}");
    // The receiver writes as data arrives; once the file stops growing, it has it all.
    let mut last = 0;
    let until = Instant::now() + Duration::from_secs(30);
    loop {
        std::thread::sleep(Duration::from_millis(500));
        let size = std::fs::metadata(&saved).map_or(0, |m| m.len());
        if size > 0 && size == last || Instant::now() > until {
            break;
        }
        last = size;
    }
    drop(receiver);
    // Killed, the receiver leaves no footer; the chunks before it are whole.
    let out = Command::new(&rerun)
        .args(["rrd", "print", "--continue-on-error=true"])
        .arg(&saved)
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&out.stdout);
    for entity in [
        "/organ",
        "/tools/scalpel",
        "/tools/grasper/outer",
        "/forces/grasper",
        "/devices/scalpel",
        "/devices/grasper/outer",
        "/couplings/scalpel",
        "/plots/force/scalpel",
        "/plots/frame_ms",
        "/events/cuts",
    ] {
        assert!(
            printed.contains(&format!("- {entity} -")),
            "{entity} not in what rerun received:\n{}",
            printed.lines().take(40).collect::<Vec<_>>().join("\n")
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
