//! A detector: a fusion stage (from the registry), the shared BEV backbone and a head; host-side
//! batches; losses and decoding; checkpoints.

use crate::data::{Frame, GtBox, LIDAR_FEATURES, Pillars, RADAR_FEATURES, pillarize};
use crate::decode::{Peaks, decode};
use crate::error::{DetectorError, Result};
use crate::fusion::{Fusion, FusionInput, FusionOutput, Registry};
use crate::layout::{At, Layout, SparseHost};
use crate::loss::{Focal, class_weights, focal_sum, weighted_l1};
use crate::modules::{Backbone, Head, PillarTensors, REG_CHANNELS};
use crate::targets::{Assignment, Targets};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use hilo_core::Detection;
use hilo_core::Valid;
pub use hilo_fusion::config::{DetectorConfig, LossNorm};
use rand::{Rng, SeedableRng};
use serde::Serialize;
use std::path::Path;

/// A batch prepared on the host: pillars of both modalities, the sparse layout's sites and
/// rulebooks, and targets laid out as the head's output is.
#[derive(Clone, Debug, Default)]
pub struct HostBatch {
    pub size: usize,
    pub tokens: Vec<String>,
    pub lidar: Pillars,
    pub radar: Pillars,
    pub sparse: Option<SparseHost>,
    pub targets: Targets,
}

impl HostBatch {
    /// Pillars (sampled with `seed` above the caps), layout and targets of `frames`.
    pub fn new(cfg: &DetectorConfig, frames: &[Frame], with_radar: bool, seed: u64) -> HostBatch {
        let lidar: Vec<&[[f32; LIDAR_FEATURES]]> = frames.iter().map(|f| f.lidar.as_slice()).collect();
        let radar: Vec<&[[f32; RADAR_FEATURES]]> =
            frames.iter().map(|f| if with_radar { f.radar.as_slice() } else { &[] }).collect();
        let boxes: Vec<&[GtBox]> = frames.iter().map(|f| f.boxes.as_slice()).collect();
        let lidar = pillarize(&cfg.grid, &lidar, seed);
        let radar = pillarize(&cfg.grid, &radar, seed ^ 0x5eed_f4ad);
        let mut targets = crate::targets::build(
            &cfg.grid,
            cfg.backbone.out_stride,
            cfg.classes().len(),
            &boxes,
            cfg.assignment,
            cfg.velocity_target,
        );
        let sparse = cfg.sparse.as_ref().map(|s| {
            let occupied: Vec<u32> = lidar.index.iter().chain(&radar.index).copied().collect();
            let h = SparseHost::build(
                cfg.grid.cells(),
                frames.len(),
                &occupied,
                cfg.levels(),
                cfg.head_level(),
                s.head_dilation,
            );
            targets = targets.at_sites(&h.head_sites, cfg.classes().len());
            h
        });
        HostBatch {
            size: frames.len(),
            tokens: frames.iter().map(|f| f.sample_token.clone()).collect(),
            lidar,
            radar,
            sparse,
            targets,
        }
    }
}

/// Loss of one batch and its parts.
#[derive(Debug)]
pub struct Loss {
    pub total: Tensor,
    pub cls: f32,
    pub reg: f32,
}

/// Wall time of the parts of one forward pass, seconds (filled when asked for).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ForwardTimes {
    /// Pillar tensors and the layout's rulebooks moved to the device.
    pub to_device_s: f64,
    /// The fusion stage: pillar nets, scatter, fusion operators (late: whole detectors).
    pub fusion_s: f64,
    pub backbone_s: f64,
    pub head_s: f64,
}

pub struct Detector {
    pub cfg: DetectorConfig,
    pub varmap: VarMap,
    fusion: Box<dyn Fusion>,
    /// The shared backbone and head (none when the plugin returns its own heads).
    backbone: Option<Backbone>,
    head: Option<Head>,
    device: Device,
}

impl std::fmt::Debug for Detector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Detector").field("cfg", &self.cfg).field("fusion", &self.fusion).finish_non_exhaustive()
    }
}

