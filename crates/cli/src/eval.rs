//! `hilo eval`: nuScenes detection metrics of a submission against ground truth.

use anyhow::{Result, bail};
use hilo_eval::{DetectionConfig, check_sample_set, evaluate_files, read_ground_truth, read_submission};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Ground truth from a nuScenes-layout dataset (its `--split` scenes).
    #[arg(long, conflicts_with = "gt")]
    data: Option<PathBuf>,
    #[arg(long, default_value = "v1.0-trainval")]
    version: String,
    #[arg(long, default_value = "val")]
    split: String,
    /// Ground truth as hilo's ground-truth JSON (samples with scene and origin, boxes with
    /// num_pts), instead of `--data`.
    #[arg(long, required_unless_present = "data")]
    gt: Option<PathBuf>,
    /// Predictions in the nuScenes submission format.
    #[arg(long)]
    results: PathBuf,
    /// Output folder for metrics_summary.json.
    #[arg(long, default_value = "metrics")]
    out: PathBuf,
    /// Evaluation settings (JSON with the devkit's config keys); hilo's default otherwise.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Scene-bootstrap resamples for 95% intervals (0 = none, at most 100,000); written to
    /// bootstrap.json.
    #[arg(long, default_value_t = 1000, value_parser = resamples)]
    bootstrap: u32,
    /// A second submission on the same ground truth: the paired bootstrap of (it − --results),
    /// written to paired.json.
    #[arg(long)]
    compare: Option<PathBuf>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(args: &EvalArgs) -> Result<()> {
    let cfg: DetectionConfig = match &args.config {
        Some(p) => {
            let cfg: DetectionConfig = hilo_core::fs::read_json(p, hilo_core::fs::limit::CONFIG)?;
            cfg.check().map_err(|m| anyhow::anyhow!("{}: {m}", p.display()))?;
            cfg
        }
        None => DetectionConfig::default(),
    };
    let gt = match (&args.data, &args.gt) {
        (Some(root), _) => {
            let ds = hilo_dataset::Dataset::open(root, &args.version)?;
            hilo_study::gt::ground_truth(
                &ds,
                &args.split,
                hilo_study::gt::GtKind::VisibleOnly,
                hilo_study::gt::SampleKey::Token,
            )?
            .0
        }
        (None, Some(p)) => read_ground_truth(p)?,
        (None, None) => bail!("give --data or --gt"),
    };
    // Without a config of its own, ground truth with cyclists evaluates them too.
    let cyclists = gt.boxes.values().flatten().any(|b| b.detection_name == hilo_core::Class::Bicycle.name());
    let cfg = if args.config.is_none() && cyclists { cfg.with_cyclists() } else { cfg };
    let pred = read_submission(&args.results, cfg.max_boxes_per_sample)?;
    check_sample_set(&gt, &pred, &args.results)?;
    // The second submission is read and checked before anything is written.
    if args.compare.is_some() && args.bootstrap == 0 {
        bail!("--compare needs the paired bootstrap: give --bootstrap N with N > 0");
    }
    let compare = match &args.compare {
        Some(other) => {
            let b = read_submission(other, cfg.max_boxes_per_sample)?;
            check_sample_set(&gt, &b, other)?;
            Some((other, b))
        }
        None => None,
    };
    let m = evaluate_files(&gt, &pred, &cfg);
    let _claim = hilo_core::folder::claim(&args.out, hilo_core::folder::Mode::Exclusive)?;
    hilo_core::fs::write_json(&args.out.join("metrics_summary.json"), &m)?;
    let bins = hilo_eval::metrics_by_distance(&gt, &pred, &cfg);
    let by_distance: BTreeMap<&str, &hilo_eval::BinMetrics> = bins.iter().map(|(l, m)| (l.as_str(), m)).collect();
    hilo_core::fs::write_json(&args.out.join("metrics_by_distance.json"), &by_distance)?;
    hilo_core::fs::write_json(&args.out.join("metrics_iou.json"), &hilo_eval::iou_aps(&gt, &pred, &cfg))?;
    print!("{}", hilo_eval::text::metrics_table(&m, &bins, gt.samples.len()));
    if args.bootstrap > 0 {
        let b = hilo_eval::bootstrap::bootstrap(&gt, &pred, &cfg, args.bootstrap as usize, 0.95, args.seed);
        hilo_core::fs::write_json(&args.out.join("bootstrap.json"), &b)?;
        println!("{}", hilo_eval::text::bootstrap_line(&b));
        if let Some((other, pred_b)) = &compare {
            let p = hilo_eval::bootstrap::paired(&gt, &pred, pred_b, &cfg, args.bootstrap as usize, 0.95, args.seed);
            hilo_core::fs::write_json(&args.out.join("paired.json"), &p)?;
            let names = (other.display().to_string(), args.results.display().to_string());
            println!("{}", hilo_eval::text::paired_line(&p, &names.0, &names.1));
        }
    }
    Ok(())
}

/// `--bootstrap`: a resample count from 0 to 100,000 (more only costs time; an absurd one would
/// exhaust memory).
fn resamples(s: &str) -> Result<u32, String> {
    match s.parse::<u64>() {
        Ok(n) if n <= 100_000 => Ok(n as u32),
        _ => Err(format!("{s} is not a resample count from 0 to 100000")),
    }
}
