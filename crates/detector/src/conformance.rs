//! The conformance suite every fusion plugin runs by adding one line to its tests:
//! `hilo_detector::conformance::check(&registry, &config)`. On both layouts (dense maps and the
//! sparse occupied cells) it checks output shapes, that gradients reach every parameter,
//! save/load identity, determinism with a seed, and finite losses on an empty radar frame, a
//! radar-only frame and a frame with no points at all. It also provides the synthetic frames
//! the suites use.

use crate::data::{Frame, GtBox};
use crate::detector::{Detector, DetectorConfig, HostBatch};
use crate::error::DetectorError;
use crate::fusion::Registry;
pub use crate::grid::small_grid;
use candle_core::Device;
use rand::{Rng, SeedableRng};

/// A frame with LiDAR points on the boxes' surfaces and on the ground, and radar detections on
/// the boxes carrying their radial velocity seen from a radar at `radar_at` (and a few static
/// clutter detections).
pub fn synthetic_frame(seed: u64, boxes: &[GtBox], lidar: bool, radar: bool) -> Frame {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let radar_at = [0.0f32, -14.0, 5.0];
    let mut lp = Vec::new();
    let mut rp = Vec::new();
    if lidar {
        for _ in 0..500 {
            lp.push([
                rng.random_range(-12.5..12.5),
                rng.random_range(-12.5..12.5),
                rng.random_range(-0.05..0.05),
                0.1,
                0.0,
            ]);
        }
    }
    for b in boxes {
        let (c, s) = (b.yaw.cos(), b.yaw.sin());
        let on_box = |rng: &mut rand_chacha::ChaCha8Rng| {
            let (u, v, h) = (
                rng.random_range(-0.5..0.5) * b.wlh[1],
                rng.random_range(-0.5..0.5) * b.wlh[0],
                rng.random_range(0.0..1.0) * b.wlh[2],
            );
            [b.center[0] + c * u - s * v, b.center[1] + s * u + c * v, b.center[2] - 0.5 * b.wlh[2] + h]
        };
        if lidar {
            for _ in 0..60 {
                let p = on_box(&mut rng);
                lp.push([p[0], p[1], p[2], 0.6, 0.0]);
            }
        }
        if radar {
            for _ in 0..8 {
                let p = on_box(&mut rng);
                let (dx, dy) = (p[0] - radar_at[0], p[1] - radar_at[1]);
                let n = (dx * dx + dy * dy).sqrt().max(1e-3);
                let (lx, ly) = (dx / n, dy / n);
                let vr = b.velocity[0] * lx + b.velocity[1] * ly + rng.random_range(-0.05..0.05);
                rp.push(crate::data::radar_point(p, rng.random_range(5.0..12.0), vr, [lx, ly], 0.0));
            }
        }
    }
    if radar {
        for _ in 0..10 {
            let (x, y) = (rng.random_range(-12.5f32..12.5), rng.random_range(-12.5f32..12.5));
            let n = ((x - radar_at[0]).powi(2) + (y - radar_at[1]).powi(2)).sqrt().max(1e-3);
            let los = [(x - radar_at[0]) / n, (y - radar_at[1]) / n];
            rp.push(crate::data::radar_point([x, y, 0.2], rng.random_range(-5.0..5.0), 0.0, los, 0.0));
        }
    }
    Frame {
        sample_token: format!("synthetic-{seed}"),
        scene: "synthetic".into(),
        lidar: lp,
        radar: rp,
        radar_origin: Vec::new(),
        boxes: boxes.to_vec(),
    }
}

pub fn car(x: f32, y: f32, yaw: f32, speed: f32) -> GtBox {
    GtBox { class: 0, center: [x, y, 0.8], wlh: [1.9, 4.6, 1.6], yaw, velocity: [speed * yaw.cos(), speed * yaw.sin()] }
}

