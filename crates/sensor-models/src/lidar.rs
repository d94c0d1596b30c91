//! Spinning-LiDAR scan simulation.
//!
//! Per beam elevation and azimuth column one ray is cast from the sensor through the scene
//! (static geometry, ground and the frame's actors). A hit becomes a return with Gaussian range
//! noise and an intensity = reflectivity × |cos incidence| × exp(−a·range); returns are then
//! dropped as CARLA does: a general rate, plus an intensity rule (probability
//! `dropoff_zero_intensity` at zero intensity, falling linearly to 0 at
//! `dropoff_intensity_limit`). A sensor with a datasheet detection range
//! ([`LidarSpec::detection_range`]) first keeps only the returns the lidar equation detects:
//! received power ρ·|cos incidence|·e^{−2αr}/r² at least the reference target's.
//!
//! Every point carries its column's time within the sweep. Given actors that move during the
//! sweep ([`hilo_raycast::ActorSet::moving`]), each column meets them where they are at its
//! time, so a moving road user is skewed as a spinning sensor sees it (a 50 ms sweep moves a
//! 20 m/s car by up to 1 m); given a still set, they are frozen at the frame's instant.
//!
//! A sensor with a [`crate::spec::Beam`] casts its beams with their width: the footprint is
//! sampled by sub-rays, their hits form echoes (a mixed pixel where two surfaces lie within the
//! separation), a thin pole intercepts only part of the pulse and is seen less far, and the
//! return mode reports the strongest, the last or both echoes ([`beam`]). Without one, a beam is
//! a ray of no width with one return.
//!
//! Left out, on purpose: the beams fire from one point (no per-laser offsets). Rain and fog act
//! through the spec ([`crate::weather::Weather::lidar`]: shorter maximum range, weaker returns,
//! and on request fog's own echo, which a beam reports as it would a surface's: [`crate::fog`]).

use crate::error::SensorError;
use crate::noise::{rng_for, stream};
use crate::pose::{SensorPose, spherical_dir};
use crate::spec::LidarSpec;
use glam::Vec3;
use hilo_core::LidarPoint;
use hilo_raycast::{ActorSet, HitTarget, Material, Ray, World};
use rand::Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;

pub mod beam;
mod window;
pub use window::{lidar_points_on, lidar_points_on_each};

/// What produced a point: the static scene, the ground, or an actor (its id); for a radar
/// also its artefacts: a road user's multipath ghost, a side lobe, a false alarm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointSource {
    Ground,
    Static,
    Actor(u32),
    /// A road user (its id) seen over a reflecting surface, at its mirror image.
    Multipath(u32),
    /// A side lobe of a stronger detection.
    SideLobe,
    /// A false alarm: noise that crossed the threshold.
    Noise,
    /// A LiDAR's echo from fog in front of it ([`crate::fog`]).
    Fog,
}

impl PointSource {
    pub(crate) fn of(t: &HitTarget) -> Self {
        match t {
            HitTarget::Ground => PointSource::Ground,
            HitTarget::Static { .. } => PointSource::Static,
            HitTarget::Actor { id, .. } => PointSource::Actor(*id),
        }
    }

    pub fn actor(&self) -> Option<u32> {
        match self {
            PointSource::Actor(id) => Some(*id),
            _ => None,
        }
    }
}

/// One LiDAR frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LidarScan {
    pub pose: SensorPose,
    /// Returns in the sensor frame, in firing order: column by column, rings ascending.
    pub points: Vec<LidarPoint>,
    /// What each point hit (same order as `points`).
    pub sources: Vec<PointSource>,
    /// Rays fired (beams × columns).
    pub rays_cast: usize,
}

impl LidarScan {
    /// The points in the scene's local frame.
    pub fn points_local(&self) -> Vec<LidarPoint> {
        let r = self.pose.rotation();
        self.points
            .iter()
            .map(|p| {
                let q = self.pose.position + r * Vec3::new(p.x, p.y, p.z);
                LidarPoint { x: q.x, y: q.y, z: q.z, ..*p }
            })
            .collect()
    }

