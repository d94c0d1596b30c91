//! Writing, reading back, and refusing broken datasets.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class, LidarPoint, RadarPoint};
use hilo_dataset::tables::TABLE_NAMES;
use hilo_dataset::{
    Annotation, Dataset, DatasetError, DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup,
};
use hilo_sensor_models::SensorPose;
use std::path::Path;

fn sensors() -> Vec<SensorSetup> {
    vec![
        SensorSetup {
            channel: "LIDAR_0".into(),
            modality: SensorModality::Lidar,
            pose: SensorPose::new(Vec3::new(13.0, 16.6, 7.8), -2.2, 0.17, 0.0),
        },
        SensorSetup {
            channel: "LIDAR_1".into(),
            modality: SensorModality::Lidar,
            pose: SensorPose::new(Vec3::new(-13.0, -16.6, 7.8), 0.9, 0.17, 0.0),
        },
        SensorSetup {
            channel: "RADAR_0".into(),
            modality: SensorModality::Radar,
            pose: SensorPose::new(Vec3::new(16.6, -7.0, 6.4), 2.9, 0.14, 0.0),
        },
    ]
}

fn scene(name: &str, frames: usize) -> SceneData {
    let base: u64 = if name.ends_with('2') { 1_700_000_100_000_000 } else { 1_700_000_000_000_000 };
    let frames = (0..frames)
        .map(|f| {
            let t = f as f32 * 0.05;
            let lidar = (0..2)
                .map(|s| {
                    (0..50 + 7 * f)
                        .map(|i| LidarPoint {
                            x: i as f32 * 0.31 + s as f32,
                            y: -(i as f32) * 0.07,
                            z: 0.1 * (i % 5) as f32,
                            intensity: (i % 11) as f32 / 11.0,
                            ring: (i % 16) as u16,
                            time_s: 0.0,
                        })
                        .collect()
                })
                .collect();
            let radar = vec![
                (0..9)
                    .map(|i| RadarPoint {
                        x: 20.0 + i as f32,
                        y: 1.0,
                        z: 0.5,
                        rcs_dbsm: 10.0 - i as f32,
                        v_r_mps: -8.0 + i as f32,
                        v_r_comp_mps: -8.0 + i as f32,
                        time_s: 0.0,
                    })
                    .collect(),
            ];
            // Instance 1 in every frame, instance 2 from frame 1 on.
            let mut annotations = vec![Annotation {
                instance: 1,
                class: Class::Car,
                box3: Box3::new(Vec3::new(10.0 + 8.0 * t, 2.0, 0.8), 4.6, 1.9, 1.6, 0.0),
                velocity_mps: Vec2::new(8.0, 0.0),
                attribute: "vehicle.moving".into(),
                num_lidar_pts: 40,
                num_radar_pts: 3,
                visibility: 4,
            }];
            if f >= 1 {
                annotations.push(Annotation {
                    instance: 2,
                    class: Class::Pedestrian,
                    box3: Box3::new(Vec3::new(-5.0, 18.0 + 1.3 * t, 0.875), 0.6, 0.6, 1.75, 1.57),
                    velocity_mps: Vec2::new(0.0, 1.3),
                    attribute: String::new(),
                    num_lidar_pts: 7,
                    num_radar_pts: 0,
                    visibility: 2,
                });
            }
            FrameData { timestamp_us: base + 50_000 * f as u64, lidar, radar, annotations }
        })
        .collect();
    SceneData { name: name.into(), description: "test".into(), frames, sweeps: Vec::new() }
}

fn write(root: &Path) -> hilo_dataset::tables::Tables {
    let mut w = DatasetWriter::new(root, "v1.0-trainval", "test", sensors()).unwrap();
    w.add_scene(&scene("scene-0001", 4), "default").unwrap();
    w.add_scene(&scene("scene-0002", 3), "default").unwrap();
    w.finish().unwrap()
}

