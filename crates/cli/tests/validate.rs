//! `hilo validate` end to end on a coarse scene at the tiny profile: the set is trained and
//! scored, the calibrated objective is fitted and its budgeted recommendation trained; a rerun
//! resumes to the same numbers; `--refit`, `--recommend` and `--absorb` work from the folder.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::Command;

/// The default scene on a coarse grid with few candidates, a validation of twelve placements.
const COARSE: &str = include_str!("../../../fixtures/validation-coarse.toml");

fn hilo() -> Command {
    Command::new(env!("CARGO_BIN_EXE_hilo"))
}

fn json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn a_tiny_validation_trains_the_set_and_the_calibrated_recommendation() {
    let dir = tempfile::tempdir().unwrap();
    let study = dir.path().join("coarse.toml");
    // Two rigs near the budget, for the recommendation's regret.
    std::fs::write(&study, COARSE.replace("placements = 12\n", "placements = 12\nnear_budget = 2\n")).unwrap();
    let out = dir.path().join("validation");
    let run = |extra: &[&str]| {
        let o = hilo()
            .arg("validate")
            .arg(&study)
            .args(["--profile", "tiny", "--seeds", "1", "--samples", "4", "--out"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    run(&[]);
    let r = json(&out.join("validation.json"));
    let members = r["members"].as_array().unwrap();
    assert!(members.len() >= 12, "{}", members.len());
    for m in members {
        let map = m[1]["map_mean"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&map), "{m}");
    }
    assert!(r["seed_spearman"].is_null(), "one seed: no seed-against-seed agreement");
    let c = &r["calibrated"];
    assert_eq!(c["held_out"].as_array().unwrap().len(), members.len(), "every placement predicted out of fold");
    assert!(c["weights"].as_array().unwrap().iter().all(|w| w.as_f64().unwrap() >= 0.0), "{c}");
    let md = std::fs::read_to_string(out.join("validation.md")).unwrap();
    for section in ["# Does the objective predict accuracy?", "## A calibrated objective", "## Every placement"] {
        assert!(md.contains(section), "validation.md lacks {section:?}");
    }
    // A rerun trains nothing again: the same numbers.
    run(&[]);
    let again = json(&out.join("validation.json"));
    assert_eq!(again["members"], r["members"]);
    assert_eq!(again["calibrated"], r["calibrated"]);
    // Four training samples teach nothing a coverage term predicts; plant accuracy that rises
    // with saturated LiDAR coverage (the seeds and scene replicates agreeing), so that the fit
    // weights it and the recommendation is placed, simulated, trained and scored.
    let mut planted = r.clone();
    for m in planted["members"].as_array_mut().unwrap() {
        let c = m[0]["predictors"]["LiDAR coverage (saturated)"].as_f64().unwrap();
        let map = 0.1 + 0.5 * c;
        let t = &mut m[1];
        t["map_mean"] = map.into();
        t["map"] = serde_json::json!([map]);
        let n = t["map_replicates"].as_array().unwrap().len();
        t["map_replicates"] = serde_json::json!(vec![map; n]);
    }
    std::fs::write(out.join("validation.json"), serde_json::to_vec(&planted).unwrap()).unwrap();
    run(&["--recommend"]);
    let r = json(&out.join("validation.json"));
    let c = &r["calibrated"];
    assert!((c["weights"][0].as_f64().unwrap() - 0.5).abs() < 1e-6, "{c}");
    let rec = &r["recommendation"];
    assert!(rec["member"]["kind"].as_str().unwrap().starts_with("calibrated"), "{rec}");
    assert!(rec["member"]["placement"]["cost_usd"].as_f64().unwrap() <= rec["budget_usd"].as_f64().unwrap() + 1e-6);
    let (p, lo, hi) = (rec["predicted"].as_f64().unwrap(), rec["lo"].as_f64().unwrap(), rec["hi"].as_f64().unwrap());
    assert!(lo <= p && p <= hi, "{rec}");
    // The planted relation is exact: the prediction is 0.1 + 0.5 × the rig's coverage.
    let cov = rec["member"]["predictors"]["LiDAR coverage (saturated)"].as_f64().unwrap();
    assert!((p - (0.1 + 0.5 * cov)).abs() < 1e-6, "{p} vs {cov}");
    let measured = rec["trained"]["map_mean"].as_f64().unwrap();
    assert_eq!(rec["inside"].as_bool().unwrap(), (lo..=hi).contains(&measured));
    assert_eq!(rec["trained"]["map"].as_array().unwrap().len(), 1, "trained as the members were: one seed");
    let rival = &rec["rival"];
    assert!((rival["difference"].as_f64().unwrap() - (measured - rival["map_mean"].as_f64().unwrap())).abs() < 1e-12);
    assert!(rival["cost_usd"].as_f64().unwrap() <= rec["budget_usd"].as_f64().unwrap() + 1e-6);
    // Its regret among the rigs within ±10% of the budget, the two drawn there among them.
    let budget = rec["budget_usd"].as_f64().unwrap();
    let near: Vec<&serde_json::Value> = r["members"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| (m[0]["placement"]["cost_usd"].as_f64().unwrap() - budget).abs() <= 0.1 * budget + 1e-6)
        .collect();
    let kinds: Vec<&str> = near.iter().map(|m| m[0]["kind"].as_str().unwrap()).collect();
    assert!(kinds.contains(&"near-budget-greedy") && kinds.contains(&"near-budget-random"), "{kinds:?}");
    let g = &rec["regret"];
    assert_eq!(g["rigs"].as_array().unwrap().len(), near.len(), "{g}");
    let best = near.iter().map(|m| m[1]["map_mean"].as_f64().unwrap()).fold(f64::NEG_INFINITY, f64::max);
    assert!((g["regret"].as_f64().unwrap() - (best - measured).max(0.0)).abs() < 1e-12, "{g}");
    let md = std::fs::read_to_string(out.join("validation.md")).unwrap();
    assert!(md.contains("## The calibrated recommendation, trained"), "{md}");
    // --refit with the same fit keeps the recommendation; --recommend again resumes it.
    run(&["--refit"]);
    assert_eq!(json(&out.join("validation.json"))["recommendation"], r["recommendation"]);
    run(&["--recommend"]);
    assert_eq!(json(&out.join("validation.json"))["recommendation"], r["recommendation"]);
    // --absorb: the trained recommendation joins the set as its last member, fitted and
    // predicted out of fold like the others, and no recommendation is left to absorb.
    let n = members.len();
    run(&["--absorb"]);
    let a = json(&out.join("validation.json"));
    let grown = a["members"].as_array().unwrap();
    assert_eq!(grown.len(), n + 1);
    assert_eq!(grown[n][0]["slug"], rec["member"]["slug"]);
    assert_eq!(grown[n][1], rec["trained"]);
    assert!(a["recommendation"].is_null(), "{}", a["recommendation"]);
    assert_eq!(a["calibrated"]["held_out"].as_array().unwrap().len(), n + 1);
    let md = std::fs::read_to_string(out.join("validation.md")).unwrap();
    assert!(md.contains(&format!("Over the {n} drawn placements alone")), "{md}");
    let o = hilo().arg("validate").arg(&study).arg("--out").arg(&out).arg("--absorb").output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no trained recommendation"), "{o:?}");
    // A rerun of the validation scores the set again and keeps the absorbed rig.
    run(&[]);
    let again = json(&out.join("validation.json"));
    let kept = again["members"].as_array().unwrap();
    assert_eq!(kept.len(), n + 1);
    assert_eq!((&kept[n][0]["slug"], &kept[n][1]), (&grown[n][0]["slug"], &grown[n][1]));
    refuses_what_would_fit_the_wrong_thing(&study, &out);
    leaves_each_site_out(dir.path(), &out.join("validation.json"));
    places_with_the_sites_calibration(dir.path(), &study);
    recommends_with_a_frozen_calibration(dir.path(), &study, &out);
}

/// The buying decision with a calibration fitted elsewhere: `--recommend --calibration FILE
/// [--budget USD]` places the rig the file's frozen weights buy at this junction, trains it as the
/// set's members were, and keeps it beside the others (one per file and budget, in order of
/// budget), with the file's prediction and the regret among the set's rigs near its budget; a
/// rerun resumes to the same result, --refit keeps them, and a bad budget or file is refused by
/// name with nothing changed.
fn recommends_with_a_frozen_calibration(dir: &std::path::Path, study: &std::path::Path, out: &std::path::Path) {
    let file = dir.join("loso").join("calibration.toml");
    let frozen = |extra: &[&str]| {
        let o = hilo()
            .arg("validate")
            .arg(study)
            .args(["--profile", "tiny", "--seeds", "1", "--samples", "4", "--out"])
            .arg(out)
            .args(["--recommend", "--calibration"])
            .arg(&file)
            .args(extra)
            .output()
            .unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let (ok, err) = frozen(&[]);
    assert!(ok, "{err}");
    let budget = json(&out.join("validation.json"))["frozen"][0]["budget_usd"].as_f64().unwrap();
    let low = format!("{:.0}", 0.6 * budget);
    let (ok, err) = frozen(&["--budget", low.as_str()]);
    assert!(ok, "{err}");
    let r = json(&out.join("validation.json"));
    let recs = r["frozen"].as_array().unwrap();
    assert_eq!(recs.len(), 2, "{recs:?}");
    assert!(recs[0]["budget_usd"].as_f64().unwrap() < recs[1]["budget_usd"].as_f64().unwrap());
    assert!((recs[0]["budget_usd"].as_f64().unwrap() - low.parse::<f64>().unwrap()).abs() < 1e-9);
    for rec in recs {
        assert!(rec["member"]["kind"].as_str().unwrap().starts_with("frozen"), "{rec}");
        assert!(rec["member"]["placement"]["cost_usd"].as_f64().unwrap() <= rec["budget_usd"].as_f64().unwrap() + 1e-6);
        assert_eq!(rec["frozen"]["file"].as_str().unwrap(), file.display().to_string());
        assert_eq!(rec["frozen"]["fitted_on"].as_array().unwrap().len(), 3);
        let (p, lo, hi) =
            (rec["predicted"].as_f64().unwrap(), rec["lo"].as_f64().unwrap(), rec["hi"].as_f64().unwrap());
        assert!(lo < p && p < hi, "{rec}");
        assert_eq!(rec["trained"]["map"].as_array().unwrap().len(), 1, "trained as the members were: one seed");
        let png = format!("recommendation/{}.png", rec["member"]["slug"].as_str().unwrap());
        assert!(std::fs::read(out.join(&png)).unwrap().starts_with(b"\x89PNG"), "{png}");
    }
    let md = std::fs::read_to_string(out.join("validation.md")).unwrap();
    assert_eq!(md.matches("## A calibration fitted elsewhere, frozen").count(), 2, "{md}");
    // Every recommendation drawn: the two frozen ones, and the set's own (trained again by the rerun above).
    let own = usize::from(!r["recommendation"].is_null());
    assert_eq!(md.matches("![Its mounts on the site](recommendation/").count(), 2 + own, "{md}");
    // A rerun at the same budget resumes to the same rig and numbers, in place of the old one.
    let (ok, err) = frozen(&["--budget", low.as_str()]);
    assert!(ok, "{err}");
    let again = json(&out.join("validation.json"));
    assert_eq!(again["frozen"], r["frozen"]);
    let o = hilo().arg("validate").arg(study).arg("--out").arg(out).arg("--refit").output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(json(&out.join("validation.json"))["frozen"].as_array().unwrap().len(), 2);
    let before = std::fs::read(out.join("validation.json")).unwrap();
    let (ok, err) = frozen(&["--budget", "0"]);
    assert!(!ok && err.contains("--budget 0") && err.contains("positive"), "{err}");
    let bad = dir.join("bad-calibration.toml");
    std::fs::write(&bad, "fitted_on = 3\n").unwrap();
    let o = hilo()
        .arg("validate")
        .arg(study)
        .arg("--out")
        .arg(out)
        .arg("--recommend")
        .arg("--calibration")
        .arg(&bad)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("bad-calibration.toml") && err.contains("fitted_on"), "{err}");
    let o = hilo().arg("validate").arg(study).arg("--out").arg(out).args(["--budget", "9000"]).output().unwrap();
    assert!(!o.status.success(), "--budget without --calibration is refused");
    assert_eq!(std::fs::read(out.join("validation.json")).unwrap(), before, "validation.json unchanged");
}

/// The user's path at a junction no validation has seen: a study file naming the calibration
/// `--sites` wrote places with it, and each placement carries its predicted mAP, interval and
/// advice; beside `[placement] calibration` the file is refused.
fn places_with_the_sites_calibration(dir: &std::path::Path, study: &std::path::Path) {
    let file = dir.join("loso").join("calibration.toml");
    let table: toml::Table = toml::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert!(table.contains_key("choice") && table.contains_key("prediction") && table.contains_key("weights"));
    let text = std::fs::read_to_string(study).unwrap();
    let calibrated = dir.join("calibrated.toml");
    std::fs::write(&calibrated, format!("calibration_file = {:?}\n{text}", file.display().to_string())).unwrap();
    let placed = dir.join("placed");
    let o = hilo().arg("place").arg(&calibrated).arg("--out").arg(&placed).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let said = String::from_utf8_lossy(&o.stderr).to_string() + &String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("predicted mAP") && said.contains("no LiDAR point on (sampled training traffic)"), "{said}");
    let mut n = 0;
    for e in std::fs::read_dir(&placed).unwrap() {
        let path = e.unwrap().path();
        if path.extension().is_some_and(|x| x == "json") {
            let p = json(&path)["prediction"].clone();
            let (map, lo, hi) = (p["map"].as_f64().unwrap(), p["lo"].as_f64().unwrap(), p["hi"].as_f64().unwrap());
            assert!(lo < map && map < hi && !p["advice"].as_str().unwrap().is_empty(), "{p}");
            // Per class, the share of the sampled road users its LiDARs never hit.
            let never = p["never_hit"].as_object().unwrap();
            assert!(
                never.contains_key("car") && never.values().all(|v| (0.0..=1.0).contains(&v.as_f64().unwrap())),
                "{p}"
            );
            n += 1;
        }
    }
    assert!(n > 0);
    places_above_a_hit_floor(dir, &placed, &calibrated);
    let both = dir.join("both.toml");
    let text = text.replacen("[placement]\n", "[placement]\ncalibration = { lidar = 1.0, radar = 0.0 }\n", 1);
    std::fs::write(&both, format!("calibration_file = {:?}\n{text}", file.display().to_string())).unwrap();
    let o = hilo().arg("place").arg(&both).arg("--out").arg(dir.join("placed2")).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("give one of the two"), "{o:?}");
}

