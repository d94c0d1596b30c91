//! The `hilo` binary as a user runs it.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

mod pictures;
use pictures::{Kind, assert_labelled};

fn hilo() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hilo"))
}

#[test]
fn scene_show_writes_a_png_of_the_default_scene() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("pics/scene.png");
    let st = hilo().args(["scene", "show", "--out"]).arg(&out).args(["--px-per-m", "2"]).status().unwrap();
    assert!(st.success());
    let png = tiny_skia::Pixmap::load_png(&out).unwrap();
    // The default ground is 300 m square.
    assert_eq!((png.width(), png.height()), (600, 600));
    // Not a blank canvas: roads (dark) and ground (light green) both present.
    let px = png.pixels();
    let dark = px.iter().filter(|p| p.red() < 90 && p.green() < 90).count();
    assert!(dark > px.len() / 20, "too little road drawn: {dark}");
    assert_labelled(&out, Kind::Map);
    // No temporary file left behind.
    assert_eq!(std::fs::read_dir(dir.path().join("pics")).unwrap().count(), 1);
}

#[test]
fn scene_show_of_a_bad_file_names_it_and_fails_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("mine.toml");
    std::fs::write(&scene, "name = \"x\"\n[[trees]]\nposition = [0.0, 0.0]\ncrown_radius_m = nan\n").unwrap();
    let out = dir.path().join("scene.png");
    let o = hilo().args(["scene", "show"]).arg(&scene).arg("--out").arg(&out).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("mine.toml") && err.contains("trees[0].crown_radius_m"), "{err}");
    assert!(!out.exists());
}

#[test]
fn bench_raycast_json_reports_speed_and_error() {
    let o = hilo().args(["bench", "raycast", "--json", "--azimuth-steps", "128", "--repeats", "1"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["rays"], 4 * 64 * 128);
    assert_eq!(v["mismatches"].as_u64(), Some(0));
    assert_eq!(v["unexplained"].as_u64(), Some(0));
    assert!(v["max_abs_dist_err_m"].as_f64().unwrap() <= 1e-4);
    assert!(v["hilo_mrays_per_s"].as_f64().unwrap() > 0.0 && v["parry_mrays_per_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn scene_info_summarises_the_default_scene() {
    let o = hilo().args(["scene", "info"]).output().unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["mounting_structures"].as_array().unwrap().len(), 4);
    assert_eq!(v["arms"].as_array().unwrap().len(), 4);
    let central = v["rois"].as_array().unwrap().iter().find(|r| r["name"] == "central conflict zone").unwrap();
    // 39.6 m x 39.6 m junction box with crosswalks, less the four corner notches.
    let area = central["area_m2"].as_f64().unwrap();
    assert!(area > 1000.0 && area < 1600.0, "{area}");
    // The demand levels each arm would run at, the peak above the off-peak everywhere.
    let rates = |level: &str| -> Vec<f64> {
        v["demand"][level]["approaches"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a["vehicles_per_hour"].as_f64().unwrap())
            .collect()
    };
    let (off, peak) = (rates("off_peak"), rates("peak"));
    assert_eq!((off.len(), peak.len()), (4, 4));
    assert!(off.iter().zip(&peak).all(|(o, p)| *o > 100.0 && p > o), "{off:?} {peak:?}");
}

#[test]
fn scan_writes_a_readable_cloud_and_a_picture() {
    use hilo_core::{LidarPoint, RadarPoint};
    use hilo_sensor_models::export::{from_pcd, from_ply};
    let dir = tempfile::tempdir().unwrap();
    let pcd = dir.path().join("scan.pcd");
    let png = dir.path().join("scan.png");
    let o = hilo()
        .args(["scan", "--sensor", "lidar-16", "--pose", "13,16.6,7.8,-127,10", "--out"])
        .arg(&pcd)
        .arg("--png")
        .arg(&png)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let pts: Vec<LidarPoint> = from_pcd(&std::fs::read(&pcd).unwrap(), &pcd).unwrap();
    assert!(pts.len() > 1000 && pts.len() <= 16 * 900);
    assert!(pts.iter().all(|p| p.ring < 16));
    assert_labelled(&png, Kind::Map);
    // Same seed, same bytes.
    let again = dir.path().join("again.pcd");
    let st = hilo()
        .args(["scan", "--sensor", "lidar-16", "--pose", "13,16.6,7.8,-127,10", "--out"])
        .arg(&again)
        .status()
        .unwrap();
    assert!(st.success());
    assert_eq!(std::fs::read(&pcd).unwrap(), std::fs::read(&again).unwrap());
    // Radar to PLY, with approaching and receding road users.
    let ply = dir.path().join("radar.ply");
    let st = hilo()
        .args(["scan", "--sensor", "radar-4d", "--pose", "16.6,-7,6.4,165,8", "--out"])
        .arg(&ply)
        .status()
        .unwrap();
    assert!(st.success());
    let r: Vec<RadarPoint> = from_ply(&std::fs::read(&ply).unwrap(), &ply).unwrap();
    assert!(r.iter().any(|p| p.v_r_mps < -1.0) && r.iter().any(|p| p.v_r_mps > 1.0));
}

#[test]
fn the_text_check_fails_on_a_picture_without_text() {
    pictures::check_can_fail();
}

#[test]
fn scan_with_bad_input_explains_itself() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.pcd");
    let o = hilo().args(["scan", "--sensor", "lidar-128", "--pose", "0,0,8", "--out"]).arg(&out).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("lidar-128") && err.contains("lidar-16") && err.contains("radar-4d"), "{err}");
    let o = hilo().args(["scan", "--sensor", "lidar-16", "--pose", "0,zero,8", "--out"]).arg(&out).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("zero"));
    // Inside the bank building.
    let o = hilo().args(["scan", "--sensor", "lidar-16", "--pose", "-35,-36,3", "--out"]).arg(&out).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("bank"));
    // Underground: refused, not 4,000 points "from below the road".
    let o = hilo().args(["scan", "--sensor", "lidar-16", "--pose", "0,0,-5", "--out"]).arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("below the ground") && err.contains("-5"), "{err}");
    assert!(!out.exists());
    // More road users than the lanes hold: written, with a warning naming both counts.
    let o = hilo()
        .args(["scan", "--sensor", "lidar-16", "--pose", "13,16.6,7.8,-127,10", "--actors", "100000", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && err.contains("--actors 100000 asked") && out.exists(), "{err}");
}

