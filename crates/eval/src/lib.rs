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

pub use boxes::{EvalBox, GroundTruth, filter_boxes, read_ground_truth, read_submission};
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

/// The metric per range bin from the sample's origin (e.g. 0–30, 30–50, 50+ m): ground truth
/// and predictions outside a bin are left out of it.
pub fn evaluate_distance_bins(
    gt: &GroundTruth,
    pred: &[(String, Vec<EvalBox>)],
    cfg: &DetectionConfig,
    edges: &[f64],
) -> Vec<(String, DetectionMetrics)> {
    let (gt_f, pred_f) = filtered(gt, pred, cfg);
    let ego = |s: &str| gt.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
    let dist = |b: &EvalBox| {
        let e = ego(&b.sample_token);
        ((b.translation[0] - e[0]).powi(2) + (b.translation[1] - e[1]).powi(2)).sqrt()
    };
    let mut bins: Vec<(f64, f64)> = edges.windows(2).map(|w| (w[0], w[1])).collect();
    if let Some(&last) = edges.last() {
        bins.push((last, f64::INFINITY));
    }
    bins.into_iter()
        .map(|(lo, hi)| {
            let keep = |v: &Vec<EvalBox>| v.iter().filter(|b| (lo..hi).contains(&dist(b))).cloned().collect::<Vec<_>>();
            let g: BTreeMap<String, Vec<EvalBox>> = gt_f.iter().map(|(k, v)| (k.clone(), keep(v))).collect();
            let p: Vec<(String, Vec<EvalBox>)> = pred_f.iter().map(|(k, v)| (k.clone(), keep(v))).collect();
            let label = if hi.is_finite() { format!("{lo:.0}-{hi:.0} m") } else { format!("{lo:.0}+ m") };
            (label, evaluate(&g, &p, cfg))
        })
        .collect()
}

/// Ground truth of the scenes of `split` in a nuScenes-layout dataset, as the devkit's `load_gt`
/// builds it: classes from categories, sizes and rotations as annotated, velocity by the
/// devkit's finite difference, points = LiDAR + radar points, the attribute if there is one.
/// Every ego pose of a roadside dataset is the origin, which is what ranges are measured from.
pub fn ground_truth_from_dataset(
    ds: &hilo_dataset::Dataset,
    split: &str,
) -> Result<GroundTruth, hilo_dataset::DatasetError> {
    let scenes: std::collections::HashSet<String> = ds.split(split)?.into_iter().collect();
    let t = &ds.tables;
    let scene_of: BTreeMap<&str, &hilo_dataset::tables::Scene> =
        t.scene.iter().map(|s| (s.token.as_str(), s)).collect();
    let mut gt = GroundTruth::default();
    for s in &t.sample {
        if let Some(sc) = scene_of.get(s.scene_token.as_str()).filter(|sc| scenes.contains(&sc.name)) {
            gt.samples.insert(s.token.clone(), boxes::SampleInfo { scene: sc.name.clone(), ego_translation: [0.0; 3] });
            gt.boxes.insert(s.token.clone(), Vec::new());
        }
    }
    let category: BTreeMap<&str, &str> = t
        .instance
        .iter()
        .filter_map(|i| {
            t.category.iter().find(|c| c.token == i.category_token).map(|c| (i.token.as_str(), c.name.as_str()))
        })
        .collect();
    let attribute: BTreeMap<&str, &str> = t.attribute.iter().map(|a| (a.token.as_str(), a.name.as_str())).collect();
    for a in &t.sample_annotation {
        let Some(list) = gt.boxes.get_mut(&a.sample_token) else { continue };
        let Some(class) =
            category.get(a.instance_token.as_str()).and_then(|c| hilo_dataset::writer::class_of_category(c))
        else {
            continue;
        };
        let v = ds.box_velocity(a);
        list.push(EvalBox {
            sample_token: a.sample_token.clone(),
            translation: a.translation,
            size: a.size,
            rotation: a.rotation,
            velocity: [v[0], v[1]],
            detection_name: class.name().to_owned(),
            detection_score: -1.0,
            attribute_name: a
                .attribute_tokens
                .first()
                .and_then(|x| attribute.get(x.as_str()))
                .map_or(String::new(), |s| (*s).to_owned()),
            num_pts: (a.num_lidar_pts + a.num_radar_pts) as i64,
        });
    }
    Ok(gt)
}
