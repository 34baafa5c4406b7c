//! The README's main command, `incise-server --demo`, as its own process: the scripted scalpel
//! (iceoryx2) presses and cuts, the grasper (zenoh) takes hold, a viewer over zenoh sees every
//! frame's statistics and the cuts, and the summary says so.

use std::process::Command;

/// The first number after `label` in `text`.
fn number_after(text: &str, label: &str) -> f64 {
    let rest = text.split(label).nth(1).unwrap_or_else(|| panic!("no {label:?} in:\n{text}"));
    let digits: String =
        rest.trim_start().chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    digits.parse().unwrap_or_else(|_| panic!("no number after {label:?} in:\n{text}"))
}

#[test]
fn the_demo_presses_cuts_grasps_and_reports() {
    let out = Command::new(env!("CARGO_BIN_EXE_incise-server"))
        .args(["--demo", "--duration", "4"])
        .output()
        .unwrap();
    let summary = String::from_utf8_lossy(&out.stdout);
    println!("{summary}");
    assert!(out.status.success(), "{summary}{}", String::from_utf8_lossy(&out.stderr));
    let frames = number_after(&summary, "physics:");
    assert!(frames > 1000.0, "{frames} frames in 4 s at dt 1 ms");
    assert!(number_after(&summary, "removed") > 0.0, "the scalpel never cut");
    for tool in ["scalpel over iceoryx2:", "grasper over zenoh:"] {
        let line = summary.lines().find(|l| l.starts_with(tool)).expect(tool);
        assert!(number_after(line, "poses,") > 1000.0, "{line}");
        assert!(number_after(line, "max force") > 0.0, "{line}");
    }
    let viewer = summary.lines().find(|l| l.starts_with("a viewer over zenoh:")).unwrap();
    // Frames published while the viewer's subscription was being set up may be missed.
    assert!(number_after(viewer, "zenoh:") > frames * 0.9, "{viewer}");
    assert!(number_after(viewer, "statistics (up to frame") > 0.0, "{viewer}");
    assert!(number_after(viewer, "),") > 0.0, "no cut event: {viewer}");
    assert!(summary.contains("faults: none"), "{summary}");
}
