//! Detection-probability model for placement: how well a sensor at a pose would see a probe
//! target (pedestrian- or car-sized) standing at a position, *ignoring occlusion* (placement
//! adds line-of-sight tests against the static scene itself).
//!
//! - LiDAR: the expected number of returns on the probe, computed exactly for the spec's beam
//!   pattern: every ray of the pattern whose direction falls in the probe's angular window is
//!   intersected with the probe box, and each hit counts with its survival probability under
//!   the drop-off rules at its intensity (and only where the lidar equation detects it, for a
//!   sensor with a datasheet detection range). No sampling: the answer is deterministic.
//! - Radar: the Swerling-I detection probability exp(−T/SNR̄) at the probe's range and class
//!   RCS, if any ray of the radar's grid reaches the probe within the field of view, else 0.

use crate::lidar::{intensity, survival_probability};
use crate::pose::{SensorPose, spherical_dir};
use crate::radar::{snr_db, swerling1_detection_probability};
use crate::spec::{LidarSpec, RadarSpec};
use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_raycast::shapes::intersect_box;
use hilo_raycast::{Material, Ray};

/// A probe target: a class and box size, standing on the ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    pub class: Class,
    pub length_m: f32,
    pub width_m: f32,
    pub height_m: f32,
}

impl Probe {
    pub const PEDESTRIAN: Probe = Probe { class: Class::Pedestrian, length_m: 0.6, width_m: 0.6, height_m: 1.75 };
    pub const CAR: Probe = Probe { class: Class::Car, length_m: 4.5, width_m: 1.9, height_m: 1.6 };

    /// The probe's box standing on ground height `ground_z` at `xy`, heading `yaw`.
    pub fn at(&self, xy: Vec2, ground_z: f32, yaw: f32) -> Box3 {
        Box3::new(xy.extend(ground_z + 0.5 * self.height_m), self.length_m, self.width_m, self.height_m, yaw)
    }

    fn material(&self) -> Material {
        if self.class == Class::Pedestrian { Material::Person } else { Material::VehicleBody }
    }
}

/// Azimuth/elevation window (sensor frame) and range bounds of a box seen from the sensor.
/// Azimuths are relative to the box centre's azimuth (so the window never wraps).
struct Window {
    center_az: f32,
    az: (f32, f32),
    el: (f32, f32),
    range: (f32, f32),
}

fn window(pose: &SensorPose, inv: glam::Quat, b: &Box3) -> Window {
    let to_sensor = |p: Vec3| inv * (p - pose.position);
    let c = to_sensor(b.center);
    let center_az = c.y.atan2(c.x);
    let mut w = Window { center_az, az: (f32::MAX, f32::MIN), el: (f32::MAX, f32::MIN), range: (f32::MAX, 0.0) };
    for corner in b.corners() {
        let s = to_sensor(corner);
        let r = s.length();
        let daz = (s.y.atan2(s.x) - center_az + std::f32::consts::PI).rem_euclid(std::f32::consts::TAU)
            - std::f32::consts::PI;
        let el = (s.z / r.max(1e-6)).clamp(-1.0, 1.0).asin();
        w.az = (w.az.0.min(daz), w.az.1.max(daz));
        w.el = (w.el.0.min(el), w.el.1.max(el));
        w.range = (w.range.0.min(r), w.range.1.max(r));
    }
    w.range.0 = (c.length() - 0.5 * Vec3::new(b.length_m, b.width_m, b.height_m).length()).max(0.0);
    w
}

/// Expected number of LiDAR returns from `probe` at box `b` (no occlusion).
pub fn lidar_expected_returns(spec: &LidarSpec, pose: &SensorPose, probe: &Probe, b: &Box3) -> f32 {
    LidarPattern::new(spec).expected_returns(pose, probe, b)
}

/// A LiDAR's beam pattern prepared for many probability queries (sorted elevations cached).
#[derive(Clone, Debug)]
pub struct LidarPattern<'a> {
    pub spec: &'a LidarSpec,
    elevations: Vec<f32>,
}

impl<'a> LidarPattern<'a> {
    pub fn new(spec: &'a LidarSpec) -> Self {
        LidarPattern { spec, elevations: spec.elevations_rad() }
    }

    /// See [`lidar_expected_returns`].
    pub fn expected_returns(&self, pose: &SensorPose, probe: &Probe, b: &Box3) -> f32 {
        expected_returns_impl(self.spec, &self.elevations, pose, probe, b, f32::INFINITY)
    }

    /// The same, but counting stops once `cap` is reached (returns a value ≥ `cap` then). A
    /// detection probability P(N ≥ m) is 1 to machine precision long before N's mean reaches a
    /// few dozen, so placement need not count every return on a car next to the pole.
    pub fn expected_returns_capped(&self, pose: &SensorPose, probe: &Probe, b: &Box3, cap: f32) -> f32 {
        expected_returns_impl(self.spec, &self.elevations, pose, probe, b, cap)
    }
}

