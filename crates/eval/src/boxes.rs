//! Boxes as the nuScenes evaluation sees them, and the files that carry them.
//!
//! - Predictions: the nuScenes submission JSON, `{"meta": {...}, "results": {sample_token:
//!   [box, ...]}}`, each box with `sample_token`, `translation` (m, x y z of the centre),
//!   `size` (m, width length height), `rotation` (quaternion w x y z), `velocity` (m/s, x y),
//!   `detection_name`, `detection_score`, `attribute_name`.
//! - Ground truth: the same box fields plus `num_pts` (LiDAR + radar points inside), grouped as
//!   `{"samples": {sample_token: {"scene": scene_token, "ego_translation": [x, y, z]}},
//!   "boxes": {sample_token: [box, ...]}}`. For roadside data the "ego" is the scene origin the
//!   dataset declares, so the devkit's range filter measures from it.

use crate::error::EvalError;
use hilo_core::{Class, Detection};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// One box (prediction or ground truth).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalBox {
    pub sample_token: String,
    pub translation: [f64; 3],
    pub size: [f64; 3],
    pub rotation: [f64; 4],
    #[serde(default)]
    pub velocity: [f64; 2],
    pub detection_name: String,
    #[serde(default = "one")]
    pub detection_score: f64,
    #[serde(default)]
    pub attribute_name: String,
    /// Points inside a ground-truth box; -1 (unknown) for predictions.
    #[serde(default = "minus_one")]
    pub num_pts: i64,
}

fn one() -> f64 {
    1.0
}
fn minus_one() -> i64 {
    -1
}

impl EvalBox {
    /// Yaw of the rotation (the devkit's `quaternion_yaw`: the rotated x axis, projected).
    pub fn yaw(&self) -> f64 {
        let [w, x, y, z] = self.rotation;
        let n = (w * w + x * x + y * y + z * z).sqrt();
        let (w, x, y, z) = (w / n, x / n, y / n, z / n);
        (2.0 * (x * y + w * z)).atan2(1.0 - 2.0 * (y * y + z * z))
    }

    /// A yaw-only box.
    pub fn from_yaw(
        sample: &str,
        class: &str,
        center: [f64; 3],
        wlh: [f64; 3],
        yaw: f64,
        velocity: [f64; 2],
        score: f64,
    ) -> Self {
        EvalBox {
            sample_token: sample.to_owned(),
            translation: center,
            size: wlh,
            rotation: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()],
            velocity,
            detection_name: class.to_owned(),
            detection_score: score,
            attribute_name: String::new(),
            num_pts: -1,
        }
    }
}

impl EvalBox {
    /// A detector's box as a submission box of `sample`, with the nuScenes attribute its class
    /// and predicted speed imply (moving above 0.5 m/s for vehicles, 0.3 m/s for pedestrians;
    /// motorcycles and bicycles always with a rider).
    pub fn from_detection(sample: &str, d: &Detection) -> Self {
        let b = &d.box3;
        let speed = d.velocity_mps.length();
        let attribute = match d.class {
            Class::Pedestrian => {
                if speed > 0.3 {
                    "pedestrian.moving"
                } else {
                    "pedestrian.standing"
                }
            }
            Class::Motorcycle | Class::Bicycle => "cycle.with_rider",
            _ => {
                if speed > 0.5 {
                    "vehicle.moving"
                } else {
                    "vehicle.stopped"
                }
            }
        };
        EvalBox {
            attribute_name: attribute.to_owned(),
            ..EvalBox::from_yaw(
                sample,
                d.class.name(),
                [b.center.x as f64, b.center.y as f64, b.center.z as f64],
                [b.width_m as f64, b.length_m as f64, b.height_m as f64],
                b.yaw as f64,
                [d.velocity_mps.x as f64, d.velocity_mps.y as f64],
                d.score.clamp(0.0, 1.0) as f64,
            )
        }
    }
}

/// Detections per sample as submission boxes, in sample order.
pub fn from_detections(results: &[(String, Vec<Detection>)]) -> Vec<(String, Vec<EvalBox>)> {
    results.iter().map(|(s, ds)| (s.clone(), ds.iter().map(|d| EvalBox::from_detection(s, d)).collect())).collect()
}