    /// Number of points on each actor id.
    pub fn points_per_actor(&self) -> std::collections::BTreeMap<u32, usize> {
        let mut m = std::collections::BTreeMap::new();
        for s in &self.sources {
            if let Some(id) = s.actor() {
                *m.entry(id).or_default() += 1;
            }
        }
        m
    }
}

/// Intensity of a return: reflectivity × |cos incidence| × exp(−a·range), in [0, 1].
pub fn intensity(reflectivity: f32, cos_incidence: f32, range_m: f32, attenuation_per_m: f32) -> f32 {
    (reflectivity * cos_incidence.abs() * (-attenuation_per_m * range_m).exp()).clamp(0.0, 1.0)
}

/// Probability that a return of this intensity survives the drop-off rules.
pub fn survival_probability(spec: &LidarSpec, intensity: f32) -> f32 {
    let p_int = if intensity >= spec.dropoff_intensity_limit || spec.dropoff_intensity_limit <= 0.0 {
        0.0
    } else {
        spec.dropoff_zero_intensity * (1.0 - intensity / spec.dropoff_intensity_limit)
    };
    (1.0 - spec.dropoff_general_rate) * (1.0 - p_int)
}

/// Refuses a mount at or below the ground plane (where it spans), or inside geometry: if the
/// four horizontal directions and straight up all hit the same static object within 60 m
/// (straight down is left out: a floor coincides with the ground plane), or if the position is
/// inside an actor. A heuristic: a sensor inside an open mesh (no roof) is not caught, and one
/// enclosed by a single large object (a tunnel) is refused.
pub fn check_mount(world: &World, actors: Option<&ActorSet>, pose: &SensorPose) -> Result<(), SensorError> {
    const WITHIN: f32 = 60.0;
    if !pose.is_valid() {
        return Err(SensorError::Pose(format!("{pose:?} has a non-finite value")));
    }
    let p = pose.position;
    if let Some(g) = world.ground() {
        let xy = p.truncate();
        if p.z <= g.z_m && xy.cmpge(g.min).all() && xy.cmple(g.max).all() {
            return Err(SensorError::Pose(format!(
                "z = {} m is at or below the ground (z = {} m): a sensor there sees nothing but the road's underside",
                p.z, g.z_m
            )));
        }
    }
    if let Some(a) = actors.and_then(|s| s.actors().iter().find(|a| a.contains(p))) {
        return Err(SensorError::InsideGeometry {
            position: p.to_array(),
            what: format!("actor {} ({})", a.id, a.class),
            within_m: 0.0,
        });
    }
    let mut object = None;
    for d in [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z] {
        let ray = Ray { origin: p, dir: d, t_min: 0.0, t_max: WITHIN };
        match world.closest_hit(&ray, None).map(|h| h.target) {
            Some(HitTarget::Static { object: o, .. }) if object.is_none_or(|x| x == o) => object = Some(o),
            _ => return Ok(()),
        }
    }
    let name = object
        .and_then(|o| world.objects().get(o as usize))
        .map_or_else(|| "static geometry".to_owned(), |o| o.name.clone());
    Err(SensorError::InsideGeometry { position: p.to_array(), what: name, within_m: WITHIN })
}

/// One sensor's scan pattern over one frame: what every ray of it returns. The full scan
/// ([`simulate_lidar`]) and the count on chosen road users ([`lidar_points_on`]) cast their rays
/// through it, so a ray gives the same return whichever of the two casts it.
struct Scanner<'a> {
    spec: &'a LidarSpec,
    pose: &'a SensorPose,
    world: &'a World,
    actors: Option<&'a ActorSet>,
    seed: u64,
    elevations: Vec<f32>,
    cols: usize,
    hfov: f32,
    full_circle: bool,
    step: f32,
    period: f32,
    rot: glam::Quat,
    /// The sub-rays of a beam of finite width ([`LidarSpec::beam`]); none: one ray of no width.
    footprint: Option<beam::Footprint>,
}