fn expected_returns_impl(
    spec: &LidarSpec,
    elevations: &[f32],
    pose: &SensorPose,
    probe: &Probe,
    b: &Box3,
    cap: f32,
) -> f32 {
    let rot = pose.rotation();
    let w = window(pose, rot.inverse(), b);
    let refl = probe.material().lidar_reflectivity();
    if w.range.0 > spec.reach_m(refl) {
        return 0.0;
    }
    // Inside the box (or touching it): everything is in the window; count the whole pattern.
    let inside = b.contains(pose.position);
    let cols = spec.columns();
    let hfov = spec.hfov_deg.to_radians();
    let full = spec.hfov_deg >= 360.0;
    let step = hfov / cols as f32;
    let mut expected = 0.0f32;
    // Only the columns and beams whose angles fall in the probe's window (plus a margin) are
    // intersected: the window is found by index arithmetic, not by scanning the pattern.
    let margin = 1e-4;
    let az_at = |k: u32| if full { k as f32 * step } else { -0.5 * hfov + (k as f32 + 0.5) * step };
    let columns: Vec<u32> = if inside {
        (0..cols).collect()
    } else {
        let lo = w.center_az + w.az.0 - margin;
        let hi = w.center_az + w.az.1 + margin;
        if full {
            let k0 = (lo / step).ceil() as i64;
            let k1 = (hi / step).floor() as i64;
            (k0..=k1).map(|k| k.rem_euclid(cols as i64) as u32).collect()
        } else {
            let base = -0.5 * hfov;
            let k0 = ((lo - base) / step - 0.5).ceil().max(0.0) as i64;
            let k1 = ((hi - base) / step - 0.5).floor().min(cols as f32 - 1.0) as i64;
            (k0..=k1).map(|k| k as u32).collect()
        }
    };
    let (e0, e1) = if inside {
        (0, elevations.len())
    } else {
        (elevations.partition_point(|&e| e < w.el.0 - margin), elevations.partition_point(|&e| e <= w.el.1 + margin))
    };
    for k in columns {
        let az = az_at(k);
        for &el in &elevations[e0..e1] {
            let ray = Ray {
                origin: pose.position,
                dir: rot * spherical_dir(az, el),
                t_min: spec.min_range_m,
                t_max: spec.max_range_m,
            };
            if let Some((t, n)) = intersect_box(b, &ray, ray.t_max)
                && spec.detects(refl, n.dot(ray.dir), t)
            {
                let i = intensity(refl, n.dot(ray.dir), t, spec.atmosphere_attenuation_per_m);
                expected += survival_probability(spec, i);
            }
        }
        if expected >= cap {
            return expected;
        }
    }
    expected
}

/// Probability that the radar detects `probe` at box `b` (no occlusion): Swerling-I at the
/// probe's nearest range if some ray of the radar grid reaches it within the field of view.
pub fn radar_detection_probability(spec: &RadarSpec, pose: &SensorPose, probe: &Probe, b: &Box3) -> f32 {
    let rot = pose.rotation();
    let w = window(pose, rot.inverse(), b);
    let (hh, hv) = (0.5 * spec.hfov_deg.to_radians(), 0.5 * spec.vfov_deg.to_radians());
    let az_lo = w.center_az + w.az.0;
    let az_hi = w.center_az + w.az.1;
    // Some part of the box within the field of view?
    if az_hi < -hh || az_lo > hh || w.el.1 < -hv || w.el.0 > hv {
        return 0.0;
    }
    // Does some ray of the grid hit it within range?
    let n_az = (spec.hfov_deg / spec.ray_azimuth_step_deg).round().max(1.0) as usize;
    let n_el = (spec.vfov_deg / spec.ray_elevation_step_deg).round().max(1.0) as usize;
    let (s_az, s_el) = (2.0 * hh / n_az as f32, 2.0 * hv / n_el as f32);
    let mut reached = false;
    'grid: for ia in 0..n_az {
        let az = -hh + (ia as f32 + 0.5) * s_az;
        if az < az_lo - s_az || az > az_hi + s_az {
            continue;
        }
        for ie in 0..n_el {
            let el = -hv + (ie as f32 + 0.5) * s_el;
            if el < w.el.0 - s_el || el > w.el.1 + s_el {
                continue;
            }
            let ray = Ray {
                origin: pose.position,
                dir: rot * spherical_dir(az, el),
                t_min: spec.min_range_m,
                t_max: spec.max_range_m,
            };
            if intersect_box(b, &ray, ray.t_max).is_some() {
                reached = true;
                break 'grid;
            }
        }
    }
    if !reached {
        return 0.0;
    }
    // Range of the probe's nearest point (the radar equation's R).
    let local = b.to_local(pose.position);
    let nearest = (local.abs() - b.half_extents()).max(Vec3::ZERO).length().max(spec.min_range_m);
    swerling1_detection_probability(spec, snr_db(spec, spec.rcs_dbsm.get(probe.class), nearest))
}
