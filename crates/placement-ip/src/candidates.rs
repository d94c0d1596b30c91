//! Candidate mounts along the scene's signal poles and mast arms, and sensor orientations.
//!
//! A *mount point* is a position on a pole (at several heights) or on a mast arm (at several
//! distances from the pole, just above the arm). A LiDAR candidate is a mount point with the
//! sensor turned from the junction centre by one of `lidar_yaw_offsets_deg` and tilted down by
//! one of `lidar_tilts_deg`; a radar candidate is a mount point with the radar aimed at the
//! centre turned by one of `radar_yaw_offsets_deg` and tilted by one of `radar_tilts_deg` (its
//! horizontal field of view is only 120°, so where it looks matters). Yaw and tilt are both
//! decision variables: every (yaw, tilt) pair of a mount is a candidate, and the solvers choose
//! at most one per mount, as the paper's formulation allows for any discrete orientation set.

use crate::error::PlacementError;
use glam::{Vec2, Vec3};
use hilo_raycast::Scene;
use hilo_sensor_models::SensorPose;
use serde::{Deserialize, Serialize};

/// How candidates are sampled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CandidateConfig {
    /// Lowest mount height on a pole, metres.
    pub pole_min_height_m: f32,
    /// Step between mount heights on a pole.
    pub pole_step_m: f32,
    /// Step between mount points along a mast arm (from the pole outward).
    pub arm_step_m: f32,
    /// Mounts on an arm sit this far above its axis.
    pub arm_clearance_m: f32,
    /// Downward tilts offered to a LiDAR (degrees; one value is a fixed tilt). The key
    /// `lidar_tilt_deg = 10.0` of older study files reads as `[10.0]`.
    #[serde(alias = "lidar_tilt_deg", deserialize_with = "one_or_many")]
    pub lidar_tilts_deg: Vec<f32>,
    pub lidar_yaw_offsets_deg: Vec<f32>,
    /// Downward tilts offered to a radar (degrees); `radar_tilt_deg` reads as one.
    #[serde(alias = "radar_tilt_deg", deserialize_with = "one_or_many")]
    pub radar_tilts_deg: Vec<f32>,
    pub radar_yaw_offsets_deg: Vec<f32>,
}

/// A number or a list of numbers, as a list.
fn one_or_many<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<f32>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum OneOrMany {
        One(f32),
        Many(Vec<f32>),
    }
    Ok(match OneOrMany::deserialize(d)? {
        OneOrMany::One(x) => vec![x],
        OneOrMany::Many(v) => v,
    })
}

impl Default for CandidateConfig {
    fn default() -> Self {
        CandidateConfig {
            pole_min_height_m: 4.0,
            pole_step_m: 0.5,
            arm_step_m: 1.0,
            arm_clearance_m: 0.3,
            lidar_tilts_deg: vec![10.0],
            lidar_yaw_offsets_deg: vec![-45.0, 0.0, 45.0],
            radar_tilts_deg: vec![8.0],
            radar_yaw_offsets_deg: vec![-45.0, -15.0, 15.0, 45.0],
        }
    }
}

/// Which modality a candidate is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Modality {
    Lidar,
    Radar,
}

/// A mount point and a sensor orientation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    pub id: u32,
    pub modality: Modality,
    /// Mount point index: at most one sensor per mount point.
    pub mount: u32,
    /// The structure it is on, e.g. "NE/pole" or "NE/arm".
    pub structure: String,
    pub pose: SensorPose,
}

