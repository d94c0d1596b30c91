//! The LiDAR-only presets, and the parts every preset shares: the grid, what the network reads,
//! the sparse layout and the backbone shapes. Fusion presets are registered by their plugin
//! crates, on top of these.

use crate::config::{
    Assignment, DecodeConfig, DetectorConfig, InputConfig, LossNorm, Preset, RadarClutterConfig, RadarPairConfig,
    RadarVelocityConfig, TrainConfig, VelocityTarget,
};
use crate::grid::BevGrid;
use crate::layout::SparseConfig;
use crate::modules::{BackboneConfig, BlockConfig};
use hilo_core::background::BackgroundConfig;

fn block(stride: usize, channels: usize, layers: usize) -> BlockConfig {
    BlockConfig { stride, channels, layers }
}

/// What every preset reads: LiDAR without its static background, one radar sweep without its
/// static clutter.
pub fn default_input() -> InputConfig {
    InputConfig {
        background: Some(BackgroundConfig::default()),
        radar_clutter: Some(RadarClutterConfig::default()),
        ..InputConfig::default()
    }
}

/// What every fusion preset reads: [`default_input`], and on a rig of two or more radars each
/// detection that another radar sees too carrying the full ground velocity the two radial
/// velocities give ([`RadarPairConfig`]'s defaults). With one radar no detection is paired, so
/// the input is [`default_input`]'s, point for point.
pub fn fusion_input() -> InputConfig {
    InputConfig { radar_pairs: Some(RadarPairConfig::default()), ..default_input() }
}

/// What every fusion preset decodes: `base`'s settings, and each vehicle box's velocity read from
/// the Doppler of the radar detections inside it where they measure it
/// ([`RadarVelocityConfig`]'s defaults; `hilo_detector::doppler`). The head's velocity stands
/// for the boxes no radar detection measures (outside every radar's field, across its line of
/// sight, or unseen). A patch turns the step off: `{"decode": {"radar_velocity": false}}` for
/// `hilo train --detector-patch`, `decode = { radar_velocity = false }` under a study's
/// `[detector_patch]`.
pub fn fusion_decode(base: &DecodeConfig) -> DecodeConfig {
    DecodeConfig { radar_velocity: Some(RadarVelocityConfig::default()), ..base.clone() }
}

/// `centerpoint`: PointPillars' pillar encoder (32 channels), a backbone at strides 2/4/8
/// (32/64/128 channels; three 3×3 convolutions at strides 2 and 4, the stride-8 block its strided
/// convolution alone), a neck back to the pillar grid (stride 1, 0.8 m cells, 16 channels per
/// block), CenterPoint's head (Gaussian heatmaps, a 3×3 convolution of 16 channels per task,
/// peak extraction), on the occupied cells only (sparse, head sites dilated by 2 cells), its
/// losses normalised by the positives of all classes ([`LossNorm::All`]; CenterPoint's per-task
/// normalisation, [`LossNorm::PerClass`], was measured and not adopted: docs/measurements.md has why).
/// Left out: the voxel (sparse 3-D) encoder of CenterPoint-Voxel, the second refinement stage,
/// multi-group heads, circular NMS, and the stride-8 block's two further 3×3 layers (at 128
/// channels, about half a step's multiply-adds for no measured gain in mAP: "Level 3" in
/// docs/measurements.md). The fusion presets share this backbone.
pub fn centerpoint() -> DetectorConfig {
    DetectorConfig {
        name: "centerpoint".into(),
        fusion: "lidar".into(),
        fusion_config: serde_json::json!({ "channels": 32 }),
        grid: BevGrid::default(),
        backbone: BackboneConfig {
            blocks: vec![block(2, 32, 2), block(2, 64, 2), block(2, 128, 0)],
            neck_channels: 16,
            out_stride: 1,
        },
        assignment: Assignment::Center,
        head_channels: 16,
        decode: DecodeConfig::default(),
        input: default_input(),
        sparse: Some(SparseConfig::default()),
        loss_norm: LossNorm::All,
        velocity_weight: 0.2,
        velocity_target: VelocityTarget::Positives,
        cyclists: false,
    }
}

/// `pointpillars`: the same encoder at 48 channels, a backbone at strides 2/4/8 (48/96/128),
/// neck to stride 2, and an anchor-free version of PointPillars' SSD head: 1×1 convolutions,
/// every cell inside a box footprint is positive (instead of anchors matched by IoU), sigmoid
/// focal loss, rotated-BEV NMS. Left out: anchors and their IoU matching, the direction
/// classifier (yaw is regressed as sin/cos instead).
pub fn pointpillars() -> DetectorConfig {
    DetectorConfig {
        name: "pointpillars".into(),
        fusion: "lidar".into(),
        fusion_config: serde_json::json!({ "channels": 48 }),
        backbone: BackboneConfig {
            blocks: vec![block(2, 48, 1), block(2, 96, 2), block(2, 128, 2)],
            neck_channels: 48,
            out_stride: 2,
        },
        assignment: Assignment::Inside,
        head_channels: 0,
        decode: dense_head_decode(),
        ..centerpoint()
    }
}

/// The schedule of the presets whose plateau was measured (`lirafusion-like` here, and
/// `centerpoint` over more samples, [`centerpoint_schedule`]): the shared one's shape over
/// 24,000 samples, each batch of two run as two data-parallel replicas of one sample (one per
/// core on two cores: with one replica training leaves the second core idle) with BatchNorm
/// synchronised across them, so the step normalises as a batch of two does (BatchNorm over one
/// sample costs more accuracy than the speed it buys). The schedule is fixed in samples, sized
/// to train the fused preset in about five minutes on two cores; docs/measurements.md has the
/// trainings, their times and the gains of four times this schedule.
pub fn plateau_schedule() -> TrainConfig {
    TrainConfig { samples: 24_000, replicas: 2, sync_batch_norm: true, ..TrainConfig::default() }
}

/// `centerpoint`'s schedule: [`plateau_schedule`] over 30,000 samples, what its speed allows
/// within about five minutes on two cores with synchronised replicas (docs/measurements.md has
/// the trainings). Ground-truth paste raises what it can reach more than what it learns in a
/// short schedule, so it takes every sample the budget buys.
pub fn centerpoint_schedule() -> TrainConfig {
    TrainConfig { samples: 30_000, ..plateau_schedule() }
}

/// The presets of the LiDAR-only plugin, with their training schedules.
pub fn lidar_only() -> Vec<Preset> {
    vec![
        Preset { detector: centerpoint(), train: centerpoint_schedule() },
        Preset { detector: pointpillars(), train: TrainConfig::default() },
    ]
}

/// Decode settings shared by presets with an anchor-free dense head.
pub fn dense_head_decode() -> DecodeConfig {
    DecodeConfig { score_threshold: 0.1, ..DecodeConfig::default() }
}
