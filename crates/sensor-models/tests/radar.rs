//! Radar scans: exact Doppler, radar-equation monotonicity, detection statistics, the cap.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_raycast::{Actor, ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::probability::{Probe, radar_detection_probability};
use hilo_sensor_models::radar::{snr_db, swerling1_detection_probability};
use hilo_sensor_models::{PointSource, SensorPose, simulate_radar};
use proptest::prelude::*;

fn radar_pose() -> SensorPose {
    SensorPose::new(Vec3::new(0.0, 0.0, 1.0), 0.0, 0.0, 0.0)
}

fn narrow_target(at: Vec3, v: Vec3, class: Class, id: u32) -> Actor {
    Actor::from_box(id, class, Box3::new(at, 0.5, 0.5, 1.0, 0.0)).with_velocity(v)
}

#[test]
fn doppler_is_the_velocity_projected_on_the_line_of_sight() {
    let world = ground_world();
    let mut spec = ideal_radar();
    spec.rcs_dbsm.car = 40.0; // always detected: this test is about velocity
    let s = 12.5;
    let at = Vec3::new(40.0, 0.0, 1.0);
    // Straight toward the sensor: v_r = −s (to the cosine of the box's half-angle).
    let toward = ActorSet::new(vec![narrow_target(at, Vec3::new(-s, 0.0, 0.0), Class::Car, 1)]).unwrap();
    let scan = simulate_radar(&spec, &radar_pose(), &world, Some(&toward), 3).unwrap();
    let on_target: Vec<_> =
        scan.points.iter().zip(&scan.sources).filter(|(_, s)| **s == PointSource::Actor(1)).collect();
    assert!(!on_target.is_empty());
    for (p, _) in &on_target {
        assert!((p.v_r_mps + s).abs() < 1e-3 * s, "v_r {} expected {}", p.v_r_mps, -s);
        assert_eq!(p.v_r_mps, p.v_r_comp_mps, "a static radar's compensated velocity equals v_r");
    }
    // Perpendicular: v_r = 0 (to the sine of the half-angle).
    let across = ActorSet::new(vec![narrow_target(at, Vec3::new(0.0, s, 0.0), Class::Car, 1)]).unwrap();
    let scan = simulate_radar(&spec, &radar_pose(), &world, Some(&across), 3).unwrap();
    for (p, src) in scan.points.iter().zip(&scan.sources) {
        if *src == PointSource::Actor(1) {
            assert!(p.v_r_mps.abs() < 0.01 * s, "{}", p.v_r_mps);
        }
    }
    // Oblique, off-axis: v_r equals v · (unit line of sight of the detection), exactly.
    let at = Vec3::new(30.0, 12.0, 1.0);
    let v = Vec3::new(-4.0, 7.0, 0.0);
    let oblique = ActorSet::new(vec![narrow_target(at, v, Class::Car, 1)]).unwrap();
    let scan = simulate_radar(&spec, &radar_pose(), &world, Some(&oblique), 3).unwrap();
    let mut n = 0;
    for (p, src) in scan.points.iter().zip(&scan.sources) {
        if *src == PointSource::Actor(1) {
            let los = Vec3::new(p.x, p.y, p.z).normalize();
            assert!((p.v_r_mps - v.dot(los)).abs() < 0.02, "{} vs {}", p.v_r_mps, v.dot(los));
            n += 1;
        }
    }
    assert!(n > 0);
}

proptest! {
    #[test]
    fn snr_falls_with_range_and_rises_with_rcs(r1 in 1.0f32..150.0, dr in 0.01f32..50.0, rcs in -20.0f32..30.0, drcs in 0.01f32..10.0) {
        let spec = ideal_radar();
        prop_assert!(snr_db(&spec, rcs, r1 + dr) < snr_db(&spec, rcs, r1));
        prop_assert!(snr_db(&spec, rcs + drcs, r1) > snr_db(&spec, rcs, r1));
        // 40 dB per decade of range: the R⁴ law.
        prop_assert!((snr_db(&spec, rcs, r1) - snr_db(&spec, rcs, 10.0 * r1) - 40.0).abs() < 1e-3);
    }
}

