//! Studies run in-process: a fusion plugin written here joins a study by one registration line,
//! and a radar known only by its own catalog's name still gets its fusion presets.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_detector::modules::PillarNet;
use hilo_detector::train::TrainConfig;
use hilo_detector::{DetectorConfig, Fusion, FusionInput, FusionOutput, Preset, Registry, Stage};
use hilo_study::{Progress, RunOptions, Study};
use std::path::Path;

// ---- A plugin of one's own: LiDAR and radar BEV maps, added. ----

/// What a plugin returns: its errors are the fusion crate's, what a plugin can get wrong.
type PluginResult<T> = Result<T, hilo_detector::FusionError>;

#[derive(Debug)]
struct Sum {
    l: PillarNet,
    r: PillarNet,
}

/// The plugin's config, read from the preset's `fusion_config` (an unknown field is an error).
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct SumConfig {
    channels: usize,
}

fn build(c: SumConfig, vb: candle_nn::VarBuilder) -> PluginResult<Box<dyn Fusion>> {
    use hilo_detector::config::{LIDAR_PILLAR_WIDTH, RADAR_PILLAR_WIDTH};
    Ok(Box::new(Sum {
        l: PillarNet::new(LIDAR_PILLAR_WIDTH, c.channels, vb.pp("l"))?,
        r: PillarNet::new(RADAR_PILLAR_WIDTH, c.channels, vb.pp("r"))?,
    }))
}

impl Fusion for Sum {
    fn forward(&self, x: &FusionInput, train: bool) -> PluginResult<FusionOutput> {
        let l = self.l.forward(x.lidar, x.layout, train)?;
        let r = self.r.forward(x.radar, x.layout, train)?;
        Ok(FusionOutput::Bev((l + r)?))
    }
}

/// What the plugin's crate would export.
fn register(r: &mut Registry) -> PluginResult<()> {
    r.register("sum", Stage::Middle, build)?;
    let detector = DetectorConfig {
        name: "sum-net".into(),
        fusion: "sum".into(),
        fusion_config: serde_json::json!({ "channels": 16 }),
        ..hilo_detector::presets::centerpoint()
    };
    r.add_preset(Preset { detector, train: TrainConfig::default() })
}

// ---- The tests. ----

fn tiny(study: &Study, registry: &Registry, presets: &[&str], out: &Path) -> hilo_study::Report {
    let mut profile = hilo_study::profile(hilo_study::ProfileName::Tiny, study, registry).unwrap();
    profile.presets = presets.iter().map(|p| p.to_string()).collect();
    // Two training steps (batches of 2).
    profile.train_samples = Some(4);
    profile.seeds = 1;
    let opts = RunOptions { profile, out: out.to_path_buf(), drop_datasets: false };
    let mut lines = Vec::new();
    let report = hilo_study::run(study, registry, &opts, &mut |p| {
        if let Progress::Stage(s) = p {
            lines.push(s.to_owned());
        }
    })
    .unwrap();
    assert!(lines.iter().any(|l| l.starts_with("report:")), "{lines:?}");
    report
}

const TWO_CONFIGS: &str = r#"
[dataset]
scenes = 2
seconds = 1.5
val_scenes = 2
val_seconds = 1.5

[[configurations]]
name = "2x lidar-16 + radar"
sensors = { "lidar-16" = 2, "radar-4d" = 1 }

[[configurations]]
name = "1x lidar-32 + radar"
sensors = { "lidar-32" = 1, "radar-4d" = 1 }
"#;

#[test]
fn a_plugin_written_here_joins_the_conformance_suite_and_a_study_by_one_line() {
    let mut registry = Registry::with_builtin();
    register(&mut registry).unwrap(); // the one line
    hilo_detector::conformance::check_plugin(&registry, "sum").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(TWO_CONFIGS, dir.path(), "two-configs.toml").unwrap();
    let report = tiny(&study, &registry, &["sum-net"], &dir.path().join("study"));
    assert_eq!(report.entries.len(), 2, "sum-net on both configurations");
    assert!(report.entries.iter().all(|e| e.preset == "sum-net" && e.samples == 4 && e.mean_ap.is_finite()));
    let md = std::fs::read_to_string(dir.path().join("study/report.md")).unwrap();
    assert!(md.contains("sum-net"));
    common_ground_truth_is_the_same_for_every_rig(&dir.path().join("study"));
}

