//! Sweep stacking in the loader: the key frame's sweep and the ones before it, each point with
//! its sweep's time lag, newest first; empty sweeps; a gap longer than the lag limit ends the
//! stack; the LiDAR's sweeps likewise, the sweeps it did not scan left out of its chain; one
//! radar's points pass radar pairing unchanged; each radar point carries its radar's position.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class, LidarPoint, RadarPoint};
use hilo_dataset::Dataset;
use hilo_dataset::writer::{Annotation, DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup, Sweep};
use hilo_detector::data::{LoadOptions, load_split, load_split_frame};
use hilo_sensor_models::SensorPose;

/// A radar point whose RCS encodes the sweep it came from.
fn rp(tag: f32) -> RadarPoint {
    RadarPoint { x: 10.0, y: 1.0, z: 0.0, rcs_dbsm: tag, v_r_mps: 1.0, v_r_comp_mps: 1.0, time_s: 0.0 }
}

fn frame(t_us: u64, radar_tag: f32) -> FrameData {
    let lidar = vec![LidarPoint { x: 5.0, y: 0.0, z: 0.0, intensity: 0.5, ring: 0, time_s: 0.0 }];
    let ann = Annotation {
        instance: 1,
        class: Class::Car,
        box3: Box3::new(Vec3::new(5.0, 0.0, 0.8), 4.6, 1.9, 1.6, 0.0),
        velocity_mps: Vec2::new(1.0, 0.0),
        attribute: "vehicle.moving".into(),
        num_lidar_pts: 1,
        num_radar_pts: 1,
        visibility: 4,
    };
    FrameData { timestamp_us: t_us, lidar: vec![lidar], radar: vec![vec![rp(radar_tag)]], annotations: vec![ann] }
}

/// A dataset writer for one LiDAR at 6 m and one radar at 5 m above the origin.
fn writer(dir: &std::path::Path) -> DatasetWriter {
    let sensors = vec![
        SensorSetup {
            channel: "LIDAR_0".into(),
            modality: SensorModality::Lidar,
            pose: SensorPose::new(Vec3::new(0.0, 0.0, 6.0), 0.0, 0.0, 0.0),
        },
        SensorSetup {
            channel: "RADAR_0".into(),
            modality: SensorModality::Radar,
            pose: SensorPose::new(Vec3::new(0.0, 0.0, 5.0), 0.0, 0.0, 0.0),
        },
    ];
    DatasetWriter::new(dir, "v1.0-trainval", "t", sensors).unwrap()
}

