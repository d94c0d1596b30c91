//! The plain configurations of a detector and its training: what a preset is made of. They
//! are data (serde, with defaults that older saved runs read), checked by their `validate`
//! methods; the detector crate builds and trains from them.

use crate::error::{FusionError, Result};
use crate::grid::BevGrid;
use crate::layout::SparseConfig;
use crate::modules::BackboneConfig;
use hilo_core::background::BackgroundConfig;
use hilo_core::{Check, Class, Valid};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The stated limits on values that size a training's allocations ([`crate::limits`]).
pub use crate::limits;

/// Everything that defines a detector's architecture and what it reads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    /// Preset name (for reports).
    pub name: String,
    /// Registered fusion plugin and its config.
    pub fusion: String,
    pub fusion_config: serde_json::Value,
    pub grid: BevGrid,
    pub backbone: BackboneConfig,
    pub assignment: Assignment,
    /// Hidden channels of the head's per-task 3×3 convolutions (0: 1×1 outputs only).
    pub head_channels: usize,
    pub decode: DecodeConfig,
    /// What the network reads: background removal, radar sweeps.
    #[serde(default)]
    pub input: InputConfig,
    /// Compute on the occupied cells only (`None`: dense maps over the whole grid).
    #[serde(default)]
    pub sparse: Option<SparseConfig>,
    /// What the losses are normalised by (detectors saved before the field existed read
    /// [`LossNorm::All`]).
    #[serde(default, skip_serializing_if = "LossNorm::is_all")]
    pub loss_norm: LossNorm,
    /// Weight of each velocity channel's L1 loss beside the box channels' 1 (CenterPoint's code
    /// weight, 0.2, for detectors saved before the field existed).
    #[serde(default = "velocity_weight", skip_serializing_if = "is_velocity_weight")]
    pub velocity_weight: f64,
    /// Which head cells learn a box's velocity (detectors saved before the field existed read
    /// [`VelocityTarget::Positives`]).
    #[serde(default, skip_serializing_if = "VelocityTarget::is_positives")]
    pub velocity_target: VelocityTarget,
    /// The head also detects cyclists (nuScenes `bicycle`): a seventh heatmap channel after the
    /// paper's six. A study sets it when its traffic carries cyclists, `hilo train` when the
    /// dataset's category table lists them; detectors saved before the field existed read false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub cyclists: bool,
}

fn velocity_weight() -> f64 {
    0.2
}

impl DetectorConfig {
    /// The classes of the head's heatmap channels, in channel order: [`Class::PAPER`], and the
    /// cyclist after them when [`DetectorConfig::cyclists`] is set.
    pub fn classes(&self) -> &'static [Class] {
        Class::first(Class::PAPER.len() + usize::from(self.cyclists))
    }
}

fn is_velocity_weight(w: &f64) -> bool {
    *w == velocity_weight()
}

/// What a batch's classification and regression losses are divided by.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LossNorm {
    /// The number of positives of all classes (CenterNet, PointPillars): each class weighs in
    /// as often as it occurs, so rare classes move the weights least.
    #[default]
    All,
    /// Each class by its own positives and the classes averaged (CenterPoint's per-task heads,
    /// one task per class): a bus counts as much as all the cars of the batch together. A class
    /// without positives in the batch is normalised by 1, its false positives still penalised.
    PerClass,
}

impl LossNorm {
    fn is_all(&self) -> bool {
        *self == LossNorm::All
    }
}

impl DetectorConfig {
    /// Levels of the sparse layout: the pillar grid and one per stride-2 block.
    pub fn levels(&self) -> usize {
        1 + self.backbone.blocks.iter().filter(|b| b.stride == 2).count()
    }

    /// The head's level (log2 of its stride).
    pub fn head_level(&self) -> usize {
        self.backbone.out_stride.trailing_zeros() as usize
    }

    /// The checked configuration a detector is built from ([`Check`]).
    pub fn validate(self) -> Result<Valid<DetectorConfig>> {
        Valid::new(self)
    }
}

impl Check for DetectorConfig {
    type Error = FusionError;

