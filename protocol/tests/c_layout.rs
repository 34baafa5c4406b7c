//! `include/incise.h` and the Rust records agree: a C program compiled against the header
//! prints every field's offset and each record's size, and they must equal Rust's.

use incise_protocol::raw::{RawToolForce, RawToolPose};
use std::mem::{offset_of, size_of};
use std::process::Command;

const PROGRAM: &str = r#"
#include <stdio.h>
#include "incise.h"
#define F(T, f) printf(#T "." #f " %zu\n", offsetof(T, f))
int main(void) {
    printf("IncisePose %zu\n", sizeof(IncisePose));
    F(IncisePose, sequence); F(IncisePose, timestamp_ns); F(IncisePose, position);
    F(IncisePose, orientation); F(IncisePose, linear_velocity); F(IncisePose, angular_velocity);
    F(IncisePose, gripper_angle); F(IncisePose, tool_id); F(IncisePose, buttons);
    F(IncisePose, has); F(IncisePose, client);
    printf("InciseForce %zu\n", sizeof(InciseForce));
    F(InciseForce, pose_sequence); F(InciseForce, timestamp_ns); F(InciseForce, force);
    F(InciseForce, torque); F(InciseForce, gripper_force); F(InciseForce, tool_id);
    F(InciseForce, flags);
    return 0;
}
"#;

#[test]
fn the_c_header_declares_the_rust_layout() {
    let dir = std::env::temp_dir().join(format!("incise_c_layout_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let source = dir.join("layout.c");
    let binary = dir.join("layout");
    std::fs::write(&source, PROGRAM).unwrap();
    let include = concat!(env!("CARGO_MANIFEST_DIR"), "/include");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let built = Command::new(&cc)
        .args(["-std=c11", "-Wall", "-Werror", "-I", include])
        .arg(&source)
        .arg("-o")
        .arg(&binary)
        .output()
        .unwrap_or_else(|e| panic!("cannot run the C compiler {cc:?}: {e}"));
    assert!(built.status.success(), "{}", String::from_utf8_lossy(&built.stderr));
    let run = Command::new(&binary).output().unwrap();
    assert!(run.status.success());
    let printed = String::from_utf8(run.stdout).unwrap();
    let expected = [
        ("IncisePose", size_of::<RawToolPose>()),
        ("IncisePose.sequence", offset_of!(RawToolPose, sequence)),
        ("IncisePose.timestamp_ns", offset_of!(RawToolPose, timestamp_ns)),
        ("IncisePose.position", offset_of!(RawToolPose, position)),
        ("IncisePose.orientation", offset_of!(RawToolPose, orientation)),
        ("IncisePose.linear_velocity", offset_of!(RawToolPose, linear_velocity)),
        ("IncisePose.angular_velocity", offset_of!(RawToolPose, angular_velocity)),
        ("IncisePose.gripper_angle", offset_of!(RawToolPose, gripper_angle)),
        ("IncisePose.tool_id", offset_of!(RawToolPose, tool_id)),
        ("IncisePose.buttons", offset_of!(RawToolPose, buttons)),
        ("IncisePose.has", offset_of!(RawToolPose, has)),
        ("IncisePose.client", offset_of!(RawToolPose, client)),
        ("InciseForce", size_of::<RawToolForce>()),
        ("InciseForce.pose_sequence", offset_of!(RawToolForce, pose_sequence)),
        ("InciseForce.timestamp_ns", offset_of!(RawToolForce, timestamp_ns)),
        ("InciseForce.force", offset_of!(RawToolForce, force)),
        ("InciseForce.torque", offset_of!(RawToolForce, torque)),
        ("InciseForce.gripper_force", offset_of!(RawToolForce, gripper_force)),
        ("InciseForce.tool_id", offset_of!(RawToolForce, tool_id)),
        ("InciseForce.flags", offset_of!(RawToolForce, flags)),
    ];
    let lines: Vec<&str> = printed.lines().collect();
    assert_eq!(lines.len(), expected.len(), "{printed}");
    for (line, (name, value)) in lines.iter().zip(expected) {
        assert_eq!(*line, format!("{name} {value}"));
    }
    let _ = std::fs::remove_dir_all(&dir);
}