/// A learning curve's point is a training of that budget of its own, not the longer training's
/// weights taken halfway (at a one-cycle learning rate still near its peak): the point at 4 of 8
/// samples holds, byte for byte, the detections of the same study trained on 4 samples.
#[test]
fn a_learning_curve_point_is_a_training_of_its_budget() {
    let registry = Registry::with_builtin();
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(TWO_CONFIGS, dir.path(), "two-configs.toml").unwrap();
    let run = |samples: usize| {
        let mut profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry).unwrap();
        profile.presets = vec!["centerpoint".into()];
        profile.configurations = Some(1);
        profile.train_samples = Some(samples);
        profile.seeds = 1;
        profile.curve = vec![0.5, 1.0];
        let out = dir.path().join(format!("at{samples}"));
        let plan = hilo_study::Plan::new(&study, &registry, &profile, &out).unwrap();
        let report =
            hilo_study::run(&study, &registry, &RunOptions { profile, out, drop_datasets: false }, &mut |_| {})
                .unwrap();
        (plan, report)
    };
    let (long, long_report) = run(8);
    let (short, short_report) = run(4);
    let (l, s) = (&long.jobs[0], &short.jobs[0]);
    assert_eq!((l.curve.as_slice(), l.train.samples, s.train.samples), (&[4][..], 8, 4));
    assert!(l.train.keep.is_empty(), "no weights kept mid-run");
    assert_eq!(l.steps(), 4 + 2, "the stage trains its 4 steps and the point's 2");
    let bytes = |p: &Path| std::fs::read(p).unwrap();
    assert_eq!(bytes(&l.curve_results(4)), bytes(&s.results), "the point is the 4-sample training");
    let schedule = |run: &Path| {
        serde_json::from_slice::<serde_json::Value>(&bytes(&run.join("run.json"))).unwrap()["train"].clone()
    };
    assert_eq!(schedule(&l.curve_run(4)), schedule(&s.run));
    assert_eq!(schedule(&l.curve_run(4))["samples"], 4);
    let curve = &long_report.learning_curves[0];
    assert!(curve.own_schedules);
    assert_eq!(curve.points.iter().map(|p| p.0).collect::<Vec<_>>(), [4, 8]);
    let entry = short_report.entries.iter().find(|e| e.seed == 0).unwrap();
    assert!((curve.points[0].1 - entry.mean_ap).abs() < 1e-12, "{curve:?} against {}", entry.mean_ap);
}

/// The two rigs' datasets (same traffic): the common ground truth is the same boxes, the
/// visible-only one is not (each rig sees other road users).
fn common_ground_truth_is_the_same_for_every_rig(study: &Path) {
    use hilo_study::gt::{GtKind, SampleKey, ground_truth};
    let dirs: Vec<_> = std::fs::read_dir(study.join("data")).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(dirs.len(), 2);
    let load = |d: &Path, kind| {
        let ds = hilo_dataset::Dataset::open(d, "v1.0-trainval").unwrap();
        ground_truth(&ds, "val", kind, SampleKey::SceneTime).unwrap().0
    };
    let boxes = |g: &hilo_eval::GroundTruth| -> Vec<(String, String, [i64; 3])> {
        let mut v: Vec<_> = g
            .boxes
            .iter()
            .flat_map(|(k, bs)| {
                bs.iter().map(move |b| {
                    (k.clone(), b.detection_name.clone(), b.translation.map(|x| (x * 1000.0).round() as i64))
                })
            })
            .collect();
        v.sort();
        v
    };
    let (a, b) = (load(&dirs[0], GtKind::Common), load(&dirs[1], GtKind::Common));
    assert_eq!(a.samples, b.samples, "the same samples (scene and time) in both rigs");
    assert!(!boxes(&a).is_empty());
    assert_eq!(boxes(&a), boxes(&b), "the same boxes in both rigs");
    let (va, vb) = (load(&dirs[0], GtKind::VisibleOnly), load(&dirs[1], GtKind::VisibleOnly));
    let visible = |g: &hilo_eval::GroundTruth| g.boxes.values().flatten().filter(|b| b.num_pts > 0).count();
    assert_ne!(visible(&va), visible(&vb), "each rig sees its own share of the road users");
    assert!(visible(&va) < boxes(&a).len() && visible(&vb) < boxes(&a).len());
}

