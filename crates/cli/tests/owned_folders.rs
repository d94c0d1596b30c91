//! Folders hilo writes stay hilo's, and inputs stay bounded: a link planted inside an output
//! folder, a second run on the same folder, a user's file where hilo would write, a FIFO or a
//! device where a file is read, and values that would size absurd allocations are each refused
//! with the path or field named, and nothing outside the target folder changes.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn hilo() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hilo"))
}

const SMALL: [&str; 6] = ["--scenes", "1", "--seconds", "0.5", "--val-scenes", "0"];

/// Runs `c` and fails the test if it has not ended within `secs` (a blocked read never ends).
fn within(mut c: Command, secs: u64) -> Output {
    let mut child = c.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            panic!("{c:?} still running after {secs} s: it blocks");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn refused(o: &Output, want: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted; stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for w in want {
        assert!(err.contains(w), "{err:?} lacks {w:?}");
    }
}

fn ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Every file under `dir` (links not followed) with its bytes, by path relative to `dir`.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let t = e.file_type().unwrap();
            let rel = e.path().strip_prefix(dir).unwrap().to_path_buf();
            if t.is_dir() {
                todo.push(e.path());
            } else if t.is_symlink() {
                out.insert(rel, std::fs::read_link(e.path()).unwrap().into_os_string().into_encoded_bytes());
            } else {
                out.insert(rel, std::fs::read(e.path()).unwrap());
            }
        }
    }
    out
}

fn place(out: &Path) -> Output {
    hilo().arg("place").arg("--out").arg(out).output().unwrap()
}

fn simulate(placement: &Path, out: &Path) -> Output {
    hilo().arg("simulate").args(SMALL).arg("--placement").arg(placement).arg("--out").arg(out).output().unwrap()
}

/// Holds an advisory lock on `dir` as another hilo run would, until dropped.
fn hold(dir: &Path) -> Held {
    std::fs::create_dir_all(dir).unwrap();
    let f = std::fs::File::open(dir).unwrap();
    f.try_lock().unwrap();
    Held(f)
}

/// A lock that is released when dropped even if a child of another test, forked meanwhile,
/// still holds a copy of the descriptor for the instant before its `exec`.
struct Held(std::fs::File);

impl Drop for Held {
    fn drop(&mut self) {
        self.0.unlock().unwrap();
    }
}

fn mkfifo(p: &Path) {
    assert!(Command::new("mkfifo").arg(p).status().unwrap().success());
}

#[test]
fn a_link_planted_in_a_dataset_or_a_validation_sends_nothing_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&place(&d.join("p")));
    let cheap = d.join("p/2x_lidar_16_radar.json");
    let data = d.join("data");
    ok(&simulate(&cheap, &data));
    // The table folder of a finished dataset becomes a link to another folder.
    let victim = d.join("victim");
    std::fs::create_dir_all(&victim).unwrap();
    std::fs::write(victim.join("sample.json"), "[\"mine\"]").unwrap();
    let before = tree(&victim);
    std::fs::rename(data.join("v1.0-trainval"), d.join("moved")).unwrap();
    std::os::unix::fs::symlink(&victim, data.join("v1.0-trainval")).unwrap();
    let o = simulate(&cheap, &data);
    refused(&o, &["v1.0-trainval", "symbolic link"]);
    assert_eq!(tree(&victim), before, "the other folder is untouched");
    // A link deeper down (a point folder) is found the same way, and in a validation folder.
    std::fs::remove_file(data.join("v1.0-trainval")).unwrap();
    std::fs::rename(d.join("moved"), data.join("v1.0-trainval")).unwrap();
    let samples = data.join("samples");
    let channel = std::fs::read_dir(&samples).unwrap().next().unwrap().unwrap().path();
    std::fs::remove_dir_all(&channel).unwrap();
    std::os::unix::fs::symlink(&victim, &channel).unwrap();
    refused(&simulate(&cheap, &data), &[&channel.display().to_string(), "symbolic link"]);
    let validation = d.join("validation");
    std::fs::create_dir_all(&validation).unwrap();
    std::os::unix::fs::symlink(&victim, validation.join("results")).unwrap();
    let o = hilo().args(["validate", "--train", "x/y-seed0", "--out"]).arg(&validation).output().unwrap();
    refused(&o, &["results", "symbolic link"]);
    let o = hilo().args(["study", "--profile", "tiny", "--workflow", "snakemake", "--out"]).arg(&validation).output();
    refused(&o.unwrap(), &["results", "symbolic link"]);
    assert_eq!(tree(&victim), before);
}