impl<'a> Scanner<'a> {
    fn new(
        spec: &'a LidarSpec,
        pose: &'a SensorPose,
        world: &'a World,
        actors: Option<&'a ActorSet>,
        seed: u64,
    ) -> Self {
        let cols = spec.columns() as usize;
        let hfov = spec.hfov_deg.to_radians();
        Scanner {
            spec,
            pose,
            world,
            actors,
            seed,
            elevations: spec.elevations_rad(),
            cols,
            hfov,
            full_circle: spec.hfov_deg >= 360.0,
            step: hfov / cols as f32,
            period: 1.0 / spec.rate_hz,
            rot: pose.rotation(),
            footprint: spec.beam.as_ref().map(beam::Footprint::new),
        }
    }

    /// Column `k`'s azimuth in the sensor frame.
    fn azimuth(&self, k: usize) -> f32 {
        if self.full_circle { k as f32 * self.step } else { -0.5 * self.hfov + (k as f32 + 0.5) * self.step }
    }

    /// The surface a ray returns from when its first hit is foliage that moves ([`Foliage`]): the
    /// leaf, displaced along the ray (the second value), or, through a gap, whatever lies behind
    /// (None: nothing). Any other hit, or still foliage, is returned as it is. Draws from its own
    /// stream, so a scan without foliage keeps its bytes.
    fn through_foliage(
        &self,
        ray: &Ray,
        hit: hilo_raycast::Hit,
        time_s: f32,
        index: usize,
    ) -> Option<(hilo_raycast::Hit, f32)> {
        let Some(f) = &self.spec.foliage else { return Some((hit, 0.0)) };
        if !(matches!(hit.target, HitTarget::Static { .. }) && hit.material == Material::Vegetation) {
            return Some((hit, 0.0));
        }
        let mut rng = rng_for(self.seed, stream::LIDAR_FOLIAGE, index as u64);
        if rng.random::<f32>() < f.gap_probability {
            // Through a gap: the next surface along the ray (one gap per ray; a second crown
            // behind returns as it is).
            let behind = Ray { t_min: hit.t + 0.05, ..*ray };
            return self.world.closest_hit_at(&behind, self.actors, time_s).map(|h| (h, 0.0));
        }
        let sway: f32 = rng.sample(StandardNormal);
        Some((hit, f.sway_m * sway))
    }

    /// The returns of ring `ring` in column `k`: none or one, or two from a dual-return beam.
    fn ray(&self, k: usize, ring: usize) -> Returns {
        match &self.footprint {
            None => [self.thin_ray(k, ring), None],
            Some(f) => self.wide_ray(k, ring, f),
        }
    }

    /// The time within the sweep at which column `k` fires, s.
    fn time_s(&self, k: usize) -> f32 {
        self.period * k as f32 / self.cols as f32
    }

    /// The reflectivity of what `hit` met.
    fn reflectivity(&self, hit: &hilo_raycast::Hit) -> f32 {
        match (hit.target, self.actors) {
            (HitTarget::Actor { index, .. }, Some(set)) => set.actors()[index as usize].reflectivity,
            _ => hit.material.lidar_reflectivity(),
        }
    }

    /// The return of a ray of no width, if any. In fog with its echo ([`crate::fog`]) the ray
    /// reports the stronger of the fog's echo and the hard target's (a single-return sensor
    /// reports its strongest), the fog's alone where no surface is seen behind it.
    fn thin_ray(&self, k: usize, ring: usize) -> Option<(LidarPoint, PointSource)> {
        let (spec, beams) = (self.spec, self.elevations.len());
        let time_s = self.time_s(k);
        let d_sensor = spherical_dir(self.azimuth(k), self.elevations[ring]);
        let index = k * beams + ring;
        let hard = self.thin_hard(index, d_sensor, time_s);
        let fog = self.fog_return(index, hard.as_ref().map(|h| h.range_m));
        let (range, reflectance, source, survive) = match (hard, fog) {
            (Some(h), Some(f)) if f.power > h.power => (f.range_m, f.reflectance, PointSource::Fog, f.survive),
            (Some(mut h), _) => {
                let survive = h.rng.random::<f32>();
                (h.range_m, h.reflectance, h.source, survive)
            }
            (None, Some(f)) => (f.range_m, f.reflectance, PointSource::Fog, f.survive),
            (None, None) => return None,
        };
        let i = intensity(reflectance, 1.0, range, spec.atmosphere_attenuation_per_m);
        if survive >= survival_probability(spec, i) {
            return None;
        }
        let p = d_sensor * range;
        Some((LidarPoint { x: p.x, y: p.y, z: p.z, intensity: i, ring: ring as u16, time_s }, source))
    }

