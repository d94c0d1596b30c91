//! The detection-probability model against the scan simulation and against physics.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use glam::{Vec2, Vec3};
use hilo_raycast::{Actor, ActorSet};
use hilo_sensor_models::probability::{Probe, lidar_expected_returns};
use hilo_sensor_models::{SensorPose, simulate_lidar};

#[test]
fn expected_returns_equal_simulated_returns_without_noise() {
    let world = ground_world();
    for name in ["lidar-16", "lidar-64"] {
        let spec = ideal_lidar(name);
        let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.5), 0.7, 0.2, 0.0);
        for (probe, xy, yaw) in [
            (Probe::CAR, Vec2::new(14.0, 9.0), 0.3),
            (Probe::PEDESTRIAN, Vec2::new(6.0, 11.0), 0.0),
            (Probe::CAR, Vec2::new(-20.0, 30.0), 1.2),
        ] {
            let b = probe.at(xy, 0.0, yaw);
            let expected = lidar_expected_returns(&spec, &pose, &probe, &b);
            let actors = ActorSet::new(vec![Actor::from_box(1, probe.class, b)]).unwrap();
            let scan = simulate_lidar(&spec, &pose, &world, Some(&actors), 0).unwrap();
            // Pedestrians are capsules in the simulation but boxes in the model: compare cars
            // exactly and pedestrians within the capsule's smaller silhouette.
            let got = scan.points_per_actor().get(&1).copied().unwrap_or(0) as f32;
            if probe.class == hilo_core::Class::Car {
                assert_eq!(got, expected, "{name} {xy}");
            } else {
                assert!(got <= expected && got >= 0.6 * expected, "{name} {xy}: {got} vs {expected}");
            }
        }
    }
}

#[test]
fn expected_returns_match_the_mean_of_noisy_scans() {
    let world = ground_world();
    let spec = catalog().lidar("lidar-32").unwrap().clone();
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.5), 0.0, 0.1, 0.0);
    let b = Probe::CAR.at(Vec2::new(45.0, 3.0), 0.0, 0.4);
    let expected = lidar_expected_returns(&spec, &pose, &Probe::CAR, &b);
    let actors = ActorSet::new(vec![Actor::from_box(1, Probe::CAR.class, b)]).unwrap();
    let n = 60;
    let mean: f32 = (0..n)
        .map(|s| {
            simulate_lidar(&spec, &pose, &world, Some(&actors), s)
                .unwrap()
                .points_per_actor()
                .get(&1)
                .copied()
                .unwrap_or(0) as f32
        })
        .sum::<f32>()
        / n as f32;
    assert!(expected > 10.0);
    assert!((mean - expected).abs() < 0.05 * expected, "mean {mean} expected {expected}");
}

/// Per position the count depends on how beams happen to align with the probe (a 16-beam
/// sensor's 2° spacing can put two beams on a pedestrian where a 32-beam sensor's 1.45° puts
/// one); summed over an area, more beams give more returns.
#[test]
fn more_beams_see_more_over_an_area_and_returns_fall_with_range() {
    let c = catalog();
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.5), 0.0, 0.0, 0.0);
    for probe in [Probe::PEDESTRIAN, Probe::CAR] {
        let mut totals = [0.0f32; 3];
        for d in [12.0f32, 17.0, 23.0, 31.0, 38.0, 47.0, 55.0, 66.0] {
            for a in 0..12 {
                let xy = Vec2::from_angle(a as f32 * std::f32::consts::FRAC_PI_6 + 0.1) * d;
                let b = probe.at(xy, 0.0, 0.3 * a as f32);
                for (k, n) in ["lidar-16", "lidar-32", "lidar-64"].iter().enumerate() {
                    totals[k] += lidar_expected_returns(c.lidar(n).unwrap(), &pose, &probe, &b);
                }
            }
        }
        assert!(totals[0] < totals[1] && totals[1] < totals[2], "{probe:?}: {totals:?}");
        // From 25 m on the whole probe is in the vertical field of view (closer, the ground at
        // 8 m is 39° down, outside it): there the count falls with range.
        let mut last = f32::INFINITY;
        for d in [25.0f32, 35.0, 50.0, 70.0] {
            let e = lidar_expected_returns(
                c.lidar("lidar-64").unwrap(),
                &pose,
                &probe,
                &probe.at(Vec2::new(d, 0.0), 0.0, 0.0),
            );
            assert!(e <= last, "{probe:?}: {e} at {d} after {last}");
            last = e;
        }
    }
}