    /// Checks what the detector can be built from.
    fn check(&self) -> std::result::Result<(), FusionError> {
        self.grid.validate()?;
        self.input.validate()?;
        if let Some(r) = &self.decode.radar_velocity {
            r.validate()?;
        }
        let bad = |field: String, value: &dyn std::fmt::Display, reason: String| {
            Err(FusionError::field(format!("detector {}: {field}", self.name), value, reason))
        };
        if !(self.velocity_weight.is_finite() && self.velocity_weight >= 0.0) {
            return bad("velocity_weight".into(), &self.velocity_weight, "must be finite and ≥ 0".into());
        }
        let b = &self.backbone;
        let channels = format!("give 1 to {}", limits::CHANNELS);
        if b.blocks.len() > limits::BLOCKS {
            return bad("backbone.blocks".into(), &b.blocks.len(), format!("at most {} blocks", limits::BLOCKS));
        }
        for (k, x) in b.blocks.iter().enumerate() {
            if x.channels == 0 || x.channels > limits::CHANNELS {
                return bad(format!("backbone.blocks[{k}].channels"), &x.channels, channels);
            }
            if x.layers > limits::LAYERS {
                return bad(format!("backbone.blocks[{k}].layers"), &x.layers, format!("at most {}", limits::LAYERS));
            }
        }
        if b.neck_channels == 0 || b.neck_channels > limits::CHANNELS {
            return bad("backbone.neck_channels".into(), &b.neck_channels, channels);
        }
        if self.head_channels > limits::CHANNELS {
            return bad("head_channels".into(), &self.head_channels, format!("at most {}", limits::CHANNELS));
        }
        if b.blocks.is_empty() || !b.out_stride.is_power_of_two() {
            let why = format!("the backbone needs blocks ({} given) and a power-of-two out_stride", b.blocks.len());
            return bad("backbone.out_stride".into(), &b.out_stride, why);
        }
        if let Some(k) = b.blocks.iter().position(|x| x.stride != 1 && x.stride != 2) {
            return bad(format!("backbone.blocks[{k}].stride"), &b.blocks[k].stride, "must be 1 or 2".into());
        }
        let total: usize = b.blocks.iter().map(|x| x.stride).product();
        if !self.grid.cells().is_multiple_of(total) || b.out_stride > total {
            let why =
                format!("it and the backbone's stride {total} must divide the grid's {} cells", self.grid.cells());
            return bad("backbone.out_stride".into(), &b.out_stride, why);
        }
        Ok(())
    }
}

impl DetectorConfig {
    /// An upper estimate of the memory one training step of `batch` samples takes, bytes: the
    /// pillar net's point tensors, every dense map of the backbone, neck and head (output,
    /// normalised, activated, and the gradient of each), and the weights with their gradient and
    /// two moments. Sparse layouts take less; the estimate is for refusing a configuration that
    /// cannot fit before any stage runs, not for planning to the byte.
    pub fn step_memory_bytes(&self, batch: usize) -> f64 {
        let b = &self.backbone;
        let side = self.grid.cells() as f64;
        let f32s = 4.0 * 4.0;
        let points = (self.grid.max_pillars * self.grid.max_points_per_pillar) as f64 * 64.0 * f32s;
        let (mut maps, mut weights, mut stride, mut cin) = (0.0, 0.0, 1.0, 64.0);
        for x in &b.blocks {
            stride *= x.stride as f64;
            let c = x.channels as f64;
            maps += (side / stride).powi(2) * c * (x.layers + 1) as f64 * f32s;
            weights += 9.0 * c * (cin + c * x.layers as f64);
            cin = c;
        }
        let out = (side / b.out_stride as f64).powi(2);
        let neck = b.neck_channels as f64 * b.blocks.len() as f64;
        maps += out * (neck + self.head_channels as f64 * self.classes().len() as f64 + 64.0) * f32s;
        weights += 9.0 * neck * self.head_channels as f64 * self.classes().len() as f64;
        batch as f64 * (points + maps) + weights * f32s
    }

    /// Refuses a training whose step would not fit in `available` bytes by
    /// [`DetectorConfig::step_memory_bytes`]; `available` is the machine's memory
    /// (`hilo_core::machine::memory_bytes`) where the system tells it.
    pub fn check_memory(&self, batch: usize, available: Option<u64>) -> std::result::Result<(), FusionError> {
        let need = self.step_memory_bytes(batch);
        match available {
            Some(have) if need > have as f64 => Err(FusionError::field(
                format!("detector {}: batch", self.name),
                batch,
                format!(
                    "a training step needs about {:.1} GB, more than this machine's {:.1} GB; make the grid coarser, \
                     the backbone narrower or the batch smaller",
                    need / 1e9,
                    have as f64 / 1e9
                ),
            )),
            _ => Ok(()),
        }
    }

    /// This config with a JSON merge patch (RFC 7386) applied: the patch names only the fields it
    /// changes (`{"input": {"lidar_sweeps": 10}}`), `null` removes an optional one. An unknown
    /// field or a wrong type is an error naming its path (`input.lidar_sweeps`).
    pub fn with_patch(&self, patch: &serde_json::Value) -> Result<DetectorConfig> {
        if !patch.is_object() {
            return Err(FusionError::field("detector patch", patch, "must be a JSON object of the fields it changes"));
        }
        let mut doc = serde_json::to_value(self).map_err(|e| FusionError::Config(e.to_string()))?;
        json_patch::merge(&mut doc, patch);
        serde_path_to_error::deserialize(doc)
            .map_err(|e| FusionError::field(format!("detector patch: {}", e.path()), patch, e.inner().to_string()))
    }
}

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
    /// Which frames an epoch holds: each once, or class-balanced (CBGS).
    #[serde(default)]
    pub sampling: Sampling,
    /// Samples seen at which a copy of the weights is kept (`model-<samples>.safetensors`), for
    /// learning curves; each a multiple of `batch`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub keep: Vec<usize>,
    /// Ground-truth paste of rare classes (the detector crate's `paste`; on by default); none (`null`):
    /// frames as loaded, as runs saved before the field existed read it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paste: Option<PasteConfig>,
    /// Data-parallel replicas of each step: the batch is split into this many equal parts, each
    /// run forward and backward on its own (on a core of its own when the thread pool has one,
    /// else one after the other, to the same bytes), with BatchNorm statistics over its part
    /// (the first replica's running statistics are kept) and the parts' gradients averaged in
    /// replica order, as multi-GPU training does. Divides `batch`; 1 (runs saved before the
    /// field existed read it) is the plain batch.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub replicas: usize,
    /// With several replicas, BatchNorm normalises over the whole batch's rows rather than each
    /// replica's ([`crate::bnrelu::BatchNormSync`]): the replicas' speed with the batch's
    /// statistics. The replicas then always run at once, one thread each. False (runs saved
    /// before the field existed read it): each replica's own statistics.
    #[serde(default, skip_serializing_if = "is_false")]
    pub sync_batch_norm: bool,
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn one() -> usize {
    1
}

