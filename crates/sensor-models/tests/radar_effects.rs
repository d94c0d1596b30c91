//! A real radar's effects, each against its source: the azimuth table against the array law
//! and its own integral, two targets resolved or merged as the table says, a wall's ghost at
//! the mirror image, side lobes where a uniform aperture puts them, false alarms Poisson over
//! the field, foliage that moves, and the RCS's Swerling-I moments and aspect swing.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_raycast::shapes::GroundPlane;
use hilo_raycast::{Actor, ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::radar::target_rcs_dbsm;
use hilo_sensor_models::radar_effects::{AzimuthRow, RadarEffects, SIDE_LOBE_OFFSET, aspect_db};
use hilo_sensor_models::{Catalog, PointSource, RadarSpec, SensorPose, simulate_radar};
use std::collections::BTreeSet;
use std::path::Path;

const DATASHEET: &str = include_str!("../../../fixtures/sensors-datasheet.toml");

fn datasheet_radar(name: &str) -> RadarSpec {
    Catalog::from_toml_str(DATASHEET, Path::new("sensors-datasheet.toml")).unwrap().radar(name).unwrap().clone()
}

/// The ARS548-class table, its accuracy zeroed: the tests that use it measure positions.
fn ars548_table() -> Vec<AzimuthRow> {
    datasheet_radar("radar-lr").azimuth_table.into_iter().map(|r| AzimuthRow { accuracy_deg: 0.0, ..r }).collect()
}

fn pose_at(z: f32) -> SensorPose {
    SensorPose::new(Vec3::new(0.0, 0.0, z), 0.0, 0.0, 0.0)
}

#[test]
fn the_ars548_table_follows_the_array_law_and_its_cells_integrate_it() {
    let spec = RadarSpec { azimuth_table: ars548_table(), ..ideal_radar() };
    let a = spec.azimuth();
    assert!((a.resolution(0.0).to_degrees() - 1.2).abs() < 1e-5);
    assert!((a.resolution(45f32.to_radians()).to_degrees() - 1.68).abs() < 1e-5);
    assert!((a.resolution((-45f32).to_radians()).to_degrees() - 1.68).abs() < 1e-5, "symmetric");
    // A beam-formed array's beam widens as 1/cos: the published pair agrees to 1%.
    let law = 1.2 / 45f32.to_radians().cos();
    assert!((1.68 - law).abs() / law < 0.012, "{law}");
    // The cell coordinate is the integral of 1/resolution: against the midpoint rule.
    for deg in [0.3f32, 10.0, 44.9, 45.0, 52.5, 59.99, 60.0] {
        let n = 20_000;
        let h = deg / n as f32;
        let numeric: f64 =
            (0..n).map(|i| h as f64 / a.resolution(((i as f32 + 0.5) * h).to_radians()).to_degrees() as f64).sum();
        let closed = a.coordinate(deg.to_radians()) as f64;
        assert!((numeric - closed).abs() < 1e-3 * closed.max(1.0), "{deg}: {numeric} vs {closed}");
        assert_eq!(a.coordinate((-deg).to_radians()), -a.coordinate(deg.to_radians()));
    }
    // Cells are as wide as the local resolution: about 50 cells from boresight to ±60 deg
    // (37.5 to 45 deg at 1.2..1.68, and so on), and boresight is a cell's centre.
    let c0 = a.cell(0.0);
    assert_eq!(a.cell(0.59f32.to_radians()), c0);
    assert_eq!(a.cell((-0.59f32).to_radians()), c0);
    assert_ne!(a.cell(0.61f32.to_radians()), c0);
    let edge = a.cell(59.99f32.to_radians()) - c0;
    let expect = a.coordinate(59.99f32.to_radians());
    assert!((edge as f32 - expect).abs() <= 1.0, "{edge} cells, coordinate {expect}");
    // Without a table, the uniform grid of before.
    let u = ideal_radar();
    let au = u.azimuth();
    for az in [-1.0f32, -0.2, 0.0, 0.33, 1.04] {
        let half = 0.5 * u.hfov_deg.to_radians();
        assert_eq!(au.cell(az), ((az + half) / u.azimuth_resolution_deg.to_radians()) as u32);
        assert_eq!(au.accuracy(az), u.azimuth_noise_deg.to_radians());
    }
}

/// A radar with a fine ray grid, no noise, and unresolved targets merged.
fn resolving_radar(table: bool) -> RadarSpec {
    let mut s = ideal_radar();
    s.ray_azimuth_step_deg = 0.05;
    s.ray_elevation_step_deg = 0.2;
    s.rcs_dbsm.car = 40.0; // always detected
    if table {
        s.azimuth_table = ars548_table();
    }
    s.azimuth_resolution_deg = 1.2;
    s.effects = RadarEffects { doppler_resolution_mps: Some(0.1), ..RadarEffects::default() };
    s
}

/// A small target 20 m away at azimuth `deg`, facing the sensor, moving radially at `v_r`.
fn post(id: u32, deg: f32, v_r: f32) -> Actor {
    let dir = Vec3::new(deg.to_radians().cos(), deg.to_radians().sin(), 0.0);
    let at = dir * 20.0 + Vec3::new(0.0, 0.0, 1.0);
    Actor::from_box(id, Class::Car, Box3::new(at, 0.05, 0.05, 0.3, deg.to_radians())).with_velocity(dir * v_r)
}

fn sources_seen(spec: &RadarSpec, actors: Vec<Actor>) -> BTreeSet<u32> {
    let set = ActorSet::new(actors).unwrap();
    let scan = simulate_radar(spec, &pose_at(1.0), &ground_world(), Some(&set), 5).unwrap();
    scan.sources.iter().filter_map(|s| s.actor()).collect()
}

#[test]
fn two_targets_are_resolved_or_merged_as_the_table_says() {
    // 1.45 deg apart: more than the 1.2 deg at boresight, less than the 1.68 deg at 45 deg.
    let pair = |centre: f32, v2: f32| vec![post(1, centre - 0.725, 0.0), post(2, centre + 0.725, v2)];
    let table = resolving_radar(true);
    assert_eq!(sources_seen(&table, pair(0.0, 0.0)).len(), 2, "resolved at boresight");
    assert_eq!(sources_seen(&table, pair(45.0, 0.0)).len(), 1, "merged at 45 deg");
    // Doppler separates what angle does not.
    assert_eq!(sources_seen(&table, pair(45.0, 1.0)).len(), 2, "resolved by Doppler");
    // Without the table the resolution is 1.2 deg everywhere: resolved at 45 deg too.
    assert_eq!(sources_seen(&resolving_radar(false), pair(45.0, 0.0)).len(), 2);
    // Without the effect, two targets are never merged.
    let mut ideal = resolving_radar(true);
    ideal.effects = RadarEffects::default();
    let close = vec![post(1, 44.9, 0.0), post(2, 45.1, 0.0)];
    assert_eq!(sources_seen(&ideal, close.clone()).len(), 2);
    assert_eq!(sources_seen(&table, close).len(), 1);
}

/// Ground, and a wall 8 m to the left of the sensor's boresight, 2..60 m ahead, 8 m high.
fn walled_world() -> World {
    let (a, b, c, d) =
        (Vec3::new(2.0, 8.0, 0.0), Vec3::new(60.0, 8.0, 0.0), Vec3::new(60.0, 8.0, 8.0), Vec3::new(2.0, 8.0, 8.0));
    World::from_triangles(
        &[[a, b, c], [a, c, d]],
        Some(GroundPlane { z_m: 0.0, min: Vec2::splat(-500.0), max: Vec2::splat(500.0) }),
    )
    .unwrap()
}

#[test]
fn a_wall_ghost_sits_at_the_mirror_image_with_the_mirrored_doppler() {
    let mut spec = ideal_radar();
    spec.rcs_dbsm.car = 40.0;
    let v = Vec3::new(-5.0, 2.0, 0.0);
    let car = Box3::new(Vec3::new(25.0, 1.0, 0.8), 4.0, 1.8, 1.6, 0.0);
    let set = ActorSet::new(vec![Actor::from_box(1, Class::Car, car).with_velocity(v)]).unwrap();
    let pose = pose_at(1.5);
    let world = walled_world();
    let scan = |spec: &RadarSpec| simulate_radar(spec, &pose, &world, Some(&set), 9).unwrap();
    let off = scan(&spec);
    assert!(!off.sources.iter().any(|s| matches!(s, PointSource::Multipath(_))), "no ghost without the effect");
    spec.effects.wall_multipath_loss_db = Some(6.0);
    let on = scan(&spec);
    // The mirror image of the car in the wall's plane y = 8, and of its velocity.
    let mirror = Box3 { center: Vec3::new(25.0, 15.0, 0.8), ..car };
    let v_m = Vec3::new(v.x, -v.y, v.z);
    let local = on.points_local();
    let mut ghosts = 0;
    for ((p, q), s) in on.points.iter().zip(&local).zip(&on.sources) {
        if *s != PointSource::Multipath(1) {
            continue;
        }
        ghosts += 1;
        let q = Vec3::new(q.x, q.y, q.z);
        let inside = mirror.to_local(q).abs().cmple(mirror.half_extents() + Vec3::splat(0.3)).all();
        assert!(inside, "ghost at {q} is not the mirror image");
        let los = (q - pose.position).normalize();
        assert!((p.v_r_mps - v_m.dot(los)).abs() < 0.02 * v.length(), "{} vs {}", p.v_r_mps, v_m.dot(los));
    }
    assert!(ghosts > 0, "the wall shows the car's ghost");
    let strongest = |s: &dyn Fn(&PointSource) -> bool| {
        on.snr_db.iter().zip(&on.sources).filter(|(_, x)| s(x)).map(|(v, _)| *v).fold(f32::MIN, f32::max)
    };
    let direct = strongest(&|s| *s == PointSource::Actor(1));
    let ghost = strongest(&|s| *s == PointSource::Multipath(1));
    assert!(ghost < direct - 6.0, "the ghost is farther and pays the wall's loss: {ghost} vs {direct}");
    // The road reflects too: ghosts below the road surface, mirrored in z.
    spec.effects = RadarEffects { ground_multipath_loss_db: Some(3.0), ..RadarEffects::default() };
    let ground = simulate_radar(&spec, &pose, &ground_world(), Some(&set), 9).unwrap();
    let below: Vec<Vec3> = ground
        .points_local()
        .iter()
        .zip(&ground.sources)
        .filter(|(_, s)| **s == PointSource::Multipath(1))
        .map(|(p, _)| Vec3::new(p.x, p.y, p.z))
        .collect();
    assert!(!below.is_empty(), "the road shows the car's ghost");
    let under = Box3 { center: Vec3::new(25.0, 1.0, -0.8), ..car };
    for q in below {
        assert!(under.to_local(q).abs().cmple(under.half_extents() + Vec3::splat(0.3)).all(), "{q}");
    }
}

#[test]
fn side_lobes_lie_where_a_uniform_aperture_puts_them() {
    let mut spec = ideal_radar();
    spec.azimuth_table = ars548_table();
    spec.effects.side_lobe_level_db = Some(20.0);
    let car = |rcs: f32| {
        let mut s = spec.clone();
        s.rcs_dbsm.car = rcs;
        let b = Box3::new(Vec3::new(26.0, 15.0, 0.8), 4.0, 1.8, 1.6, 0.4);
        let set = ActorSet::new(vec![Actor::from_box(1, Class::Car, b).with_velocity(Vec3::new(3.0, -2.0, 0.0))]);
        simulate_radar(&s, &pose_at(1.5), &ground_world(), Some(&set.unwrap()), 2).unwrap()
    };
    let strong = car(45.0);
    let a = spec.azimuth();
    let sph = |p: &hilo_core::RadarPoint| {
        let r = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt();
        (r, p.y.atan2(p.x), p.v_r_mps)
    };
    let parents: Vec<_> = strong
        .points
        .iter()
        .zip(&strong.sources)
        .zip(&strong.snr_db)
        .filter(|((_, s), _)| **s == PointSource::Actor(1))
        .map(|((p, _), snr)| (sph(p), *snr))
        .collect();
    let lobes: Vec<_> = strong
        .points
        .iter()
        .zip(&strong.sources)
        .zip(&strong.snr_db)
        .filter(|((_, s), _)| **s == PointSource::SideLobe)
        .map(|((p, _), snr)| (sph(p), *snr))
        .collect();
    let loud = parents.iter().filter(|(_, snr)| snr - 20.0 >= spec.detection_threshold_db).count();
    assert!(loud > 0);
    assert_eq!(lobes.len(), 2 * loud, "two side lobes per detection that can afford them");
    for ((r, az, v), snr) in &lobes {
        let parent = parents.iter().find(|((pr, paz, pv), psnr)| {
            let off = SIDE_LOBE_OFFSET * a.resolution(*paz);
            (pr - r).abs() < 1e-3
                && ((az - paz).abs() - off).abs() < 1e-4
                && (psnr - 20.0 - snr).abs() < 1e-3
                && pv == v
        });
        assert!(parent.is_some(), "side lobe at range {r}, azimuth {az}, SNR {snr} has no parent");
    }
    // A target whose detections lie less than 20 dB above the threshold has none.
    let weak = car(10.0);
    assert!(weak.sources.contains(&PointSource::Actor(1)));
    assert!(!weak.sources.contains(&PointSource::SideLobe));
}

#[test]
fn false_alarms_are_poisson_over_the_field() {
    let mut spec = ideal_radar();
    spec.ray_azimuth_step_deg = 4.0; // no road user here: the grid only finds the ground
    spec.ray_elevation_step_deg = 4.0;
    spec.effects.false_alarms_per_frame = 3.0;
    spec.effects.false_alarm_speed_mps = 30.0;
    let world = ground_world();
    let pose = pose_at(5.0);
    let frames = 1500;
    let mut counts = Vec::new();
    for seed in 0..frames {
        let scan = simulate_radar(&spec, &pose, &world, None, seed).unwrap();
        let mut n = 0;
        for ((p, s), snr) in scan.points.iter().zip(&scan.sources).zip(&scan.snr_db) {
            assert_eq!(*s, PointSource::Noise, "nothing else is reported");
            let r = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt();
            assert!(r >= spec.min_range_m - 1e-3 && r <= spec.max_range_m + 1e-3, "{r}");
            assert!(p.y.atan2(p.x).abs() <= 0.5 * spec.hfov_deg.to_radians() + 1e-5);
            assert!((p.z / r).asin().abs() <= 0.5 * spec.vfov_deg.to_radians() + 1e-5);
            assert!(p.v_r_mps.abs() <= 30.0);
            assert!(*snr >= spec.detection_threshold_db);
            n += 1;
        }
        counts.push(n as f64);
    }
    let mean = counts.iter().sum::<f64>() / frames as f64;
    let var = counts.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / (frames - 1) as f64;
    // Poisson: mean = variance = 3; the mean's standard error is sqrt(3/1500) = 0.045.
    assert!((mean - 3.0).abs() < 0.2, "mean {mean}");
    assert!((var / 3.0 - 1.0).abs() < 0.15, "variance {var}");
}

#[test]
fn foliage_moves_and_buildings_do_not() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let mut spec = ideal_radar();
    spec.clutter_probability = 1.0;
    let still = |spec: &RadarSpec| {
        let mut v = Vec::new();
        for k in 0..4 {
            let yaw = k as f32 * std::f32::consts::FRAC_PI_2;
            let pose = SensorPose::new(Vec3::new(12.0, 12.0, 6.0), yaw, -0.1, 0.0);
            let scan = simulate_radar(spec, &pose, &world, None, k as u64).unwrap();
            v.extend(
                scan.points
                    .iter()
                    .zip(&scan.sources)
                    .filter(|(_, s)| **s == PointSource::Static)
                    .map(|(p, _)| p.v_r_mps),
            );
        }
        v
    };
    assert!(still(&spec).iter().all(|v| *v == 0.0), "static clutter sits at zero Doppler");
    spec.effects.vegetation_doppler_mps = 0.5;
    let v = still(&spec);
    let moving: Vec<f64> = v.iter().filter(|v| **v != 0.0).map(|v| *v as f64).collect();
    assert!(moving.len() >= 100, "the fixture's trees give clutter: {}", moving.len());
    assert!(moving.len() < v.len(), "buildings and poles stay at zero");
    let n = moving.len() as f64;
    let mean = moving.iter().sum::<f64>() / n;
    let sd = (moving.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    assert!(mean.abs() < 4.0 * 0.5 / n.sqrt(), "mean {mean}");
    assert!((sd / 0.5 - 1.0).abs() < 0.15, "spread {sd}");
}

#[test]
fn rcs_is_swerling_one_around_the_aspect_curve() {
    let mut spec = ideal_radar();
    let sensor = Vec3::new(0.0, 0.0, 5.0);
    let car = |yaw: f32| Actor::from_box(7, Class::Car, Box3::new(Vec3::new(30.0, 0.0, 0.8), 4.0, 1.8, 1.6, yaw));
    // Swerling I: the linear RCS is exponential, mean = σ̄ and variance = σ̄².
    let n = 40_000;
    let lin: Vec<f64> =
        (0..n).map(|s| 10f64.powf(target_rcs_dbsm(&spec, &car(0.0), sensor, s) as f64 / 10.0)).collect();
    let mean_lin = 10f64.powf(spec.rcs_dbsm.car as f64 / 10.0);
    let m = lin.iter().sum::<f64>() / n as f64;
    let var = lin.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
    assert!((m / mean_lin - 1.0).abs() < 0.03, "mean {m} vs {mean_lin}");
    assert!((var / (mean_lin * mean_lin) - 1.0).abs() < 0.08, "variance {var}");
    // Aspect: the same fluctuation, 2a louder broadside than head-on; the mean over all
    // headings is the class's mean; a pedestrian has no aspect.
    spec.effects.rcs_aspect_db = 5.0;
    for s in 0..50 {
        let head_on = target_rcs_dbsm(&spec, &car(0.0), sensor, s);
        let broadside = target_rcs_dbsm(&spec, &car(std::f32::consts::FRAC_PI_2), sensor, s);
        assert!((broadside - head_on - 10.0).abs() < 1e-4, "{broadside} {head_on}");
    }
    let avg: f32 =
        (0..360).map(|d| aspect_db(&spec.effects, &car((d as f32).to_radians()), sensor)).sum::<f32>() / 360.0;
    assert!(avg.abs() < 1e-4, "{avg}");
    let person = Actor::from_box(8, Class::Pedestrian, Box3::new(Vec3::new(30.0, 0.0, 0.9), 0.6, 0.6, 1.8, 1.0));
    assert_eq!(aspect_db(&spec.effects, &person, sensor), 0.0);
}

#[test]
fn bad_effects_are_refused_with_the_field_named() {
    let base = DATASHEET.to_owned();
    for (from, to, field) in [
        ("off_boresight_deg = 0.0", "off_boresight_deg = 1.0", "azimuth_table[0].off_boresight_deg"),
        ("off_boresight_deg = 45.0", "off_boresight_deg = 70.0", "azimuth_table[2].off_boresight_deg"),
        ("off_boresight_deg = 60.0", "off_boresight_deg = 50.0", "azimuth_table[2].off_boresight_deg"),
        ("resolution_deg = 1.68", "resolution_deg = 0.0", "azimuth_table[1].resolution_deg"),
        ("side_lobe_level_db = 25.0", "side_lobe_level_db = -3.0", "effects.side_lobe_level_db"),
        ("doppler_resolution_mps = 0.1", "doppler_resolution_mps = 0.0", "effects.doppler_resolution_mps"),
        ("false_alarms_per_frame = 2.0", "false_alarms_per_frame = 1e9", "effects.false_alarms_per_frame"),
    ] {
        // The last radar's table and effects (radar-lr); the first effects table is radar-4d's.
        let at =
            if from.starts_with("off") || from.starts_with("resolution") { base.rfind(from) } else { base.find(from) };
        let at = at.unwrap();
        let text = format!("{}{}{}", &base[..at], to, &base[at + from.len()..]);
        let err = Catalog::from_toml_str(&text, Path::new("field.toml")).unwrap_err().to_string();
        assert!(err.contains("field.toml") && err.contains(field), "{err}");
    }
    // Unknown effects are refused too (a misspelt setting is not silently off).
    let text = base.replacen("rcs_aspect_db = 5.0", "rcs_aspect = 5.0", 1);
    let err = Catalog::from_toml_str(&text, Path::new("field.toml")).unwrap_err().to_string();
    assert!(err.contains("rcs_aspect"), "{err}");
}