#[test]
fn radar_sweeps_stack_with_their_time_lags() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = writer(dir.path());
    let t0 = 1_000_000_000u64;
    // Key frames at 0 and 0.5 s; sweeps at 0.1 (empty), 0.2, 0.3 and 0.4 s; then a key frame at
    // 1.5 s after a one-second gap with no sweep.
    // The LiDAR scanned at 0.2 and 0.4 s too (its intensity tags the sweep), not at 0.1 and 0.3.
    let sweep = |dt: u64, pts: Vec<RadarPoint>| {
        let lidar = if dt.is_multiple_of(200_000) {
            vec![vec![LidarPoint { x: 5.0, y: 1.0, z: 0.0, intensity: dt as f32 * 1e-6, ring: 0, time_s: 0.0 }]]
        } else {
            Vec::new()
        };
        Sweep { timestamp_us: t0 + dt, lidar, radar: vec![pts] }
    };
    let scene = SceneData {
        name: "val-0000".into(),
        description: String::new(),
        frames: vec![frame(t0, 0.0), frame(t0 + 500_000, 5.0), frame(t0 + 1_500_000, 15.0)],
        sweeps: vec![
            sweep(100_000, vec![]),
            sweep(200_000, vec![rp(2.0), rp(2.0)]),
            sweep(300_000, vec![rp(3.0)]),
            sweep(400_000, vec![rp(4.0)]),
        ],
    };
    w.add_scene(&scene, "x").unwrap();
    w.write_splits(&std::collections::BTreeMap::from([("val".to_string(), vec!["val-0000".to_string()])])).unwrap();
    w.finish().unwrap();
    let ds = Dataset::open(dir.path(), "v1.0-trainval").unwrap();
    let load_with = |radar_sweeps: usize, lidar_sweeps: usize| {
        let opts = LoadOptions {
            background: None,
            radar_sweeps,
            lidar_sweeps,
            max_sweep_lag_s: 0.5,
            radar_clutter: None,
            radar_pairs: None,
            lidar_min_range_m: 0.0,
            radar_only_boxes: true,
            ..LoadOptions::default()
        };
        load_split(&ds, "val", &opts).unwrap()
    };
    let load = |k: usize| load_with(k, 1);
    // One sweep: the key frame's own, lag 0; key frames only, with their LiDAR.
    let (f1, s1) = load(1);
    assert_eq!(f1.len(), 3);
    assert!(f1.iter().all(|f| f.lidar.len() == 1 && f.radar.len() == 1 && f.radar[0][7] == 0.0));
    assert_eq!((s1.radar_points, s1.older_sweep_points), (3, 0));
    // Four sweeps at 0.5 s: its own (tag 5), then 0.4 s (4), 0.3 s (3), 0.2 s (2, two points).
    let (f4, s4) = load(4);
    let tags: Vec<(f32, f32)> = f4[1].radar.iter().map(|p| (p[3], (p[7] * 10.0).round() / 10.0)).collect();
    assert_eq!(tags, vec![(5.0, 0.0), (4.0, 0.1), (3.0, 0.2), (2.0, 0.3), (2.0, 0.3)]);
    // Six sweeps reach the empty one (0.1 s: no points) and the key frame at 0 s (lag 0.5 s).
    let (f6, _) = load(6);
    let tags: Vec<f32> = f6[1].radar.iter().map(|p| p[3]).collect();
    assert_eq!(tags, vec![5.0, 4.0, 3.0, 2.0, 2.0, 0.0]);
    assert!((f6[1].radar[5][7] - 0.5).abs() < 1e-6);
    // The first key frame has nothing before it; the last one's previous sweep is 1 s back,
    // beyond the lag limit, so it keeps its own sweep only.
    assert_eq!(f6[0].radar.len(), 1);
    assert_eq!(f6[2].radar.iter().map(|p| p[3]).collect::<Vec<_>>(), vec![15.0]);
    assert_eq!(s4.older_sweep_points, 4);
    // Every radar point knows its radar's position (what the Doppler step corrects the
    // elevation with), older sweeps' too.
    for f in f1.iter().chain(&f6) {
        assert_eq!(f.radar_origin, vec![[0.0, 0.0, 5.0]; f.radar.len()]);
    }
    // One frame alone is the split's frame at that index, sweeps and all; past the end, none.
    let opts = LoadOptions {
        background: None,
        radar_sweeps: 4,
        lidar_sweeps: 1,
        max_sweep_lag_s: 0.5,
        radar_clutter: None,
        radar_pairs: None,
        lidar_min_range_m: 0.0,
        radar_only_boxes: true,
        ..LoadOptions::default()
    };
    for (i, f) in f4.iter().enumerate() {
        let one = load_split_frame(&ds, "val", &opts, i).unwrap().unwrap();
        assert_eq!((&one.sample_token, &one.lidar, &one.radar), (&f.sample_token, &f.lidar, &f.radar));
    }
    assert!(load_split_frame(&ds, "val", &opts, 3).unwrap().is_none());
    // One radar: pairing its detections with another radar's (the fusion presets' input) pairs
    // none, and every frame is the one loaded without it.
    let paired = LoadOptions { radar_pairs: Some(hilo_fusion::config::RadarPairConfig::default()), ..opts };
    let (p4, ps) = load_split(&ds, "val", &paired).unwrap();
    assert_eq!(ps.radar_paired_points, 0);
    assert_eq!(
        p4.iter().map(|f| (&f.lidar, &f.radar)).collect::<Vec<_>>(),
        f4.iter().map(|f| (&f.lidar, &f.radar)).collect::<Vec<_>>()
    );
    // LiDAR sweeps the same way, each point with its sweep's lag; the sweeps without LiDAR are
    // not in its chain. At 0.5 s: its own, 0.4 s, 0.2 s, then the key frame at 0 s (lag 0.5).
    let lidar_tags = |f: &hilo_detector::data::Frame| -> Vec<(f32, f32)> {
        f.lidar.iter().map(|p| ((p[3] * 10.0).round() / 10.0, (p[4] * 10.0).round() / 10.0)).collect()
    };
    let (l1, _) = load_with(1, 1);
    assert!(l1.iter().all(|f| f.lidar.len() == 1 && f.lidar[0][4] == 0.0));
    let (l3, _) = load_with(1, 3);
    assert_eq!(lidar_tags(&l3[1]), vec![(0.5, 0.0), (0.4, 0.1), (0.2, 0.3)]);
    let (l9, _) = load_with(1, 9);
    assert_eq!(lidar_tags(&l9[1]), vec![(0.5, 0.0), (0.4, 0.1), (0.2, 0.3), (0.5, 0.5)]);
    assert_eq!(l9[0].lidar.len(), 1, "nothing before the first key frame");
    assert_eq!(l9[2].lidar.len(), 1, "the previous LiDAR sweep is 1 s back, beyond the limit");
    // The radar is read as before whatever the LiDAR stacks.
    assert_eq!(l9[1].radar, f1[1].radar);
}

