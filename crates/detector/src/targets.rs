//! Training targets on the head's grid, built on the host.

use crate::data::GtBox;
use crate::grid::BevGrid;
use crate::modules::REG_CHANNELS;
pub use hilo_fusion::config::{Assignment, VelocityTarget};

/// Targets of a batch: class map (B, K, H, W), regression (B, 10, H, W), positive mask
/// (B, 1, H, W), the mask of positives whose velocity is known (B, 1, H, W), all row-major,
/// and the number of positives, in all and per class.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Targets {
    pub cls: Vec<f32>,
    pub reg: Vec<f32>,
    pub mask: Vec<f32>,
    /// 1 at a positive cell whose box's velocity is known, else 0: the velocity channels'
    /// loss is masked by it (an unknown velocity is not trained as zero).
    pub vel_mask: Vec<f32>,
    /// Under [`VelocityTarget::Footprint`] (empty otherwise): each cell's share of its box's
    /// velocity loss (1 / the box's footprint cells; 0 where the box's velocity is unknown or
    /// no box covers the cell), and the class of that box (−1 where none).
    pub vel_weight: Vec<f32>,
    pub vel_class: Vec<f32>,
    pub num_pos: f32,
    /// Positives per class (their sum is `num_pos`).
    pub pos_per_class: Vec<f32>,
    pub size: usize,
}

impl Targets {
    /// The targets at sparse head sites (flat cells `b · n² + row · n + col` of the head's
    /// grid): class `(N, K)`, regression `(N, 10)`, mask `(N, 1)`, row-major, as a sparse head
    /// outputs them. `num_pos` still counts every positive, so a centre off the sites counts as
    /// a miss rather than vanishing from the normalisation.
    pub fn at_sites(&self, sites: &[u32], classes: usize) -> Targets {
        let hw = self.size * self.size;
        let mut t = Targets {
            cls: Vec::with_capacity(sites.len() * classes),
            reg: Vec::with_capacity(sites.len() * REG_CHANNELS),
            mask: Vec::with_capacity(sites.len()),
            vel_mask: Vec::with_capacity(sites.len()),
            vel_weight: Vec::new(),
            vel_class: Vec::new(),
            num_pos: self.num_pos,
            pos_per_class: self.pos_per_class.clone(),
            size: self.size,
        };
        for &s in sites {
            let (b, rc) = (s as usize / hw, s as usize % hw);
            for k in 0..classes {
                t.cls.push(self.cls[(b * classes + k) * hw + rc]);
            }
            for ch in 0..REG_CHANNELS {
                t.reg.push(self.reg[(b * REG_CHANNELS + ch) * hw + rc]);
            }
            t.mask.push(self.mask[b * hw + rc]);
            t.vel_mask.push(self.vel_mask[b * hw + rc]);
            if !self.vel_weight.is_empty() {
                t.vel_weight.push(self.vel_weight[b * hw + rc]);
                t.vel_class.push(self.vel_class[b * hw + rc]);
            }
        }
        t
    }

    /// Under [`VelocityTarget::Footprint`], each cell's weight in the velocity loss for
    /// [`crate::loss::per_class_mean`]'s normalisation: its share of its box times the box
    /// class's `1 / (K · max(1, n_k))`.
    pub fn per_class_velocity_weights(&self, classes: usize) -> Vec<f32> {
        let w = crate::loss::class_weights(&self.pos_per_class, classes);
        self.vel_weight
            .iter()
            .zip(&self.vel_class)
            .map(|(share, k)| if *k >= 0.0 { share * w.get(*k as usize).copied().unwrap_or(0.0) } else { 0.0 })
            .collect()
    }

