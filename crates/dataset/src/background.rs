//! Static-background removal for roadside LiDAR.
//!
//! A roadside sensor does not move, so each of its beams, at each azimuth, sees the same static
//! surface frame after frame (the road, a curb, a wall), and a road user is whatever returns
//! closer than that. Most of a roadside frame is that static surface (on the default dataset
//! about nine points in ten), so a detector that is shown only the rest spends its computation,
//! and its learning, on what moves.
//!
//! The model is learned from the training split alone, per LiDAR channel and per cell
//! (ring, azimuth bin): from `frames` frames sampled evenly over the split, the `quantile` of
//! the ranges returned in the cell, one per frame: its farthest (a dual-return sensor's second
//! echo, or fog's echo in front of the surface, is not the background, and counting it would
//! lower the quantile). A road user only ever shortens a cell's range, so a high
//! quantile is the static surface as long as it is seen in more than `1 − quantile` of the
//! frames (a queue that covers a lane half of the time does not hide it). A cell that returns in
//! fewer than `min_return_share` of the frames has no background (the sky, or ground beyond the
//! sensor's range): every return there is kept. A point is background when its range is at
//! least the cell's background range less `margin_m + margin_rel · range`.
//!
//! Bins are centred on multiples of `azimuth_bin_deg` (rounded, not floored): a LiDAR whose
//! columns lie on multiples of its resolution puts each column in one bin whatever the float
//! rounding, provided the resolution is a whole multiple of the bin (the default 0.05° divides
//! every resolution of the catalog: 0.35° and 0.4°). Most bins then hold no column; the model
//! is stored with its occupied cells only. Left out: azimuth jitter between revolutions (a real
//! sensor's columns drift, which a bin then averages), and adapting the model over time
//! (weather, parked vehicles that stay for hours).

use crate::error::DatasetError;
use crate::reader::Dataset;
use hilo_core::{LidarPoint, Valid};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

pub use hilo_core::background::BackgroundConfig;

/// The background of one LiDAR channel: a range per (ring, azimuth bin), 0 where none.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(into = "SparseChannel", try_from = "SparseChannel")]
pub struct ChannelBackground {
    pub rings: usize,
    pub bins: usize,
    /// `range_m[ring * bins + bin]`, metres; 0: no background (every return is kept).
    pub range_m: Vec<f32>,
}

/// The stored form of a channel: its cells with a background only, as (ring · bins + bin, m).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SparseChannel {
    rings: usize,
    bins: usize,
    cells: Vec<(u32, f32)>,
}

impl From<ChannelBackground> for SparseChannel {
    fn from(c: ChannelBackground) -> Self {
        let cells = c.range_m.iter().enumerate().filter(|(_, r)| **r > 0.0).map(|(i, r)| (i as u32, *r)).collect();
        SparseChannel { rings: c.rings, bins: c.bins, cells }
    }
}

impl TryFrom<SparseChannel> for ChannelBackground {
    type Error = String;
    fn try_from(s: SparseChannel) -> Result<Self, String> {
        let n = s
            .rings
            .checked_mul(s.bins)
            .filter(|n| *n <= 1 << 28)
            .ok_or_else(|| format!("{} rings x {} bins is too large", s.rings, s.bins))?;
        let mut range_m = vec![0.0; n];
        for (i, r) in s.cells {
            if !(r.is_finite() && r > 0.0) {
                return Err(format!("cell {i}: range {r} m is not a positive number"));
            }
            *range_m.get_mut(i as usize).ok_or_else(|| format!("cell {i} is outside {n} cells"))? = r;
        }
        Ok(ChannelBackground { rings: s.rings, bins: s.bins, range_m })
    }
}

/// Background of every LiDAR channel of a dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BackgroundModel {
    pub config: BackgroundConfig,
    /// By channel name (e.g. "LIDAR_0").
    pub channels: BTreeMap<String, ChannelBackground>,
    /// Frames the model was learned from.
    pub frames: usize,
}

