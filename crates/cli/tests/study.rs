//! `hilo study` end to end on the tiny profile: every stage runs, the report has its sections
//! and every figure is written; rerunning skips finished stages; bad input is refused.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

mod pictures;

fn hilo() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hilo"))
}

#[test]
fn tiny_study_runs_every_stage_and_writes_the_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let run = || hilo().args(["study", "--profile", "tiny", "--out"]).arg(&out).output().unwrap();
    let o = run();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## The paper's claims",
        "## Configurations",
        "## What the simulation models",
        // The default study runs on field sensors, and the tiny profile casts rays of no width.
        "| radar side lobes | yes | radar-4d |",
        "| LiDAR beam width and return mode (partial hits, mixed pixels) | no | rays of no width in this profile",
        "## Accuracy",
        "## Is the difference real?",
        "## Calibration of the test",
        "## Learning curves",
        "## Figures",
        "## Speed against error",
        "2x lidar-16 + radar",
        "centerpoint",
        "pointpillars-lr",
    ] {
        assert!(md.contains(section), "report.md lacks {section:?}");
    }
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    // 2 × 16 + radar: 2 presets × 2 seeds; 64 alone: centerpoint × 2 seeds (no radar for the
    // fusion preset); scored on the common ground truth, six classes each.
    let entries = json["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 6);
    assert!(
        entries
            .iter()
            .all(|e| e["class_ap"].as_object().unwrap().len() == 6 && e["visible_only"]["mean_ap"].is_number())
    );
    assert_eq!(json["ground_truth"], "common");
    assert_eq!(json["claims"].as_array().unwrap().len(), 13);
    // The tiny profile's two rigs hold no rig of two radars: the second radar's claims say why
    // they are not tested.
    for id in ["second_radar_adds", "second_radar_velocity"] {
        let c = json["claims"].as_array().unwrap().iter().find(|c| c["id"] == id).unwrap();
        assert!(c["not_tested"].as_str().is_some_and(|m| m.contains("given")), "{c}");
    }
    // Velocity: mAVE and each class's AVE per detector, and the velocity claim tested on them
    // on the same rig; the radar's own claim needs a LiDAR-only rig cheaper than the radar rig,
    // and the tiny profile's only one is the 64-beam LiDAR.
    assert!(entries.iter().all(|e| e["mean_ave"].as_f64().is_some_and(|v| v >= 0.0)
        && e["class_ave"].as_object().unwrap().len() == 6));
    let claim = |id: &str| json["claims"].as_array().unwrap().iter().find(|c| c["id"] == id).unwrap();
    let c = claim("fusion_lowers_velocity_error");
    assert!(c["rows"].as_array().unwrap().first().is_some_and(|r| r["metric"] == "mAVE"), "{c}");
    // The nuScenes convention beside each accuracy row, as another reading of the claim.
    let c = claim("vs_lidar_alone");
    let readings = c["readings"].as_array().unwrap();
    assert!(
        readings.len() == 2
            && readings.iter().all(|r| r["reading"] == "visible-only ground truth"
                && r["metric"].as_str().is_some_and(|m| m.ends_with(", visible-only"))),
        "{c}"
    );
    assert!(md.contains("| ↳ visible-only ground truth | mAP, visible-only |"));
    let c = claim("radar_adds_velocity");
    assert!(c["not_tested"].as_str().is_some_and(|w| w.contains("costs less")), "{c}");
    assert!(md.contains("mAVE (m/s)") && md.contains("Velocity error per class"));
    // mAP per range bin: 0–30 and 30–50 m (no open bin: no class range reaches past 50 m).
    assert!(entries.iter().all(|e| e["map_by_range"].as_array().unwrap().len() == 2));
    assert_eq!(json["range_bins"][1][0], "30-50 m");
    assert!(md.contains("mAP by range"));
    // A/A: one pair of seeds in each of the three groups.
    assert_eq!(json["calibration"]["pairs"].as_u64().unwrap(), 3);
    assert!(["nominal", "conservative", "liberal"].contains(&json["calibration"]["reading"].as_str().unwrap()));
    assert!(json["learning_curves"].as_array().unwrap().iter().all(|c| c["points"].as_array().unwrap().len() == 2));
    assert!(json["provenance"]["hilo_version"].is_string() && json["provenance"]["cpu_features"].is_array());
    assert!(json["cost_reduction"].as_object().unwrap().values().all(|v| v.as_f64().unwrap() > 0.0));
    // Placement's speed against error: line-of-sight samples (the most samples is the reference)
    // and solver time limits (every bound valid, the last one proven).
    let t = &json["tradeoffs"];
    let los = t["los"].as_array().unwrap();
    assert_eq!(los.len(), 3);
    assert_eq!(los[2]["mean_abs_dv"].as_f64().unwrap(), 0.0);
    assert!(los.iter().all(|r| r["placement_loss"].as_f64().unwrap() >= -1e-9 && r["seconds"].as_f64().unwrap() > 0.0));
    let limits = t["limits"].as_array().unwrap();
    assert!(limits.iter().all(|r| r["bound"].as_f64().unwrap() >= r["objective"].as_f64().unwrap() - 1e-9));
    assert_eq!(limits.last().unwrap()["proven_optimal"], true);
    assert!(md.contains("line-of-sight samples per probe") && md.contains("time limit") && md.contains("M parameters"));
    for f in [
        "map_vs_cost.svg",
        "map_vs_cost.png",
        "pedestrian_ap.svg",
        "pedestrian_ap.png",
        "learning_curves.png",
        "class_ap_centerpoint.png",
        "coverage_2x_lidar_16_radar.png",
        "detections/2x_lidar_16_radar__centerpoint.png",
        "detections/2x_lidar_16_radar__pointpillars-lr.png",
        "detections/1x_lidar_64__centerpoint.png",
    ] {
        let p = out.join("figures").join(f);
        assert!(std::fs::metadata(&p).map(|m| m.len() > 100).unwrap_or(false), "{} missing or empty", p.display());
        if f.ends_with(".png") {
            let map = f.starts_with("coverage_") || f.starts_with("detections/");
            pictures::assert_labelled(&p, if map { pictures::Kind::Map } else { pictures::Kind::Chart });
        }
    }
    // Every figure the report links exists.
    for link in md.split("](").skip(1).filter_map(|s| s.split(')').next()) {
        assert!(out.join(link).exists(), "report links {link}, which is missing");
    }
    // A rerun finds every stage done.
    let o = run();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && !err.contains("key frames") && !err.contains("[study] placement"), "{err}");
    // Another study in the same folder is refused, and nothing is overwritten.
    let before = std::fs::read(out.join("report.json")).unwrap();
    let o = hilo().args(["study", "--profile", "quick", "--out"]).arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("holds another study"), "{err}");
    assert_eq!(before, std::fs::read(out.join("report.json")).unwrap());
    // A validation of this study in its `validation/` folder joins the report (the committed
    // quick validation of the embedded study, made when it ran on the paper's sensors, stands in
    // for `hilo validate --out study/validation`: a report matches a validation by the study's
    // name); one of another study is named and left out.
    let quick = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/validation-quick/validation.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(quick).unwrap()).unwrap();
    std::fs::create_dir_all(out.join("validation")).unwrap();
    let report = |v: &serde_json::Value| {
        std::fs::write(out.join("validation/validation.json"), serde_json::to_vec(v).unwrap()).unwrap();
        let o = hilo().args(["study", "report", "--out"]).arg(&out).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out.join("report.md")).unwrap()
    };
    let md = report(&v);
    for section in
        ["\n## Does the objective predict accuracy?", "\n### A calibrated objective", "\n### Every placement"]
    {
        assert!(md.contains(section), "report.md lacks {section:?}");
    }
    v["study"] = "elsewhere.toml".into();
    let md = report(&v);
    assert!(md.contains("holds a validation of elsewhere.toml") && !md.contains("### A calibrated objective"));
}