    /// The regression's weight at each cell of the mask for [`crate::loss::per_class_mean`]'s
    /// normalisation: a positive cell weighs its class's `1 / (K · max(1, n_k))` (its class: the
    /// one whose map is 1 there), other cells 0. `dense`: the maps are `(B, K, H, W)`, else
    /// `(N, K)` at sites.
    pub fn per_class_site_weights(&self, classes: usize, dense: bool) -> Vec<f32> {
        let w = crate::loss::class_weights(&self.pos_per_class, classes);
        let hw = self.size * self.size;
        let fallback = 1.0 / (classes as f32 * self.num_pos.max(1.0));
        (0..self.mask.len())
            .map(|i| {
                if self.mask[i] <= 0.0 {
                    return 0.0;
                }
                let at = |k: usize| if dense { (i / hw * classes + k) * hw + i % hw } else { i * classes + k };
                (0..classes).find(|&k| self.cls[at(k)] >= 0.999).map_or(fallback, |k| w[k])
            })
            .collect()
    }
}

/// CenterNet's Gaussian radius for a box of `l × w` cells at overlap `min_overlap`.
pub fn gaussian_radius(l: f32, w: f32, min_overlap: f32) -> f32 {
    let (a1, b1, c1) = (1.0, l + w, w * l * (1.0 - min_overlap) / (1.0 + min_overlap));
    let r1 = (b1 + (b1 * b1 - 4.0 * a1 * c1).max(0.0).sqrt()) / 2.0;
    let (a2, b2, c2) = (4.0, 2.0 * (l + w), (1.0 - min_overlap) * w * l);
    let r2 = (b2 + (b2 * b2 - 4.0 * a2 * c2).max(0.0).sqrt()) / 2.0;
    let (a3, b3, c3) = (4.0 * min_overlap, -2.0 * min_overlap * (l + w), (min_overlap - 1.0) * w * l);
    let r3 = (b3 + (b3 * b3 - 4.0 * a3 * c3).max(0.0).sqrt()) / 2.0;
    r1.min(r2).min(r3)
}

/// The head cells (row, column, squared distance of the cell centre from the box centre, in
/// cells) whose centre lies in the box's footprint, in row-major order; the centre cell alone
/// when none does (a box smaller than a cell). `u, v`: the box centre in cells.
fn footprint(g: &GtBox, grid: &BevGrid, cell: f32, n: usize, (u, v): (f32, f32)) -> Vec<(usize, usize, f32)> {
    let (ci, ri) = (u as usize, v as usize);
    let (cy, sy) = (g.yaw.cos(), g.yaw.sin());
    let reach = (0.5 * (g.wlh[0].hypot(g.wlh[1])) / cell).ceil() as i64 + 1;
    let mut cells = Vec::new();
    for dr in -reach..=reach {
        for dc in -reach..=reach {
            let (rr, cc) = (ri as i64 + dr, ci as i64 + dc);
            if rr < 0 || cc < 0 || rr >= n as i64 || cc >= n as i64 {
                continue;
            }
            let (x, y) = (
                (cc as f32 + 0.5) * cell - grid.half_extent_m - g.center[0],
                (rr as f32 + 0.5) * cell - grid.half_extent_m - g.center[1],
            );
            let (along, across) = (x * cy + y * sy, -x * sy + y * cy);
            if along.abs() <= 0.5 * g.wlh[1] && across.abs() <= 0.5 * g.wlh[0] {
                let (du, dv) = (cc as f32 + 0.5 - u, rr as f32 + 0.5 - v);
                cells.push((rr as usize, cc as usize, du * du + dv * dv));
            }
        }
    }
    if cells.is_empty() {
        let (du, dv) = (ci as f32 + 0.5 - u, ri as f32 + 0.5 - v);
        cells.push((ri, ci, du * du + dv * dv));
    }
    cells
}

