//! The detector framework: shapes, losses on hard cases, overfitting one batch, checkpoints,
//! determinism, resume, data-parallel replicas, and bad input.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use candle_core::{Device, Tensor};
use hilo_core::Class;
use hilo_detector::data::{Augmentation, Frame, GtBox};
use hilo_detector::detector::{Detector, DetectorConfig, HostBatch, LossNorm};
use hilo_detector::grid::BevGrid;
use hilo_detector::loss::{centernet_focal, per_class_mean, sigmoid_focal, softplus};
use hilo_detector::train::{AdamW, ReplicaPools, RunInfo, StepReport, TrainConfig, step_pass};
use hilo_detector::{Registry, Stage};
use rand::{Rng, SeedableRng};

/// A preset on a small grid (32 × 32 pillars of 0.8 m) so tests run in seconds, reading frames
/// as given (no background model: the synthetic frames have none to learn).
fn small(name: &str) -> DetectorConfig {
    let mut c = Registry::with_builtin().preset(name).unwrap().detector.clone();
    c.grid = BevGrid { half_extent_m: 12.8, cell_m: 0.8, max_pillars: 2000, ..BevGrid::default() };
    c.input.background = None;
    c.input.radar_clutter = None;
    c
}

fn dense(name: &str) -> DetectorConfig {
    DetectorConfig { sparse: None, ..small(name) }
}

/// A frame with boxes sampled on their surfaces (LiDAR) and ground points around.
fn frame(seed: u64, boxes: &[GtBox]) -> Frame {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut lidar = Vec::new();
    for _ in 0..600 {
        lidar.push([
            rng.random_range(-12.0..12.0),
            rng.random_range(-12.0..12.0),
            rng.random_range(-0.05..0.05),
            0.1,
            0.0,
        ]);
    }
    for b in boxes {
        let (c, s) = (b.yaw.cos(), b.yaw.sin());
        for _ in 0..80 {
            let (u, v, h) = (
                rng.random_range(-0.5..0.5) * b.wlh[1],
                rng.random_range(-0.5..0.5) * b.wlh[0],
                rng.random_range(0.0..1.0) * b.wlh[2],
            );
            lidar.push([
                b.center[0] + c * u - s * v,
                b.center[1] + s * u + c * v,
                b.center[2] - 0.5 * b.wlh[2] + h,
                0.6,
                0.0,
            ]);
        }
    }
    Frame {
        sample_token: format!("s{seed}"),
        scene: "s".into(),
        lidar,
        radar: Vec::new(),
        radar_origin: Vec::new(),
        boxes: boxes.to_vec(),
    }
}

fn car(x: f32, y: f32, yaw: f32) -> GtBox {
    GtBox { class: 0, center: [x, y, 0.8], wlh: [1.9, 4.6, 1.6], yaw, velocity: [3.0 * yaw.cos(), 3.0 * yaw.sin()] }
}

fn ped(x: f32, y: f32) -> GtBox {
    GtBox { class: 4, center: [x, y, 0.9], wlh: [0.6, 0.6, 1.75], yaw: 0.0, velocity: [0.0, 1.2] }
}

/// Training with the schedule checked first, as every caller does.
#[allow(clippy::too_many_arguments)]
fn train(
    run: &std::path::Path,
    det: &DetectorConfig,
    tc: &TrainConfig,
    frames: &[Frame],
    background: Option<&hilo_dataset::background::BackgroundModel>,
    registry: &Registry,
    device: &Device,
    on_step: &mut dyn FnMut(&StepReport) -> bool,
) -> hilo_detector::Result<RunInfo> {
    let tc = tc.clone().validate()?;
    hilo_detector::train::train(run, &det.clone().validate()?, &tc, frames, background, registry, device, on_step)
}

/// A detector built from a config checked first, as every caller does.
fn build(cfg: &DetectorConfig, registry: &Registry, device: &Device, seed: u64) -> hilo_detector::Result<Detector> {
    Detector::new(&cfg.clone().validate()?, registry, device, seed)
}

#[test]
fn module_shapes() {
    for name in ["centerpoint", "pointpillars"] {
        let frames = vec![frame(1, &[car(2.0, 3.0, 0.3)]), frame(2, &[ped(-4.0, 1.0)])];
        // Dense: maps over the head's grid, the 32 × 32 pillar grid divided by the output stride.
        let cfg = dense(name);
        let det = build(&cfg, &Registry::with_builtin(), &Device::Cpu, 0).unwrap();
        let b = HostBatch::new(&cfg, &frames, false, 0);
        // x, y, z, intensity, sweep lag and PointPillars' five decorations.
        assert_eq!(b.lidar.width, 10);
        assert_eq!(b.lidar.features.len(), b.lidar.count() * b.lidar.points_per_pillar * 10);
        let (cls, reg) = det.forward(&b, false).unwrap();
        let n = cfg.grid.cells() / cfg.backbone.out_stride;
        assert_eq!(n, if name == "centerpoint" { 32 } else { 16 });
        assert_eq!(cls.dims(), &[2, 6, n, n], "{name}");
        assert_eq!(reg.dims(), &[2, 10, n, n], "{name}");
        assert_eq!(b.targets.cls.len(), 2 * 6 * n * n);
        assert!(b.targets.num_pos >= 2.0);
        // Sparse: one row per head site, targets gathered to them.
        let cfg = small(name);
        let det = build(&cfg, &Registry::with_builtin(), &Device::Cpu, 0).unwrap();
        let b = HostBatch::new(&cfg, &frames, false, 0);
        let sites = b.sparse.as_ref().unwrap().head_sites.len();
        assert!(sites > 0 && sites <= 2 * n * n, "{name}: {sites} head sites");
        let (cls, reg) = det.forward(&b, false).unwrap();
        assert_eq!((cls.dims(), reg.dims()), (&[sites, 6][..], &[sites, 10][..]), "{name}");
        assert_eq!(b.targets.cls.len(), sites * 6);
    }
}

