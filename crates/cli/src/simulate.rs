//! `hilo simulate`: a roadside dataset in the nuScenes layout for one placement.

use crate::study::Study;
use anyhow::{Context, Result, bail};
use hilo_dataset::simulate::{RigSensor, SimulateConfig, WriteSummary, write_dataset};
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorPose, SensorSpec};
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Study TOML (scene, catalog, `[dataset]` settings); the embedded default when omitted.
    pub study: Option<PathBuf>,
    /// A placement written by `hilo place` (placements/<name>.json).
    #[arg(long)]
    pub placement: PathBuf,
    /// Number of scenes (overrides the study's `dataset.scenes`).
    #[arg(long)]
    pub scenes: Option<usize>,
    /// Seconds per scene (overrides `dataset.seconds`).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Frames per second (overrides `dataset.rate_hz`).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Seed of traffic and sensor noise (overrides `dataset.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output folder (nuScenes dataroot).
    #[arg(long)]
    pub out: PathBuf,
    /// Table folder name inside the dataroot.
    #[arg(long, default_value = "v1.0-trainval")]
    pub version: String,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The part of a placement file `hilo simulate` reads.
#[derive(Deserialize, Debug)]
pub struct PlacementFile {
    pub name: String,
    pub sensors: Vec<PlacedSensorFile>,
}

#[derive(Deserialize, Debug)]
pub struct PlacedSensorFile {
    #[serde(rename = "type")]
    pub ty: String,
    pub pose: SensorPose,
}

impl PlacementFile {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading placement {}", path.display()))?;
        let p: PlacementFile = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a placement written by `hilo place`", path.display()))?;
        if p.sensors.is_empty() {
            bail!("{}: the placement has no sensors", path.display());
        }
        Ok(p)
    }

    /// The rig: LiDARs first (LIDAR_0, …), then radars (RADAR_0, …).
    pub fn rig(&self, catalog: &Catalog, scene: &Scene, source: &Path) -> Result<Vec<RigSensor>> {
        let mut lidars = Vec::new();
        let mut radars = Vec::new();
        for (i, s) in self.sensors.iter().enumerate() {
            let spec = catalog
                .get(&s.ty)
                .with_context(|| format!("{}: sensors[{i}].type = {:?}", source.display(), s.ty))?
                .clone();
            let p = s.pose.position;
            if !(p.is_finite() && s.pose.yaw.is_finite() && s.pose.pitch.is_finite() && s.pose.roll.is_finite()) {
                bail!("{}: sensors[{i}].pose is not finite: {:?}", source.display(), s.pose);
            }
            if p.truncate().length() > 500.0 || p.z < scene.ground.z_m {
                bail!("{}: sensors[{i}].pose.position = {p} is outside the scene", source.display());
            }
            match spec {
                SensorSpec::Lidar(_) => lidars.push((spec, s.pose)),
                SensorSpec::Radar(_) => radars.push((spec, s.pose)),
            }
        }
        let mut rig: Vec<RigSensor> = lidars
            .into_iter()
            .enumerate()
            .map(|(k, (spec, pose))| RigSensor { channel: format!("LIDAR_{k}"), spec, pose })
            .collect();
        rig.extend(radars.into_iter().enumerate().map(|(k, (spec, pose))| RigSensor {
            channel: format!("RADAR_{k}"),
            spec,
            pose,
        }));
        Ok(rig)
    }
}