/// A nuScenes submission document: `{"meta": meta, "results": {sample: [box, ...]}}`, samples in
/// the given order.
pub fn submission_json(results: &[(String, Vec<EvalBox>)], meta: serde_json::Value) -> serde_json::Value {
    let mut map = serde_json::Map::new();
    for (s, boxes) in results {
        map.insert(s.clone(), serde_json::to_value(boxes).unwrap_or_default());
    }
    serde_json::json!({ "meta": meta, "results": map })
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleInfo {
    pub scene: String,
    pub ego_translation: [f64; 3],
}

/// Ground truth of an evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct GroundTruth {
    #[serde(deserialize_with = "unique_keys")]
    pub samples: BTreeMap<String, SampleInfo>,
    #[serde(deserialize_with = "unique_keys")]
    pub boxes: BTreeMap<String, Vec<EvalBox>>,
}

/// A submission.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Submission {
    #[serde(default)]
    pub meta: serde_json::Value,
    /// Sample order is kept: it decides the order of equal-score predictions, as in the devkit.
    #[serde(deserialize_with = "unique_keys")]
    pub results: serde_json::Map<String, serde_json::Value>,
}

/// A JSON object into a map, refusing a key that appears twice: JSON parsers keep one of the
/// two silently (serde_json and Python the last), so a sample listed twice would lose half its
/// boxes without a word.
fn unique_keys<'de, D, M, V>(d: D) -> Result<M, D::Error>
where
    D: serde::Deserializer<'de>,
    M: Default + Extend<(String, V)>,
    V: Deserialize<'de>,
{
    struct Visit<M, V>(std::marker::PhantomData<(M, V)>);
    impl<'de, M: Default + Extend<(String, V)>, V: Deserialize<'de>> serde::de::Visitor<'de> for Visit<M, V> {
        type Value = M;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("an object keyed by sample token")
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(self, mut a: A) -> Result<M, A::Error> {
            let mut seen = std::collections::HashSet::new();
            let mut out = M::default();
            while let Some((k, v)) = a.next_entry::<String, V>()? {
                if !seen.insert(k.clone()) {
                    return Err(serde::de::Error::custom(format!("sample {k:?} is listed twice")));
                }
                out.extend([(k, v)]);
            }
            Ok(out)
        }
    }
    d.deserialize_map(Visit(std::marker::PhantomData))
}

fn check_box(b: &EvalBox, file: &Path, sample: &str, k: usize, pred: bool) -> Result<(), EvalError> {
    let bad = |field: &str, v: String| {
        Err(EvalError::Field {
            path: file.to_path_buf(),
            sample: sample.to_owned(),
            index: k,
            field: field.to_owned(),
            value: v,
        })
    };
    if b.sample_token != sample {
        return bad("sample_token", format!("{:?} (listed under {sample:?})", b.sample_token));
    }
    // As the devkit does: a box of a class the metric does not know is an error, not a box
    // silently left out (which would make every box of a misspelt class a miss).
    if b.detection_name.parse::<hilo_core::Class>().is_err() {
        return bad(
            "detection_name",
            format!(
                "{:?} (not an evaluated class: car, truck, bus, motorcycle, pedestrian, golf_cart, bicycle)",
                b.detection_name
            ),
        );
    }
    if let Some((field, value, why)) = hilo_core::nuscenes_box_defect(&b.translation, &b.size, &b.rotation) {
        return bad(field, format!("{value} ({why})"));
    }
    if pred && !(b.detection_score.is_finite() && (0.0..=1.0).contains(&b.detection_score)) {
        return bad("detection_score", format!("{}", b.detection_score));
    }
    if b.velocity.iter().any(|v| v.is_infinite()) {
        return bad("velocity", format!("{:?}", b.velocity));
    }
    Ok(())
}

/// A JSON syntax error with the sample it occurred in (the last `"sample_token"` before it):
/// Python writes NaN and Infinity as bare words that JSON does not allow.
fn json_error(path: &Path, text: &str, e: &serde_json::Error) -> EvalError {
    let mut offset = (text.lines().take(e.line().saturating_sub(1)).map(|l| l.len() + 1).sum::<usize>() + e.column())
        .min(text.len());
    // serde_json's column counts bytes; step back to a character boundary (a multi-byte
    // character, a byte-order mark or a typographic quote, may sit at the error).
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let sample = before.rfind("\"sample_token\"").and_then(|i| {
        let rest = &before[i + 14..];
        let q0 = rest.find('"')? + 1;
        let q1 = rest[q0..].find('"')?;
        Some(rest[q0..q0 + q1].to_owned())
    });
    let hint = if text.get(offset.saturating_sub(1)..).is_some_and(|t| t.starts_with(['N', 'I', '-'])) {
        " (NaN and Infinity are not JSON numbers)"
    } else {
        ""
    };
    let message = match sample {
        Some(s) => format!("sample {s:?}: {e}{hint}"),
        None => format!("{e}{hint}"),
    };
    EvalError::from(hilo_core::fs::FileError::Content { path: path.to_path_buf(), message })
}

