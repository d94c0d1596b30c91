//! BEV fusion operators φ shared by the plugins: LiDAR map `L` (C_L channels) and radar map `R`
//! (C_R channels) to one map (C_out channels), dense `(B, C, H, W)` or sparse `(N, C)` alike.

use crate::error::Result;
use crate::layout::At;
use crate::modules::ConvBn;
use candle_core::Tensor;
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FuseOp {
    /// concat(L, R), then a 1×1 convolution.
    Concat,
    /// L + α · proj(R) with a learned scalar α (starting at 0.5).
    Weighted,
    /// Adaptive gating per channel: a weight in (0, 1) for every channel of both maps,
    /// w = σ(1×1 conv(frame mean of concat(L, R))), then out = 1×1 conv(w ⊙ concat(L, R)).
    GatedChannel,
    /// Adaptive gating per pixel: one weight per modality and cell, w = σ(3×3 conv(concat(L, R))).
    GatedPixel,
    /// Bidirectional enhancement: R' = R + conv(L) (LiDAR's height/BEV features enrich the
    /// radar map), then L' = L + conv(R'); out = 1×1 conv(concat(L', R')).
    Bidirectional,
}

#[derive(Debug)]
pub struct BevFuse {
    op: FuseOp,
    out: ConvBn,
    gate: Option<crate::conv::Conv>,
    proj: Option<ConvBn>,
    back: Option<ConvBn>,
    alpha: Option<Tensor>,
    pub out_channels: usize,
}

impl BevFuse {
    pub fn new(cl: usize, cr: usize, out: usize, op: FuseOp, vb: VarBuilder) -> Result<Self> {
        // The weighted sum's output convolution reads C_L channels; every other one reads both.
        let out_in = if op == FuseOp::Weighted { cl } else { cl + cr };
        let mut f = BevFuse {
            op,
            out: ConvBn::new(out_in, out, 1, 1, vb.pp("out"))?,
            gate: None,
            proj: None,
            back: None,
            alpha: None,
            out_channels: out,
        };
        match op {
            FuseOp::Concat => {}
            FuseOp::Weighted => {
                f.proj = Some(ConvBn::new(cr, cl, 1, 1, vb.pp("proj"))?);
                f.alpha = Some(vb.get_with_hints(1, "alpha", candle_nn::Init::Const(0.5))?);
            }
            FuseOp::GatedChannel => {
                f.gate = Some(crate::conv::Conv::new(cl + cr, cl + cr, 1, 1, 0, true, vb.pp("gate"))?)
            }
            FuseOp::GatedPixel => f.gate = Some(crate::conv::Conv::new(cl + cr, 2, 3, 1, 1, true, vb.pp("gate"))?),
            FuseOp::Bidirectional => {
                f.proj = Some(ConvBn::new(cl, cr, 3, 1, vb.pp("l_to_r"))?);
                f.back = Some(ConvBn::new(cr, cl, 3, 1, vb.pp("r_to_l"))?);
            }
        }
        Ok(f)
    }

    /// Fuses the two maps at one place of a layout (level 0 of the batch's [`crate::layout::Layout`]).
    pub fn forward(&self, l: &Tensor, r: &Tensor, at: At, train: bool) -> Result<Tensor> {
        match self.op {
            FuseOp::Concat => self.out.forward(&Tensor::cat(&[l, r], 1)?, at, train),
            FuseOp::Weighted => {
                let (Some(p), Some(a)) = (&self.proj, &self.alpha) else { return self.out.forward(l, at, train) };
                let x = (l + p.forward(r, at, train)?.broadcast_mul(a)?)?;
                self.out.forward(&x, at, train)
            }
            FuseOp::GatedChannel => {
                let cat = Tensor::cat(&[l, r], 1)?;
                let Some(g) = &self.gate else { return self.out.forward(&cat, at, train) };
                // One weight per channel of each modality, from the frame's mean of both maps.
                let w = candle_nn::ops::sigmoid(&g.forward(&at.frame_mean(&cat)?, at)?)?;
                self.out.forward(&cat.broadcast_mul(&w)?, at, train)
            }
            FuseOp::GatedPixel => {
                let cat = Tensor::cat(&[l, r], 1)?;
                let Some(g) = &self.gate else { return self.out.forward(&cat, at, train) };
                let w = candle_nn::ops::sigmoid(&g.forward(&cat, at)?)?;
                let (wl, wr) = (w.narrow(1, 0, 1)?, w.narrow(1, 1, 1)?);
                self.out.forward(&Tensor::cat(&[l.broadcast_mul(&wl)?, r.broadcast_mul(&wr)?], 1)?, at, train)
            }
            FuseOp::Bidirectional => {
                let (Some(p), Some(b)) = (&self.proj, &self.back) else {
                    return self.out.forward(&Tensor::cat(&[l, r], 1)?, at, train);
                };
                let r2 = (r + p.forward(l, at, train)?)?;
                let l2 = (l + b.forward(&r2, at, train)?)?;
                self.out.forward(&Tensor::cat(&[&l2, &r2], 1)?, at, train)
            }
        }
    }
}
