//! The windowed count of a LiDAR's points on road users against the full scan it shortcuts:
//! equal counts, road user by road user, over random traffic, poses (pitched and rolled, right
//! above a road user, inside the traffic), every catalog LiDAR (noise and drop-off on, a
//! limited field of view, datasheet beam tables and range gates, a beam of finite width with two
//! returns), foliage in wind and road
//! users that move during the sweep.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use glam::Vec3;
use hilo_core::{Box3, Class};
use hilo_raycast::shapes::intersect_box;
use hilo_raycast::{Actor, ActorSet, QueryRegion, Ray, Scene, World};
use hilo_sensor_models::{
    Beam, Catalog, Foliage, LidarSpec, ReturnMode, SensorPose, lidar_points_on, lidar_points_on_each, simulate_lidar,
};
use rand::{Rng, SeedableRng};
use std::collections::BTreeMap;
use std::path::Path;

const DATASHEET: &str = include_str!("../../../fixtures/sensors-datasheet.toml");

/// Road users scattered over the junction's carriageway, some under the sensor's mount.
fn traffic(rng: &mut rand_pcg::Pcg64, near: Vec3) -> Vec<Actor> {
    let classes = [(Class::Car, 4.5, 1.9, 1.6), (Class::Pedestrian, 0.6, 0.6, 1.75), (Class::Bus, 12.0, 2.6, 3.2)];
    (0..40)
        .map(|i| {
            let (class, l, w, h) = classes[i % classes.len()];
            // A few right below the sensor (its vertical axis through their footprint).
            let c = if i < 3 {
                Vec3::new(near.x + rng.random_range(-0.5..0.5), near.y + rng.random_range(-0.5..0.5), 0.5 * h)
            } else {
                Vec3::new(rng.random_range(-45.0..45.0), rng.random_range(-45.0..45.0), 0.5 * h)
            };
            let v = Vec3::new(rng.random_range(-15.0..15.0), rng.random_range(-15.0..15.0), 0.0);
            Actor::from_box(100 + i as u32, class, Box3::new(c, l, w, h, rng.random_range(-3.1..3.1))).with_velocity(v)
        })
        .collect()
}

/// The road users with no other inside their bounds or the sensor's: a set the ray engine takes.
fn apart(actors: Vec<Actor>, sensor: Vec3) -> Vec<Actor> {
    let mut kept: Vec<Actor> = Vec::new();
    for a in actors {
        let (lo, hi) = a.shape.aabb();
        let clear = kept.iter().all(|b| {
            let (l2, h2) = b.shape.aabb();
            hi.x < l2.x || h2.x < lo.x || hi.y < l2.y || h2.y < lo.y
        });
        if clear && !a.contains(sensor) && sensor.z > hi.z + 0.2 {
            kept.push(a);
        }
    }
    kept
}

fn specs() -> Vec<LidarSpec> {
    let default = Catalog::default_catalog().unwrap();
    let sheet = Catalog::from_toml_str(DATASHEET, Path::new("sensors-datasheet.toml")).unwrap();
    let mut out: Vec<LidarSpec> =
        ["lidar-16", "lidar-32", "lidar-64"].iter().map(|n| default.lidar(n).unwrap().clone()).collect();
    out.extend(["lidar-16", "lidar-64"].iter().map(|n| sheet.lidar(n).unwrap().clone()));
    // A forward-looking sensor: a field of view that does not close the circle.
    out.push(LidarSpec { hfov_deg: 120.0, ..default.lidar("lidar-32").unwrap().clone() });
    out.push(LidarSpec {
        foliage: Some(Foliage { gap_probability: 0.3, sway_m: 0.2 }),
        ..default.lidar("lidar-64").unwrap().clone()
    });
    // A beam of finite width reporting two echoes (a wide one, so partial hits reach past a
    // road user's box), through foliage in wind.
    out.push(LidarSpec {
        beam: Some(Beam {
            horizontal_mrad: 20.0,
            vertical_mrad: 10.0,
            returns: ReturnMode::Dual,
            separation_m: 0.5,
            rings: 1,
        }),
        foliage: Some(Foliage { gap_probability: 0.3, sway_m: 0.2 }),
        ..sheet.lidar("lidar-16").unwrap().clone()
    });
    out
}

