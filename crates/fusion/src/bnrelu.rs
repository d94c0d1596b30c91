//! BatchNorm and ReLU over rows `(N, C)` as one autograd node (training, CPU, f32).
//!
//! candle-nn's `BatchNorm` builds its training pass from about fifteen tensor operations
//! (transpose and copy to `(C, N)`, two means, subtraction, square, square root, division,
//! scale, shift, transpose back), and `relu` adds a comparison, a cast and a product to the
//! backward pass. candle's backward pass gives each of those nodes a zeroed gradient and adds
//! into it, so on the sparse rows of a roadside frame (a few thousand rows of 64 channels) the
//! normalisation cost more than the convolutions it follows. [`bn_relu`] computes the batch
//! statistics on the host, updates the running statistics exactly as candle-nn does (momentum,
//! unbiased variance), and applies the normalisation and the ReLU in one pass; its backward
//! pass is the closed form of BatchNorm's gradient. On other devices, in evaluation, or with a
//! batch of one row it is candle-nn's `BatchNorm` followed by `relu`, which the tests compare
//! it with (values, running statistics and all three gradients).
//!
//! Data-parallel training ([`crate::train`]) runs the replicas of a step side by side on one set
//! of variables; only the first replica updates the running statistics (as multi-GPU training
//! without synchronised BatchNorm keeps the first rank's), the others run inside
//! [`with_running_stats_frozen`]. A plugin that normalises with candle-nn's `BatchNorm`
//! directly instead of [`bn_relu`] (or the modules built on it) updates them from every
//! replica, in whatever order the threads reach them.

use crate::conv::{f32_slice, with_cpu};
use crate::error::Result;
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Shape, Tensor, Var};
use candle_nn::{BatchNorm, ModuleT};
use rayon::prelude::*;
use std::cell::Cell;