/// Samples LiDAR and radar candidates on every mounting structure of the scene.
pub fn sample_candidates(scene: &Scene, cfg: &CandidateConfig) -> Result<Vec<Candidate>, PlacementError> {
    for (name, v) in [("pole_step_m", cfg.pole_step_m), ("arm_step_m", cfg.arm_step_m)] {
        if !(v.is_finite() && v > 0.05) {
            return Err(PlacementError::setting(format!("candidates.{name}"), v, "must be a step above 0.05 m"));
        }
    }
    for (name, v) in [
        ("lidar_tilts_deg", &cfg.lidar_tilts_deg),
        ("radar_tilts_deg", &cfg.radar_tilts_deg),
        ("lidar_yaw_offsets_deg", &cfg.lidar_yaw_offsets_deg),
        ("radar_yaw_offsets_deg", &cfg.radar_yaw_offsets_deg),
    ] {
        if v.is_empty() {
            return Err(PlacementError::setting(format!("candidates.{name}"), "[]", "give at least one angle"));
        }
        let limit = if name.contains("tilt") { 90.0 } else { 180.0 };
        if let Some(a) = v.iter().find(|a| !(a.is_finite() && a.abs() <= limit)) {
            return Err(PlacementError::setting(
                format!("candidates.{name}"),
                format!("{v:?}"),
                format!("holds {a}: angles are degrees within ±{limit}"),
            ));
        }
    }
    if scene.mounts.is_empty() {
        return Err(PlacementError::instance(
            format!("scene {}", scene.source_name()),
            "has no signal poles to mount sensors on",
        ));
    }
    let gz = scene.ground.z_m;
    let centre = scene.layout.central.iter().copied().sum::<Vec2>() / scene.layout.central.len().max(1) as f32;
    let mut points: Vec<(String, Vec3)> = Vec::new();
    let g = scene.ground;
    for m in &scene.mounts {
        let tip = m.base + m.arm_dir * m.arm_length_m;
        for p in [m.base, tip] {
            if p.x < g.min.x || p.y < g.min.y || p.x > g.max.x || p.y > g.max.y {
                return Err(PlacementError::instance(
                    format!("signal pole {}", m.name),
                    format!(
                        "reaches ({:.1}, {:.1}), outside the scene's ground ({:.0}..{:.0} m, {:.0}..{:.0} m)",
                        p.x, p.y, g.min.x, g.max.x, g.min.y, g.max.y
                    ),
                ));
            }
        }
        // Just outside the pole's surface, toward the junction; not where that point is inside
        // the mast arm (an arm that points at the junction passes through it at its height).
        let out = (centre - m.base).normalize_or(Vec2::X) * (m.pole_radius_m + 0.15);
        let (a, b) = m.arm_axis(gz);
        let mut h = cfg.pole_min_height_m;
        while h <= m.pole_height_m + 1e-3 {
            let p = (m.base + out).extend(gz + h);
            if m.arm_length_m <= 0.0 || distance_to_segment(p, a, b) >= m.arm_radius_m() + ARM_CLEARANCE_M {
                points.push((format!("{}/pole", m.name), p));
            }
            h += cfg.pole_step_m;
        }
        let mut s = cfg.arm_step_m;
        while s <= m.arm_length_m + 1e-3 {
            points.push((
                format!("{}/arm", m.name),
                (m.base + m.arm_dir * s).extend(gz + m.arm_height_m + cfg.arm_clearance_m),
            ));
            s += cfg.arm_step_m;
        }
    }
    let mut out = Vec::new();
    for (mount, (structure, p)) in points.iter().enumerate() {
        let to_centre = centre - p.truncate();
        let yaw0 = to_centre.y.atan2(to_centre.x);
        for (modality, yaws, tilts) in [
            (Modality::Lidar, &cfg.lidar_yaw_offsets_deg, &cfg.lidar_tilts_deg),
            (Modality::Radar, &cfg.radar_yaw_offsets_deg, &cfg.radar_tilts_deg),
        ] {
            for tilt in tilts {
                for off in yaws {
                    let pose = SensorPose::new(*p, yaw0 + off.to_radians(), tilt.to_radians(), 0.0);
                    out.push(Candidate {
                        id: out.len() as u32,
                        modality,
                        mount: mount as u32,
                        structure: structure.clone(),
                        pose,
                    });
                }
            }
        }
    }
    Ok(out)
}

/// The least distance a pole candidate keeps from a mast arm's surface (a sensor's housing
/// against the arm, not inside it).
const ARM_CLEARANCE_M: f32 = 0.05;

/// Distance from `p` to the segment from `a` to `b`.
fn distance_to_segment(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + ab * t)
}
