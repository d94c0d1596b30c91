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
//! The effects of a real radar beyond this ideal one (azimuth by angle, unresolved targets,
//! multipath ghosts, side lobes, false alarms, vegetation Doppler, RCS by aspect) are catalog
//! settings, off when absent: see [`crate::radar_effects`]. Left out still: velocity ambiguity
//! (aliasing), and chirp timing (all detections carry time 0 within the frame).

use crate::error::SensorError;
use crate::lidar::{PointSource, check_mount};
use crate::noise::{rng_for, stream};
use crate::pose::{SensorPose, spherical_dir};
use crate::radar_effects::{Azimuth, SIDE_LOBE_OFFSET, aspect_db};
use crate::spec::RadarSpec;
use glam::Vec3;
use hilo_core::RadarPoint;
use hilo_raycast::{Actor, ActorSet, HitTarget, Material, Ray, World};
use rand::Rng;
use rand_distr::{Exp1, Poisson, StandardNormal};
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

/// What a detection comes from. The order is the order the ideal model has always emitted
/// its targets in (actors, static objects, the ground); the effects' sources come after.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Key {
    Actor(u32),
    Static(u32),
    Ground,
    /// A road user's ghost over a wall (`wall` true) or over the road.
    Multipath {
        id: u32,
        wall: bool,
    },
    /// The k-th side lobe (two per parent detection).
    SideLobe(u32),
    /// The k-th false alarm.
    Noise(u32),
}

impl Key {
    fn source(self) -> PointSource {
        match self {
            Key::Actor(id) => PointSource::Actor(id),
            Key::Static(_) => PointSource::Static,
            Key::Ground => PointSource::Ground,
            Key::Multipath { id, .. } => PointSource::Multipath(id),
            Key::SideLobe(_) => PointSource::SideLobe,
            Key::Noise(_) => PointSource::Noise,
        }
    }

    /// Separates the random streams of the targets.
    fn rng_id(self) -> u64 {
        match self {
            Key::Actor(id) => id as u64,
            Key::Static(o) => (1u64 << 32) | o as u64,
            Key::Ground => 2u64 << 32,
            Key::Multipath { id, wall } => (3u64 << 32) | ((id as u64) << 1) | wall as u64,
            Key::SideLobe(k) => (4u64 << 32) | k as u64,
            Key::Noise(k) => (5u64 << 32) | k as u64,
        }
    }
}

struct CellHits {
    sum_pos: Vec3,
    sum_vr: f32,
    n: u32,
    min_range: f32,
    vegetation: bool,
}

/// A hit of the grid, or a road user seen over a reflecting surface: where the radar places
/// it (`point`, at the path's length along the first ray), its range and its radial velocity.
struct Return {
    key: Key,
    az: f32,
    el: f32,
    range: f32,
    point: Vec3,
    v_r: f32,
    vegetation: bool,
}

/// A detection before measurement noise.
struct Candidate {
    key: Key,
    snr_db: f32,
    rcs_db: f32,
    /// Mean position of its hits, scene frame.
    pos: Vec3,
    v_r: f32,
    rng: rand_pcg::Pcg32,
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
    let azimuth = spec.azimuth();
    let actor_list = actors.map(|a| a.actors()).unwrap_or(&[]);
    let (returns, rays_cast) = cast(spec, pose, world, actors);
    let cells = bin(spec, &azimuth, &returns);
    let mut candidates = detect(spec, pose, actor_list, &cells, seed);
    let fx = &spec.effects;
    if let Some(level) = fx.side_lobe_level_db {
        candidates.extend(side_lobes(spec, &azimuth, pose, &candidates, level, seed));
    }
    if fx.false_alarms_per_frame > 0.0 {
        candidates.extend(false_alarms(spec, pose, seed));
    }
    if let Some(dres) = fx.doppler_resolution_mps {
        candidates = merge_unresolved(spec, &azimuth, pose, candidates, dres);
    }
    let mut out: Vec<(f32, RadarPoint, PointSource)> =
        candidates.into_iter().map(|c| measure(spec, &azimuth, pose, c)).collect();
    // Strongest first; ties broken by position so the order never depends on map iteration.
    out.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.x.total_cmp(&b.1.x)).then(a.1.y.total_cmp(&b.1.y)));
    out.truncate(spec.max_points as usize);
    Ok(RadarScan {
        pose: *pose,
        snr_db: out.iter().map(|o| o.0).collect(),
        points: out.iter().map(|o| o.1).collect(),
        sources: out.iter().map(|o| o.2).collect(),
        rays_cast,
    })
}