fn is_one(n: &usize) -> bool {
    *n == 1
}

/// How training frames are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    /// Every frame once per epoch, shuffled.
    #[default]
    Uniform,
    /// Class-balanced grouping and sampling (CBGS, Zhu et al. 2019, as CenterPoint trains on
    /// nuScenes): the frames holding each class are resampled so that every class present
    /// contributes the same number of frames to an epoch; frames with rare classes (bus,
    /// motorcycle) repeat, frames with only cars and pedestrians are drawn less often.
    ClassBalanced,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            samples: 12_000,
            batch: 2,
            lr_max: 6e-3,
            weight_decay: 0.01,
            clip_norm: 10.0,
            warmup: 0.3,
            seed: 0,
            augmentation: Augmentation::default(),
            checkpoint_steps: 50,
            sampling: Sampling::Uniform,
            keep: Vec::new(),
            paste: Some(PasteConfig::default()),
            replicas: 1,
            sync_batch_norm: false,
        }
    }
}

impl TrainConfig {
    /// The checked schedule that training takes ([`Check`]).
    pub fn validate(self) -> Result<Valid<TrainConfig>> {
        Valid::new(self)
    }
}

impl Check for TrainConfig {
    type Error = FusionError;

    /// The settings' own consistency (what the detector crate's training and the benchmarks
    /// refuse), the ground-truth paste's included.
    fn check(&self) -> std::result::Result<(), FusionError> {
        if let Some(p) = &self.paste {
            p.validate()?;
        }
        self.augmentation.check()?;
        if self.batch == 0 || self.samples == 0 || self.batch > limits::BATCH || self.samples > limits::SAMPLES {
            let (field, value, most) = if self.batch == 0 || self.batch > limits::BATCH {
                ("batch", self.batch, limits::BATCH)
            } else {
                ("samples", self.samples, limits::SAMPLES)
            };
            return Err(FusionError::field(format!("train: {field}"), value, format!("give 1 to {most}")));
        }
        // A negative rate climbs the loss; one over 1 diverges at the first step.
        let rates = [
            ("lr_max", self.lr_max, self.lr_max > 0.0 && self.lr_max <= 1.0, "in (0, 1]"),
            ("weight_decay", self.weight_decay, (0.0..1.0).contains(&self.weight_decay), "in [0, 1)"),
            ("clip_norm", self.clip_norm, self.clip_norm > 0.0 && self.clip_norm.is_finite(), "finite and > 0"),
            ("warmup", self.warmup, (0.0..=1.0).contains(&self.warmup), "a share in [0, 1]"),
        ];
        if let Some((field, v, _, want)) = rates.iter().find(|r| !r.2) {
            return Err(FusionError::field(format!("train: {field}"), v, format!("must be {want}")));
        }
        if self.checkpoint_steps == 0 {
            return Err(FusionError::field("train: checkpoint_steps", 0, "must be positive"));
        }
        if self.replicas == 0 || !self.batch.is_multiple_of(self.replicas) {
            return Err(FusionError::field(
                "train: replicas",
                self.replicas,
                format!("must be positive and divide batch = {}", self.batch),
            ));
        }
        if let Some(k) = self.keep.iter().find(|k| **k % self.batch != 0 || **k == 0 || **k > self.steps() * self.batch)
        {
            return Err(FusionError::field(
                "train: keep",
                k,
                format!("must be a positive multiple of batch {} and at most the {} samples", self.batch, self.samples),
            ));
        }
        Ok(())
    }
}

