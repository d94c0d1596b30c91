//! Inference over frames: boxes per sample, in the order of the frames.

use crate::data::Frame;
use crate::detector::{Detector, HostBatch};
use crate::error::Result;
use hilo_core::Detection;

/// Boxes per sample, in frame order.
pub type Detections = Vec<(String, Vec<Detection>)>;

/// Boxes of every frame (detected in batches of `batch`), and the wall time per frame, seconds.
pub fn detect_frames(
    det: &Detector,
    frames: &[Frame],
    batch: usize,
    on_batch: &mut dyn FnMut(usize),
) -> Result<(Detections, f64)> {
    let t0 = std::time::Instant::now();
    let with_radar = det.uses_radar();
    let mut out = Vec::with_capacity(frames.len());
    for chunk in frames.chunks(batch.max(1)) {
        let hb = HostBatch::new(&det.cfg, chunk, with_radar, 0);
        for (f, ds) in chunk.iter().zip(det.detect(&hb)?) {
            out.push((f.sample_token.clone(), ds));
        }
        on_batch(out.len());
    }
    Ok((out, t0.elapsed().as_secs_f64() / frames.len().max(1) as f64))
}