#[test]
fn detection_frequency_matches_the_swerling_closed_form() {
    let world = ground_world();
    let spec = ideal_radar();
    // Range where a pedestrian's mean SNR sits near the threshold (P_d around one half).
    let range = 48.0;
    let probe = Probe::PEDESTRIAN;
    let b = probe.at(Vec2::new(range, 0.0), 0.0, 0.0);
    let p_model = radar_detection_probability(&spec, &radar_pose(), &probe, &b);
    assert!(p_model > 0.2 && p_model < 0.8, "{p_model}");
    let actors = ActorSet::new(vec![Actor::from_box(5, Class::Pedestrian, b)]).unwrap();
    let trials = 400;
    let detected = (0..trials)
        .filter(|seed| {
            let s = simulate_radar(&spec, &radar_pose(), &world, Some(&actors), *seed as u64).unwrap();
            s.sources.contains(&PointSource::Actor(5))
        })
        .count();
    let freq = detected as f32 / trials as f32;
    // 4 standard errors of a binomial proportion.
    let tol = 4.0 * (p_model * (1.0 - p_model) / trials as f32).sqrt();
    assert!((freq - p_model).abs() < tol, "simulated {freq}, model {p_model}");
    // Far beyond: nothing; very close: always.
    assert!(swerling1_detection_probability(&spec, snr_db(&spec, -8.0, 300.0)) < 1e-3);
    assert!(swerling1_detection_probability(&spec, snr_db(&spec, -8.0, 5.0)) > 0.99);
}

#[test]
fn the_point_cap_keeps_the_strongest_detections() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let mut spec = catalog().radar("radar-4d").unwrap().clone();
    let actors: Vec<Actor> = (0..40)
        .map(|i| {
            let x = 10.0 + 2.0 * (i % 20) as f32;
            let y = if i < 20 { 2.0 } else { -5.0 };
            Actor::from_box(i, Class::Car, Box3::new(Vec3::new(x, y, 0.8), 4.5, 1.9, 1.6, 0.0))
                .with_velocity(Vec3::new(8.0, 0.0, 0.0))
        })
        .collect();
    let actors = ActorSet::new(actors).unwrap();
    let pose = SensorPose::new(Vec3::new(-16.6, -13.0, 6.5), 0.3, 0.15, 0.0);
    let full = simulate_radar(&spec, &pose, &world, Some(&actors), 9).unwrap();
    spec.max_points = 25;
    let capped = simulate_radar(&spec, &pose, &world, Some(&actors), 9).unwrap();
    assert!(full.points.len() > 25, "{}", full.points.len());
    assert_eq!(capped.points.len(), 25);
    assert_eq!(capped.points[..], full.points[..25]);
    assert!(capped.snr_db.windows(2).all(|w| w[0] >= w[1]));
    // No target yields more than its dominant scatterers.
    let mut per_target = std::collections::BTreeMap::new();
    for s in &full.sources {
        if let PointSource::Actor(id) = s {
            *per_target.entry(*id).or_insert(0u32) += 1;
        }
    }
    assert!(per_target.len() > 10, "{per_target:?}");
    assert!(per_target.values().all(|&n| n <= spec.max_detections_per_target));
    // Same seed, same scan.
    assert_eq!(simulate_radar(&spec, &pose, &world, Some(&actors), 9).unwrap(), capped);
    // An empty scene: no detections, no error.
    let empty = World::from_triangles(&[], None).unwrap();
    assert!(simulate_radar(&spec, &pose, &empty, None, 1).unwrap().points.is_empty());
}

/// Reach: the catalog's long-range radar (ARS548 class, 300 m) sees a car 150 m down the
/// approach, with its Doppler, where the 4D imaging radar (90 m) sees nothing; and its radar
/// equation puts a car at 150 m far above the detection threshold.
#[test]
fn the_long_range_radar_reaches_past_the_imaging_radar() {
    let world = ground_world();
    let lr = catalog().radar("radar-lr").unwrap().clone();
    let imaging = catalog().radar("radar-4d").unwrap().clone();
    assert!(lr.max_range_m >= 200.0 && imaging.max_range_m < 150.0);
    assert!(swerling1_detection_probability(&lr, snr_db(&lr, lr.rcs_dbsm.car, 150.0)) > 0.99);
    // Broadside (4.5 m across the line of sight), closing at 10 m/s.
    let car = Actor::from_box(
        1,
        Class::Car,
        Box3::new(Vec3::new(150.0, 0.0, 0.8), 4.5, 1.9, 1.6, std::f32::consts::FRAC_PI_2),
    )
    .with_velocity(Vec3::new(-10.0, 0.0, 0.0));
    let actors = ActorSet::new(vec![car]).unwrap();
    let on_car = |spec: &hilo_sensor_models::RadarSpec, seed: u64| -> Vec<f32> {
        let scan = simulate_radar(spec, &radar_pose(), &world, Some(&actors), seed).unwrap();
        scan.points
            .iter()
            .zip(&scan.sources)
            .filter(|(_, s)| **s == PointSource::Actor(1))
            .map(|(p, _)| p.v_r_mps)
            .collect()
    };
    let mut seen = 0;
    for seed in 0..10 {
        let v = on_car(&lr, seed);
        if !v.is_empty() {
            seen += 1;
        }
        assert!(v.iter().all(|v_r| (v_r + 10.0).abs() < 0.5), "seed {seed}: {v:?}");
        assert!(on_car(&imaging, seed).is_empty(), "the 4D radar reports a car past its range");
    }
    assert!(seen >= 9, "the long-range radar saw the car in {seen} of 10 scans");
}