impl TrainConfig {
    /// This schedule with the fields of a JSON object over it (a user's schedule file names
    /// only what it changes); an unknown field or a wrong type is an error naming it.
    pub fn with_fields(&self, fields: &serde_json::Value) -> Result<TrainConfig> {
        let Some(fields) = fields.as_object() else {
            return Err(FusionError::field(
                "training schedule",
                fields,
                "must be a JSON object of the fields it changes",
            ));
        };
        let mut cfg = serde_json::to_value(self).map_err(|e| FusionError::Config(e.to_string()))?;
        if let Some(base) = cfg.as_object_mut() {
            base.extend(fields.iter().map(|(k, v)| (k.clone(), v.clone())));
        }
        serde_path_to_error::deserialize(cfg).map_err(|e| {
            let given = serde_json::Value::Object(fields.clone());
            FusionError::field(format!("training schedule: {}", e.path()), given, e.inner().to_string())
        })
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

/// LiDAR point features: x, y, z, intensity (local frame), and the time lag of the point's
/// sweep behind the frame (s; 0 for the frame's own sweep, [`InputConfig::lidar_sweeps`]).
pub const LIDAR_FEATURES: usize = 5;
/// Radar point features: x, y, z, RCS (dBsm), v_r (m/s), line of sight x, y (unit, from the
/// sensor: the direction v_r is measured along), the time lag of the point's sweep behind the
/// frame (s; 0 for the frame's own sweep), and the radial velocity as a vector, v_r times the
/// line of sight (m/s; nuScenes' radar points carry it as `vx_comp`, `vy_comp`). The vector is
/// redundant with v_r and the line of sight, but a pillar encoder (linear layers, ReLU, max)
/// cannot form their product, and the product is what the velocity head regresses: with v_r
/// and the line of sight alone `lirafusion-like`'s car velocity error stayed at 3.3–3.5 m/s,
/// the error of a constant. Build points with [`radar_point`].
pub const RADAR_FEATURES: usize = 10;

pub use crate::pillars::PILLAR_DECORATIONS;
/// A LiDAR point's width in a pillar, what a LiDAR pillar encoder takes: its features, then
/// the decorations.
pub const LIDAR_PILLAR_WIDTH: usize = LIDAR_FEATURES + PILLAR_DECORATIONS;
/// A radar point's width in a pillar, what a radar pillar encoder takes.
pub const RADAR_PILLAR_WIDTH: usize = RADAR_FEATURES + PILLAR_DECORATIONS;

/// A radar point's features ([`RADAR_FEATURES`]) from its position, RCS, radial velocity, unit
/// line of sight and sweep lag.
pub fn radar_point(xyz: [f32; 3], rcs_dbsm: f32, v_r: f32, los: [f32; 2], lag_s: f32) -> [f32; RADAR_FEATURES] {
    [xyz[0], xyz[1], xyz[2], rcs_dbsm, v_r, los[0], los[1], lag_s, v_r * los[0], v_r * los[1]]
}

/// Whether a radar point's velocity vector (features 8 and 9) is its radial one, v_r times the
/// line of sight, as [`radar_point`] builds it; otherwise a second radar gave it the full ground
/// velocity (`InputConfig::radar_pairs`).
pub fn is_radial(p: &[f32; RADAR_FEATURES]) -> bool {
    p[8] == p[4] * p[5] && p[9] == p[4] * p[6]
}

/// What a detector reads from a dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InputConfig {
    /// Remove LiDAR points on the static background (a model learned from the training split).
    pub background: Option<BackgroundConfig>,
    /// Radar sweeps per frame: the frame's own and the `radar_sweeps − 1` before it.
    pub radar_sweeps: usize,
    /// LiDAR sweeps per frame, likewise (1: single-frame LiDAR). The sensors are static, so a
    /// road user's older points trail behind it, each tagged with its sweep's lag: the motion
    /// cue nuScenes detectors take from ten stacked sweeps. Older sweeps come from the key
    /// frames before (at the training split's 10 Hz) or from a dataset simulated with
    /// `lidar_sweeps = true`; a gap over `max_sweep_lag_s` ends the stack.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub lidar_sweeps: usize,
    /// Older sweeps farther than this behind the frame are not used (a gap in the recording).
    pub max_sweep_lag_s: f32,
    /// Drop radar static clutter (needs `background`: the LiDAR foreground tells road users
    /// from clutter).
    pub radar_clutter: Option<RadarClutterConfig>,
    /// With two radars or more: each detection of the frame's own sweep that another radar also
    /// sees gets the full ground velocity the two radial velocities give, in place of its
    /// radial velocity vector (the last two features of [`radar_point`]); detections seen by
    /// one radar keep theirs. None: every detection keeps its radial vector.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radar_pairs: Option<RadarPairConfig>,
    /// LiDAR points closer than this to their own sensor are dropped, m (0: none): the near-range
    /// cut a roadside pipeline applies, which takes fog's echo around the mount and the mount's
    /// own structure while a road user rarely comes that close to a LiDAR on a mast.
    #[serde(default, skip_serializing_if = "is_zero_f32")]
    pub lidar_min_range_m: f32,
}

impl Default for InputConfig {
    fn default() -> Self {
        InputConfig {
            background: None,
            radar_sweeps: 1,
            lidar_sweeps: 1,
            max_sweep_lag_s: 0.5,
            radar_clutter: None,
            radar_pairs: None,
            lidar_min_range_m: 0.0,
        }
    }
}

/// How detections of two radars are paired for a full ground velocity: the nearest detection of
/// the other radar within `max_gap_m` on the ground, when the two lines of sight meet at
/// `min_angle_deg` or more (the velocity's error grows as 1 / sin of that angle).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarPairConfig {
    pub max_gap_m: f32,
    pub min_angle_deg: f32,
}