/// The dataset settings of a study with the command line's overrides.
pub fn settings(study: &Study, args: &SimulateArgs) -> SimulateConfig {
    let mut cfg = study.file.dataset.clone();
    if let Some(n) = args.scenes {
        cfg.scenes = n;
    }
    if let Some(s) = args.seconds {
        cfg.seconds = s;
    }
    if let Some(r) = args.rate_hz {
        cfg.rate_hz = r;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    cfg
}

/// The static world around a rig (everything within the sensors' ranges).
pub fn rig_world(scene: &Scene, rig: &[RigSensor]) -> Result<World> {
    let spheres = rig.iter().map(|s| {
        let r = match &s.spec {
            SensorSpec::Lidar(l) => l.max_range_m,
            SensorSpec::Radar(r) => r.max_range_m,
        };
        (s.pose.position, r)
    });
    World::build(scene, &QueryRegion::spheres(spheres)).context("building the static world")
}

/// Writes the dataset with a progress bar; returns the summary.
pub fn write_with_progress(
    scene: &Scene,
    rig: &[RigSensor],
    cfg: &SimulateConfig,
    out: &Path,
    version: &str,
    namespace: &str,
    label: &str,
) -> Result<WriteSummary> {
    cfg.validate()?;
    let world = rig_world(scene, rig)?;
    let total = (cfg.scenes * cfg.frames_per_scene()) as u64;
    let bar = indicatif::ProgressBar::new(total);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames, {per_sec}, ETA {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(label.to_owned());
    let summary =
        write_dataset(scene, &world, rig, cfg, out, version, namespace, &|done| bar.set_position(done as u64))
            .with_context(|| format!("writing the dataset to {}", out.display()))?;
    bar.finish_and_clear();
    Ok(summary)
}

pub fn run(args: &SimulateArgs) -> Result<()> {
    let study = Study::load(args.study.as_deref())?;
    let scene = crate::load_scene(study.file.scene.as_ref().map(|p| study.resolve(p)).as_deref())?;
    let catalog = match &study.file.catalog {
        Some(p) => Catalog::load(&study.resolve(p))?,
        None => Catalog::default_catalog()?,
    };
    let placement = PlacementFile::load(&args.placement)?;
    let rig = placement.rig(&catalog, &scene, &args.placement)?;
    let cfg = settings(&study, args);
    let summary = write_with_progress(
        &scene,
        &rig,
        &cfg,
        &args.out,
        &args.version,
        &placement.name,
        &format!("simulating {}", placement.name),
    )?;
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        let fps = (summary.frames - summary.resumed_scenes * cfg.frames_per_scene()) as f64 / summary.seconds.max(1e-9);
        eprintln!(
            "wrote {} ({} scenes, {} resumed; {} frames, {} annotations) in {:.1} s: {:.1} frames/s, {:.1} MB of points",
            args.out.display(),
            summary.scenes,
            summary.resumed_scenes,
            summary.frames,
            summary.annotations,
            summary.seconds,
            fps,
            summary.bytes_written as f64 / 1e6
        );
    }
    Ok(())
}

/// `hilo bench simulate`: the dataset of the default study's first configuration (the paper's
/// 2 × 16-beam LiDAR + radar), placed optimally, written at the given scale.
#[derive(serde::Serialize, Debug)]
pub struct SimulateBench {
    pub configuration: String,
    pub sensors: Vec<String>,
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

pub fn bench(scenes: usize, seconds: f64, rate_hz: f64, keep: Option<&Path>) -> Result<SimulateBench> {
    let tmp = tempfile::tempdir().context("creating a temporary folder")?;
    let t0 = std::time::Instant::now();
    let placements = crate::place::run(&crate::place::PlaceArgs {
        study: None,
        out: tmp.path().join("placements"),
        json: false,
        export: None,
    })?;
    let placement_seconds = t0.elapsed().as_secs_f64();
    let first = placements.first().context("the default study has no configuration")?;
    let path = tmp
        .path()
        .join("placements")
        .join(format!("{}.json", crate::study::Study::load(None)?.file.configurations[0].slug()));
    let placement = PlacementFile::load(&path)?;
    let scene = crate::load_scene(None)?;
    let catalog = Catalog::default_catalog()?;
    let rig = placement.rig(&catalog, &scene, &path)?;
    let cfg = SimulateConfig { scenes, seconds, rate_hz, ..SimulateConfig::default() };
    let out = keep.map(Path::to_path_buf).unwrap_or_else(|| tmp.path().join("data"));
    let summary = write_with_progress(&scene, &rig, &cfg, &out, "v1.0-trainval", &first.name, "bench simulate")?;
    Ok(SimulateBench {
        configuration: first.name.clone(),
        sensors: rig.iter().map(|s| s.channel.clone()).collect(),
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