/// `[placement] min_hit_share`: a floor on the share of cars the LiDARs hit, set at the share the
/// worst LiDAR rig of `placed` (the same study without it) reaches, then just above it, where it
/// binds. Each rig meets it as its own prediction counts (or, where it binds, `hilo place` says
/// which configuration cannot, naming the class); a class the traffic does not hold is refused
/// by name.
fn places_above_a_hit_floor(dir: &std::path::Path, placed: &std::path::Path, calibrated: &std::path::Path) {
    let hit = |p: &serde_json::Value| 1.0 - p["prediction"]["never_hit"]["car"].as_f64().unwrap();
    let lidar_rigs = |folder: &std::path::Path| -> Vec<serde_json::Value> {
        let mut rigs: Vec<serde_json::Value> = std::fs::read_dir(folder)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "json"))
            .map(|p| json(&p))
            .filter(|p| p["sensors"].as_array().is_some_and(|s| s.iter().any(|s| s["modality"] == "lidar")))
            .collect();
        rigs.sort_by(|a, b| a["name"].as_str().cmp(&b["name"].as_str()));
        rigs
    };
    let before = lidar_rigs(placed);
    let worst = before.iter().map(hit).fold(1.0, f64::min);
    assert!(worst < 1.0, "every rig hits every car: the floor cannot bind");
    let text = std::fs::read_to_string(calibrated).unwrap();
    let floored = dir.join("floored.toml");
    let with = |class: &str, share: f64| {
        text.replacen("[placement]\n", &format!("[placement]\nmin_hit_share = {{ {class} = {share} }}\n"), 1)
    };
    // At the worst rig's share every rig already meets it: the same objectives. Just above it
    // binds: that rig moves, or its configuration is refused by name.
    for (k, floor) in
        [(worst * 1000.0).floor() / 1000.0, ((worst * 1000.0).floor() + 1.0) / 1000.0].into_iter().enumerate()
    {
        std::fs::write(&floored, with("car", floor)).unwrap();
        let out = dir.join(format!("placed-floor-{k}"));
        let o = hilo().arg("place").arg(&floored).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        if !o.status.success() {
            assert!(k == 1 && err.contains("placing configuration") && err.contains("hit floors (car ≥"), "{err}");
            continue;
        }
        let after = lidar_rigs(&out);
        assert_eq!(after.len(), before.len());
        for (p, b) in after.iter().zip(&before) {
            assert!(hit(p) >= floor - 1e-9, "{} hits {} of the cars, below {floor}", p["name"], hit(p));
            let said = format!("hit floors car ≥ {:.1}%", 100.0 * floor);
            assert!(p["method"].as_str().unwrap().contains(&said), "{}", p["method"]);
            let (now, then) = (p["objective"].as_f64().unwrap(), b["objective"].as_f64().unwrap());
            assert!(
                if k == 0 { (now - then).abs() < 1e-9 } else { now <= then + 1e-9 },
                "{}: {now} vs {then}",
                p["name"]
            );
        }
        assert!(
            k == 0 || after.iter().zip(&before).any(|(a, b)| a["sensors"] != b["sensors"]),
            "the floor moved no rig"
        );
    }
    std::fs::write(&floored, with("bicycle", 0.9)).unwrap();
    let o = hilo().arg("place").arg(&floored).arg("--out").arg(dir.join("placed-bicycle")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("placement.min_hit_share.bicycle = 0.9") && err.contains("no bicycle"),
        "{err}"
    );
}

