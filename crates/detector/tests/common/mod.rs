//! Helpers shared by the fusion crate's simulation tests.

use hilo_raycast::Scene;
use hilo_sensor_models::SensorPose;

/// A sensor halfway along mount `mount`'s arm, `above_arm_m` above it, facing the scene origin
/// and pitched 10° down.
pub fn pose(scene: &Scene, mount: usize, above_arm_m: f32) -> SensorPose {
    let m = &scene.mounts[mount];
    let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
    let yaw = (-p.y).atan2(-p.x);
    SensorPose::new(p.extend(scene.ground.z_m + m.arm_height_m + above_arm_m), yaw, 10f32.to_radians(), 0.0)
}
