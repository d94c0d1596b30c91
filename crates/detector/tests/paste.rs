//! The ground-truth paste database against what hilo knows exactly: the source of every
//! simulated LiDAR point and radar detection. A 16-beam LiDAR and a radar on one pole of the
//! default scene watch traffic; the LiDAR's background is learned from some frames, and on
//! others the instances cut for pasting must hold their own road user's points (and few others),
//! and most of them (measured: 466 instances, LiDAR 100.0% pure and complete, radar 99.9% pure,
//! 98.6% complete).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;
use common::pose;
use hilo_dataset::background::{BackgroundConfig, BackgroundModel};
use hilo_dataset::traffic::{ActorState, Traffic, TrafficConfig};
use hilo_detector::data::{Frame, GtBox, LIDAR_FEATURES, RADAR_FEATURES};
use hilo_detector::paste::{PasteConfig, PasteDb, footprints_overlap, in_box};
use hilo_raycast::{ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::lidar::PointSource;
use hilo_sensor_models::{Catalog, simulate_lidar, simulate_radar};
use rand::SeedableRng;
use std::collections::BTreeMap;

/// A simulated frame: the loader's view (LiDAR foreground, radar, boxes) and the source of each
/// of its points.
struct Sim {
    frame: Frame,
    lidar_sources: Vec<Option<u32>>,
    radar_sources: Vec<Option<u32>>,
    actor_ids: Vec<u32>,
}

fn simulate(scene: &Scene, world: &World, seed: u64, n: usize, every: usize, bg: &BackgroundModel) -> Vec<Sim> {
    let catalog = Catalog::default_catalog().unwrap();
    let (lidar, radar) = (catalog.lidar("lidar-16").unwrap(), catalog.radar("radar-4d").unwrap());
    let (lp, rp) = (pose(scene, 0, 0.4), pose(scene, 0, 0.1));
    let mut traffic = Traffic::new(&scene.layout, scene.ground.z_m, &TrafficConfig::default(), seed).unwrap();
    (0..n)
        .map(|k| {
            let actors = traffic.snapshot();
            let set = ActorSet::new(actors.iter().map(ActorState::actor).collect()).unwrap();
            let frame_seed = seed * 1000 + k as u64;
            let l = simulate_lidar(lidar, &lp, world, Some(&set), frame_seed).unwrap();
            let r = simulate_radar(radar, &rp, world, Some(&set), frame_seed).unwrap();
            for _ in 0..every {
                traffic.step();
            }
            // The LiDAR foreground as the loader keeps it (order kept, so walk both lists).
            let kept = bg.foreground("LIDAR_0", l.points.clone());
            let (mut lidar_pts, mut lidar_sources) = (Vec::new(), Vec::new());
            let mut it = kept.iter().peekable();
            for (p, s) in l.points.iter().zip(&l.sources) {
                if it.peek().is_some_and(|q| *q == p) {
                    it.next();
                    let q = lp.to_local(glam::Vec3::new(p.x, p.y, p.z));
                    lidar_pts.push([q.x, q.y, q.z, p.intensity, 0.0]);
                    lidar_sources.push(s.actor());
                }
            }
            let radar_pts: Vec<[f32; RADAR_FEATURES]> = r
                .points_local()
                .iter()
                .map(|p| hilo_detector::data::radar_point([p.x, p.y, p.z], p.rcs_dbsm, p.v_r_mps, [0.0, 0.0], 0.0))
                .collect();
            let radar_sources = r.sources.iter().map(PointSource::actor).collect();
            let boxes = actors
                .iter()
                .map(|a| GtBox {
                    class: a.class.index(),
                    center: a.box3.center.to_array(),
                    wlh: [a.box3.width_m, a.box3.length_m, a.box3.height_m],
                    yaw: a.box3.yaw,
                    velocity: a.velocity_mps.to_array(),
                })
                .collect();
            let frame = Frame {
                sample_token: format!("{seed}-{k}"),
                scene: seed.to_string(),
                lidar: lidar_pts,
                radar: radar_pts,
                radar_origin: Vec::new(),
                boxes,
            };
            Sim { frame, lidar_sources, radar_sources, actor_ids: actors.iter().map(|a| a.id).collect() }
        })
        .collect()
}

fn same<const F: usize>(a: &[f32; F], b: &[f32; F]) -> bool {
    a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

#[test]
fn cut_instances_hold_their_own_road_user() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let model = {
        let catalog = Catalog::default_catalog().unwrap();
        let lidar = catalog.lidar("lidar-16").unwrap();
        let lp = pose(&scene, 0, 0.4);
        let mut scans = Vec::new();
        for s in 0..3u64 {
            let mut traffic = Traffic::new(&scene.layout, scene.ground.z_m, &TrafficConfig::default(), 31 + s).unwrap();
            for k in 0..20u64 {
                let set = ActorSet::new(traffic.snapshot().iter().map(ActorState::actor).collect()).unwrap();
                scans.push(simulate_lidar(lidar, &lp, &world, Some(&set), (31 + s) * 1000 + k).unwrap().points);
                for _ in 0..40 {
                    traffic.step();
                }
            }
        }
        BackgroundModel::learn_from(
            &BTreeMap::from([("LIDAR_0".to_owned(), scans)]),
            &hilo_core::Valid::new(BackgroundConfig { frames: 60, ..BackgroundConfig::default() }).unwrap(),
        )
    };
    let sims: Vec<Sim> = (0..4).flat_map(|s| simulate(&scene, &world, 41 + s, 40, 20, &model)).collect();
    let frames: Vec<Frame> = sims.iter().map(|s| s.frame.clone()).collect();
    // The default fill, with golf carts (common in this traffic) filled further so that frames
    // receive them.
    let mut cfg = PasteConfig::default();
    cfg.fill.insert("golf_cart".into(), 8);
    let db = PasteDb::build(&frames, &hilo_core::Valid::new(cfg.clone()).unwrap()).unwrap();
    let held: usize = db.counts().iter().map(|(_, n)| n).sum();
    assert!(held >= 200, "too few instances to judge: {:?}", db.counts());
    let (mut l_cut, mut l_own, mut l_all) = (0usize, 0usize, 0usize);
    let (mut r_cut, mut r_own, mut r_all) = (0usize, 0usize, 0usize);
    for inst in db.instances() {
        let sim = &sims[inst.frame];
        let b = sim.frame.boxes.iter().position(|b| *b == inst.gt).unwrap();
        let id = sim.actor_ids[b];
        let src = |pts: &[[f32; LIDAR_FEATURES]], p: &[f32; LIDAR_FEATURES]| {
            pts.iter().position(|q| same(q, p)).map(|i| sim.lidar_sources[i])
        };
        l_cut += inst.lidar.len();
        l_own += inst.lidar.iter().filter(|p| src(&sim.frame.lidar, p) == Some(Some(id))).count();
        l_all += sim.lidar_sources.iter().filter(|s| **s == Some(id)).count();
        r_cut += inst.radar.len();
        r_own += inst
            .radar
            .iter()
            .filter(|p| {
                let i = sim.frame.radar.iter().position(|q| same(q, p)).unwrap();
                sim.radar_sources[i] == Some(id)
            })
            .count();
        r_all += sim.radar_sources.iter().filter(|s| **s == Some(id)).count();
    }
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    eprintln!(
        "{held} instances {:?}: LiDAR {l_cut} cut, {:.1}% their own, {:.1}% of their own kept; radar {r_cut} cut, \
         {:.1}% their own, {:.1}% of their own kept",
        db.counts(),
        pct(l_own, l_cut),
        pct(l_own, l_all),
        pct(r_own, r_cut),
        pct(r_own, r_all)
    );
    assert!(pct(l_own, l_cut) >= 99.0, "LiDAR points cut with an instance are mostly someone else's");
    assert!(pct(l_own, l_all) >= 99.0, "an instance leaves its own LiDAR points behind");
    assert!(pct(r_own, r_cut) >= 97.0, "radar detections cut with an instance are mostly someone else's");
    assert!(pct(r_own, r_all) >= 97.0, "an instance leaves its own radar detections behind");
    // Pasting into another frame of the same rig never overlaps a box, and each pasted box
    // holds at least the points an instance needs.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut pasted = 0;
    for f in &frames {
        let out = db.paste(f, &mut rng);
        for (i, a) in out.boxes.iter().enumerate().skip(f.boxes.len()) {
            pasted += 1;
            assert!(out.boxes[..i].iter().all(|b| !footprints_overlap(a, b)));
            let inside = out.lidar.iter().filter(|p| in_box(a, [p[0], p[1], p[2]], cfg.lidar_margin_m)).count();
            assert!(inside >= cfg.min_lidar_points, "{inside} points in a pasted box");
        }
    }
    assert!(pasted > frames.len(), "{pasted} instances pasted into {} frames", frames.len());
}
