//! A training on the composite path (`hilo train --fused off`): its run.json names the set, it
//! starts from the loss the fused path starts from, it trains to the same bytes with the same
//! seed and when resumed, and a run is never resumed on the other path. Alone in its binary,
//! because the switch of the fused layers is process-wide.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use candle_core::Device;
use hilo_detector::Registry;
use hilo_detector::cpu::{Layer, layers_name, parse_layers, set_fused};
use hilo_detector::data::{Frame, GtBox};
use hilo_detector::detector::DetectorConfig;
use hilo_detector::grid::BevGrid;
use hilo_detector::train::{RunInfo, StepReport, TrainConfig};
use rand::{Rng, SeedableRng};

/// `centerpoint` (sparse convolutions, BatchNorm + ReLU, focal and L1 losses: every fused
/// layer) on a 32 × 32 grid, reading frames as given.
fn small() -> DetectorConfig {
    let mut c = Registry::with_builtin().preset("centerpoint").unwrap().detector.clone();
    c.grid = BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 2000, ..BevGrid::default() };
    c.input.background = None;
    c.input.radar_clutter = None;
    c
}

/// Ground points and one car's surface points.
fn frame(seed: u64) -> Frame {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let car = GtBox {
        class: 0,
        center: [seed as f32 % 7.0 - 3.0, 2.0, 0.8],
        wlh: [1.9, 4.6, 1.6],
        yaw: 0.1 * seed as f32,
        velocity: [3.0, 0.0],
    };
    let mut lidar: Vec<[f32; 5]> = (0..500)
        .map(|_| {
            [rng.random_range(-12.0..12.0), rng.random_range(-12.0..12.0), rng.random_range(-0.05..0.05), 0.1, 0.0]
        })
        .collect();
    let (c, s) = (car.yaw.cos(), car.yaw.sin());
    for _ in 0..80 {
        let (u, v, h) = (rng.random_range(-2.3..2.3), rng.random_range(-0.95..0.95), rng.random_range(0.0..1.6));
        lidar.push([car.center[0] + c * u - s * v, car.center[1] + s * u + c * v, h, 0.6, 0.0]);
    }
    Frame { sample_token: format!("s{seed}"), scene: "s".into(), lidar, boxes: vec![car], ..Frame::default() }
}

fn train(
    run: &std::path::Path,
    frames: &[Frame],
    on_step: &mut dyn FnMut(&StepReport) -> bool,
) -> hilo_detector::Result<RunInfo> {
    let tc = TrainConfig { samples: 2 * 6, batch: 2, checkpoint_steps: 2, ..TrainConfig::default() }.validate()?;
    let det = small().validate()?;
    hilo_detector::train::train(run, &det, &tc, frames, None, &Registry::with_builtin(), &Device::Cpu, on_step)
}

fn weights(run: &std::path::Path) -> Vec<u8> {
    std::fs::read(run.join("model.safetensors")).unwrap()
}

#[test]
fn a_training_on_the_composite_path_is_recorded_reproducible_and_kept_apart() {
    // The names round-trip.
    for s in ["on", "off", "conv", "bn_relu+loss", "conv+bn_relu"] {
        assert_eq!(layers_name(&parse_layers(s).unwrap()), s);
    }
    assert_eq!(layers_name(&parse_layers("loss+conv+conv").unwrap()), "conv+loss");
    let e = parse_layers("conv+batchnorm").unwrap_err();
    assert!(e.contains("\"batchnorm\""), "{e}");

    let frames: Vec<Frame> = (0..6).map(frame).collect();
    let dirs: Vec<_> = (0..4).map(|_| tempfile::tempdir().unwrap()).collect();
    let first_loss = |run: &std::path::Path| {
        let mut first = None;
        let info = train(run, &frames, &mut |r| {
            first.get_or_insert(r.loss);
            true
        })
        .unwrap();
        (info, first.unwrap())
    };

    // The fused path, as a training runs by default: run.json names no set.
    let (fused_info, fused_loss) = first_loss(dirs[0].path());
    assert_eq!(fused_info.fused, None);
    let json = std::fs::read_to_string(dirs[0].path().join("run.json")).unwrap();
    assert!(!json.contains("\"fused\""), "an all-fused run.json is as before: {json}");

    // The composite path: recorded, starts from the same loss, same seed, same bytes.
    set_fused(&[]);
    let (info, composite_loss) = first_loss(dirs[1].path());
    assert_eq!(info.fused.as_deref(), Some("off"));
    assert!(
        (fused_loss - composite_loss).abs() <= 1e-5 * composite_loss.abs(),
        "first loss {fused_loss} fused, {composite_loss} composite"
    );
    train(dirs[2].path(), &frames, &mut |_| true).unwrap();
    assert_eq!(weights(dirs[1].path()), weights(dirs[2].path()), "same seed, same weights on the composite path");
    // Interrupted after 3 steps and resumed: the uninterrupted run's bytes.
    let info = train(dirs[3].path(), &frames, &mut |r| r.step < 3).unwrap();
    assert!(!info.finished && info.step == 3);
    // Resuming on the fused path is refused, and says how to resume it.
    set_fused(&Layer::ALL);
    let e = train(dirs[3].path(), &frames, &mut |_| true).unwrap_err().to_string();
    assert!(e.contains("fused layers off") && e.contains("--fused off"), "{e}");
    set_fused(&[]);
    let info = train(dirs[3].path(), &frames, &mut |_| true).unwrap();
    assert!(info.finished);
    assert_eq!(weights(dirs[1].path()), weights(dirs[3].path()), "a resumed composite run differs");
    set_fused(&Layer::ALL);
}
