//! Rotated IoU on hard cases, against closed forms and a Monte-Carlo estimate.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hilo_eval::EvalBox;
use hilo_eval::iou::{IouKind, ap_r40, bev_iou, iou_3d};
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

fn bx(x: f64, y: f64, w: f64, l: f64, yaw: f64) -> EvalBox {
    EvalBox::from_yaw("s", "car", [x, y, 1.0], [w, l, 2.0], yaw, [0.0, 0.0], 0.5)
}

#[test]
fn hard_cases_have_exact_values_and_never_nan() {
    let a = bx(3.0, -2.0, 2.0, 4.0, 0.7);
    assert_eq!(bev_iou(&a, &a), 1.0);
    assert_eq!(iou_3d(&a, &a), 1.0);
    // Touching along an edge: 0.
    assert_eq!(bev_iou(&bx(0.0, 0.0, 2.0, 4.0, 0.0), &bx(4.0, 0.0, 2.0, 4.0, 0.0)), 0.0);
    // Nested: the small one's area over the big one's.
    let iou = bev_iou(&bx(0.0, 0.0, 4.0, 4.0, 0.3), &bx(0.0, 0.0, 2.0, 2.0, 0.3));
    assert!((iou - 0.25).abs() < 1e-12, "{iou}");
    // A 2×4 box against itself rotated 90°: the 2×2 middle square overlaps; 4 / (8 + 8 − 4).
    let iou = bev_iou(&bx(0.0, 0.0, 2.0, 4.0, 0.0), &bx(0.0, 0.0, 2.0, 4.0, FRAC_PI_2));
    assert!((iou - 4.0 / 12.0).abs() < 1e-12, "{iou}");
    // A unit square against itself rotated 45°: intersection is a regular octagon of area 2(√2 − 1).
    let oct = 2.0 * (2f64.sqrt() - 1.0);
    let iou = bev_iou(&bx(0.0, 0.0, 1.0, 1.0, 0.0), &bx(0.0, 0.0, 1.0, 1.0, FRAC_PI_4));
    assert!((iou - oct / (2.0 - oct)).abs() < 1e-12, "{iou}");
    // Yaw differing by 2π and by π (a box is symmetric): identical footprints.
    assert!((bev_iou(&bx(1.0, 1.0, 2.0, 4.0, 0.3), &bx(1.0, 1.0, 2.0, 4.0, 0.3 + PI)) - 1.0).abs() < 1e-12);
    // Near-parallel edges, offset by a hair: close to 1, finite.
    let iou = bev_iou(&bx(0.0, 0.0, 2.0, 4.0, 0.0), &bx(1e-9, 0.0, 2.0, 4.0, 1e-12));
    assert!(iou.is_finite() && (iou - 1.0).abs() < 1e-8, "{iou}");
    // Degenerate boxes: 0, not NaN.
    let flat = bx(0.0, 0.0, 0.0, 4.0, 0.0);
    assert_eq!(bev_iou(&flat, &flat), 0.0);
    assert_eq!(bev_iou(&flat, &a), 0.0);
    assert_eq!(iou_3d(&EvalBox { size: [2.0, 4.0, 0.0], ..a.clone() }, &a), 0.0);
    // 3-D: the same footprint, heights overlapping by half.
    let mut up = a.clone();
    up.translation[2] += 1.0;
    assert!((iou_3d(&a, &up) - 1.0 / 3.0).abs() < 1e-12);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn bev_iou_matches_monte_carlo_and_is_symmetric(
        x in -2.0f64..2.0, y in -2.0f64..2.0, yaw1 in -3.2f64..3.2, yaw2 in -3.2f64..3.2,
        w1 in 0.5f64..3.0, l1 in 0.5f64..5.0, w2 in 0.5f64..3.0, l2 in 0.5f64..5.0,
    ) {
        let a = bx(0.0, 0.0, w1, l1, yaw1);
        let b = bx(x, y, w2, l2, yaw2);
        let iou = bev_iou(&a, &b);
        prop_assert!((iou - bev_iou(&b, &a)).abs() < 1e-12);
        prop_assert!((0.0..=1.0).contains(&iou));
        // Monte-Carlo area estimate on a fine grid over a's footprint.
        let inside = |bx: &EvalBox, px: f64, py: f64| {
            let (s, c) = bx.yaw().sin_cos();
            let (dx, dy) = (px - bx.translation[0], py - bx.translation[1]);
            (dx * c + dy * s).abs() <= 0.5 * bx.size[1] && (-dx * s + dy * c).abs() <= 0.5 * bx.size[0]
        };
        let n = 300;
        let r = 0.5 * (w1 * w1 + l1 * l1).sqrt();
        let mut hits = 0usize;
        let mut in_a = 0usize;
        for i in 0..n {
            for j in 0..n {
                let (px, py) = (-r + 2.0 * r * (i as f64 + 0.5) / n as f64, -r + 2.0 * r * (j as f64 + 0.5) / n as f64);
                if inside(&a, px, py) {
                    in_a += 1;
                    if inside(&b, px, py) { hits += 1; }
                }
            }
        }
        let cell = (2.0 * r / n as f64).powi(2);
        let inter = hits as f64 * cell;
        let mc = inter / (w1 * l1 + w2 * l2 - inter);
        prop_assert!((iou - mc).abs() < 0.02 + 0.02 * mc, "iou {} mc {} (a cells {})", iou, mc, in_a);
    }
}

#[test]
fn r40_ap_is_one_for_perfect_and_falls_with_misses() {
    let mut gt: BTreeMap<String, Vec<EvalBox>> = BTreeMap::new();
    let mut pred = Vec::new();
    for s in 0..10 {
        let token = format!("s{s}");
        let boxes: Vec<EvalBox> = (0..4)
            .map(|k| EvalBox { sample_token: token.clone(), ..bx(10.0 * k as f64, s as f64, 1.9, 4.5, 0.1 * k as f64) })
            .collect();
        pred.push((
            token.clone(),
            boxes
                .iter()
                .enumerate()
                .map(|(i, b)| EvalBox { detection_score: 0.9 - 0.01 * i as f64, ..b.clone() })
                .collect(),
        ));
        gt.insert(token, boxes);
    }
    assert!((ap_r40(&gt, &pred, "car", 0.7, IouKind::Bev) - 1.0).abs() < 1e-12);
    assert!((ap_r40(&gt, &pred, "car", 0.7, IouKind::ThreeD) - 1.0).abs() < 1e-12);
    // Drop half the predictions: recall stops at 0.5, so AP is 0.5.
    let half: Vec<(String, Vec<EvalBox>)> = pred.iter().map(|(s, v)| (s.clone(), v[..2].to_vec())).collect();
    assert!((ap_r40(&gt, &half, "car", 0.7, IouKind::Bev) - 0.5).abs() < 1e-12);
    assert!(ap_r40(&gt, &pred, "bus", 0.7, IouKind::Bev).is_nan(), "no ground truth: undefined");
}
