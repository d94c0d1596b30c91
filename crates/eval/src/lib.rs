//! Detection metrics for hilo.
//!
//! - [`nuscenes`]: the nuScenes detection metric exactly as nuscenes-devkit 1.2 computes it
//!   (checked against the devkit by `scripts/devkit_compare.py`);
//! - [`boxes`]: the submission and ground-truth files, validated with errors naming sample and
//!   field, and the devkit's range / empty-box filter.

pub mod boxes;
pub mod config;
pub mod error;
pub mod nuscenes;

pub use boxes::{EvalBox, GroundTruth, filter_boxes, read_ground_truth, read_submission};
pub use config::DetectionConfig;
pub use error::EvalError;
pub use nuscenes::{DetectionMetrics, evaluate};

use std::collections::BTreeMap;

/// Filters ground truth and predictions as the devkit does, then evaluates.
pub fn evaluate_files(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig) -> DetectionMetrics {
    let ego = |s: &str| gt.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
    let gt_f: BTreeMap<String, Vec<EvalBox>> =
        gt.samples.keys().map(|s| (s.clone(), filter_boxes(gt.boxes.get(s).map_or(&[][..], |v| &v[..]), ego(s), &cfg.class_range))).collect();
    let pred_f: Vec<(String, Vec<EvalBox>)> = pred.iter().map(|(s, b)| (s.clone(), filter_boxes(b, ego(s), &cfg.class_range))).collect();
    evaluate(&gt_f, &pred_f, cfg)
}
