//! Training on CPU: AdamW with a one-cycle schedule and gradient clipping, batches prepared on
//! another thread, checkpoints (weights, optimizer state, progress) after every epoch and every
//! `checkpoint_steps`, exact resume, and the same weights from the same seed.
//!
//! Budgets are counted in samples, not epochs (a time limit would make the weights depend on the
//! machine's load); each preset's default schedule is registered with it (see the fusion crate's
//! docs for how they were chosen).

use crate::bnrelu::BatchNormSync;
use crate::data::Frame;
use crate::detector::{Detector, DetectorConfig, HostBatch};
use crate::error::{DetectorError, Result};
use crate::fusion::Registry;
use crate::paste::PasteDb;
use candle_core::{Device, Tensor, Var};
use hilo_core::Valid;
use hilo_dataset::background::BackgroundModel;
pub use hilo_fusion::config::{Sampling, TrainConfig};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The frames of one epoch before shuffling: every frame once (uniform), or CBGS's
/// class-balanced draw with replacement, deterministic in `seed`. Each class c present in
/// `S_c` frames contributes `⌊Σ|S_c| / C⌋` draws from `S_c`.
pub fn epoch_frames(frames: &[Frame], sampling: Sampling, seed: u64) -> Vec<usize> {
    match sampling {
        Sampling::Uniform => (0..frames.len()).collect(),
        Sampling::ClassBalanced => {
            let k = hilo_core::Class::ALL.len();
            let mut holding: Vec<Vec<usize>> = vec![Vec::new(); k];
            for (i, f) in frames.iter().enumerate() {
                let mut seen = [false; 16];
                for b in &f.boxes {
                    if b.class < k && !seen[b.class] {
                        seen[b.class] = true;
                        holding[b.class].push(i);
                    }
                }
            }
            let present: Vec<&Vec<usize>> = holding.iter().filter(|v| !v.is_empty()).collect();
            if present.is_empty() {
                return (0..frames.len()).collect();
            }
            let total: usize = present.iter().map(|v| v.len()).sum();
            let per_class = (total / present.len()).max(1);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xcb65_cb65);
            let mut out = Vec::with_capacity(per_class * present.len());
            for v in present {
                for _ in 0..per_class {
                    out.push(v[rand::Rng::random_range(&mut rng, 0..v.len())]);
                }
            }
            out
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
    /// Update each f32 CPU variable and its moments in place ([`fused`]) rather than through
    /// candle's element-wise operations; the same values either way.
    fused: bool,
}

/// Whether new optimizers update in place ([`AdamW::with_fused`]); a benchmark's before/after
/// lever (`hilo bench train --variant optimizer=composite`).
static FUSED_DEFAULT: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(true);

impl AdamW {
    pub fn new(vars: Vec<(String, Var)>, weight_decay: f64) -> Result<Self> {
        let m = vars.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
        let v2 = vars.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
        let fused = FUSED_DEFAULT.load(std::sync::atomic::Ordering::Relaxed);
        Ok(AdamW { vars, m, v: v2, step: 0, weight_decay, fused })
    }

    /// The update in place (true) or through candle's operations (false), for this optimizer.
    pub fn with_fused(mut self, fused: bool) -> Self {
        self.fused = fused;
        self
    }

    /// Whether optimizers created from now on update in place (the default) or not.
    pub fn set_fused_default(fused: bool) {
        FUSED_DEFAULT.store(fused, std::sync::atomic::Ordering::Relaxed);
    }

    /// One update; returns the gradient norm before clipping.
    pub fn step(&mut self, grads: &candle_core::backprop::GradStore, lr: f64, clip: f64) -> Result<f64> {
        let gs = self.gradients(grads);
        self.step_with(&gs, lr, clip)
    }

    /// The gradient of each variable in `grads`, in the optimizer's order, detached (gradients,
    /// moments and updates carry no graph, so nothing accumulates).
    pub fn gradients(&self, grads: &candle_core::backprop::GradStore) -> Vec<Option<Tensor>> {
        self.vars.iter().map(|(_, v)| grads.get(v).map(|g| g.detach())).collect()
    }

    /// One update from gradients in the optimizer's order ([`Self::gradients`]).
    pub fn step_with(&mut self, gs: &[Option<Tensor>], lr: f64, clip: f64) -> Result<f64> {
        if gs.len() != self.vars.len() {
            return Err(DetectorError::Config(format!("{} gradients for {} variables", gs.len(), self.vars.len())));
        }
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
        let mut sq = 0.0f64;
        for g in gs.iter().flatten() {
            sq += g.sqr()?.sum_all()?.to_scalar::<f32>()? as f64;
        }
        let norm = sq.sqrt();
        let scale = if norm.is_finite() && norm > clip { clip / norm } else { 1.0 };
        if !norm.is_finite() {
            return Err(DetectorError::Config(format!("gradient norm is {norm} at step {}", self.step)));
        }
        self.step += 1;
        let t = self.step as i32;
        let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        for (k, g) in gs.iter().enumerate() {
            let Some(g) = g else { continue };
            let var = &self.vars[k].1;
            if self.fused && fused::applies(var.as_tensor(), &self.m[k], &self.v[k], g) {
                let (c1, c2) = (1.0 / c1, 1.0 / c2);
                self.m[k].inplace_op2(g, &fused::Moment { scale, beta: b1, squared: false })?;
                self.v[k].inplace_op2(g, &fused::Moment { scale, beta: b2, squared: true })?;
                let update = fused::Update { c1, c2, eps, lr, weight_decay: self.weight_decay };
                var.as_tensor().inplace_op3(&self.m[k], &self.v[k], &update)?;
                continue;
            }
            let g = (g * scale)?;
            self.m[k] = ((&self.m[k] * b1)? + (&g * (1.0 - b1))?)?.detach();
            self.v[k] = ((&self.v[k] * b2)? + (g.sqr()? * (1.0 - b2))?)?.detach();
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
        hilo_core::fs::write_atomic_with(
            path,
            |tmp| candle_core::safetensors::save(&map, tmp).map_err(DetectorError::from),
            |e| DetectorError::from(hilo_core::fs::FileError::io(path, e)),
        )
    }

    pub fn load(&mut self, path: &Path, device: &Device) -> Result<()> {
        let t = candle_core::safetensors::load(path, device)
            .map_err(|e| DetectorError::Checkpoint { path: path.to_path_buf(), message: e.to_string() })?;
        let get = |n: &str| {
            t.get(n).cloned().ok_or_else(|| DetectorError::Checkpoint {
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

/// [`AdamW`]'s update as three passes over each variable that write in place, for f32
/// variables on the CPU: candle's composite update allocates a tensor for each of its eleven
/// element-wise operations per variable. Each pass does the composite's f32 operations in its
/// order (a scalar `s` applied as candle's `affine` does: `x · f32(s) + 0`), so the weights and
/// moments are bit for bit the same (tested), and with them every result downstream.
mod fused {
    use crate::cpu::{f32_slice, f32_slice_mut};
    use candle_core::{CpuStorage, InplaceOp2, InplaceOp3, Layout, Tensor};

    /// Whether the in-place passes apply: every operand f32, contiguous and on the CPU.
    pub fn applies(var: &Tensor, m: &Tensor, v: &Tensor, g: &Tensor) -> bool {
        [var, m, v, g].iter().all(|t| t.device().is_cpu() && t.dtype() == candle_core::DType::F32 && t.is_contiguous())
            && g.shape() == var.shape()
    }

    /// candle's `x * s` for a scalar `s`: `affine(s, 0)`.
    #[inline(always)]
    fn scaled(x: f32, s: f32) -> f32 {
        x * s + 0.0
    }

    /// A moment: `m ← m·β + (g·scale)·(1 − β)`, or with `squared` `v ← v·β + (g·scale)²·(1 − β)`.
    pub struct Moment {
        pub scale: f64,
        pub beta: f64,
        pub squared: bool,
    }

    impl InplaceOp2 for Moment {
        fn name(&self) -> &'static str {
            if self.squared { "adamw-second-moment" } else { "adamw-first-moment" }
        }

        fn cpu_fwd(&self, s1: &mut CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> candle_core::Result<()> {
            let (scale, beta, rest) = (self.scale as f32, self.beta as f32, (1.0 - self.beta) as f32);
            let g = f32_slice(s2, l2, self.name())?;
            let m = f32_slice_mut(s1, l1, self.name())?;
            if m.len() != g.len() {
                candle_core::bail!("{}: {} moments for {} gradients", self.name(), m.len(), g.len());
            }
            for (m, &g) in m.iter_mut().zip(g) {
                let g = scaled(g, scale);
                *m = scaled(*m, beta) + scaled(if self.squared { g * g } else { g }, rest);
            }
            Ok(())
        }
    }

    /// `p ← p·(1 − lr·λ) − lr · (m·c1) / (√(v·c2) + ε)`, with `c1`, `c2` the reciprocals of the
    /// bias corrections.
    pub struct Update {
        pub c1: f64,
        pub c2: f64,
        pub eps: f64,
        pub lr: f64,
        pub weight_decay: f64,
    }

    impl InplaceOp3 for Update {
        fn name(&self) -> &'static str {
            "adamw-update"
        }

        fn cpu_fwd(
            &self,
            s1: &mut CpuStorage,
            l1: &Layout,
            s2: &CpuStorage,
            l2: &Layout,
            s3: &CpuStorage,
            l3: &Layout,
        ) -> candle_core::Result<()> {
            let (c1, c2, eps, lr) = (self.c1 as f32, self.c2 as f32, self.eps as f32, self.lr as f32);
            let decay = (1.0 - self.lr * self.weight_decay) as f32;
            let (m, v) = (f32_slice(s2, l2, self.name())?, f32_slice(s3, l3, self.name())?);
            let p = f32_slice_mut(s1, l1, self.name())?;
            if p.len() != m.len() || p.len() != v.len() {
                candle_core::bail!("{}: {} weights, {} and {} moments", self.name(), p.len(), m.len(), v.len());
            }
            for ((p, &m), &v) in p.iter_mut().zip(m).zip(v) {
                // `+ eps` is candle's affine(1, eps).
                let update = scaled(m, c1) / (scaled(v, c2).sqrt() * 1.0 + eps);
                *p = scaled(*p, decay) - scaled(update, lr);
            }
            Ok(())
        }
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
    /// Points and pillars the caps left out, over every batch trained so far.
    #[serde(default)]
    pub dropped_points: usize,
    #[serde(default)]
    pub dropped_pillars: usize,
    /// Fingerprint of the training frames (their samples and point counts): a run folder is
    /// never resumed on other data.
    #[serde(default)]
    pub data: String,
    /// The fused layers the run trained with when not all of them (`hilo train --fused`, see
    /// [`hilo_fusion::cpu::parse_layers`]); absent when all were on. A run resumes only with
    /// the same set: the fused and composite paths differ in the last bits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fused: Option<String>,
}

/// The process's fused layers as a run records them: None when all are on.
fn fused_set() -> Option<String> {
    let on = crate::cpu::fused_layers();
    (on.len() != crate::cpu::Layer::ALL.len()).then(|| crate::cpu::layers_name(&on))
}

/// A fingerprint of training frames: their sample tokens and point and box counts.
pub fn frames_fingerprint(frames: &[Frame]) -> String {
    let parts: Vec<String> = frames
        .iter()
        .map(|f| format!("{}:{}:{}:{}", f.sample_token, f.lidar.len(), f.radar.len(), f.boxes.len()))
        .collect();
    let refs: Vec<&str> = parts.iter().map(String::as_str).collect();
    hilo_dataset::writer::token(&refs)
}

pub fn weights_path(run: &Path) -> PathBuf {
    run.join("model.safetensors")
}

/// The copy of the weights kept after `samples` samples (see [`TrainConfig::keep`]).
pub fn kept_weights_path(run: &Path, samples: usize) -> PathBuf {
    run.join(format!("model-{samples}.safetensors"))
}

fn optimizer_path(run: &Path) -> PathBuf {
    run.join("optimizer.safetensors")
}

fn info_path(run: &Path) -> PathBuf {
    run.join("run.json")
}

/// Where a run keeps the background model its LiDAR input was filtered with.
pub fn background_path(run: &Path) -> PathBuf {
    run.join("background.json")
}

pub fn read_info(run: &Path) -> Result<RunInfo> {
    let p = info_path(run);
    let bytes = hilo_core::fs::read_bounded(&p, hilo_core::fs::limit::CONFIG)
        .map_err(|e| hilo_core::fs::FileError::content(&p, format!("{e} (not a training run folder?)")))?;
    serde_json::from_slice(&bytes).map_err(|e| DetectorError::Checkpoint { path: p, message: e.to_string() })
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
    /// Points and pillars the caps left out in this step's batch.
    pub dropped_points: usize,
    pub dropped_pillars: usize,
}

/// A run folder's `loss.jsonl`: one JSON line per step (step, loss and its parts, learning
/// rate, samples/s, what the caps left out). Opened at the first line, once the training holds
/// the run folder (one writer, no links in it: `hilo_core::folder`), so a refused run appends
/// nothing; appended to, so a resumed run continues it.
#[derive(Debug)]
pub struct LossLog {
    path: PathBuf,
    file: Option<std::fs::File>,
}

impl LossLog {
    pub fn new(run: &Path) -> Self {
        LossLog { path: run.join("loss.jsonl"), file: None }
    }

    /// Appends `r`'s line.
    pub fn append(&mut self, r: &StepReport) -> std::io::Result<()> {
        use std::io::Write as _;
        let file = match &mut self.file {
            Some(f) => f,
            None => self.file.insert(std::fs::OpenOptions::new().create(true).append(true).open(&self.path)?),
        };
        let line = serde_json::json!({ "step": r.step, "loss": r.loss, "cls": r.cls, "reg": r.reg, "lr": r.lr, "samples_per_s": r.samples_per_s, "dropped_points": r.dropped_points, "dropped_pillars": r.dropped_pillars });
        writeln!(file, "{line}")
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The frames of step `step`: a deterministic shuffle per epoch of `epoch` (frame indices, see
/// [`epoch_frames`]), augmented with a per-sample seed, so that resuming at any step sees
/// exactly what an uninterrupted run sees.
fn step_frames(
    frames: &[Frame],
    epoch: &[usize],
    cfg: &TrainConfig,
    step: usize,
    paste: Option<&PasteDb>,
) -> Vec<Frame> {
    let n = epoch.len().max(1);
    let mut out = Vec::with_capacity(cfg.batch);
    for i in 0..cfg.batch {
        let k = step * cfg.batch + i;
        let (e, pos) = (k / n, k % n);
        let mut order: Vec<usize> = epoch.to_vec();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed ^ (e as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
        ));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed.wrapping_add(1 + k as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9),
        );
        let frame = &frames[order[pos]];
        match paste {
            // A stream of its own, so that the augmentation draws stay those of a run without.
            Some(db) => {
                let mut prng = rand_chacha::ChaCha8Rng::seed_from_u64(
                    cfg.seed.wrapping_add(1 + k as u64).wrapping_mul(0x94d0_49bb_1331_11eb),
                );
                out.push(crate::data::augment(&cfg.augmentation, &db.paste(frame, &mut prng), &mut rng));
            }
            None => out.push(crate::data::augment(&cfg.augmentation, frame, &mut rng)),
        }
    }
    out
}

/// The paste database of a schedule that pastes, cut from its training frames.
pub fn paste_db(frames: &[Frame], cfg: &Valid<TrainConfig>) -> Result<Option<PasteDb>> {
    cfg.part(|c| c.paste.as_ref()).map(|p| PasteDb::build(frames, &p)).transpose()
}

/// The seed of step `step`'s pillar sampling.
fn step_seed(cfg: &TrainConfig, step: usize) -> u64 {
    cfg.seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ step as u64
}

/// The seed of replica `r`'s pillar sampling in step `step` (the first replica's is the step's,
/// so one replica samples as a plain batch does).
fn replica_seed(cfg: &TrainConfig, step: usize, r: usize) -> u64 {
    step_seed(cfg, step) ^ (r as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

/// The host batches of step `step`'s replicas: the step's frames split in `replicas` equal parts.
fn replica_batches(
    det_cfg: &DetectorConfig,
    frames: &[Frame],
    cfg: &TrainConfig,
    step: usize,
    with_radar: bool,
) -> Vec<HostBatch> {
    let per = (cfg.batch / cfg.replicas.max(1)).max(1);
    frames
        .chunks(per)
        .enumerate()
        .map(|(r, part)| HostBatch::new(det_cfg, part, with_radar, replica_seed(cfg, step, r)))
        .collect()
}

/// Where a step's replicas run: one single-thread pool each when the calling pool has a thread
/// per replica to spare (so a replica's matrix products and kernels stay on its core), else the
/// calling thread, one replica after the other. The weights do not depend on which.
#[derive(Debug)]
pub struct ReplicaPools(Vec<rayon::ThreadPool>);

impl ReplicaPools {
    /// Pools for `replicas` replicas within the current rayon pool's threads. None when candle
    /// splits its matrix products across threads itself (`RAYON_NUM_THREADS` unset or above 1):
    /// a product split for threads a one-thread pool does not have runs slower than the replicas
    /// one after the other.
    pub fn new(replicas: usize) -> Result<Self> {
        let workers = replicas.min(rayon::current_num_threads());
        if workers < 2 || candle_core::utils::get_num_threads() > 1 {
            return Ok(Self::sequential());
        }
        Self::threads(workers)
    }

    /// The calling thread, one replica after the other.
    pub fn sequential() -> Self {
        ReplicaPools(Vec::new())
    }

    /// `n` one-thread pools whatever candle's setting (for tests that compare the two ways).
    pub fn threads(n: usize) -> Result<Self> {
        (0..n)
            .map(|_| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .map_err(|e| DetectorError::Config(format!("starting a replica's thread: {e}")))
            })
            .collect::<Result<Vec<_>>>()
            .map(ReplicaPools)
    }

    /// The pools a training with `cfg` runs its replicas on: one thread each when BatchNorm is
    /// synchronised across them (they meet at every BatchNorm layer), else [`Self::new`].
    pub fn for_config(cfg: &TrainConfig) -> Result<Self> {
        if cfg.sync_batch_norm && cfg.replicas > 1 { Self::threads(cfg.replicas) } else { Self::new(cfg.replicas) }
    }

    /// How many replicas run at once.
    pub fn parallel(&self) -> usize {
        self.0.len().max(1)
    }
}

/// One step's losses (means over its replicas) and gradients (averaged over them, in the
/// optimizer's order).
#[derive(Debug)]
pub struct StepPass {
    pub grads: Vec<Option<Tensor>>,
    pub total: f32,
    pub cls: f32,
    pub reg: f32,
}

/// Forward and backward passes of one replica (each part timed into `times` when given); the
/// replicas after the first leave BatchNorm's running statistics alone, and with `sync` they
/// normalise over all replicas' rows.
fn replica_pass(
    det: &Detector,
    opt: &AdamW,
    batch: &HostBatch,
    r: usize,
    sync: Option<&Arc<BatchNormSync>>,
    mut times: Option<&mut StepTimes>,
) -> Result<StepPass> {
    let mut pass = || -> Result<StepPass> {
        let heads = det.forward_timed(batch, true, times.as_deref_mut().map(|t| &mut t.forward))?;
        // Timed, each part waits for the device's queued work.
        let timed = times.is_some();
        let sync = || if timed { det.device().synchronize() } else { Ok(()) };
        let c = std::time::Instant::now();
        let loss = det.loss_all(&heads, &batch.targets)?;
        sync()?;
        let loss_s = c.elapsed().as_secs_f64();
        let c = std::time::Instant::now();
        let grads = loss.total.backward()?;
        sync()?;
        if let Some(t) = times.as_deref_mut() {
            t.loss_s += loss_s;
            t.backward_s += c.elapsed().as_secs_f64();
        }
        Ok(StepPass {
            grads: opt.gradients(&grads),
            total: loss.total.to_scalar::<f32>()?,
            cls: loss.cls,
            reg: loss.reg,
        })
    };
    let frozen_after_first = || if r == 0 { pass() } else { crate::bnrelu::with_running_stats_frozen(pass) };
    match sync {
        Some(group) => crate::bnrelu::with_synced_batch_norm(group, r, frozen_after_first),
        None => frozen_after_first(),
    }
}

/// The forward and backward passes of a step's replicas (`batches`, one each), run on `pools`,
/// with their gradients summed in replica order and divided by their number. With
/// `sync_batch_norm` (and several replicas) BatchNorm normalises over all of them, which needs
/// a pool per replica.
pub fn step_pass(
    det: &Detector,
    opt: &AdamW,
    batches: &[HostBatch],
    pools: &ReplicaPools,
    sync_batch_norm: bool,
) -> Result<StepPass> {
    let sync = (sync_batch_norm && batches.len() > 1).then(|| BatchNormSync::new(batches.len()));
    if sync.is_some() && pools.0.len() < batches.len() {
        return Err(DetectorError::Config(format!(
            "synchronised BatchNorm: {} replicas need a thread each, {} given",
            batches.len(),
            pools.0.len()
        )));
    }
    let sync = sync.as_ref();
    let passes: Vec<StepPass> = if pools.0.is_empty() {
        batches.iter().enumerate().map(|(r, b)| replica_pass(det, opt, b, r, None, None)).collect::<Result<_>>()?
    } else {
        let w = pools.0.len();
        let joined = std::thread::scope(|scope| {
            let handles: Vec<_> = pools
                .0
                .iter()
                .enumerate()
                .map(|(k, pool)| {
                    scope.spawn(move || {
                        pool.install(|| {
                            (k..batches.len())
                                .step_by(w)
                                .map(|r| (r, replica_pass(det, opt, &batches[r], r, sync, None)))
                                .collect::<Vec<_>>()
                        })
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join()).collect::<Vec<_>>()
        });
        let mut slots: Vec<Option<StepPass>> = (0..batches.len()).map(|_| None).collect();
        let mut errors = Vec::new();
        for done in joined {
            let done = done.map_err(|_| DetectorError::Config("a replica's thread panicked".into()))?;
            for (r, pass) in done {
                match pass {
                    Ok(p) => slots[r] = Some(p),
                    Err(e) => errors.push(e),
                }
            }
        }
        // A replica's own error before the "replicas parted" errors it caused in the others.
        if !errors.is_empty() {
            let own = errors.iter().position(|e| !crate::bnrelu::is_parting(&e.to_string())).unwrap_or(0);
            return Err(errors.swap_remove(own));
        }
        slots
            .into_iter()
            .map(|p| p.ok_or_else(|| DetectorError::Config("a replica did not run".into())))
            .collect::<Result<_>>()?
    };
    average(passes)
}

/// The replicas' passes combined: gradients summed in replica order and divided by their
/// number, losses averaged.
fn average(passes: Vec<StepPass>) -> Result<StepPass> {
    let n = passes.len();
    let mut it = passes.into_iter();
    let mut acc = it.next().ok_or_else(|| DetectorError::Config("a step without replicas".into()))?;
    if n == 1 {
        return Ok(acc);
    }
    for p in it {
        for (a, g) in acc.grads.iter_mut().zip(p.grads) {
            *a = match (a.take(), g) {
                (Some(x), Some(y)) => Some((x + y)?),
                (x, y) => x.or(y),
            };
        }
        acc.total += p.total;
        acc.cls += p.cls;
        acc.reg += p.reg;
    }
    let inv = 1.0 / n as f64;
    acc.grads = acc.grads.into_iter().map(|g| g.map(|g| g * inv).transpose()).collect::<candle_core::Result<_>>()?;
    let nf = n as f32;
    Ok(StepPass { total: acc.total / nf, cls: acc.cls / nf, reg: acc.reg / nf, ..acc })
}

/// Lowers the calling thread to the idle scheduling class (Linux `SCHED_IDLE`): the batch thread
/// then runs on whatever the step leaves idle (the optimizer's serial part, the replicas' waits
/// at their BatchNorm exchanges, the wait for the next batch) instead of taking a core from a
/// replica, which stalls the other replica at its next exchange. When it falls behind, the
/// training thread waits for its batch, leaving a core idle, so it still makes progress. Where
/// the class is not available the thread keeps its priority (the batches are the same either
/// way: only when they are made changes).
fn idle_priority() {
    #[cfg(target_os = "linux")]
    {
        use thread_priority::{NormalThreadSchedulePolicy, ThreadPriority, ThreadSchedulePolicy};
        let _ = thread_priority::set_thread_priority_and_policy(
            thread_priority::thread_native_id(),
            ThreadPriority::Min,
            ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Idle),
        );
    }
}

/// Trains (or resumes) a detector in `run` on frames loaded with its input config (and, when it
/// removes background, the `background` model they were filtered with, kept in the run for
/// inference). Batches are prepared one step ahead on another thread, at idle priority where the
/// system has it (Linux's `SCHED_IDLE`). `on_step` returning false
/// stops the run after a checkpoint (rerunning resumes it). Returns the run's info.
#[allow(clippy::too_many_arguments)]
pub fn train(
    run: &Path,
    det_cfg: &Valid<DetectorConfig>,
    cfg: &Valid<TrainConfig>,
    frames: &[Frame],
    background: Option<&BackgroundModel>,
    registry: &Registry,
    device: &Device,
    on_step: &mut dyn FnMut(&StepReport) -> bool,
) -> Result<RunInfo> {
    if frames.is_empty() {
        return Err(DetectorError::Config("no training frames".into()));
    }
    if det_cfg.input.background.is_some() != background.is_some() {
        return Err(DetectorError::Config(format!(
            "detector {}: input.background is {} but a background model was {}given",
            det_cfg.name,
            if det_cfg.input.background.is_some() { "set" } else { "not set" },
            if background.is_some() { "" } else { "not " }
        )));
    }
    let paste = paste_db(frames, cfg)?;
    let mut det = Detector::new(det_cfg, registry, device, cfg.seed)?;
    // One training per run folder, and no link inside it (the checkpoints would land elsewhere).
    let _claim = hilo_core::folder::claim(run, hilo_core::folder::Mode::Exclusive)?;
    let mut opt = AdamW::new(det.trainable(), cfg.weight_decay)?;
    let mut info = RunInfo {
        detector: (**det_cfg).clone(),
        train: (**cfg).clone(),
        step: 0,
        samples_seen: 0,
        seconds: 0.0,
        finished: false,
        dropped_points: 0,
        dropped_pillars: 0,
        data: frames_fingerprint(frames),
        fused: fused_set(),
    };
    // A run folder whose run never took a step (refused or stopped before its first
    // checkpoint) holds nothing to lose: it is taken over, so a corrected rerun is not blocked.
    let old = if info_path(run).exists() { Some(read_info(run)?) } else { None };
    if let Some(old) = old.filter(|o| o.step > 0) {
        if old.detector != **det_cfg || old.train != **cfg {
            return Err(DetectorError::Config(format!(
                "{} holds a run with other settings (detector {}); use another --out or delete it",
                run.display(),
                old.detector.name
            )));
        }
        if old.fused != info.fused {
            let name = |f: &Option<String>| f.clone().unwrap_or_else(|| "on".into());
            return Err(DetectorError::Config(format!(
                "{} holds a run trained with fused layers {} (now {}); resume it with --fused {}, or use another --out",
                run.display(),
                name(&old.fused),
                name(&info.fused),
                name(&old.fused)
            )));
        }
        if old.data != info.data {
            return Err(DetectorError::Config(format!(
                "{} holds a run trained on other frames (data fingerprint {} there, {} now); use another --out or delete it",
                run.display(),
                old.data,
                info.data
            )));
        }
        det.load(&weights_path(run))?;
        opt.load(&optimizer_path(run), device)?;
        info = old;
        if info.finished {
            return Ok(info);
        }
    }
    if let Some(bg) = background {
        hilo_core::fs::write_json(&background_path(run), bg)?;
    }
    let steps = cfg.steps();
    let with_radar = det.uses_radar();
    let start = info.step;
    let epoch = epoch_frames(frames, cfg.sampling, cfg.seed);
    let epoch_steps = epoch.len().div_ceil(cfg.batch).max(1);
    let t_run = std::time::Instant::now();
    let seconds_before = info.seconds;
    std::thread::scope(|scope| -> Result<()> {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<HostBatch>>(2);
        let (epoch, paste) = (&epoch, paste.as_ref());
        scope.spawn(move || {
            idle_priority();
            for step in start..steps {
                let frames = step_frames(frames, epoch, cfg, step, paste);
                if tx.send(replica_batches(det_cfg, &frames, cfg, step, with_radar)).is_err() {
                    return;
                }
            }
        });
        let pools = ReplicaPools::for_config(cfg)?;
        let mut window = std::time::Instant::now();
        for step in start..steps {
            let batches = rx.recv().map_err(|_| DetectorError::Config("the batch thread stopped".into()))?;
            let pass = step_pass(&det, &opt, &batches, &pools, cfg.sync_batch_norm)?;
            let lr = cfg.lr(step);
            opt.step_with(&pass.grads, lr, cfg.clip_norm)?;
            let total = pass.total;
            if !total.is_finite() {
                return Err(DetectorError::Config(format!("loss is {total} at step {step}")));
            }
            let dt = window.elapsed().as_secs_f64();
            window = std::time::Instant::now();
            info.step = step + 1;
            info.samples_seen = info.step * cfg.batch;
            let dropped_points: usize = batches.iter().map(|b| b.lidar.dropped_points + b.radar.dropped_points).sum();
            let dropped_pillars: usize =
                batches.iter().map(|b| b.lidar.dropped_pillars + b.radar.dropped_pillars).sum();
            info.dropped_points += dropped_points;
            info.dropped_pillars += dropped_pillars;
            let go_on = on_step(&StepReport {
                step: step + 1,
                steps,
                loss: total,
                cls: pass.cls,
                reg: pass.reg,
                lr,
                samples_per_s: cfg.batch as f64 / dt.max(1e-9),
                dropped_points,
                dropped_pillars,
            });
            if cfg.keep.contains(&info.samples_seen) {
                det.save(&kept_weights_path(run, info.samples_seen))?;
            }
            let end_of_epoch = (step + 1) % epoch_steps == 0;
            if !go_on || end_of_epoch || (step + 1) % cfg.checkpoint_steps.max(1) == 0 || step + 1 == steps {
                info.seconds = seconds_before + t_run.elapsed().as_secs_f64();
                info.finished = step + 1 == steps;
                det.save(&weights_path(run))?;
                opt.save(&optimizer_path(run))?;
                hilo_core::fs::write_json(&info_path(run), &info)?;
            }
            if !go_on {
                break;
            }
        }
        Ok(())
    })?;
    Ok(info)
}

/// A trained detector from a run folder, with the background model its input was filtered
/// with (when its input removes background).
pub fn load_run(
    run: &Path,
    registry: &Registry,
    device: &Device,
) -> Result<(Detector, RunInfo, Option<BackgroundModel>)> {
    load_run_at(run, registry, device, None)
}

/// [`load_run`] with the weights kept after `samples` samples (the final ones for None).
pub fn load_run_at(
    run: &Path,
    registry: &Registry,
    device: &Device,
    samples: Option<usize>,
) -> Result<(Detector, RunInfo, Option<BackgroundModel>)> {
    let info = read_info(run)?;
    let mut det = Detector::new(&info.detector.clone().validate()?, registry, device, 0)?;
    det.load(&samples.map_or_else(|| weights_path(run), |s| kept_weights_path(run, s)))?;
    let background = match &info.detector.input.background {
        None => None,
        Some(_) => {
            let p = background_path(run);
            let bytes = hilo_core::fs::read_bounded(&p, hilo_core::fs::limit::TABLE)
                .map_err(|e| hilo_core::fs::FileError::io(&p, e))?;
            Some(
                serde_json::from_slice(&bytes)
                    .map_err(|e| DetectorError::Checkpoint { path: p, message: e.to_string() })?,
            )
        }
    };
    Ok((det, info, background))
}

/// Learns the background model a detector's input asks for from a dataset's training split
/// (`None` when its input keeps the background).
pub fn learn_background(
    ds: &hilo_dataset::Dataset,
    split: &str,
    det: &Valid<DetectorConfig>,
) -> Result<Option<BackgroundModel>> {
    match det.part(|d| d.input.background.as_ref()) {
        None => Ok(None),
        Some(cfg) if det.input.lidar_min_range_m > cfg.min_range_m => {
            // The near-range cut the detector applies to its input applies to what the
            // background is learned from too.
            let mut near = (*cfg).clone();
            near.min_range_m = det.input.lidar_min_range_m;
            let near = Valid::new(near).map_err(|e| DetectorError::Config(e.to_string()))?;
            Ok(Some(BackgroundModel::learn(ds, split, &near).map_err(DetectorError::from)?))
        }
        Some(cfg) => Ok(Some(BackgroundModel::learn(ds, split, &cfg).map_err(DetectorError::from)?)),
    }
}

/// The detector and schedule a training runs, as `hilo train` names them: a registered preset
/// (or ablation) with its default schedule, changed by the JSON merge patch (RFC 7386) in
/// `patch` when given; or the detector config in `config` with the default schedule. The
/// schedule then takes the fields of the file `schedule` (the rest keep their values). Errors
/// name the file.
pub fn recipe(
    registry: &Registry,
    preset: &str,
    config: Option<&Path>,
    patch: Option<&Path>,
    schedule: Option<&Path>,
) -> Result<(DetectorConfig, TrainConfig)> {
    use hilo_core::fs::{limit, read_json};
    let (det, base) = match config {
        Some(path) => (read_json::<DetectorConfig>(path, limit::CONFIG)?, TrainConfig::default()),
        None => {
            let p = registry.preset(preset)?;
            let det = match patch {
                Some(path) => {
                    p.detector.with_patch(&read_json::<serde_json::Value>(path, limit::CONFIG)?).map_err(|e| {
                        DetectorError::Config(format!("{}: not a patch of the preset: {e}", path.display()))
                    })?
                }
                None => p.detector.clone(),
            };
            (det, p.train.clone())
        }
    };
    let train = match schedule {
        Some(path) => base
            .with_fields(&read_json::<serde_json::Value>(path, limit::CONFIG)?)
            .map_err(|e| DetectorError::Config(format!("{}: not a valid training schedule: {e}", path.display())))?,
        None => base,
    };
    Ok((det, train))
}

/// Time of each part of a training step, seconds, summed over the steps timed.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StepTimes {
    pub steps: usize,
    /// Augmentation, pillarisation, layout and targets on the host (done on another thread
    /// when training, so hidden unless it is the slowest part).
    pub data_s: f64,
    pub forward: crate::detector::ForwardTimes,
    pub loss_s: f64,
    pub backward_s: f64,
    pub optimizer_s: f64,
    /// The step on the training thread: forward, loss, backward and optimizer.
    pub total_s: f64,
}

/// Runs `steps` training steps of a fresh detector on `frames` with every part timed (the batch
/// built on the same thread, and the replicas one after the other, so each part is measured
/// alone; with several replicas a part's time is the sum over them, and BatchNorm is each
/// replica's own: synchronising it adds barriers, not compute). For benchmarks.
pub fn time_steps(det: &Detector, frames: &[Frame], cfg: &Valid<TrainConfig>, steps: usize) -> Result<StepTimes> {
    let mut opt = AdamW::new(det.trainable(), cfg.weight_decay)?;
    let epoch = epoch_frames(frames, cfg.sampling, cfg.seed);
    let paste = paste_db(frames, cfg)?;
    let mut t = StepTimes { steps, ..StepTimes::default() };
    let with_radar = det.uses_radar();
    for step in 0..steps {
        let t0 = std::time::Instant::now();
        let step_frames = step_frames(frames, &epoch, cfg, step, paste.as_ref());
        let batches = replica_batches(&det.cfg, &step_frames, cfg, step, with_radar);
        t.data_s += t0.elapsed().as_secs_f64();
        let t1 = std::time::Instant::now();
        let passes = batches
            .iter()
            .enumerate()
            .map(|(r, batch)| replica_pass(det, &opt, batch, r, None, Some(&mut t)))
            .collect::<Result<Vec<_>>>()?;
        let pass = average(passes)?;
        let c = std::time::Instant::now();
        opt.step_with(&pass.grads, cfg.lr(step), cfg.clip_norm)?;
        det.device().synchronize()?;
        t.optimizer_s += c.elapsed().as_secs_f64();
        t.total_s += t1.elapsed().as_secs_f64();
    }
    Ok(t)
}

/// Wall seconds of `steps` training steps as training runs them (replicas side by side where
/// the pool has the threads), batches prepared beforehand, and how many replicas ran at once.
/// For benchmarks.
pub fn time_replicated_steps(
    det: &Detector,
    frames: &[Frame],
    cfg: &Valid<TrainConfig>,
    steps: usize,
) -> Result<(f64, usize)> {
    let mut opt = AdamW::new(det.trainable(), cfg.weight_decay)?;
    let epoch = epoch_frames(frames, cfg.sampling, cfg.seed);
    let paste = paste_db(frames, cfg)?;
    let with_radar = det.uses_radar();
    let batches: Vec<Vec<HostBatch>> = (0..steps)
        .map(|step| {
            let f = step_frames(frames, &epoch, cfg, step, paste.as_ref());
            replica_batches(&det.cfg, &f, cfg, step, with_radar)
        })
        .collect();
    let pools = ReplicaPools::for_config(cfg)?;
    let t0 = std::time::Instant::now();
    for (step, b) in batches.iter().enumerate() {
        let pass = step_pass(det, &opt, b, &pools, cfg.sync_batch_norm)?;
        opt.step_with(&pass.grads, cfg.lr(step), cfg.clip_norm)?;
    }
    det.device().synchronize()?;
    Ok((t0.elapsed().as_secs_f64(), pools.parallel()))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::data::GtBox;

    fn frame(classes: &[usize]) -> Frame {
        let boxes = classes
            .iter()
            .map(|&c| GtBox { class: c, center: [0.0; 3], wlh: [1.0; 3], yaw: 0.0, velocity: [0.0; 2] })
            .collect();
        Frame { boxes, ..Frame::default() }
    }

    fn bits(t: &Tensor) -> Vec<u32> {
        t.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().map(|x| x.to_bits()).collect()
    }

    /// The in-place update is the composite one bit for bit: weights and both moments after
    /// every step, over steps whose gradients are clipped (scale < 1) and not, with weight
    /// decay, signed zeros, tiny and large values, a variable without a gradient and one whose
    /// gradient is not contiguous (the composite path within a fused optimizer).
    #[test]
    fn the_in_place_adamw_update_equals_the_composite_bit_for_bit() {
        use rand::Rng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let shapes: [&[usize]; 5] = [&[7, 3], &[64], &[2, 3, 4], &[1], &[5, 4]];
        let init: Vec<Vec<f32>> = shapes
            .iter()
            .map(|s| {
                let n: usize = s.iter().product();
                (0..n)
                    .map(|i| match i % 6 {
                        0 => 0.0,
                        1 => -0.0,
                        2 => rng.random_range(-1e-30f32..1e-30),
                        3 => rng.random_range(-1e3f32..1e3),
                        _ => rng.random_range(-1f32..1.0),
                    })
                    .collect()
            })
            .collect();
        let vars = || -> Vec<(String, Var)> {
            shapes
                .iter()
                .zip(&init)
                .enumerate()
                .map(|(k, (s, v))| (format!("w{k}"), Var::from_vec(v.clone(), *s, &Device::Cpu).unwrap()))
                .collect()
        };
        let mut fused = AdamW::new(vars(), 0.01).unwrap().with_fused(true);
        let mut composite = AdamW::new(vars(), 0.01).unwrap().with_fused(false);
        for step in 0..6 {
            // Large gradients on even steps (clipped at 1.0), small ones on odd steps.
            let size = if step % 2 == 0 { 50.0f32 } else { 1e-3 };
            let gs: Vec<Option<Tensor>> = shapes
                .iter()
                .enumerate()
                .map(|(k, s)| {
                    let n: usize = s.iter().product();
                    let g: Vec<f32> =
                        (0..n).map(|i| if i % 5 == 0 { -0.0 } else { size * rng.random_range(-1f32..1.0) }).collect();
                    match k {
                        3 => None,
                        // A transposed view: not contiguous.
                        4 => Some(Tensor::from_vec(g, (4, 5), &Device::Cpu).unwrap().t().unwrap()),
                        _ => Some(Tensor::from_vec(g, *s, &Device::Cpu).unwrap()),
                    }
                })
                .collect();
            let lr = 0.003 * (step + 1) as f64;
            let a = fused.step_with(&gs, lr, 1.0).unwrap();
            let b = composite.step_with(&gs, lr, 1.0).unwrap();
            assert_eq!(a.to_bits(), b.to_bits());
            for k in 0..shapes.len() {
                let (x, y) = (fused.vars[k].1.as_tensor(), composite.vars[k].1.as_tensor());
                assert_eq!(bits(x), bits(y), "weights {k} after step {step}");
                assert_eq!(bits(&fused.m[k]), bits(&composite.m[k]), "first moment {k} after step {step}");
                assert_eq!(bits(&fused.v[k]), bits(&composite.v[k]), "second moment {k} after step {step}");
            }
        }
        // The weights moved, and the variable without gradients did not.
        assert_ne!(bits(fused.vars[0].1.as_tensor()), init[0].iter().map(|x| x.to_bits()).collect::<Vec<_>>());
        assert_eq!(bits(fused.vars[3].1.as_tensor()), init[3].iter().map(|x| x.to_bits()).collect::<Vec<_>>());
    }

    /// CBGS: every class present contributes the same number of frames; a rare class's frames
    /// repeat, and its share of the epoch rises from its share of the frames to about 1 / C.
    #[test]
    fn class_balanced_epochs_give_every_class_the_same_share() {
        // 100 frames: all hold cars (0) and pedestrians (4); 5 hold a bus (2), 20 a truck (1).
        let frames: Vec<Frame> = (0..100)
            .map(|i| {
                let mut c = vec![0, 4];
                if i % 20 == 0 {
                    c.push(2);
                }
                if i % 5 == 1 {
                    c.push(1);
                }
                frame(&c)
            })
            .collect();
        assert_eq!(epoch_frames(&frames, Sampling::Uniform, 0), (0..100).collect::<Vec<_>>());
        let e = epoch_frames(&frames, Sampling::ClassBalanced, 7);
        // Σ|S_c| = 100 + 100 + 5 + 20 = 225 over 4 classes: 56 draws each.
        assert_eq!(e.len(), 4 * 56);
        let with = |c: usize| e.iter().filter(|&&i| frames[i].boxes.iter().any(|b| b.class == c)).count();
        assert!(with(2) >= 56, "every bus draw holds a bus: {}", with(2));
        let share = with(2) as f64 / e.len() as f64;
        assert!(share > 0.24 && share < 0.30, "bus frames are {share:.3} of the epoch (5% of the frames)");
        assert!(e.iter().all(|&i| i < 100));
        // Deterministic in the seed.
        assert_eq!(e, epoch_frames(&frames, Sampling::ClassBalanced, 7));
        assert_ne!(e, epoch_frames(&frames, Sampling::ClassBalanced, 8));
    }
}