#[test]
fn bad_studies_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let o = hilo()
        .args(["study", "--profile", "tiny", "--presets", "centerpoint,pointrcnn", "--out"])
        .arg(dir.path().join("a"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("pointrcnn") && err.contains("lirafusion-like"), "{err}");
    let o = hilo().args(["study", "--profile", "fast", "--out"]).arg(dir.path().join("b")).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--profile"));
    // A configuration the budget cannot buy.
    let study = dir.path().join("s.toml");
    std::fs::write(
        &study,
        "[[configurations]]\nname = \"pennies\"\nbudget_usd = 10.0\ntypes = [\"lidar-16\", \"radar-4d\"]\n",
    )
    .unwrap();
    let o = hilo()
        .arg("study")
        .arg(&study)
        .args(["--profile", "tiny", "--out"])
        .arg(dir.path().join("c"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("pennies") && err.contains("buys no sensor"), "{err}");
    // A folder that is not a study.
    let d = dir.path().join("d");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("keep.txt"), "mine").unwrap();
    let o = hilo().args(["study", "--profile", "tiny", "--out"]).arg(&d).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("not a study folder"));
    assert_eq!(std::fs::read_to_string(d.join("keep.txt")).unwrap(), "mine");
}

#[test]
fn a_study_written_as_a_workflow_names_its_stages() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("wf");
    let o = hilo().args(["study", "--profile", "tiny", "--workflow", "snakemake", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let snake = std::fs::read_to_string(out.join("Snakefile")).unwrap();
    let config = std::fs::read_to_string(out.join("config.yaml")).unwrap();
    assert!(config.contains(env!("CARGO_BIN_EXE_hilo")), "{config}");
    for rule in [
        "rule all:",
        "rule report:",
        "rule place:",
        "rule simulate_1x_lidar_64:",
        "rule train_2x_lidar_16_radar_pointpillars_lr_seed1:",
    ] {
        assert!(snake.contains(rule), "Snakefile lacks {rule:?}");
    }
    // The folder lists its stages, none done; a stage that is not in the plan is refused.
    let o = hilo().args(["study", "plan", "--out"]).arg(&out).output().unwrap();
    let listing = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && listing.lines().count() == 1 + 2 + 6 + 1 && !listing.contains(" done "), "{listing}");
    let o = hilo()
        .args(["study", "train", "--job", "1x_lidar_64/pointpillars-lr-seed0", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("train stage") && err.contains("is not in this study's plan"), "{err}");
    let o = hilo().args(["study", "report", "--out"]).arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("run the place stage first"), "{err}");
    let o = hilo().args(["study", "report", "--out"]).arg(dir.path()).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("not a study folder"));
}

