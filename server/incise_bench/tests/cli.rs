//! `incise-bench grid` as scripts use it: its JSON keys are a contract.

use std::process::Command;

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_incise-bench"))
}

fn liver() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/liver.inr.gz").to_string()
}

fn last_json(out: &std::process::Output) -> serde_json::Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().expect("some output");
    serde_json::from_str(last).unwrap_or_else(|e| panic!("last line is not JSON ({e}): {last}"))
}

#[test]
fn grid_report_json_has_the_contract_keys() {
    let out = bench()
        .args([
            "grid",
            "--volume",
            &liver(),
            "--stride",
            "8,8,4",
            "--levels",
            "3",
            "--repeats",
            "1",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    for key in [
        "voxels",
        "levels",
        "build_ms",
        "condense_direct_ms",
        "condense_recursive_ms",
        "condense_max_rel_diff",
        "cut500_update_ms",
        "cut500_rebuild_ms",
        "incremental_equals_rebuild",
        "composite_ms",
        "incompatible_ms",
        "cut500_incompatible_ms",
        "cut500_composite_ms",
    ] {
        assert!(j.get(key).is_some(), "missing key {key} in {j}");
    }
    assert_eq!(j["voxels"], 13_648);
    assert_eq!(j["incremental_equals_rebuild"], true);
    assert!(j["condense_max_rel_diff"].as_f64().unwrap() < 1e-12);
    let levels = j["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 4);
    for (l, row) in levels.iter().enumerate() {
        assert_eq!(row["level"], l);
        for key in ["elements", "superimposed", "nodes"] {
            assert!(row[key].is_u64(), "level row lacks {key}: {row}");
        }
    }
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("superimposed") && table.contains("rebuild"), "human table printed");
}

#[test]
fn grid_report_runs_on_a_procedural_organ_and_writes_csv() {
    let csv = std::env::temp_dir().join(format!("incise-grid-{}.csv", std::process::id()));
    let out = bench()
        .args([
            "grid",
            "--procedural-size",
            "32",
            "--levels",
            "2",
            "--repeats",
            "1",
            "--cut-voxels",
            "100",
            "--json",
            "--csv",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    assert!(j["voxels"].as_u64().unwrap() > 1000);
    assert_eq!(j["incremental_equals_rebuild"], true);
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.starts_with("volume,voxels,level,elements"));
    assert_eq!(text.lines().count(), 1 + 3, "header plus levels 0..=2");
    std::fs::remove_file(&csv).ok();
}

#[test]
fn bad_input_gets_a_clear_error() {
    let out = bench().args(["grid", "--volume", "no/such/scan.nii.gz"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no/such/scan.nii.gz"), "names the file: {err}");

    let out = bench().args(["grid", "--stride", "4,0,2"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("at least 1"));

    let out = bench().args(["grid", "--levels", "9"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--levels 9"));

    // The report's flags are a contract scripts rely on: each is listed with what it does.
    let out = bench().args(["speed-error", "--help"]).output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--scene",
        "--json",
        "--csv",
        "--png",
        "--max-error",
        "--peers",
        "--liver-109k-levels",
        "--models",
        "--richardson-cells",
        "--no-richardson",
        "--elements",
    ] {
        assert!(help.contains(flag), "speed-error --help lists {flag}:\n{help}");
    }
    assert!(help.contains("b2-moving"), "speed-error --help names the moving scene:\n{help}");
    assert!(help.contains("liver-press"), "speed-error --help names the pressed liver:\n{help}");

    // Richardson extrapolation needs the second mesh finer on every axis.
    let out = bench()
        .args(["speed-error", "--scene", "b1", "--reference-cells", "11,8,6"])
        .args(["--richardson-cells", "11,10,8"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--richardson-cells") && err.contains("finer"), "{err}");

    // An element kind the report does not know is named, with the kinds it does.
    let out =
        bench().args(["speed-error", "--scene", "b1", "--elements", "quadratic"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("\"quadratic\"") && err.contains("composite"), "{err}");
}

#[test]
fn speed_error_report_writes_table_csv_png_and_json() {
    let dir = std::env::temp_dir().join(format!("incise-se-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (csv, png) = (dir.join("out.csv"), dir.join("out.png"));
    let out = bench()
        .args([
            "speed-error",
            "--scene",
            "c",
            "--max-elements",
            "100",
            "--steps",
            "2",
            "--repeats",
            "1",
        ])
        .args(["--stable-seconds", "0.02", "--settle-seconds", "3", "--max-error", "0.5"])
        // Short timed runs keep the debug build quick (the report's default aims at 0.25 s).
        .args(["--run-seconds", "0", "--warmup-steps", "1"])
        .args(["--json", "--csv"])
        .arg(&csv)
        .arg("--png")
        .arg(&png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let rows = j["rows"].as_array().unwrap();
    assert_eq!(
        rows.len(),
        2 * 2 * 3 * 2,
        "2 meshes x 2 models x (explicit, jacobi-cg and cholesky-cg implicit) x 2 dt"
    );
    for row in rows {
        for key in [
            "scene",
            "model",
            "dt",
            "steps_per_s",
            "steps_per_s_one_thread",
            "error",
            "error_abs",
            "trajectory_error",
            "stable",
            "elements",
            "dofs",
        ] {
            assert!(row.get(key).is_some(), "row lacks {key}: {row}");
        }
        assert!(row["trajectory_error"].is_null(), "only b2-moving has one: {row}");
    }
    assert!(rows.iter().any(|r| r["stable"] == true && r["steps_per_s"].as_f64().unwrap() > 0.0));
    // Every stable implicit row settles on the static answer of its own mesh and model: the
    // measured error and the static one agree (the run stops within 1e-5 of still).
    for r in rows.iter().filter(|r| r["stable"] == true && r["integrator"] == "implicit-euler") {
        assert_eq!(r["settled"], true, "{r}");
        let (e, s) = (r["error"].as_f64().unwrap(), r["error_static"].as_f64().unwrap());
        assert!((e - s).abs() <= 1e-3 * s.max(1e-3), "{r}");
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("fastest stable configuration within 50.0 %"), "{stdout}");
    assert!(stdout.contains("explicit stable dt per mesh"), "{stdout}");
    assert_eq!(std::fs::read_to_string(&csv).unwrap().lines().count(), 1 + rows.len());
    let png_bytes = std::fs::read(&png).unwrap();
    assert_eq!(&png_bytes[..8], b"\x89PNG\r\n\x1a\n", "a PNG file");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn speed_error_compares_measured_peers_at_equal_error() {
    let dir = std::env::temp_dir().join(format!("incise-peers-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let table = dir.join("mujoco.txt");
    // Two rows as `bench_mujoco.py` prints them: one settled at 11.7 mm, one that blew up.
    std::fs::write(
        &table,
        "# MuJoCo 4.0.0 flexcomp dim=3\n\
         discrete   S1  840  240  2000  1859.7  1821.8  1873.5  stable  0.0117  stable  0.0121\n\
         Euler      S1  840  240  2000  7867.4  7777.1  7910.4  blow-up (BADQACC reset)  nan  \
         blow-up (BADQACC reset)  nan\n",
    )
    .unwrap();
    let out = bench()
        .args(["speed-error", "--scene", "b1", "--steps", "2", "--repeats", "1"])
        // A coarse reference keeps the debug build quick; the comparison logic is the same.
        .args(["--reference-cells", "11,8,6", "--richardson-cells", "15,11,8"])
        .args(["--settle-seconds", "8"])
        .args(["--run-seconds", "0", "--warmup-steps", "1"])
        .args(["--stable-seconds", "0.02", "--json", "--peers"])
        .arg(&table)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let peers = j["peers"].as_array().unwrap();
    assert_eq!(peers.len(), 2);
    let implicit = &peers[0];
    let reference = j["references"]["B1"].as_f64().unwrap();
    // Scene B's rows are measured against the Richardson extrapolation of the two meshes.
    let b = &j["references"]["B"];
    let value = |key: &str| b[key].as_f64().unwrap_or_else(|| panic!("references.B.{key}: {b}"));
    let (coarse, fine, extrapolated) = (value("coarse"), value("fine"), value("extrapolated"));
    assert!(extrapolated.is_finite() && extrapolated > 0.0, "{b}");
    assert_eq!(j["references"]["B1"], b["extrapolated"], "B1's rows use the extrapolation");
    let r = value("h_ratio");
    assert!(
        (r - (0.15 / 11.0) / (10.0 / 1000.0)).abs() < 1e-12,
        "largest edges 13.6 mm, 10 mm: {b}"
    );
    assert!((extrapolated - (fine + (fine - coarse) / (r * r - 1.0))).abs() < 1e-12, "{b}");
    assert!((value("estimated_error") - (extrapolated - fine).abs()).abs() < 1e-12, "{b}");
    for row in j["rows"].as_array().unwrap() {
        if let Some(e) = row["error"].as_f64() {
            assert_eq!(row["error_abs"], serde_json::json!(e.abs()), "{row}");
        }
        let one = &row["steps_per_s_one_thread"];
        if row["integrator"] == "implicit-euler" && row["stable"] == true {
            assert!(one.as_f64().unwrap() > 0.0, "one-thread speed of an implicit row: {row}");
        } else {
            assert!(one.is_null(), "only implicit rows are timed on one thread: {row}");
        }
    }
    // Tensor-mass tetrahedra with implicit Euler: stable at 10 ms (where the explicit scheme is
    // not), and settled on the same static answer as their relaxation.
    let tets: Vec<_> = j["rows"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["model"] == "tensor-mass-svk" && r["integrator"] == "implicit-euler")
        .collect();
    assert_eq!(tets.len(), 2, "implicit tensor-mass rows at 1 and 10 ms");
    for r in tets {
        assert_eq!(
            (r["stable"].as_bool(), r["settled"].as_bool()),
            (Some(true), Some(true)),
            "{r}"
        );
        let (e, s) = (r["error"].as_f64().unwrap(), r["error_static"].as_f64().unwrap());
        assert!((e - s).abs() <= 1e-3 * s.abs(), "{r}");
    }
    // Signed: some B1 row is off on the soft or the stiff side, not only in size.
    assert!(
        j["rows"].as_array().unwrap().iter().any(|r| r["error"].as_f64().is_some_and(|e| e < 0.0))
    );
    assert_eq!(j["threads"]["steps_per_s_one_thread"], 1);
    let error = implicit["error"].as_f64().unwrap();
    assert!((error - (reference - 0.0117) / reference).abs() < 1e-4, "{implicit}");
    let ours = &implicit["ours"];
    assert!(
        ours["error"].as_f64().unwrap() <= error,
        "ours is at equal or lower error: {implicit}"
    );
    let ratio = implicit["ratio"].as_f64().unwrap();
    assert!((ratio - ours["steps_per_s"].as_f64().unwrap() / 1859.7).abs() < 1e-9);
    assert!(peers[1]["error"].is_null() && peers[1]["ours"].is_null(), "blew up: {}", peers[1]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("At equal error") && stdout.contains("blew up"), "{stdout}");

    std::fs::write(&table, "no table here\n").unwrap();
    let out = bench()
        .args(["speed-error", "--scene", "b1", "--reference-cells", "11,8,6", "--peers"])
        .arg(&table)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("mujoco.txt") && err.contains("no rows"), "names file and problem: {err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn speed_error_b2_moving_reports_trajectory_errors() {
    let csv = std::env::temp_dir().join(format!("incise-moving-{}.csv", std::process::id()));
    let out = bench()
        .args(["speed-error", "--scene", "b2-moving", "--repeats", "1"])
        // The protocol's 2 s would take minutes in a debug build; 0.1 s keeps one round trip.
        .args(["--moving-seconds", "0.1", "--json", "--csv"])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let rows = j["rows"].as_array().unwrap();
    // Per model: jacobi-cg and cholesky-cg (and the linear model's exact factor) at 1 and 10 ms,
    // and explicit at 1 ms.
    assert_eq!(rows.len(), (2 * 2 + 1) + (3 * 2 + 1), "{j}");
    for r in rows {
        assert_eq!(r["scene"], "B2-moving");
        assert_eq!(r["stable"], true, "every row is stable on B2: {r}");
        let e = r["trajectory_error"].as_f64().unwrap();
        assert!(e.is_finite() && e >= 0.0, "{r}");
        assert!(r["error"].is_null(), "a moving block has no settled error: {r}");
        assert!(r["steps_per_s"].as_f64().unwrap() > 0.0, "{r}");
        if r["integrator"] == "implicit-euler" {
            assert!(r["steps_per_s_one_thread"].as_f64().unwrap() > 0.0, "{r}");
        } else {
            assert!(r["steps_per_s_one_thread"].is_null(), "{r}");
        }
    }
    // A tenth of the step follows the reference ten times closer or so, whatever the solver.
    for r in rows.iter().filter(|r| r["integrator"] == "implicit-euler" && r["dt"] == 0.001) {
        let coarse = rows
            .iter()
            .find(|q| q["model"] == r["model"] && q["solver"] == r["solver"] && q["dt"] == 0.01)
            .unwrap();
        let (fine, coarse) = (r["trajectory_error"].as_f64(), coarse["trajectory_error"].as_f64());
        assert!(fine.unwrap() < 0.5 * coarse.unwrap(), "{r}");
    }
    let reference = &j["references"]["B2-moving"];
    assert_eq!(reference["dt"], 1e-4);
    assert_eq!(reference["cg_tolerance"], 1e-12);
    for model in ["corotational-hex", "linear-hex"] {
        let peak = reference["peak_displacement"][model].as_f64().unwrap();
        assert!(peak > 1e-3 && peak < 0.05, "the corner moves millimetres: {reference}");
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("traj err") && stdout.contains("1T steps/s"), "{stdout}");
    let text = std::fs::read_to_string(&csv).unwrap();
    let header = text.lines().next().unwrap();
    assert!(
        header.starts_with(
            "scene,model,integrator,solver,resolution,level,elements,dofs,dt,steps_per_s,steps_per_s_min,steps_per_s_max,error,stable,error_static,settled,error_abs,trajectory_error,steps_per_s_one_thread,"
        ) && header.ends_with(",element,error_signed,error_level0"),
        "older columns keep their places, new ones go at the end: {header}"
    );
    for r in rows {
        assert_eq!(r["element"], "condensed", "{r}");
    }
    assert_eq!(text.lines().count(), 1 + rows.len());
    std::fs::remove_file(&csv).ok();
}

/// The liver's rows against the liver's reference, the 109,201-voxel liver at level 0: the
/// contract keys, each row's error built from its signed errors, the settled runs on their static
/// answers, and the reference itself as `incise-bench reference` measured it (docs/benchmarks.md,
/// "The liver's reference": 47.96 mm, the 13,648-voxel liver's level 0 13.1 % short, linear).
#[test]
fn speed_error_measures_the_liver_against_the_fine_liver() {
    let out = bench()
        .args(["speed-error", "--scene", "liver", "--models", "linear"])
        .args(["--liver-levels", "3", "--liver-109k-levels", "3"])
        .args(["--elements", "condensed,incompatible"])
        .args(["--steps", "2", "--repeats", "1", "--run-seconds", "0", "--warmup-steps", "1"])
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let liver = &j["references"]["liver"];
    let reference = &liver["measures"]["linear"];
    let com = reference["centre_of_mass"].as_f64().unwrap();
    // The figures were printed to 0.01 mm and 0.1 %.
    assert!((com - 47.96e-3).abs() <= 0.005e-3, "{liver}");
    assert_eq!(liver["measures"]["points"], 13_648, "{liver}");
    assert!(liver["measures"]["corotational"].is_null(), "not asked for: {liver}");
    let level0 = liver["liver-13k level 0"]["linear"]["centre_of_mass"].as_f64().unwrap();
    assert!((level0 + 0.131).abs() <= 0.0005, "{liver}");
    let rows = j["rows"].as_array().unwrap();
    for scene in ["liver-13k", "liver-109k"] {
        let n = rows.iter().filter(|r| r["scene"] == scene).count();
        assert_eq!(n, 2 * 3 * 2, "{scene}: 2 element kinds x 3 schemes x 2 dt");
    }
    for r in rows {
        for key in ["scene", "error", "error_signed", "steps_per_s", "dt", "stable"] {
            assert!(r.get(key).is_some(), "row lacks {key}: {r}");
        }
        assert_eq!(r["model"], "linear-hex", "{r}");
        if r["settled"] != true {
            continue;
        }
        let signed = &r["error_signed"];
        let part = |k: &str| signed[k].as_f64().unwrap_or_else(|| panic!("no {k}: {r}"));
        let error = r["error"].as_f64().unwrap();
        // The same number, not a near one: `error` is one of the two.
        let worst = part("centre_of_mass").abs().max(part("max").abs());
        assert_eq!(error.to_bits(), worst.to_bits(), "{r}");
        assert!(part("rms").is_finite(), "{r}");
        // Coarse levels are stiffer than the voxels: every measure short of the reference.
        assert!(part("centre_of_mass") < 0.0 && part("max") < 0.0, "{r}");
        // Settled within 1e-5 of still: on the static answer of the row's own model.
        let s = r["error_static"].as_f64().unwrap();
        assert!((error - s).abs() <= 1e-4, "{r}");
        assert!(r["error_level0"].as_f64().unwrap() > 0.0, "{r}");
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("the liver's reference: liver_109k.toml at level 0"), "{stdout}");
    assert!(
        bench()
            .args(["speed-error", "--scene", "liver", "--models", "hyperelastic"])
            .output()
            .is_ok_and(|o| !o.status.success()
                && String::from_utf8_lossy(&o.stderr).contains("unknown model \"hyperelastic\"")),
        "an unknown model is named"
    );
}

/// The pressed liver: every row a trajectory against the level-0 reference's, with its peak's
/// signed error; the reference's step and tolerance as documented.
#[test]
fn speed_error_presses_the_liver_and_compares_trajectories() {
    let out = bench()
        .args(["speed-error", "--scene", "liver-press", "--models", "linear"])
        .args(["--liver-levels", "3", "--elements", "condensed", "--press-seconds", "0.05"])
        .arg("--json")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let reference = &j["references"]["liver-13k-press"][0];
    assert_eq!(reference["dt"], 5e-4, "{reference}");
    assert_eq!(reference["model"], "linear-hex", "{reference}");
    let peak = reference["peak_displacement"].as_f64().unwrap();
    assert!(peak > 0.0 && peak < 0.1, "the tool moves the organ, not away: {reference}");
    let rows = j["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3 * 2, "jacobi-cg, cholesky-cg and explicit at 1 and 10 ms: {j}");
    for r in rows {
        assert_eq!(r["scene"], "liver-13k-press", "{r}");
        assert!(
            r["error"].is_null() && r["settled"] == false,
            "a trajectory, not a settled value: {r}"
        );
        if r["stable"] != true {
            continue;
        }
        let e = r["trajectory_error"].as_f64().unwrap();
        assert!(e.is_finite() && e >= 0.0, "{r}");
        let signed = r["error_signed"]["peak"].as_f64().unwrap();
        assert!(signed > -1.0 && signed.is_finite(), "{r}");
    }
    let implicit = rows
        .iter()
        .filter(|r| r["integrator"] == "implicit-euler")
        .map(|r| r["stable"] == true)
        .collect::<Vec<_>>();
    assert!(implicit.iter().all(|&s| s), "implicit Euler is stable at both steps: {j}");
}

#[test]
fn coexist_json_has_a_row_per_setting_with_the_contract_keys() {
    let out =
        bench().args(["coexist", "--scene", "b1", "--seconds", "0.2", "--json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    let rows = j["rows"].as_array().expect("rows");
    let settings: Vec<(u64, bool)> = rows
        .iter()
        .map(|r| {
            for key in ["physics_threads", "spin", "steps_per_s", "jitter_us_p99", "jitter_us_max"]
            {
                assert!(r.get(key).is_some(), "missing key {key} in {r}");
            }
            (r["physics_threads"].as_u64().unwrap(), r["spin"].as_bool().unwrap())
        })
        .collect();
    assert_eq!(settings, [(0, false), (1, false), (1, true), (2, false), (2, true)]);
    for r in &rows[1..] {
        assert!(r["steps_per_s"].as_f64().unwrap() > 0.0, "the physics stepped: {r}");
        // Times are measured, not asserted; what can be checked is that the quantiles of the
        // periods' distance from the nominal period are consistent: ordered, all finite.
        let q = |key: &str| r[key].as_f64().unwrap();
        let (p50, p99, max) = (q("jitter_us_p50"), q("jitter_us_p99"), q("jitter_us_max"));
        assert!(max.is_finite() && 0.0 <= p50 && p50 <= p99 && p99 <= max, "{r}");
    }
}

#[test]
fn coexist_names_a_missing_scene() {
    let out = bench().args(["coexist", "--scene", "no_such_scene"]).output().unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no_such_scene"), "{stderr}");
}

/// `incise-bench frame` on the liver, hexahedral (coarse) and tensor-mass: the JSON keys the
/// issue's contract names are there, the scripted tools cut, and no frame's state is non-finite
/// (the report counts them; a tool setting that destabilises a family shows here first).
#[test]
fn frame_report_json_has_the_contract_keys_and_every_frame_is_finite() {
    let tensor_mass =
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/scenes/liver_tensor_mass.toml");
    // The tensor-mass liver at its own stride: its lightest vertices are what an unstable
    // explicit tool force blows up first.
    let liver = ["--stride", "16,16,8", "--levels", "2"];
    let incompatible = ["--stride", "16,16,8", "--levels", "2", "--elements", "incompatible"];
    for (scene, extra) in
        [("liver", &liver[..]), ("liver", &incompatible[..]), (tensor_mass, &[][..])]
    {
        let out = bench().args(["frame", "--scene", scene, "--json"]).args(extra).output().unwrap();
        assert!(out.status.success(), "{scene}: {}", String::from_utf8_lossy(&out.stderr));
        let j = last_json(&out);
        for key in [
            "frame_hz_median",
            "frame_ms_p99",
            "cut_stroke_ms",
            "voxels_removed",
            "triangles",
            "tool_force_max_n",
            "gpu",
            "gpu_cpu_max_diff",
        ] {
            assert!(j.get(key).is_some(), "{scene}: no {key} in {j}");
        }
        assert_eq!(j["gpu"], "none");
        assert!(j["gpu_cpu_max_diff"].is_null());
        assert_eq!(j["non_finite_frames"], 0, "{scene}: {j}");
        let cut = j["voxels_removed"].as_u64().unwrap() + j["tets_removed"].as_u64().unwrap();
        assert!(cut > 0, "{scene}: the scripted tools cut nothing");
        let kind = if extra.contains(&"incompatible") { "incompatible" } else { "condensed" };
        if scene == "liver" {
            assert_eq!(j["model"], format!("corotational hexahedra, {kind} elements"), "{j}");
        }
    }
}

/// `incise-bench frame --record DIR` runs the script again while recording it: the recording
/// reads back with every frame, those frames are bit-identical to the unrecorded run, and the
/// rates with and without recording and their ratio are reported (printed, not asserted).
#[test]
fn frame_report_records_the_script_and_reports_the_rate_with_and_without() {
    let dir = std::env::temp_dir().join(format!("incise_frame_record_{}", std::process::id()));
    let out = bench()
        .args(["frame", "--scene", "liver", "--stride", "16,16,8", "--levels", "2", "--json"])
        .arg("--record")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let j = last_json(&out);
    println!(
        "ratio {} ({} → {} frames/s)",
        j["record_ratio"], j["record_frame_hz_off"], j["record_frame_hz_on"]
    );
    assert!(j["record_ratio"].as_f64().is_some_and(|r| r > 0.0), "{j}");
    assert_eq!(j["record_bit_identical"], true);
    let file = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap();
    let contents = incise_record::read_recording(&std::fs::read(&file).unwrap()).unwrap();
    assert_eq!(contents.frames.len() as u64, j["frames"].as_u64().unwrap());
    assert!(
        contents.scene_toml.as_deref().is_some_and(|t| t.contains("[volume]")),
        "the scene is stored"
    );
    assert!(!contents.surfaces.is_empty(), "the surface is recorded");
    assert!(file.with_extension("rrd").is_file(), "the .rrd twin is written");
    assert!(j["record_mb_per_min"].as_f64().is_some_and(|m| m > 0.0), "{j}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `incise-bench latency` over each transport, briefly: a server and a client process run, the
/// round trips are measured, then the echo server's floor, and the last line holds the
/// contract's keys.
#[test]
fn latency_report_json_has_the_contract_keys() {
    for transport in ["iceoryx2", "zenoh"] {
        let out = bench()
            .args(["latency", "--transport", transport, "--duration", "1", "--json"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{transport}: {}", String::from_utf8_lossy(&out.stderr));
        let j = last_json(&out);
        assert_eq!(j["transport"], transport);
        for key in [
            "rtt_us_p50",
            "rtt_us_p99",
            "rtt_us_p999",
            "jitter_us_p99",
            "floor_us_p50",
            "floor_us_p99",
        ] {
            assert!(j[key].as_f64().is_some_and(|v| v > 0.0), "{transport}: {key} in {j}");
        }
        assert!(j["samples"].as_u64().unwrap() > 100, "{transport}: {j}");
    }
}

/// `incise-bench haptics`, briefly (a shallow sweep, two cycles) over each transport: a real
/// server and client process drive the demo's two tools, the recording replays bit for bit, and
/// the last line holds the contract's keys with figures a solid proxy gives: every tool was
/// pushed back, the grasper's proxy stayed on the surface, and the cycles gave the hand no
/// energy.
#[test]
fn haptics_report_json_has_the_contract_keys() {
    for transport in ["iceoryx2", "zenoh"] {
        let out = bench()
            .args(["haptics", "--transport", transport, "--cycles", "2", "--depth", "2"])
            .args(["--speed", "20", "--json"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{transport}: {}", String::from_utf8_lossy(&out.stderr));
        let j = last_json(&out);
        let run = &j["runs"][0];
        assert_eq!(run["transport"], transport, "{j}");
        for key in ["tick_cost_us_p50", "tick_cost_us_p99"] {
            assert!(run[key].as_f64().is_some_and(|v| v > 0.0), "{transport}: {key} in {j}");
        }
        assert!(run["frames"].as_u64().unwrap() > 0, "{j}");
        assert_eq!(run["replayed_frames"], run["frames"], "{j}");
        assert!(run["diverged"].is_null(), "the replay diverged: {j}");
        let tools = run["tools"].as_array().unwrap();
        assert_eq!(tools.len(), 2, "the demo's scalpel and grasper: {j}");
        for tool in tools {
            for key in ["max_force_step_n", "cycles_work_j"] {
                assert!(tool[key].as_f64().is_some_and(|v| v > 0.0), "{key} in {tool}");
            }
            let force = tool["max_force_n"].as_f64().unwrap();
            assert!(force > 0.0 && force <= 8.0 + 1e-9, "{tool}");
            // The proxy's outer shape against the deformed surface, over the sweep, the jab and
            // the cycles as the server ran them: the grasper's stays on the organ, within a
            // tenth of its 2.5 mm voxels (a tool that slipped in would be millimetres deep; the
            // tenth of a millimetre of the depth sweep alone is the hard-case suite's). The
            // scalpel's proxy rests in its own cut, whose walls (whole voxels) reach into its
            // outer shape, and the measure counts them.
            let depth = tool["max_penetration_mm"].as_f64().unwrap();
            assert!(depth >= 0.0, "{tool}");
            if tool["name"] == "grasper" {
                assert!(depth < 0.25, "{tool}");
            }
            let (energy, work) = (
                tool["cycles_energy_j"].as_f64().unwrap(),
                tool["cycles_work_j"].as_f64().unwrap(),
            );
            assert!(energy <= 0.01 * work, "the hand received {energy} J of {work} J: {tool}");
            for test in ["sweep", "jab", "cycles"] {
                assert!(tool["max_force_step_n_by_test"][test].is_number(), "{test} in {tool}");
            }
        }
    }
}

#[test]
fn multigrid_report_solves_every_system_to_the_cholesky_answer() {
    let out = bench()
        .args(["multigrid", "--level", "1", "--coarsest", "2,3", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    println!("{}", String::from_utf8_lossy(&out.stdout));
    let rows = last_json(&out)["rows"].as_array().unwrap().clone();
    // Three systems, each with Cholesky, block-Jacobi and the two hierarchies.
    assert_eq!(rows.len(), 12);
    let find = |system: &str, solver: &str| {
        rows.iter()
            .find(|r| r["system"] == system && r["solver"] == solver)
            .unwrap_or_else(|| panic!("no {system} {solver} row"))
    };
    for row in &rows {
        for key in ["scene", "level", "dofs", "iterations", "setup_ms", "solve_ms", "difference"] {
            assert!(!row[key].is_null(), "{key} in {row}");
        }
        assert!(row["difference"].as_f64().unwrap() < 1e-6, "{row}");
    }
    let iterations = |solver: &str| find("static", solver)["iterations"].as_u64().unwrap();
    assert!(iterations("multigrid-L3") * 5 < iterations("jacobi-cg"), "{rows:?}");
    let err = bench().args(["multigrid", "--level", "2", "--coarsest", "1"]).output().unwrap();
    assert!(!err.status.success());
    assert!(String::from_utf8_lossy(&err.stderr).contains("--coarsest 1 is not above --level 2"));
}

#[test]
fn reference_names_an_unknown_solver() {
    let out = bench().args(["reference", "--solver", "gauss"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--solver") && err.contains("gauss") && err.contains("multigrid"),
        "{err}"
    );
}
