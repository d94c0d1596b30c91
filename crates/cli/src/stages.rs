//! `hilo place` and `hilo simulate`: argument parsing and progress around the study library.

use crate::progress::Reporter;
use anyhow::{Context, Result};
use hilo_core::Valid;
use hilo_dataset::simulate::SimulateConfig;
use hilo_placement_ip::Placement;
use hilo_study::Study;
use hilo_study::place::{place_all, prepare_study, write_placements};
use serde_json::json;
use std::path::{Path, PathBuf};

/// The embedded default study: the paper's configurations on the default intersection, on field
/// sensors (its catalog, `sensors-datasheet.toml`, is embedded too).
pub const DEFAULT_STUDY_TOML: &str = include_str!("../../../fixtures/study.toml");

/// The source the embedded default study is reported under.
pub const EMBEDDED_STUDY: &str = "<embedded>/fixtures/study.toml";

/// The named study, or the embedded default.
pub fn load_study(path: Option<&Path>) -> Result<Study> {
    match path {
        Some(p) => {
            // Absolute, so that a stage run from the study folder by a workflow engine finds it.
            let abs = std::fs::canonicalize(p).with_context(|| format!("study file {}", p.display()))?;
            Study::load(&abs).with_context(|| format!("loading study {}", p.display()))
        }
        None => Study::parse_embedded(DEFAULT_STUDY_TOML, EMBEDDED_STUDY).context("loading the embedded default study"),
    }
}

#[derive(clap::Args, Debug)]
pub struct PlaceArgs {
    /// Study TOML; the embedded default (the paper's three configurations) when omitted.
    pub study: Option<PathBuf>,
    /// Output folder: <configuration>.json and <configuration>.png per configuration.
    #[arg(long, default_value = "placements")]
    pub out: PathBuf,
    /// Print a JSON summary array on stdout.
    #[arg(long)]
    pub json: bool,
    /// Also write visibility matrices (JSON) and each model (MPS) to this folder.
    #[arg(long)]
    pub export: Option<PathBuf>,
}

pub fn place(args: &PlaceArgs) -> Result<Vec<Placement>> {
    let study = load_study(args.study.as_deref())?;
    // Held from before the visibility work, so a second run on the folder is refused at once.
    let _claim = hilo_core::folder::claim(&args.out, hilo_core::folder::Mode::Exclusive)?;
    eprintln!(
        "placement: computing visibility of {} sensor types on {}",
        study.type_names().len(),
        study.scene.source_name()
    );
    let prep = prepare_study(&study)?;
    eprintln!(
        "  {} targets, {} candidates; line of sight {:.2} s, visibility {:.2} s",
        prep.targets.len(),
        prep.candidates.len(),
        prep.seconds_line_of_sight,
        prep.seconds_visibility
    );
    if let Some(dir) = &args.export {
        let _claim = hilo_core::folder::claim(dir, hilo_core::folder::Mode::Exclusive)?;
        hilo_study::place::export(&study, &prep, dir)?;
    }
    let placed = place_all(&study, prep, &mut |line| eprintln!("  {line}"))?;
    write_placements(&study, &placed, &args.out)?;
    if args.json {
        let summary: Vec<_> = placed
            .placements
            .iter()
            .map(|p| json!({"name": p.name, "objective": p.objective, "bound": p.bound, "gap": p.gap, "proven_optimal": p.proven_optimal, "solve_seconds": p.solve_seconds, "central_coverage": p.central_coverage, "lidar_radar_overlap": p.lidar_radar_overlap, "cost_usd": p.cost_usd, "sensors": p.sensors.len()}))
            .collect();
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(placed.placements)
}

#[derive(clap::Args, Debug)]
pub struct SimulateArgs {
    /// Study TOML (scene, catalog, `[dataset]` settings); the embedded default when omitted.
    pub study: Option<PathBuf>,
    /// A placement written by `hilo place` (placements/<name>.json).
    #[arg(long)]
    pub placement: PathBuf,
    /// Training scenes (overrides the study's `dataset.scenes`).
    #[arg(long)]
    pub scenes: Option<usize>,
    /// Seconds per training scene (overrides `dataset.seconds`).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Training key frames per second (overrides `dataset.rate_hz`).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Validation scenes (overrides `dataset.val_scenes`).
    #[arg(long)]
    pub val_scenes: Option<usize>,
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

pub fn simulate(args: &SimulateArgs) -> Result<()> {
    hilo_dataset::reader::check_version(&args.version)?;
    let study = load_study(args.study.as_deref())?;
    let placement = Placement::load(&args.placement)?;
    let mut cfg = study.dataset.clone().into_inner();
    if let Some(n) = args.scenes {
        cfg.scenes = n;
    }
    if let Some(s) = args.seconds {
        cfg.seconds = s;
    }
    if let Some(r) = args.rate_hz {
        cfg.rate_hz = r;
        // Radar sweeps stay a multiple of the key frames when only the key rate is asked for.
        if cfg.sweep_rate_hz < r {
            cfg.sweep_rate_hz = r;
        }
    }
    if let Some(n) = args.val_scenes {
        cfg.val_scenes = n;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    let cfg = cfg.validate()?;
    let _claim = hilo_core::folder::claim(&args.out, hilo_core::folder::Mode::Exclusive)?;
    let summary = write_dataset(
        &study,
        &placement,
        &args.placement,
        &cfg,
        &args.out,
        &args.version,
        &format!("simulating {}", placement.name),
    )?;
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        let fps = (summary.frames - summary.resumed_frames) as f64 / summary.seconds.max(1e-9);
        eprintln!(
            "wrote {} ({} scenes, {} resumed; {} key frames, {} annotations) in {:.1} s: {:.1} frames/s, {:.1} MB of points",
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

/// A placement's dataset with a progress bar.
pub fn write_dataset(
    study: &Study,
    placement: &Placement,
    source: &Path,
    cfg: &Valid<SimulateConfig>,
    out: &Path,
    version: &str,
    label: &str,
) -> Result<hilo_dataset::simulate::WriteSummary> {
    let total = cfg.total_frames();
    let reporter = std::sync::Mutex::new(Reporter::new());
    let summary = hilo_study::rig::simulate(study, placement, source, cfg, out, version, &|done| {
        if let Ok(mut r) = reporter.lock() {
            r.task(label, done, total, "frames");
        }
    })
    .with_context(|| format!("writing the dataset to {}", out.display()))?;
    if let Ok(mut r) = reporter.lock() {
        r.finish();
    }
    Ok(summary)
}