/// A conformance failure: the detector (with its layout) and the step that failed or the
/// property that does not hold.
#[derive(Debug, thiserror::Error)]
pub enum ConformanceError {
    /// A step of the suite (building, a forward pass, saving, ...) that returned an error.
    #[error("conformance of {detector}: {step}: {source}")]
    Step { detector: String, step: String, source: Box<DetectorError> },
    /// A property the suite asserts (shapes, gradients, round trips, determinism) that fails.
    #[error("conformance of {detector}: {property}")]
    Property { detector: String, property: String },
    /// A plugin that no preset of the registry uses, so the suite has nothing to build.
    #[error("conformance of plugin {plugin:?}: no preset uses it")]
    NoPreset { plugin: String },
}

fn fail(name: &str, what: impl std::fmt::Display) -> ConformanceError {
    ConformanceError::Property { detector: name.to_owned(), property: what.to_string() }
}

/// Runs the suite on `cfg` (its grid replaced by [`small_grid`]), dense and sparse.
pub fn check(registry: &Registry, cfg: &DetectorConfig) -> Result<(), ConformanceError> {
    let mut cfg = cfg.clone();
    cfg.grid = small_grid();
    let sparse = cfg.sparse.clone().unwrap_or_default();
    check_one(registry, &DetectorConfig { sparse: None, ..cfg.clone() })?;
    check_one(registry, &DetectorConfig { sparse: Some(sparse), ..cfg })
}

