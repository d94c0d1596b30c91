//! LiDAR scans: counts per spec, range and FOV, ring and time order, determinism, mounts.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use glam::Vec3;
use hilo_core::{Box3, Class};
use hilo_raycast::{Actor, ActorSet, QueryRegion, Scene, World};
use hilo_sensor_models::{LidarSpec, PointSource, SensorError, SensorPose, simulate_lidar};

#[test]
fn beam_and_azimuth_counts_ranges_fov_rings_and_times_follow_the_spec() {
    let world = dome_world();
    for name in ["lidar-16", "lidar-32", "lidar-64"] {
        let spec = ideal_lidar(name);
        let pose = SensorPose::new(Vec3::new(3.0, -2.0, 6.0), 0.4, 0.0, 0.0);
        let scan = simulate_lidar(&spec, &pose, &world, None, 1).unwrap();
        let cols = spec.columns() as usize;
        assert_eq!(scan.rays_cast, spec.beams as usize * cols);
        assert_eq!(scan.points.len(), scan.rays_cast, "{name}: every ray hits the dome or the ground");
        let elev = spec.elevations_rad();
        let mut per_ring = vec![0usize; spec.beams as usize];
        for (i, p) in scan.points.iter().enumerate() {
            let r = Vec3::new(p.x, p.y, p.z).length();
            assert!(r > spec.min_range_m && r <= spec.max_range_m, "{name}: range {r}");
            let el = (p.z / r).asin();
            assert!((el - elev[p.ring as usize]).abs() < 1e-4, "{name}: point {i} off its beam");
            per_ring[p.ring as usize] += 1;
            assert!((0.0..=1.0).contains(&p.intensity));
            if i > 0 {
                let q = &scan.points[i - 1];
                assert!(p.time_s >= q.time_s, "time must not decrease");
                if p.time_s == q.time_s {
                    assert!(p.ring > q.ring, "rings ascend within a column");
                }
            }
        }
        assert!(per_ring.iter().all(|&n| n == cols), "{name}: {per_ring:?}");
        let last = scan.points.last().unwrap().time_s;
        assert!(last < 1.0 / spec.rate_hz && last > 0.9 / spec.rate_hz);
    }
}

#[test]
fn same_seed_same_scan_and_another_seed_differs() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let spec = catalog().lidar("lidar-32").unwrap().clone();
    let pose = SensorPose::new(Vec3::new(13.0, 16.6, 7.8), 0.0, 0.2, 0.0);
    let a = simulate_lidar(&spec, &pose, &world, None, 42).unwrap();
    let b = simulate_lidar(&spec, &pose, &world, None, 42).unwrap();
    let c = simulate_lidar(&spec, &pose, &world, None, 43).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.points, c.points);
    // Drop-off removes a few percent, not most.
    let kept = a.points.len() as f64 / a.rays_cast as f64;
    assert!(kept > 0.3 && kept < 0.99, "{kept}");
}

#[test]
fn empty_scene_gives_an_empty_cloud() {
    let world = World::from_triangles(&[], None).unwrap();
    let spec = catalog().lidar("lidar-16").unwrap().clone();
    let scan =
        simulate_lidar(&spec, &SensorPose::new(Vec3::new(0.0, 0.0, 5.0), 0.0, 0.0, 0.0), &world, None, 0).unwrap();
    assert!(scan.points.is_empty() && scan.sources.is_empty());
    assert!(scan.rays_cast > 0);
}

