//! The Python client (`clients/python/incise_client.py`: zenoh's Python binding and classes
//! generated from the `.proto` files, nothing else of ours) as its own process against a real
//! `incise-server` process: it reads the scene's description and lowers a tool onto the organ
//! until a force in contact comes back. The test makes the venv it needs under `target/`
//! (`INCISE_PYTHON` names an interpreter that already has `clients/python/requirements.txt`).

mod common;

use common::root;
use std::process::{Command, Stdio};
use std::time::Instant;

#[test]
fn the_python_client_reads_the_scene_and_feels_the_organ() {
    let python = common::python("python-venv", "clients/python/requirements.txt");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut server = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--listen", &endpoint, "--no-iceoryx2", "--stop-with-parent"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let out = Command::new(&python)
        .arg(root().join("clients/python/incise_client.py"))
        .args(["--connect", &endpoint, "--scene", "demo_organ", "--tool", "1", "--json"])
        .output()
        .unwrap();
    let _ = server.kill();
    let _ = server.wait();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}(in {:.1} s)", started.elapsed().as_secs_f64());
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(j["scene"], "demo_organ");
    assert_eq!(j["tools"], 2);
    assert!(j["answered"].as_u64().unwrap() > 0);
    assert!(j["contact"]["force"][2].as_f64().unwrap() > 0.0, "{j}");
}
