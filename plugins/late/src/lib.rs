//! Late fusion: a complete detector per modality — LiDAR (pillar net, backbone, head) and radar
//! (its own pillar net, backbone, head) — trained against the same targets, whose boxes are
//! merged by 3-D IoU matching Ψ (`hilo_fusion::decode::merge_late`: matched pairs fused, position
//! and size weighted towards LiDAR, velocity from radar, scores combined by noisy-OR; unmatched
//! LiDAR boxes kept, unmatched radar boxes kept at half score).

use candle_nn::VarBuilder;
use hilo_fusion::data::{CLASSES, LIDAR_FEATURES, RADAR_FEATURES};
use hilo_fusion::grid::BevGrid;
use hilo_fusion::modules::{Backbone, BackboneConfig, Head, PillarNet};
use hilo_fusion::{Fusion, FusionInput, FusionOutput, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LateConfig {
    pub lidar_channels: usize,
    pub radar_channels: usize,
    /// Backbone of each modality's detector (its out_stride must be the detector's).
    pub backbone: BackboneConfig,
    pub head_channels: usize,
}

#[derive(Debug)]
struct Branch {
    pfn: PillarNet,
    backbone: Backbone,
    head: Head,
}

#[derive(Debug)]
pub struct LateFusion {
    lidar: Branch,
    radar: Branch,
    out_stride: usize,
    cells: usize,
}

fn branch(features: usize, channels: usize, c: &LateConfig, vb: VarBuilder) -> Result<Branch> {
    let pfn = PillarNet::new(features, channels, vb.pp("pfn"))?;
    let backbone = Backbone::new(channels, &c.backbone, vb.pp("backbone"))?;
    let head =
        Head::new(backbone.out_channels, c.head_channels.max(1), CLASSES.len(), c.head_channels > 0, vb.pp("head"))?;
    Ok(Branch { pfn, backbone, head })
}

pub fn build(cfg: &serde_json::Value, grid: &BevGrid, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    let c: LateConfig = hilo_fusion::fusion::parse_config("late", cfg)?;
    Ok(Box::new(LateFusion {
        lidar: branch(LIDAR_FEATURES + 5, c.lidar_channels, &c, vb.pp("lidar"))?,
        radar: branch(RADAR_FEATURES + 5, c.radar_channels, &c, vb.pp("radar"))?,
        out_stride: c.backbone.out_stride,
        cells: grid.cells(),
    }))
}

/// Registers `late`.
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("late", build)
}

impl Fusion for LateFusion {
    fn stage(&self) -> Stage {
        Stage::Late
    }
    fn out_channels(&self) -> usize {
        0
    }
    fn uses_radar(&self) -> bool {
        true
    }
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let mut heads = Vec::new();
        for (b, p) in [(&self.lidar, input.lidar), (&self.radar, input.radar)] {
            let bev = b.pfn.forward(p, input.batch, self.cells, train)?;
            let x = b.backbone.forward(&bev, self.out_stride, train)?;
            heads.push(b.head.forward(&x, train)?);
        }
        Ok(FusionOutput::Heads(heads))
    }
}
