//! Ground truth read from a nuScenes-layout dataset, as the devkit's `load_gt` builds it, and the
//! common ground truth that keeps boxes no sensor hit.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use glam::{Vec2, Vec3};
use hilo_core::{Box3, Class};
use hilo_dataset::{Annotation, Dataset, DatasetWriter, FrameData, SceneData, SensorModality, SensorSetup};
use hilo_eval::{DetectionConfig, EvalBox, evaluate_files};
use hilo_sensor_models::SensorPose;
use hilo_study::gt::{GtKind, SampleKey, ground_truth};

fn dataset(root: &std::path::Path, with_splits: bool) {
    let sensors = vec![SensorSetup {
        channel: "LIDAR_0".into(),
        modality: SensorModality::Lidar,
        pose: SensorPose::new(Vec3::new(0.0, 0.0, 7.0), 0.0, 0.0, 0.0),
    }];
    let mut w = DatasetWriter::new(root, "v1.0-trainval", "t", sensors).unwrap();
    for (k, name) in ["scene-a", "scene-b"].iter().enumerate() {
        let frames = (0..5)
            .map(|f| {
                let t = 0.05 * f as f32;
                let mut annotations = vec![Annotation {
                    instance: 1,
                    class: Class::Car,
                    box3: Box3::new(Vec3::new(10.0 + 8.0 * t, 2.0, 0.8), 4.6, 1.9, 1.6, 0.0),
                    velocity_mps: Vec2::new(8.0, 0.0),
                    attribute: "vehicle.moving".into(),
                    num_lidar_pts: 30,
                    num_radar_pts: 2,
                    visibility: 4,
                }];
                if f == 2 {
                    // Seen in one frame only: no velocity can be estimated.
                    annotations.push(Annotation {
                        instance: 9,
                        class: Class::Pedestrian,
                        box3: Box3::new(Vec3::new(-4.0, 6.0, 0.875), 0.6, 0.6, 1.75, 0.0),
                        velocity_mps: Vec2::ZERO,
                        attribute: String::new(),
                        num_lidar_pts: 4,
                        num_radar_pts: 0,
                        visibility: 3,
                    });
                }
                FrameData {
                    timestamp_us: 1_000_000 * (k as u64 + 1) * 100 + 50_000 * f,
                    lidar: vec![vec![]],
                    radar: vec![],
                    annotations,
                }
            })
            .collect();
        w.add_scene(
            &SceneData { name: (*name).into(), description: String::new(), frames, sweeps: Vec::new() },
            "test",
        )
        .unwrap();
    }
    if with_splits {
        w.write_splits(
            &[("train".to_owned(), vec!["scene-a".to_owned()]), ("val".to_owned(), vec!["scene-b".to_owned()])]
                .into_iter()
                .collect(),
        )
        .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn ground_truth_of_a_split_with_devkit_velocities() {
    let d = tempfile::tempdir().unwrap();
    dataset(d.path(), true);
    let ds = Dataset::open(d.path(), "v1.0-trainval").unwrap();
    let (gt, keys) = ground_truth(&ds, "val", GtKind::VisibleOnly, SampleKey::Token).unwrap();
    assert!(keys.iter().all(|(t, k)| t == k));
    assert_eq!(gt.samples.len(), 5, "only scene-b's frames");
    assert!(gt.samples.values().all(|s| s.scene == "scene-b"));
    let boxes: Vec<&EvalBox> = gt.boxes.values().flatten().collect();
    assert_eq!(boxes.len(), 6);
    for b in &boxes {
        match b.detection_name.as_str() {
            "car" => {
                assert!((b.velocity[0] - 8.0).abs() < 1e-4 && b.velocity[1].abs() < 1e-6, "{:?}", b.velocity);
                assert_eq!(b.num_pts, 32);
                assert_eq!(b.attribute_name, "vehicle.moving");
                assert_eq!(b.size, [1.9f32 as f64, 4.6f32 as f64, 1.6f32 as f64]);
            }
            "pedestrian" => assert!(b.velocity[0].is_nan() && b.velocity[1].is_nan()),
            other => panic!("{other}"),
        }
    }
    // Evaluating the ground truth against itself: AP 1 for both classes, AVE ignores the NaN.
    let pred: Vec<(String, Vec<EvalBox>)> = gt
        .boxes
        .iter()
        .map(|(k, v)| {
            (k.clone(), v.iter().map(|b| EvalBox { detection_score: 0.9, velocity: [8.0, 0.0], ..b.clone() }).collect())
        })
        .collect();
    let m = evaluate_files(&gt, &pred, &DetectionConfig::default());
    assert!((m.mean_dist_aps["car"] - 1.0).abs() < 1e-12 && (m.mean_dist_aps["pedestrian"] - 1.0).abs() < 1e-12);
    assert!(m.label_tp_errors["car"]["vel_err"].abs() < 1e-4);
    assert_eq!(m.label_tp_errors["pedestrian"]["vel_err"], 1.0, "all-NaN errors count as 1, as in the devkit");
}

#[test]
fn a_dataset_without_the_split_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    dataset(d.path(), false);
    let ds = Dataset::open(d.path(), "v1.0-trainval").unwrap();
    let e = ground_truth(&ds, "val", GtKind::VisibleOnly, SampleKey::Token).unwrap_err().to_string();
    assert!(e.contains("splits.json"), "{e}");
    dataset(d.path(), true);
    let ds = Dataset::open(d.path(), "v1.0-trainval").unwrap();
    let e = ground_truth(&ds, "test", GtKind::VisibleOnly, SampleKey::Token).unwrap_err().to_string();
    assert!(e.contains("no split \"test\"") && e.contains("train") && e.contains("val"), "{e}");
}
