//! Radar's Doppler and RCS flow through every fusion plugin: two classes with the same shape
//! that differ only by motion (moving "car", static "golf_cart") cannot be told apart from
//! LiDAR, and the fusion presets separate them (a clear AP gap).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use candle_core::Device;
use hilo_detector::Registry;
use hilo_detector::conformance::{small_grid, synthetic_frame};
use hilo_detector::data::{Augmentation, Frame, GtBox};
use hilo_detector::train::{TrainConfig, load_run, train};
use hilo_eval::boxes::{EvalBox, GroundTruth, SampleInfo};
use hilo_eval::config::DetectionConfig;
use rand::{Rng, SeedableRng};

fn frames(seed: u64, n: usize) -> Vec<Frame> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|k| {
            let mut boxes: Vec<GtBox> = Vec::new();
            while boxes.len() < 3 {
                let (x, y) = (rng.random_range(-9.0f32..9.0), rng.random_range(-9.0f32..9.0));
                if boxes.iter().any(|b| (b.center[0] - x).hypot(b.center[1] - y) < 6.0) {
                    continue;
                }
                // Heading mostly along the radar's line of sight, so motion shows in v_r.
                let yaw = std::f32::consts::FRAC_PI_2 * if rng.random::<bool>() { 1.0 } else { -1.0 }
                    + rng.random_range(-0.4..0.4);
                let moving = rng.random::<bool>();
                let speed = if moving { rng.random_range(6.0..10.0) } else { 0.0 };
                boxes.push(GtBox {
                    class: if moving { 0 } else { 5 },
                    center: [x, y, 0.8],
                    wlh: [1.9, 4.6, 1.6],
                    yaw,
                    velocity: [speed * yaw.cos(), speed * yaw.sin()],
                });
            }
            let mut f = synthetic_frame(seed * 1000 + k as u64, &boxes, true, true);
            f.sample_token = format!("m{seed}-{k}");
            f
        })
        .collect()
}

fn map_for(name: &str, registry: &Registry, train_frames: &[Frame], val: &[Frame], seed: u64) -> f64 {
    scores_for(name, registry, train_frames, val, seed, None, false).0
}

