//! Early fusion: the combined point space is pillarised with one joint encoder over mixed
//! features, and aggregated per cell by A (mean or max). Every point, LiDAR or radar, is
//! written in one layout: x, y, z, PointPillars' five decorations, LiDAR intensity, radar RCS,
//! radial velocity and line of sight (zeros where a modality has no such field) and a modality
//! flag; a shared linear layer, BatchNorm and ReLU encode it; a cell's feature is the mean or
//! maximum over all its points of both modalities. Decorations are taken per modality (offsets
//! from the modality's own pillar mean), a simplification of a joint pillar mean.
//!
//! Optionally (`middle`), a LiDAR-only pillar branch is fused with the joint map by φ
//! (LiRaFusion's joint voxel encoder + adaptive gating; L4DR's early radar–LiDAR fusion +
//! gated middle fusion). `early = false` is the paper's ablation: the joint encoder then sees
//! the radar points only, so LiDAR and radar meet only in the middle stage.

use candle_core::{DType, Tensor};
use candle_nn::{BatchNorm, Linear, Module, ModuleT, VarBuilder};
use hilo_fusion::data::LIDAR_FEATURES;
use hilo_fusion::fuse::{BevFuse, FuseOp};
use hilo_fusion::grid::BevGrid;
use hilo_fusion::modules::{PillarNet, PillarTensors};
use hilo_fusion::{Fusion, FusionError, FusionInput, FusionOutput, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

const JOINT: usize = 14;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Aggregation {
    Mean,
    Max,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MiddleStage {
    pub lidar_channels: usize,
    pub out_channels: usize,
    pub op: FuseOp,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EarlyConfig {
    pub channels: usize,
    pub aggregation: Aggregation,
    /// Whether LiDAR points enter the joint encoder (false: the paper's ablation).
    #[serde(default = "yes")]
    pub early: bool,
    #[serde(default)]
    pub middle: Option<MiddleStage>,
}

fn yes() -> bool {
    true
}

#[derive(Debug)]
pub struct EarlyFusion {
    cfg: EarlyConfig,
    linear: Linear,
    bn: BatchNorm,
    lidar: Option<PillarNet>,
    fuse: Option<BevFuse>,
    cells: usize,
}

/// Column `k` of the joint layout each input feature goes to.
const LIDAR_TO_JOINT: [usize; 9] = [0, 1, 2, 8, 3, 4, 5, 6, 7];
const RADAR_TO_JOINT: [usize; 12] = [0, 1, 2, 9, 10, 11, 12, 3, 4, 5, 6, 7];

fn selection(map: &[usize], dev: &candle_core::Device) -> Result<Tensor> {
    let mut m = vec![0f32; map.len() * JOINT];
    for (i, &k) in map.iter().enumerate() {
        m[i * JOINT + k] = 1.0;
    }
    Ok(Tensor::from_vec(m, (map.len(), JOINT), dev)?)
}

pub fn build(cfg: &serde_json::Value, grid: &BevGrid, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    let c: EarlyConfig = hilo_fusion::fusion::parse_config("early", cfg)?;
    let bn = candle_nn::batch_norm(c.channels, candle_nn::BatchNormConfig { eps: 1e-3, remove_mean: true, affine: true, momentum: 0.1 }, vb.pp("joint_bn"))?;
    let (lidar, fuse) = match &c.middle {
        Some(m) => (Some(PillarNet::new(LIDAR_FEATURES + 5, m.lidar_channels, vb.pp("lidar"))?), Some(BevFuse::new(m.lidar_channels, c.channels, m.out_channels, m.op, vb.pp("fuse"))?)),
        None => (None, None),
    };
    if c.middle.is_none() && !c.early {
        return Err(FusionError::Config("fusion plugin \"early\": early = false needs a middle stage (otherwise LiDAR is never used)".into()));
    }
    Ok(Box::new(EarlyFusion { linear: candle_nn::linear_no_bias(JOINT, c.channels, vb.pp("joint"))?, bn, lidar, fuse, cells: grid.cells(), cfg: c }))
}

/// Registers `early`.
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("early", build)
}

impl EarlyFusion {
    /// Joint-layout point features (P, N, 14) of one modality.
    fn to_joint(p: &PillarTensors, map: &[usize], flag: bool) -> Result<Tensor> {
        let (n, npp, f) = p.features.dims3()?;
        let sel = selection(map, p.features.device())?;
        let x = p.features.reshape((n * npp, f))?.matmul(&sel)?.reshape((n, npp, JOINT))?;
        if !flag {
            return Ok(x);
        }
        // The modality flag is 1 on real radar points.
        let mut e = vec![0f32; JOINT];
        e[JOINT - 1] = 1.0;
        let e = Tensor::from_vec(e, (1, 1, JOINT), p.features.device())?;
        Ok((x + p.mask.broadcast_mul(&e)?)?)
    }

    /// Per-pillar (sum or max, count) of the joint encoding for each present modality.
    fn joint_map(&self, input: &FusionInput, train: bool) -> Result<Tensor> {
        let dev = input.lidar.features.device().clone();
        let mut parts: Vec<(Tensor, &PillarTensors)> = Vec::new();
        if self.cfg.early && input.lidar.count > 0 {
            parts.push((Self::to_joint(input.lidar, &LIDAR_TO_JOINT, false)?, input.lidar));
        }
        if input.radar.count > 0 {
            parts.push((Self::to_joint(input.radar, &RADAR_TO_JOINT, true)?, input.radar));
        }
        let c = self.cfg.channels;
        let hw = input.batch * self.cells * self.cells;
        let bev = |flat: Tensor| -> Result<Tensor> { Ok(flat.reshape((input.batch, self.cells, self.cells, c))?.permute((0, 3, 1, 2))?.contiguous()?) };
        if parts.is_empty() {
            return bev(Tensor::zeros((hw, c), DType::F32, &dev)?);
        }
        // One BatchNorm over the points of both modalities.
        let rows: Vec<Tensor> = parts.iter().map(|(x, _)| x.reshape(((), JOINT))).collect::<candle_core::Result<_>>()?;
        let sizes: Vec<usize> = rows.iter().map(|r| r.dim(0)).collect::<candle_core::Result<_>>()?;
        let all = self.bn.forward_t(&self.linear.forward(&Tensor::cat(&rows, 0)?)?, train)?.relu()?;
        let mut offset = 0;
        let mut acc = Tensor::zeros((hw, c), DType::F32, &dev)?;
        let mut count = Tensor::zeros((hw, 1), DType::F32, &dev)?;
        for ((_, p), rows_k) in parts.iter().zip(sizes) {
            let (n, npp, _) = p.features.dims3()?;
            let x = all.narrow(0, offset, rows_k)?.reshape((n, npp, c))?.broadcast_mul(&p.mask)?;
            offset += rows_k;
            match self.cfg.aggregation {
                Aggregation::Max => acc = acc.maximum(&Tensor::zeros((hw, c), DType::F32, &dev)?.index_add(&p.index, &x.max(1)?, 0)?)?,
                Aggregation::Mean => {
                    acc = acc.index_add(&p.index, &x.sum(1)?, 0)?;
                    count = count.index_add(&p.index, &p.mask.sum(1)?, 0)?;
                }
            }
        }
        if self.cfg.aggregation == Aggregation::Mean {
            acc = acc.broadcast_div(&count.clamp(1.0, f32::MAX)?)?;
        }
        bev(acc)
    }
}

impl Fusion for EarlyFusion {
    fn stage(&self) -> Stage {
        Stage::Early
    }
    fn out_channels(&self) -> usize {
        self.fuse.as_ref().map_or(self.cfg.channels, |f| f.out_channels)
    }
    fn uses_radar(&self) -> bool {
        true
    }
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let joint = self.joint_map(input, train)?;
        match (&self.lidar, &self.fuse) {
            (Some(l), Some(f)) => {
                let lm = l.forward(input.lidar, input.batch, self.cells, train)?;
                Ok(FusionOutput::Bev(f.forward(&lm, &joint, train)?))
            }
            _ => Ok(FusionOutput::Bev(joint)),
        }
    }
}
