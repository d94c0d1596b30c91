//! IoU-based evaluation: KITTI-style average precision with 40 recall points (R40) over the
//! rotated bird's-eye-view or 3-D IoU of yaw-only boxes (the geometry is hilo-core's
//! [`hilo_core::iou`], applied to the files' f64 boxes).
//!
//! Matching for the R40 AP, a documented simplification of KITTI's: predictions in descending
//! score order, each to the still unmatched ground truth of the same sample and class with the
//! highest IoU at or above the threshold; no difficulty levels or don't-care regions.

use crate::boxes::EvalBox;
use hilo_core::iou::YawBox;
use std::collections::BTreeMap;

pub use hilo_core::iou::convex_intersection_area;

/// The box's geometry in f64, exactly as the file gives it (nuScenes size is width, length,
/// height; length along the heading).
pub fn yaw_box(b: &EvalBox) -> YawBox {
    YawBox { center: b.translation, length_m: b.size[1], width_m: b.size[0], height_m: b.size[2], yaw: b.yaw() }
}

/// Footprint corners (counter-clockwise) of a box.
pub fn footprint(b: &EvalBox) -> [[f64; 2]; 4] {
    yaw_box(b).footprint()
}

/// Rotated bird's-eye-view IoU in [0, 1] (hilo-core's, on the file's f64 geometry).
pub fn bev_iou(a: &EvalBox, b: &EvalBox) -> f64 {
    hilo_core::iou::bev_iou(&yaw_box(a), &yaw_box(b))
}

/// 3-D IoU of yaw-only boxes in [0, 1].
pub fn iou_3d(a: &EvalBox, b: &EvalBox) -> f64 {
    hilo_core::iou::iou_3d(&yaw_box(a), &yaw_box(b))
}

/// Which IoU to match with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IouKind {
    Bev,
    ThreeD,
}

/// KITTI R40 average precision of one class at one IoU threshold.
pub fn ap_r40(
    gt: &BTreeMap<String, Vec<EvalBox>>,
    pred: &[(String, Vec<EvalBox>)],
    class: &str,
    threshold: f64,
    kind: IouKind,
) -> f64 {
    let npos = gt.values().flatten().filter(|b| b.detection_name == class).count();
    if npos == 0 {
        return f64::NAN;
    }
    let mut list: Vec<&EvalBox> =
        pred.iter().flat_map(|(_, v)| v.iter()).filter(|b| b.detection_name == class).collect();
    list.sort_by(|a, b| b.detection_score.total_cmp(&a.detection_score));
    let mut taken: BTreeMap<&str, Vec<bool>> = gt.iter().map(|(k, v)| (k.as_str(), vec![false; v.len()])).collect();
    let (mut tp, mut fp) = (0.0, 0.0);
    let mut curve = Vec::with_capacity(list.len());
    for p in list {
        let boxes = gt.get(&p.sample_token);
        let mut best = (threshold, None);
        if let Some(boxes) = boxes {
            for (i, g) in boxes.iter().enumerate() {
                if g.detection_name != class || taken[p.sample_token.as_str()][i] {
                    continue;
                }
                let iou = match kind {
                    IouKind::Bev => bev_iou(g, p),
                    IouKind::ThreeD => iou_3d(g, p),
                };
                if iou >= best.0 {
                    best = (iou, Some(i));
                }
            }
        }
        match best.1 {
            Some(i) => {
                if let Some(t) = taken.get_mut(p.sample_token.as_str()) {
                    t[i] = true;
                }
                tp += 1.0;
            }
            None => fp += 1.0,
        }
        curve.push((tp / npos as f64, tp / (tp + fp)));
    }
    // Interpolated precision at recall r: the best precision at any recall >= r.
    let mut best_from = vec![0.0f64; curve.len() + 1];
    for i in (0..curve.len()).rev() {
        best_from[i] = best_from[i + 1].max(curve[i].1);
    }
    (1..=40)
        .map(|k| {
            let r = k as f64 / 40.0;
            let i = curve.partition_point(|c| c.0 < r - 1e-12);
            best_from[i]
        })
        .sum::<f64>()
        / 40.0
}
