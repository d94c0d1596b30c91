//! Training on CPU: AdamW with a one-cycle schedule and gradient clipping, batches prepared on
//! another thread, checkpoints (weights, optimizer state, progress) after every epoch and every
//! `checkpoint_steps`, exact resume, and the same weights from the same seed.
//!
//! Budgets are counted in samples, not epochs (a time limit would make the weights depend on the
//! machine's load): on two cores the default detector trains at about 6 samples/s, so the
//! default schedule is 1,400 samples (234 s measured). Presets with a second branch at full
//! resolution are slower per sample; [`TrainConfig::for_preset`] gives each preset the samples
//! that fit the same 5 minutes.
//!
//! At such budgets the number of updates matters more than their precision: batches of 2 at a
//! peak learning rate of 6e-3 train `centerpoint` on the default dataset to mAP 0.171 in 600
//! samples (107 s), where batches of 4 at 3e-3 reach 0.040 in the same samples and time (6e-3
//! alone: 0.086; batches of 2 alone: 0.115), and `lirafusion-like` to 0.200. A CPU step costs
//! the same per sample at either batch size.

use crate::data::{Augmentation, Frame};
use crate::detector::{Detector, DetectorConfig, HostBatch};
use crate::error::{FusionError, Result};
use crate::fusion::Registry;
use candle_core::{Device, Tensor, Var};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Training samples to see in total (steps × batch).
    pub samples: usize,
    pub batch: usize,
    pub lr_max: f64,
    pub weight_decay: f64,
    /// Global gradient-norm limit.
    pub clip_norm: f64,
    /// Share of the schedule spent warming up (one-cycle).
    pub warmup: f64,
    pub seed: u64,
    pub augmentation: Augmentation,
    pub checkpoint_steps: usize,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            samples: 1400,
            batch: 2,
            lr_max: 6e-3,
            weight_decay: 0.01,
            clip_norm: 10.0,
            warmup: 0.3,
            seed: 0,
            augmentation: Augmentation::default(),
            checkpoint_steps: 50,
        }
    }
}

impl TrainConfig {
    /// The default schedule of a preset: as many samples as it trains in under 5 minutes on a
    /// 2-core CPU (measured on the default dataset, see the README's detector table: `l4dr-like`
    /// 4.4 samples/s, `lirafusion-like` 5.0, `bi-lrfusion-like` 3.7, `late` 3.3, so 241–276 s;
    /// the others, 6.0–8.7 samples/s, keep 1,400). Unknown names (a detector of one's own) get
    /// the default.
    pub fn for_preset(name: &str) -> TrainConfig {
        let samples = match name {
            "l4dr-like" | "l4dr-like-no-early" => 1100,
            "lirafusion-like" | "lirafusion-like-no-early" => 1200,
            "bi-lrfusion-like" | "late" => 900,
            _ => TrainConfig::default().samples,
        };
        TrainConfig { samples, ..TrainConfig::default() }
    }

    pub fn steps(&self) -> usize {
        self.samples.div_ceil(self.batch.max(1))
    }

    /// One-cycle learning rate at `step` (cosine up from lr_max/10, cosine down to lr_max/1e4).
    pub fn lr(&self, step: usize) -> f64 {
        let total = self.steps().max(1) as f64;
        let up = (self.warmup * total).max(1.0);
        let t = step as f64;
        let cos = |a: f64, b: f64, f: f64| b + (a - b) * 0.5 * (1.0 + (std::f64::consts::PI * f.clamp(0.0, 1.0)).cos());
        if t < up {
            cos(self.lr_max / 10.0, self.lr_max, t / up)
        } else {
            cos(self.lr_max, self.lr_max / 1e4, (t - up) / (total - up).max(1.0))
        }
    }
}

/// AdamW (decoupled weight decay) with its state kept for checkpoints.
#[derive(Debug)]
pub struct AdamW {
    vars: Vec<(String, Var)>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    pub step: usize,
    weight_decay: f64,
}

impl AdamW {
    pub fn new(vars: Vec<(String, Var)>, weight_decay: f64) -> Result<Self> {
        let m = vars.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
        let v2 = vars.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
        Ok(AdamW { vars, m, v: v2, step: 0, weight_decay })
    }

