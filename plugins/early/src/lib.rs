//! Early fusion: the combined point space is pillarised with one joint encoder over mixed features,
//! and aggregated per cell by A (max or mean, over all points or per modality). Every point, LiDAR or radar, is
//! written in one layout: x, y, z, PointPillars' five decorations, LiDAR intensity, radar RCS,
//! radial velocity, line of sight, sweep lag and radial velocity vector (zeros where a modality
//! has no such field) and a modality flag; a shared linear layer, BatchNorm and ReLU encode it; a cell's feature aggregates the
//! encodings of all its points of both modalities by A: the maximum, the mean, or the mean or
//! maximum per modality summed (`modality_mean`, `modality_max`: LiDAR's plus radar's, so each
//! modality counts once in a cell). The plain mean lets a cell's many LiDAR points drown its one or two radar points: on
//! the motion fixture (`crates/cli/tests/fusion_motion.rs`) `lirafusion-like` with it stayed at
//! LiDAR-only mAP (0.41 against 0.43), with `modality_mean` it reaches 0.97. Decorations are taken
//! per modality (offsets from the modality's own pillar mean), a simplification of a joint pillar
//! mean. The encoder runs on the real points alone (a pillar fills about three of its 10 slots on a
//! roadside frame), its BatchNorm counting the padding slots as the zero rows they are in the
//! padded form, so the function is that of the padded pillars (docs/measurements.md has what it
//! saves).
//!
//! Optionally (`middle`), a LiDAR-only pillar branch is fused with the joint map by φ
//! (LiRaFusion's joint voxel encoder + adaptive gating; L4DR's early radar–LiDAR fusion +
//! gated middle fusion). `early = false` is the paper's ablation: the joint encoder then sees
//! the radar points only, so LiDAR and radar meet only in the middle stage.

use candle_core::{DType, Tensor};
use candle_nn::{BatchNorm, Linear, Module, VarBuilder};
use hilo_fusion::config::LIDAR_PILLAR_WIDTH;
use hilo_fusion::config::TrainConfig;
use hilo_fusion::fuse::{BevFuse, FuseOp};
use hilo_fusion::modules::{PillarNet, PillarTensors};
use hilo_fusion::presets::centerpoint;
use hilo_fusion::{DetectorConfig, Fusion, FusionError, FusionInput, FusionOutput, Preset, Registry, Result, Stage};
use serde::{Deserialize, Serialize};