    /// The hard target a ray of no width sees, before the drop-off: its noisy range, ρ·|cos|,
    /// received power and source, and the ray's generator, whose next draw is the drop-off's.
    fn thin_hard(&self, index: usize, d_sensor: Vec3, time_s: f32) -> Option<HardReturn> {
        let spec = self.spec;
        let ray = Ray {
            origin: self.pose.position,
            dir: self.rot * d_sensor,
            t_min: spec.min_range_m,
            t_max: spec.max_range_m,
        };
        // Moving actors (a set built with a span) are met where they are when this column
        // fires: the rolling shutter of a spinning sensor.
        let hit = self.world.closest_hit_at(&ray, self.actors, time_s)?;
        let mut rng = rng_for(self.seed, stream::LIDAR_RAY, index as u64);
        let noise: f32 = rng.sample(StandardNormal);
        let (hit, sway) = self.through_foliage(&ray, hit, time_s, index)?;
        let range = hit.t + spec.range_noise_m * noise + sway;
        if range <= spec.min_range_m || range > spec.max_range_m {
            return None;
        }
        let cos_inc = hit.normal.dot(ray.dir);
        let reflectivity = self.reflectivity(&hit);
        if !spec.detects(reflectivity, cos_inc, range) {
            return None;
        }
        let reflectance = reflectivity * cos_inc.abs();
        let power = reflectance * (-2.0 * spec.extinction_per_m * range).exp() / (range * range);
        Some(HardReturn { range_m: range, reflectance, power, source: PointSource::of(&hit.target), rng })
    }

    /// The fog's echo on ray `index` ([`crate::fog`]), if the weather gives one, the sensor sees it
    /// and it lies before the hard target at `hard_m` (a target within the echo's span masks
    /// it): its range drawn over the echo's crest, and the drop-off's draw.
    fn fog_return(&self, index: usize, hard_m: Option<f32>) -> Option<FogReturn> {
        let echo = self.spec.fog_echo.as_ref()?;
        if hard_m.is_some_and(|h| h <= echo.span_m.1) || !self.spec.detects_power(echo.power) {
            return None;
        }
        let mut rng = rng_for(self.seed, stream::LIDAR_FOG, index as u64);
        let range_m = echo.range_at(rng.random());
        let survive = rng.random();
        if range_m <= self.spec.min_range_m {
            return None;
        }
        let reflectance = echo.reflectance_at(range_m, self.spec.extinction_per_m);
        Some(FogReturn { range_m, reflectance, power: echo.power, survive })
    }

