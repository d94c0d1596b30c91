//! No panic on any input: every reader of a user's file (study, scene and catalog TOML,
//! placement, results and ground-truth JSON, point files, OBJ and glTF meshes, a validation's
//! `validation.json`, a calibration file) gets 10,000 mutations of a valid
//! document (characters replaced, inserted and deleted, among them quotes, brackets, a byte-order
//! mark, typographic quotes and multi-byte letters) and must return a value or an error.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use proptest::prelude::*;
use std::path::Path;

const CASES: u32 = 10_000;

const TRICKY: [char; 20] = [
    '"',
    '\'',
    '{',
    '}',
    '[',
    ']',
    ',',
    ':',
    '=',
    '\n',
    '\\',
    '0',
    '-',
    'e',
    'N',
    '.',
    '\u{feff}',
    '\u{201c}',
    '\u{e9}',
    '\u{1f600}',
];

/// Up to 8 edits: (position, character, 0 replace / 1 insert / 2 delete).
fn edits() -> impl Strategy<Value = Vec<(usize, usize, u8)>> {
    prop::collection::vec((any::<usize>(), 0..TRICKY.len(), 0..3u8), 1..8)
}

fn mutate(doc: &str, edits: &[(usize, usize, u8)]) -> String {
    let mut chars: Vec<char> = doc.chars().collect();
    for &(pos, c, op) in edits {
        let at = if chars.is_empty() { 0 } else { pos % chars.len() };
        match op {
            0 if !chars.is_empty() => chars[at] = TRICKY[c],
            1 => chars.insert(at, TRICKY[c]),
            _ if !chars.is_empty() => {
                chars.remove(at);
            }
            _ => {}
        }
    }
    chars.into_iter().collect()
}

fn fixture(name: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)).unwrap()
}

const GT: &str = r#"{"samples": {"a": {"scene": "s0", "ego_translation": [0, 0, 0]}},
  "boxes": {"a": [{"sample_token": "a", "translation": [5, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "num_pts": 20}]}}"#;

const RESULTS: &str = r#"{"meta": {"use_lidar": true}, "results": {
  "a": [{"sample_token": "a", "translation": [5.2, 0, 0.8], "size": [1.9, 4.6, 1.6], "rotation": [1, 0, 0, 0], "velocity": [1, 0], "detection_name": "car", "detection_score": 0.9, "attribute_name": "vehicle.moving"}]}}"#;

fn placement() -> String {
    use hilo::placement::{Modality, PlacedSensor, Placement};
    use hilo::sensors::SensorPose;
    let pose = SensorPose::new(glam::Vec3::new(13.0, 16.5, 7.8), -2.2, 0.17, 0.0);
    Placement {
        name: "2x lidar-16 + radar".into(),
        sensors: vec![PlacedSensor::new("lidar-16", Modality::Lidar, 7, "NE pole", pose)],
        objective: 12107.3,
        bound: f64::INFINITY,
        gap: f64::INFINITY,
        proven_optimal: false,
        solve_seconds: 0.1,
        method: "exact".into(),
        solved: true,
        greedy_objective: 12081.8,
        central_coverage: 0.545,
        lidar_radar_overlap: 0.3,
        cost_usd: 10000.0,
        targets: 4846,
        candidates: 616,
        scene_hash: "s".into(),
        catalog_hash: "c".into(),
        prediction: None,
    }
    .to_json()
    .unwrap()
}

const CUBE_OBJ: &str = "o cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nmtllib cube.mtl\nusemtl a\n";

