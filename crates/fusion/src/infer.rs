//! Inference over a split, written as a nuScenes detection submission (what `hilo eval` reads).

use crate::data::{CLASSES, Frame};
use crate::decode::Det;
use crate::detector::{Detector, HostBatch};
use crate::error::Result;
use hilo_eval::boxes::EvalBox;

/// nuScenes attribute for a detection (moving/stopped by its predicted speed).
fn attribute(class: usize, speed: f32) -> &'static str {
    match CLASSES[class] {
        hilo_core::Class::Pedestrian => {
            if speed > 0.3 {
                "pedestrian.moving"
            } else {
                "pedestrian.standing"
            }
        }
        hilo_core::Class::Motorcycle => "cycle.with_rider",
        _ => {
            if speed > 0.5 {
                "vehicle.moving"
            } else {
                "vehicle.stopped"
            }
        }
    }
}

pub fn to_eval_box(token: &str, d: &Det) -> EvalBox {
    let mut b = EvalBox::from_yaw(
        token,
        CLASSES[d.class].name(),
        d.center.map(|v| v as f64),
        d.wlh.map(|v| v as f64),
        d.yaw as f64,
        d.velocity.map(|v| v as f64),
        d.score.clamp(0.0, 1.0) as f64,
    );
    b.attribute_name = attribute(d.class, (d.velocity[0].powi(2) + d.velocity[1].powi(2)).sqrt()).to_owned();
    b
}

/// Detects every frame (in batches) and returns the submission JSON and the seconds per frame.
pub fn detect_frames(
    det: &Detector,
    frames: &[Frame],
    batch: usize,
    on_batch: &mut dyn FnMut(usize),
) -> Result<(serde_json::Value, f64)> {
    let t0 = std::time::Instant::now();
    let mut results = serde_json::Map::new();
    let with_radar = det.uses_radar();
    let mut done = 0;
    for chunk in frames.chunks(batch.max(1)) {
        let hb = HostBatch::new(&det.cfg, chunk, with_radar);
        let dets = det.detect(&hb)?;
        for (f, ds) in chunk.iter().zip(dets) {
            let boxes: Vec<EvalBox> = ds.iter().map(|d| to_eval_box(&f.sample_token, d)).collect();
            results.insert(f.sample_token.clone(), serde_json::to_value(boxes).unwrap_or_default());
        }
        done += chunk.len();
        on_batch(done);
    }
    let per_frame = t0.elapsed().as_secs_f64() / frames.len().max(1) as f64;
    let meta = serde_json::json!({ "use_camera": false, "use_lidar": true, "use_radar": with_radar, "use_map": false, "use_external": false, "detector": det.cfg.name });
    Ok((serde_json::json!({ "meta": meta, "results": results }), per_frame))
}
