//! What two radars measure of the default junction's traffic: two catalog `radar-4d` (noise and
//! clutter on) on adjacent corner poles, over the key frames of a training scene, with every
//! detection pair on one road user solved for its full ground velocity and checked against the
//! road user's true velocity. Prints the share of moving road users that get a pair and the
//! error; asserts what the radar's 0.1 m/s radial noise and the geometry allow.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_dataset::simulate::{SceneId, SimulateConfig, Split, derive_seed, key_frame_states};
use hilo_raycast::{ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::radar_pair::pair_velocities;
use hilo_sensor_models::{Catalog, SensorPose, simulate_radar};
use std::collections::{BTreeMap, BTreeSet};

#[test]
fn two_corner_radars_measure_moving_road_users_full_velocity() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let cfg =
        SimulateConfig { scenes: 1, seconds: 6.0, val_scenes: 1, ..SimulateConfig::default() }.validate().unwrap();
    let spec = Catalog::default_catalog().unwrap().radar("radar-4d").unwrap().clone();
    // NE and NW: adjacent corners, so their lines of sight to the junction's middle cross.
    let pose = |name: &str| {
        let m = scene.mounts.iter().find(|m| m.name == name).unwrap();
        let p = m.base + m.arm_dir * (0.5 * m.arm_length_m);
        SensorPose::new(p.extend(scene.ground.z_m + m.arm_height_m + 0.1), (-p.y).atan2(-p.x), 0.14, 0.0)
    };
    let poses = [pose("NE"), pose("NW")];
    let id = SceneId { split: Split::Train, index: 0 };
    let frames = key_frame_states(&scene, &cfg, &id).unwrap();
    let (mut errors, mut moving, mut paired) = (Vec::new(), BTreeSet::new(), BTreeSet::new());
    // The same detections' radial velocity vector (v_r along the line of sight on the ground:
    // what one radar gives the detector) against the truth.
    let mut radial = Vec::new();
    for (f, states) in frames.iter().enumerate().step_by(2) {
        let truth: BTreeMap<u32, Vec3> = states.iter().map(|a| (a.id, a.velocity_mps.extend(0.0))).collect();
        let set = ActorSet::new(states.iter().map(|a| a.actor()).collect()).unwrap();
        let views: Vec<Vec<(Vec3, f32, Option<u32>)>> = poses
            .iter()
            .enumerate()
            .map(|(k, pose)| {
                let scan =
                    simulate_radar(&spec, pose, &world, Some(&set), derive_seed(5, &[f as u64, k as u64])).unwrap();
                scan.points_local()
                    .iter()
                    .zip(&scan.sources)
                    .map(|(p, s)| (Vec3::new(p.x, p.y, p.z), p.v_r_mps, s.actor()))
                    .collect()
            })
            .collect();
        for a in states.iter().filter(|a| a.velocity_mps.length() > 1.0 && a.box3.center.truncate().length() < 50.0) {
            moving.insert((f, a.id));
        }
        let plain = |k: usize| views[k].iter().map(|&(p, r, _)| (p, r)).collect::<Vec<_>>();
        let (a, b) = (plain(0), plain(1));
        for (i, j, v) in pair_velocities((poses[0].position, &a), (poses[1].position, &b), 1.0, 20f32.to_radians()) {
            let (Some(x), Some(y)) = (views[0][i].2, views[1][j].2) else { continue };
            if x != y {
                continue;
            }
            let t = truth[&x].truncate();
            if t.length() > 1.0 {
                errors.push((v.velocity - t).length());
                paired.insert((f, x));
                let (p, r, _) = views[0][i];
                let u = (p - poses[0].position).truncate().normalize();
                radial.push((u * r - t).length());
            }
        }
    }
    errors.sort_by(f32::total_cmp);
    radial.sort_by(f32::total_cmp);
    let q = |p: f32| errors[((errors.len() - 1) as f32 * p) as usize];
    let radial_median = radial[radial.len() / 2];
    let share = paired.len() as f32 / moving.len().max(1) as f32;
    println!(
        "two radars: {} of {} moving road users within 50 m paired ({:.0}%), {} pairs on them; velocity error median {:.2} m/s, 90th percentile {:.2}; one radar's radial vector, median {:.2}",
        paired.len(),
        moving.len(),
        100.0 * share,
        errors.len(),
        q(0.5),
        q(0.9),
        radial_median
    );
    assert!(errors.len() >= 20 && share > 0.1, "{} pairs, {share}", errors.len());
    // 0.1 m/s of radial noise times a dilution of 1–3 at 20°–90°, plus a turning car's rotation.
    assert!(q(0.5) < 0.5, "median {}", q(0.5));
    assert!(radial_median > 3.0 * q(0.5), "one radar alone: {radial_median}");
}