/// Deterministic initialisation from a seed, by variable name (sorted): Kaiming-uniform for
/// weights of rank ≥ 2, 0 for biases and running means, 1 for running variances, −2.19 (a prior
/// of 0.1) for the class logits' bias, as CenterNet does. Other rank-1 variables (BatchNorm
/// scales, a fusion operator's α) keep the constant their module created them with.
fn seeded_init(varmap: &VarMap, seed: u64) -> Result<()> {
    let data = varmap.data().lock().map_err(|_| DetectorError::Config("variable map lock poisoned".into()))?;
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    for name in names {
        let var = &data[name];
        let dims = var.dims().to_vec();
        let n: usize = dims.iter().product();
        let values: Vec<f32> = if name.ends_with("running_var") {
            vec![1.0; n]
        } else if name.ends_with("cls.bias") {
            vec![-2.19; n]
        } else if name.ends_with("running_mean") || name.ends_with("bias") {
            vec![0.0; n]
        } else if dims.len() < 2 {
            continue;
        } else {
            let fan_in: usize = dims[1..].iter().product();
            let bound = (6.0 / fan_in.max(1) as f32).sqrt();
            (0..n).map(|_| rng.random_range(-bound..bound)).collect()
        };
        var.set(&Tensor::from_vec(values, dims.as_slice(), var.device())?)?;
    }
    Ok(())
}

/// A batch of one frame with one LiDAR and one radar point at the grid's centre: what the
/// detector runs once when built, to learn the channels of its plugin's map.
fn probe(cfg: &DetectorConfig) -> HostBatch {
    let f = Frame {
        sample_token: "probe".into(),
        scene: String::new(),
        lidar: vec![[0.1, 0.1, 0.5, 0.5, 0.0]],
        radar: vec![crate::data::radar_point([0.1, 0.1, 0.5], 0.0, 0.0, [1.0, 0.0], 0.0)],
        radar_origin: Vec::new(),
        boxes: Vec::new(),
    };
    HostBatch::new(cfg, &[f], true, 0)
}

impl Detector {
    pub fn new(cfg: &Valid<DetectorConfig>, registry: &Registry, device: &Device, seed: u64) -> Result<Self> {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        // A plugin that makes its own heads (late fusion) takes their class count from its
        // config's `classes`; the detector sets it when its classes are not the paper's six.
        let k = cfg.classes().len();
        let mut fusion_config = cfg.fusion_config.clone();
        if k != hilo_core::Class::PAPER.len()
            && registry.stage(&cfg.fusion) == Some(hilo_fusion::Stage::Late)
            && let Some(o) = fusion_config.as_object_mut()
        {
            o.insert("classes".into(), k.into());
        }
        let fusion = registry.build(&cfg.fusion, &fusion_config, vb.pp("fusion"))?;
        let mut det =
            Detector { cfg: (**cfg).clone(), varmap, fusion, backbone: None, head: None, device: device.clone() };
        // The plugin's output, on a probe batch, decides the rest: a map of C channels gets the
        // shared backbone and head; per-modality heads need nothing more.
        let (lidar, radar, layout) = det.tensors(&probe(cfg))?;
        let input = FusionInput { lidar: &lidar, radar: &radar, batch: 1, grid: cfg.grid, layout: &layout };
        match det.fusion.forward(&input, false)? {
            FusionOutput::Bev(map) => {
                let backbone = Backbone::new(map.dim(1)?, &cfg.backbone, vb.pp("backbone"))?;
                let head = Head::new(
                    backbone.out_channels,
                    cfg.head_channels.max(1),
                    k,
                    cfg.head_channels > 0,
                    vb.pp("head"),
                )?;
                det.backbone = Some(backbone);
                det.head = Some(head);
            }
            FusionOutput::Heads(heads) => {
                if let Some((cls, _)) = heads.iter().find(|(cls, _)| cls.dim(1).ok() != Some(k)) {
                    return Err(DetectorError::Config(format!(
                        "fusion plugin {:?} makes heads of {:?} class channels; the detector has {k} ({})",
                        cfg.fusion,
                        cls.dims().get(1),
                        cfg.classes().iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
                    )));
                }
            }
        }
        seeded_init(&det.varmap, seed)?;
        Ok(det)
    }

    pub fn uses_radar(&self) -> bool {
        self.fusion.uses_radar()
    }