fn check_one(registry: &Registry, cfg: &DetectorConfig) -> Result<(), ConformanceError> {
    let name = format!("{} ({})", cfg.name, if cfg.sparse.is_some() { "sparse" } else { "dense" });
    let e = |what: &str, err: DetectorError| ConformanceError::Step {
        detector: name.clone(),
        step: what.to_owned(),
        source: Box::new(err),
    };
    let cfg = cfg.clone().validate().map_err(|x| e("config", x.into()))?;
    let dev = Device::Cpu;
    let det = Detector::new(&cfg, registry, &dev, 7).map_err(|x| e("build", x))?;
    let boxes = [car(2.0, 3.0, 0.3, 6.0), car(-5.0, -4.0, 1.2, 0.0)];
    let frames = vec![synthetic_frame(1, &boxes, true, true), synthetic_frame(2, &boxes[..1], true, true)];
    let b = HostBatch::new(&cfg, &frames, det.uses_radar(), 0);
    // Shapes.
    let heads = det.forward_heads(&b, true).map_err(|x| e("forward", x))?;
    let n = cfg.grid.cells() / cfg.backbone.out_stride;
    let (want_cls, want_reg) = match &b.sparse {
        None => (vec![2, 6, n, n], vec![2, 10, n, n]),
        Some(h) => (vec![h.head_sites.len(), 6], vec![h.head_sites.len(), 10]),
    };
    for (cls, reg) in &heads {
        if cls.dims() != want_cls || reg.dims() != want_reg {
            return Err(fail(
                &name,
                format!("output shapes {:?} and {:?}, expected {want_cls:?} and {want_reg:?}", cls.dims(), reg.dims()),
            ));
        }
    }
    // Gradients reach every parameter.
    let loss = det.loss_all(&heads, &b.targets).map_err(|x| e("loss", x))?;
    let grads = loss.total.backward().map_err(|x| e("backward", x.into()))?;
    for (vn, v) in det.trainable() {
        let g = grads.get(&v).ok_or_else(|| fail(&name, format!("no gradient reaches {vn}")))?;
        let s = g
            .abs()
            .and_then(|a| a.sum_all())
            .and_then(|a| a.to_scalar::<f32>())
            .map_err(|x| e("gradient", x.into()))?;
        if !(s.is_finite() && s > 0.0) {
            return Err(fail(&name, format!("gradient of {vn} is {s}")));
        }
    }
    // Save → load identity, and determinism with a seed.
    let dir = tempfile_dir().map_err(|x| e("a scratch folder", x.into()))?;
    let path = dir.join("weights.safetensors");
    det.save(&path).map_err(|x| e("save", x))?;
    let mut other = Detector::new(&cfg, registry, &dev, 8).map_err(|x| e("build", x))?;
    other.load(&path).map_err(|x| e("load", x))?;
    let same = Detector::new(&cfg, registry, &dev, 7).map_err(|x| e("build", x))?;
    let out = |d: &Detector| -> Result<Vec<f32>, ConformanceError> {
        let mut v = Vec::new();
        for (c, r) in d.forward_heads(&b, false).map_err(|x| e("forward", x))? {
            v.extend(c.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|x| e("read", x.into()))?);
            v.extend(r.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|x| e("read", x.into()))?);
        }
        Ok(v)
    };
    let (o1, o2) = (out(&det)?, out(&other)?);
    if o1 != o2 {
        return Err(fail(&name, "outputs differ after save and load"));
    }
    let fresh = Detector::new(&cfg, registry, &dev, 7).map_err(|x| e("build", x))?;
    if out(&fresh)? != out(&same)? {
        return Err(fail(&name, "two detectors built with the same seed differ"));
    }
    let _ = std::fs::remove_dir_all(&dir);
    // Hard frames: no radar, radar only, nothing at all.
    for (what, f) in [
        ("an empty radar frame", synthetic_frame(3, &boxes, true, false)),
        ("a radar-only frame", synthetic_frame(4, &boxes, false, true)),
        ("a frame with no points", synthetic_frame(5, &boxes, false, false)),
    ] {
        let hb = HostBatch::new(&cfg, std::slice::from_ref(&f), det.uses_radar(), 0);
        let heads = det.forward_heads(&hb, true).map_err(|x| e(what, x))?;
        let l = det.loss_all(&heads, &hb.targets).map_err(|x| e(what, x))?;
        let v = l.total.to_scalar::<f32>().map_err(|x| e(what, x.into()))?;
        if !v.is_finite() {
            return Err(fail(&name, format!("loss on {what} is {v}")));
        }
        det.detect(&hb).map_err(|x| e(what, x))?;
    }
    // Synchronised BatchNorm: replicas of those frames, one thread each, meet at every
    // BatchNorm layer (a plugin that skips an empty modality must still take part, with no
    // rows) and give finite gradients.
    let replicas: Vec<HostBatch> = [
        synthetic_frame(6, &boxes, true, true),
        synthetic_frame(3, &boxes, true, false),
        synthetic_frame(4, &boxes, false, true),
        synthetic_frame(5, &boxes, false, false),
    ]
    .iter()
    .enumerate()
    .map(|(r, f)| HostBatch::new(&cfg, std::slice::from_ref(f), det.uses_radar(), r as u64))
    .collect();
    let opt = crate::train::AdamW::new(det.trainable(), 0.01).map_err(|x| e("optimizer", x))?;
    let pools = crate::train::ReplicaPools::threads(replicas.len()).map_err(|x| e("replica threads", x))?;
    let pass = crate::train::step_pass(&det, &opt, &replicas, &pools, true)
        .map_err(|x| e("a step of synchronised replicas", x))?;
    for g in pass.grads.iter().flatten() {
        let s = g
            .abs()
            .and_then(|a| a.sum_all())
            .and_then(|a| a.to_scalar::<f32>())
            .map_err(|x| e("gradient", x.into()))?;
        if !s.is_finite() {
            return Err(fail(&name, format!("a synchronised replicas' gradient sums to {s}")));
        }
    }
    Ok(())
}

fn tempfile_dir() -> Result<std::path::PathBuf, hilo_core::fs::FileError> {
    let d =
        std::env::temp_dir().join(format!("hilo-conformance-{}-{:?}", std::process::id(), std::thread::current().id()));
    std::fs::create_dir_all(&d).map_err(|x| hilo_core::fs::FileError::io(&d, x))?;
    Ok(d)
}

/// Runs the suite on every preset registered for `plugin`; a plugin with no preset fails.
pub fn check_plugin(registry: &Registry, plugin: &str) -> Result<(), ConformanceError> {
    let names: Vec<String> = registry
        .preset_names()
        .into_iter()
        .filter(|n| registry.preset(n).is_ok_and(|p| p.detector.fusion == plugin))
        .collect();
    if names.is_empty() {
        return Err(ConformanceError::NoPreset { plugin: plugin.to_owned() });
    }
    for n in names {
        let p = registry.preset(&n).map_err(|e| ConformanceError::Step {
            detector: n.clone(),
            step: "the preset".into(),
            source: Box::new(e.into()),
        })?;
        check(registry, &p.detector)?;
    }
    Ok(())
}
