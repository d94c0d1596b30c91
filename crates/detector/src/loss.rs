//! Losses, computed stably for extreme logits: log σ(x) = −softplus(−x) with
//! softplus(x) = max(x, 0) + ln(1 + e^−|x|), so ±100 never produces inf or NaN.
//!
//! Each loss exists twice. The composite functions ([`centernet_focal`], [`sigmoid_focal`],
//! [`per_class_mean`], [`masked_l1`]) build it from candle's operations, about twenty autograd
//! nodes over the head's output, each with its own buffers and zeroed gradient. The fused ones
//! ([`focal_sum`], [`weighted_l1`]) are one node each: the weighted sum in one pass over the
//! logits (f64 per element, partial sums in fixed chunks, so the result does not depend on the
//! threads), with the derivative of every term kept from that pass for the hand-written backward
//! pass. Training takes the fused ones on the CPU while [`hilo_fusion::cpu::fused`] is on for
//! [`hilo_fusion::cpu::Layer::Loss`]; the tests hold them to the composites and to central
//! differences.

use crate::error::Result;
use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};
use hilo_fusion::cpu::{Layer, fused_on};
use rayon::prelude::*;
use std::sync::OnceLock;

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
    class_weighted_sum(terms, &class_weights(pos_per_class, terms.dim(1)?))
}

/// `Σ_k weight[k] · Σ terms[·, k, ·]` over loss terms whose class axis is 1 (`(N, K)` or
/// `(B, K, H, W)`), from candle's operations.
fn class_weighted_sum(terms: &Tensor, weight: &[f32]) -> Result<Tensor> {
    let by_class = match terms.rank() {
        2 => terms.sum(0)?,
        _ => terms.flatten_from(2)?.sum(2)?.sum(0)?,
    };
    Ok(by_class.mul(&Tensor::from_slice(weight, weight.len(), terms.device())?)?.sum_all()?)
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

/// The focal losses the heads train with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Focal {
    /// [`centernet_focal`]'s terms (a Gaussian heatmap target, positives where t ≥ 0.999).
    CenterNet,
    /// [`sigmoid_focal`]'s terms (α = 0.25, γ = 2).
    Sigmoid,
}

impl Focal {
    /// The term (≥ 0) at logit `x` and target `t`, and its derivative in `x`, in f64.
    /// With p = σ(x), q = 1 − p = σ(−x) (each from e^−|x|, so neither loses digits near 0 or
    /// 1), log p = −softplus(−x), log q = −softplus(x), dp/dx = p·q:
    /// - CenterNet, positive: −q² log p, derivative q² (2p log p − q);
    /// - CenterNet, negative: −(1−t)⁴ p² log q, derivative (1−t)⁴ p² (p − 2q log q);
    /// - sigmoid: −α t q² log p − (1−α)(1−t) p² log q, derivative
    ///   −α t q² (q − 2p log p) − (1−α)(1−t) p² (2q log q − p).
    pub fn term(self, x: f64, t: f64) -> (f64, f64) {
        let e = (-x.abs()).exp();
        let (p, q) = if x >= 0.0 { (1.0 / (1.0 + e), e / (1.0 + e)) } else { (e / (1.0 + e), 1.0 / (1.0 + e)) };
        let softplus = |v: f64| v.max(0.0) + e.ln_1p();
        let (log_p, log_q) = (-softplus(-x), -softplus(x));
        match self {
            Focal::CenterNet if t >= 0.999 => (-q * q * log_p, q * q * (2.0 * p * log_p - q)),
            Focal::CenterNet => {
                let w = (1.0 - t).powi(4);
                (-w * p * p * log_q, w * p * p * (p - 2.0 * q * log_q))
            }
            Focal::Sigmoid => {
                let (a, b) = (0.25 * t, 0.75 * (1.0 - t));
                (
                    -a * q * q * log_p - b * p * p * log_q,
                    -a * q * q * (q - 2.0 * p * log_p) - b * p * p * (2.0 * q * log_q - p),
                )
            }
        }
    }
}

/// Elements per chunk of the fused losses' passes: the partial sums are taken over these fixed
/// chunks and added in order, so the sum is the same at any number of threads.
const CHUNK: usize = 4096;

/// Σ_e w(e) · f(e) over `n` elements, and every f′(e)·w(e), from `term(e) = (f, f′)` and the
/// weight `w(e)`; partial sums per [`CHUNK`], added in order.
fn weighted_pass(
    n: usize,
    weight: impl Fn(usize) -> f64 + Sync,
    term: impl Fn(usize) -> (f64, f64) + Sync,
) -> (f64, Vec<f32>) {
    let mut slope = vec![0f32; n];
    let partial: Vec<f64> = slope
        .par_chunks_mut(CHUNK)
        .enumerate()
        .map(|(k, out)| {
            let mut sum = 0.0;
            for (j, d) in out.iter_mut().enumerate() {
                let e = k * CHUNK + j;
                let w = weight(e);
                if w == 0.0 {
                    continue;
                }
                let (f, df) = term(e);
                sum += w * f;
                *d = (w * df) as f32;
            }
            sum
        })
        .collect();
    (partial.iter().sum(), slope)
}

