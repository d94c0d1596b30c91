//! Middle fusion: each modality is encoded to its own BEV map (a pillar feature net per
//! modality; the sparse radar map is widened by a 3×3 convolution), and the maps are fused by
//! φ, selectable: concatenation, a weighted sum with a learned α, adaptive gating per channel or
//! per pixel, or bidirectional enhancement (see `hilo_fusion::fuse::FuseOp`). One scale: the
//! gating acts on the pillar-grid maps before the shared backbone (multi-scale gating inside
//! the backbone is left out to keep the backbone shared by every preset).

use candle_nn::VarBuilder;
use hilo_fusion::data::{LIDAR_FEATURES, RADAR_FEATURES};
use hilo_fusion::fuse::{BevFuse, FuseOp};
use hilo_fusion::grid::BevGrid;
use hilo_fusion::modules::{ConvBn, PillarNet};
use hilo_fusion::{Fusion, FusionInput, FusionOutput, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MiddleConfig {
    pub lidar_channels: usize,
    pub radar_channels: usize,
    pub out_channels: usize,
    pub op: FuseOp,
}

#[derive(Debug)]
pub struct MiddleFusion {
    lidar: PillarNet,
    radar: PillarNet,
    widen: ConvBn,
    fuse: BevFuse,
    cells: usize,
}

pub fn build(cfg: &serde_json::Value, grid: &BevGrid, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    let c: MiddleConfig = hilo_fusion::fusion::parse_config("middle", cfg)?;
    Ok(Box::new(MiddleFusion {
        lidar: PillarNet::new(LIDAR_FEATURES + 5, c.lidar_channels, vb.pp("lidar"))?,
        radar: PillarNet::new(RADAR_FEATURES + 5, c.radar_channels, vb.pp("radar"))?,
        widen: ConvBn::new(c.radar_channels, c.radar_channels, 3, 1, vb.pp("widen"))?,
        fuse: BevFuse::new(c.lidar_channels, c.radar_channels, c.out_channels, c.op, vb.pp("fuse"))?,
        cells: grid.cells(),
    }))
}

/// Registers `middle`.
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("middle", build)
}

impl Fusion for MiddleFusion {
    fn stage(&self) -> Stage {
        Stage::Middle
    }
    fn out_channels(&self) -> usize {
        self.fuse.out_channels
    }
    fn uses_radar(&self) -> bool {
        true
    }
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let l = self.lidar.forward(input.lidar, input.batch, self.cells, train)?;
        let r = self.widen.forward(&self.radar.forward(input.radar, input.batch, self.cells, train)?, train)?;
        Ok(FusionOutput::Bev(self.fuse.forward(&l, &r, train)?))
    }
}
