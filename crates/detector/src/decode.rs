//! From head outputs to boxes: heatmap peaks (CenterPoint) or thresholded cells with rotated
//! BEV non-maximum suppression (PointPillars), over a dense grid or sparse head sites.

use crate::grid::BevGrid;
use crate::layout::{NONE, SparseHost};
use crate::targets::Assignment;
use glam::{Vec2, Vec3};
use hilo_core::Class;
use hilo_core::{Box3, Detection};
pub use hilo_fusion::config::DecodeConfig;

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// The cells a frame's head output covers, and each one's eight neighbours: every cell of an
/// `n × n` grid (dense), or the frame's head sites (sparse; a neighbour that is not a site
/// counts as a logit of −∞).
#[derive(Debug)]
pub struct Peaks {
    n: usize,
    sparse: bool,
    /// (row, col) of each output index; empty for dense (index = row · n + col).
    cells: Vec<(usize, usize)>,
    /// Sparse: 8 neighbour indices per output (relative to `offset`), NONE where absent.
    neighbours: Vec<[u32; 8]>,
    /// First row of this frame in the batch's sparse output.
    pub offset: usize,
}

impl Peaks {
    pub fn dense(n: usize) -> Peaks {
        Peaks { n, sparse: false, cells: Vec::new(), neighbours: Vec::new(), offset: 0 }
    }

    /// Frame `b`'s head sites of a sparse batch on an `n × n` head grid.
    pub fn sparse(h: &SparseHost, b: usize, n: usize) -> Peaks {
        let hw = (n * n) as u32;
        let lo = h.head_sites.partition_point(|&s| s < b as u32 * hw);
        let hi = h.head_sites.partition_point(|&s| s < (b as u32 + 1) * hw);
        let cells = h.head_sites[lo..hi].iter().map(|&s| ((s % hw) as usize / n, (s % hw) as usize % n)).collect();
        let neighbours = (lo..hi)
            .map(|i| {
                let r = &h.head_subm[i * 9..i * 9 + 9];
                let mut out = [NONE; 8];
                for (o, &x) in out.iter_mut().zip(r.iter().take(4).chain(r.iter().skip(5))) {
                    *o = if x == NONE { NONE } else { x - lo as u32 };
                }
                out
            })
            .collect();
        Peaks { n, sparse: true, cells, neighbours, offset: lo }
    }

    fn len(&self) -> usize {
        if self.sparse { self.cells.len() } else { self.n * self.n }
    }

    fn cell(&self, i: usize) -> (usize, usize) {
        if self.sparse { self.cells[i] } else { (i / self.n, i % self.n) }
    }

    /// Whether output `i` is not below any of its neighbours for class `k`.
    fn is_peak(&self, i: usize, k: usize, logit: &impl Fn(usize, usize) -> f32) -> bool {
        let v = logit(k, i);
        if !self.sparse {
            let (r, c) = (i / self.n, i % self.n);
            for dr in -1i64..=1 {
                for dc in -1i64..=1 {
                    let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                    if (dr, dc) != (0, 0)
                        && rr >= 0
                        && cc >= 0
                        && rr < self.n as i64
                        && cc < self.n as i64
                        && logit(k, rr as usize * self.n + cc as usize) > v
                    {
                        return false;
                    }
                }
            }
            true
        } else {
            self.neighbours[i].iter().all(|&j| j == NONE || logit(k, j as usize) <= v)
        }
    }
}

/// Decodes one frame: `logit(k, i)` and `reg(channel, i)` at output `i` of `peaks`.
#[allow(clippy::too_many_arguments)]
pub fn decode(
    grid: &BevGrid,
    out_stride: usize,
    peaks: &Peaks,
    classes: usize,
    logit: impl Fn(usize, usize) -> f32,
    reg: impl Fn(usize, usize) -> f32,
    how: Assignment,
    cfg: &DecodeConfig,
) -> Vec<Detection> {
    let cell = grid.cell_m * out_stride as f32;
    let mut cands: Vec<(f32, usize, usize)> = Vec::new();
    for k in 0..classes {
        for i in 0..peaks.len() {
            let s = sigmoid(logit(k, i));
            if s < cfg.score_threshold || !s.is_finite() {
                continue;
            }
            if how == Assignment::Center && !peaks.is_peak(i, k, &logit) {
                continue;
            }
            cands.push((s, k, i));
        }
    }
    // Highest score first; ties by class then cell, so decoding is deterministic.
    cands.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(peaks.cell(a.2).cmp(&peaks.cell(b.2))));
    let mut out: Vec<Detection> = Vec::new();
    let limit = if how == Assignment::Inside { cfg.max_per_frame * 5 } else { cfg.max_per_frame };
    for &(score, k, i) in cands.iter().take(limit) {
        let (r, c) = peaks.cell(i);
        let x = (c as f32 + 0.5 + reg(0, i)) * cell - grid.half_extent_m;
        let y = (r as f32 + 0.5 + reg(1, i)) * cell - grid.half_extent_m;
        let (w, l, h) =
            (reg(3, i).clamp(-3.0, 3.0).exp(), reg(4, i).clamp(-3.0, 3.5).exp(), reg(5, i).clamp(-3.0, 2.5).exp());
        let d = Detection {
            box3: Box3::new(Vec3::new(x, y, reg(2, i)), l, w, h, reg(6, i).atan2(reg(7, i))),
            class: Class::ALL[k.min(Class::ALL.len() - 1)],
            score,
            velocity_mps: Vec2::new(reg(8, i), reg(9, i)),
        };
        if how == Assignment::Inside
            && out.iter().any(|o| o.class == d.class && o.box3.bev_iou(&d.box3) > cfg.nms_iou as f64)
        {
            continue;
        }
        out.push(d);
        if out.len() >= cfg.max_per_frame {
            break;
        }
    }
    out
}
