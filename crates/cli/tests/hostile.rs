//! Inputs a hostile or careless user gives: each is refused with the file, field and value named,
//! or quoted so that it stays data; nothing outside the folder given is written.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;
use std::process::{Command, Output};

fn hilo() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hilo"))
}

/// `hilo simulate [study] --placement P --out OUT` with a small dataset (`--scenes 1 --seconds S
/// --val-scenes 0`), or with `args` in place of the size flags.
fn simulate(study: Option<&Path>, placement: &Path, out: &Path, args: &[&str]) -> Output {
    let mut c = hilo();
    c.arg("simulate");
    if let Some(s) = study {
        c.arg(s);
    }
    c.args(args).arg("--placement").arg(placement).arg("--out").arg(out).output().unwrap()
}

const SMALL: [&str; 6] = ["--scenes", "1", "--seconds", "0.5", "--val-scenes", "0"];

fn refused(o: &Output, want: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted; stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for w in want {
        assert!(err.contains(w), "{err:?} lacks {w:?}");
    }
}

#[test]
fn a_workflow_for_a_hostile_folder_name_keeps_every_string_data() {
    let dir = tempfile::tempdir().unwrap();
    // A newline ends a comment line in Python: what follows it would run on `snakemake -n`.
    let out = dir.path().join("wf \"q' $(touch X) `touch X`\nimport os; os.system('touch INJECTED')\n#");
    let o = hilo().args(["study", "--profile", "tiny", "--workflow", "snakemake", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let snake = std::fs::read_to_string(out.join("Snakefile")).unwrap();
    for line in snake.lines() {
        assert!(!line.trim_start().starts_with("import"), "a line of code from the folder name: {line:?}");
    }
    assert!(snake.contains("{config[hilo]:q}"), "the executable's path is quoted for the shell");
    // config.yaml holds the executable as a double-quoted scalar (JSON's escaping).
    let config = std::fs::read_to_string(out.join("config.yaml")).unwrap();
    let value = config.lines().find_map(|l| l.strip_prefix("hilo: ")).unwrap();
    assert_eq!(serde_json::from_str::<String>(value).unwrap(), env!("CARGO_BIN_EXE_hilo"));
}

#[test]
fn configuration_names_that_make_no_file_name_or_collide_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let study = |configs: &str| {
        let p = dir.path().join("study.toml");
        std::fs::write(&p, configs).unwrap();
        hilo().args(["place"]).arg(&p).arg("--out").arg(dir.path().join("p")).output().unwrap()
    };
    for name in ["", "..", "/"] {
        let o = study(&format!(
            "[[configurations]]\nname = \"{name}\"\nsensors = {{ \"lidar-16\" = 1, \"radar-4d\" = 1 }}\n"
        ));
        refused(&o, &["configurations[0].name", "no ASCII letter or digit"]);
    }
    let o = study(
        "[[configurations]]\nname = \"A B\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n\
         [[configurations]]\nname = \"a-b\"\nsensors = { \"lidar-32\" = 1, \"radar-4d\" = 1 }\n",
    );
    refused(&o, &["configurations[1].name = \"a-b\"", "configurations[0].name = \"A B\"", "\"a_b\""]);
    assert!(!dir.path().join("p").exists(), "nothing written for a refused study");
}

#[test]
fn a_catalog_sensor_named_like_a_path_is_refused_before_any_export() {
    let dir = tempfile::tempdir().unwrap();
    let catalog = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sensors.toml"))
        .unwrap()
        .replace("name = \"lidar-16\"", "name = \"x/../../../ESC3\"");
    std::fs::write(dir.path().join("sensors.toml"), catalog).unwrap();
    let study = dir.path().join("study.toml");
    std::fs::write(
        &study,
        "catalog = \"sensors.toml\"\n[[configurations]]\nname = \"a\"\nsensors = { \"x/../../../ESC3\" = 1, \"radar-4d\" = 1 }\n",
    )
    .unwrap();
    let export = dir.path().join("sub/export");
    let o = hilo().arg("place").arg(&study).arg("--export").arg(&export).output().unwrap();
    refused(&o, &["sensors.toml", "lidar[2].name", "ESC3", "path separator"]);
    assert!(!dir.path().join("ESC3.json").exists() && !export.exists());
}

#[test]
fn simulate_refuses_a_version_outside_the_dataroot_and_a_folder_of_foreign_files() {
    let dir = tempfile::tempdir().unwrap();
    let o = hilo()
        .args(["simulate", "--placement", "missing.json", "--version", "../../x", "--out"])
        .arg(dir.path().join("d"))
        .output()
        .unwrap();
    refused(&o, &["version", "../../x"]);
    // Another program's dataset: never overwritten.
    let foreign = dir.path().join("theirs");
    std::fs::create_dir_all(foreign.join("v1.0-trainval")).unwrap();
    std::fs::write(foreign.join("v1.0-trainval/sample.json"), "[\"theirs\"]").unwrap();
    let placements = dir.path().join("placements");
    let o = hilo().args(["place", "--out"]).arg(&placements).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cheap = placements.join("2x_lidar_16_radar.json");
    let o = simulate(None, &cheap, &foreign, &SMALL);
    refused(&o, &["theirs", "not written by `hilo simulate`"]);
    assert_eq!(std::fs::read_to_string(foreign.join("v1.0-trainval/sample.json")).unwrap(), "[\"theirs\"]");
    // Counts past what a machine can hold are refused before anything is allocated.
    let o = simulate(None, &cheap, &dir.path().join("big"), &["--scenes", "1000000000"]);
    refused(&o, &["dataset.scenes = 1000000000", "at most 10000"]);
    let o = hilo().args(["study", "--seeds", "1000000", "--out"]).arg(dir.path().join("s")).output().unwrap();
    refused(&o, &["1000000", "seed count from 1 to 100"]);
}

const GT: &str = r#"{"samples": {"a": {"scene": "s0", "ego_translation": [0, 0, 0]}, "b": {"scene": "s0", "ego_translation": [0, 0, 0]}},
  "boxes": {"a": [{"sample_token": "a", "translation": [5, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "num_pts": 20}],
            "b": [{"sample_token": "b", "translation": [0, 8, 0.9], "size": [0.6, 0.6, 1.75], "rotation": [1, 0, 0, 0], "velocity": [0, 1], "detection_name": "pedestrian", "num_pts": 5}]}}"#;

const RESULTS: &str = r#"{"meta": {}, "results": {
  "a": [{"sample_token": "a", "translation": [5.2, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "detection_score": 0.9}],
  "b": [{"sample_token": "b", "translation": [0, 8.1, 0.9], "size": [0.6, 0.6, 1.75], "rotation": [1, 0, 0, 0], "velocity": [0, 1], "detection_name": "pedestrian", "detection_score": 0.8}]}}"#;

