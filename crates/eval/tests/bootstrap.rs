//! Scene bootstrap and paired bootstrap.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_eval::bootstrap::{bootstrap, paired};
use hilo_eval::boxes::SampleInfo;
use hilo_eval::nuscenes::ClassData;
use hilo_eval::{DetectionConfig, EvalBox, GroundTruth, evaluate_files, filtered};
use rand::{Rng, SeedableRng};

/// 24 scenes of 10 frames; predictions with position noise `noise` (m) and some misses.
fn data(noise: f64, seed: u64) -> (GroundTruth, Vec<(String, Vec<EvalBox>)>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut prng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut gt = GroundTruth::default();
    let mut pred = Vec::new();
    for f in 0..240 {
        let token = format!("f{f:04}");
        gt.samples.insert(token.clone(), SampleInfo { scene: format!("scene{}", f / 10), ego_translation: [0.0; 3] });
        let mut g = Vec::new();
        let mut p = Vec::new();
        for _ in 0..8 {
            let class = ["car", "pedestrian", "bus"][rng.random_range(0..3)];
            let (x, y) = (rng.random_range(-35.0..35.0), rng.random_range(-35.0..35.0));
            let mut b = EvalBox::from_yaw(&token, class, [x, y, 0.8], [1.9, 4.5, 1.6], 0.3, [1.0, 0.0], 1.0);
            b.num_pts = 12;
            g.push(b);
            if prng.random_bool(0.85) {
                let (dx, dy) = (prng.random_range(-noise..noise), prng.random_range(-noise..noise));
                p.push(EvalBox::from_yaw(
                    &token,
                    class,
                    [x + dx, y + dy, 0.8],
                    [1.9, 4.5, 1.6],
                    0.35,
                    [1.0, 0.1],
                    prng.random_range(0.2..1.0),
                ));
            }
        }
        gt.boxes.insert(token.clone(), g);
        pred.push((token, p));
    }
    (gt, pred)
}

#[test]
fn unit_weights_reproduce_the_plain_curves_exactly() {
    let (gt, pred) = data(1.0, 1);
    let cfg = DetectionConfig::default();
    let (g, p) = filtered(&gt, &pred, &cfg);
    let cd = ClassData::new(&g, &p, "car");
    let m = cd.matches("car", 1.0);
    let ones = vec![1u32; g.len()];
    assert_eq!(m.curves(None), m.curves(Some(&ones)));
    assert_eq!(m.curves(None), cd.accumulate("car", 1.0));
}

#[test]
fn intervals_are_deterministic_and_bracket_the_estimate() {
    let (gt, pred) = data(1.0, 1);
    let cfg = DetectionConfig::default();
    let a = bootstrap(&gt, &pred, &cfg, 200, 0.95, 42);
    let b = bootstrap(&gt, &pred, &cfg, 200, 0.95, 42);
    assert_eq!(a, b);
    let c = bootstrap(&gt, &pred, &cfg, 200, 0.95, 43);
    assert_ne!(a.mean_ap.lo, c.mean_ap.lo);
    let m = evaluate_files(&gt, &pred, &cfg);
    assert!((a.mean_ap.estimate - m.mean_ap).abs() < 1e-12 && (a.nd_score.estimate - m.nd_score).abs() < 1e-12);
    assert!(a.mean_ap.lo <= a.mean_ap.estimate && a.mean_ap.estimate <= a.mean_ap.hi, "{:?}", a.mean_ap);
    assert!(a.mean_ap.hi - a.mean_ap.lo > 0.0 && a.mean_ap.std > 0.0);
    assert_eq!(a.scenes, 24);
}

#[test]
fn paired_bootstrap_finds_a_real_gain_and_no_gain_against_itself() {
    let cfg = DetectionConfig::default();
    let (gt, sloppy) = data(2.5, 1);
    let (_, sharp) = data(0.3, 1);
    let same = paired(&gt, &sloppy, &sloppy, &cfg, 200, 0.95, 5);
    assert_eq!((same.mean_ap_diff.lo, same.mean_ap_diff.hi), (0.0, 0.0));
    assert_eq!(same.p_mean_ap_not_better, 1.0);
    let gain = paired(&gt, &sloppy, &sharp, &cfg, 200, 0.95, 5);
    assert!(gain.mean_ap_diff.lo > 0.0, "{:?}", gain.mean_ap_diff);
    assert!(gain.p_mean_ap_not_better < 0.01);
}

