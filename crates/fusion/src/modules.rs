//! Shared detector modules: the pillar feature net, the BEV backbone with its neck, and the
//! two heads. Every module is built from a `VarBuilder`, runs on any candle device, and on
//! either [`Layout`]: dense maps, or the occupied sites only.

use crate::conv::Conv;
use crate::error::{FusionError, Result};
use crate::layout::{At, Layout};
use crate::pillars::Pillars;
use candle_core::{Device, Tensor};
use candle_nn::{BatchNorm, BatchNormConfig, Linear, Module, VarBuilder};
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
    /// (P,) the row of the layout each pillar is scattered to: its flat BEV cell including the
    /// batch offset (dense), or its level-0 site (sparse).
    pub index: Tensor,
    pub count: usize,
    /// The real points alone, pillar after pillar (padding left out): `(R, F)` features, and
    /// per point its pillar's layout row (`index` of its pillar, `(R,)` u32) and the share
    /// 1 / (its pillar's real points) `(R, 1)`. A per-point encoder on these rows does the work
    /// of the points there are (a roadside pillar holds about three of its 10 slots on average).
    pub points: Tensor,
    pub point_rows: Tensor,
    pub point_share: Tensor,
    /// `(R,)` u32: each real point's slot in the padded layout (pillar · N + slot), where a
    /// per-point result goes back to for a per-pillar maximum.
    pub point_slots: Tensor,
    /// Padding slots left out of `points` (P·N − R): zero rows, which BatchNorm over the
    /// padded layout counts ([`crate::bnrelu::bn_relu_padded`]).
    pub padding: usize,
}

impl PillarTensors {
    /// `(P, C)`: the maximum over each pillar's slots of per-point rows `x` `(R, C)` (one per
    /// real point), the padding slots 0, which is at most every ReLU output, as the masked
    /// padding was.
    pub fn max_per_pillar(&self, x: &Tensor) -> Result<Tensor> {
        let (n, npp, _) = self.features.dims3()?;
        let c = x.dim(1)?;
        let slots = Tensor::zeros((n * npp, c), x.dtype(), x.device())?.index_add(&self.point_slots, x, 0)?;
        Ok(slots.reshape((n, npp, c))?.max(1)?)
    }

