//! IoU-based evaluation: rotated bird's-eye-view and 3-D IoU of yaw-only boxes, and KITTI-style
//! average precision with 40 recall points (R40).
//!
//! Intersection areas come from clipping one box's footprint by the other's four edge lines
//! (Sutherland–Hodgman). A crossing point is only computed between two vertices on opposite sides
//! of a line, as `t = d_p / (d_p − d_q)` with `d_p`, `d_q` of opposite signs, so `t` is always in
//! [0, 1] and near-parallel edges cannot blow it up. Identical boxes give exactly 1; boxes of zero
//! area give 0 (never NaN); IoU is clamped to [0, 1].
//!
//! Matching for the R40 AP, a documented simplification of KITTI's: predictions in descending
//! score order, each to the still unmatched ground truth of the same sample and class with the
//! highest IoU at or above the threshold; no difficulty levels or don't-care regions.

use crate::boxes::EvalBox;
use std::collections::BTreeMap;

type P = [f64; 2];

/// Footprint corners (counter-clockwise) of a box: nuScenes size is (width, length, height),
/// length along the heading.
pub fn footprint(b: &EvalBox) -> [P; 4] {
    let (s, c) = b.yaw().sin_cos();
    let (hl, hw) = (0.5 * b.size[1], 0.5 * b.size[0]);
    let (cx, cy) = (b.translation[0], b.translation[1]);
    let at = |l: f64, w: f64| [cx + l * c - w * s, cy + l * s + w * c];
    [at(hl, hw), at(-hl, hw), at(-hl, -hw), at(hl, -hw)]
}

fn area(poly: &[P]) -> f64 {
    let n = poly.len();
    if n < 3 {
        return 0.0;
    }
    0.5 * (0..n).map(|i| poly[i][0] * poly[(i + 1) % n][1] - poly[(i + 1) % n][0] * poly[i][1]).sum::<f64>()
}

/// Area of the intersection of two convex counter-clockwise polygons.
pub fn convex_intersection_area(subject: &[P], clip: &[P]) -> f64 {
    let mut out: Vec<P> = subject.to_vec();
    let m = clip.len();
    for k in 0..m {
        if out.is_empty() {
            return 0.0;
        }
        let (a, b) = (clip[k], clip[(k + 1) % m]);
        // Signed distance-like value: > 0 left of a→b (inside for a CCW polygon).
        let side = |p: P| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        let input = std::mem::take(&mut out);
        let n = input.len();
        for i in 0..n {
            let (p, q) = (input[i], input[(i + 1) % n]);
            let (dp, dq) = (side(p), side(q));
            if dp >= 0.0 {
                out.push(p);
            }
            if (dp > 0.0 && dq < 0.0) || (dp < 0.0 && dq > 0.0) {
                let t = dp / (dp - dq);
                out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
            }
        }
    }
    area(&out).max(0.0)
}

fn same_box(a: &EvalBox, b: &EvalBox) -> bool {
    a.translation == b.translation && a.size == b.size && a.rotation == b.rotation
}

/// Rotated bird's-eye-view IoU in [0, 1].
pub fn bev_iou(a: &EvalBox, b: &EvalBox) -> f64 {
    let (aa, ab) = (a.size[0] * a.size[1], b.size[0] * b.size[1]);
    if aa <= 0.0 || ab <= 0.0 {
        return 0.0;
    }
    if same_box(a, b) {
        return 1.0;
    }
    let inter = convex_intersection_area(&footprint(a), &footprint(b));
    (inter / (aa + ab - inter)).clamp(0.0, 1.0)
}

/// 3-D IoU of yaw-only boxes in [0, 1].
pub fn iou_3d(a: &EvalBox, b: &EvalBox) -> f64 {
    let (va, vb) = (a.size.iter().product::<f64>(), b.size.iter().product::<f64>());
    if va <= 0.0 || vb <= 0.0 {
        return 0.0;
    }
    if same_box(a, b) {
        return 1.0;
    }
    let (za0, za1) = (a.translation[2] - 0.5 * a.size[2], a.translation[2] + 0.5 * a.size[2]);
    let (zb0, zb1) = (b.translation[2] - 0.5 * b.size[2], b.translation[2] + 0.5 * b.size[2]);
    let dz = (za1.min(zb1) - za0.max(zb0)).max(0.0);
    let inter = convex_intersection_area(&footprint(a), &footprint(b)) * dz;
    (inter / (va + vb - inter)).clamp(0.0, 1.0)
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
