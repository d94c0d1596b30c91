//! The background model against the oracle hilo can compute exactly: the static scene ray-cast
//! from the sensor without road users. Learned from one set of traffic frames, applied to
//! others: the static points it removes and the road-user points it keeps, by each point's
//! known source.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_dataset::background::{BackgroundConfig, BackgroundModel};
use hilo_dataset::traffic::{ActorState, Traffic, TrafficConfig};
use hilo_raycast::{ActorSet, QueryRegion, Ray, Scene, World};
use hilo_sensor_models::lidar::PointSource;
use hilo_sensor_models::pose::spherical_dir;
use hilo_sensor_models::{Catalog, LidarSpec, SensorPose, simulate_lidar};
use std::collections::BTreeMap;

fn pose(scene: &Scene, mount: usize) -> SensorPose {
    let m = &scene.mounts[mount];
    let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
    let yaw = (-p.y).atan2(-p.x);
    SensorPose::new(p.extend(scene.ground.z_m + m.arm_height_m + 0.4), yaw, 10f32.to_radians(), 0.0)
}

/// Frames of traffic seen by the sensor: every `every` traffic steps after the warm-up.
fn frames(
    scene: &Scene,
    world: &World,
    spec: &LidarSpec,
    pose: &SensorPose,
    seed: u64,
    n: usize,
    every: usize,
) -> Vec<(Vec<hilo_core::LidarPoint>, Vec<PointSource>)> {
    let mut traffic = Traffic::new(&scene.layout, scene.ground.z_m, &TrafficConfig::default(), seed).unwrap();
    (0..n)
        .map(|k| {
            let set = ActorSet::new(traffic.snapshot().iter().map(ActorState::actor).collect()).unwrap();
            let scan = simulate_lidar(spec, pose, world, Some(&set), seed * 1000 + k as u64).unwrap();
            for _ in 0..every {
                traffic.step();
            }
            (scan.points, scan.sources)
        })
        .collect()
}

#[test]
fn background_removal_against_the_ray_cast_static_scene() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let catalog = Catalog::default_catalog().unwrap();
    let spec = catalog.lidar("lidar-16").unwrap().clone();
    let pose = pose(&scene, 0);
    let cfg = hilo_core::Valid::new(BackgroundConfig { frames: 80, ..BackgroundConfig::default() }).unwrap();
    // Learned from 80 frames of four traffic seeds, two seconds apart (as the training split is
    // sampled: evenly over its scenes).
    let train: Vec<_> = (0..4).flat_map(|s| frames(&scene, &world, &spec, &pose, 11 + s, 20, 40)).collect();
    let model = BackgroundModel::learn_from(
        &BTreeMap::from([("LIDAR_0".to_owned(), train.iter().map(|f| f.0.clone()).collect())]),
        &cfg,
    );
    let ch = &model.channels["LIDAR_0"];

    // 1. Oracle: each beam and column ray-cast on the static scene alone.
    let rot = pose.rotation();
    let (elev, cols) = (spec.elevations_rad(), spec.columns() as usize);
    let (mut cells, mut within, mut missing) = (0usize, 0usize, 0usize);
    for k in 0..cols {
        let az = k as f32 * spec.hfov_deg.to_radians() / cols as f32;
        for (ring, &el) in elev.iter().enumerate() {
            let d = spherical_dir(az, el);
            let ray = Ray { origin: pose.position, dir: rot * d, t_min: spec.min_range_m, t_max: spec.max_range_m };
            let Some(hit) = world.closest_hit(&ray, None) else { continue };
            cells += 1;
            let p = hilo_core::LidarPoint { x: d.x, y: d.y, z: d.z, intensity: 0.0, ring: ring as u16, time_s: 0.0 };
            let bg = ch.range_at(&p, &cfg);
            if bg == 0.0 {
                missing += 1;
            } else if (bg - hit.t).abs() <= cfg.margin_m {
                within += 1;
            }
        }
    }
    let share = within as f64 / cells as f64;
    eprintln!(
        "oracle: {cells} static cells, {within} learned within {} m ({:.2}%), {missing} without a background",
        cfg.margin_m,
        100.0 * share
    );
    assert!(share >= 0.97, "only {:.2}% of the static cells learned within the margin", 100.0 * share);

    // 2. On frames of another traffic seed: static points removed, road-user points kept.
    let test = frames(&scene, &world, &spec, &pose, 21, 30, 10);
    let (mut st, mut st_removed, mut ru, mut ru_kept) = (0usize, 0usize, 0usize, 0usize);
    for (points, sources) in &test {
        for (p, s) in points.iter().zip(sources) {
            let bg = ch.is_background(p, &cfg);
            match s {
                PointSource::Actor(_) => {
                    ru += 1;
                    ru_kept += usize::from(!bg);
                    if bg && std::env::var("HILO_DEBUG").is_ok() {
                        let d = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt();
                        eprintln!("lost ring {} range {d:.2} background {:.2}", p.ring, ch.range_at(p, &cfg));
                    }
                }
                _ => {
                    st += 1;
                    st_removed += usize::from(bg);
                }
            }
        }
    }
    let (removed, kept) = (st_removed as f64 / st as f64, ru_kept as f64 / ru as f64);
    eprintln!("{st} static points, {:.3}% removed; {ru} road-user points, {:.2}% kept", 100.0 * removed, 100.0 * kept);
    assert!(ru > 1000, "the test frames hold too few road-user points ({ru})");
    assert!(removed >= 0.995, "{:.2}% of the static points removed", 100.0 * removed);
    assert!(kept >= 0.97, "{:.2}% of the road-user points kept", 100.0 * kept);
}