    /// Pillars scattered to their flat cells (`p.index`), or, with `rows`, to `rows[p.index]`.
    pub fn new(p: &Pillars, rows: Option<&[u32]>, device: &Device) -> Result<Self> {
        let n = p.count();
        let npp = p.points_per_pillar.max(1);
        let index: Vec<u32> = match rows {
            Some(r) => p
                .index
                .iter()
                .map(|&i| r.get(i as usize).copied().filter(|s| *s != crate::layout::NONE))
                .collect::<Option<_>>()
                .ok_or_else(|| FusionError::Config("a pillar has no site in the sparse layout".into()))?,
            None => p.index.clone(),
        };
        let width = p.width.max(1);
        let (mut points, mut point_rows, mut point_share, mut point_slots) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (k, (slots, &row)) in p.mask.chunks(npp).zip(&index).enumerate() {
            let real = slots.iter().filter(|m| **m > 0.5).count();
            for (j, _) in slots.iter().enumerate().filter(|(_, m)| **m > 0.5) {
                let at = (k * npp + j) * width;
                points.extend_from_slice(&p.features[at..at + width]);
                point_rows.push(row);
                point_share.push(1.0 / real as f32);
                point_slots.push((k * npp + j) as u32);
            }
        }
        let r = point_rows.len();
        Ok(PillarTensors {
            features: Tensor::from_slice(&p.features, (n, npp, width), device)?,
            mask: Tensor::from_slice(&p.mask, (n, npp, 1), device)?,
            index: Tensor::from_vec(index, n, device)?,
            count: n,
            points: Tensor::from_vec(points, (r, width), device)?,
            point_rows: Tensor::from_vec(point_rows, r, device)?,
            point_share: Tensor::from_vec(point_share, (r, 1), device)?,
            point_slots: Tensor::from_vec(point_slots, r, device)?,
            padding: n * npp - r,
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

    /// (P, C) pillar features: the per-point layers on the real points alone (BatchNorm
    /// counting the padding slots as the zero rows they are, so the function is that of the
    /// padded pillars), then the maximum over each pillar's slots (a padding slot's 0 is below
    /// or equal to every ReLU output, as the masked padding was).
    pub fn encode(&self, p: &PillarTensors, train: bool) -> Result<Tensor> {
        let (n, _, f) = p.features.dims3()?;
        let r = p.points.dim(0)?;
        crate::conv::count_matmul(r, f, self.channels);
        let x = self.linear.forward(&p.points)?;
        let x = crate::bnrelu::bn_relu_padded(&self.bn, &x, p.padding, train)?;
        if n == 0 {
            // No pillars (a synchronised replica's empty modality): candle reduces no empty
            // tensor, and the (0, C) rows need only stay in the graph.
            return Ok(x);
        }
        p.max_per_pillar(&x)
    }

    /// Pillar features (P, C) scattered to the layout's level 0: `(B, C, H, W)` or `(N_0, C)`.
    pub fn scatter(
        feats: Option<(&Tensor, &Tensor)>,
        layout: &Layout,
        channels: usize,
        device: &Device,
    ) -> Result<Tensor> {
        let zeros = layout.zeros(channels, device)?;
        let flat = match feats {
            Some((f, index)) => zeros.index_add(index, f, 0)?,
            None => zeros,
        };
        layout.from_rows(flat)
    }

    /// Encode and scatter; an empty modality gives zeros (encoded with no rows when BatchNorm
    /// is synchronised, so this replica still meets the others at the layer's exchanges).
    pub fn forward(&self, p: &PillarTensors, layout: &Layout, train: bool) -> Result<Tensor> {
        if p.count == 0 && !(train && crate::bnrelu::synced()) {
            return Self::scatter(None, layout, self.channels, p.features.device());
        }
        let f = self.encode(p, train)?;
        Self::scatter(Some((&f, &p.index)), layout, self.channels, p.features.device())
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

    /// At one place of a layout (a 3×3 stride-1 or 1×1 convolution when sparse).
    pub fn forward(&self, x: &Tensor, at: At, train: bool) -> Result<Tensor> {
        crate::bnrelu::bn_relu(&self.bn, &self.conv.forward(x, at)?, train)
    }

    /// Sparse rows along a rulebook (any stride).
    pub fn forward_rules(&self, x: &Tensor, rules: &crate::layout::Rules, train: bool) -> Result<Tensor> {
        crate::bnrelu::bn_relu(&self.bn, &self.conv.forward_rules(x, rules)?, train)
    }

    /// `(a.forward(x), b.forward(x))` for two 3×3 stride-1 layers without bias that read the
    /// same sparse rows: one gather of `x` and one matrix product with the two kernels side by
    /// side instead of two of each (and one scatter of their input gradient instead of two),
    /// each half then through its own BatchNorm + ReLU. The same function as two calls, its
    /// sums rounded differently; other layers and layouts take two calls.
    pub fn forward_pair(a: &ConvBn, b: &ConvBn, x: &Tensor, at: At, train: bool) -> Result<(Tensor, Tensor)> {
        match at {
            At::Sparse(plane) if Self::pairable(a, b) => {
                let y =
                    crate::layout::gather_conv(x, &Tensor::cat(&[a.conv.weight(), b.conv.weight()], 0)?, &plane.subm)?;
                Self::split_bn_relu(a, b, &y, train)
            }
            _ => Ok((a.forward(x, at, train)?, b.forward(x, at, train)?)),
        }
    }

    /// Whether two layers can run as one product with their kernels side by side: both 3×3,
    /// stride 1, without bias, reading the same channels.
    fn pairable(a: &ConvBn, b: &ConvBn) -> bool {
        let one = |c: &Conv| c.weight().dim(2).ok() == Some(3) && c.stride() == 1 && c.bias().is_none();
        one(&a.conv) && one(&b.conv) && a.conv.weight().dims()[1..] == b.conv.weight().dims()[1..]
    }

    /// The paired product `y` split into `a`'s and `b`'s output channels, each through its own
    /// BatchNorm + ReLU.
    fn split_bn_relu(a: &ConvBn, b: &ConvBn, y: &Tensor, train: bool) -> Result<(Tensor, Tensor)> {
        let ca = a.conv.weight().dim(0)?;
        let (ya, yb) = (y.narrow(1, 0, ca)?.contiguous()?, y.narrow(1, ca, y.dim(1)? - ca)?.contiguous()?);
        Ok((crate::bnrelu::bn_relu(&a.bn, &ya, train)?, crate::bnrelu::bn_relu(&b.bn, &yb, train)?))
    }

    /// [`ConvBn::forward_pair`] at the head sites of a neck held as parts
    /// ([`Neck::Parts`]): each part's slice of the two kernels side by side convolves its own
    /// rows through its tap rulebook ([`crate::layout::parent_conv`]), the parts' sums are
    /// added, and each half goes through its BatchNorm + ReLU. The same function as
    /// `forward_pair` of the materialised neck ([`Neck::rows`]), rounded differently. `None`
    /// where the two layers cannot run so (not 3×3 stride 1 without bias, or inputs other than
    /// the parts' channels).
    fn forward_pair_parts(a: &ConvBn, b: &ConvBn, parts: &[NeckPart], train: bool) -> Result<Option<(Tensor, Tensor)>> {
        let width: usize = parts.iter().map(|p| p.values.dim(1).unwrap_or(0)).sum();
        if !(Self::pairable(a, b) && a.conv.weight().dim(1)? == width) {
            return Ok(None);
        }
        let w = Tensor::cat(&[a.conv.weight(), b.conv.weight()], 0)?;
        let mut y: Option<Tensor> = None;
        let mut off = 0;
        for p in parts {
            let c = p.values.dim(1)?;
            let yp = crate::layout::parent_conv(&p.values, &w.narrow(1, off, c)?, &p.taps)?;
            y = Some(match y {
                None => yp,
                Some(acc) => (acc + yp)?,
            });
            off += c;
        }
        let Some(y) = y else { return Ok(None) };
        Ok(Some(Self::split_bn_relu(a, b, &y, train)?))
    }
}

/// One block's contribution to the neck, sparse: its rows where the neck computed them and how
/// the head sites read them.
#[derive(Debug, Clone)]
pub struct NeckPart {
    /// `(N, C_part)`: at the block's own level's sites when it is as coarse as the head or
    /// coarser, else at the head sites.
    pub values: Tensor,
    /// Each head site's row of `values` (its parent; [`crate::layout::NONE`]: zeros), or `None`
    /// where `values` is at the head sites already.
    pub from: Option<crate::layout::Rules>,
    /// The head's 3×3 rulebook through those rows ([`crate::layout::SparseHost::head_taps`]).
    pub taps: crate::layout::Rules,
}

/// The neck's output as the head reads it.
#[derive(Debug, Clone)]
pub enum Neck {
    /// `(B, C, H / s, W / s)` dense, or `(N_head, C)` rows at the head sites.
    Rows(Tensor),
    /// Sparse, per block in order (their channels concatenated are the neck's): a coarse
    /// block's rows stay at its parents, which a head convolution reads through its tap
    /// rulebook instead of copying each parent's row to every head site below it.
    Parts(Vec<NeckPart>),
}

impl Neck {
    /// The neck as one tensor: `(N_head, C)` rows (each head site its parents' rows, blocks
    /// side by side) or the dense map.
    pub fn rows(&self) -> Result<Tensor> {
        match self {
            Neck::Rows(x) => Ok(x.clone()),
            Neck::Parts(parts) => {
                let outs = parts
                    .iter()
                    .map(|p| match &p.from {
                        Some(f) => crate::layout::gather(&p.values, f),
                        None => Ok(p.values.clone()),
                    })
                    .collect::<Result<Vec<_>>>()?;
                Ok(Tensor::cat(&outs, 1)?)
            }
        }
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
    strides: Vec<usize>,
    neck: Vec<(usize, ConvBn)>,
    pub out_channels: usize,
}

impl Backbone {
    pub fn new(cin: usize, cfg: &BackboneConfig, vb: VarBuilder) -> Result<Self> {
        let mut blocks = Vec::new();
        let mut strides = Vec::new();
        let mut neck = Vec::new();
        let (mut c, mut stride) = (cin, 1usize);
        for (i, b) in cfg.blocks.iter().enumerate() {
            let vbb = vb.pp(format!("block{i}"));
            let mut layers = vec![ConvBn::new(c, b.channels, 3, b.stride, vbb.pp("0"))?];
            for l in 0..b.layers {
                layers.push(ConvBn::new(b.channels, b.channels, 3, 1, vbb.pp(format!("{}", l + 1)))?);
            }
            blocks.push(layers);
            strides.push(b.stride);
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
        Ok(Backbone { blocks, strides, neck, out_channels: cfg.neck_channels * cfg.blocks.len() })
    }

    /// The neck's output as the head reads it ([`Head::forward_neck`]): dense rows, or sparse
    /// parts (each block's rows where they were computed, [`Neck::Parts`]); [`Neck::rows`]
    /// gives it as one tensor, `(B, C, H / s, W / s)` dense or `(N_head, C)` sparse.
    pub fn forward_neck(&self, x: &Tensor, layout: &Layout, out_stride: usize, train: bool) -> Result<Neck> {
        let Layout::Sparse(sp) = layout else { return Ok(Neck::Rows(self.forward_dense(x, out_stride, train)?)) };
        let mut x = x.clone();
        let mut level = 0usize;
        let mut outs = Vec::new();
        for ((layers, &stride), (total, n)) in self.blocks.iter().zip(&self.strides).zip(&self.neck) {
            for (k, l) in layers.iter().enumerate() {
                x = if k == 0 && stride == 2 {
                    level += 1;
                    let rules = sp.down.get(level).and_then(|d| d.as_ref()).ok_or_else(|| {
                        FusionError::Config(format!("the sparse layout has no level {level} (stride {total})"))
                    })?;
                    l.forward_rules(&x, rules, train)?
                } else {
                    l.forward(&x, At::Sparse(&sp.levels[level]), train)?
                };
            }
            let from = sp
                .head_from
                .get(level)
                .ok_or_else(|| FusionError::Config(format!("no head link from level {level}")))?;
            let taps = sp
                .head_taps
                .get(level)
                .ok_or_else(|| FusionError::Config(format!("no head tap rulebook for level {level}")))?
                .clone();
            // As coarse as the head or coarser: 1×1 convolution at the level's sites, which
            // each head site reads through its parent; finer: a strided 3×3 convolution into
            // the head sites.
            outs.push(if *total >= out_stride {
                NeckPart {
                    values: n.forward(&x, At::Sparse(&sp.levels[level]), train)?,
                    from: Some(from.clone()),
                    taps,
                }
            } else {
                NeckPart { values: n.forward_rules(&x, from, train)?, from: None, taps }
            });
        }
        Ok(Neck::Parts(outs))
    }

    fn forward_dense(&self, x: &Tensor, out_stride: usize, train: bool) -> Result<Tensor> {
        let (_, _, h, w) = x.dims4()?;
        let (th, tw) = (h / out_stride, w / out_stride);
        let mut x = x.clone();
        let mut outs = Vec::new();
        for (layers, (stride, n)) in self.blocks.iter().zip(&self.neck) {
            for l in layers {
                x = l.forward(&x, At::Dense, train)?;
            }
            // A coarser map goes through its 1×1 neck convolution first and is upsampled after:
            // the same values as upsampling first (nearest upsampling repeats each pixel equally
            // often, so BatchNorm's statistics are unchanged), at a fraction of the cost.
            let y = if *stride > out_stride {
                n.forward(&x, At::Dense, train)?.upsample_nearest2d(th, tw)?
            } else {
                n.forward(&x, At::Dense, train)?
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

    /// Class logits and regression: `(B, K, H, W)` and `(B, 10, H, W)` dense, `(N, K)` and
    /// `(N, 10)` at the head sites when sparse.
    pub fn forward(&self, x: &Tensor, at: At, train: bool) -> Result<(Tensor, Tensor)> {
        let (c, r) = match (&self.cls_pre, &self.reg_pre) {
            (Some(c), Some(r)) => ConvBn::forward_pair(c, r, x, at, train)?,
            (c, r) => (
                c.as_ref().map_or_else(|| Ok(x.clone()), |m| m.forward(x, at, train))?,
                r.as_ref().map_or_else(|| Ok(x.clone()), |m| m.forward(x, at, train))?,
            ),
        };
        Ok((self.cls.forward(&c, at)?, self.reg.forward(&r, at)?))
    }

    /// [`Head::forward`] of the neck as the backbone left it: with a sparse neck held as
    /// parts, the two 3×3 layers run on the parents' rows ([`ConvBn::forward_pair_parts`]);
    /// otherwise on the materialised rows.
    pub fn forward_neck(&self, neck: &Neck, at: At, train: bool) -> Result<(Tensor, Tensor)> {
        if let (Neck::Parts(parts), Some(c), Some(r), At::Sparse(_)) = (neck, &self.cls_pre, &self.reg_pre, at)
            && let Some((c, r)) = ConvBn::forward_pair_parts(c, r, parts, train)?
        {
            return Ok((self.cls.forward(&c, at)?, self.reg.forward(&r, at)?));
        }
        self.forward(&neck.rows()?, at, train)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::layout::SparseHost;
    use candle_core::{DType, Var};
    use candle_nn::VarMap;
    use rand::{Rng, SeedableRng};

    fn values(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1().unwrap()
    }

    /// Kernels, scales and shifts away from their initial constants, so every term counts.
    fn randomise_weights(varmap: &VarMap, rng: &mut rand_chacha::ChaCha8Rng) {
        for (name, var) in varmap.data().lock().unwrap().iter() {
            if name.ends_with("weight") || name.ends_with("bias") {
                let k = var.elem_count();
                let v: Vec<f32> = (0..k).map(|_| rng.random_range(-0.5f32..0.5) + 0.2).collect();
                var.set(&Tensor::from_vec(v, var.shape(), var.device()).unwrap()).unwrap();
            }
        }
    }

    /// Two outputs, then the gradients of `Σ out · up` (summed over both) with respect to `x`
    /// and every trainable variable, by name.
    fn outputs_and_gradients(outs: [(&str, &Tensor, &Tensor); 2], x: &Var, varmap: &VarMap) -> Vec<(String, Vec<f32>)> {
        let loss = outs.iter().map(|(_, y, up)| (*y * *up).unwrap().sum_all().unwrap()).reduce(|a, b| (a + b).unwrap());
        let grads = loss.unwrap().backward().unwrap();
        let data = varmap.data().lock().unwrap();
        let mut names: Vec<&String> = data.keys().filter(|k| !k.contains("running")).collect();
        names.sort();
        let mut out: Vec<(String, Vec<f32>)> = outs.iter().map(|(n, y, _)| (n.to_string(), values(y))).collect();
        out.push(("dx".into(), values(grads.get(x.as_tensor()).unwrap())));
        for k in names {
            out.push((format!("d{k}"), values(grads.get(data[k].as_tensor()).unwrap())));
        }
        out
    }

    /// Each named vector of `got` within `tol` of `want`'s largest magnitude, and `want` not all
    /// zeros (`floor`: what counts as zero).
    fn assert_close(got: &[(String, Vec<f32>)], want: &[(String, Vec<f32>)], tol: f32, floor: f32, what: &str) {
        assert_eq!(got.len(), want.len(), "{what}");
        for ((name, p), (_, s)) in got.iter().zip(want) {
            assert_eq!(p.len(), s.len(), "{what}: {name}");
            let scale = s.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-3);
            for (i, (u, v)) in p.iter().zip(s).enumerate() {
                assert!((u - v).abs() <= tol * scale, "{what}: {name}[{i}]: {u} against {v}");
            }
            assert!(s.iter().any(|v| v.abs() > floor), "{what}: {name} is not all zeros");
        }
    }

    /// The paired head convolution (one gather, both kernels side by side) is the function of
    /// two separate layers: outputs, and the gradients of the input, both kernels and both
    /// BatchNorms' scales and shifts, for halves of unequal width, on sites of two frames.
    #[test]
    fn paired_convolutions_equal_two_separate_ones() {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (cells, ci) = (12usize, 5usize);
        let occupied: Vec<u32> = (0..30).map(|_| rng.random_range(0..(2 * cells * cells) as u32)).collect();
        let host = SparseHost::build(cells, 2, &occupied, 1, 0, 1);
        let layout = Layout::new(2, cells, Some(&host), &dev).unwrap();
        let at = layout.level0();
        let n = layout.rows();
        let x = Var::from_vec((0..n * ci).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (n, ci), &dev).unwrap();
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let (a, b) = (ConvBn::new(ci, 4, 3, 1, vb.pp("a")).unwrap(), ConvBn::new(ci, 3, 3, 1, vb.pp("b")).unwrap());
        randomise_weights(&varmap, &mut rng);
        let (ra, rb) = (
            Tensor::from_vec((0..n * 4).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (n, 4), &dev).unwrap(),
            Tensor::from_vec((0..n * 3).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (n, 3), &dev).unwrap(),
        );
        let run = |paired: bool| {
            let (ya, yb) = if paired {
                ConvBn::forward_pair(&a, &b, x.as_tensor(), at, true).unwrap()
            } else {
                (a.forward(x.as_tensor(), at, true).unwrap(), b.forward(x.as_tensor(), at, true).unwrap())
            };
            outputs_and_gradients([("ya", &ya, &ra), ("yb", &yb, &rb)], &x, &varmap)
        };
        let (paired, separate) = (run(true), run(false));
        assert_eq!(paired.len(), 2 + 1 + 6, "outputs, input gradient, two kernels, scales and shifts");
        assert_close(&paired, &separate, 1e-5, 1e-4, "paired against separate");
    }

    /// The head's 3×3 layers on the neck's parts (each block's rows at its own level, read
    /// through the tap rulebooks) equal them on the materialised neck (every head site holding
    /// its parents' rows): outputs, and the gradients of the input and of every weight, with
    /// the head at level 0 (every block coarser, head sites dilated by 2 so that some parents
    /// are missing), at level 1 (the first block at the head's level) and at level 2 (the
    /// first block finer than the head, convolved into the head sites).
    #[test]
    fn head_on_the_neck_parts_equals_it_on_the_materialised_neck() {
        let dev = Device::Cpu;
        for (seed, out_stride) in [(3u64, 1usize), (4, 2), (5, 4)] {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let (cells, ci) = (32usize, 3usize);
            let occupied: Vec<u32> = (0..60).map(|_| rng.random_range(0..(2 * cells * cells) as u32)).collect();
            let head_level = out_stride.trailing_zeros() as usize;
            let host = SparseHost::build(cells, 2, &occupied, 4, head_level, 2);
            assert!(host.head_taps[3].contains(&crate::layout::NONE) || head_level > 0);
            let layout = Layout::new(2, cells, Some(&host), &dev).unwrap();
            let n = layout.rows();
            let x =
                Var::from_vec((0..n * ci).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (n, ci), &dev).unwrap();
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
            let cfg = BackboneConfig {
                blocks: vec![
                    BlockConfig { stride: 2, channels: 4, layers: 1 },
                    BlockConfig { stride: 2, channels: 6, layers: 0 },
                    BlockConfig { stride: 2, channels: 5, layers: 1 },
                ],
                neck_channels: 3,
                out_stride,
            };
            let backbone = Backbone::new(ci, &cfg, vb.pp("backbone")).unwrap();
            let head = Head::new(backbone.out_channels, 4, 2, true, vb.pp("head")).unwrap();
            randomise_weights(&varmap, &mut rng);
            let Layout::Sparse(sp) = &layout else { panic!("sparse layout expected") };
            let at = At::Sparse(&sp.head);
            let nh = sp.head.sites;
            let (rc, rr) = (
                Tensor::from_vec((0..nh * 2).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (nh, 2), &dev).unwrap(),
                Tensor::from_vec(
                    (0..nh * REG_CHANNELS).map(|_| rng.random_range(-1.0f32..1.0)).collect(),
                    (nh, REG_CHANNELS),
                    &dev,
                )
                .unwrap(),
            );
            let run = |parts: bool| {
                let neck = backbone.forward_neck(x.as_tensor(), &layout, out_stride, true).unwrap();
                let (c, r) = if parts {
                    let Neck::Parts(p) = &neck else { panic!("a sparse neck is held as parts") };
                    let (Some(a), Some(b)) = (&head.cls_pre, &head.reg_pre) else { panic!("a centre head") };
                    assert!(ConvBn::forward_pair_parts(a, b, p, true).unwrap().is_some(), "the parts path runs");
                    head.forward_neck(&neck, at, true).unwrap()
                } else {
                    head.forward(&neck.rows().unwrap(), at, true).unwrap()
                };
                outputs_and_gradients([("cls", &c, &rc), ("reg", &r, &rr)], &x, &varmap)
            };
            let (parts, rows) = (run(true), run(false));
            assert_close(&parts, &rows, 1e-4, 1e-5, &format!("stride {out_stride}, parts against rows"));
        }
    }

    /// The pillar net on the real points alone equals PointPillars' padded form (every slot
    /// through the linear layer, BatchNorm over all of them, the padding masked, the maximum per
    /// pillar): outputs, running statistics and the gradients of every variable, in training,
    /// on pillars with one point, full pillars (points left out above the cap) and pillars in
    /// between. And the packed rows are the mask's real slots.
    #[test]
    fn pillar_net_on_real_points_equals_the_padded_form() {
        let grid = crate::grid::small_grid();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        // A dense clump (full pillars), a sparse spread (one point per pillar), and between.
        let mut pts: Vec<[f32; 4]> = (0..60)
            .map(|_| {
                [rng.random_range(1.0f32..1.7), rng.random_range(2.0f32..2.7), rng.random_range(-1.0f32..2.0), 0.4]
            })
            .collect();
        pts.extend((0..25).map(|k| [-10.0 + 0.81 * k as f32, -6.0 + 0.1 * k as f32, 0.5, 0.9]));
        pts.extend((0..30).map(|_| [rng.random_range(4.0f32..6.4), rng.random_range(-3.0f32..-1.4), 0.2, 0.1]));
        let pillars = crate::pillars::pillarize(&grid, &[&pts], 3);
        assert!(pillars.dropped_points > 0, "some pillar is over its cap");
        let dev = Device::Cpu;
        let p = PillarTensors::new(&pillars, None, &dev).unwrap();
        let (n, npp, f) = p.features.dims3().unwrap();
        let real = pillars.mask.iter().filter(|m| **m > 0.5).count();
        assert_eq!(p.points.dims(), &[real, f]);
        assert_eq!(p.padding, n * npp - real);
        assert!(p.padding > 0 && real > n, "padding and pillars of several points");
        let packed: Vec<f32> = pillars
            .features
            .chunks(f)
            .zip(&pillars.mask)
            .filter(|(_, m)| **m > 0.5)
            .flat_map(|(row, _)| row.to_vec())
            .collect();
        assert_eq!(values(&p.points), packed, "the real slots in order");

        let varmap = VarMap::new();
        let net = PillarNet::new(f, 16, VarBuilder::from_varmap(&varmap, DType::F32, &dev)).unwrap();
        randomise_weights(&varmap, &mut rng);
        let up =
            Tensor::from_vec((0..n * 16).map(|_| rng.random_range(-1.0f32..1.0)).collect(), (n, 16), &dev).unwrap();
        let stats = |v: &VarMap| {
            let d = v.data().lock().unwrap();
            let mut k: Vec<&String> = d.keys().filter(|k| k.contains("running")).collect();
            k.sort();
            k.into_iter().flat_map(|k| values(d[k].as_tensor())).collect::<Vec<f32>>()
        };
        let before: Vec<(String, Tensor)> =
            varmap.data().lock().unwrap().iter().map(|(k, v)| (k.clone(), v.as_tensor().copy().unwrap())).collect();
        let restore = || {
            let d = varmap.data().lock().unwrap();
            for (k, v) in &before {
                d[k].set(v).unwrap();
            }
        };
        // The padded form, by hand.
        let x = Var::from_tensor(&p.features).unwrap();
        let h = net.linear.forward(&x.as_tensor().reshape((n * npp, f)).unwrap()).unwrap();
        let h = crate::bnrelu::bn_relu(&net.bn, &h, true).unwrap();
        let want_y = h.reshape((n, npp, 16)).unwrap().broadcast_mul(&p.mask).unwrap().max(1).unwrap();
        let want = outputs_and_gradients([("y", &want_y, &up), ("y", &want_y, &up.zeros_like().unwrap())], &x, &varmap);
        let want_stats = stats(&varmap);
        restore();
        // The net on the packed rows (x enters through the points, so dx is taken on them and
        // compared on the real slots).
        let xp = Var::from_tensor(&p.points).unwrap();
        let q = PillarTensors { points: xp.as_tensor().clone(), ..p.clone() };
        let got_y = net.encode(&q, true).unwrap();
        let got = outputs_and_gradients([("y", &got_y, &up), ("y", &got_y, &up.zeros_like().unwrap())], &xp, &varmap);
        let dx_real: Vec<f32> = want[2]
            .1
            .chunks(f)
            .zip(&pillars.mask)
            .filter(|(_, m)| **m > 0.5)
            .flat_map(|(row, _)| row.to_vec())
            .collect();
        let want: Vec<(String, Vec<f32>)> =
            want.into_iter().map(|(k, v)| if k == "dx" { (k, dx_real.clone()) } else { (k, v) }).collect();
        assert_close(&got, &want, 1e-5, 1e-7, "packed against padded");
        let got_stats = stats(&varmap);
        for (a, b) in got_stats.iter().zip(&want_stats) {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "running statistics: {a} against {b}");
        }
    }
}
