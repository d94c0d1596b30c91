//! Hand-computed cases and properties of the nuScenes metric.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_eval::nuscenes::{accumulate, angle_diff, calc_ap, calc_tp, evaluate};
use hilo_eval::{DetectionConfig, EvalBox, read_submission};
use proptest::prelude::*;
use std::collections::BTreeMap;

fn b(sample: &str, class: &str, x: f64, y: f64, yaw: f64, score: f64) -> EvalBox {
    let mut e = EvalBox::from_yaw(sample, class, [x, y, 0.8], [1.9, 4.6, 1.6], yaw, [3.0, 0.0], score);
    e.attribute_name = "vehicle.moving".into();
    e
}

fn gt_map(boxes: Vec<EvalBox>) -> BTreeMap<String, Vec<EvalBox>> {
    let mut m: BTreeMap<String, Vec<EvalBox>> = BTreeMap::new();
    for x in boxes {
        m.entry(x.sample_token.clone()).or_default().push(x);
    }
    m
}

fn pred_list(boxes: Vec<EvalBox>) -> Vec<(String, Vec<EvalBox>)> {
    let mut out: Vec<(String, Vec<EvalBox>)> = Vec::new();
    for x in boxes {
        match out.iter_mut().find(|(s, _)| *s == x.sample_token) {
            Some((_, v)) => v.push(x),
            None => out.push((x.sample_token.clone(), vec![x])),
        }
    }
    out
}

#[test]
fn hand_computed_ap_with_one_false_positive_above_the_true_one() {
    // One car; a confident prediction 3 m off (false positive at 2 m), a weaker one on it.
    let gt = gt_map(vec![b("s", "car", 10.0, 0.0, 0.0, 1.0)]);
    let pred = pred_list(vec![b("s", "car", 13.0, 0.0, 0.0, 0.9), b("s", "car", 10.0, 0.0, 0.0, 0.5)]);
    let md = accumulate(&gt, &pred, "car", 2.0);
    // precision(recall) = recall / 2 on (0, 1]; AP = mean over r > 0.1 of max(r/2 − 0.1, 0) / 0.9.
    let expected: f64 = (11..=100).map(|i| (0.005 * i as f64 - 0.1f64).max(0.0)).sum::<f64>() / 90.0 / 0.9;
    assert!((calc_ap(&md, 0.1, 0.1) - expected).abs() < 1e-12);
    assert!((expected - 0.2).abs() < 1e-12);
    // At 4 m the confident one takes the car (3 m off) and the other is a false positive at the
    // same recall 1: precision 1 for recall < 1, and at recall 1 numpy's interp takes the last
    // value recorded there, ½. So AP = (89 · 0.9 + 0.4) / 90 / 0.9, not 1.
    let md4 = accumulate(&gt, &pred, "car", 4.0);
    assert!((calc_ap(&md4, 0.1, 0.1) - (89.0 * 0.9 + 0.4) / 90.0 / 0.9).abs() < 1e-12);
    assert!((calc_tp(&md4, 0.1, "trans_err") - 3.0).abs() < 1e-12);
}

#[test]
fn each_tp_error_by_hand() {
    let gt = gt_map(vec![b("s", "car", 0.0, 0.0, 3.0, 1.0)]);
    let mut p = b("s", "car", 0.6, 0.8, -3.0, 0.7); // 1 m off; yaw differs by 2π − 6 across ±π
    p.size = [1.9, 4.6, 0.8]; // half the height: scale IoU ½
    p.velocity = [0.0, 4.0]; // |(−3, 4)| = 5
    p.attribute_name = "vehicle.parked".into();
    let md = accumulate(&gt, &pred_list(vec![p]), "car", 2.0);
    assert!((calc_tp(&md, 0.1, "trans_err") - 1.0).abs() < 1e-12);
    assert!((calc_tp(&md, 0.1, "scale_err") - 0.5).abs() < 1e-12);
    assert!((calc_tp(&md, 0.1, "orient_err") - (2.0 * std::f64::consts::PI - 6.0)).abs() < 1e-9);
    assert!((calc_tp(&md, 0.1, "vel_err") - 5.0).abs() < 1e-12);
    assert!((calc_tp(&md, 0.1, "attr_err") - 1.0).abs() < 1e-12);
    // Yaw wrap-around: π − ε against −π + ε is 2ε apart.
    assert!(
        (angle_diff(std::f64::consts::PI - 1e-6, -std::f64::consts::PI + 1e-6, 2.0 * std::f64::consts::PI).abs()
            - 2e-6)
            .abs()
            < 1e-12
    );
}