/// The targets of a batch of frames on the head's grid (`out_stride` cells of the BEV grid per
/// head cell), with velocity supervised where `velocity` says.
pub fn build(
    grid: &BevGrid,
    out_stride: usize,
    classes: usize,
    frames: &[&[GtBox]],
    how: Assignment,
    velocity: VelocityTarget,
) -> Targets {
    let n = grid.cells() / out_stride;
    let cell = grid.cell_m * out_stride as f32;
    let hw = n * n;
    let b = frames.len();
    let mut t = Targets {
        cls: vec![0.0; b * classes * hw],
        reg: vec![0.0; b * REG_CHANNELS * hw],
        mask: vec![0.0; b * hw],
        vel_mask: vec![0.0; b * hw],
        vel_weight: Vec::new(),
        vel_class: Vec::new(),
        num_pos: 0.0,
        pos_per_class: vec![0.0; classes],
        size: n,
    };
    let footprints = velocity == VelocityTarget::Footprint;
    if footprints {
        t.vel_weight = vec![0.0; b * hw];
        t.vel_class = vec![-1.0; b * hw];
    }
    for (bi, boxes) in frames.iter().enumerate() {
        // Under `Footprint`: per cell, the squared distance to the centre of the box it learns.
        let mut nearest = if footprints { vec![f32::INFINITY; hw] } else { Vec::new() };
        for g in boxes.iter() {
            let u = (g.center[0] + grid.half_extent_m) / cell;
            let v = (g.center[1] + grid.half_extent_m) / cell;
            if !(u >= 0.0 && v >= 0.0 && u < n as f32 && v < n as f32) || g.class >= classes {
                continue;
            }
            let (ci, ri) = (u as usize, v as usize);
            let known = g.velocity.iter().all(|v| v.is_finite());
            let vel = if known { g.velocity } else { [0.0; 2] };
            let put_reg = |t: &mut Targets, r: usize, c: usize| {
                let base = bi * REG_CHANNELS * hw + r * n + c;
                let vals = [
                    u - (c as f32 + 0.5),
                    v - (r as f32 + 0.5),
                    g.center[2],
                    g.wlh[0].max(0.05).ln(),
                    g.wlh[1].max(0.05).ln(),
                    g.wlh[2].max(0.05).ln(),
                    g.yaw.sin(),
                    g.yaw.cos(),
                    vel[0],
                    vel[1],
                ];
                for (k, val) in vals.iter().enumerate() {
                    t.reg[base + k * hw] = *val;
                }
                if t.mask[bi * hw + r * n + c] == 0.0 {
                    t.num_pos += 1.0;
                    t.pos_per_class[g.class] += 1.0;
                }
                t.mask[bi * hw + r * n + c] = 1.0;
                t.vel_mask[bi * hw + r * n + c] = if known { 1.0 } else { 0.0 };
            };
            let cls_base = bi * classes * hw + g.class * hw;
            match how {
                Assignment::Center => {
                    let r = gaussian_radius(g.wlh[1] / cell, g.wlh[0] / cell, 0.1).floor().max(1.0) as i64;
                    let sigma = (2 * r + 1) as f32 / 6.0;
                    for dr in -r..=r {
                        for dc in -r..=r {
                            let (rr, cc) = (ri as i64 + dr, ci as i64 + dc);
                            if rr < 0 || cc < 0 || rr >= n as i64 || cc >= n as i64 {
                                continue;
                            }
                            let val = (-((dr * dr + dc * dc) as f32) / (2.0 * sigma * sigma)).exp();
                            let k = cls_base + rr as usize * n + cc as usize;
                            t.cls[k] = t.cls[k].max(val);
                        }
                    }
                    t.cls[cls_base + ri * n + ci] = 1.0;
                    put_reg(&mut t, ri, ci);
                }
                Assignment::Inside => {
                    for (rr, cc, _) in footprint(g, grid, cell, n, (u, v)) {
                        t.cls[cls_base + rr * n + cc] = 1.0;
                        put_reg(&mut t, rr, cc);
                    }
                }
            }
            if footprints {
                let cells = footprint(g, grid, cell, n, (u, v));
                let share = if known { 1.0 / cells.len() as f32 } else { 0.0 };
                for (rr, cc, d2) in cells {
                    let i = rr * n + cc;
                    if d2 < nearest[i] {
                        nearest[i] = d2;
                        t.vel_weight[bi * hw + i] = share;
                        t.vel_class[bi * hw + i] = g.class as f32;
                        let base = bi * REG_CHANNELS * hw + i;
                        t.reg[base + 8 * hw] = vel[0];
                        t.reg[base + 9 * hw] = vel[1];
                    }
                }
            }
        }
    }
    t
}