impl Default for RadarPairConfig {
    fn default() -> Self {
        RadarPairConfig { max_gap_m: 1.0, min_angle_deg: 20.0 }
    }
}

impl RadarPairConfig {
    pub fn validate(&self) -> std::result::Result<(), FusionError> {
        if !(self.max_gap_m > 0.0 && self.max_gap_m <= 10.0) {
            return Err(FusionError::field("input.radar_pairs.max_gap_m", self.max_gap_m, "must be in (0, 10] m"));
        }
        if !(self.min_angle_deg >= 1.0 && self.min_angle_deg <= 89.0) {
            return Err(FusionError::field(
                "input.radar_pairs.min_angle_deg",
                self.min_angle_deg,
                "must be in [1, 89] degrees",
            ));
        }
        Ok(())
    }
}

/// Which radar detections are static clutter: those moving at most `max_speed_mps` along the
/// line of sight with no LiDAR foreground point within `lidar_radius_m` (bird's-eye view).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarClutterConfig {
    /// Largest |v_r| of a static detection, m/s (three times the catalog radar's velocity noise).
    pub max_speed_mps: f32,
    /// A detection with a LiDAR foreground point this close (x, y) is kept, m.
    pub lidar_radius_m: f32,
}

impl Default for RadarClutterConfig {
    fn default() -> Self {
        RadarClutterConfig { max_speed_mps: 0.15, lidar_radius_m: 1.0 }
    }
}

impl RadarClutterConfig {
    pub fn validate(&self) -> std::result::Result<(), FusionError> {
        if !(self.max_speed_mps >= 0.0 && self.max_speed_mps.is_finite()) {
            return Err(FusionError::field(
                "input.radar_clutter.max_speed_mps",
                self.max_speed_mps,
                "must be a finite speed >= 0",
            ));
        }
        if !(self.lidar_radius_m > 0.0 && self.lidar_radius_m <= 20.0) {
            return Err(FusionError::field(
                "input.radar_clutter.lidar_radius_m",
                self.lidar_radius_m,
                "must be in (0, 20]",
            ));
        }
        Ok(())
    }
}

impl InputConfig {
    pub fn validate(&self) -> std::result::Result<(), FusionError> {
        if self.lidar_sweeps == 0 || self.lidar_sweeps > 20 {
            return Err(FusionError::field("input.lidar_sweeps", self.lidar_sweeps, "must be in 1..=20"));
        }
        if self.radar_sweeps == 0 || self.radar_sweeps > 20 {
            return Err(FusionError::field("input.radar_sweeps", self.radar_sweeps, "must be in 1..=20"));
        }
        if self.max_sweep_lag_s.is_nan() || self.max_sweep_lag_s <= 0.0 {
            return Err(FusionError::field("input.max_sweep_lag_s", self.max_sweep_lag_s, "must be > 0"));
        }
        if !(self.lidar_min_range_m >= 0.0 && self.lidar_min_range_m <= 20.0) {
            return Err(FusionError::field("input.lidar_min_range_m", self.lidar_min_range_m, "must be in [0, 20] m"));
        }
        if let Some(b) = &self.background {
            b.validate().map_err(|e| FusionError::field(format!("input.{}", e.field), e.value, e.reason))?;
        }
        if let Some(p) = &self.radar_pairs {
            p.validate()?;
        }
        if let Some(c) = &self.radar_clutter {
            c.validate()?;
            if self.background.is_none() {
                return Err(FusionError::field(
                    "input.background",
                    "(not given)",
                    "input.radar_clutter needs it: without the LiDAR background removed every radar detection near \
                     a static surface would count as a road user's",
                ));
            }
        }
        Ok(())
    }
}

/// Global augmentation (roadside: about the scene origin).
///
/// A roadside rig sees one site from fixed poses, and its traffic keeps to the site's lanes:
/// with `keep_site_p` > 0, that share of the draws keeps the site's geometry (rotated by at
/// most `keep_site_rotate_deg`, never mirrored), and only those teach velocity; the others
/// rotate and mirror as `rotate_deg` and `flip_p` say, their velocities unknown (the velocity
/// loss skips them). The boxes, classes and sizes learn from every draw. 0, the default:
/// every draw teaches everything.
#[derive(Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Augmentation {
    /// Uniform rotation in ±this many degrees.
    pub rotate_deg: f32,
    /// Probability of mirroring across the x axis.
    pub flip_p: f32,
    /// Uniform scaling in [1 − s, 1 + s].
    pub scale: f32,
    /// The share of draws that keep the site's geometry and teach velocity (0: off).
    #[serde(skip_serializing_if = "is_zero_f32")]
    pub keep_site_p: f32,
    /// Rotation of a draw that keeps the site's geometry, uniform in ± this many degrees.
    #[serde(skip_serializing_if = "is_fifteen")]
    pub keep_site_rotate_deg: f32,
}

fn is_zero_f32(v: &f32) -> bool {
    *v == 0.0
}

