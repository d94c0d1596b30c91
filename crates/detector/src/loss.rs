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
    let (pos_loss, neg_loss) = centernet_focal_parts(logits, t)?;
    Ok(((pos_loss.sum_all()? + neg_loss.sum_all()?)?.neg()? / num_pos.max(1.0) as f64)?)
}

/// The terms of [`centernet_focal`] before the sum and normalisation (the logits' shape; each
/// ≥ 0).
pub fn centernet_focal_terms(logits: &Tensor, t: &Tensor) -> Result<Tensor> {
    let (pos_loss, neg_loss) = centernet_focal_parts(logits, t)?;
    Ok((pos_loss + neg_loss)?.neg()?)
}

/// The positive and negative log-likelihood terms of [`centernet_focal`] (each ≤ 0).
fn centernet_focal_parts(logits: &Tensor, t: &Tensor) -> Result<(Tensor, Tensor)> {
    let p = candle_nn::ops::sigmoid(logits)?;
    let log_p = softplus(&logits.neg()?)?.neg()?;
    let log_1mp = softplus(logits)?.neg()?;
    let pos = t.ge(0.999)?.to_dtype(logits.dtype())?;
    let neg = (1.0 - &pos)?;
    let pos_loss = ((1.0 - &p)?.sqr()?.mul(&log_p)?.mul(&pos))?;
    let neg_w = (1.0 - t)?.powf(4.0)?;
    let neg_loss = (p.sqr()?.mul(&log_1mp)?.mul(&neg_w)?.mul(&neg))?;
    Ok((pos_loss, neg_loss))
}

/// Sigmoid focal loss (RetinaNet; α = 0.25, γ = 2) over binary targets, normalised by the
/// number of positives (at least 1).
pub fn sigmoid_focal(logits: &Tensor, t: &Tensor, num_pos: f32) -> Result<Tensor> {
    // Negation is exact, so this is the sum of the negated terms bit for bit.
    Ok((sigmoid_focal_terms(logits, t)?.sum_all()? / num_pos.max(1.0) as f64)?)
}

/// The terms of [`sigmoid_focal`] before the sum and normalisation (each ≥ 0).
pub fn sigmoid_focal_terms(logits: &Tensor, t: &Tensor) -> Result<Tensor> {
    let p = candle_nn::ops::sigmoid(logits)?;
    let log_p = softplus(&logits.neg()?)?.neg()?;
    let log_1mp = softplus(logits)?.neg()?;
    let pos = (t * 0.25)?.mul(&(1.0 - &p)?.sqr()?)?.mul(&log_p)?;
    let neg = ((1.0 - t)? * 0.75)?.mul(&p.sqr()?)?.mul(&log_1mp)?;
    Ok((pos + neg)?.neg()?)
}

/// Loss terms (the class axis 1: `(N, K)` at sites or `(B, K, H, W)` dense) summed per class,
/// each class's sum divided by its positives (at least 1), and the classes averaged:
/// `(1/K) Σ_k Σ terms[·, k, ·] / max(1, n_k)`, the per-task normalisation of CenterPoint's heads.
pub fn per_class_mean(terms: &Tensor, pos_per_class: &[f32]) -> Result<Tensor> {
    let k = terms.dim(1)?;
    let by_class = match terms.rank() {
        2 => terms.sum(0)?,
        _ => terms.flatten_from(2)?.sum(2)?.sum(0)?,
    };
    Ok(by_class.mul(&Tensor::from_vec(class_weights(pos_per_class, k), k, terms.device())?)?.sum_all()?)
}

/// Each class's weight in [`per_class_mean`]: `1 / (K · max(1, n_k))` (a class missing from
/// `pos_per_class` has no positives).
pub fn class_weights(pos_per_class: &[f32], k: usize) -> Vec<f32> {
    (0..k).map(|c| 1.0 / (k as f32 * pos_per_class.get(c).copied().unwrap_or(0.0).max(1.0))).collect()
}

/// Weighted L1 between prediction and target (B, C, H, W) with per-channel weights, masked to
/// the positive cells (B, 1, H, W), normalised by the number of positives.
pub fn masked_l1(pred: &Tensor, target: &Tensor, mask: &Tensor, channel_w: &Tensor, num_pos: f32) -> Result<Tensor> {
    let d = (pred - target)?.abs()?.broadcast_mul(mask)?.broadcast_mul(channel_w)?;
    Ok((d.sum_all()? / num_pos.max(1.0) as f64)?)
}