/// Whether a static surface reflects a 77 GHz wave specularly: smooth structures do,
/// foliage and grass scatter it.
fn specular(m: Material) -> bool {
    !matches!(m, Material::Vegetation | Material::Grass)
}

/// Casts the ray grid; with multipath on, reflects the rays that meet a smooth static surface
/// and keeps the road users they meet. Returns the returns and the number of primary rays.
fn cast(spec: &RadarSpec, pose: &SensorPose, world: &World, actors: Option<&ActorSet>) -> (Vec<Return>, usize) {
    let rot = pose.rotation();
    let (hfov, vfov) = (spec.hfov_deg.to_radians(), spec.vfov_deg.to_radians());
    let n_az = (spec.hfov_deg / spec.ray_azimuth_step_deg).round().max(1.0) as usize;
    let n_el = (spec.vfov_deg / spec.ray_elevation_step_deg).round().max(1.0) as usize;
    let (s_az, s_el) = (hfov / n_az as f32, vfov / n_el as f32);
    let actor_list = actors.map(|a| a.actors()).unwrap_or(&[]);
    let fx = &spec.effects;
    let multipath = fx.wall_multipath_loss_db.is_some() || fx.ground_multipath_loss_db.is_some();
    let returns: Vec<Vec<Return>> = (0..n_az * n_el)
        .into_par_iter()
        .map(|i| {
            let (ia, ie) = (i / n_el, i % n_el);
            let az = -0.5 * hfov + (ia as f32 + 0.5) * s_az;
            let el = -0.5 * vfov + (ie as f32 + 0.5) * s_el;
            let dir = rot * spherical_dir(az, el);
            let ray = Ray { origin: pose.position, dir, t_min: spec.min_range_m, t_max: spec.max_range_m };
            let Some(h) = world.closest_hit(&ray, actors) else { return Vec::new() };
            let (key, velocity) = match h.target {
                HitTarget::Actor { index, id, .. } => (Key::Actor(id), actor_list[index as usize].velocity_mps),
                HitTarget::Static { object, .. } => (Key::Static(object), Vec3::ZERO),
                HitTarget::Ground => (Key::Ground, Vec3::ZERO),
            };
            let los = (h.point - pose.position).normalize_or_zero();
            let direct = Return {
                key,
                az,
                el,
                range: h.t,
                point: h.point,
                v_r: velocity.dot(los),
                vegetation: h.material == Material::Vegetation,
            };
            let mut out = vec![direct];
            if multipath && !matches!(key, Key::Actor(_)) && specular(h.material) {
                out.extend(bounce(spec, world, actors, &ray, &h, az, el));
            }
            out
        })
        .collect();
    (returns.into_iter().flatten().collect(), n_az * n_el)
}

/// The ghost of a road user met by `ray`'s specular reflection at `h`, if the effect is on for
/// that surface: seen along the first ray at the path's length, the mirror image of the road
/// user in the surface, moving along the reflected ray.
fn bounce(
    spec: &RadarSpec,
    world: &World,
    actors: Option<&ActorSet>,
    ray: &Ray,
    h: &hilo_raycast::Hit,
    az: f32,
    el: f32,
) -> Option<Return> {
    let wall = h.normal.z.abs() < 0.9;
    let fx = &spec.effects;
    if (wall && fx.wall_multipath_loss_db.is_none()) || (!wall && fx.ground_multipath_loss_db.is_none()) {
        return None;
    }
    let d2 = ray.dir - 2.0 * ray.dir.dot(h.normal) * h.normal;
    let second = Ray { origin: h.point + 1e-3 * h.normal, dir: d2, t_min: 0.0, t_max: spec.max_range_m - h.t };
    let g = world.closest_hit(&second, actors)?;
    let HitTarget::Actor { index, id, .. } = g.target else { return None };
    let actor = &actors?.actors()[index as usize];
    let range = h.t + g.t;
    Some(Return {
        key: Key::Multipath { id, wall },
        az,
        el,
        range,
        point: ray.origin + ray.dir * range,
        v_r: actor.velocity_mps.dot(d2),
        vegetation: false,
    })
}