#[test]
fn bench_sensors_json_reports_frame_times_and_model_error() {
    let o = hilo().args(["bench", "sensors", "--json", "--frames", "2", "--actors", "20"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["cheap_suite_frame_ms"].as_f64().unwrap() > 0.0);
    assert!(v["lidar64_radar_rays_per_frame"].as_u64().unwrap() > v["cheap_suite_rays_per_frame"].as_u64().unwrap());
    let (e, s) =
        (v["probe_car_expected_returns"].as_f64().unwrap(), v["probe_car_simulated_mean_returns"].as_f64().unwrap());
    assert!((e - s).abs() < 0.1 * e, "model {e} vs simulation {s}");
}

/// `hilo bench simulate STUDY` benches the study's first configuration and names the LiDARs
/// whose beams' width it casts: a datasheet LiDAR's, unless the study says `lidar_beam_width =
/// false`; the paper's catalog gives no width.
#[test]
fn bench_simulate_names_the_lidars_whose_beams_width_it_casts() {
    let dir = tempfile::tempdir().unwrap();
    let sheet = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sensors-datasheet.toml");
    let rig = "[[configurations]]\nname = \"one\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n";
    let study = coarse_study(dir.path(), rig);
    let coarse = std::fs::read_to_string(&study).unwrap();
    let bench = |name: &str, head: &str, tail: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, format!("{head}{coarse}{tail}")).unwrap();
        let o = hilo()
            .args(["bench", "simulate"])
            .arg(&p)
            .args(["--scenes", "1", "--seconds", "0.2", "--rate-hz", "10", "--json"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!((v["configuration"].as_str(), v["frames"].as_u64()), (Some("one"), Some(2)), "{v}");
        assert!(v["study"].as_str().unwrap().ends_with(name), "{v}");
        v["beam_width_cast"].as_array().unwrap().iter().map(|c| c.as_str().unwrap().to_owned()).collect::<Vec<_>>()
    };
    let catalog = format!("catalog = {:?}\n", sheet.display().to_string());
    assert_eq!(bench("sheet.toml", &catalog, ""), ["LIDAR_0"]);
    assert!(bench("thin.toml", &catalog, "[dataset]\nlidar_beam_width = false\n").is_empty());
    assert!(bench("paper.toml", "", "").is_empty());
}

/// A coarse study (3 m cells, fewer mounts) so the test runs in seconds.
/// The solver's time limit is far above what these instances take on an idle machine, so that
/// "proven optimal" does not depend on how busy the machine is (tests run side by side).
fn coarse_study(dir: &std::path::Path, configurations: &str) -> std::path::PathBuf {
    let text = format!(
        "[placement]\ncell_m = 3.0\ntime_limit_s = 900.0\n[placement.candidates]\npole_step_m = 1.5\narm_step_m = 3.0\nlidar_yaw_offsets_deg = [0.0]\nradar_yaw_offsets_deg = [-30.0, 30.0]\n{configurations}"
    );
    let p = dir.join("study.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// A JSON file the command wrote.
fn json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `hilo place STUDY --out OUT`, which must succeed.
fn place_ok(study: &std::path::Path, out: &std::path::Path) {
    let o = hilo().arg("place").arg(study).arg("--out").arg(out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn place_writes_proven_placements_coverage_maps_and_exports() {
    let dir = tempfile::tempdir().unwrap();
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"2x lidar-16 + radar\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\n[[configurations]]\nname = \"1x lidar-64 + radar\"\nsensors = { \"lidar-64\" = 1, \"radar-4d\" = 1 }\n",
    );
    let out = dir.path().join("placements");
    let ex = dir.path().join("export");
    let o =
        hilo().arg("place").arg(&study).arg("--out").arg(&out).arg("--json").arg("--export").arg(&ex).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary.as_array().unwrap().len(), 2);
    let p = json(&out.join("2x_lidar_16_radar.json"));
    assert_eq!(p["proven_optimal"], true);
    assert_eq!(p["gap"].as_f64(), Some(0.0));
    assert_eq!(p["sensors"].as_array().unwrap().len(), 3);
    assert_eq!(p["cost_usd"].as_f64(), Some(10000.0));
    assert!(p["objective"].as_f64().unwrap() >= p["greedy_objective"].as_f64().unwrap());
    let cov = p["central_coverage"].as_f64().unwrap();
    assert!(cov > 0.0 && cov <= 1.0);
    assert_labelled(&out.join("2x_lidar_16_radar.png"), Kind::Map);
    for f in [
        "targets.json",
        "candidates.json",
        "visibility_lidar-16.json",
        "visibility_radar-4d.json",
        "2x_lidar_16_radar.mps.gz",
    ] {
        assert!(ex.join(f).exists(), "{f} not exported");
    }
    let v = json(&ex.join("visibility_lidar-16.json"));
    assert_eq!(v["candidate"].as_array().unwrap().len(), v["v"].as_array().unwrap().len());
}

#[test]
fn a_lidar_only_configuration_is_placed_for_its_own_coverage() {
    let dir = tempfile::tempdir().unwrap();
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"16 alone\"\nsensors = { \"lidar-16\" = 1 }\n[[configurations]]\nname = \"16 + radar\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n",
    );
    let out = dir.path().join("p");
    place_ok(&study, &out);
    let read = |f: &str| json(&out.join(f));
    let (alone, both) = (read("16_alone.json"), read("16_radar.json"));
    assert_eq!(alone["sensors"].as_array().unwrap().len(), 1);
    // Its own objective (LiDAR coverage only), solved and proven, not a sibling's poses.
    assert!(alone["solved"].as_bool().unwrap() && alone["proven_optimal"].as_bool().unwrap(), "{alone}");
    assert!(alone["objective"].as_f64().unwrap() > 0.0);
    assert!(alone["objective"].as_f64().unwrap() + 1e-9 >= alone["greedy_objective"].as_f64().unwrap());
    assert!(alone["cost_usd"].as_f64().unwrap() < both["cost_usd"].as_f64().unwrap());
    // A study of that configuration alone places too.
    let study = coarse_study(dir.path(), "[[configurations]]\nname = \"16 alone\"\nsensors = { \"lidar-16\" = 1 }\n");
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("q")).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A radar rig placed `given` a LiDAR-only rig keeps its LiDARs at their poses and places the
/// radar, proven optimal for the rest and never above the rig placed for itself, whether the
/// given rig stands above or below it in the file; a chain, itself or no configuration is refused.
#[test]
fn a_configuration_given_another_keeps_its_sensors() {
    let dir = tempfile::tempdir().unwrap();
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"2x lidar-16\"\nsensors = { \"lidar-16\" = 2 }\n[[configurations]]\nname = \"2x lidar-16 + radar\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\ngiven = \"2x lidar-16\"\n[[configurations]]\nname = \"placed alone\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\n",
    );
    let out = dir.path().join("p");
    place_ok(&study, &out);
    let read = |f: &str| json(&out.join(f));
    let (lidars, given, alone) = (read("2x_lidar_16.json"), read("2x_lidar_16_radar.json"), read("placed_alone.json"));
    let poses = |p: &serde_json::Value, ty: &str| -> Vec<String> {
        let mut v: Vec<String> = p["sensors"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["type"] == ty)
            .map(|s| format!("{} {}", s["candidate_id"], s["position_m"]))
            .collect();
        v.sort();
        v
    };
    assert_eq!(poses(&given, "lidar-16"), poses(&lidars, "lidar-16"));
    assert_eq!(poses(&given, "radar-4d").len(), 1);
    assert!(given["proven_optimal"].as_bool().unwrap(), "{given}");
    assert!(given["method"].as_str().unwrap().contains("given"), "{given}");
    assert!(given["objective"].as_f64().unwrap() <= alone["objective"].as_f64().unwrap() + 1e-6);
    // A configuration below may be the given one: it is placed first, and the files are the same.
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"2x lidar-16 + radar\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\ngiven = \"2x lidar-16\"\n[[configurations]]\nname = \"2x lidar-16\"\nsensors = { \"lidar-16\" = 2 }\n",
    );
    let below = dir.path().join("q");
    place_ok(&study, &below);
    for f in ["2x_lidar_16.json", "2x_lidar_16_radar.json"] {
        let (a, b) = (json(&out.join(f)), json(&below.join(f)));
        assert_eq!((&a["sensors"], &a["objective"]), (&b["sensors"], &b["objective"]), "{f}");
    }
    // A chain, written top down: each keeps the whole rig below it, the second radar is placed
    // given both LiDARs and the first radar, apart from it (on a structure without a radar).
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"two radars\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 2 }\ngiven = \"2x lidar-16 + radar\"\napart = true\n[[configurations]]\nname = \"2x lidar-16 + radar\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\ngiven = \"2x lidar-16\"\n[[configurations]]\nname = \"2x lidar-16\"\nsensors = { \"lidar-16\" = 2 }\n",
    );
    let chain = dir.path().join("chain");
    place_ok(&study, &chain);
    let two = json(&chain.join("two_radars.json"));
    assert_eq!(poses(&two, "lidar-16"), poses(&lidars, "lidar-16"));
    let first = poses(&given, "radar-4d");
    let both = poses(&two, "radar-4d");
    assert!(both.len() == 2 && both.contains(&first[0]), "{both:?} keeps {first:?}");
    assert!(two["proven_optimal"].as_bool().unwrap(), "{two}");
    let radar_structures: Vec<&str> = two["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["type"] == "radar-4d")
        .map(|s| s["structure"].as_str().unwrap())
        .collect();
    assert_ne!(radar_structures[0], radar_structures[1], "{two}");
    // A cycle, itself, or no configuration: refused.
    for (confs, needle) in [
        (
            "name = \"a\"\nsensors = { \"lidar-16\" = 2 }\ngiven = \"b\"\n[[configurations]]\nname = \"b\"\nsensors = { \"lidar-16\" = 2 }\ngiven = \"a\"\n",
            "cycle of given configurations: a → b → a",
        ),
        ("name = \"a\"\nsensors = { \"lidar-16\" = 2 }\ngiven = \"a\"\n", "no other configuration"),
        ("name = \"a\"\nsensors = { \"lidar-16\" = 2 }\napart = true\n", "name one with `given`"),
        ("name = \"a\"\nsensors = { \"lidar-16\" = 2 }\ngiven = \"nowhere\"\n", "no other configuration"),
    ] {
        let study = coarse_study(dir.path(), &format!("[[configurations]]\n{confs}"));
        let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("r")).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("given") && err.contains(needle), "{needle}: {err}");
    }
}