#[test]
fn losses_are_finite_and_exact_for_extreme_logits() {
    let d = Device::Cpu;
    let x = Tensor::new(&[-100f32, -10.0, 0.0, 10.0, 100.0], &d).unwrap();
    let sp = softplus(&x).unwrap().to_vec1::<f32>().unwrap();
    for (v, want) in sp.iter().zip([0.0f32, 4.54e-5, std::f32::consts::LN_2, 10.000_045, 100.0]) {
        assert!((v - want).abs() <= 1e-4 * want.max(1.0), "softplus {v} vs {want}");
    }
    let logits = Tensor::new(&[[[[100f32, -100.0], [-100.0, 100.0]]]], &d).unwrap();
    let t = Tensor::new(&[[[[1f32, 0.0], [0.5, 0.0]]]], &d).unwrap();
    for l in [
        centernet_focal(&logits, &t, 1.0).unwrap(),
        sigmoid_focal(&logits, &t.ge(0.999).unwrap().to_dtype(candle_core::DType::F32).unwrap(), 1.0).unwrap(),
    ] {
        let v = l.to_scalar::<f32>().unwrap();
        assert!(v.is_finite(), "{v}");
    }
    // Closed form: one positive at logit 0 → (1 − ½)² · ln 2 = 0.1733.
    let v = centernet_focal(&Tensor::new(&[[[[0f32]]]], &d).unwrap(), &Tensor::new(&[[[[1f32]]]], &d).unwrap(), 1.0)
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!((v - 0.25 * std::f32::consts::LN_2).abs() < 1e-6, "{v}");
}

/// CenterPoint's per-task normalisation ([`LossNorm::PerClass`]) against the formula on the
/// host: `(1/K) Σ_k Σ terms[·, k, ·] / max(1, n_k)`, for site rows and dense maps, with classes
/// that have no positives; each present class's regression weights sum to `1/K`.
#[test]
fn per_class_normalisation_weighs_every_class_alike() {
    let d = Device::Cpu;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let counts = [7.0f32, 0.0, 1.0, 3.0, 12.0, 0.0];
    for dims in [vec![37usize, 6], vec![2, 6, 3, 5]] {
        let n: usize = dims.iter().product();
        let v: Vec<f32> = (0..n).map(|_| rng.random_range(0.0..2.0)).collect();
        let terms = Tensor::from_vec(v.clone(), dims.as_slice(), &d).unwrap();
        let got = per_class_mean(&terms, &counts).unwrap().to_scalar::<f32>().unwrap() as f64;
        let inner: usize = dims[2..].iter().product();
        let mut want = 0.0f64;
        for (i, x) in v.iter().enumerate() {
            let k = (i / inner) % 6;
            want += *x as f64 / (6.0 * counts[k].max(1.0) as f64);
        }
        assert!((got - want).abs() <= 1e-5 * want, "{dims:?}: {got} vs {want}");
    }
    // Targets of a real batch: three cars and a pedestrian over two frames.
    let frames =
        vec![frame(1, &[car(2.0, 3.0, 0.3), ped(-4.0, 1.0)]), frame(2, &[car(-6.0, 6.0, 2.0), car(6.0, -7.0, -1.0)])];
    for cfg in [dense("centerpoint"), small("centerpoint")] {
        let b = HostBatch::new(&cfg, &frames, false, 0);
        let t = &b.targets;
        assert_eq!(t.pos_per_class.len(), 6);
        assert_eq!((t.pos_per_class[0], t.pos_per_class[4], t.num_pos), (3.0, 1.0, 4.0));
        let w = t.per_class_site_weights(6, cfg.sparse.is_none());
        assert_eq!(w.len(), t.mask.len());
        let total: f32 = w.iter().sum();
        assert!((total - 2.0 / 6.0).abs() < 1e-6, "two classes present, each weighing 1/6: {total}");
        assert!(w.iter().zip(&t.mask).all(|(w, m)| (*w > 0.0) == (*m > 0.0)));
        // The detector's loss with the option: finite, and it differs from the plain one.
        let per_class = DetectorConfig { loss_norm: LossNorm::PerClass, ..cfg.clone() };
        let plain = DetectorConfig { loss_norm: LossNorm::All, ..cfg.clone() };
        let losses: Vec<f32> = [plain, per_class]
            .iter()
            .map(|c| {
                let det = build(c, &Registry::with_builtin(), &Device::Cpu, 0).unwrap();
                let (cls, reg) = det.forward(&b, true).unwrap();
                det.loss(&cls, &reg, t).unwrap().total.to_scalar::<f32>().unwrap()
            })
            .collect();
        assert!(losses.iter().all(|l| l.is_finite()) && losses[0] != losses[1], "{losses:?}");
    }
}

