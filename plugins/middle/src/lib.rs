//! Middle fusion: each modality is encoded to its own BEV map (a pillar feature net per
//! modality; the sparse radar map is widened by a 3×3 convolution), and the maps are fused by
//! φ, selectable: concatenation, a weighted sum with a learned α, adaptive gating per channel or
//! per pixel, bidirectional enhancement, or cross-attention per cell (see
//! `hilo_fusion::fuse::FuseOp`). One scale: the
//! gating acts on the pillar-grid maps before the shared backbone (multi-scale gating inside
//! the backbone is left out to keep the backbone shared by every preset).

use candle_nn::VarBuilder;
use hilo_fusion::config::TrainConfig;
use hilo_fusion::config::{LIDAR_PILLAR_WIDTH, RADAR_PILLAR_WIDTH};
use hilo_fusion::fuse::{BevFuse, FuseOp};
use hilo_fusion::modules::{ConvBn, PillarNet};
use hilo_fusion::presets::centerpoint;
use hilo_fusion::{DetectorConfig, Fusion, FusionInput, FusionOutput, Preset, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MiddleConfig {
    pub lidar_channels: usize,
    pub radar_channels: usize,
    pub out_channels: usize,
    pub op: FuseOp,
}

impl Default for MiddleConfig {
    fn default() -> Self {
        MiddleConfig { lidar_channels: 32, radar_channels: 16, out_channels: 32, op: FuseOp::Concat }
    }
}

#[derive(Debug)]
pub struct MiddleFusion {
    lidar: PillarNet,
    radar: PillarNet,
    widen: ConvBn,
    fuse: BevFuse,
}

pub fn build(c: MiddleConfig, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    Ok(Box::new(MiddleFusion {
        lidar: PillarNet::new(LIDAR_PILLAR_WIDTH, c.lidar_channels, vb.pp("lidar"))?,
        radar: PillarNet::new(RADAR_PILLAR_WIDTH, c.radar_channels, vb.pp("radar"))?,
        widen: ConvBn::new(c.radar_channels, c.radar_channels, 3, 1, vb.pp("widen"))?,
        fuse: BevFuse::new(c.lidar_channels, c.radar_channels, c.out_channels, c.op, vb.pp("fuse"))?,
    }))
}

/// `bi-lrfusion-like` (Bi-LRFusion): LiDAR features enrich the radar BEV map, which then
/// enhances the LiDAR map, on `centerpoint`'s backbone and head. Left out: its query-based
/// height feature transfer (a 3×3 convolution here).
pub fn bi_lrfusion_like() -> DetectorConfig {
    DetectorConfig {
        name: "bi-lrfusion-like".into(),
        input: hilo_fusion::presets::fusion_input(),
        decode: hilo_fusion::presets::fusion_decode(&centerpoint().decode),
        fusion: "middle".into(),
        fusion_config: serde_json::json!({ "lidar_channels": 32, "radar_channels": 16, "out_channels": 32, "op": "bidirectional" }),
        ..centerpoint()
    }
}

/// `middle-attention`: the paper's third middle-fusion operator, attention, as φ (multi-head
/// cross-attention of the LiDAR feature over the cell's LiDAR and radar tokens), on
/// `centerpoint`'s backbone and head.
pub fn middle_attention() -> DetectorConfig {
    DetectorConfig {
        name: "middle-attention".into(),
        input: hilo_fusion::presets::fusion_input(),
        decode: hilo_fusion::presets::fusion_decode(&centerpoint().decode),
        fusion: "middle".into(),
        fusion_config: serde_json::json!({ "lidar_channels": 32, "radar_channels": 16, "out_channels": 32, "op": "attention" }),
        ..centerpoint()
    }
}

/// Registers `middle` and its presets `bi-lrfusion-like` and `middle-attention`.
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("middle", Stage::Middle, build)?;
    r.add_preset(Preset { detector: bi_lrfusion_like(), train: TrainConfig::default() })?;
    r.add_preset(Preset { detector: middle_attention(), train: TrainConfig::default() })
}

impl Fusion for MiddleFusion {
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let at = input.layout.level0();
        let l = self.lidar.forward(input.lidar, input.layout, train)?;
        let r = self.widen.forward(&self.radar.forward(input.radar, input.layout, train)?, at, train)?;
        Ok(FusionOutput::Bev(self.fuse.forward(&l, &r, at, train)?))
    }
}
