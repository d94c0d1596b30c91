//! Losses, computed stably for extreme logits: log σ(x) = −softplus(−x) with
//! softplus(x) = max(x, 0) + ln(1 + e^−|x|), so ±100 never produces inf or NaN.

use crate::error::Result;
use candle_core::Tensor;

/// softplus(x), stable for any x.
pub fn softplus(x: &Tensor) -> Result<Tensor> {
    Ok((x.relu()? + (x.abs()?.neg()?.exp()? + 1.0)?.log()?)?)
}

/// CenterNet's penalty-reduced focal loss over a Gaussian heatmap target `t` (1 at centres),
/// normalised by the number of centres (at least 1).
pub fn centernet_focal(logits: &Tensor, t: &Tensor, num_pos: f32) -> Result<Tensor> {
    let p = candle_nn::ops::sigmoid(logits)?;
    let log_p = softplus(&logits.neg()?)?.neg()?;
    let log_1mp = softplus(logits)?.neg()?;
    let pos = t.ge(0.999)?.to_dtype(logits.dtype())?;
    let neg = (1.0 - &pos)?;
    let pos_loss = ((1.0 - &p)?.sqr()?.mul(&log_p)?.mul(&pos))?;
    let neg_w = (1.0 - t)?.powf(4.0)?;
    let neg_loss = (p.sqr()?.mul(&log_1mp)?.mul(&neg_w)?.mul(&neg))?;
    Ok(((pos_loss.sum_all()? + neg_loss.sum_all()?)?.neg()? / num_pos.max(1.0) as f64)?)
}

/// Sigmoid focal loss (RetinaNet; α = 0.25, γ = 2) over binary targets, normalised by the
/// number of positives (at least 1).
pub fn sigmoid_focal(logits: &Tensor, t: &Tensor, num_pos: f32) -> Result<Tensor> {
    let p = candle_nn::ops::sigmoid(logits)?;
    let log_p = softplus(&logits.neg()?)?.neg()?;
    let log_1mp = softplus(logits)?.neg()?;
    let pos = (t * 0.25)?.mul(&(1.0 - &p)?.sqr()?)?.mul(&log_p)?;
    let neg = ((1.0 - t)? * 0.75)?.mul(&p.sqr()?)?.mul(&log_1mp)?;
    Ok(((pos + neg)?.sum_all()?.neg()? / num_pos.max(1.0) as f64)?)
}

/// Weighted L1 between prediction and target (B, C, H, W) with per-channel weights, masked to
/// the positive cells (B, 1, H, W), normalised by the number of positives.
pub fn masked_l1(pred: &Tensor, target: &Tensor, mask: &Tensor, channel_w: &Tensor, num_pos: f32) -> Result<Tensor> {
    let d = (pred - target)?.abs()?.broadcast_mul(mask)?.broadcast_mul(channel_w)?;
    Ok((d.sum_all()? / num_pos.max(1.0) as f64)?)
}
