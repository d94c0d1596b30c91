//! 4D imaging radar simulation.
//!
//! Rays are cast on an angular grid over the field of view; their hits are merged into the
//! radar's resolution cells (range × azimuth × elevation), one detection per occupied cell and
//! target. Whether a target is detected at all follows the radar equation: SNR ∝ σ/R⁴, with σ
//! drawn per frame from a Swerling-I (exponential) fluctuation around the class's mean RCS, and
//! detection when SNR reaches the threshold. The expected detection probability is therefore
//! exp(−threshold/mean SNR), which [`crate::probability`] uses. A detection's radial velocity
//! is the target's velocity projected on the line of sight of each hit, exactly (then averaged
//! over the cell and perturbed by Gaussian noise); a roadside radar is static, so the
//! compensated velocity equals it. Static geometry gives clutter: each static resolution cell is
//! reported with `clutter_probability` (`ground_clutter_probability` on the road surface) if its
//! SNR passes. A target yields at most `max_detections_per_target` detections (its cells with
//! the most hits). At most `max_points` detections are
//! kept, the strongest first.
//!
//! Left out: multipath and ghost targets, side lobes, targets sharing a cell (two targets in
//! one cell are reported separately), angular resolution limits beyond the cell grid, velocity
//! ambiguity (aliasing), and chirp timing (all detections carry time 0 within the frame).

use crate::error::SensorError;
use crate::lidar::{PointSource, check_mount};
use crate::noise::{rng_for, stream};
use crate::pose::{SensorPose, spherical_dir};
use crate::spec::RadarSpec;
use glam::Vec3;
use hilo_core::RadarPoint;
use hilo_raycast::{ActorSet, HitTarget, Ray, World};
use rand::Rng;
use rand_distr::{Exp1, StandardNormal};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// One radar frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RadarScan {
    pub pose: SensorPose,
    /// Detections in the sensor frame, strongest first.
    pub points: Vec<RadarPoint>,
    /// What each detection came from.
    pub sources: Vec<PointSource>,
    /// Signal-to-noise ratio of each detection, dB.
    pub snr_db: Vec<f32>,
    pub rays_cast: usize,
}

impl RadarScan {
    /// The detections in the scene's local frame.
    pub fn points_local(&self) -> Vec<RadarPoint> {
        let r = self.pose.rotation();
        self.points
            .iter()
            .map(|p| {
                let q = self.pose.position + r * Vec3::new(p.x, p.y, p.z);
                RadarPoint { x: q.x, y: q.y, z: q.z, ..*p }
            })
            .collect()
    }
}

/// Mean SNR (dB) of a target of `rcs_dbsm` at `range_m`: the radar equation, SNR ∝ σ/R⁴,
/// anchored at `snr_at_max_range_db` for 10 dBsm at `max_range_m`, less the air's two-way path
/// loss (`path_loss_db_per_m`: rain, 0 in clear air).
pub fn snr_db(spec: &RadarSpec, rcs_dbsm: f32, range_m: f32) -> f32 {
    spec.snr_at_max_range_db + (rcs_dbsm - 10.0)
        - 40.0 * (range_m.max(1e-3) / spec.max_range_m).log10()
        - 2.0 * spec.path_loss_db_per_m * range_m
}

/// Probability that a Swerling-I target of mean SNR `mean_snr_db` passes the threshold:
/// P(σ·K/R⁴ ≥ T) with σ exponential = exp(−T/SNR̄) (linear units).
pub fn swerling1_detection_probability(spec: &RadarSpec, mean_snr_db: f32) -> f32 {
    let t = 10f32.powf(spec.detection_threshold_db / 10.0);
    let s = 10f32.powf(mean_snr_db / 10.0);
    (-t / s).exp()
}

#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Key {
    Actor(u32),
    Static(u32),
    Ground,
}

struct CellHits {
    sum_pos: Vec3,
    sum_vr: f32,
    n: u32,
    min_range: f32,
}