/// `--sites` over three finished validations (here one validation as three sites, which the
/// command cannot tell apart): each held out and ranked by the fit on the others, beside the
/// count baselines; fewer than three sites are refused.
fn leaves_each_site_out(dir: &std::path::Path, finished: &std::path::Path) {
    let sites: Vec<std::path::PathBuf> = ["a", "b", "c"].iter().map(|s| dir.join(format!("{s}.json"))).collect();
    for s in &sites {
        std::fs::copy(finished, s).unwrap();
    }
    let loso = dir.join("loso");
    let o = hilo().args(["validate", "--out"]).arg(&loso).arg("--sites").args(&sites).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json(&loso.join("sites.json"));
    let held = r["held_out"].as_array().unwrap();
    assert_eq!(held.len(), 3);
    let n = json(finished)["members"].as_array().unwrap().len();
    for h in held {
        assert_eq!(h["predicted"].as_array().unwrap().len(), n);
        assert_eq!(h["fitted_on"].as_array().unwrap().len(), 2);
        assert!(h["baselines"].as_array().unwrap().iter().any(|b| b["predictor"] == "LiDARs"), "{h}");
    }
    assert!(std::fs::read_to_string(loso.join("sites.md")).unwrap().contains("best baseline"));
    let o =
        hilo().args(["validate", "--out"]).arg(dir.join("loso2")).arg("--sites").args(&sites[..2]).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("at least 3"), "{o:?}");
    // A study or a stage beside --sites would be ignored: refused instead.
    let o = hilo().args(["validate", "study.toml", "--sites"]).args(&sites).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("cannot be used with"), "{o:?}");
}