#[test]
fn a_radar_named_by_its_own_catalog_trains_the_fusion_presets() {
    let dir = tempfile::tempdir().unwrap();
    let catalog = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../fixtures/sensors.toml"))
        .unwrap()
        .replace("name = \"radar-4d\"", "name = \"ars548\"");
    std::fs::write(dir.path().join("catalog.toml"), catalog).unwrap();
    let text = format!(
        "catalog = \"catalog.toml\"\n{}",
        TWO_CONFIGS.replace("\"radar-4d\" = 1", "\"ars548\" = 1").replace(
            "[[configurations]]\nname = \"1x lidar-32 + radar\"\nsensors = { \"lidar-32\" = 1, \"ars548\" = 1 }\n",
            ""
        )
    );
    std::fs::write(dir.path().join("study.toml"), &text).unwrap();
    let study = Study::load(&dir.path().join("study.toml")).unwrap();
    assert!(study.file.configurations[0].has_radar(&study.catalog));
    let mut registry = Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    let report = tiny(&study, &registry, &["centerpoint", "pointpillars-lr"], &dir.path().join("study"));
    let presets: Vec<&str> = report.entries.iter().map(|e| e.preset.as_str()).collect();
    assert_eq!(presets, ["centerpoint", "pointpillars-lr"], "the fusion preset trains on the ars548 rig");
}

/// Removes what measures time (it differs between any two runs) from a report, and the
/// placement trade-off's time-limit rows (a solver stopped by the wall clock: under another load
/// the same limit can stop at another incumbent).
fn without_timings(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| {
                !(k == "seconds"
                    || k.ends_with("_s")
                    || k == "ms_per_frame"
                    || k.ends_with("_seconds")
                    || k == "limits")
            });
            m.values_mut().for_each(without_timings);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(without_timings),
        _ => {}
    }
}

/// The `report.json` in study folder `d`, without what measures time.
fn report_without_timings(d: &Path) -> serde_json::Value {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("report.json")).unwrap()).unwrap();
    without_timings(&mut v);
    v
}

#[test]
fn stages_run_one_by_one_give_the_report_of_one_run_and_redo_nothing_done() {
    use hilo_study::{Plan, stages};
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(TWO_CONFIGS, dir.path(), "two-configs.toml").unwrap();
    let mut registry = Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    let mut profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry).unwrap();
    profile.presets = vec!["centerpoint".into()];
    profile.train_samples = Some(4);
    let whole = dir.path().join("whole");
    hilo_study::run(
        &study,
        &registry,
        &RunOptions { profile: profile.clone(), out: whole.clone(), drop_datasets: false },
        &mut |_| {},
    )
    .unwrap();
    // The same plan, stage by stage, as a workflow engine runs it (the trainings in reverse).
    let by_stage = dir.path().join("stages");
    let plan = Plan::new(&study, &registry, &profile, &by_stage).unwrap();
    assert_eq!(plan.jobs.len(), 4, "centerpoint × 2 configurations × 2 seeds");
    plan.claim_folder(&study).unwrap();
    assert!(stages::place(&study, &plan, &mut |_| {}).unwrap().is_some());
    for ci in 0..plan.configurations.len() {
        stages::simulate(&study, &plan, ci, &mut |_| {}).unwrap();
    }
    for job in plan.jobs.iter().rev() {
        stages::train_one(&plan, job, &registry, &|_| {}).unwrap();
    }
    hilo_study::run::report(&study, &plan, &registry, &mut |_| {}).unwrap();
    assert_eq!(report_without_timings(&whole), report_without_timings(&by_stage));
    // Everything is done: a stage run again writes nothing.
    let stamp = |p: &Path| std::fs::metadata(p).unwrap().modified().unwrap();
    let before: Vec<_> = plan.jobs.iter().map(|j| stamp(&j.meta())).collect();
    assert!(stages::place(&study, &plan, &mut |_| {}).unwrap().is_none());
    for job in &plan.jobs {
        stages::train_one(&plan, job, &registry, &|_| {}).unwrap();
    }
    assert_eq!(before, plan.jobs.iter().map(|j| stamp(&j.meta())).collect::<Vec<_>>());
    // The folder refuses another study.
    let mut other = profile.clone();
    other.seeds = 3;
    let err = Plan::new(&study, &registry, &other, &by_stage).unwrap().claim_folder(&study).unwrap_err();
    assert!(err.to_string().contains("holds another study"), "{err}");
    // The Snakefile names every stage's files, relative to the folder.
    let wf = hilo_study::workflow::Workflow { hilo: "/opt/hilo".into(), gpu: false };
    let snake = hilo_study::workflow::snakefile(&plan, &wf).unwrap();
    assert_eq!(snake.matches("\nrule ").count(), 1 + 1 + 2 + 4 + 1, "all, report, place, 2 simulate, 4 train");
    for job in &plan.jobs {
        let rel = job.results.strip_prefix(&by_stage).unwrap().to_string_lossy().into_owned();
        assert!(snake.contains(&format!("\"{rel}\"")), "{rel} in the Snakefile");
        assert!(snake.contains(&format!("study train --job {} --out .", job.id)));
    }
}

