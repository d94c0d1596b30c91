//! A LiDAR's points on chosen road users without the full scan: only the rays whose
//! directions can meet a road user's bounds are cast.
//!
//! A ray that returns a point on a road user passed through the road user's bounding box (its
//! axis-aligned bounds, swept over the set's span for moving actors), so its direction lies in
//! the cone the box subtends at the sensor. In the sensor frame that cone's azimuths lie
//! between the extreme azimuths of the box's eight corners (when the sensor's vertical axis
//! misses the box's footprint; otherwise every column), and its elevations between
//! atan2(z_max, r_min) and atan2(z_min, r_min) widened to the corners' own (r_min: the least
//! horizontal distance to the footprint, the convex hull of the projected corners, which an
//! edge between two corners attains). The rays of the pattern inside these windows, plus a
//! margin (a beam of finite width: its box grown by the footprint's spread at the box's far
//! corner), are cast through the same [`super::Scanner`] the full scan uses, with the same
//! per-ray random draws, so the counts equal the full scan's exactly; the test
//! `windowed_counts_equal_the_full_scan` holds them to it.

use super::Scanner;
use crate::error::SensorError;
use crate::pose::SensorPose;
use crate::spec::LidarSpec;
use glam::{Vec2, Vec3};
use hilo_raycast::{ActorSet, World};
use std::collections::BTreeMap;
use std::f32::consts::{PI, TAU};

/// Angular margin of every window, rad: well above the rounding of an f32 direction.
const MARGIN_RAD: f32 = 2e-3;

/// The azimuth interval [lo, hi] (hi − lo < 2π, or `None` for every azimuth) and the elevation
/// interval of the directions from the origin that meet the convex hull of `corners` (sensor
/// frame).
fn cone(corners: &[Vec3; 8]) -> (Option<(f32, f32)>, (f32, f32)) {
    let flat: Vec<Vec2> = corners.iter().map(|c| c.truncate()).collect();
    // The least horizontal distance to the footprint: over the segments between corners (the
    // hull's edges are among them); 0 when the origin lies inside the footprint.
    let mut r_min = f32::INFINITY;
    for i in 0..8 {
        for j in i + 1..8 {
            r_min = r_min.min(segment_distance(flat[i], flat[j]));
        }
    }
    let inside = contains_origin(&flat);
    if inside {
        r_min = 0.0;
    }
    let r_max = flat.iter().map(|p| p.length()).fold(0.0, f32::max);
    let z_min = corners.iter().map(|c| c.z).fold(f32::INFINITY, f32::min);
    let z_max = corners.iter().map(|c| c.z).fold(f32::NEG_INFINITY, f32::max);
    let el_hi = if z_max >= 0.0 { z_max.atan2(r_min) } else { z_max.atan2(r_max) };
    let el_lo = if z_min <= 0.0 { z_min.atan2(r_min) } else { z_min.atan2(r_max) };
    let elevation = (el_lo - MARGIN_RAD, el_hi + MARGIN_RAD);
    // Near the vertical axis the azimuths of the corners say nothing: take them all.
    if inside || r_min < 1e-3 {
        return (None, elevation);
    }
    let a0 = flat[0].y.atan2(flat[0].x);
    let (mut lo, mut hi) = (0.0f32, 0.0f32);
    for p in &flat[1..] {
        let mut d = p.y.atan2(p.x) - a0;
        if d > PI {
            d -= TAU;
        } else if d < -PI {
            d += TAU;
        }
        lo = lo.min(d);
        hi = hi.max(d);
    }
    let azimuth = (hi - lo + 2.0 * MARGIN_RAD < PI).then_some((a0 + lo - MARGIN_RAD, a0 + hi + MARGIN_RAD));
    (azimuth, elevation)
}