fn eval(dir: &Path, gt: &str, results: &str, extra: &[&str]) -> Output {
    std::fs::write(dir.join("gt.json"), gt).unwrap();
    std::fs::write(dir.join("results.json"), results).unwrap();
    hilo()
        .arg("eval")
        .arg("--gt")
        .arg(dir.join("gt.json"))
        .arg("--results")
        .arg(dir.join("results.json"))
        .arg("--out")
        .arg(dir.join("metrics"))
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn eval_refuses_a_sample_listed_twice_an_empty_ground_truth_and_a_bad_compare_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The second "a" would replace the first: refused in results and in the ground truth.
    let twice = RESULTS.replace("\"b\": [", "\"a\": [").replace("\"sample_token\": \"b\"", "\"sample_token\": \"a\"");
    refused(&eval(d, GT, &twice, &[]), &["results.json", "sample \"a\" is listed twice"]);
    let gt_twice = GT.replacen("\"b\": {\"scene\"", "\"a\": {\"scene\"", 1);
    refused(&eval(d, &gt_twice, RESULTS, &[]), &["gt.json", "sample \"a\" is listed twice"]);
    // Ground truth of no samples would print mAP 0.
    let empty = r#"{"samples": {}, "boxes": {}}"#;
    refused(&eval(d, empty, r#"{"results": {}}"#, &[]), &["gt.json", "`samples` is empty"]);
    // Ground-truth boxes are checked like predictions.
    let flat = GT.replace("[1.9, 4.6, 1.6]", "[0, 4.6, 1.6]");
    refused(&eval(d, &flat, RESULTS, &[]), &["gt.json", "size"]);
    // A compare file with a sample missing is refused before any metric is written.
    std::fs::write(
        d.join("other.json"),
        RESULTS.replace("\"b\": [", "\"c\": [").replace("\"sample_token\": \"b\"", "\"sample_token\": \"c\""),
    )
    .unwrap();
    let other = d.join("other.json");
    let o = eval(d, GT, RESULTS, &["--compare", other.to_str().unwrap()]);
    refused(&o, &["other.json", "samples differ"]);
    assert!(!d.join("metrics").exists(), "nothing written before the compare file was checked");
    // A byte-order mark and a typographic quote at a syntax error: an error, never a panic.
    for bad in [
        "\u{feff}{\"results\": }",
        "{\"results\": {\u{201c}a\u{201d}: []}}",
        "{\"results\": {\"a\": [{\"sample_token\": \"a\", \u{00e9}}]}}",
    ] {
        refused(&eval(d, GT, bad, &[]), &["results.json"]);
    }
}

/// Every placement `hilo place` writes, `hilo simulate` reads: several radars (the LiDAR-first
/// exact search, or a stated bound), two LiDAR types, one modality.
#[test]
fn every_placement_shape_hilo_writes_hilo_simulates() {
    let dir = tempfile::tempdir().unwrap();
    let study = dir.path().join("study.toml");
    std::fs::write(
        &study,
        "[placement]\ncell_m = 3.0\n[placement.candidates]\npole_step_m = 1.5\narm_step_m = 3.0\n\
         lidar_yaw_offsets_deg = [0.0]\nradar_yaw_offsets_deg = [-30.0, 30.0]\n\
         [[configurations]]\nname = \"two radars\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 2 }\n\
         [[configurations]]\nname = \"two lidar types\"\nsensors = { \"lidar-16\" = 1, \"lidar-32\" = 1, \"radar-4d\" = 1 }\n\
         [[configurations]]\nname = \"lidar alone\"\nsensors = { \"lidar-16\" = 2 }\n",
    )
    .unwrap();
    let out = dir.path().join("p");
    let o = hilo().arg("place").arg(&study).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let two: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("two_radars.json")).unwrap()).unwrap();
    assert_ne!(two["method"], "greedy", "several radars go to an exact search: {two}");
    assert!(two["gap"].as_f64().is_some(), "the gap is stated: {two}");
    for name in ["two_radars", "two_lidar_types", "lidar_alone"] {
        let o =
            simulate(Some(&study), &out.join(format!("{name}.json")), &dir.path().join(format!("d-{name}")), &SMALL);
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
    }
    // A fusion detector on the LiDAR-only dataset would train its radar branch on nothing.
    let o = hilo()
        .args(["train", "--detector", "lirafusion-like", "--samples", "2", "--data"])
        .arg(dir.path().join("d-lidar_alone"))
        .arg("--out")
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    refused(&o, &["lirafusion-like fuses radar", "d-lidar_alone", "no radar channel"]);
}