fn is_fifteen(v: &f32) -> bool {
    *v == KEEP_SITE_ROTATE_DEG
}

/// [`Augmentation::keep_site_rotate_deg`]'s default.
pub const KEEP_SITE_ROTATE_DEG: f32 = 15.0;

impl Default for Augmentation {
    fn default() -> Self {
        Augmentation { rotate_deg: 180.0, flip_p: 0.5, scale: 0.05, ..Augmentation::none() }
    }
}

impl Augmentation {
    pub fn none() -> Self {
        Augmentation {
            rotate_deg: 0.0,
            flip_p: 0.0,
            scale: 0.0,
            keep_site_p: 0.0,
            keep_site_rotate_deg: KEEP_SITE_ROTATE_DEG,
        }
    }

    /// The settings' own range: finite angles in [0, 180], probabilities in [0, 1], a scale in
    /// [0, 1).
    pub fn check(&self) -> std::result::Result<(), FusionError> {
        let fields = [
            ("rotate_deg", self.rotate_deg, (0.0..=180.0).contains(&self.rotate_deg), "in [0, 180]"),
            ("flip_p", self.flip_p, (0.0..=1.0).contains(&self.flip_p), "a probability in [0, 1]"),
            ("scale", self.scale, (0.0..1.0).contains(&self.scale), "in [0, 1)"),
            ("keep_site_p", self.keep_site_p, (0.0..=1.0).contains(&self.keep_site_p), "a probability in [0, 1]"),
            (
                "keep_site_rotate_deg",
                self.keep_site_rotate_deg,
                (0.0..=180.0).contains(&self.keep_site_rotate_deg),
                "in [0, 180]",
            ),
        ];
        match fields.iter().find(|f| !f.2) {
            Some((field, v, _, want)) => {
                Err(FusionError::field(format!("train: augmentation.{field}"), v, format!("must be {want}")))
            }
            None => Ok(()),
        }
    }
}

/// As derived, but the site-keeping share appears only when set, so a schedule without it
/// keeps the text (and the stage hashes taken over it) it had before the share existed.
impl std::fmt::Debug for Augmentation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Augmentation");
        d.field("rotate_deg", &self.rotate_deg).field("flip_p", &self.flip_p).field("scale", &self.scale);
        if self.keep_site_p != 0.0 || self.keep_site_rotate_deg != KEEP_SITE_ROTATE_DEG {
            d.field("keep_site_p", &self.keep_site_p).field("keep_site_rotate_deg", &self.keep_site_rotate_deg);
        }
        d.finish()
    }
}

#[derive(Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DecodeConfig {
    pub score_threshold: f32,
    pub max_per_frame: usize,
    /// BEV IoU above which the weaker of two same-class boxes is suppressed (Inside only).
    pub nms_iou: f32,
    /// Each decoded box's velocity from the Doppler of the radar detections inside it, where
    /// they measure it well (`None`: the head's velocity stands; see `hilo_detector::doppler`).
    /// Read from a table of its fields, or `false` (off; what a TOML study file can write, having
    /// no null) or `true` (the defaults).
    #[serde(skip_serializing_if = "Option::is_none", deserialize_with = "radar_velocity_or_flag")]
    pub radar_velocity: Option<RadarVelocityConfig>,
}

impl Default for DecodeConfig {
    fn default() -> Self {
        DecodeConfig { score_threshold: 0.05, max_per_frame: 200, nms_iou: 0.2, radar_velocity: None }
    }
}

/// As derived, but the radar velocity step appears only when set, so a detector without it
/// keeps the text it had before the step existed.
impl std::fmt::Debug for DecodeConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("DecodeConfig");
        d.field("score_threshold", &self.score_threshold)
            .field("max_per_frame", &self.max_per_frame)
            .field("nms_iou", &self.nms_iou);
        if let Some(r) = &self.radar_velocity {
            d.field("radar_velocity", r);
        }
        d.finish()
    }
}

/// How a box's velocity is read from the radar detections inside it. A road user moves along
/// its heading, so each detection's radial velocity v_r = s (u · h), with u its unit line of
/// sight and h the box's heading, gives the speed s; detections whose ground line of sight is
/// more than `max_angle_deg` off the heading (or its reverse) are left out, since their
/// speed's error grows as 1 / cos of that angle. The defaults (1.0 m, 60°, one detection) were
/// chosen on the training split of the default study's cheap rig, over margins of 0.25–1.0 m
/// and angles of 30–75° (docs/measurements.md, "The radar's Doppler read into the boxes").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarVelocityConfig {
    /// The box's footprint is widened by this on every side (bird's-eye view), m: a radar
    /// detection's position is noisy, and the radar and the LiDAR sample a moving road user a
    /// few tens of milliseconds apart.
    pub margin_m: f32,
    /// Largest angle between a detection's ground line of sight and the box's heading axis, deg.
    pub max_angle_deg: f32,
    /// Fewest such detections a box needs; with fewer the head's velocity stands.
    pub min_detections: usize,
    /// The classes whose velocity is read (those that move along their heading).
    pub classes: Vec<Class>,
}