/// Distance from the origin to the segment a–b.
fn segment_distance(a: Vec2, b: Vec2) -> f32 {
    let d = b - a;
    let len2 = d.length_squared();
    let t = if len2 > 0.0 { (-a.dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
    (a + d * t).length()
}

/// Whether the origin lies in the convex hull of `pts`: no line through the origin has them
/// all strictly on one side (tested on the directions to each point).
fn contains_origin(pts: &[Vec2]) -> bool {
    let mut az: Vec<f32> = pts.iter().filter(|p| p.length() > 1e-6).map(|p| p.y.atan2(p.x)).collect();
    if az.len() < pts.len() {
        return true;
    }
    az.sort_by(f32::total_cmp);
    // Some gap between consecutive directions of at least π leaves the origin outside.
    let wrap = az[0] + TAU - az[az.len() - 1];
    let widest = az.windows(2).map(|w| w[1] - w[0]).fold(wrap, f32::max);
    widest < PI
}

/// The columns of `scanner`'s pattern whose azimuth lies in [lo, hi] (modulo 2π).
fn columns(scanner: &Scanner, lo: f32, hi: f32, out: &mut [bool]) {
    let first = scanner.azimuth(0);
    for shift in [-TAU, 0.0, TAU, 2.0 * TAU] {
        let a = ((lo + shift - first) / scanner.step).ceil();
        let b = ((hi + shift - first) / scanner.step).floor();
        if b < 0.0 || a > (scanner.cols - 1) as f32 {
            continue;
        }
        out[a.max(0.0) as usize..=(b as usize).min(scanner.cols - 1)].fill(true);
    }
}

/// The LiDAR points `spec` at `pose` puts on each road user of `actors` whose id is in `ids`
/// (ids not found, or not hit, count 0), as [`super::simulate_lidar`] with the same arguments
/// would count them ([`super::LidarScan::points_per_actor`]), casting only the rays that can
/// meet those road users' bounds.
pub fn lidar_points_on(
    spec: &LidarSpec,
    pose: &SensorPose,
    world: &World,
    actors: &ActorSet,
    seed: u64,
    ids: &[u32],
) -> Result<BTreeMap<u32, usize>, SensorError> {
    let mut counts: BTreeMap<u32, usize> = ids.iter().map(|&id| (id, 0)).collect();
    lidar_points_on_each(spec, pose, world, actors, seed, ids, |id, _| {
        if let Some(n) = counts.get_mut(&id) {
            *n += 1;
        }
    })?;
    Ok(counts)
}

/// [`lidar_points_on`]'s points themselves: `f(id, point)` for each point on a road user of
/// `ids`, the point in the scene frame, in the full scan's firing order (the same points
/// [`crate::simulate_lidar`] returns on them).
pub fn lidar_points_on_each(
    spec: &LidarSpec,
    pose: &SensorPose,
    world: &World,
    actors: &ActorSet,
    seed: u64,
    ids: &[u32],
    mut f: impl FnMut(u32, Vec3),
) -> Result<(), SensorError> {
    super::check_mount(world, Some(actors), pose)?;
    let scanner = Scanner::new(spec, pose, world, Some(actors), seed);
    let beams = scanner.elevations.len();
    let inverse = scanner.rot.inverse();
    let wanted: std::collections::BTreeSet<u32> = ids.iter().copied().collect();
    // Per column, the rings to cast (a ray is cast once however many windows hold it).
    let mut cast = vec![false; scanner.cols * beams];
    let mut cols = vec![false; scanner.cols];
    let spread = scanner.footprint.as_ref().map_or(0.0, |f| f.spread_rad());
    for a in actors.actors().iter().filter(|a| wanted.contains(&a.id)) {
        let (mut lo, mut hi) = a.shape.aabb();
        if actors.span_s() > 0.0 {
            let (l2, h2) = a.moved(actors.span_s()).shape.aabb();
            (lo, hi) = (lo.min(l2), hi.max(h2));
        }
        if spread > 0.0 {
            // A beam's axis passes within D·spread of any point its sub-rays meet at range ≤ D.
            let far = (lo - pose.position).abs().max((hi - pose.position).abs()).length();
            let grow = Vec3::splat(far * spread.tan() * 1.01 + 1e-3);
            (lo, hi) = (lo - grow, hi + grow);
        }
        let corners: [Vec3; 8] = std::array::from_fn(|i| {
            let c = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            inverse * (c - pose.position)
        });
        let (azimuth, (el_lo, el_hi)) = cone(&corners);
        cols.fill(false);
        match azimuth {
            Some((lo, hi)) => columns(&scanner, lo, hi, &mut cols),
            None => cols.fill(true),
        }
        let rings: Vec<usize> = (0..beams).filter(|&r| (el_lo..=el_hi).contains(&scanner.elevations[r])).collect();
        for k in (0..scanner.cols).filter(|&k| cols[k]) {
            for &r in &rings {
                cast[k * beams + r] = true;
            }
        }
    }
    for (index, _) in cast.iter().enumerate().filter(|(_, c)| **c) {
        for (p, source) in scanner.ray(index / beams, index % beams).into_iter().flatten() {
            if let Some(id) = source.actor().filter(|id| wanted.contains(id)) {
                f(id, pose.position + scanner.rot * Vec3::new(p.x, p.y, p.z));
            }
        }
    }
    Ok(())
}
