//! The detection evaluation settings (the devkit's `detection_cvpr_2019` with hilo's classes).

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
    /// Class names in the order the devkit iterates them (the order of `class_range`; serde keeps
    /// keys sorted here, and every per-class result is keyed by name, so order does not matter).
    pub fn class_names(&self) -> Vec<String> {
        self.class_range.keys().cloned().collect()
    }
}