/// With the calibrated objective and a radar worth nothing to the detectors, the budget buys
/// LiDARs only, and a rig that may hold a radar holds none, which `hilo place` says; the paper's
/// objective spends the budget on radars. Without weights it is refused.
#[test]
fn a_calibrated_objective_that_prices_radar_at_zero_buys_lidars() {
    let dir = tempfile::tempdir().unwrap();
    let budget = "[[configurations]]\nname = \"budget\"\nbudget_usd = 12000.0\ntypes = [\"lidar-16\", \"radar-4d\"]\n\
                  [[configurations]]\nname = \"rig\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\n";
    let text = |objective: &str| {
        format!(
            "[placement]\ncell_m = 3.0\ntime_limit_s = 20.0\n{objective}\n[placement.candidates]\npole_step_m = 1.5\narm_step_m = 3.0\n{budget}"
        )
    };
    let types = |name: &str, objective: &str| -> Vec<String> {
        let study = dir.path().join(format!("{name}.toml"));
        std::fs::write(&study, text(objective)).unwrap();
        let out = dir.path().join(name);
        place_ok(&study, &out);
        let p = json(&out.join("budget.json"));
        p["sensors"].as_array().unwrap().iter().map(|s| s["type"].as_str().unwrap().to_owned()).collect()
    };
    let calibrated = types("calibrated", "objective = \"calibrated\"\ncalibration = { lidar = 0.6, radar = 0.0 }");
    assert!(calibrated.iter().all(|t| t == "lidar-16") && calibrated.len() == 3, "{calibrated:?}");
    let rig = json(&dir.path().join("calibrated").join("rig.json"));
    assert!(rig["sensors"].as_array().unwrap().iter().all(|s| s["type"] == "lidar-16"), "{rig}");
    let o =
        hilo().arg("place").arg(dir.path().join("calibrated.toml")).arg("--out").arg(dir.path().join("again")).output();
    let o = o.unwrap();
    let said = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(said.contains("holds 0 of the 1 radar-4d it may"), "{said}");
    assert!(!said.contains("of the 2 lidar-16"), "{said}");
    let paper = types("paper", "");
    assert!(paper.iter().any(|t| t == "radar-4d"), "{paper:?}");
    let study = dir.path().join("bad.toml");
    std::fs::write(&study, text("objective = \"calibrated\"")).unwrap();
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("bad")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("placement.calibration"), "{err}");
}

