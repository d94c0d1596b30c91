//! BEV fusion operators φ shared by the plugins: LiDAR map `L` (B, C_L, H, W) and radar map
//! `R` (B, C_R, H, W) to one map (B, C_out, H, W).

use crate::error::Result;
use crate::modules::ConvBn;
use candle_core::{D, Tensor};
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FuseOp {
    /// concat(L, R), then a 1×1 convolution.
    Concat,
    /// L + α · proj(R) with a learned scalar α (starting at 0.5).
    Weighted,
    /// Adaptive gating per channel: w = σ(1×1 conv(global mean of concat(L, R))) per modality.
    GatedChannel,
    /// Adaptive gating per pixel: w = σ(3×3 conv(concat(L, R))) per modality.
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
        let mut f = BevFuse {
            op,
            out: ConvBn::new(cl + cr, out, 1, 1, vb.pp("out"))?,
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
                f.out = ConvBn::new(cl, out, 1, 1, vb.pp("out"))?;
                f.alpha = Some(vb.get_with_hints(1, "alpha", candle_nn::Init::Const(0.5))?);
            }
            FuseOp::GatedChannel => f.gate = Some(crate::conv::Conv::new(cl + cr, 2, 1, 1, 0, true, vb.pp("gate"))?),
            FuseOp::GatedPixel => f.gate = Some(crate::conv::Conv::new(cl + cr, 2, 3, 1, 1, true, vb.pp("gate"))?),
            FuseOp::Bidirectional => {
                f.proj = Some(ConvBn::new(cl, cr, 3, 1, vb.pp("l_to_r"))?);
                f.back = Some(ConvBn::new(cr, cl, 3, 1, vb.pp("r_to_l"))?);
            }
        }
        Ok(f)
    }

    pub fn forward(&self, l: &Tensor, r: &Tensor, train: bool) -> Result<Tensor> {
        match self.op {
            FuseOp::Concat => self.out.forward(&Tensor::cat(&[l, r], 1)?, train),
            FuseOp::Weighted => {
                let (Some(p), Some(a)) = (&self.proj, &self.alpha) else { return self.out.forward(l, train) };
                let x = (l + p.forward(r, train)?.broadcast_mul(&a.reshape((1, 1, 1, 1))?)?)?;
                self.out.forward(&x, train)
            }
            FuseOp::GatedChannel | FuseOp::GatedPixel => {
                let cat = Tensor::cat(&[l, r], 1)?;
                let Some(g) = &self.gate else { return self.out.forward(&cat, train) };
                let src = if self.op == FuseOp::GatedChannel {
                    cat.mean_keepdim(D::Minus1)?.mean_keepdim(D::Minus2)?
                } else {
                    cat.clone()
                };
                let w = candle_nn::ops::sigmoid(&g.forward(&src)?)?;
                let (wl, wr) = (w.narrow(1, 0, 1)?, w.narrow(1, 1, 1)?);
                self.out.forward(&Tensor::cat(&[l.broadcast_mul(&wl)?, r.broadcast_mul(&wr)?], 1)?, train)
            }
            FuseOp::Bidirectional => {
                let (Some(p), Some(b)) = (&self.proj, &self.back) else {
                    return self.out.forward(&Tensor::cat(&[l, r], 1)?, train);
                };
                let r2 = (r + p.forward(l, train)?)?;
                let l2 = (l + b.forward(&r2, train)?)?;
                self.out.forward(&Tensor::cat(&[&l2, &r2], 1)?, train)
            }
        }
    }
}
