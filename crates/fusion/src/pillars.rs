//! Pillars: points grouped by bird's-eye-view cell and decorated as PointPillars does, the
//! input every pillar encoder reads.

use crate::grid::BevGrid;
use rand::{Rng, SeedableRng};

/// Pillars of one modality for a batch: decorated point features, a validity mask, and the
/// flat BEV cell index (`b · H · W + row · W + col`) of each pillar.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pillars {
    pub features: Vec<f32>,
    pub mask: Vec<f32>,
    pub index: Vec<u32>,
    /// Decorated features per point.
    pub width: usize,
    pub points_per_pillar: usize,
    /// Points left out because their pillar was full, and the pillars left out because the
    /// frame had more than `max_pillars` (their points are not counted in `dropped_points`).
    pub dropped_points: usize,
    pub dropped_pillars: usize,
}

impl Pillars {
    pub fn count(&self) -> usize {
        self.index.len()
    }
}

/// What pillarisation adds to every point: its offsets from its pillar's mean (x, y, z) and
/// from its pillar's centre (x, y), as PointPillars decorates.
pub const PILLAR_DECORATIONS: usize = 5;

/// Groups points into pillars and decorates each point with its offsets from the pillar's mean
/// and from the pillar's centre (PointPillars). `raw` features come first.
///
/// Above the caps, what is kept is a uniform sample drawn with `seed` (and the frame's position
/// in the batch), not the first cells or points: a frame over `max_pillars` keeps pillars from
/// all of its area, and a full pillar keeps points of every sensor that hit it in proportion.
/// Points are sampled by reservoir in file order, pillars by a seeded shuffle; pillars are then
/// written in cell order. The same seed gives the same pillars.
pub fn pillarize<const F: usize>(grid: &BevGrid, frames: &[&[[f32; F]]], seed: u64) -> Pillars {
    let n = grid.cells();
    let npp = grid.max_points_per_pillar;
    let width = F + PILLAR_DECORATIONS;
    let mut out = Pillars { width, points_per_pillar: npp, ..Pillars::default() };
    for (b, pts) in frames.iter().enumerate() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ (b as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        // Cell → (points seen, reservoir of at most npp point indices).
        let mut cells: std::collections::BTreeMap<usize, (usize, Vec<usize>)> = std::collections::BTreeMap::new();
        for (k, p) in pts.iter().enumerate() {
            if !(p[2] >= grid.z_min_m && p[2] <= grid.z_max_m) {
                continue;
            }
            if let Some((c, r)) = grid.cell_of(p[0], p[1]) {
                let (seen, v) = cells.entry(r * n + c).or_default();
                *seen += 1;
                if v.len() < npp {
                    v.push(k);
                } else {
                    let j = rng.random_range(0..*seen);
                    if j < npp {
                        v[j] = k;
                    }
                }
            }
        }
        let mut chosen: Vec<(usize, (usize, Vec<usize>))> = cells.into_iter().collect();
        if chosen.len() > grid.max_pillars {
            out.dropped_pillars += chosen.len() - grid.max_pillars;
            // Partial Fisher–Yates: a uniform subset, then back to cell order.
            for i in 0..grid.max_pillars {
                let j = rng.random_range(i..chosen.len());
                chosen.swap(i, j);
            }
            chosen.truncate(grid.max_pillars);
            chosen.sort_by_key(|c| c.0);
        }
        for (cell, (seen, mut members)) in chosen {
            out.dropped_points += seen - members.len();
            members.sort_unstable();
            let (cx, cy) = grid.center(cell % n, cell / n);
            let m = members.len() as f32;
            let mean = members
                .iter()
                .fold([0.0f32; 3], |a, &k| [a[0] + pts[k][0] / m, a[1] + pts[k][1] / m, a[2] + pts[k][2] / m]);
            for slot in 0..npp {
                match members.get(slot) {
                    Some(&k) => {
                        let p = &pts[k];
                        out.features.extend_from_slice(p);
                        out.features.extend_from_slice(&[
                            p[0] - mean[0],
                            p[1] - mean[1],
                            p[2] - mean[2],
                            p[0] - cx,
                            p[1] - cy,
                        ]);
                        out.mask.push(1.0);
                    }
                    None => {
                        out.features.extend(std::iter::repeat_n(0.0, width));
                        out.mask.push(0.0);
                    }
                }
            }
            out.index.push((b * n * n + cell) as u32);
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn grid() -> BevGrid {
        BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 5, max_points_per_pillar: 10, ..BevGrid::default() }
    }

    /// Per-cell oracle: a point's cell by direct arithmetic, counted in a plain map.
    fn oracle(g: &BevGrid, pts: &[[f32; 4]]) -> std::collections::BTreeMap<usize, usize> {
        let n = g.cells();
        let mut m = std::collections::BTreeMap::new();
        for p in pts {
            let (c, r) = (((p[0] + g.half_extent_m) / g.cell_m).floor(), ((p[1] + g.half_extent_m) / g.cell_m).floor());
            if c >= 0.0 && r >= 0.0 && (c as usize) < n && (r as usize) < n && p[2] >= g.z_min_m && p[2] <= g.z_max_m {
                *m.entry(r as usize * n + c as usize).or_insert(0) += 1;
            }
        }
        m
    }

    #[test]
    fn pillars_below_the_caps_keep_every_point_and_above_them_count_what_they_drop() {
        let g = grid();
        // Four cells: 3, 10 (exactly the cap), 11 and 25 points.
        let mut pts = Vec::new();
        for (cell_x, count) in [(-10.0f32, 3), (-6.0, 10), (2.0, 11), (6.0, 25)] {
            for k in 0..count {
                pts.push([cell_x + 0.01 * k as f32, 1.0, 0.2, k as f32]);
            }
        }
        let o = oracle(&g, &pts);
        let p = pillarize(&g, &[&pts], 3);
        assert_eq!(p.count(), o.len());
        assert_eq!(p.dropped_pillars, 0);
        assert_eq!(p.dropped_points, (11 - 10) + (25 - 10));
        // Every cell at or below the cap keeps all its points; full ones keep exactly the cap.
        for (i, (cell, want)) in o.iter().enumerate() {
            assert_eq!(p.index[i] as usize, *cell);
            let kept = p.mask[i * 10..(i + 1) * 10].iter().filter(|m| **m > 0.5).count();
            assert_eq!(kept, (*want).min(10), "cell {cell}");
        }
        // Deterministic by seed; another seed samples the full cells differently.
        assert_eq!(p, pillarize(&g, &[&pts], 3));
        assert_ne!(p.features, pillarize(&g, &[&pts], 4).features);
    }

    #[test]
    fn a_full_pillar_keeps_points_of_both_lidars_and_a_full_frame_keeps_pillars_everywhere() {
        let g = grid();
        // One cell hit by 40 points of LIDAR_0 (intensity 0) listed first, then 40 of LIDAR_1 (1).
        let pts: Vec<[f32; 4]> =
            (0..80).map(|k| [0.1 + 0.001 * k as f32, 0.1, 0.5, if k < 40 { 0.0 } else { 1.0 }]).collect();
        for seed in 0..20 {
            let p = pillarize(&g, &[&pts], seed);
            let second: usize = (0..10).filter(|s| p.features[s * 9 + 3] > 0.5).count();
            assert!(second > 0 && second < 10, "seed {seed}: {second} of 10 points from the second LiDAR");
            assert_eq!(p.dropped_points, 70);
        }
        // 12 cells along x (cap 5): the kept pillars are not just the first ones in row order.
        let row: Vec<[f32; 4]> = (0..12).map(|k| [-12.0 + 2.0 * k as f32, 0.5, 0.0, 0.0]).collect();
        let mut reach = 0usize;
        for seed in 0..10 {
            let p = pillarize(&g, &[&row], seed);
            assert_eq!((p.count(), p.dropped_pillars), (5, 7));
            assert!(p.index.windows(2).all(|w| w[0] < w[1]), "pillars in cell order");
            reach = reach.max(*p.index.last().unwrap() as usize % g.cells());
        }
        assert!(reach > g.cells() / 2, "pillars from the +x half are kept too");
    }
}
