//! Cyclists (nuScenes `bicycle`) on the roadway: they ride with the vehicles at a cyclist's
//! speed and stop for the same lights, and a dataset whose traffic carries them lists and
//! annotates them; a dataset whose traffic cannot carry them is the paper's six classes.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use hilo_core::Class;
use hilo_dataset::Dataset;
use hilo_dataset::simulate::{SimulateConfig, write_dataset};
use hilo_dataset::traffic::{Traffic, TrafficConfig, class_model};
use hilo_raycast::{QueryRegion, Scene, World};
use std::collections::{BTreeMap, BTreeSet};

/// A mix in which every third vehicle is a cyclist.
fn with_cyclists() -> TrafficConfig {
    let mut cfg = TrafficConfig::default();
    cfg.class_mix.insert("bicycle".into(), 0.5);
    cfg
}

#[test]
fn cyclists_ride_the_roadway_at_a_cyclists_speed_and_stop_at_the_line() {
    let s = Scene::default_fixture().unwrap();
    let cfg = with_cyclists();
    let mut t = Traffic::new(&s.layout, s.ground.z_m, &cfg, 7).unwrap();
    let m = class_model(Class::Bicycle);
    let dt = t.step_s() as f32;
    let (mut prev, mut through, mut seen) = (BTreeMap::new(), BTreeSet::new(), BTreeSet::new());
    let (mut stopped_at_line, mut fastest) = (0usize, 0f32);
    for _ in 0..(150.0 / t.step_s()) as usize {
        for a in t.snapshot().into_iter().filter(|a| a.class == Class::Bicycle) {
            seen.insert(a.id);
            let v = a.velocity_mps.length();
            fastest = fastest.max(v);
            assert!(v <= m.v_max + 1e-3, "cyclist {} at {v} m/s", a.id);
            assert_eq!(a.attribute, "cycle.with_rider");
            let b = a.box3;
            assert!((m.length.2..=m.length.3).contains(&b.length_m) && (m.width.2..=m.width.3).contains(&b.width_m));
            assert!(
                s.layout.on_carriageway(b.center.truncate()),
                "cyclist {} off the carriageway at {}",
                a.id,
                b.center
            );
            if let Some(p) = prev.get(&a.id) {
                let acc = (v - p) / dt;
                assert!(acc >= -m.b_max - 1e-3 && acc <= m.a + 1e-3, "cyclist {} accelerates at {acc} m/s²", a.id);
            }
            prev.insert(a.id, v);
            if let Some(r) = a.route {
                if r.front_s > r.stop_s {
                    through.insert(a.id);
                } else if v < 0.1 && r.stop_s - r.front_s < 3.0 {
                    stopped_at_line += 1;
                }
            }
        }
        t.step();
    }
    eprintln!(
        "{} cyclists, {} through, {stopped_at_line} frames held at a line, fastest {fastest:.2} m/s",
        seen.len(),
        through.len()
    );
    // Every third vehicle at the default rates: tens of cyclists in 150 s, most of them through
    // the junction, some held at a red light, cruising at about their 5.5 m/s.
    assert!(seen.len() >= 20, "{} cyclists", seen.len());
    assert!(through.len() * 2 >= seen.len(), "{} of {} cyclists crossed their stop line", through.len(), seen.len());
    assert!(stopped_at_line > 0, "no cyclist ever waited at a stop line");
    assert!(fastest > 4.5, "the fastest cyclist rode at {fastest} m/s");
}

#[test]
fn a_dataset_lists_cyclists_only_where_its_traffic_carries_them() {
    let scene = Scene::default_fixture().unwrap();
    let w = World::build(&scene, &QueryRegion::everything()).unwrap();
    let catalog = hilo_sensor_models::Catalog::default_catalog().unwrap();
    let mount = &scene.mounts[0];
    let p = mount.base + mount.arm_dir * (0.5 * mount.arm_length_m);
    let rig = vec![hilo_dataset::simulate::RigSensor {
        channel: "LIDAR_0".into(),
        spec: catalog.get("lidar-16").unwrap().clone(),
        pose: hilo_sensor_models::SensorPose::new(
            p.extend(scene.ground.z_m + mount.arm_height_m),
            (-p.y).atan2(-p.x),
            10f32.to_radians(),
            0.0,
        ),
    }];
    let base = SimulateConfig {
        scenes: 1,
        seconds: 3.0,
        val_scenes: 1,
        val_seconds: 2.0,
        seed: 3,
        ..SimulateConfig::default()
    };
    let write = |cfg: SimulateConfig| {
        let dir = tempfile::tempdir().unwrap();
        write_dataset(&scene, &w, &rig, &cfg.validate().unwrap(), dir.path(), "v1.0-trainval", "t", &|_| {}).unwrap();
        let ds = Dataset::open(dir.path(), "v1.0-trainval").unwrap();
        (dir, ds)
    };
    let (_plain_dir, plain) = write(base.clone());
    assert_eq!(plain.classes(), Class::PAPER);
    assert_eq!(plain.tables.category.len(), Class::PAPER.len());
    let (dir, ds) = write(SimulateConfig { traffic: with_cyclists(), ..base });
    assert_eq!(ds.classes(), Class::ALL);
    let bicycle = ds.tables.category.iter().find(|c| c.name == "vehicle.bicycle").unwrap();
    let instances: BTreeSet<&str> =
        ds.tables.instance.iter().filter(|i| i.category_token == bicycle.token).map(|i| i.token.as_str()).collect();
    assert!(!instances.is_empty(), "no cyclist annotated");
    let rider = ds.tables.attribute.iter().find(|a| a.name == "cycle.with_rider").unwrap();
    for a in ds.tables.sample_annotation.iter().filter(|a| instances.contains(a.instance_token.as_str())) {
        assert_eq!(a.attribute_tokens, std::slice::from_ref(&rider.token));
    }
    common::devkit_check(dir.path());
}