/// On a finished validation: a transfer from the folder's own file (or a copy) would be scored
/// in-sample, a refit with another study's traffic would fit predictors the trainings never
/// saw, and an accuracy edited past 1 would be fitted as if trained. Each is refused with the
/// file and field named, and nothing in the folder changes.
fn refuses_what_would_fit_the_wrong_thing(study: &std::path::Path, out: &std::path::Path) {
    let before = std::fs::read(out.join("validation.json")).unwrap();
    let refused = |extra: &[&std::ffi::OsStr], study: &std::path::Path, want: &[&str]| {
        let o = hilo().arg("validate").arg(study).arg("--out").arg(out).args(extra).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "accepted: {err}");
        for w in want {
            assert!(err.contains(w), "{err:?} lacks {w:?}");
        }
        assert_eq!(std::fs::read(out.join("validation.json")).unwrap(), before, "validation.json unchanged");
    };
    let own = out.join("validation.json");
    let copy = out.parent().unwrap().join("copy.json");
    std::fs::copy(&own, &copy).unwrap();
    for source in [&own, &copy] {
        refused(&["--transfer".as_ref(), source.as_os_str()], study, &["same placements and trainings"]);
    }
    let other = out.parent().unwrap().join("other-traffic.toml");
    std::fs::write(&other, format!("{COARSE}\n[dataset]\nseed = 99\n")).unwrap();
    refused(&["--refit".as_ref()], &other, &["other-traffic.toml", "is not the one validated there"]);
    // Training sections join the study only where they change what the validation trains: the
    // presets' own velocity head and augmentation written out open the folder, the footprint
    // head does not.
    let trains = |name: &str, target: &str, weight: f64, keep: f64| {
        let path = out.parent().unwrap().join(name);
        let extra = format!(
            "\n[detector_patch]\nvelocity_target = \"{target}\"\nvelocity_weight = {weight:?}\n\
             [train_schedule.augmentation]\nkeep_site_p = {keep:?}\n"
        );
        std::fs::write(&path, std::fs::read_to_string(study).unwrap() + &extra).unwrap();
        path
    };
    let footprint = trains("footprint.toml", "footprint", 1.0, 0.75);
    refused(&["--refit".as_ref()], &footprint, &["footprint.toml", "is not the one validated there"]);
    let mut edited = json(&own);
    edited["members"][3][1]["map_mean"] = 7.5.into();
    std::fs::write(&copy, serde_json::to_vec(&edited).unwrap()).unwrap();
    refused(&["--transfer".as_ref(), copy.as_os_str()], study, &["copy.json", "map_mean = 7.5", "[0, 1]"]);
    let own_settings = trains("own-settings.toml", "positives", 0.2, 0.0);
    let o = hilo().arg("validate").arg(&own_settings).arg("--out").arg(out).arg("--refit").output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Drops what measures time (`seconds`, `*_s`, `*_seconds`): it differs between any two runs.
