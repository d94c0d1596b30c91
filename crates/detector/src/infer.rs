//! Inference over frames: boxes per sample, in the order of the frames.

use crate::data::Frame;
use crate::detector::{Detector, HostBatch};
use crate::doppler::{DopplerCount, read_velocities};
use crate::error::Result;
use hilo_core::Detection;

/// Boxes per sample, in frame order.
pub type Detections = Vec<(String, Vec<Detection>)>;

/// Boxes of every frame (detected in batches of `batch`), and the wall time per frame, seconds.
/// A detector that reads the radar and asks for it (`decode.radar_velocity`) takes its boxes'
/// velocities from the radar's Doppler ([`crate::doppler`]).
pub fn detect_frames(
    det: &Detector,
    frames: &[Frame],
    batch: usize,
    on_batch: &mut dyn FnMut(usize),
) -> Result<(Detections, f64)> {
    Ok(detect_counted(det, frames, batch, on_batch)?.0)
}

/// As [`detect_frames`], with what the Doppler step did over all frames.
pub fn detect_counted(
    det: &Detector,
    frames: &[Frame],
    batch: usize,
    on_batch: &mut dyn FnMut(usize),
) -> Result<((Detections, f64), DopplerCount)> {
    let t0 = std::time::Instant::now();
    let with_radar = det.uses_radar();
    let doppler = det.cfg.decode.radar_velocity.as_ref().filter(|_| with_radar);
    let mut count = DopplerCount::default();
    let mut out = Vec::with_capacity(frames.len());
    for chunk in frames.chunks(batch.max(1)) {
        let hb = HostBatch::new(&det.cfg, chunk, with_radar, 0);
        for (f, mut ds) in chunk.iter().zip(det.detect(&hb)?) {
            if let Some(cfg) = doppler {
                count += read_velocities(cfg, f, &mut ds);
            }
            out.push((f.sample_token.clone(), ds));
        }
        on_batch(out.len());
    }
    Ok(((out, t0.elapsed().as_secs_f64() / frames.len().max(1) as f64), count))
}
