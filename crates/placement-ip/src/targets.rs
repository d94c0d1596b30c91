//! The ROI target grid: square cells over the scene's regions of interest, each weighted by the
//! heaviest ROI containing its centre.

use crate::error::PlacementError;
use glam::Vec2;
use hilo_raycast::Scene;
use serde::{Deserialize, Serialize};

/// One target cell.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Target {
    pub center: Vec2,
    /// w_j: the weight of the heaviest ROI containing the centre.
    pub weight: f32,
    /// Index of that ROI in the scene's ROI list.
    pub roi: u16,
}

/// Targets on a grid of `cell_m` squares (centres at half-cell offsets from the grid origin).
pub fn roi_targets(scene: &Scene, cell_m: f32) -> Result<Vec<Target>, PlacementError> {
    if !(cell_m.is_finite() && cell_m >= 0.1) {
        return Err(PlacementError::setting("placement.cell_m", cell_m, "must be at least 0.1 m"));
    }
    if scene.rois.is_empty() {
        return Err(PlacementError::instance(
            format!("scene {}", scene.source_name()),
            "has no regions of interest ([[roi]])",
        ));
    }
    let pts: Vec<Vec2> = scene.rois.iter().flat_map(|r| r.polygons.iter().flatten().copied()).collect();
    let lo = pts.iter().fold(Vec2::splat(f32::MAX), |a, b| a.min(*b));
    let hi = pts.iter().fold(Vec2::splat(f32::MIN), |a, b| a.max(*b));
    let nx = ((hi.x - lo.x) / cell_m).ceil() as usize;
    let ny = ((hi.y - lo.y) / cell_m).ceil() as usize;
    let mut out = Vec::new();
    for iy in 0..ny {
        for ix in 0..nx {
            let c = lo + Vec2::new((ix as f32 + 0.5) * cell_m, (iy as f32 + 0.5) * cell_m);
            let best = scene
                .rois
                .iter()
                .enumerate()
                .filter(|(_, r)| r.contains(c))
                .max_by(|a, b| a.1.weight.total_cmp(&b.1.weight).then(b.0.cmp(&a.0)));
            if let Some((i, r)) = best {
                out.push(Target { center: c, weight: r.weight, roi: i as u16 });
            }
        }
    }
    if out.is_empty() {
        return Err(PlacementError::instance("the regions of interest", "contain no target cell centre"));
    }
    Ok(out)
}