/// Cell of a point in the sensor frame: (ring, bin) and range.
fn cell(p: &LidarPoint, bin_deg: f32, bins: usize) -> (usize, usize, f32) {
    let az = p.y.atan2(p.x).to_degrees().rem_euclid(360.0);
    let bin = ((az / bin_deg).round() as usize) % bins;
    (p.ring as usize, bin, (p.x * p.x + p.y * p.y + p.z * p.z).sqrt())
}

impl ChannelBackground {
    /// Learns one channel from frames of its points (sensor frame).
    pub fn learn(frames: &[&[LidarPoint]], cfg: &BackgroundConfig) -> ChannelBackground {
        let bins = cfg.bins();
        let rings = frames.iter().flat_map(|f| f.iter()).map(|p| p.ring as usize + 1).max().unwrap_or(0);
        // Every return as (cell, frame, range), sorted; then each cell's farthest return of each
        // frame (a second return, or fog's echo in front of the surface, is not the background
        // and must not dilute the quantile), sorted by range: each cell's ranges are one run.
        let mut all: Vec<(u32, u32, f32)> = frames
            .iter()
            .enumerate()
            .flat_map(|(k, f)| f.iter().map(move |p| (k, p)))
            .map(|(k, p)| {
                let (r, b, d) = cell(p, cfg.azimuth_bin_deg, bins);
                ((r * bins + b) as u32, k as u32, d)
            })
            .filter(|x| x.2 >= cfg.min_range_m)
            .collect();
        all.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.total_cmp(&b.2)));
        let mut last: Vec<(u32, f32)> =
            all.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)).filter_map(|run| run.last().map(|x| (x.0, x.2))).collect();
        last.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let need = (cfg.min_return_share * frames.len() as f32).ceil().max(1.0) as usize;
        let mut range_m = vec![0.0; rings * bins];
        for run in last.chunk_by(|a, b| a.0 == b.0) {
            if run.len() >= need {
                range_m[run[0].0 as usize] = run[(((run.len() - 1) as f32) * cfg.quantile).round() as usize].1;
            }
        }
        ChannelBackground { rings, bins, range_m }
    }

    /// The background range of a point's cell (0: none).
    pub fn range_at(&self, p: &LidarPoint, cfg: &BackgroundConfig) -> f32 {
        let (r, b, _) = cell(p, cfg.azimuth_bin_deg, self.bins);
        if r >= self.rings { 0.0 } else { self.range_m[r * self.bins + b] }
    }

    /// Whether a point (sensor frame) lies on the background.
    pub fn is_background(&self, p: &LidarPoint, cfg: &BackgroundConfig) -> bool {
        let (r, b, d) = cell(p, cfg.azimuth_bin_deg, self.bins);
        if r >= self.rings {
            return false;
        }
        let bg = self.range_m[r * self.bins + b];
        bg > 0.0 && d >= bg - cfg.margin_m - cfg.margin_rel * d
    }
}

impl BackgroundModel {
    /// Learns the model from in-memory frames: per channel, its point clouds (sensor frame).
    pub fn learn_from(
        frames: &BTreeMap<String, Vec<Vec<LidarPoint>>>,
        cfg: &Valid<BackgroundConfig>,
    ) -> BackgroundModel {
        Self::fit(frames, cfg)
    }

    /// The model of checked settings.
    fn fit(frames: &BTreeMap<String, Vec<Vec<LidarPoint>>>, cfg: &BackgroundConfig) -> BackgroundModel {
        let channels = frames
            .iter()
            .map(|(ch, clouds)| {
                let refs: Vec<&[LidarPoint]> = clouds.iter().map(Vec::as_slice).collect();
                (ch.clone(), ChannelBackground::learn(&refs, cfg))
            })
            .collect();
        let n = frames.values().map(Vec::len).max().unwrap_or(0);
        BackgroundModel { config: cfg.clone(), channels, frames: n }
    }