    /// Number of trainable parameters.
    pub fn parameters(&self) -> usize {
        self.trainable().iter().map(|(_, v)| v.as_tensor().elem_count()).sum()
    }

    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Parameters that training updates (BatchNorm running statistics are not).
    pub fn trainable(&self) -> Vec<(String, candle_core::Var)> {
        let data = self
            .varmap
            .data()
            .lock()
            .map(|d| d.iter().map(|(k, v)| (k.clone(), v.clone())).collect::<Vec<_>>())
            .unwrap_or_default();
        let mut v: Vec<_> = data.into_iter().filter(|(k, _)| !k.contains("running_")).collect();
        v.sort_by(|a, b| a.0.cmp(&b.0));
        v
    }

    fn tensors(&self, b: &HostBatch) -> Result<(PillarTensors, PillarTensors, Layout)> {
        let rows = b.sparse.as_ref().map(SparseHost::level0_lookup);
        let lidar = PillarTensors::new(&b.lidar, rows.as_deref(), &self.device)?;
        let radar = PillarTensors::new(&b.radar, rows.as_deref(), &self.device)?;
        let layout = Layout::new(b.size, self.cfg.grid.cells(), b.sparse.as_ref(), &self.device)?;
        Ok((lidar, radar, layout))
    }

    /// Class logits and regression of every head: one for a plugin that returns a map, one
    /// per modality for late fusion. Dense: `(B, K, H, W)` and `(B, 10, H, W)`; sparse:
    /// `(N, K)` and `(N, 10)` at the head sites.
    pub fn forward_heads(&self, b: &HostBatch, train: bool) -> Result<Vec<(Tensor, Tensor)>> {
        self.forward_timed(b, train, None)
    }

    /// [`Self::forward_heads`], filling `times` with the time of each part.
    pub fn forward_timed(
        &self,
        b: &HostBatch,
        train: bool,
        mut times: Option<&mut ForwardTimes>,
    ) -> Result<Vec<(Tensor, Tensor)>> {
        let mut clock = std::time::Instant::now();
        let device = &self.device;
        // Timed, each part waits for the device's queued work (a GPU's kernels run behind the host).
        let mut lap = |slot: fn(&mut ForwardTimes) -> &mut f64, times: &mut Option<&mut ForwardTimes>| -> Result<()> {
            if let Some(t) = times.as_deref_mut() {
                device.synchronize()?;
                *slot(t) += clock.elapsed().as_secs_f64();
            }
            clock = std::time::Instant::now();
            Ok(())
        };
        let (lidar, radar, layout) = self.tensors(b)?;
        lap(|t| &mut t.to_device_s, &mut times)?;
        let input = FusionInput { lidar: &lidar, radar: &radar, batch: b.size, grid: self.cfg.grid, layout: &layout };
        let out = self.fusion.forward(&input, train)?;
        lap(|t| &mut t.fusion_s, &mut times)?;
        match (out, &self.backbone, &self.head) {
            (FusionOutput::Bev(bev), Some(backbone), Some(head)) => {
                let x = backbone.forward_neck(&bev, &layout, self.cfg.backbone.out_stride, train)?;
                lap(|t| &mut t.backbone_s, &mut times)?;
                let at = match &layout {
                    Layout::Dense { .. } => At::Dense,
                    Layout::Sparse(s) => At::Sparse(&s.head),
                };
                let h = head.forward_neck(&x, at, train)?;
                lap(|t| &mut t.head_s, &mut times)?;
                Ok(vec![h])
            }
            (FusionOutput::Heads(h), None, None) if !h.is_empty() => Ok(h),
            _ => Err(DetectorError::Config(format!(
                "detector {}: fusion plugin {:?} returned another kind of output than when the detector was built",
                self.cfg.name, self.cfg.fusion
            ))),
        }
    }

    /// The first head's outputs (the only one except for late fusion).
    pub fn forward(&self, b: &HostBatch, train: bool) -> Result<(Tensor, Tensor)> {
        self.forward_heads(b, train)?.into_iter().next().ok_or_else(|| DetectorError::Config("no head output".into()))
    }