fn untimed(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| !(k == "seconds" || k.ends_with("_s") || k.ends_with("_seconds")));
            m.values_mut().for_each(untimed);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(untimed),
        _ => {}
    }
}

/// A dataset's box annotations (sample time, translation), of its training and of its
/// validation scenes.
fn annotations_by_split(data: &std::path::Path) -> (Vec<String>, Vec<String>) {
    let table = |name: &str| json(&data.join("v1.0-trainval").join(name));
    let val: Vec<serde_json::Value> = table("splits.json")["val"].as_array().unwrap().clone();
    let scene_val: std::collections::BTreeMap<String, bool> = table("scene.json")
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["token"].as_str().unwrap().to_owned(), val.contains(&s["name"])))
        .collect();
    let sample: std::collections::BTreeMap<String, (bool, u64)> = table("sample.json")
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            let on_val = scene_val[s["scene_token"].as_str().unwrap()];
            (s["token"].as_str().unwrap().to_owned(), (on_val, s["timestamp"].as_u64().unwrap()))
        })
        .collect();
    let (mut train, mut valid) = (Vec::new(), Vec::new());
    for a in table("sample_annotation.json").as_array().unwrap() {
        let (on_val, t) = sample[a["sample_token"].as_str().unwrap()];
        let row = format!("{t} {}", a["translation"]);
        if on_val { valid.push(row) } else { train.push(row) }
    }
    train.sort();
    valid.sort();
    (train, valid)
}