/// A fused loss's pass over the host values of its input: the sum and each element's derivative.
type Pass = Box<dyn Fn(&[f32]) -> (f64, Vec<f32>) + Send + Sync>;

/// One fused loss node: `cpu_fwd` computes the sum and keeps each element's derivative, `bwd`
/// scales them by the upstream gradient (a scalar).
struct FusedLoss {
    name: &'static str,
    /// The sum and the derivatives from the host values of the input.
    pass: Pass,
    slope: OnceLock<Vec<f32>>,
}

impl std::fmt::Debug for FusedLoss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FusedLoss").field("name", &self.name).finish_non_exhaustive()
    }
}

impl CustomOp1 for FusedLoss {
    fn name(&self) -> &'static str {
        self.name
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = hilo_fusion::cpu::f32_slice(s, l, self.name)?;
        let (sum, slope) = (self.pass)(x);
        // A node is run forward once; a second run would find the same derivatives.
        let _ = self.slope.set(slope);
        Ok((CpuStorage::F32(vec![sum as f32]), Shape::from(())))
    }

    fn bwd(&self, arg: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let Some(slope) = self.slope.get() else { candle_core::bail!("{}: backward before forward", self.name) };
        let g = grad.to_dtype(candle_core::DType::F32)?.to_scalar::<f32>()?;
        let d: Vec<f32> = slope.par_iter().map(|v| v * g).collect();
        Ok(Some(Tensor::from_vec(d, arg.shape(), arg.device())?))
    }
}

/// Σ over the logits of `class_weight[k] · term(x, t)`, k the element's class (axis 1 of `(N, K)`
/// or `(B, K, H, W)`), as one node on the CPU: with every weight 1/max(1, num_pos) it is
/// [`centernet_focal`] or [`sigmoid_focal`], with [`class_weights`] it is [`per_class_mean`] of
/// their terms. Elsewhere (or with the fused layers off) it is built from those.
pub fn focal_sum(kind: Focal, logits: &Tensor, t: &[f32], class_weight: &[f32]) -> Result<Tensor> {
    let k = logits.dim(1)?;
    let inner: usize = logits.dims().iter().skip(2).product();
    if class_weight.len() != k || t.len() != logits.elem_count() {
        return Err(crate::error::DetectorError::Config(format!(
            "focal loss: {} targets and {} class weights for logits {:?}",
            t.len(),
            class_weight.len(),
            logits.dims()
        )));
    }
    if !fused_on(Layer::Loss, logits) {
        let tt = Tensor::from_slice(t, logits.shape(), logits.device())?;
        let terms = match kind {
            Focal::CenterNet => centernet_focal_terms(logits, &tt)?,
            Focal::Sigmoid => sigmoid_focal_terms(logits, &tt)?,
        };
        return class_weighted_sum(&terms, class_weight);
    }
    let (t, w) = (t.to_vec(), class_weight.to_vec());
    let pass =
        move |x: &[f32]| weighted_pass(x.len(), |e| w[(e / inner) % k] as f64, |e| kind.term(x[e] as f64, t[e] as f64));
    Ok(logits.contiguous()?.apply_op1(FusedLoss {
        name: "hilo-focal",
        pass: Box::new(pass),
        slope: OnceLock::new(),
    })?)
}

/// Σ_e w_e · |pred_e − target_e| as one node on the CPU (the derivative w_e · sign, +1 at 0 as
/// candle's `abs` has it); elsewhere (or with the fused layers off) from candle's operations.
/// [`masked_l1`] is this with w = mask · channel weight / max(1, num_pos).
pub fn weighted_l1(pred: &Tensor, target: &[f32], weight: &[f32]) -> Result<Tensor> {
    if target.len() != pred.elem_count() || weight.len() != pred.elem_count() {
        return Err(crate::error::DetectorError::Config(format!(
            "weighted L1: {} targets and {} weights for {:?}",
            target.len(),
            weight.len(),
            pred.dims()
        )));
    }
    if !fused_on(Layer::Loss, pred) {
        let (tt, w) = (
            Tensor::from_slice(target, pred.shape(), pred.device())?,
            Tensor::from_slice(weight, pred.shape(), pred.device())?,
        );
        return Ok((pred - tt)?.abs()?.mul(&w)?.sum_all()?);
    }
    let (t, w) = (target.to_vec(), weight.to_vec());
    let pass = move |x: &[f32]| {
        weighted_pass(
            x.len(),
            |e| w[e] as f64,
            |e| {
                let d = x[e] as f64 - t[e] as f64;
                (d.abs(), if d >= 0.0 { 1.0 } else { -1.0 })
            },
        )
    };
    Ok(pred.contiguous()?.apply_op1(FusedLoss {
        name: "hilo-weighted-l1",
        pass: Box::new(pass),
        slope: OnceLock::new(),
    })?)
}