    /// The returns of a beam of finite width ([`beam`]): its sub-rays cast, their hits grouped
    /// into echoes, the echoes the return mode reports kept when the lidar equation sees them,
    /// each then drawn its range noise and drop-off in range order. A point lies on the beam's
    /// axis at its echo's range, as a sensor reports it.
    fn wide_ray(&self, k: usize, ring: usize, footprint: &beam::Footprint) -> Returns {
        let (spec, beams, b) = (self.spec, self.elevations.len(), &footprint.beam);
        let time_s = self.time_s(k);
        let (az, el) = (self.azimuth(k), self.elevations[ring]);
        let d_sensor = spherical_dir(az, el);
        let index = k * beams + ring;
        let two_alpha = 2.0 * spec.extinction_per_m;
        let mut hits = Vec::with_capacity(footprint.samples.len());
        for (j, (dir, sample)) in footprint.directions(az, el, d_sensor).enumerate() {
            let ray = Ray {
                origin: self.pose.position,
                dir: self.rot * dir,
                t_min: spec.min_range_m,
                t_max: spec.max_range_m,
            };
            let Some(hit) = self.world.closest_hit_at(&ray, self.actors, time_s) else { continue };
            // Each sub-ray draws its own gap and leaf (a crown's leaves are smaller than the spot).
            let Some((hit, sway)) = self.through_foliage(&ray, hit, time_s, index * beam::MAX_SUB_RAYS + j) else {
                continue;
            };
            let range_m = hit.t + sway;
            if range_m <= spec.min_range_m || range_m > spec.max_range_m {
                continue;
            }
            let reflectance = sample.weight * self.reflectivity(&hit) * hit.normal.dot(ray.dir).abs();
            let power = reflectance * (-two_alpha * range_m).exp() / (range_m * range_m);
            hits.push(beam::SubHit { range_m, reflectance, power, source: PointSource::of(&hit.target) });
        }
        let mut echoes = beam::echoes(&mut hits, b.separation_m);
        // The fog's echo, in front of the nearest surface's by more than the separation.
        let nearest = echoes.first().map(|e| e.range_m - b.separation_m);
        if let Some(f) = self.fog_return(index, nearest) {
            let fog =
                beam::Echo { range_m: f.range_m, reflectance: f.reflectance, power: f.power, source: PointSource::Fog };
            echoes.insert(0, fog);
        }
        let mut rng = rng_for(self.seed, stream::LIDAR_RAY, index as u64);
        let mut out = [None, None];
        for (slot, e) in out.iter_mut().zip(beam::reported(&echoes, b.returns, |e| spec.detects_power(e.power))) {
            let noise: f32 = rng.sample(StandardNormal);
            let survive: f32 = rng.random();
            let range = e.range_m + spec.range_noise_m * noise;
            if range <= spec.min_range_m || range > spec.max_range_m {
                continue;
            }
            let i = intensity(e.reflectance, 1.0, range, spec.atmosphere_attenuation_per_m);
            if survive >= survival_probability(spec, i) {
                continue;
            }
            let p = d_sensor * range;
            *slot = Some((LidarPoint { x: p.x, y: p.y, z: p.z, intensity: i, ring: ring as u16, time_s }, e.source));
        }
        out
    }
}

/// A ray's returns: none, one, or two (a dual-return beam), nearest first.
type Returns = [Option<(LidarPoint, PointSource)>; 2];

/// What a ray of no width returns from a surface, before the drop-off.
struct HardReturn {
    range_m: f32,
    /// ρ·|cos incidence|.
    reflectance: f32,
    /// ρ·|cos|·e^{−2αr}/r².
    power: f32,
    source: PointSource,
    rng: rand_pcg::Pcg32,
}

/// The fog's echo on one ray: its range, the reflectance its intensity is computed from, its
/// received power, and the drop-off's draw.
struct FogReturn {
    range_m: f32,
    reflectance: f32,
    power: f32,
    survive: f32,
}

/// Simulates one frame. `seed` should already identify the sensor and frame (see
/// [`crate::noise::mix`]); the same inputs give identical scans.
pub fn simulate_lidar(
    spec: &LidarSpec,
    pose: &SensorPose,
    world: &World,
    actors: Option<&ActorSet>,
    seed: u64,
) -> Result<LidarScan, SensorError> {
    check_mount(world, actors, pose)?;
    let scanner = Scanner::new(spec, pose, world, actors, seed);
    let (cols, beams) = (scanner.cols, scanner.elevations.len());
    // Columns in blocks: enough tasks for the thread pool, few allocations.
    const BLOCK: usize = 32;
    let blocks: Vec<(Vec<LidarPoint>, Vec<PointSource>)> = (0..cols.div_ceil(BLOCK))
        .into_par_iter()
        .map(|blk| {
            let mut pts = Vec::with_capacity(BLOCK * beams);
            let mut src = Vec::with_capacity(BLOCK * beams);
            for k in blk * BLOCK..((blk + 1) * BLOCK).min(cols) {
                for ring in 0..beams {
                    for (p, s) in scanner.ray(k, ring).into_iter().flatten() {
                        pts.push(p);
                        src.push(s);
                    }
                }
            }
            (pts, src)
        })
        .collect();
    let n: usize = blocks.iter().map(|b| b.0.len()).sum();
    let mut points = Vec::with_capacity(n);
    let mut sources = Vec::with_capacity(n);
    for (p, s) in blocks {
        points.extend(p);
        sources.extend(s);
    }
    Ok(LidarScan { pose: *pose, points, sources, rays_cast: cols * beams })
}
