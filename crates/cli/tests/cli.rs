//! The `hilo` binary as a user runs it.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

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
}