/// A weather condition records its configurations again at the same poses (one placement
/// each), in its own weather (fog leaves more road users unseen by the LiDAR-only rig), trains
/// them like the others, and the verdict judges the radar's claims and prices the radar in it;
/// a profile without conditions plans none.
/// Two training-traffic draws: each configuration recorded again with other training traffic
/// (its validation scenes the same), every detector trained on both, the report's replicates
/// the draws (two a side), the traffic's variance component reported, and the workflow names
/// the second draw's stages. The report also says where each rig's radar stands.
#[test]
fn a_second_traffic_draw_trains_every_detector_again_and_is_the_replicate() {
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(TWO_CONFIGS, dir.path(), "two-configs.toml").unwrap();
    let registry = Registry::with_builtin();
    let mut profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry).unwrap();
    profile.presets = vec!["centerpoint".into()];
    profile.train_samples = Some(4);
    profile.traffic_draws = 2;
    let out = dir.path().join("drawn");
    let plan = hilo_study::Plan::new(&study, &registry, &profile, &out).unwrap();
    assert_eq!((plan.data.len(), plan.jobs.len()), (4, 8), "2 configurations × 2 draws; × 2 seeds");
    assert_eq!(plan.data_stage(3), (1, 1));
    assert_eq!(plan.data_index(1, 1).unwrap(), 3);
    assert!(plan.data_index(0, 2).unwrap_err().to_string().contains("--draw"));
    let second: Vec<&str> = plan.jobs.iter().filter(|j| j.draw == 1).map(|j| j.id.as_str()).collect();
    assert_eq!(second.len(), 4);
    assert!(second.iter().all(|id| id.contains("centerpoint-draw1-seed")), "{second:?}");
    assert!(plan.jobs.iter().all(|j| plan.data_stage(j.data) == (j.configuration, j.draw)));
    let wf = hilo_study::workflow::Workflow { hilo: "/usr/bin/hilo".into(), gpu: false };
    let snake = hilo_study::workflow::snakefile(&plan, &wf).unwrap();
    assert!(snake.contains("--draw 1") && snake.contains("centerpoint-draw1-seed1"), "{snake}");
    let report = hilo_study::run(
        &study,
        &registry,
        &RunOptions { profile, out: out.clone(), drop_datasets: false },
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(report.entries.len(), 8);
    assert_eq!(report.entries.iter().filter(|e| e.draw == 1).count(), 4);
    // Every detector is scored on the validation scenes both draws share.
    let val = |di: usize| {
        let ds = hilo_dataset::Dataset::open(&plan.data[di].dir, "v1.0-trainval").unwrap();
        let (kind, key) = (hilo_study::gt::GtKind::Common, hilo_study::gt::SampleKey::SceneTime);
        serde_json::to_string(&hilo_study::gt::ground_truth(&ds, "val", kind, key).unwrap().0).unwrap()
    };
    assert_eq!(val(0), val(2));
    let d = &report.calibration.traffic_draws["mAP"];
    assert_eq!((d.draws, d.seeds), (2, 2));
    for c in &report.comparisons {
        assert!((c.test.seeds_a, c.test.seeds_b) == (2, 2), "{}: {:?}", c.b, c.test);
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("2 training-traffic draws") && md.contains("--traffic-draws 2"), "{md}");
    assert!(md.contains("over 4 detectors (2 seeds on each of 2 training-traffic draws)"), "{md}");
    // Where each rig's radar stands, against its placement file.
    assert!(md.contains("Where the radars stand"), "{md}");
    for (ci, c) in report.configurations.iter().enumerate() {
        let p = hilo_placement_ip::Placement::load(&plan.placement(ci)).unwrap();
        let radar = p.sensors.iter().find(|s| s.modality == hilo_placement_ip::Modality::Radar).unwrap();
        let beside = p
            .sensors
            .iter()
            .any(|s| s.modality == hilo_placement_ip::Modality::Lidar && s.structure == radar.structure);
        assert_eq!(c.radar_mounts, vec![(radar.structure.clone(), beside)], "{}", c.name);
    }
}

