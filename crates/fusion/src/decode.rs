//! From head outputs to boxes: heatmap peaks (CenterPoint) or thresholded cells with rotated
//! BEV non-maximum suppression (PointPillars).

use crate::grid::BevGrid;
use crate::targets::Assignment;

/// A detected box in the scene's local frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Det {
    pub class: usize,
    pub score: f32,
    pub center: [f32; 3],
    pub wlh: [f32; 3],
    pub yaw: f32,
    pub velocity: [f32; 2],
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DecodeConfig {
    pub score_threshold: f32,
    pub max_per_frame: usize,
    /// BEV IoU above which the weaker of two same-class boxes is suppressed (Inside only).
    pub nms_iou: f32,
}

impl Default for DecodeConfig {
    fn default() -> Self {
        DecodeConfig { score_threshold: 0.05, max_per_frame: 200, nms_iou: 0.2 }
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Rotated BEV IoU of two boxes (hilo-eval's convex clipping).
pub fn bev_iou(a: &Det, b: &Det) -> f64 {
    let e = |d: &Det| {
        hilo_eval::boxes::EvalBox::from_yaw(
            "",
            "",
            d.center.map(|v| v as f64),
            d.wlh.map(|v| v as f64),
            d.yaw as f64,
            [0.0; 2],
            0.0,
        )
    };
    hilo_eval::iou::bev_iou(&e(a), &e(b))
}

/// Decodes one frame: `cls` (K, H, W) logits and `reg` (10, H, W), row-major.
pub fn decode_frame(
    grid: &BevGrid,
    out_stride: usize,
    classes: usize,
    cls: &[f32],
    reg: &[f32],
    how: Assignment,
    cfg: &DecodeConfig,
) -> Vec<Det> {
    let n = grid.cells() / out_stride;
    let hw = n * n;
    let cell = grid.cell_m * out_stride as f32;
    let mut cands: Vec<(f32, usize, usize)> = Vec::new();
    for k in 0..classes {
        for r in 0..n {
            for c in 0..n {
                let s = sigmoid(cls[k * hw + r * n + c]);
                if s < cfg.score_threshold || !s.is_finite() {
                    continue;
                }
                if how == Assignment::Center {
                    // A peak: not below any 8-neighbour.
                    let mut peak = true;
                    for dr in -1i64..=1 {
                        for dc in -1i64..=1 {
                            let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                            if (dr, dc) != (0, 0)
                                && rr >= 0
                                && cc >= 0
                                && rr < n as i64
                                && cc < n as i64
                                && cls[k * hw + rr as usize * n + cc as usize] > cls[k * hw + r * n + c]
                            {
                                peak = false;
                            }
                        }
                    }
                    if !peak {
                        continue;
                    }
                }
                cands.push((s, k, r * n + c));
            }
        }
    }
    // Highest score first; ties by class then cell, so decoding is deterministic.
    cands.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let at = |ch: usize, cell_i: usize| reg[ch * hw + cell_i];
    let mut out: Vec<Det> = Vec::new();
    let limit = if how == Assignment::Inside { cfg.max_per_frame * 5 } else { cfg.max_per_frame };
    for &(score, k, i) in cands.iter().take(limit) {
        let (r, c) = (i / n, i % n);
        let x = (c as f32 + 0.5 + at(0, i)) * cell - grid.half_extent_m;
        let y = (r as f32 + 0.5 + at(1, i)) * cell - grid.half_extent_m;
        let wlh = [at(3, i).clamp(-3.0, 3.0).exp(), at(4, i).clamp(-3.0, 3.5).exp(), at(5, i).clamp(-3.0, 2.5).exp()];
        let d = Det {
            class: k,
            score,
            center: [x, y, at(2, i)],
            wlh,
            yaw: at(6, i).atan2(at(7, i)),
            velocity: [at(8, i), at(9, i)],
        };
        if how == Assignment::Inside && out.iter().any(|o| o.class == d.class && bev_iou(o, &d) > cfg.nms_iou as f64) {
            continue;
        }
        out.push(d);
        if out.len() >= cfg.max_per_frame {
            break;
        }
    }
    out
}

/// Late fusion's merge Ψ of a LiDAR detector's boxes `l` and a radar detector's boxes `r`:
/// same-class pairs with 3-D IoU ≥ 0.1 are matched greedily by score. A matched pair becomes one
/// box: position and size weighted by score with LiDAR counted twice (it measures shape far
/// better), the radar's velocity (Doppler support), and the noisy-OR of the scores. Unmatched
/// LiDAR boxes are kept as they are; unmatched radar boxes are kept at half their score (radar
/// alone localises coarsely, but may see what LiDAR misses).
pub fn merge_late(l: &[Det], r: &[Det], cfg: &DecodeConfig) -> Vec<Det> {
    let e = |d: &Det| {
        hilo_eval::boxes::EvalBox::from_yaw(
            "",
            "",
            d.center.map(|v| v as f64),
            d.wlh.map(|v| v as f64),
            d.yaw as f64,
            [0.0; 2],
            0.0,
        )
    };
    let mut used = vec![false; r.len()];
    let mut out = Vec::with_capacity(l.len() + r.len());
    for a in l {
        let best = r
            .iter()
            .enumerate()
            .filter(|(k, b)| !used[*k] && b.class == a.class)
            .map(|(k, b)| (k, hilo_eval::iou::iou_3d(&e(a), &e(b))))
            .filter(|(_, iou)| *iou >= 0.1)
            .max_by(|x, y| x.1.total_cmp(&y.1).then(y.0.cmp(&x.0)));
        match best {
            Some((k, _)) => {
                used[k] = true;
                let b = &r[k];
                let (wa, wb) = (2.0 * a.score, b.score);
                let mix = |x: f32, y: f32| (wa * x + wb * y) / (wa + wb).max(1e-6);
                out.push(Det {
                    class: a.class,
                    score: 1.0 - (1.0 - a.score) * (1.0 - b.score),
                    center: [
                        mix(a.center[0], b.center[0]),
                        mix(a.center[1], b.center[1]),
                        mix(a.center[2], b.center[2]),
                    ],
                    wlh: [mix(a.wlh[0], b.wlh[0]), mix(a.wlh[1], b.wlh[1]), mix(a.wlh[2], b.wlh[2])],
                    yaw: if a.score >= b.score { a.yaw } else { b.yaw },
                    velocity: b.velocity,
                });
            }
            None => out.push(*a),
        }
    }
    for (k, b) in r.iter().enumerate() {
        if !used[k] {
            out.push(Det { score: 0.5 * b.score, ..*b });
        }
    }
    out.sort_by(|x, y| y.score.total_cmp(&x.score));
    out.truncate(cfg.max_per_frame);
    out
}