/// A box whose velocity is unknown (NaN: no neighbour in time) trains its box but not its
/// velocity: the targets mark it, and the loss does not move when the predicted velocity at its
/// cell changes, while it does at a box whose velocity is known. Both normalisations, dense
/// maps and sparse sites.
#[test]
fn unknown_velocity_is_masked_out_of_the_loss() {
    let mut still = car(-6.0, 6.0, 2.0);
    still.velocity = [f32::NAN; 2];
    let frames = vec![frame(4, &[car(4.0, 3.0, 0.3), still])];
    for cfg in [dense("centerpoint"), small("centerpoint")] {
        let b = HostBatch::new(&cfg, &frames, false, 0);
        let t = &b.targets;
        assert!(t.reg.iter().all(|v| v.is_finite()));
        let (pos, known) =
            (t.mask.iter().filter(|m| **m > 0.0).count(), t.vel_mask.iter().filter(|m| **m > 0.0).count());
        assert_eq!((pos, known), (2, 1), "two centres, one with a known velocity");
        for norm in [LossNorm::All, LossNorm::PerClass] {
            let c = DetectorConfig { loss_norm: norm, ..cfg.clone() };
            let det = build(&c, &Registry::with_builtin(), &Device::Cpu, 0).unwrap();
            let (cls, reg) = det.forward(&b, true).unwrap();
            let base = det.loss(&cls, &reg, t).unwrap().reg;
            // Adds 5 m/s to the predicted velocity channels at the cells where `pick` holds.
            let nudge = |pick: &dyn Fn(usize) -> bool| -> f32 {
                let mut v: Vec<f32> = reg.flatten_all().unwrap().to_vec1().unwrap();
                let cells = t.mask.len();
                let dense = reg.rank() == 4;
                for i in (0..cells).filter(|&i| t.mask[i] > 0.0 && pick(i)) {
                    for ch in 8..10 {
                        let at = if dense { ch * cells + i } else { i * 10 + ch };
                        v[at] += 5.0;
                    }
                }
                let r = Tensor::from_vec(v, reg.shape(), &Device::Cpu).unwrap();
                det.loss(&cls, &r, t).unwrap().reg
            };
            let unknown = nudge(&|i| t.vel_mask[i] == 0.0);
            let known = nudge(&|i| t.vel_mask[i] > 0.0);
            assert!((unknown - base).abs() <= 1e-6 * base.abs().max(1.0), "{norm:?}: {base} → {unknown}");
            assert!((known - base).abs() > 0.01, "{norm:?}: {base} → {known}");
        }
    }
}

#[test]
fn empty_clouds_and_frames_without_boxes_give_finite_losses() {
    let cfg = small("centerpoint");
    let det = build(&cfg, &Registry::with_builtin(), &Device::Cpu, 0).unwrap();
    let empty = Frame { sample_token: "e".into(), scene: "s".into(), ..Frame::default() };
    for frames in [vec![empty.clone()], vec![frame(3, &[]), empty]] {
        let b = HostBatch::new(&cfg, &frames, false, 0);
        let (cls, reg) = det.forward(&b, true).unwrap();
        let l = det.loss(&cls, &reg, &b.targets).unwrap();
        assert!(l.total.to_scalar::<f32>().unwrap().is_finite());
        let g = l.total.backward().unwrap();
        assert!(det.trainable().iter().any(|(_, v)| g.get(v).is_some()));
    }
}