#[test]
fn weak_inputs_are_refused_naming_the_field_before_the_work_starts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A pose 10,000 km away: the same refusal as `simulate`'s, not an empty cloud.
    let o = hilo()
        .args(["scan", "--sensor", "lidar-16", "--pose", "1e7,0,5", "--out"])
        .arg(d.join("x.pcd"))
        .output()
        .unwrap();
    refused(&o, &["--pose 1e7,0,5", "outside the scene"]);
    assert!(!d.join("x.pcd").exists());
    // A picture named .jpg would hold PNG bytes.
    let o = hilo().args(["scene", "show", "--out"]).arg(d.join("x.jpg")).output().unwrap();
    refused(&o, &["x.jpg", ".png"]);
    let o = hilo().args(["bench", "eval", "--frames", "0"]).output().unwrap();
    refused(&o, &["--frames", "0"]);
    // p_min is checked when the study is read, not after the visibility is computed.
    let study = d.join("study.toml");
    std::fs::write(&study, "[placement]\np_min = 1.5\n[[configurations]]\nname = \"a\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n").unwrap();
    let o = hilo().arg("place").arg(&study).arg("--out").arg(d.join("p")).output().unwrap();
    refused(&o, &["placement.p_min = 1.5", "(0, 1)"]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("computing visibility"), "refused before the visibility work");
    std::fs::write(&study, "[placement]\nnode_limit = 0\n[[configurations]]\nname = \"a\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n").unwrap();
    let o = hilo().arg("place").arg(&study).arg("--out").arg(d.join("p")).output().unwrap();
    refused(&o, &["placement.node_limit = 0", "at least 1 node"]);
    // A catalog rate no sensor has.
    let catalog =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sensors.toml")).unwrap();
    let fast = catalog.replacen("rate_hz = 20.0", "rate_hz = 1e9", 1);
    assert_ne!(fast, catalog, "the fixture's first rate");
    std::fs::write(d.join("fast.toml"), fast).unwrap();
    let o = hilo()
        .args(["scan", "--sensor", "lidar-16", "--pose", "0,0,8", "--catalog"])
        .arg(d.join("fast.toml"))
        .arg("--out")
        .arg(d.join("y.pcd"))
        .output()
        .unwrap();
    refused(&o, &["fast.toml", "rate_hz", "(0, 100] Hz"]);
}

