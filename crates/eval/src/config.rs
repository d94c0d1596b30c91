//! The detection evaluation settings (the devkit's `detection_cvpr_2019` with hilo's classes).

use hilo_core::FieldError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionConfig {
    /// Evaluated classes and their ranges (m from the scene origin).
    pub class_range: BTreeMap<String, f64>,
    pub dist_fcn: String,
    pub dist_ths: Vec<f64>,
    pub dist_th_tp: f64,
    pub min_recall: f64,
    pub min_precision: f64,
    pub max_boxes_per_sample: usize,
    pub mean_ap_weight: f64,
}

impl Default for DetectionConfig {
    /// The devkit's `detection_cvpr_2019` numbers; hilo's six classes with the ranges of their
    /// nearest nuScenes classes (golf carts as motorcycles: 40 m).
    fn default() -> Self {
        let class_range = [
            ("car", 50.0),
            ("truck", 50.0),
            ("bus", 50.0),
            ("motorcycle", 40.0),
            ("pedestrian", 40.0),
            ("golf_cart", 40.0),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect();
        DetectionConfig {
            class_range,
            dist_fcn: "center_distance".into(),
            dist_ths: vec![0.5, 1.0, 2.0, 4.0],
            dist_th_tp: 2.0,
            min_recall: 0.1,
            min_precision: 0.1,
            max_boxes_per_sample: 500,
            mean_ap_weight: 5.0,
        }
    }
}

impl DetectionConfig {
    /// The same settings with cyclists evaluated at nuScenes' bicycle range, 40 m, unless
    /// they set a range for `bicycle` already.
    pub fn with_cyclists(mut self) -> Self {
        self.class_range.entry(hilo_core::Class::Bicycle.name().to_owned()).or_insert(40.0);
        self
    }

    /// Refuses a configuration the metric has no meaning for, naming the field: an empty
    /// threshold list (mAP would be the mean of nothing), `min_recall` or `min_precision`
    /// outside [0, 1) (AP divides by 1 − min_precision and averages the recalls above
    /// min_recall), ranges, thresholds and the TP threshold not positive and finite (a class
    /// with range ≤ 0 would silently score 0), a distance function other than the centre
    /// distance (the only one hilo computes), no box allowed per sample.
    pub fn check(&self) -> Result<(), FieldError> {
        let bad = |field: &str, value: &dyn std::fmt::Display, reason: &str| Err(FieldError::new(field, value, reason));
        if self.class_range.is_empty() {
            return bad("class_range", &"{}", "is empty: name at least one class and its range");
        }
        if let Some((c, r)) = self.class_range.iter().find(|(_, r)| !(r.is_finite() && **r > 0.0)) {
            return bad(&format!("class_range.{c}"), r, "a range is a distance in metres, finite and > 0");
        }
        if self.dist_fcn != "center_distance" {
            return bad("dist_fcn", &format!("{:?}", self.dist_fcn), "hilo computes \"center_distance\" only");
        }
        let ths = format!("{:?}", self.dist_ths);
        if self.dist_ths.is_empty() {
            return bad("dist_ths", &ths, "give the matching thresholds (the devkit's [0.5, 1.0, 2.0, 4.0])");
        }
        let positive = |t: f64| t.is_finite() && t > 0.0;
        if let Some(t) = self.dist_ths.iter().find(|t| !positive(**t)) {
            return bad("dist_ths", &ths, &format!("holds {t}: a threshold is a distance in metres, finite and > 0"));
        }
        if !positive(self.dist_th_tp) {
            return bad("dist_th_tp", &self.dist_th_tp, "must be finite and > 0");
        }
        for (field, v) in [("min_recall", self.min_recall), ("min_precision", self.min_precision)] {
            if !(0.0..1.0).contains(&v) {
                return bad(field, &v, "must be in [0, 1)");
            }
        }
        if self.max_boxes_per_sample == 0 {
            return bad("max_boxes_per_sample", &0, "must be at least 1");
        }
        if !(self.mean_ap_weight.is_finite() && self.mean_ap_weight >= 0.0) {
            return bad("mean_ap_weight", &self.mean_ap_weight, "must be finite and ≥ 0");
        }
        Ok(())
    }

    /// Class names in the order the devkit iterates them (the order of `class_range`; serde keeps
    /// keys sorted here, and every per-class result is keyed by name, so order does not matter).
    pub fn class_names(&self) -> Vec<String> {
        self.class_range.keys().cloned().collect()
    }
}

#[cfg(test)]
#[allow(clippy::expect_used)]
mod tests {
    use super::*;

    #[test]
    fn configs_without_a_meaning_are_refused_by_field() {
        assert_eq!(DetectionConfig::default().check(), Ok(()));
        type Change = fn(&mut DetectionConfig);
        let cases: [(Change, &str); 9] = [
            (|c| c.dist_ths.clear(), "dist_ths = []"),
            (|c| c.dist_ths.push(f64::NAN), "holds NaN"),
            (|c| c.min_recall = 1.0, "min_recall = 1"),
            (|c| c.min_precision = -0.1, "min_precision = -0.1"),
            (
                |c| {
                    c.class_range.insert("car".into(), -5.0);
                },
                "class_range.car = -5",
            ),
            (|c| c.class_range.clear(), "class_range = {}: is empty"),
            (|c| c.dist_th_tp = 0.0, "dist_th_tp = 0"),
            (|c| c.max_boxes_per_sample = 0, "max_boxes_per_sample = 0"),
            (|c| c.dist_fcn = "iou".into(), "dist_fcn"),
        ];
        for (change, needle) in cases {
            let mut c = DetectionConfig::default();
            change(&mut c);
            let e = c.check().expect_err(needle);
            let e = e.to_string();
            assert!(e.contains(needle), "{e} lacks {needle}");
        }
    }
}