    /// The sum of every head's loss against the same targets.
    pub fn loss_all(&self, heads: &[(Tensor, Tensor)], t: &Targets) -> Result<Loss> {
        let mut total: Option<Loss> = None;
        for (c, r) in heads {
            let l = self.loss(c, r, t)?;
            total = Some(match total {
                None => l,
                Some(a) => Loss { total: (&a.total + &l.total)?, cls: a.cls + l.cls, reg: a.reg + l.reg },
            });
        }
        total.ok_or_else(|| DetectorError::Config("no head output".into()))
    }

    /// Focal loss on the heatmap (or inside-box map) and weighted L1 on the regression at the
    /// positive cells; targets are laid out as the head's output is. Each is one fused node on
    /// the CPU ([`focal_sum`], [`weighted_l1`]), else candle's operations.
    pub fn loss(&self, cls: &Tensor, reg: &Tensor, t: &Targets) -> Result<Loss> {
        let k = cls.dim(1)?;
        let dense = cls.rank() == 4;
        let kind = match self.cfg.assignment {
            Assignment::Center => Focal::CenterNet,
            Assignment::Inside => Focal::Sigmoid,
        };
        // Per cell (the mask's layout), the weight of the box channels and of the velocity
        // channels (velocity only where it is known).
        let (class_w, box_w, vel_w): (Vec<f32>, Vec<f32>, Vec<f32>) = match self.cfg.loss_norm {
            LossNorm::All => {
                let norm = 1.0 / t.num_pos.max(1.0);
                let vel = if t.vel_weight.is_empty() { &t.vel_mask } else { &t.vel_weight };
                (vec![norm; k], t.mask.iter().map(|m| m * norm).collect(), vel.iter().map(|m| m * norm).collect())
            }
            LossNorm::PerClass => {
                let site_w = t.per_class_site_weights(k, dense);
                let vel_w: Vec<f32> = match t.vel_weight.is_empty() {
                    true => site_w.iter().zip(&t.vel_mask).map(|(w, m)| w * m).collect(),
                    false => t.per_class_velocity_weights(k),
                };
                (class_weights(&t.pos_per_class, k), site_w, vel_w)
            }
        };
        let lc = focal_sum(kind, cls, &t.cls, &class_w)?;
        let lr = weighted_l1(reg, &t.reg, &regression_weights(reg, &box_w, &vel_w, self.cfg.velocity_weight as f32)?)?;
        let total = (&lc + (&lr * 0.25)?)?;
        Ok(Loss { total, cls: lc.to_scalar::<f32>()?, reg: lr.to_scalar::<f32>()? })
    }

    /// Boxes per frame of a batch.
    pub fn detect(&self, b: &HostBatch) -> Result<Vec<Vec<Detection>>> {
        let heads = self.forward_heads(b, false)?;
        let n = self.cfg.grid.cells() >> self.cfg.head_level();
        let stride = self.cfg.backbone.out_stride;
        let k = self.cfg.classes().len();
        let mut per_frame: Vec<Vec<Vec<Detection>>> = vec![Vec::new(); b.size];
        for (cls, reg) in heads {
            let cls = cls.flatten_all()?.to_vec1::<f32>()?;
            let reg = reg.flatten_all()?.to_vec1::<f32>()?;
            match &b.sparse {
                None => {
                    for (i, dets) in per_frame.iter_mut().enumerate() {
                        let (c, r) = (
                            &cls[i * k * n * n..(i + 1) * k * n * n],
                            &reg[i * REG_CHANNELS * n * n..(i + 1) * REG_CHANNELS * n * n],
                        );
                        dets.push(decode(
                            &self.cfg.grid,
                            stride,
                            &Peaks::dense(n),
                            k,
                            |kk, j| c[kk * n * n + j],
                            |ch, j| r[ch * n * n + j],
                            self.cfg.assignment,
                            &self.cfg.decode,
                        ));
                    }
                }
                Some(h) => {
                    for (i, dets) in per_frame.iter_mut().enumerate() {
                        let peaks = Peaks::sparse(h, i, n);
                        let off = peaks.offset;
                        dets.push(decode(
                            &self.cfg.grid,
                            stride,
                            &peaks,
                            k,
                            |kk, j| cls[(off + j) * k + kk],
                            |ch, j| reg[(off + j) * REG_CHANNELS + ch],
                            self.cfg.assignment,
                            &self.cfg.decode,
                        ));
                    }
                }
            }
        }
        Ok(per_frame.into_iter().map(|heads| self.fusion.merge(heads, self.cfg.decode.max_per_frame)).collect())
    }