#[test]
fn place_with_bad_configurations_explains_itself() {
    let dir = tempfile::tempdir().unwrap();
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"big\"\nsensors = { \"lidar-128\" = 1, \"radar-4d\" = 1 }\n",
    );
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("p")).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("lidar-128") && err.contains("lidar-16"), "{err}");
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"cheap\"\nbudget_usd = 500.0\ntypes = [\"lidar-16\", \"radar-4d\"]\n",
    );
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("p")).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cheap") && err.contains("500"), "{err}");
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"x\"\nsensors = { \"lidar-16\" = 1 }\nbudget_usd = 3.0\n",
    );
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("p")).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("either"));
    // More sensors than mount points, and no sensor at all: refused before any solving.
    let study = coarse_study(
        dir.path(),
        "[[configurations]]\nname = \"many\"\nsensors = { \"lidar-16\" = 1000, \"radar-4d\" = 1 }\n",
    );
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("p")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("1000 x lidar-16") && err.contains("mount points"), "{err}");
    let study = coarse_study(dir.path(), "[[configurations]]\nname = \"none\"\nsensors = { \"lidar-16\" = 0 }\n");
    let o = hilo().arg("place").arg(&study).arg("--out").arg(dir.path().join("p")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("needs a sensor"), "{err}");
}