#[test]
fn written_datasets_read_back_exactly_and_the_same_input_gives_the_same_bytes() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let written = write(a.path());
    write(b.path());
    let ds = Dataset::open(a.path(), "v1.0-trainval").unwrap();
    assert_eq!(ds.tables, written);
    assert_eq!(ds.tables.scene.len(), 2);
    assert_eq!(ds.tables.sample.len(), 7);
    assert_eq!(ds.tables.sample_data.len(), 21);
    assert_eq!(ds.tables.instance.len(), 4);
    assert_eq!(ds.tables.sample_annotation.len(), 4 + 3 + 3 + 2);
    // Point files round trip (LiDAR keeps x y z intensity ring).
    let src = scene("scene-0001", 4);
    let sd =
        ds.tables.sample_data.iter().find(|s| s.filename.contains("scene-0001__LIDAR_1__1700000000050000")).unwrap();
    assert_eq!(ds.lidar_points(sd).unwrap(), src.frames[1].lidar[1]);
    let sd =
        ds.tables.sample_data.iter().find(|s| s.filename.contains("scene-0001__RADAR_0__1700000000100000")).unwrap();
    // Radar keeps position and RCS exactly; the radial velocity comes back from nuScenes' vx, vy.
    let read = ds.radar_points(sd).unwrap();
    assert_eq!(read.len(), src.frames[2].radar[0].len());
    for (r, w) in read.iter().zip(&src.frames[2].radar[0]) {
        assert_eq!([r.x, r.y, r.z, r.rcs_dbsm], [w.x, w.y, w.z, w.rcs_dbsm]);
        assert!((r.v_r_mps - w.v_r_mps).abs() < 1e-5 && (r.v_r_comp_mps - w.v_r_comp_mps).abs() < 1e-5, "{r:?} {w:?}");
    }
    // Byte-identical datasets from the same input.
    for name in TABLE_NAMES {
        let f = format!("v1.0-trainval/{name}.json");
        assert_eq!(std::fs::read(a.path().join(&f)).unwrap(), std::fs::read(b.path().join(&f)).unwrap(), "{f}");
    }
    common::devkit_check(a.path());
}

#[test]
fn broken_datasets_name_the_file_or_token() {
    let d = tempfile::tempdir().unwrap();
    let written = write(d.path());
    // A dangling token.
    let p = d.path().join("v1.0-trainval/sample_annotation.json");
    let text = std::fs::read_to_string(&p).unwrap();
    let bad_instance = &written.sample_annotation[0].instance_token;
    std::fs::write(&p, text.replacen(bad_instance.as_str(), "deadbeef", 1)).unwrap();
    let e = Dataset::open(d.path(), "v1.0-trainval").unwrap_err();
    assert!(matches!(e, DatasetError::Dangling { .. }) && e.to_string().contains("deadbeef"), "{e}");
    std::fs::write(&p, text).unwrap();
    // A missing table.
    std::fs::remove_file(d.path().join("v1.0-trainval/visibility.json")).unwrap();
    let e = Dataset::open(d.path(), "v1.0-trainval").unwrap_err().to_string();
    assert!(e.contains("visibility.json"), "{e}");
    write(d.path());
    // A truncated point file.
    let ds = Dataset::open(d.path(), "v1.0-trainval").unwrap();
    let sd = ds.tables.sample_data.iter().find(|s| s.filename.ends_with(".pcd.bin")).unwrap();
    let f = d.path().join(&sd.filename);
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() - 3]).unwrap();
    let e = ds.lidar_points(sd).unwrap_err().to_string();
    assert!(e.contains(&sd.filename) && e.contains("truncated"), "{e}");
    // Bad writer input: equal scene start times, duplicate channels.
    let mut w = DatasetWriter::new(d.path(), "v2", "t", sensors()).unwrap();
    w.add_scene(&scene("a-1", 2), "x").unwrap();
    assert!(w.add_scene(&scene("b-1", 2), "x").unwrap_err().to_string().contains("start"));
    let mut dup = sensors();
    dup[1].channel = "LIDAR_0".into();
    assert!(DatasetWriter::new(d.path(), "v", "t", dup).unwrap_err().to_string().contains("LIDAR_0"));
}

