//! Studies run in-process: a fusion plugin written here joins a study by one registration line,
//! and a radar known only by its own catalog's name still gets its fusion presets.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_fusion::modules::PillarNet;
use hilo_fusion::train::TrainConfig;
use hilo_fusion::{DetectorConfig, Fusion, FusionInput, FusionOutput, Preset, Registry, Stage};
use hilo_study::{Progress, RunOptions, Study};
use std::path::Path;

// ---- A plugin of one's own: LiDAR and radar BEV maps, added. ----

#[derive(Debug)]
struct Sum {
    l: PillarNet,
    r: PillarNet,
}

fn build(
    _: &serde_json::Value,
    _: &hilo_fusion::grid::BevGrid,
    vb: candle_nn::VarBuilder,
) -> hilo_fusion::Result<Box<dyn Fusion>> {
    use hilo_fusion::data::{LIDAR_FEATURES, RADAR_FEATURES};
    Ok(Box::new(Sum {
        l: PillarNet::new(LIDAR_FEATURES + 5, 16, vb.pp("l"))?,
        r: PillarNet::new(RADAR_FEATURES + 5, 16, vb.pp("r"))?,
    }))
}

impl Fusion for Sum {
    fn forward(&self, x: &FusionInput, train: bool) -> hilo_fusion::Result<FusionOutput> {
        let l = self.l.forward(x.lidar, x.layout, train)?;
        let r = self.r.forward(x.radar, x.layout, train)?;
        Ok(FusionOutput::Bev((l + r)?))
    }
}

/// What the plugin's crate would export.
fn register(r: &mut Registry) -> hilo_fusion::Result<()> {
    r.register("sum", Stage::Middle, build)?;
    let detector = DetectorConfig {
        name: "sum-net".into(),
        fusion: "sum".into(),
        fusion_config: serde_json::json!({}),
        ..hilo_fusion::presets::centerpoint()
    };
    r.add_preset(Preset { detector, train: TrainConfig::default() })
}

// ---- The tests. ----

fn tiny(study: &Study, registry: &Registry, presets: &[&str], out: &Path) -> hilo_study::Report {
    let mut profile = hilo_study::profile("tiny", study, registry).unwrap();
    profile.presets = presets.iter().map(|p| p.to_string()).collect();
    // Two training steps (batches of 2).
    profile.train_samples = 4;
    let opts = RunOptions { profile, seeds: 1, out: out.to_path_buf() };
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
    hilo_fusion::conformance::check_plugin(&registry, "sum").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let study = Study::parse(TWO_CONFIGS, dir.path(), "two-configs.toml").unwrap();
    let report = tiny(&study, &registry, &["sum-net"], &dir.path().join("study"));
    assert_eq!(report.entries.len(), 2, "sum-net on both configurations");
    assert!(report.entries.iter().all(|e| e.preset == "sum-net" && e.samples == 4 && e.mean_ap.is_finite()));
    let md = std::fs::read_to_string(dir.path().join("study/report.md")).unwrap();
    assert!(md.contains("sum-net"));
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