#[test]
fn a_mount_inside_a_building_or_an_actor_is_an_error() {
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let spec = catalog().lidar("lidar-16").unwrap().clone();
    // Inside the bank (x -45..-25, y -45..-28, 7 m high).
    let expect_err = |r: Result<_, SensorError>| match r {
        Err(e) => e,
        Ok(_) => panic!("a mount inside geometry must be refused"),
    };
    let err = expect_err(simulate_lidar(
        &spec,
        &SensorPose::new(Vec3::new(-35.0, -36.0, 3.0), 0.0, 0.0, 0.0),
        &world,
        None,
        0,
    ));
    assert!(matches!(err, SensorError::InsideGeometry { .. }));
    assert!(err.to_string().contains("bank"), "{err}");
    let car = Actor::from_box(7, Class::Car, Box3::new(Vec3::new(0.0, 5.0, 0.8), 4.5, 1.9, 1.6, 0.0));
    let actors = ActorSet::new(vec![car]).unwrap();
    let err = expect_err(simulate_lidar(
        &spec,
        &SensorPose::new(Vec3::new(0.5, 5.0, 1.0), 0.0, 0.0, 0.0),
        &world,
        Some(&actors),
        0,
    ));
    assert!(err.to_string().contains("actor 7"), "{err}");
    // Underground.
    let err =
        expect_err(simulate_lidar(&spec, &SensorPose::new(Vec3::new(0.0, 0.0, -5.0), 0.0, 0.0, 0.0), &world, None, 0));
    assert!(err.to_string().contains("below the ground"), "{err}");
    // On top of a pole is fine.
    assert!(
        simulate_lidar(&spec, &SensorPose::new(Vec3::new(13.0, 16.6, 7.8), 0.0, 0.0, 0.0), &world, None, 0).is_ok()
    );
}

#[test]
fn points_on_actors_are_attributed_and_local_frame_is_consistent() {
    let world = ground_world();
    let spec = ideal_lidar("lidar-64");
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.0), 0.3, 0.15, 0.0);
    let bus = Actor::from_box(11, Class::Bus, Box3::new(Vec3::new(15.0, 4.0, 1.6), 12.0, 2.6, 3.2, 0.2));
    let ped = Actor::from_box(12, Class::Pedestrian, Box3::new(Vec3::new(10.0, -6.0, 0.875), 0.6, 0.6, 1.75, 0.0));
    let actors = ActorSet::new(vec![bus, ped]).unwrap();
    let scan = simulate_lidar(&spec, &pose, &world, Some(&actors), 5).unwrap();
    let counts = scan.points_per_actor();
    assert!(counts[&11] > counts[&12] && counts[&12] > 5, "{counts:?}");
    for (p, s) in scan.points_local().iter().zip(&scan.sources) {
        let q = Vec3::new(p.x, p.y, p.z);
        match s {
            PointSource::Ground => assert!(q.z.abs() < 1e-3, "{q}"),
            PointSource::Actor(id) => {
                let a = actors.actors().iter().find(|a| a.id == *id).unwrap();
                let b = a.shape.outline();
                let grown =
                    Box3 { length_m: b.length_m + 0.01, width_m: b.width_m + 0.01, height_m: b.height_m + 0.01, ..b };
                assert!(grown.contains(q), "point {q} not on actor {id}");
            }
            PointSource::Static => panic!("no static geometry here"),
            other => panic!("a LiDAR gives no radar artefact: {other:?}"),
        }
    }
}

