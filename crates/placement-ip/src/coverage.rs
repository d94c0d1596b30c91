//! Coverage metrics: which target cells the chosen LiDARs actually hit with rays (the paper's
//! "central coverage": the share of central-ROI cells passed by at least one ray), and where
//! LiDAR and radar coverage overlap.

use crate::error::PlacementError;
use crate::targets::Target;
use glam::Vec2;
use hilo_raycast::{Scene, World};
use hilo_sensor_models::{LidarSpec, SensorPose, simulate_lidar};
use std::collections::{HashMap, HashSet};

/// Targets whose cell holds at least one ground return of the given LiDARs (ideal scans of the
/// static scene: no noise, no drop-off). `cell_m` is the target grid's cell size.
pub fn lidar_hit_targets(
    scene: &Scene,
    world: &World,
    targets: &[Target],
    cell_m: f32,
    lidars: &[(LidarSpec, SensorPose)],
) -> Result<HashSet<usize>, PlacementError> {
    if targets.is_empty() {
        return Ok(HashSet::new());
    }
    let lo = targets.iter().fold(Vec2::splat(f32::MAX), |a, t| a.min(t.center)) - Vec2::splat(0.5 * cell_m);
    let key = |p: Vec2| (((p.x - lo.x) / cell_m).floor() as i64, ((p.y - lo.y) / cell_m).floor() as i64);
    let index: HashMap<(i64, i64), usize> = targets.iter().enumerate().map(|(j, t)| (key(t.center), j)).collect();
    let mut hit = HashSet::new();
    for (spec, pose) in lidars {
        let mut ideal = spec.clone();
        ideal.range_noise_m = 0.0;
        ideal.dropoff_general_rate = 0.0;
        ideal.dropoff_zero_intensity = 0.0;
        let scan = simulate_lidar(&ideal, pose, world, None, 0)?;
        for p in scan.points_local() {
            if (p.z - scene.ground.z_m).abs() < 0.3
                && let Some(&j) = index.get(&key(Vec2::new(p.x, p.y)))
            {
                hit.insert(j);
            }
        }
    }
    Ok(hit)
}

/// Share of `subset` (target indices) in `hit`.
pub fn share(subset: &[usize], hit: &HashSet<usize>) -> f64 {
    if subset.is_empty() { 0.0 } else { subset.iter().filter(|j| hit.contains(j)).count() as f64 / subset.len() as f64 }
}