#[test]
fn eval_writes_a_devkit_shaped_summary_and_refuses_mismatched_samples() {
    let dir = tempfile::tempdir().unwrap();
    let gt = r#"{"samples": {"a": {"scene": "s0", "ego_translation": [0, 0, 0]}, "b": {"scene": "s0", "ego_translation": [0, 0, 0]}},
      "boxes": {"a": [{"sample_token": "a", "translation": [5, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "attribute_name": "vehicle.moving", "num_pts": 20}],
                "b": [{"sample_token": "b", "translation": [0, 8, 0.9], "size": [0.6, 0.6, 1.75], "rotation": [1, 0, 0, 0], "velocity": [0, 1], "detection_name": "pedestrian", "attribute_name": "pedestrian.moving", "num_pts": 5}]}}"#;
    let res = r#"{"meta": {"use_lidar": true}, "results": {
      "a": [{"sample_token": "a", "translation": [5.2, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "detection_score": 0.9, "attribute_name": "vehicle.moving"}],
      "b": [{"sample_token": "b", "translation": [0, 8.1, 0.9], "size": [0.6, 0.6, 1.75], "rotation": [1, 0, 0, 0], "velocity": [0, 1], "detection_name": "pedestrian", "detection_score": 0.8, "attribute_name": "pedestrian.moving"}]}}"#;
    let (g, r, out) = (dir.path().join("gt.json"), dir.path().join("results.json"), dir.path().join("metrics"));
    std::fs::write(&g, gt).unwrap();
    std::fs::write(&r, res).unwrap();
    let o = hilo().arg("eval").arg("--gt").arg(&g).arg("--results").arg(&r).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = json(&out.join("metrics_summary.json"));
    for key in [
        "label_aps",
        "mean_dist_aps",
        "mean_ap",
        "label_tp_errors",
        "tp_errors",
        "tp_scores",
        "nd_score",
        "eval_time",
        "cfg",
    ] {
        assert!(m.get(key).is_some(), "missing {key}");
    }
    assert!((m["mean_dist_aps"]["car"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    assert!((m["label_aps"]["pedestrian"]["0.5"].as_f64().unwrap() - 1.0).abs() < 1e-12);
    std::fs::write(
        &r,
        res.replace("\"b\": [", "\"c\": [").replace("\"sample_token\": \"b\"", "\"sample_token\": \"c\""),
    )
    .unwrap();
    let o = hilo().arg("eval").arg("--gt").arg(&g).arg("--results").arg(&r).arg("--out").arg(&out).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("samples differ"));
}

/// A two-scene dataset written with hilo-dataset, with a split.
fn small_dataset(root: &std::path::Path) -> Vec<String> {
    small_dataset_spaced(root, [50_000, 50_000])
}

/// [`small_dataset`] with its two scenes' frames `spacing_us` apart.
fn small_dataset_spaced(root: &std::path::Path, spacing_us: [u64; 2]) -> Vec<String> {
    use hilo_dataset::{Annotation, DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup};
    let sensors = vec![SensorSetup {
        channel: "LIDAR_0".into(),
        modality: SensorModality::Lidar,
        pose: hilo_sensor_models::SensorPose::new(glam::Vec3::new(0.0, 0.0, 7.0), 0.0, 0.0, 0.0),
    }];
    let mut w = DatasetWriter::new(root, "v1.0-trainval", "cli", sensors).unwrap();
    let mut samples = Vec::new();
    for (k, name) in ["scene-a", "scene-b"].iter().enumerate() {
        let frames: Vec<FrameData> = (0..3)
            .map(|f| FrameData {
                timestamp_us: 10_000_000 * (k as u64 + 1) + spacing_us[k] * f,
                lidar: vec![
                    (0..20)
                        .map(|i| hilo_core::LidarPoint {
                            x: i as f32,
                            y: 1.0,
                            z: -6.0,
                            intensity: 0.5,
                            ring: 3,
                            time_s: 0.0,
                        })
                        .collect(),
                ],
                radar: vec![],
                annotations: vec![Annotation {
                    instance: 1,
                    class: hilo_core::Class::Car,
                    box3: hilo_core::Box3::new(glam::Vec3::new(10.0 + 0.4 * f as f32, 2.0, 0.8), 4.6, 1.9, 1.6, 0.0),
                    velocity_mps: glam::Vec2::new(8.0, 0.0),
                    attribute: "vehicle.moving".into(),
                    num_lidar_pts: 25,
                    num_radar_pts: 1,
                    visibility: 4,
                }],
            })
            .collect();
        w.add_scene(&SceneData { name: (*name).into(), description: String::new(), frames, sweeps: Vec::new() }, "x")
            .unwrap();
    }
    w.write_splits(&[("val".to_owned(), vec!["scene-b".to_owned()])].into_iter().collect()).unwrap();
    let t = w.finish().unwrap();
    let scene_b = t.scene.iter().find(|s| s.name == "scene-b").unwrap().token.clone();
    for s in t.sample.iter().filter(|s| s.scene_token == scene_b) {
        samples.push(s.token.clone());
    }
    samples
}

#[test]
fn bench_train_json_splits_the_step_into_matrix_products_and_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("data");
    small_dataset(&root);
    // Scene a trains.
    let splits = root.join("v1.0-trainval/splits.json");
    std::fs::write(&splits, r#"{"train": ["scene-a"], "val": ["scene-b"]}"#).unwrap();
    let o = hilo()
        .args(["bench", "train", "--json", "--steps", "2", "--presets", "centerpoint", "--data"])
        .arg(&root)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let r = &v["presets"][0];
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} missing in {r}"));
    // Every product the step counted was replayed: the families' FLOPs are the forward
    // products' and the two of each one's backward pass.
    let families = r["product_families"].as_array().unwrap();
    assert!(!families.is_empty());
    let replayed: f64 = families.iter().map(|x| x["gflop_per_step"].as_f64().unwrap()).sum();
    let forward = f("forward_gflop_per_step");
    assert!(forward > 0.0);
    assert!(
        (replayed - 3.0 * forward).abs() <= 1e-9 * forward.max(1.0),
        "replayed {replayed} GFLOP, forward {forward}"
    );
    let shares: f64 = families.iter().map(|x| x["share_of_time"].as_f64().unwrap()).sum();
    assert!((shares - 1.0).abs() < 1e-9, "family shares sum to {shares}");
    // The step's share of the peak is the products' share of its time times their own rate.
    assert!(f("products_gflops") > 0.0 && f("products_share_of_step") > 0.0);
    let split = f("products_share_of_step") * f("products_ratio_to_peak");
    assert!((f("ratio_to_peak") - split).abs() <= 1e-9 * split, "{} vs {split}", f("ratio_to_peak"));
}

