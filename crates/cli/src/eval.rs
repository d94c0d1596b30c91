//! `hilo eval`: nuScenes detection metrics of a submission against ground truth.

use crate::write_atomic;
use anyhow::{Context, Result, bail};
use hilo_eval::{DetectionConfig, evaluate_files, read_ground_truth, read_submission};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Ground truth (hilo's ground-truth JSON: samples with scene and ego/origin position, boxes
    /// with num_pts).
    #[arg(long)]
    gt: PathBuf,
    /// Predictions in the nuScenes submission format.
    #[arg(long)]
    results: PathBuf,
    /// Output folder for metrics_summary.json.
    #[arg(long, default_value = "metrics")]
    out: PathBuf,
    /// Evaluation settings (JSON with the devkit's config keys); hilo's default otherwise.
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run(args: &EvalArgs) -> Result<()> {
    let cfg: DetectionConfig = match &args.config {
        Some(p) => serde_json::from_str(&std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?)
            .with_context(|| format!("{}: invalid evaluation config", p.display()))?,
        None => DetectionConfig::default(),
    };
    let gt = read_ground_truth(&args.gt)?;
    let pred = read_submission(&args.results, cfg.max_boxes_per_sample)?;
    // As the devkit: the submission must cover exactly the ground truth's samples.
    let pred_samples: std::collections::BTreeSet<&String> = pred.iter().map(|(s, _)| s).collect();
    let gt_samples: std::collections::BTreeSet<&String> = gt.samples.keys().collect();
    if pred_samples != gt_samples {
        let missing: Vec<_> = gt_samples.difference(&pred_samples).take(3).collect();
        let extra: Vec<_> = pred_samples.difference(&gt_samples).take(3).collect();
        bail!("{}: samples differ from the ground truth's (missing e.g. {missing:?}, unknown e.g. {extra:?})", args.results.display());
    }
    let m = evaluate_files(&gt, &pred, &cfg);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    write_atomic(&args.out.join("metrics_summary.json"), serde_json::to_string_pretty(&m)?.as_bytes())?;
    println!("mAP {:.4}  NDS {:.4}  ({} samples, {:.2} s)", m.mean_ap, m.nd_score, gt.samples.len(), m.eval_time);
    println!("{:<12} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}", "class", "AP", "ATE", "ASE", "AOE", "AVE", "AAE");
    for (c, ap) in &m.mean_dist_aps {
        let e = &m.label_tp_errors[c];
        println!("{:<12} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3}", c, ap, e["trans_err"], e["scale_err"], e["orient_err"], e["vel_err"], e["attr_err"]);
    }
    Ok(())
}