#[test]
fn a_second_writer_is_refused_at_once_and_the_first_writes_a_clean_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let me = format!("pid {}", std::process::id());
    // place: refused while the folder is held, then the same bytes as a run on a fresh folder.
    let held = hold(&d.join("p"));
    let o = place(&d.join("p"));
    refused(&o, &["another hilo run", &me, "p"]);
    assert!(tree(&d.join("p")).is_empty(), "the refused run wrote nothing");
    drop(held);
    ok(&place(&d.join("p")));
    ok(&place(&d.join("p2")));
    let strip = |t: BTreeMap<PathBuf, Vec<u8>>| -> BTreeMap<PathBuf, serde_json::Value> {
        // solve_seconds is a timing; everything else must match.
        t.into_iter()
            .filter(|(p, _)| p.extension().is_some_and(|e| e == "json"))
            .map(|(p, b)| {
                let mut v: serde_json::Value = serde_json::from_slice(&b).unwrap();
                v["solve_seconds"] = serde_json::Value::Null;
                (p, v)
            })
            .collect()
    };
    assert_eq!(strip(tree(&d.join("p"))), strip(tree(&d.join("p2"))));
    // simulate: the same, and the held run's result is byte-identical to a clean one.
    let cheap = d.join("p/2x_lidar_16_radar.json");
    let held = hold(&d.join("data"));
    refused(&simulate(&cheap, &d.join("data")), &["another hilo run", &me, "data"]);
    assert!(tree(&d.join("data")).is_empty());
    drop(held);
    ok(&simulate(&cheap, &d.join("data")));
    ok(&simulate(&cheap, &d.join("clean")));
    assert_eq!(tree(&d.join("data")), tree(&d.join("clean")));
    // study and validate, whole runs and stages alike: refused before anything is written.
    let held = hold(&d.join("study"));
    let o = hilo().args(["study", "--profile", "tiny", "--out"]).arg(d.join("study")).output().unwrap();
    refused(&o, &["another hilo run", &me]);
    let o = hilo().args(["study", "report", "--out"]).arg(d.join("study")).output().unwrap();
    refused(&o, &["another hilo run", &me]);
    assert!(tree(&d.join("study")).is_empty());
    drop(held);
    let held = hold(&d.join("validation"));
    for args in
        [&["validate", "--profile", "quick"][..], &["validate", "--train", "x/y-seed0"], &["validate", "--resume"]]
    {
        let o = hilo().args(args).arg("--out").arg(d.join("validation")).output().unwrap();
        refused(&o, &["another hilo run", &me]);
    }
    assert!(tree(&d.join("validation")).is_empty());
    drop(held);
    // A training's run folder and eval's metrics folder.
    let held = hold(&d.join("run"));
    let o = hilo()
        .args(["train", "--detector", "centerpoint", "--samples", "2", "--data"])
        .arg(d.join("data"))
        .arg("--out")
        .arg(d.join("run"))
        .output()
        .unwrap();
    refused(&o, &["another hilo run", &me]);
    assert!(tree(&d.join("run")).is_empty(), "no loss.jsonl from a refused training");
    drop(held);
}

#[test]
fn place_refuses_to_replace_a_users_file_of_the_same_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("2x_lidar_16_radar.json"), "my notes").unwrap();
    let o = place(&out);
    refused(&o, &["2x_lidar_16_radar.json", "not a placement hilo wrote"]);
    assert_eq!(std::fs::read(out.join("2x_lidar_16_radar.json")).unwrap(), b"my notes");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1, "nothing else written");
    // A picture of the user's beside no placement of hilo's.
    std::fs::remove_file(out.join("2x_lidar_16_radar.json")).unwrap();
    std::fs::write(out.join("2x_lidar_16_radar.png"), "holiday.png").unwrap();
    refused(&place(&out), &["2x_lidar_16_radar.png", "not a coverage map hilo wrote"]);
    assert_eq!(std::fs::read(out.join("2x_lidar_16_radar.png")).unwrap(), b"holiday.png");
    // hilo's own files are replaced on a rerun.
    std::fs::remove_file(out.join("2x_lidar_16_radar.png")).unwrap();
    ok(&place(&out));
    ok(&place(&out));
    // An --out that is a file is named as such.
    std::fs::write(dir.path().join("f"), "x").unwrap();
    refused(&place(&dir.path().join("f")), &["exists and is not a folder"]);
}