#[test]
fn streamed_precision_equals_the_interpolated_curve() {
    let (gt, pred) = data(1.5, 3);
    let cfg = DetectionConfig::default();
    let (g, p) = filtered(&gt, &pred, &cfg);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for class in ["car", "pedestrian", "bus", "truck"] {
        let cd = ClassData::new(&g, &p, class);
        for th in [0.5, 1.0, 2.0, 4.0] {
            let m = cd.matches(class, th);
            for trial in 0..20 {
                // Small counts (many scenes not drawn) and large ones (recall points crossed mid-step).
                let top = if trial % 2 == 0 { 3u32 } else { 40 };
                let w: Option<Vec<u32>> = (trial > 0).then(|| (0..g.len()).map(|_| rng.random_range(0..top)).collect());
                let mut streamed = [0.0; hilo_eval::nuscenes::NELEM];
                m.precision_only(w.as_deref(), &mut streamed);
                assert_eq!(streamed.to_vec(), m.curves(w.as_deref()).precision, "{class} {th} trial {trial}");
            }
            // Eight replicates in one pass give each one's curve.
            let lanes: Vec<[u32; 8]> =
                (0..g.len()).map(|_| std::array::from_fn(|r| rng.random_range(0..[3, 40][r % 2]))).collect();
            let mut batch = [[0.0; hilo_eval::nuscenes::NELEM]; 8];
            m.precision_batch(&lanes, &mut batch);
            for (r, got) in batch.iter().enumerate() {
                let lane: Vec<u32> = lanes.iter().map(|c| c[r]).collect();
                assert_eq!(got.to_vec(), m.curves(Some(&lane)).precision, "{class} {th} lane {r}");
            }
        }
    }
}

#[test]
fn paired_between_pairs_scenes_across_token_spaces() {
    use hilo_eval::bootstrap::paired_between;
    use hilo_eval::boxes::{EvalBox, GroundTruth, SampleInfo};
    let gt = |prefix: &str| {
        let mut g = GroundTruth::default();
        for s in 0..4 {
            for f in 0..2 {
                let t = format!("{prefix}{s}-{f}");
                g.samples.insert(t.clone(), SampleInfo { scene: format!("scene-{s}"), ego_translation: [0.0; 3] });
                g.boxes.insert(
                    t.clone(),
                    vec![EvalBox {
                        num_pts: 10,
                        ..EvalBox::from_yaw(
                            &t,
                            "car",
                            [5.0 + s as f64, f as f64, 0.8],
                            [1.9, 4.6, 1.6],
                            0.0,
                            [0.0; 2],
                            1.0,
                        )
                    }],
                );
            }
        }
        g
    };
    let (ga, gb) = (gt("a"), gt("b"));
    let perfect = |g: &GroundTruth| -> Vec<(String, Vec<EvalBox>)> {
        g.boxes
            .iter()
            .map(|(t, b)| {
                (t.clone(), b.iter().map(|x| EvalBox { detection_score: 0.9, num_pts: -1, ..x.clone() }).collect())
            })
            .collect()
    };
    let mut cfg = hilo_eval::DetectionConfig::default();
    cfg.class_range.retain(|k, _| k == "car");
    // The same detector under two token spaces: no difference, in every replicate.
    let p = paired_between(&ga, &perfect(&ga), &gb, &perfect(&gb), &cfg, 200, 0.95, 1);
    assert_eq!((p.mean_ap_diff.estimate, p.mean_ap_diff.lo, p.mean_ap_diff.hi), (0.0, 0.0, 0.0));
    // B finds nothing: B − A = −1, certainly not better.
    let empty: Vec<(String, Vec<EvalBox>)> = gb.boxes.keys().map(|t| (t.clone(), Vec::new())).collect();
    let p = paired_between(&ga, &perfect(&ga), &gb, &empty, &cfg, 200, 0.95, 1);
    assert!((p.mean_ap_diff.estimate + 1.0).abs() < 1e-9 && p.mean_ap_diff.hi < 0.0, "{:?}", p.mean_ap_diff);
    assert_eq!(p.p_mean_ap_not_better, 1.0);
}