    /// One update; returns the gradient norm before clipping.
    pub fn step(&mut self, grads: &candle_core::backprop::GradStore, lr: f64, clip: f64) -> Result<f64> {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
        let mut sq = 0.0f64;
        // Gradients, moments and updates carry no graph: detached, so nothing accumulates.
        let gs: Vec<Option<Tensor>> = self.vars.iter().map(|(_, v)| grads.get(v).map(|g| g.detach())).collect();
        for g in gs.iter().flatten() {
            sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
        }
        let norm = sq.sqrt();
        let scale = if norm.is_finite() && norm > clip { clip / norm } else { 1.0 };
        if !norm.is_finite() {
            return Err(FusionError::Config(format!("gradient norm is {norm} at step {}", self.step)));
        }
        self.step += 1;
        let t = self.step as i32;
        let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        for (k, g) in gs.iter().enumerate() {
            let Some(g) = g else { continue };
            let g = (g * scale)?;
            self.m[k] = ((&self.m[k] * b1)? + (&g * (1.0 - b1))?)?.detach();
            self.v[k] = ((&self.v[k] * b2)? + (g.sqr()? * (1.0 - b2))?)?.detach();
            let var = &self.vars[k].1;
            let update = ((&self.m[k] / c1)? / ((&self.v[k] / c2)?.sqrt()? + eps)?)?;
            let next = ((var.as_tensor().detach() * (1.0 - lr * self.weight_decay))? - (update * lr)?)?;
            var.set(&next)?;
        }
        Ok(norm)
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        let mut map: HashMap<String, Tensor> = HashMap::new();
        for (k, (name, _)) in self.vars.iter().enumerate() {
            map.insert(format!("m.{name}"), self.m[k].clone());
            map.insert(format!("v.{name}"), self.v[k].clone());
        }
        map.insert(
            "step".into(),
            Tensor::new(&[self.step as u32], self.m.first().map_or(&Device::Cpu, |t| t.device()))?,
        );
        let tmp = path.with_extension("safetensors.tmp");
        candle_core::safetensors::save(&map, &tmp)?;
        std::fs::rename(&tmp, path).map_err(|e| FusionError::Io { path: path.to_path_buf(), message: e.to_string() })
    }

    pub fn load(&mut self, path: &Path, device: &Device) -> Result<()> {
        let t = candle_core::safetensors::load(path, device)
            .map_err(|e| FusionError::Checkpoint { path: path.to_path_buf(), message: e.to_string() })?;
        let get = |n: &str| {
            t.get(n).cloned().ok_or_else(|| FusionError::Checkpoint {
                path: path.to_path_buf(),
                message: format!("optimizer state has no {n:?}"),
            })
        };
        for (k, (name, _)) in self.vars.iter().enumerate() {
            self.m[k] = get(&format!("m.{name}"))?;
            self.v[k] = get(&format!("v.{name}"))?;
        }
        self.step = get("step")?.to_vec1::<u32>()?.first().copied().unwrap_or(0) as usize;
        Ok(())
    }
}

/// What a run folder holds besides the weights.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunInfo {
    pub detector: DetectorConfig,
    pub train: TrainConfig,
    pub step: usize,
    pub samples_seen: usize,
    pub seconds: f64,
    pub finished: bool,
}

pub fn weights_path(run: &Path) -> PathBuf {
    run.join("model.safetensors")
}

fn optimizer_path(run: &Path) -> PathBuf {
    run.join("optimizer.safetensors")
}

fn info_path(run: &Path) -> PathBuf {
    run.join("run.json")
}

pub fn read_info(run: &Path) -> Result<RunInfo> {
    let p = info_path(run);
    let bytes = std::fs::read(&p)
        .map_err(|e| FusionError::Io { path: p.clone(), message: format!("{e} (not a training run folder?)") })?;
    serde_json::from_slice(&bytes).map_err(|e| FusionError::Checkpoint { path: p, message: e.to_string() })
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(value)
        .map_err(|e| FusionError::Io { path: path.to_path_buf(), message: e.to_string() })?;
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, bytes).map_err(|e| FusionError::Io { path: tmp.clone(), message: e.to_string() })?;
    std::fs::rename(&tmp, path).map_err(|e| FusionError::Io { path: path.to_path_buf(), message: e.to_string() })
}

/// Progress of a training run, reported after every step.
#[derive(Clone, Copy, Debug)]
pub struct StepReport {
    pub step: usize,
    pub steps: usize,
    pub loss: f32,
    pub cls: f32,
    pub reg: f32,
    pub lr: f64,
    pub samples_per_s: f64,
}