/// Merges the returns into resolution cells (range × azimuth × elevation) per target.
fn bin(spec: &RadarSpec, azimuth: &Azimuth, returns: &[Return]) -> BTreeMap<(Key, u32, u32, u32), CellHits> {
    let (rr, er) = (spec.range_resolution_m, spec.elevation_resolution_deg.to_radians());
    let vfov = spec.vfov_deg.to_radians();
    let mut cells: BTreeMap<(Key, u32, u32, u32), CellHits> = BTreeMap::new();
    for r in returns {
        let cell = (r.key, (r.range / rr) as u32, azimuth.cell(r.az), ((r.el + 0.5 * vfov) / er) as u32);
        let e = cells.entry(cell).or_insert(CellHits {
            sum_pos: Vec3::ZERO,
            sum_vr: 0.0,
            n: 0,
            min_range: f32::INFINITY,
            vegetation: false,
        });
        e.sum_pos += r.point;
        e.sum_vr += r.v_r;
        e.n += 1;
        e.min_range = e.min_range.min(r.range);
        e.vegetation |= r.vegetation;
    }
    cells
}

/// Per-target detection decision from the radar equation with a Swerling-I draw, the
/// target's strongest cells, and the static cells reported as clutter.
fn detect(
    spec: &RadarSpec,
    pose: &SensorPose,
    actor_list: &[Actor],
    cells: &BTreeMap<(Key, u32, u32, u32), CellHits>,
    seed: u64,
) -> Vec<Candidate> {
    let mut target_cells: BTreeMap<Key, Vec<(u32, u32, u32)>> = BTreeMap::new();
    for (key, r, a, e) in cells.keys() {
        target_cells.entry(*key).or_default().push((*r, *a, *e));
    }
    let by_id: BTreeMap<u32, &Actor> = actor_list.iter().map(|a| (a.id, a)).collect();
    let mut out = Vec::new();
    for (key, target) in target_cells.iter_mut() {
        let road_user = match key {
            Key::Actor(id) | Key::Multipath { id, .. } => Some(*id),
            _ => None,
        };
        if road_user.is_some() && target.len() > spec.max_detections_per_target as usize {
            // Keep the cells with the most hits (stable: ties keep key order).
            target.sort_by_key(|c| std::cmp::Reverse(cells[&(*key, c.0, c.1, c.2)].n));
            target.truncate(spec.max_detections_per_target as usize);
        }
        let k = target.len() as f32;
        let (snr_target, rcs_total_db) = match road_user {
            Some(id) => {
                let rcs = target_rcs_dbsm(spec, by_id[&id], pose.position, seed);
                let range =
                    target.iter().map(|c| cells[&(*key, c.0, c.1, c.2)].min_range).fold(f32::INFINITY, f32::min);
                let loss = match key {
                    Key::Multipath { wall: true, .. } => spec.effects.wall_multipath_loss_db.unwrap_or(0.0),
                    Key::Multipath { wall: false, .. } => spec.effects.ground_multipath_loss_db.unwrap_or(0.0),
                    _ => 0.0,
                };
                (snr_db(spec, rcs, range) - loss, rcs - loss)
            }
            None => (f32::NAN, spec.static_rcs_dbsm),
        };
        if road_user.is_some() && snr_target < spec.detection_threshold_db {
            continue;
        }
        for c in target.iter() {
            let cell = &cells[&(*key, c.0, c.1, c.2)];
            let cell_id = ((c.0 as u64) << 40) ^ ((c.1 as u64) << 20) ^ c.2 as u64;
            let mut rng = rng_for(seed ^ key.rng_id().wrapping_mul(0x2545_F491_4F6C_DD1D), stream::RADAR_CELL, cell_id);
            let (snr, rcs) = if road_user.is_some() {
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
            let mut v_r = cell.sum_vr / cell.n as f32;
            if cell.vegetation && spec.effects.vegetation_doppler_mps > 0.0 {
                v_r += spec.effects.vegetation_doppler_mps * rng.sample::<f32, _>(StandardNormal);
            }
            out.push(Candidate { key: *key, snr_db: snr, rcs_db: rcs, pos: cell.sum_pos / cell.n as f32, v_r, rng });
        }
    }
    out
}

/// A road user's RCS in one frame, dBsm: its class's mean, the aspect term
/// ([`crate::radar_effects::aspect_db`]) and a Swerling-I (exponential) fluctuation drawn once
/// per frame and road user, shared by its ghosts.
pub fn target_rcs_dbsm(spec: &RadarSpec, actor: &Actor, sensor: Vec3, seed: u64) -> f32 {
    let mean = spec.rcs_dbsm.get(actor.class) + aspect_db(&spec.effects, actor, sensor);
    let mut rng = rng_for(seed, stream::RADAR_TARGET, actor.id as u64);
    let fluct: f32 = rng.sample(Exp1);
    mean + 10.0 * fluct.max(1e-12).log10()
}

/// Range, azimuth and elevation of a scene point in the sensor's frame.
fn spherical(pose: &SensorPose, p: Vec3) -> (f32, f32, f32) {
    let s = pose.to_sensor(p);
    let range = s.length();
    (range, s.y.atan2(s.x), (s.z / range.max(1e-6)).clamp(-1.0, 1.0).asin())
}

/// Two side lobes of each detection strong enough that they pass the threshold `level` dB
/// weaker, at ±[`SIDE_LOBE_OFFSET`] resolutions in azimuth, same range, elevation and Doppler.
fn side_lobes(
    spec: &RadarSpec,
    azimuth: &Azimuth,
    pose: &SensorPose,
    detections: &[Candidate],
    level: f32,
    seed: u64,
) -> Vec<Candidate> {
    let half = 0.5 * spec.hfov_deg.to_radians();
    let mut out = Vec::new();
    for d in detections.iter().filter(|d| d.snr_db - level >= spec.detection_threshold_db) {
        let (range, az, el) = spherical(pose, d.pos);
        for side in [-1.0f32, 1.0] {
            let az_s = az + side * SIDE_LOBE_OFFSET * azimuth.resolution(az);
            if az_s.abs() > half {
                continue;
            }
            let k = out.len() as u32;
            let key = Key::SideLobe(k);
            out.push(Candidate {
                key,
                snr_db: d.snr_db - level,
                rcs_db: d.rcs_db - level,
                pos: pose.position + pose.rotation() * (spherical_dir(az_s, el) * range),
                v_r: d.v_r,
                rng: rng_for(seed, stream::RADAR_ARTEFACT, key.rng_id()),
            });
        }
    }
    out
}

/// Noise crossings of the threshold: Poisson in number, uniform over the field's range,
/// azimuth and elevation and over ± `false_alarm_speed_mps`; power = threshold + Exp(1)
/// (noise power, unit mean, conditioned on crossing the threshold).
fn false_alarms(spec: &RadarSpec, pose: &SensorPose, seed: u64) -> Vec<Candidate> {
    let fx = &spec.effects;
    let mut rng = rng_for(seed, stream::RADAR_ARTEFACT, Key::Noise(u32::MAX).rng_id());
    let n = Poisson::new(fx.false_alarms_per_frame as f64).map(|p| rng.sample(p) as u32).unwrap_or(0);
    let threshold = 10f32.powf(spec.detection_threshold_db / 10.0);
    let (h, v) = (0.5 * spec.hfov_deg.to_radians(), 0.5 * spec.vfov_deg.to_radians());
    (0..n)
        .map(|k| {
            let key = Key::Noise(k);
            let mut r = rng_for(seed, stream::RADAR_ARTEFACT, key.rng_id());
            let range = spec.min_range_m + (spec.max_range_m - spec.min_range_m) * r.random::<f32>();
            let az = -h + 2.0 * h * r.random::<f32>();
            let el = -v + 2.0 * v * r.random::<f32>();
            let excess: f32 = r.sample(Exp1);
            let snr = 10.0 * (threshold + excess).log10();
            let v_r = fx.false_alarm_speed_mps * (2.0 * r.random::<f32>() - 1.0);
            Candidate {
                key,
                snr_db: snr,
                rcs_db: snr - snr_db(spec, 10.0, range) + 10.0,
                pos: pose.position + pose.rotation() * (spherical_dir(az, el) * range),
                v_r,
                rng: r,
            }
        })
        .collect()
}

/// Merges detections of different sources that the radar cannot resolve: closer than one
/// resolution in range, azimuth (at the stronger one's angle), elevation and Doppler. The
/// stronger absorbs the weaker: powers add, position and velocity are power-weighted.
fn merge_unresolved(
    spec: &RadarSpec,
    azimuth: &Azimuth,
    pose: &SensorPose,
    mut candidates: Vec<Candidate>,
    doppler_resolution: f32,
) -> Vec<Candidate> {
    // Strongest first; ties keep creation order.
    candidates.sort_by(|a, b| b.snr_db.total_cmp(&a.snr_db));
    let er = spec.elevation_resolution_deg.to_radians();
    struct Kept {
        c: Candidate,
        at: (f32, f32, f32),
        power: f32,
        rcs_lin: f32,
        w_pos: Vec3,
        w_v: f32,
    }
    let mut kept: Vec<Kept> = Vec::new();
    for c in candidates {
        let at = spherical(pose, c.pos);
        let power = 10f32.powf(c.snr_db / 10.0);
        let rcs_lin = 10f32.powf(c.rcs_db / 10.0);
        let host = kept.iter_mut().find(|k| {
            k.c.key != c.key
                && (k.at.0 - at.0).abs() < spec.range_resolution_m
                && (k.at.1 - at.1).abs() < azimuth.resolution(k.at.1)
                && (k.at.2 - at.2).abs() < er
                && (k.c.v_r - c.v_r).abs() < doppler_resolution
        });
        match host {
            Some(k) => {
                k.power += power;
                k.rcs_lin += rcs_lin;
                k.w_pos += c.pos * power;
                k.w_v += c.v_r * power;
            }
            None => kept.push(Kept { w_pos: c.pos * power, w_v: c.v_r * power, c, at, power, rcs_lin }),
        }
    }
    kept.into_iter()
        .map(|k| Candidate {
            snr_db: 10.0 * k.power.log10(),
            rcs_db: 10.0 * k.rcs_lin.log10(),
            pos: k.w_pos / k.power,
            v_r: k.w_v / k.power,
            ..k.c
        })
        .collect()
}

/// Measurement noise on a detection: range, azimuth (the accuracy at its angle), elevation,
/// radial velocity and RCS; the point in the sensor frame.
fn measure(spec: &RadarSpec, azimuth: &Azimuth, pose: &SensorPose, c: Candidate) -> (f32, RadarPoint, PointSource) {
    let mut rng = c.rng;
    let (range, az, el) = spherical(pose, c.pos);
    let g = |rng: &mut rand_pcg::Pcg32| -> f32 { rng.sample(StandardNormal) };
    let range_n = (range + spec.range_noise_m * g(&mut rng)).max(spec.min_range_m);
    let az_n = az + azimuth.accuracy(az) * g(&mut rng);
    let el_n = el + spec.elevation_noise_deg.to_radians() * g(&mut rng);
    let v_r = c.v_r + spec.velocity_noise_mps * g(&mut rng);
    let p = spherical_dir(az_n, el_n) * range_n;
    let rcs_n = c.rcs_db + spec.rcs_noise_db * g(&mut rng);
    (
        c.snr_db,
        RadarPoint { x: p.x, y: p.y, z: p.z, rcs_dbsm: rcs_n, v_r_mps: v_r, v_r_comp_mps: v_r, time_s: 0.0 },
        c.key.source(),
    )
}