thread_local! {
    static FROZEN: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with [`bn_relu`]'s running statistics left as they are on this thread (training
/// still normalises with the batch statistics): the data-parallel replicas after the first.
pub fn with_running_stats_frozen<T>(f: impl FnOnce() -> T) -> T {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            FROZEN.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(FROZEN.with(|c| c.replace(true)));
    f()
}

fn frozen() -> bool {
    FROZEN.with(Cell::get)
}

/// candle-nn's training pass (batch statistics over every dimension but the channels, dim 1)
/// without its update of the running statistics.
fn batch_norm_frozen(bn: &BatchNorm, x: &Tensor) -> Result<Tensor> {
    let xt = x.transpose(0, 1)?;
    let dims = xt.dims().to_vec();
    let flat = xt.flatten_from(1)?.contiguous()?;
    let centred = flat.broadcast_sub(&flat.mean_keepdim(1)?)?;
    let var = centred.sqr()?.mean_keepdim(1)?;
    let mut y = centred.broadcast_div(&(var + bn.eps())?.sqrt()?)?;
    if let Some((gamma, beta)) = bn.weight_and_bias() {
        y = y.broadcast_mul(&gamma.unsqueeze(1)?)?.broadcast_add(&beta.unsqueeze(1)?)?;
    }
    Ok(y.reshape(dims.as_slice())?.transpose(0, 1)?)
}

/// `relu(bn(x))` for rows `x` `(N, C)`; in training on the CPU one fused node.
pub fn bn_relu(bn: &BatchNorm, x: &Tensor, train: bool) -> Result<Tensor> {
    let fused = train
        && x.device().is_cpu()
        && x.dtype() == DType::F32
        && x.rank() == 2
        && x.dim(0)? > 1
        && bn.weight_and_bias().is_some();
    let Some((gamma, beta)) = bn.weight_and_bias().filter(|_| fused) else {
        if train && frozen() {
            return Ok(batch_norm_frozen(bn, x)?.relu()?);
        }
        return Ok(bn.forward_t(x, train)?.relu()?);
    };
    let x = x.contiguous()?;
    let (n, c) = x.dims2()?;
    let (mean, var) = with_cpu::<f32, _>(&x, OP, |v| Ok(moments(v, c)))?;
    // Running statistics as candle-nn updates them: biased mean, unbiased variance.
    let m = bn.momentum();
    let dev = x.device();
    let mean_t = Tensor::from_slice(&mean, c, dev)?;
    let var_t = Tensor::from_slice(&var, c, dev)?;
    if !frozen() {
        let running_mean = ((bn.running_mean() * (1.0 - m))? + (&mean_t * m)?)?;
        let running_var = ((bn.running_var() * (1.0 - m))? + (&var_t * (m * n as f64 / (n as f64 - 1.0)))?)?;
        Var::from_tensor(bn.running_mean())?.set(&running_mean)?;
        Var::from_tensor(bn.running_var())?.set(&running_var)?;
    }
    let inv: Vec<f32> = var.iter().map(|v| 1.0 / (v + bn.eps() as f32).sqrt()).collect();
    Ok(x.apply_op3(&gamma.contiguous()?, &beta.contiguous()?, BnRelu { mean, inv })?)
}

/// Per-channel mean and biased variance of rows `(N, C)`, accumulated in f64.
fn moments(x: &[f32], c: usize) -> (Vec<f32>, Vec<f32>) {
    let n = (x.len() / c.max(1)).max(1) as f64;
    let mut sum = vec![0f64; c];
    for row in x.chunks_exact(c) {
        for (s, &v) in sum.iter_mut().zip(row) {
            *s += v as f64;
        }
    }
    let mean: Vec<f64> = sum.iter().map(|s| s / n).collect();
    let mut sq = vec![0f64; c];
    for row in x.chunks_exact(c) {
        for ((s, &v), m) in sq.iter_mut().zip(row).zip(&mean) {
            let d = v as f64 - m;
            *s += d * d;
        }
    }
    (mean.iter().map(|&m| m as f32).collect(), sq.iter().map(|s| (s / n) as f32).collect())
}

/// The fused node: `y = max(0, γ · (x − μ) · inv + β)` with the batch's μ and inv = 1/√(σ² + ε).
#[derive(Debug, Clone)]
struct BnRelu {
    mean: Vec<f32>,
    inv: Vec<f32>,
}

const ROWS: usize = 512;
const OP: &str = "hilo-bn-relu";

fn host(t: &Tensor) -> candle_core::Result<Vec<f32>> {
    t.flatten_all()?.to_vec1::<f32>()
}

impl CustomOp3 for BnRelu {
    fn name(&self) -> &'static str {
        OP
    }

    fn cpu_fwd(
        &self,
        xs: &CpuStorage,
        xl: &Layout,
        gs: &CpuStorage,
        gl: &Layout,
        bs: &CpuStorage,
        bl: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (x, gamma, beta) = (f32_slice(xs, xl, OP)?, f32_slice(gs, gl, OP)?, f32_slice(bs, bl, OP)?);
        let c = self.mean.len();
        // y = max(0, x · a + b) per channel, a = γ · inv, b = β − μ · a.
        let a: Vec<f32> = gamma.iter().zip(&self.inv).map(|(g, i)| g * i).collect();
        let b: Vec<f32> = beta.iter().zip(&a).zip(&self.mean).map(|((bt, a), m)| bt - m * a).collect();
        let mut y = vec![0f32; x.len()];
        y.par_chunks_mut(ROWS * c).zip(x.par_chunks(ROWS * c)).for_each(|(yc, xc)| {
            for (yr, xr) in yc.chunks_exact_mut(c).zip(xc.chunks_exact(c)) {
                for (((y, &x), a), b) in yr.iter_mut().zip(xr).zip(&a).zip(&b) {
                    *y = (x * a + b).max(0.0);
                }
            }
        });
        Ok((CpuStorage::F32(y), xl.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        gamma: &Tensor,
        beta: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (n, c) = x.dims2()?;
        let (xv, gv, gamma_v, beta_v) = (host(x)?, host(grad)?, host(gamma)?, host(beta)?);
        // dz = dy where the pre-activation z = γ·x̂ + β is ≥ 0 (candle's relu gradient), else 0.
        // dβ = Σ dz, dγ = Σ dz·x̂, dx = γ·inv/N · (N·dz − dβ − x̂·dγ).
        let xhat = |row: &[f32], k: usize| (row[k] - self.mean[k]) * self.inv[k];
        let mut dz = vec![0f32; n * c];
        let (mut dbeta, mut dgamma) = (vec![0f64; c], vec![0f64; c]);
        for ((dzr, xr), gr) in dz.chunks_exact_mut(c).zip(xv.chunks_exact(c)).zip(gv.chunks_exact(c)) {
            for k in 0..c {
                let h = xhat(xr, k);
                if gamma_v[k] * h + beta_v[k] >= 0.0 {
                    dzr[k] = gr[k];
                    dbeta[k] += gr[k] as f64;
                    dgamma[k] += (gr[k] * h) as f64;
                }
            }
        }
        let nf = n as f32;
        let (db, dg): (Vec<f32>, Vec<f32>) =
            (dbeta.iter().map(|&v| v as f32).collect(), dgamma.iter().map(|&v| v as f32).collect());
        let scale: Vec<f32> = gamma_v.iter().zip(&self.inv).map(|(g, i)| g * i / nf).collect();
        let mut dx = vec![0f32; n * c];
        dx.par_chunks_mut(ROWS * c).zip(dz.par_chunks(ROWS * c)).zip(xv.par_chunks(ROWS * c)).for_each(
            |((dxc, dzc), xc)| {
                for ((dxr, dzr), xr) in dxc.chunks_exact_mut(c).zip(dzc.chunks_exact(c)).zip(xc.chunks_exact(c)) {
                    for k in 0..c {
                        dxr[k] = scale[k] * (nf * dzr[k] - db[k] - xhat(xr, k) * dg[k]);
                    }
                }
            },
        );
        let dev = x.device();
        Ok((
            Some(Tensor::from_vec(dx, (n, c), dev)?),
            Some(Tensor::from_vec(dg, c, dev)?),
            Some(Tensor::from_vec(db, c, dev)?),
        ))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::{VarBuilder, VarMap};
    use rand::SeedableRng;

    fn bn(varmap: &VarMap, c: usize) -> BatchNorm {
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let cfg = candle_nn::BatchNormConfig { eps: 1e-3, remove_mean: true, affine: true, momentum: 0.1 };
        candle_nn::batch_norm(c, cfg, vb).unwrap()
    }

    fn close(a: &Tensor, b: &Tensor, tol: f32, what: &str) {
        let (a, b) = (host(a).unwrap(), host(b).unwrap());
        assert_eq!(a.len(), b.len(), "{what}");
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!((x - y).abs() <= tol * (1.0 + y.abs()), "{what}[{i}]: {x} vs {y}");
        }
    }

    /// The fused node equals candle-nn's BatchNorm + relu: outputs, running statistics after
    /// the step, and the gradients of x, γ and β, on rows with a large common offset (the
    /// case where a one-pass variance loses digits), a constant channel (variance 0: ε alone)
    /// and an odd number of rows not a multiple of the chunk.
    #[test]
    fn fused_equals_candle_batch_norm_and_relu() {
        let dev = Device::Cpu;
        let (n, c) = (1037usize, 7usize);
        // Seeded: candle's CPU `randn` cannot be.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut normal = |len: usize| -> Vec<f32> {
            (0..len).map(|_| rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng)).collect()
        };
        let base = Tensor::from_vec(normal(n * c), (n, c), &dev).unwrap();
        let offset = Tensor::from_slice(&[0f32, 100.0, -3.0, 0.0, 1e3, 0.5, 0.0], (1, c), &dev).unwrap();
        let mut x = base.broadcast_add(&offset).unwrap();
        // Channel 3 constant.
        let col = Tensor::full(2.5f32, (n, 1), &dev).unwrap();
        x = Tensor::cat(&[&x.narrow(1, 0, 3).unwrap(), &col, &x.narrow(1, 4, 3).unwrap()], 1).unwrap();
        let up = Tensor::from_vec(normal(n * c), (n, c), &dev).unwrap();
        let (vm_a, vm_b) = (VarMap::new(), VarMap::new());
        let (bn_a, bn_b) = (bn(&vm_a, c), bn(&vm_b, c));
        // Non-trivial γ, β (some γ negative), identical in both.
        let (g, b) = bn_a.weight_and_bias().unwrap();
        let gs = Tensor::from_slice(&[1.5f32, -0.7, 0.3, 2.0, 1.0, -1.2, 0.9], c, &dev).unwrap();
        let bs = Tensor::from_slice(&[0.1f32, 0.2, -0.3, 0.0, 0.5, -0.1, 0.05], c, &dev).unwrap();
        Var::from_tensor(g).unwrap().set(&gs).unwrap();
        Var::from_tensor(b).unwrap().set(&bs).unwrap();
        let (g2, b2) = bn_b.weight_and_bias().unwrap();
        Var::from_tensor(g2).unwrap().set(&gs).unwrap();
        Var::from_tensor(b2).unwrap().set(&bs).unwrap();

        let xa = Var::from_tensor(&x).unwrap();
        let xb = Var::from_tensor(&x).unwrap();
        let ya = bn_relu(&bn_a, xa.as_tensor(), true).unwrap();
        let yb = bn_b.forward_t(xb.as_tensor(), true).unwrap().relu().unwrap();
        // candle-nn's statistics are f32: at a common offset of 1e3 its normalised values carry
        // about 5e-4 relative error (ours are f64), so the outputs agree to 2e-3, as the gradients.
        close(&ya, &yb, 2e-3, "output");
        close(bn_a.running_mean(), bn_b.running_mean(), 1e-5, "running mean");
        close(bn_a.running_var(), bn_b.running_var(), 1e-4, "running var");
        let ga = (&ya * &up).unwrap().sum_all().unwrap().backward().unwrap();
        let gb = (&yb * &up).unwrap().sum_all().unwrap().backward().unwrap();
        close(ga.get(xa.as_tensor()).unwrap(), gb.get(xb.as_tensor()).unwrap(), 2e-3, "dx");
        close(ga.get(g).unwrap(), gb.get(g2).unwrap(), 2e-3, "dgamma");
        close(ga.get(b).unwrap(), gb.get(b2).unwrap(), 2e-3, "dbeta");
        // Evaluation takes candle-nn's path with the running statistics.
        close(&bn_relu(&bn_a, &x, false).unwrap(), &bn_b.forward_t(&x, false).unwrap().relu().unwrap(), 1e-5, "eval");
    }

    /// A replica after the first (statistics frozen) gives the training pass's output, on the
    /// fused path (rows) and on candle-nn's (a dense `(B, C, H, W)` map), and leaves the running
    /// statistics as they were; outside the frozen scope they update again.
    #[test]
    fn frozen_replicas_normalise_alike_and_keep_the_statistics() {
        let dev = Device::Cpu;
        let c = 5usize;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for dims in [vec![41usize, c], vec![2, c, 3, 4]] {
            let n: usize = dims.iter().product();
            let v: Vec<f32> = (0..n)
                .map(|_| 3.0 * rand_distr::Distribution::<f32>::sample(&rand_distr::StandardNormal, &mut rng) + 1.0)
                .collect();
            let x = Tensor::from_vec(v, dims.as_slice(), &dev).unwrap();
            let (vm_a, vm_b) = (VarMap::new(), VarMap::new());
            let (bn_a, bn_b) = (bn(&vm_a, c), bn(&vm_b, c));
            let before = (host(bn_a.running_mean()).unwrap(), host(bn_a.running_var()).unwrap());
            let frozen = with_running_stats_frozen(|| bn_relu(&bn_a, &x, true)).unwrap();
            assert!(!super::frozen(), "the scope restores the flag");
            assert_eq!(host(bn_a.running_mean()).unwrap(), before.0, "{dims:?}: running mean kept");
            assert_eq!(host(bn_a.running_var()).unwrap(), before.1, "{dims:?}: running var kept");
            let live = bn_relu(&bn_b, &x, true).unwrap();
            close(&frozen, &live, 1e-4, "frozen output");
            assert_ne!(host(bn_b.running_mean()).unwrap(), before.0, "{dims:?}: unfrozen updates");
        }
    }
}