#[test]
fn a_refused_run_leaves_nothing_that_blocks_the_corrected_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A study refused at its place stage (more LiDARs than the scene has mounts) has claimed
    // its folder; the corrected study takes the folder over.
    let bad = d.join("bad.toml");
    std::fs::write(&bad, "[[configurations]]\nname = \"16 alone\"\nsensors = { \"lidar-16\" = 5000 }\n").unwrap();
    let out = d.join("study");
    let o = hilo().arg("study").arg(&bad).args(["--profile", "tiny", "--out"]).arg(&out).output().unwrap();
    refused(&o, &["16 alone", "5000 x lidar-16"]);
    assert!(out.join("study.json").exists(), "the refused run claimed the folder");
    let good = d.join("good.toml");
    std::fs::write(
        &good,
        "[[configurations]]\nname = \"16 alone\"\nsensors = { \"lidar-16\" = 1 }\n\
         [[configurations]]\nname = \"16 + radar\"\nsensors = { \"lidar-16\" = 1, \"radar-4d\" = 1 }\n",
    )
    .unwrap();
    let o = hilo()
        .arg("study")
        .arg(&good)
        .args(["--profile", "tiny", "--workflow", "snakemake", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A dataset folder holding only the run record of a run that finished no scene.
    let placements = d.join("p");
    let o = hilo().arg("place").arg("--out").arg(&placements).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let data = d.join("data");
    std::fs::create_dir_all(data.join(".hilo")).unwrap();
    std::fs::write(
        data.join(".hilo/run.json"),
        r#"{"fingerprint": "other", "namespace": "x", "version": "v1.0-trainval", "scenes": 1}"#,
    )
    .unwrap();
    let cheap = placements.join("2x_lidar_16_radar.json");
    let o = simulate(None, &cheap, &data, &SMALL);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // One that finished a scene is still refused with other settings.
    let o = simulate(None, &cheap, &data, &["--scenes", "1", "--seconds", "1.0", "--val-scenes", "0"]);
    refused(&o, &["made with other settings"]);
}