impl Default for RadarVelocityConfig {
    fn default() -> Self {
        RadarVelocityConfig {
            margin_m: 1.0,
            max_angle_deg: 60.0,
            min_detections: 1,
            classes: vec![Class::Car, Class::Truck, Class::Bus, Class::Motorcycle, Class::GolfCart],
        }
    }
}

/// `decode.radar_velocity`: a table of [`RadarVelocityConfig`]'s fields, `true` (its defaults),
/// `false` or null (off). A wrong field keeps serde's own message (the unknown field and the
/// ones expected).
fn radar_velocity_or_flag<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<RadarVelocityConfig>, D::Error> {
    use serde::de::Error;
    match serde_json::Value::deserialize(d)? {
        serde_json::Value::Null | serde_json::Value::Bool(false) => Ok(None),
        serde_json::Value::Bool(true) => Ok(Some(RadarVelocityConfig::default())),
        v => serde_json::from_value(v).map(Some).map_err(D::Error::custom),
    }
}

impl RadarVelocityConfig {
    pub fn validate(&self) -> std::result::Result<(), FusionError> {
        let field = |name: &str, v: &dyn std::fmt::Display, why: &str| {
            Err(FusionError::field(format!("decode.radar_velocity.{name}"), v, why))
        };
        if !(self.margin_m >= 0.0 && self.margin_m <= 5.0) {
            return field("margin_m", &self.margin_m, "must be in [0, 5] m");
        }
        if !(self.max_angle_deg > 0.0 && self.max_angle_deg <= 85.0) {
            return field("max_angle_deg", &self.max_angle_deg, "must be in (0, 85] degrees");
        }
        if self.min_detections == 0 {
            return field("min_detections", &self.min_detections, "must be at least 1");
        }
        if self.classes.is_empty() {
            return field("classes", &"[]", "must name at least one class");
        }
        Ok(())
    }
}

/// How ground truth is assigned to the head's cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Assignment {
    /// CenterPoint: a Gaussian peak at each box centre; regression at the centre cell.
    Center,
    /// Anchor-free PointPillars: every cell whose centre lies in a box footprint is positive
    /// (the centre cell when none does) and regresses that box.
    Inside,
}

/// Which head cells learn a box's velocity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityTarget {
    /// The cells that regress the box: its centre cell under [`Assignment::Center`] (where a
    /// radar point rarely falls), every cell inside it under [`Assignment::Inside`].
    #[default]
    Positives,
    /// Every head cell whose centre lies in the box's footprint (its centre cell when none
    /// does), the cells of one box sharing one box's weight; where footprints overlap, a cell
    /// learns the box whose centre is nearest. The cells holding a box's radar points then
    /// learn its velocity, and the centre cell still does (decoding reads it there).
    Footprint,
}

impl VelocityTarget {
    pub fn is_positives(&self) -> bool {
        *self == VelocityTarget::Positives
    }
}

/// What the detector crate's ground-truth paste fills a frame with.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PasteConfig {
    /// Class name → the number of instances a training frame is filled up to (OpenPCDet's
    /// "sample groups"): a frame holding k of the class receives up to n − k pasted ones (fewer
    /// where they would overlap).
    pub fill: BTreeMap<String, usize>,
    /// Fewest LiDAR points an instance needs to enter the database.
    pub min_lidar_points: usize,
    /// How far outside its box a LiDAR point still belongs to an instance (m; surface noise).
    pub lidar_margin_m: f32,
    /// The same for radar detections (m; the radar's position noise is larger).
    pub radar_margin_m: f32,
}

impl Default for PasteConfig {
    fn default() -> Self {
        PasteConfig {
            fill: [("bus", 2), ("truck", 2), ("golf_cart", 3), ("motorcycle", 2)]
                .into_iter()
                .map(|(c, n)| (c.to_string(), n))
                .collect(),
            min_lidar_points: 5,
            lidar_margin_m: 0.15,
            radar_margin_m: 0.5,
        }
    }
}

impl PasteConfig {
    /// The fill as (class index, count), in class order; errors name the field and value.
    pub fn fill_by_class(&self) -> Result<Vec<(usize, usize)>> {
        let mut out = Vec::new();
        for (name, &n) in &self.fill {
            let c: Class = name.parse().map_err(|_| {
                FusionError::field(
                    "train.paste.fill",
                    format!("{name:?}"),
                    format!("unknown class (one of {})", Class::ALL.map(|c| c.name()).join(", ")),
                )
            })?;
            if n > 64 {
                return Err(FusionError::field(format!("train.paste.fill.{name}"), n, "at most 64 per frame"));
            }
            out.push((c.index(), n));
        }
        out.sort_unstable();
        Ok(out)
    }

    pub fn validate(&self) -> std::result::Result<(), FusionError> {
        self.fill_by_class()?;
        for (field, v) in [("lidar_margin_m", self.lidar_margin_m), ("radar_margin_m", self.radar_margin_m)] {
            if !(v.is_finite() && (0.0..=5.0).contains(&v)) {
                return Err(FusionError::field(format!("train.paste.{field}"), v, "must be within 0..=5 m"));
            }
        }
        Ok(())
    }
}