/// With road users that move during the sweep, every return on one lies on it where it is at
/// the return's column time (the rolling shutter), and a fast one's returns no longer fit where
/// it was at the frame's instant.
#[test]
fn a_spinning_lidar_sees_a_moving_road_user_where_it_is_at_each_column() {
    let world = ground_world();
    let spec = ideal_lidar("lidar-64");
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 6.0), 0.0, 0.0, 0.0);
    let period = 1.0 / spec.rate_hz;
    // Across the start of the rotation (azimuth 0: time 0 on its +y side, time ≈ period on its
    // −y side), moving toward −y: the rotation's end finds it a metre on, stretched.
    let car = Actor::from_box(3, Class::Car, Box3::new(Vec3::new(18.0, 0.0, 0.8), 4.5, 1.9, 1.6, 0.0))
        .with_velocity(Vec3::new(0.0, -20.0, 0.0));
    let moving = ActorSet::moving(vec![car], period).unwrap();
    let scan = simulate_lidar(&spec, &pose, &world, Some(&moving), 4).unwrap();
    let grown =
        |b: Box3| Box3 { length_m: b.length_m + 0.01, width_m: b.width_m + 0.01, height_m: b.height_m + 0.01, ..b };
    let box_of = |a: &Actor| match a.shape {
        hilo_raycast::ActorShape::Box(b) => b,
        _ => unreachable!(),
    };
    let (mut on_car, mut off_start) = (0, 0);
    for (p, s) in scan.points_local().iter().zip(&scan.sources) {
        if *s != PointSource::Actor(3) {
            continue;
        }
        let q = Vec3::new(p.x, p.y, p.z);
        on_car += 1;
        assert!(grown(box_of(&car.moved(p.time_s))).contains(q), "{q} at {} s is not on the car", p.time_s);
        off_start += usize::from(!grown(box_of(&car)).contains(q));
    }
    assert!(on_car > 100, "{on_car}");
    assert!(off_start > on_car / 10, "the car is skewed: {off_start} of {on_car} returns off its start");
    // A still set freezes it at the frame's instant, as before.
    let still = simulate_lidar(&spec, &pose, &world, Some(&ActorSet::new(vec![car]).unwrap()), 4).unwrap();
    for (p, s) in still.points_local().iter().zip(&still.sources) {
        if *s == PointSource::Actor(3) {
            assert!(grown(box_of(&car)).contains(Vec3::new(p.x, p.y, p.z)));
        }
    }
}

/// A road user's own reflectivity reaches its returns: intensities scale with it, and under
/// the lidar equation a black car is lost where a white one is still seen.
#[test]
fn a_road_users_paint_sets_its_returns() {
    let world = ground_world();
    let mut spec = ideal_lidar("lidar-16");
    let pose = SensorPose::new(Vec3::new(0.0, 0.0, 4.0), 0.0, 0.0, 0.0);
    let car = |r: f32, x: f32| {
        let b = Box3::new(Vec3::new(x, 0.0, 0.8), 4.5, 1.9, 1.6, 0.3);
        ActorSet::new(vec![Actor::from_box(2, Class::Car, b).with_reflectivity(r)]).unwrap()
    };
    let on_car = |s: &hilo_sensor_models::LidarScan| -> Vec<f32> {
        s.points
            .iter()
            .zip(&s.sources)
            .filter(|(_, s)| **s == PointSource::Actor(2))
            .map(|(p, _)| p.intensity)
            .collect()
    };
    let white = on_car(&simulate_lidar(&spec, &pose, &world, Some(&car(0.75, 20.0)), 1).unwrap());
    let black = on_car(&simulate_lidar(&spec, &pose, &world, Some(&car(0.06, 20.0)), 1).unwrap());
    assert!(!white.is_empty() && white.len() == black.len(), "the same rays hit it");
    for (w, b) in white.iter().zip(&black) {
        assert!((w / 0.75 - b / 0.06).abs() < 1e-4, "intensity ∝ reflectivity: {w} {b}");
    }
    // The lidar equation: 100 m at 0.8, so reach = 100·sqrt(ρ/0.8): 97 m white, 27 m black.
    spec.detection_range = Some(hilo_sensor_models::DetectionRange { range_m: 100.0, reflectivity: 0.8 });
    let at = |r: f32, x: f32| on_car(&simulate_lidar(&spec, &pose, &world, Some(&car(r, x)), 1).unwrap()).len();
    assert!(at(0.06, 20.0) > 0 && at(0.75, 40.0) > 0);
    assert_eq!(at(0.06, 40.0), 0, "a black car 40 m away is past its reach");
    // The default is the class's.
    let plain = Actor::from_box(2, Class::Car, Box3::new(Vec3::ZERO, 4.5, 1.9, 1.6, 0.0));
    assert_eq!(plain.reflectivity, hilo_raycast::Material::VehicleBody.lidar_reflectivity());
    assert!(ActorSet::new(vec![Actor { reflectivity: f32::NAN, ..plain }]).is_err());
}