    /// Learns the model from `cfg.frames` samples spread evenly over the scenes of `split`.
    pub fn learn(ds: &Dataset, split: &str, cfg: &Valid<BackgroundConfig>) -> Result<BackgroundModel, DatasetError> {
        let t = &ds.tables;
        let scenes: std::collections::HashSet<String> = ds.split(split)?.into_iter().collect();
        let scene_tokens: std::collections::HashSet<&str> =
            t.scene.iter().filter(|s| scenes.contains(&s.name)).map(|s| s.token.as_str()).collect();
        let mut samples: Vec<&crate::tables::Sample> =
            t.sample.iter().filter(|s| scene_tokens.contains(s.scene_token.as_str())).collect();
        samples.sort_by(|a, b| (a.scene_token.as_str(), a.timestamp).cmp(&(b.scene_token.as_str(), b.timestamp)));
        if samples.is_empty() {
            return Err(DatasetError::Writer {
                what: format!("split {split:?}"),
                reason: "has no samples to learn a background from".into(),
            });
        }
        let n = cfg.frames.min(samples.len());
        let picked: std::collections::HashSet<&str> =
            (0..n).map(|k| samples[k * samples.len() / n].token.as_str()).collect();
        let channel_of: BTreeMap<&str, &str> = t
            .calibrated_sensor
            .iter()
            .filter_map(|c| {
                t.sensor
                    .iter()
                    .find(|s| s.token == c.sensor_token && s.modality == "lidar")
                    .map(|s| (c.token.as_str(), s.channel.as_str()))
            })
            .collect();
        let mut frames: BTreeMap<String, Vec<Vec<LidarPoint>>> = BTreeMap::new();
        let mut sds: Vec<&crate::tables::SampleData> =
            t.sample_data.iter().filter(|sd| sd.is_key_frame && picked.contains(sd.sample_token.as_str())).collect();
        sds.sort_by(|a, b| a.filename.cmp(&b.filename));
        for sd in sds {
            if let Some(ch) = channel_of.get(sd.calibrated_sensor_token.as_str()) {
                frames.entry((*ch).to_owned()).or_default().push(ds.lidar_points(sd)?);
            }
        }
        Ok(Self::fit(&frames, cfg))
    }