/// Simulates one frame. `seed` should already identify the sensor and frame.
pub fn simulate_radar(
    spec: &RadarSpec,
    pose: &SensorPose,
    world: &World,
    actors: Option<&ActorSet>,
    seed: u64,
) -> Result<RadarScan, SensorError> {
    check_mount(world, actors, pose)?;
    let rot = pose.rotation();
    let (hfov, vfov) = (spec.hfov_deg.to_radians(), spec.vfov_deg.to_radians());
    let n_az = (spec.hfov_deg / spec.ray_azimuth_step_deg).round().max(1.0) as usize;
    let n_el = (spec.vfov_deg / spec.ray_elevation_step_deg).round().max(1.0) as usize;
    let (s_az, s_el) = (hfov / n_az as f32, vfov / n_el as f32);
    // Cast the grid.
    let hits: Vec<(f32, f32, hilo_raycast::Hit)> = (0..n_az * n_el)
        .into_par_iter()
        .filter_map(|i| {
            let (ia, ie) = (i / n_el, i % n_el);
            let az = -0.5 * hfov + (ia as f32 + 0.5) * s_az;
            let el = -0.5 * vfov + (ie as f32 + 0.5) * s_el;
            let ray = Ray {
                origin: pose.position,
                dir: rot * spherical_dir(az, el),
                t_min: spec.min_range_m,
                t_max: spec.max_range_m,
            };
            world.closest_hit(&ray, actors).map(|h| (az, el, h))
        })
        .collect();
    // Merge hits into resolution cells per target, accumulating exact radial velocities.
    let (rr, ar, er) =
        (spec.range_resolution_m, spec.azimuth_resolution_deg.to_radians(), spec.elevation_resolution_deg.to_radians());
    let mut cells: BTreeMap<(Key, u32, u32, u32), CellHits> = BTreeMap::new();
    let actor_list = actors.map(|a| a.actors()).unwrap_or(&[]);
    for (az, el, h) in &hits {
        let (key, velocity) = match h.target {
            HitTarget::Actor { index, id, .. } => (Key::Actor(id), actor_list[index as usize].velocity_mps),
            HitTarget::Static { object, .. } => (Key::Static(object), Vec3::ZERO),
            HitTarget::Ground => (Key::Ground, Vec3::ZERO),
        };
        let los = (h.point - pose.position).normalize_or_zero();
        let cell = (key, (h.t / rr) as u32, ((az + 0.5 * hfov) / ar) as u32, ((el + 0.5 * vfov) / er) as u32);
        let e =
            cells.entry(cell).or_insert(CellHits { sum_pos: Vec3::ZERO, sum_vr: 0.0, n: 0, min_range: f32::INFINITY });
        e.sum_pos += h.point;
        e.sum_vr += velocity.dot(los);
        e.n += 1;
        e.min_range = e.min_range.min(h.t);
    }
    // Per-target detection decision from the radar equation with a Swerling-I draw.
    let mut target_cells: BTreeMap<Key, Vec<(u32, u32, u32)>> = BTreeMap::new();
    for (key, r, a, e) in cells.keys() {
        target_cells.entry(*key).or_default().push((*r, *a, *e));
    }
    let mut out: Vec<(f32, RadarPoint, PointSource)> = Vec::new();
    let classes: BTreeMap<u32, hilo_core::Class> = actor_list.iter().map(|a| (a.id, a.class)).collect();
    for (key, target) in target_cells.iter_mut() {
        if matches!(key, Key::Actor(_)) && target.len() > spec.max_detections_per_target as usize {
            // Keep the cells with the most hits (stable: ties keep key order).
            target.sort_by_key(|c| std::cmp::Reverse(cells[&(*key, c.0, c.1, c.2)].n));
            target.truncate(spec.max_detections_per_target as usize);
        }
        let k = target.len() as f32;
        let (snr_target, rcs_total_db, source) = match key {
            Key::Actor(id) => {
                let mean = spec.rcs_dbsm.get(classes[id]);
                let mut rng = rng_for(seed, stream::RADAR_TARGET, *id as u64);
                let fluct: f32 = rng.sample(Exp1);
                let rcs = mean + 10.0 * fluct.max(1e-12).log10();
                let range =
                    target.iter().map(|c| cells[&(*key, c.0, c.1, c.2)].min_range).fold(f32::INFINITY, f32::min);
                (snr_db(spec, rcs, range), rcs, PointSource::Actor(*id))
            }
            Key::Static(_) | Key::Ground => (
                f32::NAN,
                spec.static_rcs_dbsm,
                if *key == Key::Ground { PointSource::Ground } else { PointSource::Static },
            ),
        };
        if matches!(key, Key::Actor(_)) && snr_target < spec.detection_threshold_db {
            continue;
        }
        for c in target.iter() {
            let cell = &cells[&(*key, c.0, c.1, c.2)];
            let cell_id = ((c.0 as u64) << 40) ^ ((c.1 as u64) << 20) ^ c.2 as u64;
            let target_id = match key {
                Key::Actor(id) => *id as u64,
                Key::Static(o) => (1u64 << 32) | *o as u64,
                Key::Ground => 2u64 << 32,
            };
            let mut rng = rng_for(seed ^ target_id.wrapping_mul(0x2545_F491_4F6C_DD1D), stream::RADAR_CELL, cell_id);
            let (snr, rcs) = if matches!(key, Key::Actor(_)) {
                // The target's energy is shared among its cells.
                (snr_target - 10.0 * k.log10(), rcs_total_db - 10.0 * k.log10())
            } else {
                let p = if *key == Key::Ground { spec.ground_clutter_probability } else { spec.clutter_probability };
                if rng.random::<f32>() >= p {
                    continue;
                }
                let s = snr_db(spec, rcs_total_db, cell.min_range);
                if s < spec.detection_threshold_db {
                    continue;
                }
                (s, rcs_total_db)
            };
            let mean = cell.sum_pos / cell.n as f32;
            let s = pose.to_sensor(mean);
            let range = s.length();
            let az = s.y.atan2(s.x);
            let el = (s.z / range.max(1e-6)).clamp(-1.0, 1.0).asin();
            let g = |rng: &mut rand_pcg::Pcg32| -> f32 { rng.sample(StandardNormal) };
            let range_n = (range + spec.range_noise_m * g(&mut rng)).max(spec.min_range_m);
            let az_n = az + spec.azimuth_noise_deg.to_radians() * g(&mut rng);
            let el_n = el + spec.elevation_noise_deg.to_radians() * g(&mut rng);
            let v_r = cell.sum_vr / cell.n as f32 + spec.velocity_noise_mps * g(&mut rng);
            let p = spherical_dir(az_n, el_n) * range_n;
            let rcs_n = rcs + spec.rcs_noise_db * g(&mut rng);
            out.push((
                snr,
                RadarPoint { x: p.x, y: p.y, z: p.z, rcs_dbsm: rcs_n, v_r_mps: v_r, v_r_comp_mps: v_r, time_s: 0.0 },
                source,
            ));
        }
    }
    // Strongest first; ties broken by position so the order never depends on map iteration.
    out.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.x.total_cmp(&b.1.x)).then(a.1.y.total_cmp(&b.1.y)));
    out.truncate(spec.max_points as usize);
    Ok(RadarScan {
        pose: *pose,
        snr_db: out.iter().map(|o| o.0).collect(),
        points: out.iter().map(|o| o.1).collect(),
        sources: out.iter().map(|o| o.2).collect(),
        rays_cast: n_az * n_el,
    })
}