#[test]
fn a_weather_condition_is_recorded_trained_and_judged_on_its_own() {
    use hilo_study::Plan;
    let dir = tempfile::tempdir().unwrap();
    let text = TWO_CONFIGS.replace(
        "name = \"1x lidar-32 + radar\"\nsensors = { \"lidar-32\" = 1, \"radar-4d\" = 1 }",
        "name = \"2x lidar-16\"\nsensors = { \"lidar-16\" = 2 }",
    ) + "\n[[conditions]]\nname = \"fog\"\nweather = { fog_visibility_m = 30.0 }\nconfigurations = [\"2x lidar-16 + radar\", \"2x lidar-16\"]\n";
    let study = Study::parse(&text, dir.path(), "fog.toml").unwrap();
    let mut registry = Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    let mut profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry).unwrap();
    assert_eq!(profile.conditions, Some(0), "the tiny profile leaves conditions out");
    let out = dir.path().join("study");
    assert_eq!(Plan::new(&study, &registry, &profile, &out).unwrap().configurations.len(), 2);
    profile.conditions = None;
    profile.train_samples = Some(4);
    let plan = Plan::new(&study, &registry, &profile, &out).unwrap();
    let names: Vec<&str> = plan.configurations.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["2x lidar-16 + radar", "2x lidar-16", "2x lidar-16 + radar in fog", "2x lidar-16 in fog"]);
    assert_eq!(plan.placed, [0, 1, 0, 1]);
    assert_eq!(plan.placement(2), plan.placement(0));
    assert_eq!(plan.placement_outputs().len(), 3, "two placements and the trade-offs");
    assert_eq!(plan.datasets[3].weather.fog_visibility_m, Some(30.0));
    assert!(plan.datasets[1].weather.is_clear());
    assert_ne!(plan.data[1].dir, plan.data[3].dir);
    // centerpoint on four rigs, pointpillars-lr on the two with a radar; two seeds.
    assert_eq!(plan.jobs.len(), (4 + 2) * 2);
    let opts = RunOptions { profile, out: out.clone(), drop_datasets: false };
    let report = hilo_study::run(&study, &registry, &opts, &mut |_| {}).unwrap();
    let conf = |n: &str| report.configurations.iter().find(|c| c.name == n).unwrap();
    assert_eq!(conf("2x lidar-16 in fog").sensors, conf("2x lidar-16").sensors, "the same poses");
    assert_eq!(conf("2x lidar-16 in fog").condition.as_deref(), Some("fog"));
    assert!(
        conf("2x lidar-16 in fog").unseen_share > conf("2x lidar-16").unseen_share,
        "fog hides road users from the LiDARs: {} against {}",
        conf("2x lidar-16 in fog").unseen_share,
        conf("2x lidar-16").unseen_share
    );
    let claim = |id: &str| report.claims.iter().find(|c| c.id == id).unwrap();
    let fog = claim("radar_adds@fog");
    assert_eq!(fog.condition.as_deref(), Some("fog"));
    assert_eq!(fog.rows[0].a, [("2x lidar-16 in fog".to_string(), "centerpoint".to_string())]);
    assert_eq!(fog.rows[0].b, [("2x lidar-16 + radar in fog".to_string(), "pointpillars-lr".to_string())]);
    assert!(claim("radar_adds").rows[0].a.iter().all(|(c, _)| c == "2x lidar-16"));
    let worth: Vec<(Option<&str>, &str)> =
        report.radar_value.iter().map(|v| (v.condition.as_deref(), v.metric.as_str())).collect();
    assert!(worth.contains(&(None, "mAP")) && worth.contains(&(Some("fog"), "mAP")), "{worth:?}");
    assert!(report.radar_value.iter().all(|v| v.extra_cost_usd > 0.0));
    // The design that would find the target MDE: only for accuracy, never a smaller one than
    // this study's, and reaching the target.
    for v in &report.radar_value {
        match (&v.design, hilo_study::verdict::lower_is_better(&v.metric)) {
            (Some(_), true) => panic!("a design for a velocity error: {v:?}"),
            (Some(d), false) => assert!(
                d.mde <= hilo_study::verdict::RADAR_TARGET_MDE
                    && d.replicates >= report.seeds
                    && d.val_scenes >= report.validation_scenes,
                "{d:?}"
            ),
            (None, _) => {}
        }
    }
    let short = report.radar_value.iter().any(|v| !hilo_study::verdict::lower_is_better(&v.metric) && v.mde > 0.015);
    assert_eq!(
        short,
        std::fs::read_to_string(out.join("report.md")).unwrap().contains("The design that would find 0.015")
    );
    assert!(report.comparisons.iter().all(|c| !c.a.contains("fog") && !c.b.contains("fog")));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("## What the radar is worth, per weather") && md.contains("| fog: fog (visibility 30 m) | mAP |")
    );
    // Every figure the report links is there (a weather condition's rig has no map of its own).
    let links: Vec<&str> = md.split("](figures/").skip(1).filter_map(|s| s.split(')').next()).collect();
    assert!(links.iter().any(|l| l.starts_with("coverage_")) && links.iter().any(|l| l.contains("in_fog")));
    for l in links {
        assert!(out.join("figures").join(l).is_file(), "report.md links figures/{l}, which is not there");
    }
    // Stage by stage, as a workflow engine runs them (the datasets in reverse): the same report.
    let by_stage = dir.path().join("stages");
    let plan = Plan::new(&study, &registry, &opts.profile, &by_stage).unwrap();
    plan.claim_folder(&study).unwrap();
    hilo_study::stages::place(&study, &plan, &mut |_| {}).unwrap();
    for ci in (0..plan.configurations.len()).rev() {
        hilo_study::stages::simulate(&study, &plan, ci, &mut |_| {}).unwrap();
    }
    for job in &plan.jobs {
        hilo_study::stages::train_one(&plan, job, &registry, &|_| {}).unwrap();
    }
    hilo_study::run::report(&study, &plan, &registry, &mut |_| {}).unwrap();
    assert_eq!(report_without_timings(&out), report_without_timings(&by_stage));
}