/// mAP and car velocity error (AVE, m/s) of preset `name` trained on `train_frames`, with its
/// velocity learned over each box's footprint at weight `footprint` where given, and read from
/// the radar's Doppler after decoding (`hilo_detector::doppler`, as the fusion presets ship)
/// only where `doppler` says so: without it the velocity is the head's.
fn scores_for(
    name: &str,
    registry: &Registry,
    train_frames: &[Frame],
    val: &[Frame],
    seed: u64,
    footprint: Option<f64>,
    doppler: bool,
) -> (f64, f64) {
    let mut cfg = registry.preset(name).unwrap().detector.clone();
    if !doppler {
        cfg.decode.radar_velocity = None;
    }
    if let Some(w) = footprint {
        cfg.velocity_target = hilo_detector::targets::VelocityTarget::Footprint;
        cfg.velocity_weight = w;
    }
    cfg.grid = small_grid();
    // The synthetic frames have no static background to learn (and so no LiDAR foreground for
    // the radar clutter rule: their radar holds no clutter).
    cfg.input.background = None;
    cfg.input.radar_clutter = None;
    // The head at stride 2 (1.6 m cells, 32 channels): what is tested is that Doppler and RCS
    // flow through each plugin, and the coarser head trains faster on this small grid.
    cfg.backbone.out_stride = 2;
    cfg.backbone.neck_channels = 32;
    cfg.head_channels = 32;
    if let Some(b) = cfg.fusion_config.get_mut("backbone") {
        *b = serde_json::to_value(&cfg.backbone).unwrap();
        cfg.fusion_config["head_channels"] = serde_json::json!(32);
    }
    // 500 steps: `l4dr-like`, whose max over a cell's points lets its one radar point's
    // Doppler through only once the encoder has learnt to, separated the classes after 250
    // steps on two training seeds of three with the stride-8 block's two further 3×3 layers and
    // on none without them (0.45–0.49, the LiDAR-only level), and after 500 on both seeds tried.
    let tc = TrainConfig {
        samples: 4 * 500,
        batch: 4,
        lr_max: 5e-3,
        augmentation: Augmentation { scale: 0.02, ..Augmentation::none() },
        checkpoint_steps: 10_000,
        // The fixture holds one class per motion state in set proportions; pasting golf carts
        // would change them, and what is tested is the radar's path through each plugin.
        paste: None,
        seed,
        ..TrainConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    train(
        dir.path(),
        &cfg.clone().validate().unwrap(),
        &tc.clone().validate().unwrap(),
        train_frames,
        None,
        registry,
        &Device::Cpu,
        &mut |_| true,
    )
    .unwrap();
    let (det, _, _) = load_run(dir.path(), registry, &Device::Cpu).unwrap();
    let (dets, _) = hilo_detector::infer::detect_frames(&det, val, 4, &mut |_| {}).unwrap();
    let dets: std::collections::BTreeMap<String, Vec<hilo_core::Detection>> = dets.into_iter().collect();
    let mut gt = GroundTruth::default();
    let mut pred = Vec::new();
    for f in val {
        gt.samples.insert(f.sample_token.clone(), SampleInfo { scene: "s".into(), ego_translation: [0.0; 3] });
        let boxes = f
            .boxes
            .iter()
            .map(|b| EvalBox {
                num_pts: 50,
                ..EvalBox::from_yaw(
                    &f.sample_token,
                    if b.class == 0 { "car" } else { "golf_cart" },
                    b.center.map(f64::from),
                    b.wlh.map(f64::from),
                    b.yaw as f64,
                    b.velocity.map(f64::from),
                    1.0,
                )
            })
            .collect();
        gt.boxes.insert(f.sample_token.clone(), boxes);
        let p: Vec<EvalBox> =
            dets[&f.sample_token].iter().map(|d| EvalBox::from_detection(&f.sample_token, d)).collect();
        pred.push((f.sample_token.clone(), p));
    }
    // AP at the 2 and 4 m thresholds: the question is the class, not centimetre localisation.
    let mut ec = DetectionConfig { dist_ths: vec![2.0, 4.0], ..DetectionConfig::default() };
    ec.class_range.retain(|k, _| k == "car" || k == "golf_cart");
    let m = hilo_eval::evaluate_files(&gt, &pred, &ec);
    let car_ave = m.label_tp_errors.get("car").and_then(|e| e.get("vel_err")).copied().unwrap_or(f64::NAN);
    eprintln!(
        "{name} (training seed {seed}, footprint velocity {footprint:?}): mAP {:.3} ({:?}), car AVE {car_ave:.2} m/s",
        m.mean_ap,
        m.label_aps.iter().map(|(k, v)| (k.clone(), v.values().sum::<f64>() / v.len() as f64)).collect::<Vec<_>>()
    );
    (m.mean_ap, car_ave)
}

/// Fixture and training seeds to run: the first `HILO_MOTION_SEEDS` (1 unless set; 5 for the
/// robustness run `HILO_MOTION_SEEDS=5 cargo test --release -p hilo-cli --test fusion_motion`,
/// with `HILO_MOTION_PRESETS` to pick presets).
/// Seed k draws the fixture's training frames from 2k + 1, its validation frames from 2k + 2,
/// and trains every detector with seed k: a CPU whose float path happens to favour one seed
/// does not pass on it alone.
fn seeds() -> u64 {
    match std::env::var("HILO_MOTION_SEEDS") {
        Ok(v) => v.parse().unwrap_or_else(|_| panic!("HILO_MOTION_SEEDS={v:?}: a count of seeds (e.g. 5)")),
        Err(_) => 1,
    }
}

/// The fusion presets to run: all of them, or those named in `HILO_MOTION_PRESETS`
/// (comma-separated, e.g. `l4dr-like` to rerun one preset over many seeds).
fn presets() -> Vec<&'static str> {
    let all = ["pointpillars-lr", "l4dr-like", "lirafusion-like", "bi-lrfusion-like", "middle-attention", "late"];
    match std::env::var("HILO_MOTION_PRESETS") {
        Ok(v) => {
            let named: Vec<&str> = v.split(',').map(str::trim).collect();
            if let Some(bad) = named.iter().find(|n| !all.contains(n)) {
                panic!("HILO_MOTION_PRESETS={v:?}: {bad:?} is not one of {all:?}");
            }
            all.into_iter().filter(|p| named.contains(p)).collect()
        }
        Err(_) => all.to_vec(),
    }
}