    /// The points of `channel` that are not background (all of them for an unknown channel).
    pub fn foreground(&self, channel: &str, points: Vec<LidarPoint>) -> Vec<LidarPoint> {
        match self.channels.get(channel) {
            Some(c) => points.into_iter().filter(|p| !c.is_background(p, &self.config)).collect(),
            None => points,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn pt(ring: u16, az_deg: f32, range: f32) -> LidarPoint {
        let a = az_deg.to_radians();
        LidarPoint { x: range * a.cos(), y: range * a.sin(), z: 0.0, intensity: 0.5, ring, time_s: 0.0 }
    }

    #[test]
    fn a_cell_hidden_most_of_the_time_keeps_its_background_and_the_sky_has_none() {
        let cfg = BackgroundConfig { frames: 20, ..BackgroundConfig::default() };
        // Ring 0 at 10°: the wall at 30 m, hidden by a car at 12 m in 14 of 20 frames.
        // Ring 1 at 10°: a return in one frame in 20 (a passing truck), below the share.
        let frames: Vec<Vec<LidarPoint>> = (0..20)
            .map(|k| {
                let mut f = vec![pt(0, 10.0, if k % 10 < 7 { 12.0 } else { 30.0 + 0.01 * k as f32 })];
                if k == 3 {
                    f.push(pt(1, 10.0, 8.0));
                }
                f
            })
            .collect();
        let refs: Vec<&[LidarPoint]> = frames.iter().map(Vec::as_slice).collect();
        let bg = ChannelBackground::learn(&refs, &BackgroundConfig { min_return_share: 0.1, ..cfg.clone() });
        let wall = bg.range_at(&pt(0, 10.0, 1.0), &cfg);
        assert!((wall - 30.2).abs() < 0.2, "background {wall}");
        assert!(bg.is_background(&pt(0, 10.0, 30.1), &cfg) && bg.is_background(&pt(0, 10.0, 29.95), &cfg));
        assert!(!bg.is_background(&pt(0, 10.0, 12.0), &cfg), "the car is foreground");
        assert_eq!(bg.range_at(&pt(1, 10.0, 1.0), &cfg), 0.0, "one return in 20 is not a background");
        assert!(!bg.is_background(&pt(1, 10.0, 8.0), &cfg));
        // A neighbouring bin has its own background (none here).
        assert!(!bg.is_background(&pt(0, 10.4, 30.0), &cfg));
    }

    #[test]
    fn fogs_echo_neither_dilutes_a_wall_nor_becomes_the_skys_background() {
        let cfg = BackgroundConfig { frames: 20, min_return_share: 0.1, ..BackgroundConfig::default() };
        // Ring 0 at 10°: each frame a fog point at 1–3 m in front of the wall at 30 m, which a car
        // at 12 m hides in 16 of 20 frames (dual returns: the fog's echo and the last surface).
        // Ring 1 at 10°: the sky, whose beam returns fog's echo alone; a car at 15 m in frame 5.
        let fog = |k: usize| 1.0 + 0.1 * k as f32;
        let frames: Vec<Vec<LidarPoint>> = (0..20)
            .map(|k| {
                let mut f = vec![pt(0, 10.0, fog(k)), pt(0, 10.0, if k % 5 < 4 { 12.0 } else { 30.0 })];
                f.push(pt(1, 10.0, fog(k)));
                if k == 5 {
                    f.push(pt(1, 10.0, 15.0));
                }
                f
            })
            .collect();
        let refs: Vec<&[LidarPoint]> = frames.iter().map(Vec::as_slice).collect();
        // Counting every return, fog's half of them would put the 0.9 quantile at the car; one
        // return a frame, the farthest, keeps the wall.
        let bg = ChannelBackground::learn(&refs, &cfg);
        assert!((bg.range_at(&pt(0, 10.0, 1.0), &cfg) - 30.0).abs() < 1e-4);
        assert!(!bg.is_background(&pt(0, 10.0, 12.0), &cfg), "the car is foreground");
        // Without a near-range cut the sky's background is the fog's echo, and the car at 15 m
        // behind it would count as background; with the cut the sky has none.
        assert!(bg.is_background(&pt(1, 10.0, 15.0), &cfg));
        let near = BackgroundConfig { min_range_m: 4.0, ..cfg.clone() };
        let bg = ChannelBackground::learn(&refs, &near);
        assert_eq!(bg.range_at(&pt(1, 10.0, 1.0), &near), 0.0);
        assert!(!bg.is_background(&pt(1, 10.0, 15.0), &near));
        assert!((bg.range_at(&pt(0, 10.0, 1.0), &near) - 30.0).abs() < 1e-4);
    }

    #[test]
    fn columns_on_multiples_of_the_resolution_fall_in_one_bin_each() {
        let cfg = BackgroundConfig::default();
        for res in [0.35f32, 0.4] {
            let cols = (360.0 / res).round() as usize;
            let mut seen = std::collections::HashSet::new();
            for k in 0..cols {
                let a = k as f32 * res;
                let (_, b0, _) = cell(&pt(0, a, 20.0), cfg.azimuth_bin_deg, cfg.bins());
                // The same column in another frame, with range noise, lands in the same bin.
                let (_, b1, _) = cell(&pt(0, a, 20.3), cfg.azimuth_bin_deg, cfg.bins());
                assert_eq!(b0, b1);
                assert!(seen.insert(b0), "resolution {res}: column {k} shares bin {b0}");
            }
        }
    }
}