/// A matched submission scored under scene weights: every scene once (or every scene twice) is
/// the plain metric; dropping a scene is the metric without it. The velocity errors (mAVE and
/// each class's AVE) reweight the same way.
#[test]
fn reweighted_scores_equal_direct_evaluation() {
    use hilo_eval::bootstrap::Reweighable;
    use hilo_eval::boxes::{GroundTruth, SampleInfo};
    use hilo_eval::{DetectionConfig, EvalBox, evaluate_files};
    let mut gt = GroundTruth::default();
    let mut pred = Vec::new();
    for f in 0..12 {
        let s = format!("s{f:02}");
        gt.samples.insert(s.clone(), SampleInfo { scene: format!("scene{}", f % 4), ego_translation: [0.0; 3] });
        let g: Vec<EvalBox> = (0..5)
            .map(|k| EvalBox {
                num_pts: 3,
                ..EvalBox::from_yaw(
                    &s,
                    if k % 2 == 0 { "car" } else { "pedestrian" },
                    [5.0 * k as f64, f as f64, 0.8],
                    [1.9, 4.5, 1.6],
                    0.0,
                    if k % 2 == 0 { [4.0, 0.5] } else { [1.2, 0.0] },
                    1.0,
                )
            })
            .collect();
        let p: Vec<EvalBox> = g
            .iter()
            .enumerate()
            .filter(|(k, _)| (k + f) % 3 != 0)
            .map(|(k, b)| EvalBox {
                translation: [b.translation[0] + 0.3 * (k as f64 - 2.0), b.translation[1], 0.8],
                detection_score: 0.1 + 0.07 * ((k * 7 + f) % 12) as f64,
                velocity: [b.velocity[0] + 0.25 * ((k + f) % 4) as f64, b.velocity[1] - 0.1 * (f % 3) as f64],
                num_pts: -1,
                ..b.clone()
            })
            .collect();
        gt.boxes.insert(s.clone(), g);
        pred.push((s, p));
    }
    let cfg = DetectionConfig::default();
    let scenes: Vec<String> = (0..4).map(|i| format!("scene{i}")).collect();
    let r = Reweighable::new(&gt, &pred, &cfg, &scenes).unwrap();
    let direct = evaluate_files(&gt, &pred, &cfg);
    assert!((r.full(&cfg).0 - direct.mean_ap).abs() < 1e-12);
    let under = r.under(&cfg, &[vec![1; 4], vec![2; 4], vec![1, 1, 0, 1]]);
    assert_eq!(under.len(), 3);
    assert!((under[0].0 - direct.mean_ap).abs() < 1e-12 && (under[1].0 - direct.mean_ap).abs() < 1e-12);
    // Without scene2: the metric of the submission restricted to the other scenes.
    let keep = |s: &str| gt.samples[s].scene != "scene2";
    let gt3 = GroundTruth {
        samples: gt.samples.iter().filter(|(k, _)| keep(k)).map(|(k, v)| (k.clone(), v.clone())).collect(),
        boxes: gt.boxes.iter().filter(|(k, _)| keep(k)).map(|(k, v)| (k.clone(), v.clone())).collect(),
    };
    let pred3: Vec<_> = pred.iter().filter(|(k, _)| keep(k)).cloned().collect();
    let direct3 = evaluate_files(&gt3, &pred3, &cfg);
    assert!((under[2].0 - direct3.mean_ap).abs() < 1e-9);
    // Velocity errors: the devkit's mAVE and per-class AVE, in full and under the same draws.
    let (_, v) = r.full_with_velocity(&cfg);
    let vel = |m: &hilo_eval::DetectionMetrics, c: &str| m.label_tp_errors[c]["vel_err"];
    assert!(v.mean > 0.05 && (v.mean - direct.tp_errors["vel_err"]).abs() < 1e-12, "{v:?}");
    for c in ["car", "pedestrian"] {
        assert!((v.by_class[c] - vel(&direct, c)).abs() < 1e-12, "{c}: {v:?}");
    }
    let vu = r.under_with_velocity(&cfg, &[vec![1; 4], vec![1, 1, 0, 1]]);
    assert!((vu[0].1.mean - v.mean).abs() < 1e-12 && (vu[0].0.0 - direct.mean_ap).abs() < 1e-12);
    assert!((vu[1].1.mean - direct3.tp_errors["vel_err"]).abs() < 1e-9, "{:?}", vu[1].1);
    assert!((vu[1].1.by_class["car"] - vel(&direct3, "car")).abs() < 1e-9);
    assert!(Reweighable::new(&gt, &pred, &cfg, &scenes[..2]).is_err(), "a scene missing from the list");
}