/// Foliage in wind: of the rays whose first surface is a tree crown, the stated share passes
/// through a gap and returns from what lies behind (exactly the next surface along the ray);
/// the others return from a leaf displaced along the ray with the stated spread; every other
/// ray returns as it did, and still foliage is no change at all.
#[test]
fn crowns_in_wind_let_rays_through_and_sway() {
    use hilo_raycast::{HitTarget, Material, Ray};
    use hilo_sensor_models::Foliage;
    use std::collections::BTreeMap;
    let scene = Scene::default_fixture().unwrap();
    let world = World::build(&scene, &QueryRegion::everything()).unwrap();
    let base = ideal_lidar("lidar-64");
    let pose = SensorPose::new(Vec3::new(13.0, 16.6, 7.8), -2.2, 0.17, 0.0);
    let scan = |f: Option<Foliage>| {
        let spec = LidarSpec { foliage: f, ..base.clone() };
        let s = simulate_lidar(&spec, &pose, &world, None, 8).unwrap();
        // Each ray by (ring, column time): its return in the sensor frame.
        s.points.iter().map(|p| ((p.ring, p.time_s.to_bits()), Vec3::new(p.x, p.y, p.z))).collect::<BTreeMap<_, _>>()
    };
    let still = scan(None);
    assert_eq!(still, scan(Some(Foliage { gap_probability: 0.0, sway_m: 0.0 })), "still foliage changes nothing");
    let rot = pose.rotation();
    let first = |p: Vec3| {
        let ray =
            Ray { origin: pose.position, dir: rot * p.normalize(), t_min: base.min_range_m, t_max: base.max_range_m };
        (ray, world.closest_hit(&ray, None).unwrap())
    };
    let on_crown = |p: &Vec3| {
        let h = first(*p).1;
        matches!(h.target, HitTarget::Static { .. }) && h.material == Material::Vegetation
    };
    let crown_rays = still.values().filter(|p| on_crown(p)).count();
    assert!(crown_rays >= 300, "the pose sees the fixture's trees: {crown_rays} crown returns");
    // Gaps: 30% of crown rays pass; each returns the next surface or nothing.
    let gappy = scan(Some(Foliage { gap_probability: 0.3, sway_m: 0.0 }));
    let mut passed = 0;
    for (key, p) in &still {
        let q = gappy.get(key);
        if !on_crown(p) {
            assert_eq!(q, Some(p), "a ray that meets no crown returns as before");
            continue;
        }
        if q == Some(p) {
            continue;
        }
        passed += 1;
        let (ray, h) = first(*p);
        let behind = world.closest_hit(&Ray { t_min: h.t + 0.05, ..ray }, None).filter(|b| b.t <= base.max_range_m);
        match (q, behind) {
            (Some(q), Some(b)) => assert!((q.length() - b.t).abs() < 1e-3, "{} vs {}", q.length(), b.t),
            (None, None) => {}
            (q, b) => panic!("through the gap: {q:?} against {:?}", b.map(|b| b.t)),
        }
    }
    let share = passed as f64 / crown_rays as f64;
    let sd = (0.3 * 0.7 / crown_rays as f64).sqrt();
    assert!((share - 0.3).abs() < 4.5 * sd, "{passed} of {crown_rays} passed");
    // Sway: leaves move along the ray with the stated spread.
    let swayed = scan(Some(Foliage { gap_probability: 0.0, sway_m: 0.2 }));
    let d: Vec<f64> = still
        .iter()
        .filter(|(_, p)| on_crown(p))
        .filter_map(|(k, p)| swayed.get(k).map(|q| (q.length() - p.length()) as f64))
        .collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    assert!(mean.abs() < 4.0 * 0.2 / n.sqrt() && (sd / 0.2 - 1.0).abs() < 0.1, "mean {mean}, sd {sd} over {n}");
}