/// The frames of step `step`: a deterministic shuffle per epoch, augmented with a per-sample
/// seed, so that resuming at any step sees exactly what an uninterrupted run sees.
fn step_frames(frames: &[Frame], cfg: &TrainConfig, step: usize) -> Vec<Frame> {
    let n = frames.len();
    let mut out = Vec::with_capacity(cfg.batch);
    for i in 0..cfg.batch {
        let k = step * cfg.batch + i;
        let (epoch, pos) = (k / n, k % n);
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed ^ (epoch as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
        ));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed.wrapping_add(1 + k as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9),
        );
        out.push(cfg.augmentation.apply(&frames[order[pos]], &mut rng));
    }
    out
}

/// Trains (or resumes) a detector in `run`. Batches are prepared one step ahead on another
/// thread. `on_step` returning false stops the run after a checkpoint (rerunning resumes it).
/// Returns the run's info.
pub fn train(
    run: &Path,
    det_cfg: &DetectorConfig,
    cfg: &TrainConfig,
    frames: &[Frame],
    registry: &Registry,
    device: &Device,
    on_step: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<RunInfo> {
    if frames.is_empty() {
        return Err(FusionError::Config("no training frames".into()));
    }
    if cfg.batch == 0 || cfg.samples == 0 {
        return Err(FusionError::Config(format!(
            "train: batch = {} and samples = {} must be positive",
            cfg.batch, cfg.samples
        )));
    }
    std::fs::create_dir_all(run).map_err(|e| FusionError::Io { path: run.to_path_buf(), message: e.to_string() })?;
    let mut det = Detector::new(det_cfg, registry, device, cfg.seed)?;
    let mut opt = AdamW::new(det.trainable(), cfg.weight_decay)?;
    let mut info = RunInfo {
        detector: det_cfg.clone(),
        train: cfg.clone(),
        step: 0,
        samples_seen: 0,
        seconds: 0.0,
        finished: false,
    };
    if info_path(run).exists() {
        let old = read_info(run)?;
        if old.detector != *det_cfg || old.train != *cfg {
            return Err(FusionError::Config(format!(
                "{} holds a run with other settings (detector {}); use another --out or delete it",
                run.display(),
                old.detector.name
            )));
        }
        if old.step > 0 {
            det.load(&weights_path(run))?;
            opt.load(&optimizer_path(run), device)?;
        }
        info = old;
        if info.finished {
            return Ok(info);
        }
    }
    let steps = cfg.steps();
    let with_radar = det.uses_radar();
    let start = info.step;
    let epoch_steps = frames.len().div_ceil(cfg.batch).max(1);
    let t_run = std::time::Instant::now();
    let seconds_before = info.seconds;
    std::thread::scope(|scope| -> Result<()> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<HostBatch>(2);
        scope.spawn(move || {
            for step in start..steps {
                let b = HostBatch::new(det_cfg, &step_frames(frames, cfg, step), with_radar);
                if tx.send(b).is_err() {
                    return;
                }
            }
        });
        let mut window = std::time::Instant::now();
        for step in start..steps {
            let batch = rx.recv().map_err(|_| FusionError::Config("the batch thread stopped".into()))?;
            let heads = det.forward_heads(&batch, true)?;
            let loss = det.loss_all(&heads, &batch.targets)?;
            let grads = loss.total.backward()?;
            let lr = cfg.lr(step);
            opt.step(&grads, lr, cfg.clip_norm)?;
            let total = loss.total.to_scalar::<f32>()?;
            if !total.is_finite() {
                return Err(FusionError::Config(format!("loss is {total} at step {step}")));
            }
            let dt = window.elapsed().as_secs_f64();
            window = std::time::Instant::now();
            info.step = step + 1;
            info.samples_seen = info.step * cfg.batch;
            let go_on = on_step(&StepReport {
                step: step + 1,
                steps,
                loss: total,
                cls: loss.cls,
                reg: loss.reg,
                lr,
                samples_per_s: cfg.batch as f64 / dt.max(1e-9),
            });
            let end_of_epoch = (step + 1) % epoch_steps == 0;
            if !go_on || end_of_epoch || (step + 1) % cfg.checkpoint_steps.max(1) == 0 || step + 1 == steps {
                info.seconds = seconds_before + t_run.elapsed().as_secs_f64();
                info.finished = step + 1 == steps;
                det.save(&weights_path(run))?;
                opt.save(&optimizer_path(run))?;
                write_json(&info_path(run), &info)?;
            }
            if !go_on {
                break;
            }
        }
        Ok(())
    })?;
    Ok(info)
}

/// A trained detector from a run folder.
pub fn load_run(run: &Path, registry: &Registry, device: &Device) -> Result<(Detector, RunInfo)> {
    let info = read_info(run)?;
    let mut det = Detector::new(&info.detector, registry, device, 0)?;
    det.load(&weights_path(run))?;
    Ok((det, info))
}