#[test]
fn perfect_predictions_score_one_and_a_class_without_gt_scores_as_the_devkit_does() {
    let mut gts = Vec::new();
    for s in 0..20 {
        for k in 0..5 {
            gts.push(b(
                &format!("s{s}"),
                if k % 2 == 0 { "car" } else { "bus" },
                10.0 * k as f64 - 20.0,
                s as f64,
                0.1 * k as f64,
                1.0,
            ));
        }
    }
    let preds: Vec<EvalBox> =
        gts.iter().enumerate().map(|(i, x)| EvalBox { detection_score: 0.5 + 0.001 * i as f64, ..x.clone() }).collect();
    let m = evaluate(&gt_map(gts), &pred_list(preds), &DetectionConfig::default());
    for c in ["car", "bus"] {
        assert!((m.mean_dist_aps[c] - 1.0).abs() < 1e-12, "{c}");
        for (k, e) in &m.label_tp_errors[c] {
            assert!(e.abs() < 1e-12, "{c} {k} {e}");
        }
    }
    // No truck ground truth: AP 0 and errors 1, as nuscenes-devkit's "no predictions".
    assert_eq!(m.mean_dist_aps["truck"], 0.0);
    assert!(m.label_tp_errors["truck"].values().all(|e| *e == 1.0));
}

#[test]
fn equal_scores_are_taken_in_the_devkits_order() {
    // Two equal-score predictions compete for one car: the devkit takes the later one first.
    let gt = gt_map(vec![b("s", "car", 0.0, 0.0, 0.0, 1.0)]);
    let near = b("s", "car", 0.1, 0.0, 0.0, 0.5);
    let far = b("s", "car", 1.5, 0.0, 0.0, 0.5);
    let md = accumulate(&gt, &pred_list(vec![near.clone(), far.clone()]), "car", 2.0);
    assert!((calc_tp(&md, 0.1, "trans_err") - 1.5).abs() < 1e-12, "the later box (far) matched");
    let md = accumulate(&gt, &pred_list(vec![far, near]), "car", 2.0);
    assert!((calc_tp(&md, 0.1, "trans_err") - 0.1).abs() < 1e-12);
}

fn scene(seed: u64) -> (BTreeMap<String, Vec<EvalBox>>, Vec<EvalBox>) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut gts = Vec::new();
    let mut preds = Vec::new();
    for s in 0..6 {
        for _ in 0..rng.random_range(1..6) {
            let (x, y) = (rng.random_range(-30.0..30.0), rng.random_range(-30.0..30.0));
            let class = ["car", "pedestrian"][rng.random_range(0..2)];
            gts.push(b(&format!("s{s}"), class, x, y, 0.0, 1.0));
            if rng.random_bool(0.8) {
                preds.push(b(
                    &format!("s{s}"),
                    class,
                    x + rng.random_range(-2.0..2.0),
                    y + rng.random_range(-2.0..2.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(0.0..1.0),
                ));
            }
        }
    }
    (gt_map(gts), preds)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn permuting_predictions_with_distinct_scores_changes_nothing(seed in 0u64..1000, perm_seed in 0u64..1000) {
        use rand::seq::SliceRandom;
        use rand::SeedableRng;
        let (gt, preds) = scene(seed);
        let cfg = DetectionConfig::default();
        let a = evaluate(&gt, &pred_list(preds.clone()), &cfg);
        let mut shuffled = preds;
        shuffled.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(perm_seed));
        let b2 = evaluate(&gt, &pred_list(shuffled), &cfg);
        prop_assert_eq!(a.label_aps, b2.label_aps);
        prop_assert!((a.nd_score - b2.nd_score).abs() < 1e-12);
    }

    #[test]
    fn a_lowest_score_false_positive_never_raises_ap(seed in 0u64..1000, x in -30.0f64..30.0) {
        let (gt, preds) = scene(seed);
        let cfg = DetectionConfig::default();
        let before = evaluate(&gt, &pred_list(preds.clone()), &cfg);
        let mut more = preds;
        more.push(b("s0", "car", x, 80.0 + x, 0.0, 0.0)); // far from every box, score 0
        let after = evaluate(&gt, &pred_list(more), &cfg);
        for (c, aps) in &before.label_aps {
            for (t, ap) in aps {
                prop_assert!(after.label_aps[c][t] <= ap + 1e-12, "{} {}: {} > {}", c, t, after.label_aps[c][t], ap);
            }
        }
    }
}