#[test]
fn windowed_counts_equal_the_full_scan() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let (mut cases, mut on_users) = (0, 0usize);
    for (s, spec) in specs().iter().enumerate() {
        for case in 0..6 {
            let p = Vec3::new(rng.random_range(-25.0..25.0), rng.random_range(-25.0..25.0), rng.random_range(4.5..9.0));
            let pose = SensorPose::new(
                p,
                rng.random_range(-3.1..3.1),
                rng.random_range(-0.4..0.4),
                if case % 2 == 0 { 0.0 } else { rng.random_range(-0.3..0.3) },
            );
            let actors = apart(traffic(&mut rng, p), p);
            let set = if case % 3 == 2 {
                ActorSet::moving(actors, 1.0 / spec.rate_hz).unwrap()
            } else {
                ActorSet::new(actors).unwrap()
            };
            let seed = 1_000 + case as u64;
            let Ok(full) = simulate_lidar(spec, &pose, &world, Some(&set), seed) else { continue };
            // Every other road user asked for, and one id that is not there.
            let ids: Vec<u32> = set.actors().iter().map(|a| a.id).step_by(2).chain([9_999]).collect();
            let got = lidar_points_on(spec, &pose, &world, &set, seed, &ids).unwrap();
            let all = full.points_per_actor();
            let want: BTreeMap<u32, usize> = ids.iter().map(|id| (*id, all.get(id).copied().unwrap_or(0))).collect();
            assert_eq!(got, want, "spec {s}, case {case}, pose {pose:?}");
            // And the points themselves, in the scene frame and the scan's order.
            let mut each: BTreeMap<u32, Vec<Vec3>> = BTreeMap::new();
            lidar_points_on_each(spec, &pose, &world, &set, seed, &ids, |id, q| each.entry(id).or_default().push(q))
                .unwrap();
            let mut scan: BTreeMap<u32, Vec<Vec3>> = BTreeMap::new();
            for (q, src) in full.points_local().iter().zip(&full.sources) {
                if let Some(id) = src.actor().filter(|id| ids.contains(id)) {
                    scan.entry(id).or_default().push(Vec3::new(q.x, q.y, q.z));
                }
            }
            assert_eq!(each, scan, "spec {s}, case {case}: the points");
            cases += 1;
            on_users += want.values().sum::<usize>();
        }
    }
    assert!(cases >= 35, "mounts outside the fixture's geometry: {cases}");
    assert!(on_users > 5_000, "the cases put points on road users: {on_users}");
}

/// Right above a road user (the sensor's axis through its roof), level and pitched down either
/// way: the azimuth window cannot bound it, and every column is cast.
#[test]
fn a_road_user_under_the_sensor_is_counted_whole() {
    let world = common::ground_world();
    let spec = Catalog::default_catalog().unwrap().lidar("lidar-64").unwrap().clone();
    let car = Actor::from_box(1, Class::Car, Box3::new(Vec3::new(0.3, -0.2, 0.8), 4.5, 1.9, 1.6, 0.4));
    let set = ActorSet::new(vec![car]).unwrap();
    let mut seen = 0;
    for pitch in [0.0, 0.6, 1.2, -0.6, -1.2] {
        let pose = SensorPose::new(Vec3::new(0.0, 0.0, 5.0), 0.2, pitch, 0.0);
        let full = simulate_lidar(&spec, &pose, &world, Some(&set), 3).unwrap().points_per_actor();
        let got = lidar_points_on(&spec, &pose, &world, &set, 3, &[1]).unwrap();
        assert_eq!(got[&1], full.get(&1).copied().unwrap_or(0), "pitch {pitch}");
        seen = seen.max(got[&1]);
    }
    // Level, its beams pass over the car; tilted, they meet its roof.
    assert!(seen > 50, "seen from above: {seen}");
}

/// A wide beam puts points on a car from columns whose axis passes beside it (a sub-ray at the
/// footprint's edge meets the car): the window grows by the footprint and counts them.
#[test]
fn a_wide_beams_partial_hits_are_counted() {
    let sheet = Catalog::from_toml_str(DATASHEET, Path::new("sensors-datasheet.toml")).unwrap();
    let spec = LidarSpec {
        beam: Some(Beam {
            horizontal_mrad: 50.0,
            vertical_mrad: 50.0,
            returns: ReturnMode::Dual,
            separation_m: 0.5,
            rings: 1,
        }),
        ..sheet.lidar("lidar-16").unwrap().clone()
    };
    let car = Actor::from_box(1, Class::Car, Box3::new(Vec3::new(12.0, 0.0, 0.8), 4.5, 1.9, 1.6, 0.0));
    let set = ActorSet::new(vec![car]).unwrap();
    let world = common::ground_world();
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 5.0), 0.0, 0.0, 0.0);
    let scan = simulate_lidar(&spec, &pose, &world, Some(&set), 1).unwrap();
    // Points whose beam axis misses the car's box, grown by more than the window's own margin.
    let margin = 2.0 * 12.0 * 5e-3;
    let grown = Box3::new(Vec3::new(12.0, 0.0, 0.8), 4.5 + margin, 1.9 + margin, 1.6 + margin, 0.0);
    let beside = scan
        .points_local()
        .iter()
        .zip(&scan.sources)
        .filter(|(p, s)| {
            let dir = (Vec3::new(p.x, p.y, p.z) - pose.position).normalize();
            let axis = Ray { origin: pose.position, dir, t_min: 0.0, t_max: f32::INFINITY };
            s.actor() == Some(1) && intersect_box(&grown, &axis, f32::INFINITY).is_none()
        })
        .count();
    assert!(beside > 0, "no partial hit beside the box: the test would not test the grown window");
    let got = lidar_points_on(&spec, &pose, &world, &set, 1, &[1]).unwrap();
    assert_eq!(got[&1], scan.points_per_actor()[&1], "{beside} points beside the box");
}