/// Joint point layout: x, y, z, five decorations, intensity, RCS, v_r, line of sight x, y,
/// sweep lag (either modality's), radial velocity x, y, modality flag.
const JOINT: usize = 17;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Aggregation {
    /// Mean over all of a cell's points, LiDAR and radar alike.
    Mean,
    /// Mean over the cell's LiDAR points plus mean over its radar points: each modality counts
    /// once in a cell, whatever its point count.
    ModalityMean,
    /// Maximum over all of a cell's points, LiDAR and radar alike.
    Max,
    /// Maximum over the cell's LiDAR points plus maximum over its radar points: a radar
    /// point's encoding reaches the map whatever the cell's LiDAR points encode.
    ModalityMax,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MiddleStage {
    pub lidar_channels: usize,
    pub out_channels: usize,
    pub op: FuseOp,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EarlyConfig {
    pub channels: usize,
    pub aggregation: Aggregation,
    /// Whether LiDAR points enter the joint encoder (false: the paper's ablation).
    pub early: bool,
    pub middle: Option<MiddleStage>,
}

impl Default for EarlyConfig {
    fn default() -> Self {
        EarlyConfig { channels: 32, aggregation: Aggregation::ModalityMean, early: true, middle: None }
    }
}

#[derive(Debug)]
pub struct EarlyFusion {
    cfg: EarlyConfig,
    linear: Linear,
    bn: BatchNorm,
    lidar: Option<PillarNet>,
    fuse: Option<BevFuse>,
}

/// Column `k` of the joint layout each input feature goes to.
const LIDAR_TO_JOINT: [usize; LIDAR_PILLAR_WIDTH] = [0, 1, 2, 8, 13, 3, 4, 5, 6, 7];
const RADAR_TO_JOINT: [usize; hilo_fusion::config::RADAR_PILLAR_WIDTH] =
    [0, 1, 2, 9, 10, 11, 12, 13, 14, 15, 3, 4, 5, 6, 7];

fn selection(map: &[usize], dev: &candle_core::Device) -> Result<Tensor> {
    let mut m = vec![0f32; map.len() * JOINT];
    for (i, &k) in map.iter().enumerate() {
        m[i * JOINT + k] = 1.0;
    }
    Ok(Tensor::from_vec(m, (map.len(), JOINT), dev)?)
}

pub fn build(c: EarlyConfig, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    Ok(Box::new(EarlyFusion::new(c, vb)?))
}

impl EarlyFusion {
    fn new(c: EarlyConfig, vb: VarBuilder) -> Result<Self> {
        let bn = candle_nn::batch_norm(
            c.channels,
            candle_nn::BatchNormConfig { eps: 1e-3, remove_mean: true, affine: true, momentum: 0.1 },
            vb.pp("joint_bn"),
        )?;
        let (lidar, fuse) = match &c.middle {
            Some(m) => (
                Some(PillarNet::new(LIDAR_PILLAR_WIDTH, m.lidar_channels, vb.pp("lidar"))?),
                Some(BevFuse::new(m.lidar_channels, c.channels, m.out_channels, m.op, vb.pp("fuse"))?),
            ),
            None => (None, None),
        };
        if c.middle.is_none() && !c.early {
            return Err(FusionError::Config(
                "fusion plugin \"early\": early = false needs a middle stage (otherwise LiDAR is never used)".into(),
            ));
        }
        Ok(EarlyFusion {
            linear: candle_nn::linear_no_bias(JOINT, c.channels, vb.pp("joint"))?,
            bn,
            lidar,
            fuse,
            cfg: c,
        })
    }
}

/// `l4dr-like` (L4DR): early LiDAR–4D-radar fusion and gated middle fusion, on `centerpoint`'s
/// backbone and head. Taken: radar and LiDAR points in one early encoder, pooled per cell by a
/// maximum per modality (LiDAR's plus radar's), and pixel-wise gating against a LiDAR branch.
/// L4DR keeps an intra-modal radar path beside the inter-modal one; with one maximum over all of
/// a cell's points, a radar point's Doppler reached the map only in channels where it beat every
/// LiDAR point, and on the motion fixture one training seed of five stayed at the LiDAR-only
/// level (docs/measurements.md). Left out: L4DR's LiDAR-guided radar denoising, its point-level
/// feature exchange and its multi-scale gates inside the backbone.
pub fn l4dr_like() -> DetectorConfig {
    DetectorConfig {
        name: "l4dr-like".into(),
        input: hilo_fusion::presets::fusion_input(),
        decode: hilo_fusion::presets::fusion_decode(&centerpoint().decode),
        fusion: "early".into(),
        fusion_config: serde_json::json!({ "channels": 32, "aggregation": "modality_max", "early": true, "middle": { "lidar_channels": 32, "out_channels": 32, "op": "gated_pixel" } }),
        ..centerpoint()
    }
}

/// `lirafusion-like` (LiRaFusion): a joint voxel encoder over both modalities (early; per-cell
/// means taken per modality, so a cell's few radar points are not averaged away by its LiDAR
/// points) and adaptive gated fusion with one weight per channel, on `centerpoint`'s backbone
/// and head. Left out: the 3-D voxel encoder (pillars instead) and the exact gating network.
pub fn lirafusion_like() -> DetectorConfig {
    DetectorConfig {
        name: "lirafusion-like".into(),
        input: hilo_fusion::presets::fusion_input(),
        decode: hilo_fusion::presets::fusion_decode(&centerpoint().decode),
        fusion: "early".into(),
        fusion_config: serde_json::json!({ "channels": 32, "aggregation": "modality_mean", "early": true, "middle": { "lidar_channels": 32, "out_channels": 32, "op": "gated_channel" } }),
        ..centerpoint()
    }
}

/// `lirafusion-like`'s default schedule: [`hilo_fusion::presets::plateau_schedule`] (24,000
/// samples, batches of two as two data-parallel replicas with synchronised BatchNorm), about
/// five minutes on two cores. docs/measurements.md has the trainings and the gains of four
/// times this schedule.
pub fn lirafusion_like_schedule() -> TrainConfig {
    hilo_fusion::presets::plateau_schedule()
}

/// The paper's ablation: the preset without its early stage (LiDAR points no longer enter the
/// joint encoding; radar alone does).
pub fn without_early(cfg: &DetectorConfig) -> Result<DetectorConfig> {
    if cfg.fusion != "early" {
        return Err(FusionError::Config(format!("detector {} has no early fusion stage to remove", cfg.name)));
    }
    let mut c = cfg.clone();
    c.fusion_config["early"] = serde_json::Value::Bool(false);
    c.name = format!("{}-no-early", cfg.name);
    Ok(c)
}

/// Registers `early` and its presets: `l4dr-like`, `lirafusion-like`, and each without its early
/// stage (`*-no-early`, the paper's ablation: LiDAR and radar meet only in the middle stage, on
/// the same schedule as the preset it ablates).
pub fn register(r: &mut Registry) -> Result<()> {
    r.register("early", Stage::Early, build)?;
    for (d, train) in [(l4dr_like(), TrainConfig::default()), (lirafusion_like(), lirafusion_like_schedule())] {
        let ablation = without_early(&d)?;
        let of = d.name.clone();
        r.add_preset(Preset { detector: d, train: train.clone() })?;
        r.add_ablation(&of, Preset { detector: ablation, train })?;
    }
    Ok(())
}

impl EarlyFusion {
    /// Joint-layout rows `(R, 15)` of one modality's real points (padding left out).
    fn to_joint(p: &PillarTensors, map: &[usize], flag: bool) -> Result<Tensor> {
        let sel = selection(map, p.points.device())?;
        let x = p.points.matmul(&sel)?;
        if !flag {
            return Ok(x);
        }
        // The modality flag is 1 on every (real) radar point.
        let mut e = vec![0f32; JOINT];
        e[JOINT - 1] = 1.0;
        Ok(x.broadcast_add(&Tensor::from_vec(e, (1, JOINT), p.points.device())?)?)
    }

    /// The joint map: the encodings of the real points of each present modality, aggregated
    /// per cell. BatchNorm counts the padding slots as the zero rows they are in the padded
    /// layout ([`hilo_fusion::bnrelu::bn_relu_padded`]), so the encoder computes only the points
    /// there are and gives what it gave on the padded pillars.
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
        let layout = input.layout;
        if parts.is_empty() {
            if !(train && hilo_fusion::bnrelu::synced()) {
                return layout.from_rows(layout.zeros(c, &dev)?);
            }
            // A synchronised replica meets the others at the BatchNorm, with no rows.
            parts.push((Tensor::zeros((0, JOINT), DType::F32, &dev)?, input.radar));
        }
        // One BatchNorm over the points of both modalities.
        let rows: Vec<&Tensor> = parts.iter().map(|(x, _)| x).collect();
        let sizes: Vec<usize> = rows.iter().map(|r| r.dim(0)).collect::<candle_core::Result<_>>()?;
        let padding = parts.iter().map(|(_, p)| p.padding).sum();
        let all = hilo_fusion::bnrelu::bn_relu_padded(
            &self.bn,
            &self.linear.forward(&Tensor::cat(&rows, 0)?)?,
            padding,
            train,
        )?;
        let mut offset = 0;
        let mut acc = layout.zeros(c, &dev)?;
        let mut count = layout.zeros(1, &dev)?;
        for ((_, p), rows_k) in parts.iter().zip(sizes) {
            let x = all.narrow(0, offset, rows_k)?;
            offset += rows_k;
            if rows_k == 0 {
                // No points: nothing to aggregate (candle reduces no empty tensor), but the
                // rows stay in the graph so the backward pass meets the other replicas too.
                acc = acc.index_add(&p.point_rows, &x, 0)?;
                continue;
            }
            match self.cfg.aggregation {
                Aggregation::Max => {
                    let max = p.max_per_pillar(&x)?;
                    acc = acc.maximum(&layout.zeros(c, &dev)?.index_add(&p.index, &max, 0)?)?;
                }
                Aggregation::Mean => {
                    acc = acc.index_add(&p.point_rows, &x, 0)?;
                    count = count.index_add(&p.point_rows, &Tensor::ones((rows_k, 1), DType::F32, &dev)?, 0)?;
                }
                Aggregation::ModalityMean => {
                    acc = acc.index_add(&p.point_rows, &x.broadcast_mul(&p.point_share)?, 0)?;
                }
                Aggregation::ModalityMax => {
                    acc = acc.index_add(&p.index, &p.max_per_pillar(&x)?, 0)?;
                }
            }
        }
        if self.cfg.aggregation == Aggregation::Mean {
            acc = acc.broadcast_div(&count.clamp(1.0, f32::MAX)?)?;
        }
        layout.from_rows(acc)
    }
}

impl Fusion for EarlyFusion {
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        let joint = self.joint_map(input, train)?;
        match (&self.lidar, &self.fuse) {
            (Some(l), Some(f)) => {
                let lm = l.forward(input.lidar, input.layout, train)?;
                Ok(FusionOutput::Bev(f.forward(&lm, &joint, input.layout.level0(), train)?))
            }
            _ => Ok(FusionOutput::Bev(joint)),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::ModuleT;
    use hilo_fusion::config::radar_point;
    use hilo_fusion::grid::small_grid;
    use hilo_fusion::layout::Layout;
    use hilo_fusion::pillars::pillarize;

    /// Per modality and pillar, the encodings of its real points, computed on the padded
    /// features and the mask (not the packed rows the plugin reads): every slot of both
    /// modalities through the linear layer and one BatchNorm (in training over all slots, the
    /// padding included, as the padded form normalised), then the real slots kept.
    fn encodings(
        f: &EarlyFusion,
        parts: [(&PillarTensors, &[usize], bool); 2],
        train: bool,
    ) -> Vec<Vec<Vec<Vec<f32>>>> {
        let dev = Device::Cpu;
        let mut rows = Vec::new();
        for (p, map, flag) in parts {
            let (n, npp, w) = p.features.dims3().unwrap();
            let x = p.features.reshape((n * npp, w)).unwrap().matmul(&selection(map, &dev).unwrap()).unwrap();
            let mut e = vec![0f32; JOINT];
            e[JOINT - 1] = 1.0;
            let e = Tensor::from_vec(e, (1, JOINT), &dev).unwrap();
            // The flag on real radar points only: a padding slot is a zero row.
            let flagged = p.mask.reshape((n * npp, 1)).unwrap().broadcast_mul(&e).unwrap();
            rows.push(if flag { (x + flagged).unwrap() } else { x });
        }
        let h = f.linear.forward(&Tensor::cat(&rows, 0).unwrap()).unwrap();
        let h = if train {
            hilo_fusion::bnrelu::bn_relu(&f.bn, &h, true).unwrap()
        } else {
            f.bn.forward_t(&h, false).unwrap().relu().unwrap()
        };
        let mut offset = 0;
        parts
            .iter()
            .map(|(p, _, _)| {
                let (n, npp, _) = p.features.dims3().unwrap();
                let e = h.narrow(0, offset, n * npp).unwrap();
                offset += n * npp;
                let e = e.reshape((n, npp, f.cfg.channels)).unwrap().to_vec3::<f32>().unwrap();
                let mask = p.mask.squeeze(2).unwrap().to_vec2::<f32>().unwrap();
                e.into_iter()
                    .zip(mask)
                    .map(|(rows, m)| rows.into_iter().zip(m).filter(|(_, m)| *m > 0.5).map(|(r, _)| r).collect())
                    .collect()
            })
            .collect()
    }

    /// The joint map of each aggregation against a per-cell loop over the points' encodings: a
    /// cell with nine LiDAR points and one radar point, a LiDAR-only cell, a radar-only cell; in
    /// evaluation (each point normalised on its own) and in training, where the plugin's
    /// encoder on the real points must normalise as the padded slots did.
    #[test]
    fn aggregations_match_a_per_cell_oracle() {
        let grid = small_grid();
        let lidar: Vec<[f32; hilo_fusion::config::LIDAR_FEATURES]> = (0..9)
            .map(|k| [1.1 + 0.05 * k as f32, 2.1 + 0.03 * k as f32, 0.2 * k as f32, 0.3, 0.0])
            .chain((0..3).map(|k| [-4.3, 5.2 + 0.1 * k as f32, 0.5, 0.8, 0.1]))
            .collect();
        let radar: Vec<[f32; hilo_fusion::config::RADAR_FEATURES]> = vec![
            radar_point([1.2, 2.2, 0.9], 8.0, 7.0, [0.1, 0.99], 0.0),
            radar_point([6.1, -3.3, 0.4], 3.0, -2.0, [0.8, 0.6], 0.1),
            radar_point([6.2, -3.4, 0.6], 5.0, -2.5, [0.8, 0.6], 0.0),
        ];
        let dev = Device::Cpu;
        let (lt, rt) = (
            PillarTensors::new(&pillarize(&grid, &[&lidar], 0), None, &dev).unwrap(),
            PillarTensors::new(&pillarize(&grid, &[&radar], 0), None, &dev).unwrap(),
        );
        let layout = Layout::Dense { batch: 1, cells: grid.cells() };
        let modes = [Aggregation::Max, Aggregation::Mean, Aggregation::ModalityMean, Aggregation::ModalityMax];
        for (aggregation, train) in modes.into_iter().flat_map(|a| [(a, false), (a, true)]) {
            let varmap = candle_nn::VarMap::new();
            let cfg = EarlyConfig { channels: 8, aggregation, early: true, middle: None };
            let f = EarlyFusion::new(cfg, VarBuilder::from_varmap(&varmap, DType::F32, &dev)).unwrap();
            let map =
                f.joint_map(&FusionInput { lidar: &lt, radar: &rt, batch: 1, grid, layout: &layout }, train).unwrap();
            let map = map.squeeze(0).unwrap().to_vec3::<f32>().unwrap();
            // Points per cell, per modality.
            let mut cells: std::collections::BTreeMap<u32, [Vec<Vec<f32>>; 2]> = Default::default();
            let parts = [(&lt, &LIDAR_TO_JOINT[..], false), (&rt, &RADAR_TO_JOINT[..], true)];
            for (m, (p, per_pillar)) in parts.iter().zip(encodings(&f, parts, train)).enumerate() {
                let index = p.0.index.to_vec1::<u32>().unwrap();
                for (cell, points) in index.into_iter().zip(per_pillar) {
                    cells.entry(cell).or_default()[m].extend(points);
                }
            }
            assert_eq!(cells.len(), 3, "three occupied cells");
            let n = grid.cells();
            for (cell, [l, r]) in &cells {
                let (row, col) = (*cell as usize / n, *cell as usize % n);
                for c in 0..8 {
                    let mean = |v: &Vec<Vec<f32>>| {
                        if v.is_empty() { 0.0 } else { v.iter().map(|e| e[c]).sum::<f32>() / v.len() as f32 }
                    };
                    let max = |v: &Vec<Vec<f32>>| v.iter().fold(0.0f32, |a, e| a.max(e[c]));
                    let all: Vec<f32> = l.iter().chain(r).map(|e| e[c]).collect();
                    let want = match aggregation {
                        Aggregation::Max => all.iter().fold(0.0f32, |a, &b| a.max(b)),
                        Aggregation::Mean => all.iter().sum::<f32>() / all.len() as f32,
                        Aggregation::ModalityMean => mean(l) + mean(r),
                        Aggregation::ModalityMax => max(l) + max(r),
                    };
                    let got = map[c][row][col];
                    assert!(
                        (got - want).abs() <= 1e-5 * (1.0 + want.abs()),
                        "{aggregation:?} (training {train}), cell {cell}, channel {c}: {got} against {want}"
                    );
                }
            }
            // Everywhere else the map is zero.
            let total: f32 = map.iter().flatten().flatten().map(|v| v.abs()).sum();
            let occupied: f32 = cells
                .keys()
                .map(|&cell| (0..8).map(|c| map[c][cell as usize / n][cell as usize % n].abs()).sum::<f32>())
                .sum();
            assert!(
                (total - occupied).abs() <= 1e-4 * (1.0 + total),
                "{aggregation:?}: values outside the occupied cells"
            );
        }
    }
}
