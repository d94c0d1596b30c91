//! Shared detector modules: the pillar feature net, the BEV backbone with its neck, and the
//! two heads. Every module is built from a `VarBuilder` and runs on any candle device.

use crate::conv::Conv;
use crate::data::Pillars;
use crate::error::Result;
use candle_core::{DType, Device, Tensor};
use candle_nn::{BatchNorm, BatchNormConfig, Linear, Module, ModuleT, VarBuilder};
use serde::{Deserialize, Serialize};

/// BatchNorm with momentum 0.1: training runs are short (hundreds of steps), and with 0.01 the
/// running statistics used at inference would still lag the trained ones.
fn bn_cfg() -> BatchNormConfig {
    BatchNormConfig { eps: 1e-3, remove_mean: true, affine: true, momentum: 0.1 }
}

/// Pillars of one modality on the device.
#[derive(Debug, Clone)]
pub struct PillarTensors {
    /// (P, N, F) decorated point features.
    pub features: Tensor,
    /// (P, N, 1) 1 for real points, 0 for padding.
    pub mask: Tensor,
    /// (P,) flat BEV cell index including the batch offset.
    pub index: Tensor,
    pub count: usize,
}

impl PillarTensors {
    pub fn new(p: &Pillars, device: &Device) -> Result<Self> {
        let n = p.count();
        let npp = p.points_per_pillar.max(1);
        Ok(PillarTensors {
            features: Tensor::from_slice(&p.features, (n, npp, p.width.max(1)), device)?,
            mask: Tensor::from_slice(&p.mask, (n, npp, 1), device)?,
            index: Tensor::from_slice(&p.index, n, device)?,
            count: n,
        })
    }
}

/// PointPillars' pillar feature net: a per-point linear layer, BatchNorm and ReLU, max over the
/// pillar's points, scattered to a dense BEV map (B, C, H, W). Only pillars that exist are
/// computed; empty space costs nothing.
#[derive(Debug)]
pub struct PillarNet {
    linear: Linear,
    bn: BatchNorm,
    pub channels: usize,
}

impl PillarNet {
    pub fn new(in_features: usize, channels: usize, vb: VarBuilder) -> Result<Self> {
        Ok(PillarNet {
            linear: candle_nn::linear_no_bias(in_features, channels, vb.pp("linear"))?,
            bn: candle_nn::batch_norm(channels, bn_cfg(), vb.pp("bn"))?,
            channels,
        })
    }

    /// (P, C) pillar features.
    pub fn encode(&self, p: &PillarTensors, train: bool) -> Result<Tensor> {
        let (n, npp, f) = p.features.dims3()?;
        let x = self.linear.forward(&p.features.reshape((n * npp, f))?)?;
        let x = self.bn.forward_t(&x, train)?.relu()?;
        let x = x.reshape((n, npp, self.channels))?.broadcast_mul(&p.mask)?;
        Ok(x.max(1)?)
    }

    /// Dense BEV map (B, C, H, W) from pillar features (P, C).
    pub fn scatter(
        feats: Option<(&Tensor, &Tensor)>,
        batch: usize,
        cells: usize,
        channels: usize,
        device: &Device,
    ) -> Result<Tensor> {
        let zeros = Tensor::zeros((batch * cells * cells, channels), DType::F32, device)?;
        let flat = match feats {
            Some((f, index)) => zeros.index_add(index, f, 0)?,
            None => zeros,
        };
        Ok(flat.reshape((batch, cells, cells, channels))?.permute((0, 3, 1, 2))?.contiguous()?)
    }

    /// Encode and scatter; an empty modality gives zeros.
    pub fn forward(&self, p: &PillarTensors, batch: usize, cells: usize, train: bool) -> Result<Tensor> {
        if p.count == 0 {
            return Self::scatter(None, batch, cells, self.channels, p.features.device());
        }
        let f = self.encode(p, train)?;
        Self::scatter(Some((&f, &p.index)), batch, cells, self.channels, p.features.device())
    }
}

/// Convolution, BatchNorm, ReLU.
#[derive(Debug)]
pub struct ConvBn {
    conv: Conv,
    bn: BatchNorm,
}

impl ConvBn {
    pub fn new(cin: usize, cout: usize, k: usize, stride: usize, vb: VarBuilder) -> Result<Self> {
        Ok(ConvBn {
            conv: Conv::new(cin, cout, k, stride, k / 2, false, vb.pp("conv"))?,
            bn: candle_nn::batch_norm(cout, bn_cfg(), vb.pp("bn"))?,
        })
    }

