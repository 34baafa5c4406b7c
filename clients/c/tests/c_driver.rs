//! The C example driver (`clients/c/examples/press.c`), compiled with the system's C compiler
//! against `protocol/include/incise.h` and this package's `libincise_c`, run as its own process
//! against a real server (started in this test's process on loopback) over each transport: it
//! lowers a tool onto the organ and must receive a non-zero force in contact.

use incise_server::server::{self, Options};
use incise_transport::zenoh_link::Endpoints;
use std::path::PathBuf;
use std::process::Command;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The folder cargo put `libincise_c.so` in: this test's own `deps/` folder when cargo built it
/// for the tests, the profile folder above it after a `cargo build`.
fn library_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap().to_path_buf();
    let profile = deps.parent().unwrap().to_path_buf();
    [deps, profile]
        .into_iter()
        .find(|d| d.join("libincise_c.so").exists())
        .expect("cargo builds libincise_c.so beside the tests")
}

#[test]
fn the_c_example_driver_feels_the_organ_over_both_transports() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let lib = library_dir();
    let dir = std::env::temp_dir().join(format!("incise_c_driver_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let binary = dir.join("press");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let built = Command::new(&cc)
        .args(["-std=c11", "-Wall", "-Werror", "-D_POSIX_C_SOURCE=199309L"])
        .arg(root.join("examples/press.c"))
        .arg("-I")
        .arg(root.join("../../protocol/include"))
        .arg("-L")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .args(["-lincise_c", "-o"])
        .arg(&binary)
        .output()
        .unwrap();
    assert!(built.status.success(), "{}", String::from_utf8_lossy(&built.stderr));

    let port = free_port();
    let options = Options { zenoh: Some(Endpoints::listen_loopback(port)), ..Options::default() };
    let scene = incise_server::scene::load(None).unwrap();
    let running = server::start(&scene, "<embedded>", &options).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // The scalpel (tool 0, its outer shape a 12 × 4 mm box) at the organ's top centre; the
    // organ is 8 × 6 × 5 cm.
    for transport in ["iceoryx2", "zenoh"] {
        let out = Command::new(&binary)
            .args([transport, "demo_organ", "0", &endpoint, "0.04", "0.03", "0.05"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        println!("{transport}: {stdout}");
        assert!(
            out.status.success(),
            "{transport}: {stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(stdout.contains("force ("), "{stdout}");
    }
    // A bad transport name is an error the library reports, not a crash.
    let out = Command::new(&binary)
        .args(["carrier-pigeon", "demo_organ", "1", &endpoint, "0", "0", "0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown transport"));
    running.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
