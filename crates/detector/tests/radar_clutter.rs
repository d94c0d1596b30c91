//! The radar clutter rule against what hilo knows exactly: the source of every simulated radar
//! detection (a road user, a static structure, the ground). A LiDAR and a radar on one pole of
//! the default scene watch traffic; the LiDAR's background is learned from some frames, and on
//! others the rule, given the LiDAR foreground, must drop the static detections and keep the
//! road users'.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
use common::pose;
use hilo_dataset::background::{BackgroundConfig, BackgroundModel};
use hilo_dataset::traffic::{ActorState, Traffic, TrafficConfig};
use hilo_detector::data::{LIDAR_FEATURES, RADAR_FEATURES, RadarClutterConfig, drop_radar_clutter};
use hilo_raycast::{ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::lidar::PointSource;
use hilo_sensor_models::{Catalog, simulate_lidar, simulate_radar};
use std::collections::BTreeMap;

struct Frame {
    lidar: Vec<hilo_core::LidarPoint>,
    radar: Vec<[f32; RADAR_FEATURES]>,
    radar_sources: Vec<PointSource>,
}

/// Frames of traffic, every `every` steps after the start, seen by both sensors.
fn frames(scene: &Scene, world: &World, seed: u64, n: usize, every: usize) -> Vec<Frame> {
    let catalog = Catalog::default_catalog().unwrap();
    let (lidar, radar) = (catalog.lidar("lidar-16").unwrap(), catalog.radar("radar-4d").unwrap());
    let (lp, rp) = (pose(scene, 0, 0.4), pose(scene, 0, 0.1));
    let mut traffic = Traffic::new(&scene.layout, scene.ground.z_m, &TrafficConfig::default(), seed).unwrap();
    (0..n)
        .map(|k| {
            let set = ActorSet::new(traffic.snapshot().iter().map(ActorState::actor).collect()).unwrap();
            let frame_seed = seed * 1000 + k as u64;
            let l = simulate_lidar(lidar, &lp, world, Some(&set), frame_seed).unwrap();
            let r = simulate_radar(radar, &rp, world, Some(&set), frame_seed).unwrap();
            for _ in 0..every {
                traffic.step();
            }
            // Radar features as the loader writes them (local frame; the rule reads x, y, v_r).
            let radar_local = r
                .points_local()
                .iter()
                .map(|p| hilo_detector::data::radar_point([p.x, p.y, p.z], p.rcs_dbsm, p.v_r_mps, [0.0, 0.0], 0.0))
                .collect();
            Frame { lidar: l.points, radar: radar_local, radar_sources: r.sources }
        })
        .collect()
}

#[test]
fn radar_clutter_rule_against_the_known_sources() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let bg_cfg = hilo_core::Valid::new(BackgroundConfig { frames: 60, ..BackgroundConfig::default() }).unwrap();
    let train: Vec<Frame> = (0..3).flat_map(|s| frames(&scene, &world, 31 + s, 20, 40)).collect();
    let model = BackgroundModel::learn_from(
        &BTreeMap::from([("LIDAR_0".to_owned(), train.iter().map(|f| f.lidar.clone()).collect())]),
        &bg_cfg,
    );
    let lp = pose(&scene, 0, 0.4);
    let cfg = RadarClutterConfig::default();
    let (mut clutter, mut clutter_dropped, mut road, mut road_kept, mut moving, mut moving_kept) =
        (0usize, 0usize, 0usize, 0usize, 0usize, 0usize);
    for f in frames(&scene, &world, 41, 30, 10) {
        let foreground: Vec<[f32; LIDAR_FEATURES]> = model
            .foreground("LIDAR_0", f.lidar.clone())
            .iter()
            .map(|p| {
                let q = lp.to_local(glam::Vec3::new(p.x, p.y, p.z));
                [q.x, q.y, q.z, p.intensity, 0.0]
            })
            .collect();
        let mut kept = f.radar.clone();
        let dropped = drop_radar_clutter(&foreground, &mut kept, &cfg);
        assert_eq!(dropped + kept.len(), f.radar.len(), "the drop count is what left");
        // Which detections survived: the rule keeps order, so walk both lists.
        let mut it = kept.iter().peekable();
        for (p, s) in f.radar.iter().zip(&f.radar_sources) {
            let survived = it.peek().is_some_and(|q| *q == p);
            if survived {
                it.next();
            }
            match s {
                PointSource::Actor(_) => {
                    road += 1;
                    road_kept += usize::from(survived);
                    if p[4].abs() > cfg.max_speed_mps {
                        moving += 1;
                        moving_kept += usize::from(survived);
                    }
                }
                _ => {
                    clutter += 1;
                    clutter_dropped += usize::from(!survived);
                }
            }
        }
        assert!(it.next().is_none(), "every kept detection is one of the frame's, in order");
    }
    let (dropped, kept) = (clutter_dropped as f64 / clutter as f64, road_kept as f64 / road as f64);
    eprintln!(
        "{clutter} clutter detections, {:.1}% dropped; {road} road-user detections, {:.1}% kept ({moving} moving, \
         {moving_kept} kept)",
        100.0 * dropped,
        100.0 * kept
    );
    assert!(clutter > 200 && road > 500, "too few detections to judge ({clutter} clutter, {road} road users)");
    assert_eq!(moving_kept, moving, "a moving detection is never dropped");
    assert!(dropped >= 0.90, "only {:.1}% of the clutter dropped", 100.0 * dropped);
    assert!(kept >= 0.95, "only {:.1}% of the road users' detections kept", 100.0 * kept);
}