/// A junction of a real road network, straight from its OpenDRIVE file: imported to a scene
/// file that says what it assumed (and refuses to replace another file), summarised with those
/// assumptions, and studied end to end on the tiny profile with `scene = "….xodr"` and
/// `[junction] id = …`.
#[test]
fn a_junction_of_an_opendrive_map_is_imported_and_studied() {
    let dir = tempfile::tempdir().unwrap();
    let map =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/opendrive/multi_intersections.xodr");
    let scene = dir.path().join("junction150.toml");
    let import = || {
        hilo().args(["scene", "import"]).arg(&map).args(["--junction", "150", "--out"]).arg(&scene).output().unwrap()
    };
    let o = import();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&scene).unwrap();
    assert!(text.contains("junction 150") && text.contains("arm") && text.contains("[[signal_poles]]"), "{text}");
    assert!(import().status.success(), "a scene the import wrote is replaced by the next import");
    let foreign = dir.path().join("notes.toml");
    std::fs::write(&foreign, "name = \"mine\"\n").unwrap();
    let o =
        hilo().args(["scene", "import"]).arg(&map).args(["--junction", "150", "--out"]).arg(&foreign).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("is not a scene"));
    assert_eq!(std::fs::read_to_string(&foreign).unwrap(), "name = \"mine\"\n");
    // The written scene builds like any scene file; the map itself needs a junction.
    let o = hilo().args(["scene", "info"]).arg(&scene).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = hilo().args(["scene", "info"]).arg(&map).args(["--junction", "150"]).output().unwrap();
    let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let assumed: Vec<&str> = info["assumed"].as_array().unwrap().iter().filter_map(|v| v.as_str()).collect();
    assert!(
        assumed.iter().any(|n| n.contains("junction 150")) && assumed.iter().any(|n| n.contains("120 m")),
        "{assumed:?}"
    );
    let o = hilo().args(["scene", "info"]).arg(&map).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("name one"));
    // The study.
    let study = dir.path().join("study.toml");
    let fixture = include_str!("../../../fixtures/paper-sensors-study.toml");
    std::fs::write(&study, format!("scene = {:?}\n{fixture}\n[junction]\nid = \"150\"\n", map.display().to_string()))
        .unwrap();
    let out = dir.path().join("out");
    let o = hilo().arg("study").arg(&study).args(["--profile", "tiny", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert!(!report["entries"].as_array().unwrap().is_empty());
}