    pub fn forward(&self, x: &Tensor, train: bool) -> Result<Tensor> {
        Ok(self.bn.forward_t(&self.conv.forward(x)?, train)?.relu()?)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlockConfig {
    /// Stride of the block's first convolution (1 or 2).
    pub stride: usize,
    pub channels: usize,
    /// Convolutions after the first.
    pub layers: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackboneConfig {
    pub blocks: Vec<BlockConfig>,
    /// Channels each block contributes to the neck's output.
    pub neck_channels: usize,
    /// Output stride relative to the pillar grid (the head's resolution).
    pub out_stride: usize,
}

/// A 2-D BEV backbone (blocks of 3×3 convolutions, each block halving or keeping the size) and
/// a neck that brings every block to the output stride (nearest upsampling + 1×1 convolution,
/// or a strided 3×3 convolution when a block is finer) and concatenates them.
#[derive(Debug)]
pub struct Backbone {
    blocks: Vec<Vec<ConvBn>>,
    neck: Vec<(usize, ConvBn)>,
    pub out_channels: usize,
}

impl Backbone {
    pub fn new(cin: usize, cfg: &BackboneConfig, vb: VarBuilder) -> Result<Self> {
        let mut blocks = Vec::new();
        let mut neck = Vec::new();
        let (mut c, mut stride) = (cin, 1usize);
        for (i, b) in cfg.blocks.iter().enumerate() {
            let vbb = vb.pp(format!("block{i}"));
            let mut layers = vec![ConvBn::new(c, b.channels, 3, b.stride, vbb.pp("0"))?];
            for l in 0..b.layers {
                layers.push(ConvBn::new(b.channels, b.channels, 3, 1, vbb.pp(format!("{}", l + 1)))?);
            }
            blocks.push(layers);
            c = b.channels;
            stride *= b.stride;
            let vbn = vb.pp(format!("neck{i}"));
            let n = if stride < cfg.out_stride {
                ConvBn::new(c, cfg.neck_channels, 3, cfg.out_stride / stride, vbn)?
            } else {
                ConvBn::new(c, cfg.neck_channels, 1, 1, vbn)?
            };
            neck.push((stride, n));
        }
        Ok(Backbone { blocks, neck, out_channels: cfg.neck_channels * cfg.blocks.len() })
    }

    pub fn forward(&self, x: &Tensor, out_stride: usize, train: bool) -> Result<Tensor> {
        let (_, _, h, w) = x.dims4()?;
        let (th, tw) = (h / out_stride, w / out_stride);
        let mut x = x.clone();
        let mut outs = Vec::new();
        for (layers, (stride, n)) in self.blocks.iter().zip(&self.neck) {
            for l in layers {
                x = l.forward(&x, train)?;
            }
            // A coarser map goes through its 1×1 neck convolution first and is upsampled after:
            // the same values as upsampling first (nearest upsampling repeats each pixel equally
            // often, so BatchNorm's statistics are unchanged), at a fraction of the cost.
            let y = if *stride > out_stride {
                n.forward(&x, train)?.upsample_nearest2d(th, tw)?
            } else {
                n.forward(&x, train)?
            };
            outs.push(y);
        }
        Ok(Tensor::cat(&outs, 1)?)
    }
}

/// Regression channels: dx, dy (offset of the centre from the cell centre, in cells), z,
/// ln w, ln l, ln h, sin yaw, cos yaw, vx, vy.
pub const REG_CHANNELS: usize = 10;

/// A detection head: class logits (B, K, H, W) and box regression (B, 10, H, W).
/// `Center` (CenterPoint) has a 3×3 convolution per task before its 1×1 output; `Dense`
/// (PointPillars' SSD head, anchor-free) predicts directly with 1×1 convolutions.
#[derive(Debug)]
pub struct Head {
    cls_pre: Option<ConvBn>,
    reg_pre: Option<ConvBn>,
    cls: Conv,
    reg: Conv,
}

impl Head {
    pub fn new(cin: usize, hidden: usize, classes: usize, with_convs: bool, vb: VarBuilder) -> Result<Self> {
        let (cls_pre, reg_pre, c) = if with_convs {
            (
                Some(ConvBn::new(cin, hidden, 3, 1, vb.pp("cls_pre"))?),
                Some(ConvBn::new(cin, hidden, 3, 1, vb.pp("reg_pre"))?),
                hidden,
            )
        } else {
            (None, None, cin)
        };
        Ok(Head {
            cls_pre,
            reg_pre,
            cls: Conv::new(c, classes, 1, 1, 0, true, vb.pp("cls"))?,
            reg: Conv::new(c, REG_CHANNELS, 1, 1, 0, true, vb.pp("reg"))?,
        })
    }

    pub fn forward(&self, x: &Tensor, train: bool) -> Result<(Tensor, Tensor)> {
        let c = match &self.cls_pre {
            Some(m) => m.forward(x, train)?,
            None => x.clone(),
        };
        let r = match &self.reg_pre {
            Some(m) => m.forward(x, train)?,
            None => x.clone(),
        };
        Ok((self.cls.forward(&c)?, self.reg.forward(&r)?))
    }
}