/// Reads and checks a submission; returns boxes grouped by sample in file order.
pub fn read_submission(path: &Path, max_boxes_per_sample: usize) -> Result<Vec<(String, Vec<EvalBox>)>, EvalError> {
    let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::TABLE)
        .map_err(|e| EvalError::from(hilo_core::fs::FileError::io(path, e)))?;
    parse_submission(&text, path, max_boxes_per_sample)
}

/// [`read_submission`] of text already read; `path` names it in errors.
pub fn parse_submission(
    text: &str,
    path: &Path,
    max_boxes_per_sample: usize,
) -> Result<Vec<(String, Vec<EvalBox>)>, EvalError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let sub: Submission = serde_json::from_str(text).map_err(|e| json_error(path, text, &e))?;
    let mut out = Vec::new();
    for (sample, v) in sub.results {
        let boxes: Vec<EvalBox> = serde_json::from_value(v).map_err(|e| {
            EvalError::from(hilo_core::fs::FileError::Content {
                path: path.to_path_buf(),
                message: format!("sample {sample:?}: {e}"),
            })
        })?;
        if boxes.len() > max_boxes_per_sample {
            return Err(EvalError::from(hilo_core::fs::FileError::Content {
                path: path.to_path_buf(),
                message: format!("sample {sample:?} has {} boxes, above the limit {max_boxes_per_sample}", boxes.len()),
            }));
        }
        for (k, b) in boxes.iter().enumerate() {
            check_box(b, path, &sample, k, true)?;
        }
        out.push((sample, boxes));
    }
    Ok(out)
}

/// Reads and checks a ground-truth file.
pub fn read_ground_truth(path: &Path) -> Result<GroundTruth, EvalError> {
    let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::TABLE)
        .map_err(|e| EvalError::from(hilo_core::fs::FileError::io(path, e)))?;
    parse_ground_truth(&text, path)
}

/// [`read_ground_truth`] of text already read; `path` names it in errors.
pub fn parse_ground_truth(text: &str, path: &Path) -> Result<GroundTruth, EvalError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let gt: GroundTruth = serde_json::from_str(text).map_err(|e| json_error(path, text, &e))?;
    if gt.samples.is_empty() {
        return Err(EvalError::from(hilo_core::fs::FileError::Content {
            path: path.to_path_buf(),
            message: "`samples` is empty: an evaluation over no samples would print mAP 0".into(),
        }));
    }
    for (sample, boxes) in &gt.boxes {
        if !gt.samples.contains_key(sample) {
            return Err(EvalError::from(hilo_core::fs::FileError::Content {
                path: path.to_path_buf(),
                message: format!("boxes listed for sample {sample:?}, which is not in `samples`"),
            }));
        }
        for (k, b) in boxes.iter().enumerate() {
            check_box(b, path, sample, k, false)?;
        }
    }
    Ok(gt)
}

/// The devkit's `filter_eval_boxes` (without its bike-rack rule, which roadside data lacks):
/// drops boxes farther than their class range from the sample's ego (here: scene origin)
/// position, boxes of classes not evaluated, and ground-truth boxes with no points.
pub fn filter_boxes(boxes: &[EvalBox], ego: [f64; 3], class_range: &BTreeMap<String, f64>) -> Vec<EvalBox> {
    boxes
        .iter()
        .filter(|b| {
            let d = ((b.translation[0] - ego[0]).powi(2) + (b.translation[1] - ego[1]).powi(2)).sqrt();
            class_range.get(&b.detection_name).is_some_and(|r| d < *r)
        })
        .filter(|b| b.num_pts != 0)
        .cloned()
        .collect()
}

/// Checks that a submission covers exactly the ground truth's samples, as the devkit does
/// (a missing sample would count its boxes as misses, an unknown one would be ignored).
pub fn check_sample_set(gt: &GroundTruth, pred: &[(String, Vec<EvalBox>)], path: &Path) -> Result<(), EvalError> {
    let pred_samples: std::collections::BTreeSet<&String> = pred.iter().map(|(s, _)| s).collect();
    let gt_samples: std::collections::BTreeSet<&String> = gt.samples.keys().collect();
    if pred_samples == gt_samples {
        return Ok(());
    }
    let missing: Vec<_> = gt_samples.difference(&pred_samples).take(3).collect();
    let extra: Vec<_> = pred_samples.difference(&gt_samples).take(3).collect();
    Err(EvalError::from(hilo_core::fs::FileError::Content {
        path: path.to_path_buf(),
        message: format!("samples differ from the ground truth's (missing e.g. {missing:?}, unknown e.g. {extra:?})"),
    }))
}
