#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{Vec2, Vec3};
use hilo_raycast::World;
use hilo_raycast::mesh::icosphere;
use hilo_raycast::shapes::GroundPlane;
use hilo_sensor_models::{Catalog, LidarSpec, RadarSpec};

/// A dome of radius 60 m over a ground plane: every ray from inside hits something.
pub fn dome_world() -> World {
    let tris: Vec<[Vec3; 3]> = icosphere(3).into_iter().map(|t| t.map(|v| v * 60.0)).collect();
    World::from_triangles(&tris, Some(GroundPlane { z_m: 0.0, min: Vec2::splat(-100.0), max: Vec2::splat(100.0) }))
        .unwrap()
}

/// Open ground only.
pub fn ground_world() -> World {
    World::from_triangles(&[], Some(GroundPlane { z_m: 0.0, min: Vec2::splat(-500.0), max: Vec2::splat(500.0) }))
        .unwrap()
}

pub fn catalog() -> Catalog {
    Catalog::default_catalog().unwrap()
}

/// A LiDAR spec without noise or drop-off, for exact counts.
pub fn ideal_lidar(name: &str) -> LidarSpec {
    let mut s = catalog().lidar(name).unwrap().clone();
    s.range_noise_m = 0.0;
    s.dropoff_general_rate = 0.0;
    s.dropoff_zero_intensity = 0.0;
    s
}

/// A radar without measurement noise or clutter.
pub fn ideal_radar() -> RadarSpec {
    let mut s = catalog().radar("radar-4d").unwrap().clone();
    s.range_noise_m = 0.0;
    s.azimuth_noise_deg = 0.0;
    s.elevation_noise_deg = 0.0;
    s.velocity_noise_mps = 0.0;
    s.rcs_noise_db = 0.0;
    s.clutter_probability = 0.0;
    s.ground_clutter_probability = 0.0;
    s
}
