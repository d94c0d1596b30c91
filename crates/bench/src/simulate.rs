//! `hilo bench simulate`: the dataset of a study's first configuration at a given scale.

use anyhow::{Context, Result};
use hilo_dataset::simulate::SimulateConfig;
use std::path::Path;

/// `hilo bench simulate`: the dataset of a study's first configuration (the default study's:
/// the paper's 2 × 16-beam LiDAR + radar), placed optimally, written at the given scale.
#[derive(serde::Serialize, Debug)]
pub struct SimulateBench {
    /// The study file (or the embedded default's name).
    pub study: String,
    pub configuration: String,
    pub sensors: Vec<String>,
    /// The rig's LiDAR channels whose beams are cast with their width (a catalog `beam`, and the
    /// study's `lidar_beam_width` not false): about twenty times the ray casting of a thin ray.
    pub beam_width_cast: Vec<String>,
    pub scenes: usize,
    pub seconds_per_scene: f64,
    pub rate_hz: f64,
    pub frames: usize,
    pub annotations: usize,
    pub placement_seconds: f64,
    /// Simulation and writing only.
    pub write_seconds: f64,
    pub frames_per_second: f64,
    pub megabytes_written: f64,
    pub threads: usize,
}

fn dir_bytes(root: &Path) -> u64 {
    let mut total = 0;
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        if let Ok(rd) = std::fs::read_dir(&d) {
            for e in rd.flatten() {
                let p = e.path();
                match e.metadata() {
                    Ok(m) if m.is_dir() => stack.push(p),
                    Ok(m) => total += m.len(),
                    Err(_) => {}
                }
            }
        }
    }
    total
}

/// The dataset settings the bench writes: the study's, at the given scale, with no validation
/// scenes and radar sweeps at the key-frame rate.
pub fn config(study: &hilo_study::Study, scenes: usize, seconds: f64, rate_hz: f64) -> SimulateConfig {
    SimulateConfig {
        scenes,
        seconds,
        rate_hz,
        val_scenes: 0,
        sweep_rate_hz: rate_hz,
        ..study.dataset.clone().into_inner()
    }
}

/// Places `study`'s configurations, then writes its first one's dataset at the given scale
/// (into `keep`, or a temporary folder); `progress` hears the key frames written.
pub fn bench(
    study: &hilo_study::Study,
    scenes: usize,
    seconds: f64,
    rate_hz: f64,
    keep: Option<&Path>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<SimulateBench> {
    let tmp = tempfile::tempdir().context("creating a temporary folder")?;
    let t0 = std::time::Instant::now();
    let prep = hilo_study::place::prepare_study(study)?;
    let placed = hilo_study::place::place_all(study, prep, &mut |_| {})?;
    hilo_study::place::write_placements(study, &placed, &tmp.path().join("placements"))?;
    let placement_seconds = t0.elapsed().as_secs_f64();
    let first = placed.placements.first().context("the study has no configuration")?;
    let path = tmp.path().join("placements").join(format!("{}.json", hilo_study::study::slug(&first.name)));
    let cfg = config(study, scenes, seconds, rate_hz).validate()?;
    let out = keep.map(Path::to_path_buf).unwrap_or_else(|| tmp.path().join("data"));
    let summary = hilo_study::rig::simulate(study, first, &path, &cfg, &out, "v1.0-trainval", progress)?;
    let rig = hilo_study::rig::rig(first, &study.catalog, &study.scene, &path)?;
    let wide = |s: &&hilo_dataset::simulate::RigSensor| match &s.spec {
        hilo_sensor_models::SensorSpec::Lidar(l) => l.beam.is_some() && cfg.lidar_beam_width != Some(false),
        hilo_sensor_models::SensorSpec::Radar(_) => false,
    };
    Ok(SimulateBench {
        study: study.source.clone(),
        configuration: first.name.clone(),
        sensors: rig.iter().map(|s| s.channel.clone()).collect(),
        beam_width_cast: rig.iter().filter(wide).map(|s| s.channel.clone()).collect(),
        scenes,
        seconds_per_scene: seconds,
        rate_hz,
        frames: summary.frames,
        annotations: summary.annotations,
        placement_seconds,
        write_seconds: summary.seconds,
        frames_per_second: summary.frames as f64 / summary.seconds.max(1e-9),
        megabytes_written: dir_bytes(&out) as f64 / 1e6,
        threads: rayon::current_num_threads(),
    })
}
