//! The loader's near-range cut: LiDAR points closer than `lidar_min_range_m` to their own
//! sensor are left out, measured in the sensor's frame (not from the scene's origin), against
//! a brute-force count; the rest arrive in the scene's frame as before.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::Vec3;
use hilo_core::LidarPoint;
use hilo_dataset::Dataset;
use hilo_dataset::writer::{DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup};
use hilo_detector::data::{LoadOptions, load_split};
use hilo_fusion::config::InputConfig;
use hilo_sensor_models::SensorPose;

fn lidar(channel: &str, pose: SensorPose) -> SensorSetup {
    SensorSetup { channel: channel.into(), modality: SensorModality::Lidar, pose }
}

/// Points along rays of the sensor's frame at ranges 0.5, 1.0, …, 8.0 m.
fn ranged_points(dir: Vec3) -> Vec<LidarPoint> {
    (1..=16)
        .map(|k| {
            let p = dir.normalize() * (0.5 * k as f32);
            LidarPoint { x: p.x, y: p.y, z: p.z, intensity: 0.5, ring: 0, time_s: 0.0 }
        })
        .collect()
}

#[test]
fn points_near_their_own_sensor_are_left_out() {
    let dir = tempfile::tempdir().unwrap();
    // Two LiDARs on masts 20 m apart, one turned a quarter and tilted down.
    let poses = [
        SensorPose::new(Vec3::new(10.0, 0.0, 5.0), 0.0, 0.0, 0.0),
        SensorPose::new(Vec3::new(-10.0, 0.0, 4.0), 90.0, 10.0, 0.0),
    ];
    let sensors = vec![lidar("LIDAR_0", poses[0]), lidar("LIDAR_1", poses[1])];
    let mut w = DatasetWriter::new(dir.path(), "v1.0-trainval", "t", sensors).unwrap();
    let clouds = [ranged_points(Vec3::new(1.0, 0.3, -0.5)), ranged_points(Vec3::new(-0.2, 1.0, 0.1))];
    let frame = FrameData { timestamp_us: 1_000_000_000, lidar: clouds.to_vec(), radar: vec![], annotations: vec![] };
    let scene = SceneData { name: "val-0000".into(), description: String::new(), frames: vec![frame], sweeps: vec![] };
    w.add_scene(&scene, "x").unwrap();
    w.write_splits(&std::collections::BTreeMap::from([("val".to_string(), vec!["val-0000".to_string()])])).unwrap();
    w.finish().unwrap();
    let ds = Dataset::open(dir.path(), "v1.0-trainval").unwrap();
    let load = |cut: f32| {
        let input = InputConfig { lidar_min_range_m: cut, ..InputConfig::default() };
        load_split(&ds, "val", &LoadOptions::new(&input, None, false)).unwrap()
    };
    let (all, s0) = load(0.0);
    assert_eq!((all[0].lidar.len(), s0.near_points), (32, 0));
    for cut in [0.75, 2.0, 3.0, 6.2] {
        let (frames, stats) = load(cut);
        // Brute force: the points of each sensor at cut or more from it, in the scene's frame.
        let want: Vec<Vec3> = clouds
            .iter()
            .zip(&poses)
            .flat_map(|(c, pose)| {
                c.iter()
                    .filter(|p| Vec3::new(p.x, p.y, p.z).length() >= cut)
                    .map(|p| pose.position + pose.rotation() * Vec3::new(p.x, p.y, p.z))
                    .collect::<Vec<_>>()
            })
            .collect();
        let got: Vec<Vec3> = frames[0].lidar.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect();
        assert_eq!(got.len(), want.len(), "cut {cut}");
        assert_eq!(stats.near_points, 32 - want.len());
        for (g, w) in got.iter().zip(&want) {
            assert!((*g - *w).length() < 1e-4, "cut {cut}: {g} against {w}");
        }
        // Measured from each sensor: every kept point is at least the cut from its own mast.
        for g in &got {
            assert!(poses.iter().any(|p| (*g - p.position).length() >= cut - 1e-4));
        }
        assert!(stats.notes(false, false).iter().any(|n| n.starts_with("near-range LiDAR points removed")));
    }
}

#[test]
fn the_cut_is_checked_and_absent_from_a_presets_json_when_off() {
    let json = serde_json::to_string(&InputConfig::default()).unwrap();
    assert!(!json.contains("lidar_min_range_m"), "{json}");
    for bad in [-1.0, f32::NAN, 25.0] {
        let e = InputConfig { lidar_min_range_m: bad, ..InputConfig::default() }.validate().unwrap_err().to_string();
        assert!(e.contains("input.lidar_min_range_m"), "{e}");
    }
    assert!(InputConfig { lidar_min_range_m: 4.0, ..InputConfig::default() }.validate().is_ok());
}