impl Check for PasteConfig {
    type Error = FusionError;

    fn check(&self) -> std::result::Result<(), FusionError> {
        self.validate()
    }
}

/// A named detector and its default training schedule.
#[derive(Clone, Debug, PartialEq)]
pub struct Preset {
    pub detector: DetectorConfig,
    pub train: TrainConfig,
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The presets fit in a few GB a step even at a GPU's batch of 16 (an upper estimate: every
    /// pillar full); the estimate grows with the batch and the width; a backbone far too wide is
    /// refused before it is built.
    #[test]
    fn the_step_memory_estimate_admits_the_presets_and_refuses_what_cannot_fit() {
        for det in [crate::presets::centerpoint(), crate::presets::pointpillars()] {
            let need = det.step_memory_bytes(16);
            assert!(need > 1e8 && need < 4e9, "{}: {need}", det.name);
            assert!((det.step_memory_bytes(32) - det.step_memory_bytes(16)) > 0.9 * (need - det.step_memory_bytes(0)));
            det.check_memory(16, Some(4 << 30)).unwrap();
            let mut wide = det.clone();
            wide.backbone.blocks.iter_mut().for_each(|b| b.channels *= 16);
            assert!(wide.step_memory_bytes(16) > 2.0 * need);
            let e = wide.check_memory(16, Some(4 << 30)).unwrap_err().to_string();
            assert!(e.contains(&det.name) && e.contains("batch = 16") && e.contains("GB"), "{e}");
            assert!(det.check_memory(16, None).is_ok(), "no figure from the system: no refusal");
        }
        let mut det = crate::presets::centerpoint();
        det.backbone.blocks[0].channels = 1_000_000_000;
        assert!(det.validate().unwrap_err().to_string().contains("1000000000"));
    }

    #[test]
    fn a_schedule_file_overrides_only_its_fields_of_the_preset_schedule() {
        let preset = TrainConfig { samples: 900, ..TrainConfig::default() };
        let fields =
            serde_json::json!({ "lr_max": 0.001, "augmentation": { "rotate_deg": 0.0, "flip_p": 0.0, "scale": 0.0 } });
        let c = preset.with_fields(&fields).unwrap();
        assert_eq!((c.samples, c.batch, c.lr_max, c.augmentation.flip_p), (preset.samples, preset.batch, 0.001, 0.0));
        assert_eq!(c.paste, preset.paste, "the preset's paste is kept");
        assert!(preset.paste.is_some());
        // `null` turns ground-truth paste off; a field of its own changes only that field.
        assert_eq!(preset.with_fields(&serde_json::json!({ "paste": null })).unwrap().paste, None);
        let fill =
            preset.with_fields(&serde_json::json!({ "paste": { "fill": { "bus": 4 } } })).unwrap().paste.unwrap();
        assert_eq!((fill.fill.len(), fill.min_lidar_points), (1, 5));
        let bad = preset.with_fields(&serde_json::json!({ "paste": { "margin": 1 } })).unwrap_err();
        assert!(bad.to_string().contains("margin"), "{bad}");
        // The schedule's check covers its paste: a checked schedule's paste needs no check again.
        let e = preset
            .with_fields(&serde_json::json!({ "paste": { "fill": { "bicycle_bell": 1 } } }))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("train.paste.fill") && e.contains("bicycle_bell"), "{e}");
        let bad = preset.with_fields(&serde_json::json!({ "sampels": 10 })).unwrap_err();
        assert!(bad.to_string().contains("sampels"), "{bad}");
        assert!(preset.with_fields(&serde_json::json!([1, 2])).is_err());
    }

    #[test]
    fn a_detector_patch_changes_only_the_fields_it_names_at_any_depth() {
        let base = crate::presets::centerpoint();
        assert!(base.input.background.is_some());
        let patch = serde_json::json!({ "input": { "lidar_sweeps": 10, "background": null }, "velocity_weight": 1.5 });
        let c = base.with_patch(&patch).unwrap();
        assert_eq!((c.input.lidar_sweeps, c.input.background.is_none(), c.velocity_weight), (10, true, 1.5));
        // Unlike a schedule file's fields, a nested object merges: its siblings stay.
        assert_eq!(
            (c.input.radar_sweeps, &c.input.radar_clutter),
            (base.input.radar_sweeps, &base.input.radar_clutter)
        );
        assert_eq!((&c.grid, &c.backbone, &c.name), (&base.grid, &base.backbone, &base.name));
        assert_eq!(base.with_patch(&serde_json::json!({})).unwrap(), base);
        for (bad, path) in [
            (serde_json::json!({ "input": { "lidar_sweps": 3 } }), "input.lidar_sweps"),
            (serde_json::json!({ "grid": { "cell_m": "fine" } }), "grid.cell_m"),
        ] {
            let e = base.with_patch(&bad).unwrap_err().to_string();
            assert!(e.contains(path), "{e}");
        }
        assert!(base.with_patch(&serde_json::json!("lidar_sweeps")).unwrap_err().to_string().contains("JSON object"));
    }
}