/// A detector is trained on the boxes its own sensors hit: a box that only a radar detection
/// hit is kept for a detector that reads radar and left out for a LiDAR-only one; a box that
/// no sensor hit is left out for both, and a box a LiDAR point hit is kept for both.
#[test]
fn a_lidar_only_detector_is_not_given_boxes_only_the_radar_saw() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = writer(dir.path());
    let ann = |instance: u32, x: f32, lidar: u32, radar: u32| Annotation {
        instance,
        class: Class::Car,
        box3: Box3::new(Vec3::new(x, 0.0, 0.8), 4.6, 1.9, 1.6, 0.0),
        velocity_mps: Vec2::new(1.0, 0.0),
        attribute: "vehicle.moving".into(),
        num_lidar_pts: lidar,
        num_radar_pts: radar,
        visibility: 4,
    };
    let mut f = frame(1_000_000_000, 0.0);
    // Instance 1 (x = 5, a LiDAR point and a radar point) is `frame`'s own.
    f.annotations.push(ann(2, 20.0, 0, 3));
    f.annotations.push(ann(3, 30.0, 0, 0));
    f.annotations.push(ann(4, 40.0, 7, 0));
    let scene = SceneData { name: "val-0000".into(), description: String::new(), frames: vec![f], sweeps: vec![] };
    w.add_scene(&scene, "x").unwrap();
    w.write_splits(&std::collections::BTreeMap::from([("val".to_string(), vec!["val-0000".to_string()])])).unwrap();
    w.finish().unwrap();
    let ds = Dataset::open(dir.path(), "v1.0-trainval").unwrap();
    let input = hilo_fusion::config::InputConfig::default();
    let xs = |uses_radar: bool| {
        let (frames, stats) = load_split(&ds, "val", &LoadOptions::new(&input, None, uses_radar)).unwrap();
        let mut xs: Vec<f32> = frames[0].boxes.iter().map(|b| b.center[0]).collect();
        xs.sort_by(f32::total_cmp);
        (xs, stats)
    };
    let (fusion, stats) = xs(true);
    assert_eq!(fusion, vec![5.0, 20.0, 40.0], "fusion: LiDAR-hit and radar-only boxes");
    assert_eq!((stats.boxes, stats.radar_only_boxes), (3, 0));
    assert!(stats.notes(false, false).iter().all(|n| !n.contains("only a radar")));
    let (lidar_only, stats) = xs(false);
    assert_eq!(lidar_only, vec![5.0, 40.0], "LiDAR-only: the boxes a LiDAR point hit");
    assert_eq!((stats.boxes, stats.radar_only_boxes), (2, 1));
    let notes = stats.notes(false, false);
    assert!(notes.iter().any(|n| n.contains("boxes only a radar hit") && n.contains("1 of 3 (33.3%)")), "{notes:?}");
}