/// The validation written as a Snakefile names a job per placement's datasets and per training,
/// each a `hilo validate` stage of the folder; run one by one, as the engine runs them, then the
/// last step, they give the validation of one process apart from timing fields. Two
/// training-traffic draws: each placement is recorded on both (the validation scenes shared)
/// and trained on each, and the report sets draw 0 against draw 1.
#[test]
fn a_validation_run_stage_by_stage_as_its_snakefile_says_equals_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let study = dir.path().join("coarse.toml");
    std::fs::write(&study, COARSE).unwrap();
    let validate = |out: &std::path::Path, extra: &[&str]| {
        let o = hilo()
            .arg("validate")
            .arg(&study)
            .args(["--profile", "tiny", "--seeds", "1", "--traffic-draws", "2", "--samples", "4", "--out"])
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{extra:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    let (one, wf) = (dir.path().join("one"), dir.path().join("wf"));
    validate(&one, &[]);
    validate(&wf, &["--workflow", "snakemake"]);
    assert!(!wf.join("validation.json").exists(), "the workflow is written, not run");
    let snake = std::fs::read_to_string(wf.join("Snakefile")).unwrap();
    assert!(wf.join("config.yaml").exists());
    let stage = |flag: &str| -> Vec<String> {
        snake
            .lines()
            .filter_map(|l| l.split(&format!("validate {flag} ")).nth(1))
            .map(|rest| rest.split(' ').next().unwrap().to_owned())
            .collect()
    };
    let (members, trainings) = (stage("--simulate"), stage("--train"));
    let r = json(&one.join("validation.json"));
    assert_eq!(members.len(), r["members"].as_array().unwrap().len());
    assert_eq!(trainings.len(), 2 * members.len(), "one seed per placement and draw");
    assert_eq!(trainings.iter().filter(|t| t.contains("-draw1-seed0")).count(), members.len(), "{trainings:?}");
    for (m, t) in r["members"].as_array().unwrap().iter().map(|m| (&m[0], &m[1])) {
        assert_eq!(t["draw"], serde_json::json!([0, 1]), "{}", m["slug"]);
        let (a, b) = (t["map"][0].as_f64().unwrap(), t["map"][1].as_f64().unwrap());
        assert!((t["map_mean"].as_f64().unwrap() - (a + b) / 2.0).abs() < 1e-12, "{t}");
        // Each draw its own training scenes, the validation scenes shared.
        let slug = m["slug"].as_str().unwrap();
        let folders: Vec<std::path::PathBuf> = std::fs::read_dir(one.join("data"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.file_name().unwrap().to_str().unwrap().starts_with(&format!("{slug}-")))
            .collect();
        assert_eq!(folders.len(), 2, "{slug}: {folders:?}");
        let (train0, val0) = annotations_by_split(&folders[0]);
        let (train1, val1) = annotations_by_split(&folders[1]);
        assert!(!val0.is_empty() && !train0.is_empty(), "{slug}");
        assert_eq!(val0, val1, "{slug}: the draws share their validation scenes");
        assert_ne!(train0, train1, "{slug}: the draws' training scenes differ");
    }
    assert!(r["seed_spearman"].is_null(), "one seed per draw: no seed pair");
    assert!(r["draw_spearman"]["n"].as_u64().unwrap() as usize == members.len(), "{}", r["draw_spearman"]);
    let md = std::fs::read_to_string(one.join("validation.md")).unwrap();
    assert!(md.contains("draw 0 against draw 1"), "{md}");
    assert_eq!(
        snake.matches("\nrule ").count(),
        1 + 1 + members.len() + trainings.len(),
        "all, the last step, the stages"
    );
    assert!(snake.contains("validate --resume --out ."), "{snake}");
    // As the engine would: each stage alone, from the folder's record (no study argument).
    let stage_run = |args: &[&str]| {
        let o = hilo().arg("validate").args(args).arg("--out").arg(&wf).output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    for m in &members {
        stage_run(&["--simulate", m]);
    }
    for t in &trainings {
        stage_run(&["--train", t]);
    }
    stage_run(&["--resume"]);
    let (mut a, mut b) = (r, json(&wf.join("validation.json")));
    untimed(&mut a);
    untimed(&mut b);
    assert_eq!(a, b);
    // A stage that names no placement of the folder is refused by name.
    let o = hilo().args(["validate", "--simulate", "m99-nothing", "--out"]).arg(&wf).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("m99-nothing"));
}