    /// Weights (and BatchNorm statistics) to safetensors.
    pub fn save(&self, path: &Path) -> Result<()> {
        let io = |e: std::io::Error| DetectorError::from(hilo_core::fs::FileError::io(path, e));
        hilo_core::fs::write_atomic_with(
            path,
            |tmp| self.varmap.save(tmp).map_err(|e| io(std::io::Error::other(e.to_string()))),
            io,
        )
    }

    /// Loads weights saved by [`Self::save`] for the same architecture.
    pub fn load(&mut self, path: &Path) -> Result<()> {
        let tensors = candle_core::safetensors::load(path, &self.device)
            .map_err(|e| DetectorError::Checkpoint { path: path.to_path_buf(), message: e.to_string() })?;
        let data = self.varmap.data().lock().map_err(|_| DetectorError::Config("variable map lock poisoned".into()))?;
        for (name, var) in data.iter() {
            let t = tensors.get(name).ok_or_else(|| DetectorError::Checkpoint {
                path: path.to_path_buf(),
                message: format!(
                    "has no tensor {name:?}: it was saved by another architecture than {} ({} tensors there)",
                    self.cfg.name,
                    tensors.len()
                ),
            })?;
            if t.dims() != var.dims() {
                return Err(DetectorError::Checkpoint {
                    path: path.to_path_buf(),
                    message: format!(
                        "tensor {name:?} has shape {:?}, detector {} needs {:?}: another architecture",
                        t.dims(),
                        self.cfg.name,
                        var.dims()
                    ),
                });
            }
            var.set(t)?;
        }
        if tensors.len() != data.len() {
            return Err(DetectorError::Checkpoint {
                path: path.to_path_buf(),
                message: format!(
                    "holds {} tensors, detector {} has {}: another architecture",
                    tensors.len(),
                    self.cfg.name,
                    data.len()
                ),
            });
        }
        Ok(())
    }
}

/// The regression's weight per element of `reg` (`(N, 10)` at sites or `(B, 10, H, W)` dense):
/// the cell's box weight on the eight box channels, its velocity weight times
/// `velocity_weight` on the two velocity channels.
fn regression_weights(reg: &Tensor, box_w: &[f32], vel_w: &[f32], velocity_weight: f32) -> Result<Vec<f32>> {
    let cells = box_w.len();
    let inner: usize = reg.dims().iter().skip(2).product();
    if reg.elem_count() != cells * REG_CHANNELS || vel_w.len() != cells {
        return Err(DetectorError::Config(format!(
            "regression loss: {} and {} cell weights for {:?}",
            cells,
            vel_w.len(),
            reg.dims()
        )));
    }
    Ok((0..reg.elem_count())
        .map(|e| {
            let (c, cell) = ((e / inner) % REG_CHANNELS, e / (inner * REG_CHANNELS) * inner + e % inner);
            if c < 8 { box_w[cell] } else { vel_w[cell] * velocity_weight }
        })
        .collect())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The weighted fusion operator's α starts at its documented 0.5 (seeded initialisation once
    /// set every rank-1 variable to 1).
    #[test]
    fn seeded_init_keeps_constant_rank1_variables() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let _f = crate::fuse::BevFuse::new(8, 4, 8, crate::fuse::FuseOp::Weighted, vb.pp("fuse")).unwrap();
        seeded_init(&varmap, 3).unwrap();
        let data = varmap.data().lock().unwrap();
        assert_eq!(data["fuse.alpha"].as_tensor().to_vec1::<f32>().unwrap(), vec![0.5]);
        assert!(data["fuse.out.bn.weight"].as_tensor().to_vec1::<f32>().unwrap().iter().all(|v| *v == 1.0));
        assert!(data["fuse.out.bn.bias"].as_tensor().to_vec1::<f32>().unwrap().iter().all(|v| *v == 0.0));
    }
}