#[test]
fn a_fifo_or_a_device_in_place_of_an_input_is_refused_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fifo = |name: &str| {
        let p = d.join(name);
        mkfifo(&p);
        p
    };
    // A study, a scene, a placement, a results file and an eval configuration.
    let study = fifo("study.toml");
    let mut c = hilo();
    c.arg("place").arg(&study).arg("--out").arg(d.join("p"));
    refused(&within(c, 30), &["study.toml", "FIFO"]);
    let scene = fifo("scene.toml");
    let mut c = hilo();
    c.args(["scene", "info"]).arg(&scene);
    refused(&within(c, 30), &["scene.toml", "FIFO"]);
    let placement = fifo("placement.json");
    let mut c = hilo();
    c.arg("simulate").arg("--placement").arg(&placement).arg("--out").arg(d.join("data"));
    refused(&within(c, 30), &["placement.json", "FIFO"]);
    let gt = fifo("gt.json");
    let mut c = hilo();
    c.arg("eval").arg("--gt").arg(&gt).arg("--results").arg(&gt).arg("--out").arg(d.join("m"));
    refused(&within(c, 30), &["gt.json", "FIFO"]);
    // A mesh: a FIFO, and a link to /dev/zero (which once grew to 24 GB through the OBJ reader).
    let mesh = fifo("mesh.obj");
    std::os::unix::fs::symlink("/dev/zero", d.join("zero.obj")).unwrap();
    for (file, name) in [(&mesh, "FIFO"), (&d.join("zero.obj"), "a device")] {
        let text = format!("name = \"m\"\n[[meshes]]\nname = \"x\"\npath = {:?}\n", file.display().to_string());
        std::fs::write(d.join("m.toml"), text).unwrap();
        let mut c = hilo();
        c.args(["scene", "info"]).arg(d.join("m.toml"));
        refused(&within(c, 30), &[&file.display().to_string(), name]);
    }
    // A detector patch and a training schedule, on a real dataset; then a point file of it.
    ok(&place(&d.join("p")));
    let data = d.join("data");
    ok(&simulate(&d.join("p/2x_lidar_16_radar.json"), &data));
    for flag in ["--detector-patch", "--train-config"] {
        let f = fifo(&format!("{}.json", &flag[2..]));
        let mut c = hilo();
        c.args(["train", "--detector", "centerpoint", "--samples", "2", "--data"]).arg(&data).arg(flag).arg(&f);
        c.arg("--out").arg(d.join("run"));
        refused(&within(c, 60), &[&f.display().to_string(), "FIFO"]);
    }
    let points = first_file(&data.join("samples"));
    std::fs::remove_file(&points).unwrap();
    mkfifo(&points);
    let mut c = hilo();
    c.args(["train", "--detector", "centerpoint", "--samples", "2", "--data"]).arg(&data);
    c.arg("--out").arg(d.join("run"));
    refused(&within(c, 60), &[&points.file_name().unwrap().to_string_lossy(), "FIFO"]);
}

/// The first file under `dir` in name order, descending into the first folder.
fn first_file(dir: &Path) -> PathBuf {
    let mut entries: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    entries.sort();
    let first = entries.into_iter().next().unwrap_or_else(|| panic!("nothing under {}", dir.display()));
    if first.is_dir() { first_file(&first) } else { first }
}