#[test]
fn one_batch_overfits() {
    for name in ["centerpoint", "pointpillars"] {
        let cfg = small(name);
        let frames = vec![
            frame(4, &[car(3.0, 2.0, 0.4), ped(-5.0, -3.0)]),
            frame(5, &[car(-6.0, 6.0, 2.0), car(6.0, -7.0, -1.0)]),
        ];
        let tc = TrainConfig {
            samples: 2 * 120,
            batch: 2,
            lr_max: 5e-3,
            augmentation: Augmentation::none(),
            checkpoint_steps: 1000,
            ..TrainConfig::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let mut losses = Vec::new();
        let one: Vec<Frame> = frames.clone();
        train(dir.path(), &cfg, &tc, &one, None, &Registry::with_builtin(), &Device::Cpu, &mut |r| {
            losses.push(r.loss);
            true
        })
        .unwrap();
        let first = losses[..3].iter().sum::<f32>() / 3.0;
        let last = losses[losses.len() - 3..].iter().sum::<f32>() / 3.0;
        assert!(last * 10.0 <= first, "{name}: loss {first} → {last}");
        // And the overfit detector finds the boxes it saw.
        let (det, _, _) = hilo_detector::train::load_run(dir.path(), &Registry::with_builtin(), &Device::Cpu).unwrap();
        let found = det.detect(&HostBatch::new(&cfg, &frames[..1], false, 0)).unwrap();
        let best = found[0]
            .iter()
            .filter(|d| d.class == Class::Car)
            .map(|d| ((d.box3.center.x - 3.0).powi(2) + (d.box3.center.y - 2.0).powi(2)).sqrt())
            .fold(f32::INFINITY, f32::min);
        // Within half a car length: the detector found the car it was shown (centerpoint lands
        // within ~0.3 m; the dense head's border cells regress less precisely after 120 steps).
        assert!(best < 2.3, "{name}: nearest car detection {best} m from the car");
    }
}

#[test]
fn checkpoints_reload_bit_identically_and_training_is_deterministic_and_resumes() {
    let cfg = small("centerpoint");
    let frames: Vec<Frame> =
        (0..6).map(|k| frame(10 + k, &[car(k as f32 - 3.0, 2.0, 0.1 * k as f32), ped(4.0, -(k as f32))])).collect();
    let tc = TrainConfig { samples: 2 * 8, batch: 2, checkpoint_steps: 3, ..TrainConfig::default() };
    let reg = Registry::with_builtin();
    let (a, b, c) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    train(a.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    train(b.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    let w = |d: &std::path::Path| std::fs::read(d.join("model.safetensors")).unwrap();
    assert_eq!(w(a.path()), w(b.path()), "same seed, same weights");
    // Interrupted after 5 steps, then resumed: the same weights as without interruption.
    let info = train(c.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |r| r.step < 5).unwrap();
    assert!(!info.finished && info.step == 5);
    let info = train(c.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    assert!(info.finished && info.step == 8);
    assert_eq!(w(a.path()), w(c.path()), "resumed run differs");
    // A run folder is never reused for other frames.
    let e = train(c.path(), &cfg, &tc, &frames[..5], None, &reg, &Device::Cpu, &mut |_| true).unwrap_err().to_string();
    assert!(e.contains("other frames"), "{e}");
    // Save → load: bit-identical outputs.
    let (d1, _, _) = hilo_detector::train::load_run(a.path(), &reg, &Device::Cpu).unwrap();
    let (d2, _, _) = hilo_detector::train::load_run(a.path(), &reg, &Device::Cpu).unwrap();
    let hb = HostBatch::new(&cfg, &frames[..2], false, 0);
    let (x1, y1) = d1.forward(&hb, false).unwrap();
    let (x2, y2) = d2.forward(&hb, false).unwrap();
    assert_eq!(
        x1.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
        x2.flatten_all().unwrap().to_vec1::<f32>().unwrap()
    );
    assert_eq!(
        y1.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
        y2.flatten_all().unwrap().to_vec1::<f32>().unwrap()
    );
    // Another seed, other weights.
    let d = tempfile::tempdir().unwrap();
    train(d.path(), &cfg, &TrainConfig { seed: 1, ..tc.clone() }, &frames, None, &reg, &Device::Cpu, &mut |_| true)
        .unwrap();
    assert_ne!(w(a.path()), w(d.path()));
}

/// The running statistics of a detector, by name.
fn running_stats(det: &Detector) -> Vec<(String, Vec<f32>)> {
    let data = det.varmap.data().lock().unwrap();
    let mut v: Vec<(String, Vec<f32>)> = data
        .iter()
        .filter(|(k, _)| k.contains("running_"))
        .map(|(k, t)| (k.clone(), t.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// Data-parallel replicas: the same gradients (bytes) on threads of their own as one after the
/// other; equal to candle's gradient of the replicas' mean loss taken through one graph (the
/// oracle, up to the order of summation); BatchNorm's running statistics moved by the first
/// replica alone; and a schedule with replicas trains deterministically, resumes to the weights
/// of an uninterrupted run, and differs from the plain batch (per-replica statistics).
#[test]
fn replicas_average_gradients_deterministically() {
    let cfg = small("centerpoint");
    let reg = Registry::with_builtin();
    let frames = [
        frame(4, &[car(3.0, 2.0, 0.4), ped(-5.0, -3.0)]),
        frame(5, &[car(-6.0, 6.0, 2.0), car(6.0, -7.0, -1.0)]),
        frame(6, &[ped(1.0, 1.0)]),
    ];
    let batches: Vec<HostBatch> = frames
        .iter()
        .enumerate()
        .map(|(r, f)| HostBatch::new(&cfg, std::slice::from_ref(f), false, r as u64))
        .collect();
    type Grads = Vec<Option<Vec<f32>>>;
    let host = |g: &[Option<Tensor>]| -> Grads {
        g.iter().map(|g| g.as_ref().map(|g| g.flatten_all().unwrap().to_vec1::<f32>().unwrap())).collect()
    };
    let run = |pools: &ReplicaPools| {
        let det = build(&cfg, &reg, &Device::Cpu, 0).unwrap();
        let opt = AdamW::new(det.trainable(), 0.01).unwrap();
        let pass = step_pass(&det, &opt, &batches, pools, false).unwrap();
        (host(&pass.grads), pass.total, running_stats(&det))
    };
    let one_after_other = run(&ReplicaPools::sequential());
    // Three replicas on two threads: the second thread runs one, the first two.
    let side_by_side = run(&ReplicaPools::threads(2).unwrap());
    assert_eq!(one_after_other, side_by_side, "threads change the step");

    // The oracle: each replica's forward pass (the later ones with frozen statistics), the
    // mean of their losses, one backward pass through candle's autograd.
    let det = build(&cfg, &reg, &Device::Cpu, 0).unwrap();
    let opt = AdamW::new(det.trainable(), 0.01).unwrap();
    let before = running_stats(&det);
    let mut total: Option<Tensor> = None;
    for (r, b) in batches.iter().enumerate() {
        let pass = || det.loss_all(&det.forward_heads(b, true).unwrap(), &b.targets).unwrap().total;
        let l = if r == 0 { pass() } else { hilo_detector::bnrelu::with_running_stats_frozen(pass) };
        total = Some(match total {
            None => l,
            Some(t) => (t + l).unwrap(),
        });
        if r == 0 {
            assert_eq!(running_stats(&det), one_after_other.2, "the first replica's statistics, the step's");
            assert_ne!(running_stats(&det), before, "training moves the statistics");
        }
    }
    let mean = (total.unwrap() / batches.len() as f64).unwrap();
    let oracle = host(&opt.gradients(&mean.backward().unwrap()));
    assert!((mean.to_scalar::<f32>().unwrap() - one_after_other.1).abs() <= 1e-5 * (1.0 + one_after_other.1.abs()));
    assert_eq!(oracle.len(), one_after_other.0.len());
    let mut compared = 0;
    for (k, (a, b)) in one_after_other.0.iter().zip(&oracle).enumerate() {
        assert_eq!(a.is_some(), b.is_some(), "variable {k}: a gradient on one side only");
        let (Some(a), Some(b)) = (a, b) else { continue };
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 * (1.0 + scale), "variable {k}: {x} vs {y} (oracle)");
        }
        compared += 1;
    }
    assert!(compared > 10, "only {compared} variables had gradients");

    // Whole runs: deterministic, resumable, and not the plain batch.
    let frames: Vec<Frame> =
        (0..6).map(|k| frame(10 + k, &[car(k as f32 - 3.0, 2.0, 0.1 * k as f32), ped(4.0, -(k as f32))])).collect();
    let tc = TrainConfig { samples: 2 * 6, batch: 2, replicas: 2, checkpoint_steps: 2, ..TrainConfig::default() };
    let w = |d: &std::path::Path| std::fs::read(d.join("model.safetensors")).unwrap();
    let (a, b, c) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    train(a.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    train(b.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |r| r.step < 3).unwrap();
    let info = train(b.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    assert!(info.finished && info.step == 6);
    assert_eq!(w(a.path()), w(b.path()), "a resumed run with replicas differs");
    train(c.path(), &cfg, &TrainConfig { replicas: 1, ..tc.clone() }, &frames, None, &reg, &Device::Cpu, &mut |_| true)
        .unwrap();
    assert_ne!(w(a.path()), w(c.path()), "replicas normalise over their own samples");
    // Replicas that do not divide the batch are refused, naming both.
    let d = tempfile::tempdir().unwrap();
    let e = train(d.path(), &cfg, &TrainConfig { replicas: 3, ..tc }, &frames, None, &reg, &Device::Cpu, &mut |_| true)
        .unwrap_err()
        .to_string();
    assert!(e.contains("replicas = 3") && e.contains("batch = 2"), "{e}");
}

/// Two replicas with synchronised BatchNorm train as one batch of two: on frames with as many
/// boxes each (so the mean of the replicas' losses is the batch's loss) and no pillar over the
/// point cap (so no pillar is sampled, differently by each replica's seed) their gradients, loss
/// and running statistics are the plain batch's (to float rounding), the same bytes twice, and
/// not what unsynchronised replicas give. A replica whose frame is empty still meets the other
/// at every BatchNorm layer; too few threads are refused; runs resume byte-identically.
#[test]
fn synchronised_replicas_train_as_one_batch() {
    let mut cfg = small("centerpoint");
    // No pillar over the point cap, so the replicas' pillars are the batch's (no sampling).
    cfg.grid.max_points_per_pillar = 128;
    // One normaliser for all classes: the per-class one divides a class absent from the batch
    // by 1, so the replicas' mean loss would weigh its negatives half as much as the batch does.
    cfg.loss_norm = LossNorm::All;
    let reg = Registry::with_builtin();
    let frames = [frame(7, &[car(3.0, 2.0, 0.4), ped(-5.0, -3.0)]), frame(8, &[car(-6.0, 6.0, 2.0), ped(1.0, 1.0)])];
    let replicas: Vec<HostBatch> = frames
        .iter()
        .enumerate()
        .map(|(r, f)| HostBatch::new(&cfg, std::slice::from_ref(f), false, r as u64))
        .collect();
    let whole = [HostBatch::new(&cfg, &frames, false, 0)];
    type Grads = Vec<Option<Vec<f32>>>;
    let run = |batches: &[HostBatch], pools: &ReplicaPools, sync: bool| {
        let det = build(&cfg, &reg, &Device::Cpu, 0).unwrap();
        let opt = AdamW::new(det.trainable(), 0.01).unwrap();
        let pass = step_pass(&det, &opt, batches, pools, sync).unwrap();
        let grads: Grads =
            pass.grads.iter().map(|g| g.as_ref().map(|g| g.flatten_all().unwrap().to_vec1::<f32>().unwrap())).collect();
        (grads, pass.total, running_stats(&det))
    };
    let synced = run(&replicas, &ReplicaPools::threads(2).unwrap(), true);
    assert_eq!(
        synced,
        run(&replicas, &ReplicaPools::threads(2).unwrap(), true),
        "synchronised replicas are not repeatable"
    );
    let batch = run(&whole, &ReplicaPools::sequential(), false);
    let unsynced = run(&replicas, &ReplicaPools::threads(2).unwrap(), false);
    assert!((synced.1 - batch.1).abs() <= 1e-5 * (1.0 + batch.1.abs()), "loss {} vs {}", synced.1, batch.1);
    for ((name, a), (_, b)) in synced.2.iter().zip(&batch.2) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 * (1.0 + y.abs()), "{name}: {x} vs {y}");
        }
    }
    // The largest gradient difference, relative to the variable's scale.
    let worst = |a: &Grads, b: &Grads| {
        a.iter().zip(b).fold(0f32, |m, (a, b)| match (a, b) {
            (Some(a), Some(b)) => {
                let scale = b.iter().fold(0f32, |s, v| s.max(v.abs())).max(1e-12);
                a.iter().zip(b).fold(m, |m, (x, y)| m.max((x - y).abs() / scale))
            }
            (None, None) => m,
            _ => f32::INFINITY,
        })
    };
    let (d_synced, d_unsynced) = (worst(&synced.0, &batch.0), worst(&unsynced.0, &batch.0));
    assert!(d_synced <= 1e-3, "synchronised replicas' gradients differ from the batch's by {d_synced}");
    assert!(d_unsynced > 100.0 * d_synced, "unsynchronised replicas too close to the batch: {d_unsynced}");

    // A replica with an empty frame takes part with no rows.
    let empty = Frame { sample_token: "e".into(), scene: "s".into(), ..Frame::default() };
    let with_empty = [replicas[0].clone(), HostBatch::new(&cfg, std::slice::from_ref(&empty), false, 1)];
    let r = run(&with_empty, &ReplicaPools::threads(2).unwrap(), true);
    assert!(r.1.is_finite() && r.0.iter().flatten().flatten().all(|g| g.is_finite()));
    // Synchronised replicas one after the other would wait for each other: refused.
    let det = build(&cfg, &reg, &Device::Cpu, 0).unwrap();
    let opt = AdamW::new(det.trainable(), 0.01).unwrap();
    let e = step_pass(&det, &opt, &replicas, &ReplicaPools::sequential(), true).unwrap_err().to_string();
    assert!(e.contains("thread each"), "{e}");

    // Whole runs resume to the same bytes.
    let frames: Vec<Frame> =
        (0..6).map(|k| frame(20 + k, &[car(k as f32 - 3.0, 2.0, 0.1 * k as f32), ped(4.0, -(k as f32))])).collect();
    let tc = TrainConfig {
        samples: 2 * 6,
        batch: 2,
        replicas: 2,
        sync_batch_norm: true,
        checkpoint_steps: 2,
        ..TrainConfig::default()
    };
    let w = |d: &std::path::Path| std::fs::read(d.join("model.safetensors")).unwrap();
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    train(a.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    train(b.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |r| r.step < 3).unwrap();
    let info = train(b.path(), &cfg, &tc, &frames, None, &reg, &Device::Cpu, &mut |_| true).unwrap();
    assert!(info.finished && info.step == 6);
    assert_eq!(w(a.path()), w(b.path()), "a resumed run with synchronised replicas differs");
}

#[test]
fn bad_input_is_a_clear_error() {
    let e = Registry::with_builtin().preset("pointrcnn").unwrap_err().to_string();
    assert!(e.contains("pointrcnn") && e.contains("centerpoint") && e.contains("pointpillars"), "{e}");
    let mut r = Registry::with_builtin();
    fn builder(
        _: serde_json::Value,
        _: candle_nn::VarBuilder,
    ) -> Result<Box<dyn hilo_detector::Fusion>, hilo_detector::FusionError> {
        Err(hilo_detector::FusionError::Config("unused".into()))
    }
    let e = r.register("lidar", Stage::Raw, builder).unwrap_err().to_string();
    assert!(e.contains("twice"), "{e}");
    let mut cfg = small("centerpoint");
    cfg.fusion = "radar-magic".into();
    let e = build(&cfg, &r, &Device::Cpu, 0).unwrap_err().to_string();
    assert!(e.contains("radar-magic") && e.contains("lidar"), "{e}");
    // A checkpoint of another architecture.
    let dir = tempfile::tempdir().unwrap();
    let pp = build(&small("pointpillars"), &r, &Device::Cpu, 0).unwrap();
    let path = dir.path().join("pp.safetensors");
    pp.save(&path).unwrap();
    let mut cp = build(&small("centerpoint"), &r, &Device::Cpu, 0).unwrap();
    let e = cp.load(&path).unwrap_err().to_string();
    assert!(e.contains("another architecture") && e.contains("pp.safetensors"), "{e}");
    // Bad fusion config names the plugin and the field.
    let mut cfg = small("centerpoint");
    cfg.fusion_config = serde_json::json!({ "chanels": 32 });
    let e = build(&cfg, &r, &Device::Cpu, 0).unwrap_err().to_string();
    assert!(e.contains("lidar") && e.contains("chanels"), "{e}");
}

/// The built-in LiDAR-only plugin's presets (`centerpoint`, `pointpillars`) pass the same
/// conformance suite as the plugins' crates run on theirs.
#[test]
fn the_builtin_plugin_passes_the_conformance_suite() {
    hilo_detector::conformance::check_plugin(&Registry::with_builtin(), "lidar").unwrap();
}

/// `velocity_target = "footprint"`: every head cell inside a moving box learns its velocity (the
/// cells of a box share one box's weight), a box of unknown velocity teaches none, the cell
/// between two overlapping boxes learns the nearer one, and `positives` (the default) still
/// supervises the centre cell alone. Then the loss: moving a footprint cell's predicted velocity
/// off its target raises the loss under `footprint` and not under `positives`, the sparse and
/// dense heads agree on it, and per-class normalisation keeps a box's weight at its class's.
#[test]
fn footprint_velocity_targets_cover_the_box_and_enter_the_loss() {
    use hilo_detector::targets::{Assignment, VelocityTarget, build};
    let cfg = dense("centerpoint");
    let (grid, n) = (cfg.grid, cfg.grid.cells());
    let hw = n * n;
    let moving = car(3.0, 2.0, 0.4);
    let still_unknown = GtBox { velocity: [f32::NAN, f32::NAN], ..car(-6.0, -6.0, 0.0) };
    let boxes = [moving, still_unknown];
    let fp = build(&grid, 1, 6, &[&boxes], Assignment::Center, VelocityTarget::Footprint);
    let pos = build(&grid, 1, 6, &[&boxes], Assignment::Center, VelocityTarget::Positives);
    assert!(pos.vel_weight.is_empty() && pos.vel_mask.iter().sum::<f32>() == 1.0);
    // The moving car's cells: 1.9 × 4.6 m over 0.8 m cells, about a dozen.
    let cells: Vec<usize> = (0..hw).filter(|&i| fp.vel_weight[i] > 0.0).collect();
    assert!((8..=20).contains(&cells.len()), "{} cells", cells.len());
    let total: f32 = cells.iter().map(|&i| fp.vel_weight[i]).sum();
    assert!((total - 1.0).abs() < 1e-5, "shares sum to {total}");
    for &i in &cells {
        assert_eq!(
            (fp.reg[8 * hw + i], fp.reg[9 * hw + i], fp.vel_class[i]),
            (moving.velocity[0], moving.velocity[1], 0.0)
        );
    }
    // The unknown box claims its cells with no weight; the other targets are the positives'.
    let claimed: Vec<usize> = (0..hw).filter(|&i| fp.vel_class[i] == 0.0).collect();
    assert!(claimed.len() > cells.len() && claimed.iter().all(|&i| cells.contains(&i) || fp.vel_weight[i] == 0.0));
    assert_eq!((fp.cls.clone(), fp.mask.clone(), fp.num_pos), (pos.cls.clone(), pos.mask.clone(), pos.num_pos));
    // Overlap: two cars side by side 1 m apart; each shared cell learns the nearer centre.
    let (a, b) = (car(0.0, 0.0, 0.0), GtBox { velocity: [-2.0, 0.0], ..car(0.0, 1.0, 0.0) });
    let t = build(&grid, 1, 6, &[&[a, b]], Assignment::Center, VelocityTarget::Footprint);
    for i in (0..hw).filter(|&i| t.vel_class[i] >= 0.0) {
        let y = (i / n) as f32 * grid.cell_m + 0.5 * grid.cell_m - grid.half_extent_m;
        let want = if y.abs() <= (y - 1.0).abs() { a.velocity[0] } else { b.velocity[0] };
        assert_eq!(t.reg[8 * hw + i], want, "cell {i} at y {y}");
    }
    // The loss sees a footprint cell's velocity only under `footprint`, dense or sparse, with
    // either normalisation.
    let loss_at = |c: DetectorConfig| {
        let det = build_detector(&c);
        let b = HostBatch::new(&c, &[frame(1, &boxes)], false, 0);
        let (cls, _) = det.forward(&b, true).unwrap();
        let t = &b.targets;
        let shape = cls.dims().iter().enumerate().map(|(k, d)| if k == 1 { 10 } else { *d }).collect::<Vec<_>>();
        let rows = t.mask.len();
        let at = |i: usize, ch: usize| if cls.rank() == 4 { ch * rows + i } else { i * 10 + ch };
        // A cell learning the moving car's velocity that is not one of its positives.
        let off = (0..rows).find(|&i| t.mask[i] == 0.0 && t.reg[at(i, 8)] == moving.velocity[0]);
        let target = Tensor::from_slice(&t.reg, shape.as_slice(), &Device::Cpu).unwrap();
        let l = |r: &Tensor| det.loss(&cls, r, t).unwrap().reg;
        let moved = off.map(|i| {
            let mut m = t.reg.clone();
            m[at(i, 8)] += 1.0;
            l(&Tensor::from_slice(&m, shape.as_slice(), &Device::Cpu).unwrap())
        });
        (l(&target), moved)
    };
    for c in [cfg.clone(), small("centerpoint")] {
        for norm in [LossNorm::All, LossNorm::PerClass] {
            let with = |f: VelocityTarget| DetectorConfig { velocity_target: f, loss_norm: norm, ..c.clone() };
            let (at, off) = loss_at(with(VelocityTarget::Footprint));
            let off = off.expect("a footprint cell off the centre among the head's cells");
            assert!(at.abs() < 1e-6 && off > 1e-3, "footprint, {norm:?}: {at} then {off}");
            let (at, off) = loss_at(with(VelocityTarget::Positives));
            assert!(at.abs() < 1e-6 && off.is_none(), "positives, {norm:?}: {at}, {off:?}");
        }
    }
}

fn build_detector(cfg: &DetectorConfig) -> Detector {
    build(cfg, &Registry::with_builtin(), &Device::Cpu, 0).unwrap()
}

/// Footprint velocity targets against a brute-force rasterisation: for random boxes (any yaw,
/// sizes from a pedestrian to a bus, some smaller than a cell, some over the grid's edge), the
/// cells that learn a box's velocity are exactly those of the whole grid whose centre lies in
/// its rotated rectangle (its centre cell when none does), each with weight 1 / their count.
#[test]
fn footprint_velocity_cells_match_a_brute_force_rasterisation() {
    use hilo_detector::targets::{Assignment, VelocityTarget, build};
    let grid = dense("centerpoint").grid;
    let (n, cell, half) = (grid.cells(), grid.cell_m, grid.half_extent_m);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    for _ in 0..300 {
        let g = GtBox {
            class: rng.random_range(0..6),
            center: [rng.random_range(-13.0..13.0), rng.random_range(-13.0..13.0), 0.8],
            wlh: [rng.random_range(0.3..3.0), rng.random_range(0.3..12.0), 1.5],
            yaw: rng.random_range(-3.2..3.2),
            velocity: [rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0)],
        };
        let (u, v) = ((g.center[0] + half) / cell, (g.center[1] + half) / cell);
        let t = build(&grid, 1, 6, &[&[g]], Assignment::Center, VelocityTarget::Footprint);
        if !(u >= 0.0 && v >= 0.0 && u < n as f32 && v < n as f32) {
            assert!(t.vel_weight.iter().all(|w| *w == 0.0), "a box off the grid teaches nothing");
            continue;
        }
        let (c, s) = (g.yaw.cos(), g.yaw.sin());
        let mut want: Vec<usize> = (0..n * n)
            .filter(|&i| {
                let (x, y) = (
                    ((i % n) as f32 + 0.5) * cell - half - g.center[0],
                    ((i / n) as f32 + 0.5) * cell - half - g.center[1],
                );
                (x * c + y * s).abs() <= 0.5 * g.wlh[1] && (-x * s + y * c).abs() <= 0.5 * g.wlh[0]
            })
            .collect();
        if want.is_empty() {
            want.push(v as usize * n + u as usize);
        }
        let got: Vec<usize> = (0..n * n).filter(|&i| t.vel_weight[i] > 0.0).collect();
        assert_eq!(got, want, "{g:?}");
        for &i in &got {
            assert!((t.vel_weight[i] - 1.0 / want.len() as f32).abs() < 1e-7);
            assert_eq!((t.reg[8 * n * n + i], t.reg[9 * n * n + i]), (g.velocity[0], g.velocity[1]));
        }
    }
}

/// The detector's loss (fused nodes on the CPU) equals the loss written from the composite
/// functions (focal terms, per-class mean, masked L1 per mask and channel weight), in value and
/// in the gradients of the class and regression maps: dense maps and sparse sites, both
/// normalisations, both assignments, velocity on the positives and on the footprint, and a
/// box of unknown velocity.
#[test]
fn the_fused_loss_equals_the_composite_formula() {
    use hilo_detector::config::VelocityTarget;
    use hilo_detector::loss::{centernet_focal_terms, masked_l1, sigmoid_focal_terms};
    use hilo_detector::targets::Assignment;
    let mut still = car(-6.0, 6.0, 2.0);
    still.velocity = [f32::NAN; 2];
    let frames = vec![frame(1, &[car(2.0, 3.0, 0.3), ped(-4.0, 1.0)]), frame(2, &[still, car(6.0, -7.0, -1.0)])];
    let dev = Device::Cpu;
    let host = |t: &Tensor| -> Vec<f32> { t.flatten_all().unwrap().to_vec1().unwrap() };
    for name in ["centerpoint", "pointpillars"] {
        for base in [dense(name), small(name)] {
            for (norm, target) in [
                (LossNorm::All, VelocityTarget::Positives),
                (LossNorm::PerClass, VelocityTarget::Positives),
                (LossNorm::PerClass, VelocityTarget::Footprint),
                (LossNorm::All, VelocityTarget::Footprint),
            ] {
                let cfg =
                    DetectorConfig { loss_norm: norm, velocity_target: target, velocity_weight: 0.7, ..base.clone() };
                let det = build(&cfg, &Registry::with_builtin(), &dev, 0).unwrap();
                let b = HostBatch::new(&cfg, &frames, false, 0);
                let t = &b.targets;
                let (cls, reg) = det.forward(&b, true).unwrap();
                let (cls, reg) = (host(&cls), host(&reg));
                let (cv, rv) = (
                    candle_core::Var::from_slice(&cls, det.forward(&b, false).unwrap().0.shape(), &dev).unwrap(),
                    candle_core::Var::from_slice(&reg, det.forward(&b, false).unwrap().1.shape(), &dev).unwrap(),
                );
                let fused = det.loss(cv.as_tensor(), rv.as_tensor(), t).unwrap();
                // The same loss from the composite functions.
                let (c, r) = (
                    candle_core::Var::from_slice(&cls, cv.shape(), &dev).unwrap(),
                    candle_core::Var::from_slice(&reg, rv.shape(), &dev).unwrap(),
                );
                let k = cv.dim(1).unwrap();
                let is_dense = cv.rank() == 4;
                let mask_shape: Vec<usize> = if is_dense {
                    vec![cv.dim(0).unwrap(), 1, cv.dim(2).unwrap(), cv.dim(3).unwrap()]
                } else {
                    vec![cv.dim(0).unwrap(), 1]
                };
                let cw_shape: Vec<usize> = if is_dense { vec![1, 10, 1, 1] } else { vec![1, 10] };
                let vw = 0.7f32;
                let cw_box =
                    Tensor::from_slice(&[1f32, 1., 1., 1., 1., 1., 1., 1., 0., 0.], cw_shape.as_slice(), &dev).unwrap();
                let cw_vel =
                    Tensor::from_slice(&[0f32, 0., 0., 0., 0., 0., 0., 0., vw, vw], cw_shape.as_slice(), &dev).unwrap();
                let tc = Tensor::from_slice(&t.cls, cv.shape(), &dev).unwrap();
                let tr = Tensor::from_slice(&t.reg, rv.shape(), &dev).unwrap();
                let terms = match cfg.assignment {
                    Assignment::Center => centernet_focal_terms(c.as_tensor(), &tc).unwrap(),
                    Assignment::Inside => sigmoid_focal_terms(c.as_tensor(), &tc).unwrap(),
                };
                let mk = |v: Vec<f32>| Tensor::from_vec(v, mask_shape.as_slice(), &dev).unwrap();
                let (lc, lr) = match norm {
                    LossNorm::All => {
                        let n = t.num_pos.max(1.0);
                        let vm = if t.vel_weight.is_empty() { t.vel_mask.clone() } else { t.vel_weight.clone() };
                        (
                            (terms.sum_all().unwrap() / n as f64).unwrap(),
                            (masked_l1(r.as_tensor(), &tr, &mk(t.mask.clone()), &cw_box, n).unwrap()
                                + masked_l1(r.as_tensor(), &tr, &mk(vm), &cw_vel, n).unwrap())
                            .unwrap(),
                        )
                    }
                    LossNorm::PerClass => {
                        let sw = t.per_class_site_weights(k, is_dense);
                        let vel: Vec<f32> = if t.vel_weight.is_empty() {
                            sw.iter().zip(&t.vel_mask).map(|(w, m)| w * m).collect()
                        } else {
                            t.per_class_velocity_weights(k)
                        };
                        (
                            per_class_mean(&terms, &t.pos_per_class).unwrap(),
                            (masked_l1(r.as_tensor(), &tr, &mk(sw), &cw_box, 1.0).unwrap()
                                + masked_l1(r.as_tensor(), &tr, &mk(vel), &cw_vel, 1.0).unwrap())
                            .unwrap(),
                        )
                    }
                };
                let what = format!("{name} {} {norm:?} {target:?}", if is_dense { "dense" } else { "sparse" });
                let (rc, rr) = (lc.to_scalar::<f32>().unwrap(), lr.to_scalar::<f32>().unwrap());
                assert!(rr > 0.0 && rc > 0.0, "{what}: a loss to compare ({rc}, {rr})");
                assert!((fused.cls - rc).abs() <= 1e-5 * rc, "{what}: class loss {} vs {rc}", fused.cls);
                assert!((fused.reg - rr).abs() <= 1e-5 * rr, "{what}: regression loss {} vs {rr}", fused.reg);
                let total = (&lc + (&lr * 0.25).unwrap()).unwrap();
                let (g, gr) = (fused.total.backward().unwrap(), total.backward().unwrap());
                for (a, b, part) in [(&cv, &c, "class"), (&rv, &r, "regression")] {
                    let (x, y) = (host(g.get(a.as_tensor()).unwrap()), host(gr.get(b.as_tensor()).unwrap()));
                    let scale = y.iter().fold(0f32, |m, v| m.max(v.abs()));
                    let worst = x.iter().zip(&y).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
                    assert!(
                        scale > 0.0 && worst <= 1e-5 * scale,
                        "{what}: {part} gradient off by {worst} (scale {scale})"
                    );
                }
            }
        }
    }
}
