//! `hilo train` and `hilo detect`.

use anyhow::{Context, Result, bail};
use hilo_detector::data::LoadOptions;
use hilo_detector::train::StepReport;
use hilo_detector::{DetectorConfig, Registry};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Dataset root (nuScenes layout, as `hilo simulate` writes it).
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, default_value = "v1.0-trainval")]
    pub version: String,
    #[arg(long, default_value = "train")]
    pub split: String,
    /// Detector preset or ablation: centerpoint, pointpillars (LiDAR only); pointpillars-lr,
    /// l4dr-like, lirafusion-like, bi-lrfusion-like, middle-attention, late (LiDAR + radar);
    /// l4dr-like-no-early, lirafusion-like-no-early (ablations). An unknown name lists them.
    #[arg(long, default_value = "centerpoint")]
    pub detector: String,
    /// A detector of one's own: a JSON file with the fields of run.json's "detector" (grid,
    /// backbone, head, fusion plugin and its config); replaces --detector.
    #[arg(long, conflicts_with = "detector")]
    pub detector_config: Option<PathBuf>,
    /// Changes to the preset: a JSON merge patch (RFC 7386) over its detector config, e.g.
    /// `{"input": {"lidar_sweeps": 10}, "velocity_weight": 1.0}`; the preset's training schedule
    /// is kept. run.json records the patched config.
    #[arg(long, conflicts_with = "detector_config")]
    pub detector_patch: Option<PathBuf>,
    /// A training schedule: a JSON file with any fields of run.json's "train" (the rest keep
    /// the preset's default schedule); --samples, --batch and --seed override it.
    #[arg(long)]
    pub train_config: Option<PathBuf>,
    /// Run folder: weights, optimizer state, run.json, loss.jsonl. Rerunning resumes.
    #[arg(long)]
    pub out: PathBuf,
    /// Training samples in total (overrides the default schedule: the preset's, 12,000–30,000
    /// samples, within five minutes of training on two cores).
    #[arg(long)]
    pub samples: Option<usize>,
    #[arg(long)]
    pub batch: Option<usize>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Fused layers: `on`, `off` (every layer the composite of candle's operations it is tested
    /// against) or some of `conv+bn_relu+loss`; run.json records any but `on`, and a run
    /// resumes only with its own.
    #[arg(long, default_value = "on")]
    pub fused: hilo_detector::cpu::LayerSet,
}

/// Every fusion plugin hilo ships (the umbrella crate's list).
pub fn registry() -> Result<Registry> {
    Ok(hilo::registry()?)
}