#[test]
fn values_that_size_allocations_are_refused_by_field_before_any_stage_runs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let study = |extra: &str| {
        let p = d.join("study.toml");
        std::fs::write(
            &p,
            format!("[[configurations]]\nname = \"a\"\nsensors = {{ \"lidar-16\" = 1, \"radar-4d\" = 1 }}\n{extra}"),
        )
        .unwrap();
        p
    };
    let run_study =
        |p: &Path| hilo().arg("study").arg(p).args(["--profile", "tiny", "--out"]).arg(d.join("s")).output().unwrap();
    for (patch, needle) in [
        ("grid = { max_points_per_pillar = 1000000000000 }", "max_points_per_pillar = 1000000000000"),
        ("grid = { half_extent_m = 1e9 }", "half_extent_m = 1000000000"),
        ("grid = { cell_m = 1e-6 }", "cell_m = 0.000001"),
        ("backbone = { neck_channels = 1000000000 }", "backbone.neck_channels = 1000000000"),
        ("velocity_weight = nan", "detector_patch.velocity_weight = NaN"),
    ] {
        let o = run_study(&study(&format!("[detector_patch]\n{patch}\n")));
        refused(&o, &[needle]);
        assert!(!d.join("s/data").exists(), "{patch}: refused before any dataset was simulated");
    }
    for (schedule, needle) in [
        ("batch = 1000000000", "batch = 1000000000"),
        ("lr_max = -0.01", "lr_max = -0.01"),
        ("lr_max = 1e30", "lr_max = 1000000000000000000000000000000"),
        ("warmup = -5.0", "warmup = -5"),
        ("lr_max = inf", "train_schedule.lr_max = inf"),
    ] {
        let o = run_study(&study(&format!("[train_schedule]\n{schedule}\n")));
        refused(&o, &[needle]);
    }
    // A count that would wrap when doubled.
    let o = hilo()
        .args(["validate", "--profile", "quick", "--samples", "18446744073709551615", "--out"])
        .arg(d.join("v"))
        .output()
        .unwrap();
    refused(&o, &["validation.samples = 18446744073709551615"]);
    // [validation] is read by `hilo validate`, and checked by `hilo study` too, before any stage.
    study("[validation]\nfusion_preset = \"centerpoint\"\n");
    let o = hilo().arg("validate").arg(d.join("study.toml")).arg("--out").arg(d.join("v2")).output().unwrap();
    refused(&o, &["fusion_preset = \"centerpoint\"", "reads no radar"]);
    for (section, needle) in [
        ("fusion_preset = \"centerpoint\"", "reads no radar"),
        ("placements = 3", "validation.placements = 3"),
        ("lidar_tilts_deg = []", "validation.lidar_tilts_deg = []: 0 tilts"),
        ("radar_tilts_deg = [400.0]", "validation.radar_tilts_deg = [400.0]: holds 400"),
        ("lidar_preset = \"lirafusion-like\"", "needs a radar"),
    ] {
        let o = run_study(&study(&format!("[validation]\n{section}\n")));
        refused(&o, &[needle]);
        assert!(!d.join("s/placements").exists(), "{section}: refused before placement");
    }
    // Weights CBC cannot take, and range bins by the hundred thousand.
    let o = hilo()
        .arg("place")
        .arg(study("[placement]\nobjective = \"calibrated\"\ncalibration = { lidar = 1e308, radar = 1.0 }\n"))
        .arg("--out")
        .arg(d.join("p"))
        .output()
        .unwrap();
    refused(&o, &["placement.calibration.lidar", "[0, 1e6]"]);
    let edges: Vec<String> = (0..100_000).map(|i| format!("{}.0", i)).collect();
    let o = run_study(&study(&format!("[evaluation]\nrange_bins_m = [{}]\n", edges.join(", "))));
    refused(&o, &["range_bins_m = (100000 edges)", "at most 65"]);
}

#[test]
fn eval_configs_without_a_meaning_and_huge_polygons_are_refused_by_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gt = r#"{"samples": {"a": {"scene": "s0", "ego_translation": [0, 0, 0]}},
      "boxes": {"a": [{"sample_token": "a", "translation": [5, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "num_pts": 20}]}}"#;
    std::fs::write(d.join("gt.json"), gt).unwrap();
    std::fs::write(d.join("r.json"), r#"{"results": {"a": []}}"#).unwrap();
    let mut cfg = serde_json::json!({
        "class_range": {"car": 50.0}, "dist_fcn": "center_distance", "dist_ths": [0.5, 1.0, 2.0, 4.0],
        "dist_th_tp": 2.0, "min_recall": 0.1, "min_precision": 0.1, "max_boxes_per_sample": 500, "mean_ap_weight": 5.0
    });
    for (field, value, needle) in [
        ("dist_ths", serde_json::json!([]), "dist_ths = []"),
        ("min_recall", serde_json::json!(1.0), "min_recall = 1"),
        ("class_range", serde_json::json!({"car": -5.0}), "class_range.car = -5"),
    ] {
        let good = cfg[field].clone();
        cfg[field] = value;
        std::fs::write(d.join("cfg.json"), cfg.to_string()).unwrap();
        cfg[field] = good;
        let o = hilo()
            .arg("eval")
            .arg("--gt")
            .arg(d.join("gt.json"))
            .arg("--results")
            .arg(d.join("r.json"))
            .arg("--config")
            .arg(d.join("cfg.json"))
            .arg("--out")
            .arg(d.join("m"))
            .output()
            .unwrap();
        refused(&o, &["cfg.json", needle]);
    }
    // 100,000 corners: refused by count, at once, not after minutes of pairwise checks.
    let ring: Vec<String> = (0..100_000)
        .map(|i| {
            let a = i as f64 / 100_000.0 * std::f64::consts::TAU;
            format!("[{:.4}, {:.4}]", 60.0 + 5.0 * a.cos(), 60.0 + 5.0 * a.sin())
        })
        .collect();
    std::fs::write(
        d.join("big.toml"),
        format!("name = \"b\"\n[[buildings]]\nfootprint = [{}]\nheight_m = 10.0\n", ring.join(", ")),
    )
    .unwrap();
    let mut c = hilo();
    c.args(["scene", "info"]).arg(d.join("big.toml"));
    refused(&within(c, 30), &["big.toml", "buildings[0].footprint", "at most 4096 points"]);
}
