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
    /// Cross-attention at every cell, multi-head: the LiDAR feature queries the cell's two
    /// tokens (its own and the radar's), q = W_q L, k_m = W_k,m X_m, v_m = W_v,m X_m, softmax over
    /// the two scores q·k_m / √d per head, A = Σ_m a_m v_m; out = 1×1 conv(concat(L, A)). The
    /// weights a_m say, per cell and head, how much the radar is listened to. Left out: attention
    /// across cells (a global or deformable one costs more than two CPU cores afford per step;
    /// the radar map is already widened by a 3×3 convolution before φ).
    Attention,
}

/// Heads and channels per head of [`FuseOp::Attention`].
pub const ATTENTION_HEADS: usize = 4;
pub const ATTENTION_HEAD_DIM: usize = 8;

#[derive(Debug)]
pub struct BevFuse {
    op: FuseOp,
    out: ConvBn,
    gate: Option<crate::conv::Conv>,
    proj: Option<ConvBn>,
    back: Option<ConvBn>,
    alpha: Option<Tensor>,
    /// Attention's projections: q from L; (k, v) from L and from R.
    attn: Option<[crate::conv::Conv; 3]>,
    pub out_channels: usize,
}

impl BevFuse {
    pub fn new(cl: usize, cr: usize, out: usize, op: FuseOp, vb: VarBuilder) -> Result<Self> {
        // The weighted sum's output convolution reads C_L channels; every other one reads both.
        let att = ATTENTION_HEADS * ATTENTION_HEAD_DIM;
        let out_in = match op {
            FuseOp::Weighted => cl,
            FuseOp::Attention => cl + att,
            _ => cl + cr,
        };
        let mut f = BevFuse {
            op,
            out: ConvBn::new(out_in, out, 1, 1, vb.pp("out"))?,
            gate: None,
            proj: None,
            back: None,
            alpha: None,
            attn: None,
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
            FuseOp::Attention => {
                use crate::conv::Conv;
                f.attn = Some([
                    Conv::new(cl, att, 1, 1, 0, false, vb.pp("query"))?,
                    Conv::new(cl, 2 * att, 1, 1, 0, false, vb.pp("lidar_kv"))?,
                    Conv::new(cr, 2 * att, 1, 1, 0, false, vb.pp("radar_kv"))?,
                ]);
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
            FuseOp::Attention => {
                let Some(attn) = &self.attn else { return self.out.forward(&Tensor::cat(&[l, r], 1)?, at, train) };
                let a = cross_attention(attn, l, r, at)?;
                self.out.forward(&Tensor::cat(&[l, &a], 1)?, at, train)
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

/// Splits the channel dimension (1) of `x` into (heads, head dim): `(B, C, H, W)` to
/// `(B, h, d, H, W)`, `(N, C)` to `(N, h, d)`.
fn heads(x: &Tensor) -> Result<Tensor> {
    let dims = x.dims();
    let mut shape = vec![dims[0], ATTENTION_HEADS, dims[1] / ATTENTION_HEADS];
    shape.extend_from_slice(&dims[2..]);
    Ok(x.reshape(shape)?)
}

/// [`FuseOp::Attention`]'s value map A (channels heads × head dim), for dense and sparse maps.
pub fn cross_attention(attn: &[crate::conv::Conv; 3], l: &Tensor, r: &Tensor, at: At) -> Result<Tensor> {
    let att = ATTENTION_HEADS * ATTENTION_HEAD_DIM;
    let q = heads(&attn[0].forward(l, at)?)?;
    let kv_l = attn[1].forward(l, at)?;
    let kv_r = attn[2].forward(r, at)?;
    let (k_l, v_l) = (heads(&kv_l.narrow(1, 0, att)?)?, heads(&kv_l.narrow(1, att, att)?)?);
    let (k_r, v_r) = (heads(&kv_r.narrow(1, 0, att)?)?, heads(&kv_r.narrow(1, att, att)?)?);
    let scale = 1.0 / (ATTENTION_HEAD_DIM as f64).sqrt();
    // Two tokens: the softmax over them is the logistic of the score difference.
    let diff = ((q.mul(&k_l)?.sum_keepdim(2)? - q.mul(&k_r)?.sum_keepdim(2)?)? * scale)?;
    let w_l = candle_nn::ops::sigmoid(&diff)?;
    let a = (v_r.clone() + v_l.sub(&v_r)?.broadcast_mul(&w_l)?)?;
    Ok(a.reshape(l.dims().iter().enumerate().map(|(i, &d)| if i == 1 { att } else { d }).collect::<Vec<_>>())?)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    /// The operator against a direct evaluation of its definition at one cell: per head, the
    /// softmax over the LiDAR and radar tokens' scores weights their values.
    #[test]
    fn attention_matches_its_definition_at_a_cell() {
        let dev = Device::Cpu;
        let varmap = candle_nn::VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let (cl, cr) = (6, 5);
        let f = BevFuse::new(cl, cr, 7, FuseOp::Attention, vb).unwrap();
        let l = Tensor::randn(0f32, 1.0, (2, cl, 3, 4), &dev).unwrap();
        let r = Tensor::randn(0f32, 1.0, (2, cr, 3, 4), &dev).unwrap();
        let attn = f.attn.as_ref().unwrap();
        let a = cross_attention(attn, &l, &r, At::Dense).unwrap();
        assert_eq!(a.dims(), &[2, ATTENTION_HEADS * ATTENTION_HEAD_DIM, 3, 4]);
        let cell = |x: &Tensor| -> Vec<f32> {
            x.narrow(0, 1, 1)
                .unwrap()
                .narrow(2, 2, 1)
                .unwrap()
                .narrow(3, 1, 1)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap()
        };
        let (lc, rc) = (cell(&l), cell(&r));
        let w = |c: &crate::conv::Conv| -> Vec<Vec<f32>> {
            c.weight().squeeze(3).unwrap().squeeze(2).unwrap().to_vec2().unwrap()
        };
        let mv = |m: &[Vec<f32>], x: &[f32]| -> Vec<f32> {
            m.iter().map(|row| row.iter().zip(x).map(|(a, b)| a * b).sum()).collect()
        };
        let (q, kvl, kvr) = (mv(&w(&attn[0]), &lc), mv(&w(&attn[1]), &lc), mv(&w(&attn[2]), &rc));
        let n = ATTENTION_HEADS * ATTENTION_HEAD_DIM;
        let got = cell(&a);
        for h in 0..ATTENTION_HEADS {
            let idx = h * ATTENTION_HEAD_DIM..(h + 1) * ATTENTION_HEAD_DIM;
            let dot = |k: &[f32]| idx.clone().map(|i| q[i] * k[i]).sum::<f32>() / (ATTENTION_HEAD_DIM as f32).sqrt();
            let (sl, sr) = (dot(&kvl[..n]), dot(&kvr[..n]));
            let (el, er) = (sl.exp(), sr.exp());
            for i in idx.clone() {
                let want = (el * kvl[n + i] + er * kvr[n + i]) / (el + er);
                assert!((got[i] - want).abs() < 1e-4, "head {h} channel {i}: {} vs {want}", got[i]);
            }
        }
        // The whole operator runs and keeps the map's shape.
        assert_eq!(f.forward(&l, &r, At::Dense, true).unwrap().dims(), &[2, 7, 3, 4]);
    }
}