/// Rewrites one table through a JSON edit, then expects `Dataset::open` to refuse it naming
/// `want` (table, field, token or value), and restores the table.
fn refused(root: &Path, table: &str, edit: impl Fn(&mut serde_json::Value), want: &[&str]) {
    let p = root.join(format!("v1.0-trainval/{table}.json"));
    let text = std::fs::read_to_string(&p).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    edit(&mut v);
    std::fs::write(&p, serde_json::to_vec(&v).unwrap()).unwrap();
    let e = Dataset::open(root, "v1.0-trainval").unwrap_err().to_string();
    for w in want {
        assert!(e.contains(w), "{table}: {e:?} lacks {w:?}");
    }
    std::fs::write(&p, text).unwrap();
}

#[test]
fn ground_truth_with_unknown_categories_bad_boxes_duplicate_tokens_or_broken_chains_is_refused() {
    let d = tempfile::tempdir().unwrap();
    write(d.path());
    let root = d.path();
    refused(root, "category", |v| v[0]["name"] = "vehicle.carx".into(), &["category", "name", "vehicle.carx"]);
    for (field, value) in [
        ("size", serde_json::json!([0.0, 4.5, 1.6])),
        ("size", serde_json::json!([-1.9, 4.5, 1.6])),
        ("rotation", serde_json::json!([0.0, 0.0, 0.0, 0.0])),
    ] {
        refused(root, "sample_annotation", |v| v[3][field] = value.clone(), &["sample_annotation", field]);
    }
    refused(
        root,
        "sample_annotation",
        |v| {
            let a = v.as_array_mut().unwrap();
            let dup = a[0].clone();
            a.push(dup);
        },
        &["sample_annotation", "appears twice"],
    );
    refused(
        root,
        "sample",
        |v| {
            let a = v.as_array_mut().unwrap();
            let dup = a[1].clone();
            a.push(dup);
        },
        &["table sample:", "appears twice"],
    );
    // A `next` whose record points back elsewhere: both tokens exist, so only the chain check sees it.
    refused(
        root,
        "sample",
        |v| {
            let third = v[2]["token"].clone();
            v[0]["next"] = third;
        },
        &["table sample:", "`next`"],
    );
    refused(
        root,
        "sample_data",
        |v| v[0]["filename"] = "../../OUTSIDE.pcd.bin".into(),
        &["sample_data", "filename", "OUTSIDE"],
    );
    // A table folder outside the dataroot.
    let e = Dataset::open(root, "../v1.0-trainval").unwrap_err().to_string();
    assert!(e.contains("version") && e.contains("../v1.0-trainval"), "{e}");
    // A point file of NaN: refused, not drawn and counted.
    let ds = Dataset::open(root, "v1.0-trainval").unwrap();
    let sd = ds.tables.sample_data.iter().find(|s| s.filename.ends_with(".pcd.bin")).unwrap();
    std::fs::write(root.join(&sd.filename), f32::NAN.to_le_bytes().repeat(5)).unwrap();
    let e = ds.lidar_points(sd).unwrap_err().to_string();
    assert!(e.contains(&sd.filename) && e.contains("not a finite number"), "{e}");
}

/// Tokens and name hashes are fixed numbers: a dataset written by another build resumes and
/// keeps its tokens, and a sensor keeps its calibration draw. The values are those of the
/// first implementation.
#[test]
fn tokens_and_name_hashes_do_not_change_between_builds() {
    use hilo_dataset::writer::{name_hash, token};
    assert_eq!(token(&["ns", "calibrated_sensor", "LIDAR_0"]), "160f3bbd0903bb7a3e41609997fb7c25");
    assert_eq!(token(&[]), "cbf29ce48422232584222325cbf29ce4");
    assert_eq!(token(&[""]), "af63d24c8601db8e4f5a1cc6a05f40bc");
    assert_eq!(token(&["scene-0001"]), "fb876f8cb40bb3d609f6728c42ce271f");
    assert_eq!(name_hash("LIDAR_0"), 0xafac_7ef5_3771_2fca);
}