#[test]
fn a_sweep_runs_each_study_as_if_alone_and_compares_them() {
    use hilo_study::compare::Across;
    use hilo_study::sweep::{Loaded, Sweep};
    let dir = tempfile::tempdir().unwrap();
    let catalog =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/sensors.toml")).unwrap();
    assert_eq!(catalog.matches("price_usd = 4000.0").count(), 1, "the 16-beam LiDAR's price");
    std::fs::write(dir.path().join("list.toml"), &catalog).unwrap();
    std::fs::write(dir.path().join("dear.toml"), catalog.replace("price_usd = 4000.0", "price_usd = 6000.0")).unwrap();
    let text = format!("catalogs = [\"list.toml\", \"dear.toml\"]\n{TWO_CONFIGS}");
    let Loaded::Sweep(sweep) = hilo_study::sweep::parse(&text, dir.path(), "sweep.toml").unwrap() else {
        panic!("two catalogs make a sweep")
    };
    let mut registry = Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    let profile = |s: &Study| {
        let mut p = hilo_study::profile(hilo_study::ProfileName::Tiny, s, &registry)?;
        p.presets = vec!["centerpoint".into()];
        p.train_samples = Some(4);
        Ok(p)
    };
    let out = dir.path().join("sweep");
    let c = hilo_study::run_sweep(&sweep, &registry, &profile, &out, false, &mut |_| {}).unwrap();
    assert_eq!(c.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["list", "dear"]);
    // The catalogs differ by $2,000 per 16-beam LiDAR: the two-LiDAR rig costs $4,000 more.
    let cheap = &c.configurations[0];
    assert_eq!(cheap.name, "2x lidar-16 + radar");
    assert_eq!(cheap.at["dear"].cost_usd - cheap.at["list"].cost_usd, 4_000.0);
    assert_eq!(c.configurations[1].at["dear"].cost_usd, c.configurations[1].at["list"].cost_usd);
    for conf in &c.configurations {
        for at in conf.at.values() {
            assert_eq!(at.map["centerpoint"].seeds, 2);
        }
    }
    assert!(c.claims.iter().all(|cl| cl.at.len() == 2));
    assert!(c.claims.iter().any(|cl| cl.across == Across::NotTested), "the tiny profile trains no fusion preset");
    // A study of the sweep is the study run alone: the same report, apart from timings.
    let alone = dir.path().join("alone");
    let dear = &sweep.shards[1].study;
    hilo_study::run(
        dear,
        &registry,
        &RunOptions { profile: profile(dear).unwrap(), out: alone.clone(), drop_datasets: false },
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(report_without_timings(&alone), report_without_timings(&Sweep::shard_out(&out, "dear")));
    // Rerun: everything is done, the comparison is the same; the folder refuses another sweep.
    // A finished study whose datasets were deleted (to free the disk) is not simulated or
    // reported again: its report stays, byte for byte.
    let shard = Sweep::shard_out(&out, "list");
    let report = std::fs::read(shard.join("report.json")).unwrap();
    std::fs::remove_dir_all(shard.join("data")).unwrap();
    let mut lines = Vec::new();
    // With --drop-datasets: the other study's datasets go too, its report stays.
    let again = hilo_study::run_sweep(&sweep, &registry, &profile, &out, true, &mut |p| {
        if let Progress::Stage(s) = p {
            lines.push(s.to_owned());
        }
    })
    .unwrap();
    assert_eq!(serde_json::to_value(&again).unwrap(), serde_json::to_value(&c).unwrap());
    assert!(!shard.join("data").exists(), "the finished study's datasets were simulated again");
    assert!(!Sweep::shard_out(&out, "dear").join("data").exists());
    assert!(lines.iter().any(|l| l.starts_with("datasets deleted:")), "{lines:?}");
    assert_eq!(std::fs::read(shard.join("report.json")).unwrap(), report);
    assert_eq!(lines.iter().filter(|l| l.starts_with("complete:")).count(), 2, "{lines:?}");
    // A training made after the report (here: its output touched) makes the report stale.
    let plan = hilo_study::run::sweep_plans(&sweep, &registry, &profile, &out).unwrap().remove(1);
    assert!(plan.complete());
    let results = std::fs::File::options().append(true).open(&plan.jobs[0].results).unwrap();
    results.set_modified(std::time::SystemTime::now() + std::time::Duration::from_secs(5)).unwrap();
    assert!(!plan.complete());
    let mut one = sweep.clone();
    one.shards.truncate(1);
    let err = hilo_study::run_sweep(&one, &registry, &profile, &out, false, &mut |_| {}).unwrap_err();
    assert!(err.to_string().contains("holds another sweep"), "{err}");
    let md = std::fs::read_to_string(out.join("comparison.md")).unwrap();
    assert!(md.contains("| [dear](dear/report.md) |") && md.contains("$14,000"), "{md}");
}

/// The tiny profile's plan of the study file `text` (in `dir`), with the raw fusion plugin's
/// presets registered beside the built-in ones.
fn tiny_plan(dir: &std::path::Path, text: &str) -> hilo_study::Result<hilo_study::Plan> {
    let mut registry = Registry::with_builtin();
    hilo_fusion_raw::register(&mut registry).unwrap();
    let study = Study::parse(text, dir, "study.toml")?;
    let profile = hilo_study::profile(hilo_study::ProfileName::Tiny, &study, &registry)?;
    hilo_study::Plan::new(&study, &registry, &profile, &dir.join("study"))
}

/// `[detector_patch]` reaches every detector the study trains (and their stage hashes, so a
/// patched study never reuses an unpatched run); a patch that stacks LiDAR sweeps on datasets
/// recorded without them, renames a preset or names an unknown field is refused by section,
/// preset and field.
#[test]
fn a_detector_patch_reaches_every_job_and_is_checked() {
    let dir = tempfile::tempdir().unwrap();
    let plan = |text: &str| tiny_plan(dir.path(), text);
    let plain = plan(TWO_CONFIGS).unwrap();
    let sweeps = TWO_CONFIGS.replacen("[dataset]\n", "[dataset]\nlidar_sweeps = true\n", 1);
    let patch = "\n[detector_patch]\nvelocity_weight = 2.0\ninput = { lidar_sweeps = 10, max_sweep_lag_s = 1.0 }\n";
    let patched = plan(&format!("{sweeps}{patch}")).unwrap();
    assert_eq!(patched.jobs.len(), plain.jobs.len());
    assert!(!patched.jobs.is_empty());
    for (p, q) in patched.jobs.iter().zip(&plain.jobs) {
        assert_eq!((p.detector.velocity_weight, p.detector.input.lidar_sweeps), (2.0, 10), "{}", p.id);
        assert_eq!((&p.detector.grid, &p.detector.name), (&q.detector.grid, &q.detector.name));
        assert_ne!(p.run, q.run, "{}: a patched run has a folder of its own", p.id);
    }
    for (text, words) in [
        (format!("{TWO_CONFIGS}{patch}"), vec!["[detector_patch]", "lidar_sweeps = true", "[dataset]"]),
        (format!("{sweeps}\n[detector_patch]\nname = \"mine\"\n"), vec!["[detector_patch]", "name or fusion"]),
        (format!("{sweeps}\n[detector_patch]\ninput = {{ lidar_sweps = 3 }}\n"), vec!["input.lidar_sweps"]),
    ] {
        let e = plan(&text).unwrap_err().to_string();
        assert!(words.iter().all(|w| e.contains(w)), "{e}");
    }
}

/// `[train_schedule]` reaches every training the study runs (and its stage hash, so a study
/// with its own schedule never reuses a preset-schedule run), its sample count wins over the
/// profile's, and the fields the study sets itself, an unknown field and a bad value are refused
/// by section, preset and field.
#[test]
fn a_train_schedule_reaches_every_job_and_is_checked() {
    let dir = tempfile::tempdir().unwrap();
    let plan = |text: &str| tiny_plan(dir.path(), text);
    let plain = plan(TWO_CONFIGS).unwrap();
    let schedule = "\n[train_schedule]\nbatch = 4\nlr_max = 0.012\nsamples = 12\n";
    let scheduled = plan(&format!("{TWO_CONFIGS}{schedule}")).unwrap();
    assert_eq!(scheduled.jobs.len(), plain.jobs.len());
    assert!(!scheduled.jobs.is_empty());
    for (p, q) in scheduled.jobs.iter().zip(&plain.jobs) {
        assert_eq!((p.train.batch, p.train.lr_max, p.train.samples), (4, 0.012, 12), "{}", p.id);
        assert_ne!(q.train.samples, 12, "the tiny profile's own sample count differs");
        assert_eq!((p.train.seed, p.train.replicas, p.train.sync_batch_norm), (q.train.seed, 1, false));
        assert_eq!(p.detector, q.detector);
        assert_ne!(p.run, q.run, "{}: a rescheduled run has a folder of its own", p.id);
    }
    // The augmentation's site-keeping share (the default study's): the other
    // augmentation fields keep the preset's.
    let site = plan(&format!("{TWO_CONFIGS}\n[train_schedule.augmentation]\nkeep_site_p = 0.75\n")).unwrap();
    for (p, q) in site.jobs.iter().zip(&plain.jobs) {
        let (a, b) = (&p.train.augmentation, &q.train.augmentation);
        assert_eq!(
            (a.keep_site_p, a.rotate_deg, a.flip_p, a.scale),
            (0.75, b.rotate_deg, b.flip_p, b.scale),
            "{}",
            p.id
        );
        assert_ne!(p.run, q.run, "{}", p.id);
    }
    for (text, words) in [
        ("\n[train_schedule.augmentation]\nkeep_site_p = 2.0\n", vec!["[train_schedule]", "keep_site_p"]),
        ("\n[train_schedule]\nseed = 3\n", vec!["[train_schedule]", "seed = 3"]),
        ("\n[train_schedule]\nreplicas = 2\n", vec!["[train_schedule]", "replicas = 2"]),
        ("\n[train_schedule]\nbatchsize = 16\n", vec!["[train_schedule]", "batchsize"]),
        ("\n[train_schedule]\nbatch = 0\n", vec!["[train_schedule]", "batch = 0"]),
    ] {
        let e = plan(&format!("{TWO_CONFIGS}{text}")).unwrap_err().to_string();
        assert!(words.iter().all(|w| e.contains(w)), "{e}");
    }
}

/// The placements of a calibrated objective over road users depend on the study's traffic, so
/// their stage hash does; with the paper's objective, or calibrated weights over the regions
/// only, the traffic decides nothing there and the hash ignores it.
#[test]
fn placements_for_road_users_are_hashed_with_the_traffic() {
    let dir = tempfile::tempdir().unwrap();
    let placements = |placement: &str, seed: u64| {
        let text = TWO_CONFIGS.replacen("[dataset]\n", &format!("{placement}\n[dataset]\nseed = {seed}\n"), 1);
        let sub = dir.path().join(format!("{}-{seed}", placement.len()));
        std::fs::create_dir_all(&sub).unwrap();
        tiny_plan(&sub, &text).unwrap().placements.file_name().unwrap().to_owned()
    };
    let users =
        "[placement]\nobjective = \"calibrated\"\ncalibration = { lidar = 0.2, radar = 0.0, lidar_road_users = 0.5 }\n";
    let regions =
        "[placement]\nobjective = \"calibrated\"\ncalibration = { lidar = 0.2, radar = 0.0, lidar_two_views = 0.5 }\n";
    assert_ne!(placements(users, 0), placements(users, 1));
    assert_eq!(placements(regions, 0), placements(regions, 1));
    assert_eq!(placements("", 0), placements("", 1));
    assert_ne!(placements(users, 0), placements(regions, 0));
}