#[test]
fn dataset_stats_and_eval_against_a_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("data");
    let samples = small_dataset(&root);
    let png = dir.path().join("frame.png");
    let o = hilo().args(["dataset", "stats"]).arg(&root).arg("--png").arg(&png).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("2 scenes, 6 frames") && text.contains("car") && text.contains("25.0"), "{text}");
    assert_labelled(&png, Kind::Map);
    // Batches of 0 are refused, and no run folder is left behind.
    let run = dir.path().join("run0");
    let o = hilo()
        .args(["train", "--detector", "centerpoint", "--batch", "0", "--data"])
        .arg(&root)
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--batch") && !run.exists(), "{err}");
    // A folder where the picture should go: refused, and no temporary file left beside it.
    let folder = dir.path().join("pics");
    std::fs::create_dir(&folder).unwrap();
    let o = hilo().args(["dataset", "stats"]).arg(&root).arg("--png").arg(&folder).output().unwrap();
    assert!(!o.status.success());
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(left.iter().all(|n| !n.to_string_lossy().contains("tmp")), "{left:?}");
    // A perfect submission for the val split.
    let results: serde_json::Map<String, serde_json::Value> = samples
        .iter()
        .enumerate()
        .map(|(f, s)| {
            let b = serde_json::json!({"sample_token": s, "translation": [10.0 + 0.4 * f as f64, 2.0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1.0, 0.0, 0.0, 0.0], "velocity": [8.0, 0.0], "detection_name": "car", "detection_score": 0.9, "attribute_name": "vehicle.moving"});
            (s.clone(), serde_json::json!([b]))
        })
        .collect();
    let res = dir.path().join("results.json");
    std::fs::write(&res, serde_json::json!({"meta": {}, "results": results}).to_string()).unwrap();
    let out = dir.path().join("metrics");
    // `hilo eval` of that submission against the dataset, with extra arguments.
    let eval = |extra: &[&str]| {
        hilo()
            .arg("eval")
            .arg("--data")
            .arg(&root)
            .arg("--results")
            .arg(&res)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap()
    };
    let o = eval(&["--bootstrap", "50"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = json(&out.join("metrics_summary.json"));
    assert!((m["mean_dist_aps"]["car"].as_f64().unwrap() - 1.0).abs() < 1e-9);
    // Two validation scenes: intervals are not estimable, and said so.
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("not estimable"), "{text}");
    // An absurd resample count is refused, not a capacity-overflow panic.
    let o = eval(&["--bootstrap", "18446744073709551615"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--bootstrap") && err.contains("100000"), "{err}");
    // Without the split: a clear error.
    let o = eval(&["--split", "train"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("no split \"train\""));
}

/// A preset changed by a JSON merge patch keeps its schedule and records the patched config; a
/// misspelled or mistyped field is refused by file and field, before any run folder exists.
/// Stacking LiDAR sweeps on a dataset whose validation scene has LiDAR only at key frames
/// farther apart than the training scene's sweeps is refused: the splits would see different
/// motion.
#[test]
fn a_detector_patch_changes_a_preset_and_sweeps_need_recorded_sweeps() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("data");
    small_dataset(&root);
    let patch = dir.path().join("patch.json");
    let train = |patch_text: &str, data: &std::path::Path, out: &str| {
        std::fs::write(&patch, patch_text).unwrap();
        hilo()
            .args(["train", "--detector", "centerpoint", "--samples", "2", "--split", "val", "--detector-patch"])
            .arg(&patch)
            .arg("--data")
            .arg(data)
            .arg("--out")
            .arg(dir.path().join(out))
            .output()
            .unwrap()
    };
    let o = train(r#"{"velocity_weight": 1.0, "grid": {"max_points_per_pillar": 20}}"#, &root, "run");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = json(&dir.path().join("run/run.json"));
    assert_eq!(run["detector"]["velocity_weight"], 1.0);
    assert_eq!(run["detector"]["grid"]["max_points_per_pillar"], 20);
    // The fields the patch leaves alone, and the preset's schedule (replicas and all).
    assert_eq!(run["detector"]["grid"]["cell_m"], 0.8);
    assert_eq!(run["detector"]["name"], "centerpoint");
    assert_eq!(run["train"]["samples"], 2);
    assert_eq!(run["train"]["replicas"], 2);
    for (text, field) in [
        (r#"{"velocty_weight": 1.0}"#, "velocty_weight"),
        (r#"{"input": {"lidar_sweeps": "ten"}}"#, "input.lidar_sweeps"),
    ] {
        let o = train(text, &root, "bad");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("patch.json") && err.contains(field), "{err}");
        assert!(!dir.path().join("bad").exists());
    }
    let o = train("[1]", &root, "bad");
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("JSON object"));
    // Key frames 0.5 s apart in the validation scene, 0.05 s in the training one.
    let spaced = dir.path().join("spaced");
    small_dataset_spaced(&spaced, [50_000, 500_000]);
    let o = train(r#"{"input": {"lidar_sweeps": 3, "max_sweep_lag_s": 1.0}}"#, &spaced, "sweeps");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("lidar_sweeps = true") && err.contains("\"val\""), "{err}");
    // The same dataset evenly recorded stacks its sweeps.
    let o = train(r#"{"input": {"lidar_sweeps": 3, "max_sweep_lag_s": 1.0}}"#, &root, "even");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