pub fn run_train(args: &TrainArgs) -> Result<()> {
    let registry = registry()?;
    let ds = hilo_dataset::Dataset::open(&args.data, &args.version)
        .with_context(|| format!("opening dataset {}", args.data.display()))?;
    let (det, mut cfg) = hilo_detector::train::recipe(
        &registry,
        &args.detector,
        args.detector_config.as_deref(),
        args.detector_patch.as_deref(),
        args.train_config.as_deref(),
    )?;
    if let Some(s) = args.samples {
        cfg.samples = s;
    }
    if let Some(b) = args.batch {
        cfg.batch = b;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    let cfg = cfg.validate().context("--batch, --samples or the training schedule")?;
    hilo_detector::cpu::set_fused(&args.fused.0);
    // A dataset whose traffic carries cyclists gets a detector that finds them.
    let cyclists = det.cyclists || ds.classes().contains(&hilo_core::Class::Bicycle);
    let det = DetectorConfig { cyclists, ..det }.validate()?;
    det.check_memory(cfg.batch, hilo_core::machine::memory_bytes())?;
    // Held from before the data is loaded, so a second training of the folder is refused at once.
    let _claim = hilo_core::folder::claim(&args.out, hilo_core::folder::Mode::Exclusive)?;
    hilo_detector::data::check_modalities(&ds, &det.name, registry.uses_radar(&det))?;
    let background = hilo_detector::train::learn_background(&ds, &args.split, &det).with_context(|| {
        format!("{}: learning the static background of split {:?}", args.data.display(), args.split)
    })?;
    let (frames, stats) =
        hilo_detector::data::load_split(&ds, &args.split, &LoadOptions::of(&det, &registry, background.as_ref()))
            .with_context(|| format!("{}: split {:?}", args.data.display(), args.split))?;
    for note in stats.notes(background.is_some(), det.input.radar_clutter.is_some()) {
        eprintln!("{note}");
    }
    if let Some(db) = hilo_detector::train::paste_db(&frames, &cfg).context("train.paste")? {
        eprintln!("ground-truth paste: instances to paste from the training frames: {}", db.describe());
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if cfg.sync_batch_norm && cfg.replicas > cores {
        eprintln!(
            "warning: {} replicas with synchronised BatchNorm on {cores} cores: each runs on a thread of its \
             own and they meet at every BatchNorm layer, so sharing cores slows every step (fewer replicas \
             would train faster here)",
            cfg.replicas
        );
    }
    let mut bar = crate::progress::Reporter::new();
    let label = format!("train {}", det.name);
    let steps = cfg.steps();
    let mut log = hilo_detector::train::LossLog::new(&args.out);
    let mut log_error: Option<anyhow::Error> = None;
    let mut warned = false;
    let mut on_step = |r: &StepReport| {
        if let Err(e) = log.append(r) {
            log_error = Some(anyhow::Error::new(e).context(format!("writing {}", log.path().display())));
            return false;
        }
        bar.task(&label, r.step, steps, "steps");
        bar.message(format!(
            "{} loss {:.3} (cls {:.3}, reg {:.3}) {:.1} samples/s",
            det.name, r.loss, r.cls, r.reg, r.samples_per_s
        ));
        if r.dropped_pillars > 0 && !warned {
            warned = true;
            bar.line(&format!(
                "warning: step {}: {} pillars over the grid's max_pillars were left out (a uniform sample is kept)",
                r.step, r.dropped_pillars
            ));
        }
        true
    };
    let info = hilo_detector::train::train(
        &args.out,
        &det,
        &cfg,
        &frames,
        background.as_ref(),
        &registry,
        &hilo_detector::default_device(),
        &mut on_step,
    )
    .with_context(|| format!("training {} in {}", det.name, args.out.display()))?;
    if let Some(e) = log_error {
        return Err(e);
    }
    bar.finish();
    eprintln!(
        "trained {} on {} frames: {} steps, {} samples in {:.1} s ({} points over the pillar cap left out); weights in {}",
        det.name,
        frames.len(),
        info.step,
        info.samples_seen,
        info.seconds,
        info.dropped_points,
        hilo_detector::train::weights_path(&args.out).display()
    );
    Ok(())
}

#[derive(clap::Args, Debug)]
pub struct DetectArgs {
    /// A run folder written by `hilo train`.
    #[arg(long)]
    pub run: PathBuf,
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, default_value = "v1.0-trainval")]
    pub version: String,
    #[arg(long, default_value = "val")]
    pub split: String,
    /// Submission JSON (nuScenes format) for `hilo eval`.
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
}

pub fn run_detect(args: &DetectArgs) -> Result<()> {
    if args.batch == 0 {
        bail!("--batch must be at least 1");
    }
    let (det, info, background) =
        hilo_detector::train::load_run(&args.run, &registry()?, &hilo_detector::default_device())
            .with_context(|| format!("loading run {}", args.run.display()))?;
    let ds = hilo_dataset::Dataset::open(&args.data, &args.version)
        .with_context(|| format!("opening dataset {}", args.data.display()))?;
    hilo_detector::data::check_modalities(&ds, &info.detector.name, det.uses_radar())?;
    let options = LoadOptions::new(&det.cfg.input, background.as_ref(), det.uses_radar());
    let (frames, _) = hilo_detector::data::load_split(&ds, &args.split, &options)
        .with_context(|| format!("{}: split {:?}", args.data.display(), args.split))?;
    let mut bar = crate::progress::Reporter::new();
    let total = frames.len();
    let ((dets, per_frame), read) = hilo_detector::infer::detect_counted(&det, &frames, args.batch, &mut |n| {
        bar.task("detect", n, total, "frames")
    })?;
    bar.finish();
    let meta = serde_json::json!({ "use_camera": false, "use_lidar": true, "use_radar": det.uses_radar(), "use_map": false, "use_external": false, "detector": det.cfg.name });
    let json = hilo_eval::boxes::submission_json(&hilo_eval::boxes::from_detections(&dets), meta);
    hilo_core::fs::write_atomic(&args.out, serde_json::to_string(&json)?.as_bytes())?;
    eprintln!(
        "{} ({}) on {} frames: {:.1} ms per frame{}; wrote {}",
        info.detector.name,
        args.run.display(),
        frames.len(),
        per_frame * 1e3,
        read.note(),
        args.out.display()
    );
    Ok(())
}
