//! How a roadside LiDAR's static background is learned and applied: the settings a detector
//! names (the model itself, learned from a dataset, is `hilo_dataset::background`).

use serde::{Deserialize, Serialize};

/// How the background is learned and applied.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundConfig {
    /// Width of an azimuth bin, degrees: every LiDAR's resolution should be a whole multiple.
    pub azimuth_bin_deg: f32,
    /// Training frames the model is learned from, sampled evenly over the split.
    pub frames: usize,
    /// Quantile of a cell's returned ranges taken as its background.
    pub quantile: f32,
    /// A cell returning in fewer than this share of the frames has no background.
    pub min_return_share: f32,
    /// A point within `margin_m + margin_rel · range` of the background is background.
    pub margin_m: f32,
    pub margin_rel: f32,
    /// Returns nearer than this to their sensor are not learned from, m (0: all are): fog's
    /// echo in a sensor's sky cells would otherwise become their background and hide every
    /// road user beyond it. A detector sets it to its `input.lidar_min_range_m`.
    #[serde(skip_serializing_if = "is_zero")]
    pub min_range_m: f32,
}

fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

impl Default for BackgroundConfig {
    fn default() -> Self {
        BackgroundConfig {
            azimuth_bin_deg: 0.05,
            frames: 120,
            quantile: 0.9,
            min_return_share: 0.05,
            margin_m: 0.15,
            margin_rel: 0.005,
            min_range_m: 0.0,
        }
    }
}

impl crate::valid::Check for BackgroundConfig {
    type Error = crate::FieldError;

    fn check(&self) -> Result<(), crate::FieldError> {
        self.validate()
    }
}

impl BackgroundConfig {
    pub fn validate(&self) -> Result<(), crate::FieldError> {
        let bad = |f: &str, v: String, why: &str| Err(crate::FieldError::new(format!("background.{f}"), v, why));
        if !(self.azimuth_bin_deg > 0.0 && self.azimuth_bin_deg <= 10.0) {
            return bad("azimuth_bin_deg", self.azimuth_bin_deg.to_string(), "must be in (0, 10]");
        }
        if self.frames == 0 {
            return bad("frames", "0".into(), "at least one frame is needed");
        }
        if !(self.quantile > 0.0 && self.quantile <= 1.0) {
            return bad("quantile", self.quantile.to_string(), "must be in (0, 1]");
        }
        if !(0.0..=1.0).contains(&self.min_return_share) {
            return bad("min_return_share", self.min_return_share.to_string(), "must be in [0, 1]");
        }
        if !(self.min_range_m >= 0.0 && self.min_range_m <= 20.0) {
            return bad("min_range_m", self.min_range_m.to_string(), "must be in [0, 20] m");
        }
        if !(self.margin_m >= 0.0 && self.margin_rel >= 0.0 && self.margin_m.is_finite() && self.margin_rel < 1.0) {
            return bad("margin_m / margin_rel", format!("{} / {}", self.margin_m, self.margin_rel), "must be >= 0");
        }
        Ok(())
    }

    /// Azimuth bins of a revolution.
    pub fn bins(&self) -> usize {
        (360.0 / self.azimuth_bin_deg).round().max(1.0) as usize
    }
}
