//! Detection metrics for hilo.
//!
//! - [`nuscenes`]: the nuScenes detection metric exactly as nuscenes-devkit 1.2 computes it
//!   (checked against the devkit by `scripts/devkit_compare.py`);
//! - [`boxes`]: the submission and ground-truth files, validated with errors naming sample and
//!   field, and the devkit's range / empty-box filter.

pub mod bootstrap;
pub mod boxes;
pub mod config;
pub mod error;
pub mod iou;
pub mod nuscenes;
pub mod text;

pub use boxes::{
    EvalBox, GroundTruth, check_sample_set, filter_boxes, parse_ground_truth, parse_submission, read_ground_truth,
    read_submission,
};
pub use config::DetectionConfig;
pub use error::EvalError;
pub use nuscenes::{DetectionMetrics, evaluate};

use std::collections::BTreeMap;

/// Ground truth (every sample, possibly empty) and predictions after the devkit's filter.
pub type Filtered = (BTreeMap<String, Vec<EvalBox>>, Vec<(String, Vec<EvalBox>)>);

/// Filters ground truth and predictions as the devkit does.
pub fn filtered(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig) -> Filtered {
    let ego = |s: &str| gt.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
    let gt_f = gt
        .samples
        .keys()
        .map(|s| (s.clone(), filter_boxes(gt.boxes.get(s).map_or(&[][..], |v| &v[..]), ego(s), &cfg.class_range)))
        .collect();
    let pred_f = pred.iter().map(|(s, b)| (s.clone(), filter_boxes(b, ego(s), &cfg.class_range))).collect();
    (gt_f, pred_f)
}

/// Filters ground truth and predictions as the devkit does, then evaluates.
pub fn evaluate_files(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig) -> DetectionMetrics {
    let (gt_f, pred_f) = filtered(gt, pred, cfg);
    evaluate(&gt_f, &pred_f, cfg)
}

/// One range bin: its label, the metric of the boxes inside it, and the ground-truth boxes of
/// each evaluated class inside it.
#[derive(Clone, Debug)]
pub struct RangeBin {
    pub label: String,
    pub metrics: DetectionMetrics,
    pub gt_boxes: BTreeMap<String, usize>,
}

impl RangeBin {
    /// Mean AP over the classes with ground truth in the bin; None when it holds none. A class
    /// absent from a bin scores AP 0 for every submission there, which says nothing about the
    /// bin (pedestrians keep to the crosswalks near the centre, for one).
    pub fn mean_ap_present(&self) -> Option<f64> {
        let aps: Vec<f64> = self
            .metrics
            .mean_dist_aps
            .iter()
            .filter(|(c, _)| self.gt_boxes.get(*c).is_some_and(|n| *n > 0))
            .map(|(_, ap)| *ap)
            .collect();
        (!aps.is_empty()).then(|| aps.iter().sum::<f64>() / aps.len() as f64)
    }
}

/// The metric per range bin from the sample's origin (e.g. 0–30, 30–50 m): ground truth and
/// predictions outside a bin are left out of it. A last, open bin beyond the final edge is
/// added only while it reaches inside the farthest class range (every class is evaluated within
/// its range, at most 50 m by default, so a "50+ m" bin would always be empty).
pub fn evaluate_distance_bins(
    gt: &GroundTruth,
    pred: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
    edges: &[f64],
) -> Vec<RangeBin> {
    let (gt_f, pred_f) = filtered(gt, pred, cfg);
    let ego = |s: &str| gt.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
    let dist = |b: &EvalBox| {
        let e = ego(&b.sample_token);
        ((b.translation[0] - e[0]).powi(2) + (b.translation[1] - e[1]).powi(2)).sqrt()
    };
    let reach = cfg.class_range.values().copied().fold(0.0, f64::max);
    let mut bins: Vec<(f64, f64)> = edges.windows(2).map(|w| (w[0], w[1])).collect();
    if let Some(&last) = edges.last().filter(|&&e| e < reach) {
        bins.push((last, f64::INFINITY));
    }
    bins.into_iter()
        .map(|(lo, hi)| {
            let keep = |v: &Vec<EvalBox>| v.iter().filter(|b| (lo..hi).contains(&dist(b))).cloned().collect::<Vec<_>>();
            let g: BTreeMap<String, Vec<EvalBox>> = gt_f.iter().map(|(k, v)| (k.clone(), keep(v))).collect();
            let p: Vec<(String, Vec<EvalBox>)> = pred_f.iter().map(|(k, v)| (k.clone(), keep(v))).collect();
            let label = if hi.is_finite() { format!("{lo:.0}-{hi:.0} m") } else { format!("{lo:.0}+ m") };
            let mut gt_boxes: BTreeMap<String, usize> = cfg.class_names().into_iter().map(|c| (c, 0)).collect();
            for b in g.values().flatten() {
                if let Some(n) = gt_boxes.get_mut(&b.detection_name) {
                    *n += 1;
                }
            }
            RangeBin { label, metrics: evaluate(&g, &p, cfg), gt_boxes }
        })
        .collect()
}

/// The range bins `hilo eval` reports: 0–30 m and 30–50 m from the sample's origin.
pub const DISTANCE_EDGES_M: [f64; 3] = [0.0, 30.0, 50.0];

/// One range bin's summary, as `metrics_by_distance.json` holds it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BinMetrics {
    pub mean_ap: f64,
    pub mean_dist_aps: BTreeMap<String, f64>,
    pub nd_score: f64,
    /// Ground-truth boxes of each class in the bin (a class with none has AP 0 there).
    pub gt_boxes: BTreeMap<String, usize>,
}

/// [`evaluate_distance_bins`] at [`DISTANCE_EDGES_M`], each bin's summary by its label.
pub fn metrics_by_distance(
    gt: &GroundTruth,
    pred: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
) -> Vec<(String, BinMetrics)> {
    evaluate_distance_bins(gt, pred, cfg, &DISTANCE_EDGES_M)
        .into_iter()
        .map(|b| {
            let m = b.metrics;
            (
                b.label,
                BinMetrics {
                    mean_ap: m.mean_ap,
                    mean_dist_aps: m.mean_dist_aps,
                    nd_score: m.nd_score,
                    gt_boxes: b.gt_boxes,
                },
            )
        })
        .collect()
}

/// One class's IoU-based AP, as `metrics_iou.json` holds it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct IouAp {
    pub ap3d_r40: f64,
    pub bev_ap_r40: f64,
    pub iou_threshold: f64,
}

/// IoU-based AP per class at KITTI's R40 recall points, in the bird's-eye view and in 3-D, at
/// KITTI's thresholds: 0.7 for cars, trucks and buses, 0.5 for the rest.
pub fn iou_aps(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], cfg: &DetectionConfig) -> BTreeMap<String, IouAp> {
    let (gt_f, pred_f) = filtered(gt, pred, cfg);
    cfg.class_names()
        .into_iter()
        .map(|c| {
            let th = if ["car", "truck", "bus"].contains(&c.as_str()) { 0.7 } else { 0.5 };
            let ap = |kind| iou::ap_r40(&gt_f, &pred_f, &c, th, kind);
            let v = IouAp { ap3d_r40: ap(iou::IouKind::ThreeD), bev_ap_r40: ap(iou::IouKind::Bev), iou_threshold: th };
            (c, v)
        })
        .collect()
}