#[test]
fn every_fusion_preset_separates_classes_that_differ_only_by_motion() {
    let r = hilo::registry().unwrap();
    let mut failures = Vec::new();
    for k in 0..seeds() {
        // 200 training frames: with 24, a detector could tell the classes apart by memorising
        // where each object stood (the point features hold absolute x, y), and every preset,
        // LiDAR-only or not, ended between 0.3 and 0.7 with gaps within run-to-run noise. With 200
        // no position repeats: LiDAR-only stays near 0.4 (the class is a coin toss) and a
        // detector reaches 0.9 only through the radar's Doppler.
        let (tr, val) = (frames(2 * k + 1, 200), frames(2 * k + 2, 12));
        // Each fusion preset against the LiDAR-only preset it extends (same backbone and head).
        let wanted = presets();
        // Each LiDAR-only preset that one of the fusion presets to run extends.
        let lidar_only: Vec<(&str, f64)> = [("pointpillars", true), ("centerpoint", false)]
            .into_iter()
            .filter(|&(_, pp)| wanted.iter().any(|n| (*n == "pointpillars-lr") == pp))
            .map(|(lidar, _)| (lidar, map_for(lidar, &r, &tr, &val, k)))
            .collect();
        for &(lidar, base) in &lidar_only {
            assert!(
                base < 0.6,
                "seed {k}: {lidar} (LiDAR only) separates the classes: mAP {base:.3}; the fixture leaks the class into LiDAR"
            );
        }
        for name in presets() {
            let base_name = if name == "pointpillars-lr" { "pointpillars" } else { "centerpoint" };
            let base = lidar_only.iter().find(|(l, _)| *l == base_name).map(|&(_, m)| m).unwrap();
            let fused = map_for(name, &r, &tr, &val, k);
            eprintln!("seed {k}: {name} {fused:.3} against {base_name} {base:.3} (margin {:+.3})", fused - base);
            if fused < base + 0.25 {
                failures.push(format!("seed {k}: {name}: mAP {fused:.3} against LiDAR-only {base_name} {base:.3}"));
            }
        }
    }
    assert!(failures.is_empty(), "fused below LiDAR-only + 0.25:\n{}", failures.join("\n"));
}

/// The radar's Doppler reaches a CenterPoint head's velocity output when velocity is learned
/// over each box's footprint: on the motion fixture (cars at 6–10 m/s, mostly along the radar's
/// line of sight) `lirafusion-like` with `velocity_target = "footprint"` (weight 1.0) brings the
/// car velocity error below 3 m/s and at least 3 m/s below LiDAR-only `centerpoint` (seeds 0–2:
/// 1.81, 1.89, 1.97 against 7.59, 7.94, 7.67; at the centre cell alone the preset reached 5.97,
/// 7.33 and 1.79: sometimes, not reliably).
#[test]
fn footprint_velocity_lets_the_radar_set_a_cars_velocity() {
    let r = hilo::registry().unwrap();
    let mut failures = Vec::new();
    for k in 0..seeds() {
        let (tr, val) = (frames(2 * k + 1, 200), frames(2 * k + 2, 12));
        let lidar = scores_for("centerpoint", &r, &tr, &val, k, None, false).1;
        let footprint = scores_for("lirafusion-like", &r, &tr, &val, k, Some(1.0), false).1;
        eprintln!("seed {k}: car AVE {footprint:.2} (footprint) against {lidar:.2} (LiDAR only)");
        if !(footprint <= 3.0 && footprint <= lidar - 3.0) {
            failures.push(format!("seed {k}: footprint {footprint:.2}, LiDAR only {lidar:.2} m/s"));
        }
    }
    assert!(failures.is_empty(), "car velocity error not lowered by the footprint:\n{}", failures.join("\n"));
}

/// The fusion presets as shipped read each car's speed from the Doppler of the radar detections
/// inside its box along the box's heading (`decode.radar_velocity`): on the motion fixture,
/// where every car has radar points and moves within 23° of the radar's line of sight, the
/// preset's car velocity error falls to a fraction of the LiDAR-only one, whatever its head
/// learned (the centre cell, which the footprint test shows does not learn it reliably). Seeds
/// 0–2: 1.35, 1.82, 1.22 m/s against 7.72, 7.76, 7.57. The velocity's direction is the box's
/// heading, so the heading's error stays in it (10° at 8 m/s alone is 1.4 m/s).
#[test]
fn the_presets_read_a_cars_velocity_from_the_doppler() {
    let r = hilo::registry().unwrap();
    let mut failures = Vec::new();
    for k in 0..seeds() {
        let (tr, val) = (frames(2 * k + 1, 200), frames(2 * k + 2, 12));
        let lidar = scores_for("centerpoint", &r, &tr, &val, k, None, true).1;
        let read = scores_for("lirafusion-like", &r, &tr, &val, k, None, true).1;
        eprintln!("seed {k}: car AVE {read:.2} (Doppler read) against {lidar:.2} (LiDAR only)");
        if !(read <= 2.5 && read <= lidar - 5.0) {
            failures.push(format!("seed {k}: Doppler read {read:.2}, LiDAR only {lidar:.2} m/s"));
        }
    }
    assert!(failures.is_empty(), "car velocity error not lowered by the Doppler step:\n{}", failures.join("\n"));
}