/// One triangle, (0,0,0), (1,0,0), (0,1,0), indexed, its buffer embedded as base64.
const TRIANGLE_GLTF: &str = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
"nodes":[{"mesh":0,"translation":[10.0,0.0,0.0]}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
"buffers":[{"byteLength":42,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIA"}],
"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0.0,0.0,0.0],"max":[1.0,1.0,0.0]},
{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}]}"#;

/// A finished validation's record of three placements, as `hilo validate` writes it.
fn validation_json() -> String {
    use hilo::study::validation::{Trained, ValidationReport, ValidationSettings, set::Member};
    let placement: hilo::placement::Placement = serde_json::from_str(&placement()).unwrap();
    let agreement = hilo::study::validation::rank::Agreement { value: 0.5, lo: 0.1, hi: 0.9, n: 3 };
    let members = (0..3)
        .map(|i| {
            let map = 0.2 + 0.1 * i as f64;
            let m = Member {
                slug: format!("m{i}-random-a"),
                kind: "random".into(),
                configuration: "a".into(),
                placement: placement.clone(),
                predictors: [("LiDAR coverage (saturated)".to_owned(), Some(map))].into(),
            };
            let t = Trained {
                preset: "centerpoint".into(),
                map: vec![map],
                draw: Vec::new(),
                map_mean: map,
                map_at_b: vec![map],
                map_at_b_mean: map,
                pedestrian_ap_mean: map,
                pedestrian_ap: vec![map],
                class_ap: [("car".to_owned(), map)].into(),
                map_replicates: vec![map; 4],
                pedestrian_replicates: vec![map; 4],
                train_s: 1.0,
            };
            (m, t)
        })
        .collect();
    serde_json::to_string(&ValidationReport {
        study: "s.toml".into(),
        profile: "tiny".into(),
        settings: ValidationSettings::default(),
        provenance: hilo::study::plan::Provenance::here(1),
        validation_scenes: 2,
        resamples: 4,
        members,
        predictors: Vec::new(),
        budget_spearman: agreement,
        budget_kendall: agreement,
        seed_spearman: None,
        draw_spearman: None,
        calibrated: None,
        recommendation: None,
        frozen: Vec::new(),
        transfer: None,
        seconds: 1.0,
    })
    .unwrap()
}

fn config() -> ProptestConfig {
    ProptestConfig { cases: CASES, failure_persistence: None, ..ProptestConfig::default() }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn results_and_ground_truth_json_never_panic(e in edits()) {
        let p = Path::new("fuzz.json");
        let _ = hilo::eval::parse_submission(&mutate(RESULTS, &e), p, 500);
        let _ = hilo::eval::parse_ground_truth(&mutate(GT, &e), p);
    }

    #[test]
    fn placement_json_never_panics(e in edits()) {
        thread_local!(static DOC: String = placement());
        let text = DOC.with(|d| mutate(d, &e));
        let _ = hilo::placement::Placement::from_json(&text, Path::new("fuzz.json"));
    }

    #[test]
    fn catalog_and_study_toml_never_panic(e in edits()) {
        thread_local!(static DOCS: (String, String) = (fixture("sensors.toml"), fixture("study.toml")));
        let (catalog, study) = DOCS.with(|d| (mutate(&d.0, &e), mutate(&d.1, &e)));
        let _ = hilo::sensors::Catalog::from_toml_str(&catalog, Path::new("fuzz.toml"));
        if let Ok(file) = toml::from_str::<hilo::study::study::StudyFile>(&study) {
            let _ = file.dataset.validate();
        }
    }

    #[test]
    fn calibration_toml_never_panics(e in edits()) {
        thread_local!(static DOC: String = fixture("calibration-sites.toml"));
        let text = DOC.with(|d| mutate(d, &e));
        // A file that still parses has passed its checks.
        if let Ok(f) = hilo::placement::calibrated::file::CalibrationFile::from_toml(&text) {
            prop_assert!(f.check().is_ok());
        }
    }

    #[test]
    fn scene_toml_never_panics(e in edits()) {
        thread_local!(static DOC: String = fixture("intersection.toml"));
        let text = DOC.with(|d| mutate(d, &e));
        let _ = hilo::raycast::scene::config::SceneConfig::from_toml_str(&text, Path::new("fuzz.toml"));
    }

    #[test]
    fn obj_and_gltf_meshes_never_panic(e in edits()) {
        let p = Path::new("fuzz-mesh");
        let _ = hilo::raycast::scene::import::parse_obj(mutate(CUBE_OBJ, &e).as_bytes(), p);
        let _ = hilo::raycast::scene::import::parse_gltf(mutate(TRIANGLE_GLTF, &e).as_bytes(), p);
    }

    #[test]
    fn validation_json_never_panics(e in edits()) {
        thread_local!(static DOC: String = validation_json());
        let text = DOC.with(|d| mutate(d, &e));
        let _ = hilo::study::validation::parse_report(&text, Path::new("validation.json"));
    }

    #[test]
    fn point_files_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..64), at in any::<usize>(), cut in any::<bool>()) {
        use hilo::core::RadarPoint;
        use hilo::sensors::export::{from_nuscenes_radar_pcd, from_pcd, to_nuscenes_radar_pcd, to_pcd};
        let pts = vec![RadarPoint { x: 10.0, y: 1.0, z: -5.0, rcs_dbsm: 3.0, v_r_mps: -2.0, v_r_comp_mps: -2.0, time_s: 0.0 }; 3];
        for mut doc in [to_nuscenes_radar_pcd(&pts), to_pcd(&pts)] {
            // Splice random bytes in (header or body), or cut the file short there.
            let at = at % doc.len();
            if cut { doc.truncate(at) } else { doc.splice(at..at, bytes.iter().copied()); }
            let _ = from_nuscenes_radar_pcd(&doc, Path::new("fuzz.pcd"));
            let _ = from_pcd::<RadarPoint>(&doc, Path::new("fuzz.pcd"));
        }
    }
}

/// The documents the fuzzing starts from are valid: the mutations explore near real input.
#[test]
fn the_fuzzed_documents_parse_unmutated() {
    let p = Path::new("seed");
    assert_eq!(hilo::raycast::scene::import::parse_obj(CUBE_OBJ.as_bytes(), p).unwrap().triangles.len(), 12);
    assert_eq!(hilo::raycast::scene::import::parse_gltf(TRIANGLE_GLTF.as_bytes(), p).unwrap().triangles.len(), 1);
    assert_eq!(hilo::study::validation::parse_report(&validation_json(), p).unwrap().members.len(), 3);
    assert!(hilo::placement::calibrated::file::CalibrationFile::from_toml(&fixture("calibration-sites.toml")).is_ok());
}