#[test]
fn bad_results_files_name_the_sample_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("results.json");
    let boxj = |extra: &str| {
        format!(
            r#"{{"sample_token": "abc", "translation": [1, 2, 0], "size": [1, 1, 1], "rotation": [1, 0, 0, 0], "velocity": [0, 0], "detection_name": "car", "detection_score": 0.5, "attribute_name": ""{extra}}}"#
        )
    };
    std::fs::write(&p, format!(r#"{{"meta": {{}}, "results": {{"abc": [{}]}}}}"#, boxj("").replace("0.5", "NaN")))
        .unwrap();
    let e = read_submission(&p, 500).unwrap_err().to_string();
    assert!(e.contains("abc") && e.contains("NaN"), "{e}");
    std::fs::write(&p, r#"{"meta": {}, "results": {"xyz": [{"sample_token": "xyz", "translation": [1, 2, 0]}]}}"#)
        .unwrap();
    let e = read_submission(&p, 500).unwrap_err().to_string();
    assert!(e.contains("xyz") && e.contains("size"), "{e}");
    std::fs::write(
        &p,
        format!(r#"{{"meta": {{}}, "results": {{"abc": [{}]}}}}"#, boxj("").replace("[1, 1, 1]", "[0, 1, 1]")),
    )
    .unwrap();
    let e = read_submission(&p, 500).unwrap_err().to_string();
    assert!(e.contains("abc") && e.contains("size"), "{e}");
    std::fs::write(&p, format!(r#"{{"meta": {{}}, "results": {{"abc": [{}, {}]}}}}"#, boxj(""), boxj(""))).unwrap();
    assert!(read_submission(&p, 1).unwrap_err().to_string().contains("limit"));
    // A class the metric does not evaluate is refused, naming the box, not silently dropped.
    for name in ["tram", "vehicle.car", "Car"] {
        std::fs::write(
            &p,
            format!(
                r#"{{"meta": {{}}, "results": {{"abc": [{}, {}]}}}}"#,
                boxj(""),
                boxj("").replace("\"car\"", &format!("{name:?}"))
            ),
        )
        .unwrap();
        let e = read_submission(&p, 500).unwrap_err().to_string();
        assert!(e.contains("abc") && e.contains("detection_name") && e.contains(name) && e.contains("1"), "{e}");
    }
}

/// Range bins: each holds the boxes within its distances of the sample's origin, counts each
/// class's ground truth, and its mean AP over the classes present is not dragged down by a class
/// that has no box there (the devkit's mAP counts that class as 0).
#[test]
fn range_bins_count_their_ground_truth_and_average_the_classes_present() {
    use hilo_eval::boxes::{GroundTruth, SampleInfo};
    let mut gt = GroundTruth::default();
    let mut pred = Vec::new();
    for f in 0..4 {
        let s = format!("s{f}");
        gt.samples.insert(s.clone(), SampleInfo { scene: "a".into(), ego_translation: [0.0; 3] });
        let boxes = vec![
            EvalBox { num_pts: 5, ..b(&s, "car", 10.0, f as f64, 0.0, 1.0) },
            EvalBox { num_pts: 5, ..b(&s, "car", 40.0, f as f64, 0.0, 1.0) },
            EvalBox { num_pts: 5, ..b(&s, "pedestrian", 0.0, 12.0 + f as f64, 0.0, 1.0) },
        ];
        pred.push((s.clone(), boxes.iter().map(|x| EvalBox { num_pts: -1, ..x.clone() }).collect::<Vec<_>>()));
        gt.boxes.insert(s, boxes);
    }
    let mut cfg = DetectionConfig::default();
    cfg.class_range.retain(|k, _| k == "car" || k == "pedestrian");
    let bins = hilo_eval::evaluate_distance_bins(&gt, &pred, &cfg, &[0.0, 30.0, 50.0]);
    assert_eq!(bins.iter().map(|b| b.label.as_str()).collect::<Vec<_>>(), ["0-30 m", "30-50 m"]);
    assert_eq!(bins[0].gt_boxes, BTreeMap::from([("car".to_string(), 4), ("pedestrian".to_string(), 4)]));
    assert_eq!(bins[1].gt_boxes, BTreeMap::from([("car".to_string(), 4), ("pedestrian".to_string(), 0)]));
    assert!((bins[0].metrics.mean_ap - 1.0).abs() < 1e-12);
    assert!(bins[0].mean_ap_present().is_some_and(|m| (m - bins[0].metrics.mean_ap).abs() < 1e-15));
    // 30–50 m: the car is found (AP 1), the pedestrian class has no box (AP 0 by the devkit).
    assert!((bins[1].metrics.mean_ap - 0.5).abs() < 1e-12, "{:?}", bins[1].metrics.mean_dist_aps);
    assert!(bins[1].mean_ap_present().is_some_and(|m| (m - 1.0).abs() < 1e-12), "{:?}", bins[1].mean_ap_present());
    // A range reaching past the last edge adds an open bin; one holding nothing has no mean.
    cfg.class_range.insert("car".into(), 60.0);
    let bins = hilo_eval::evaluate_distance_bins(&gt, &pred, &cfg, &[0.0, 30.0, 45.0]);
    assert_eq!(bins.last().map(|b| b.label.as_str()), Some("45+ m"));
    assert_eq!(bins.last().and_then(|b| b.mean_ap_present()), None);
}
