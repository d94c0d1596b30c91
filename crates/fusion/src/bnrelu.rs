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
//! pass is the closed form of BatchNorm's gradient. On other devices (a GPU), in evaluation, or
//! with a batch of one row it is candle-nn's `BatchNorm` followed by `relu`, which the tests
//! compare it with (values, running statistics and all three gradients); except synchronised
//! replicas off the CPU, which need the exchange below and take the same function built from
//! candle's tensor operations (`bn_relu_composite`, statistics in f64 on the device, the
//! gradient's path through them in a copy-forward node's backward pass), also tested against it.
//!
//! Data-parallel training (the detector crate's `train`) runs the replicas of a step side by side on one set
//! of variables; only the first replica updates the running statistics (as multi-GPU training
//! keeps the first rank's), the others run inside [`with_running_stats_frozen`]. A plugin that
//! normalises with candle-nn's `BatchNorm` directly instead of [`bn_relu`] (or the modules built
//! on it) updates them from every replica, in whatever order the threads reach them.
//!
//! Synchronised BatchNorm ([`BatchNormSync`], [`with_synced_batch_norm`]): the replicas of a step
//! normalise with the statistics of the whole batch, as one batch would. In the forward pass each
//! replica hands its rows' count, per-channel sums and centred sums of squares to the others
//! (combined in replica order, Chan's pairwise formula, f64), in the backward pass its sums of
//! `dz` and `dz · x̂`; each exchange is a barrier all replicas meet at, so they must run at once,
//! one thread each. The gradient is then the whole batch's: the sum over the replicas of their
//! parameter gradients is the gradient of the sum of their losses. Rows exchange on any device;
//! a dense map normalised by candle-nn keeps its replica's statistics. The replicas must reach
//! the same BatchNorm layers in the same order (they run one network); one that does not, or
//! that ends its pass while another waits, fails the step with an error naming the layer rather
//! than hanging.

use crate::cpu::{f32_slice, with_cpu};
use crate::error::Result;
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Shape, Tensor, TensorId, Var};
use candle_nn::{BatchNorm, ModuleT};
use rayon::prelude::*;
use std::cell::{Cell, RefCell};
use std::sync::{Arc, Condvar, Mutex};

thread_local! {
    static FROZEN: Cell<bool> = const { Cell::new(false) };
    static SYNC: RefCell<Option<(Arc<BatchNormSync>, usize)>> = const { RefCell::new(None) };
}

/// The replicas of one training step exchanging BatchNorm's sums: a barrier per exchange, at
/// which every replica leaves its numbers and takes all of them, in replica order. One per step.
#[derive(Debug)]
pub struct BatchNormSync {
    ranks: usize,
    state: Mutex<SyncState>,
    turn: Condvar,
}

#[derive(Debug)]
struct SyncState {
    /// Exchanges completed.
    generation: u64,
    /// The layer (its running mean's id) and pass (backward or not) of the exchange under way.
    tag: Option<(TensorId, bool)>,
    arrived: usize,
    deposits: Vec<Option<Vec<f64>>>,
    /// The last completed exchange's deposits, in replica order.
    result: Arc<Vec<Vec<f64>>>,
    /// Replicas whose pass has ended.
    left: usize,
    failure: Option<String>,
}

impl BatchNormSync {
    /// An exchange for `ranks` replicas.
    pub fn new(ranks: usize) -> Arc<Self> {
        Arc::new(BatchNormSync {
            ranks,
            state: Mutex::new(SyncState {
                generation: 0,
                tag: None,
                arrived: 0,
                deposits: vec![None; ranks],
                result: Arc::new(Vec::new()),
                left: 0,
                failure: None,
            }),
            turn: Condvar::new(),
        })
    }

    fn fail(&self, s: &mut SyncState, message: String) -> candle_core::Error {
        s.failure.get_or_insert(message.clone());
        self.turn.notify_all();
        candle_core::Error::Msg(message)
    }

    /// Leaves replica `rank`'s `data` for the exchange of layer `tag` and waits for the others'.
    fn exchange(&self, rank: usize, tag: (TensorId, bool), data: Vec<f64>) -> candle_core::Result<Arc<Vec<Vec<f64>>>> {
        let pass = if tag.1 { "backward" } else { "forward" };
        let mut s = self.state.lock().map_err(|_| candle_core::Error::Msg("a replica panicked in BatchNorm".into()))?;
        if let Some(f) = &s.failure {
            return Err(candle_core::Error::Msg(f.clone()));
        }
        if rank >= self.ranks || s.deposits[rank].is_some() {
            return Err(
                self.fail(&mut s, format!("synchronised BatchNorm: replica {rank} of {} arrived twice", self.ranks))
            );
        }
        if s.left > 0 {
            let message = format!(
                "{PARTED}: replica {rank} reached a BatchNorm layer ({pass} pass) after another replica ended its \
                 pass (it failed, or the replicas' networks took different paths)"
            );
            return Err(self.fail(&mut s, message));
        }
        match s.tag {
            None => s.tag = Some(tag),
            Some(t) if t != tag => {
                let message = format!(
                    "{PARTED}: replica {rank} reached BatchNorm layer {:?} ({pass} pass) while another replica waits \
                     at layer {:?} ({} pass); the replicas' networks took different paths",
                    tag.0,
                    t.0,
                    if t.1 { "backward" } else { "forward" }
                );
                return Err(self.fail(&mut s, message));
            }
            Some(_) => {}
        }
        s.deposits[rank] = Some(data);
        s.arrived += 1;
        if s.arrived == self.ranks {
            s.result = Arc::new(s.deposits.iter_mut().map(|d| d.take().unwrap_or_default()).collect());
            s.arrived = 0;
            s.tag = None;
            s.generation += 1;
            self.turn.notify_all();
            return Ok(s.result.clone());
        }
        let generation = s.generation;
        while s.generation == generation && s.failure.is_none() {
            s = self.turn.wait(s).map_err(|_| candle_core::Error::Msg("a replica panicked in BatchNorm".into()))?;
        }
        match (s.generation != generation, &s.failure) {
            (true, _) => Ok(s.result.clone()),
            (false, Some(f)) => Err(candle_core::Error::Msg(f.clone())),
            (false, None) => Err(candle_core::Error::Msg("synchronised BatchNorm: woken without an exchange".into())),
        }
    }

    /// Replica's pass ended: any replica waiting now, or arriving later, waits in vain.
    fn leave(&self) {
        if let Ok(mut s) = self.state.lock() {
            s.left += 1;
            if s.arrived > 0 {
                let message = format!(
                    "{PARTED}: a replica ended its pass while another waits at a BatchNorm layer (it failed, or \
                     the replicas' networks took different paths)"
                );
                let _ = self.fail(&mut s, message);
            }
        }
    }
}

/// Runs `f` (replica `rank`'s forward and backward pass) with [`bn_relu`] normalising over the
/// rows of all of `sync`'s replicas; on return (or unwinding) the replica is counted as done.
pub fn with_synced_batch_norm<T>(sync: &Arc<BatchNormSync>, rank: usize, f: impl FnOnce() -> T) -> T {
    struct Leave(Option<(Arc<BatchNormSync>, usize)>, Arc<BatchNormSync>);
    impl Drop for Leave {
        fn drop(&mut self) {
            SYNC.with(|c| *c.borrow_mut() = self.0.take());
            self.1.leave();
        }
    }
    let previous = SYNC.with(|c| c.borrow_mut().replace((sync.clone(), rank)));
    let _leave = Leave(previous, sync.clone());
    f()
}

const PARTED: &str = "synchronised BatchNorm: the replicas parted";

/// Whether an error message is a replica's report that the others left the exchange (the
/// consequence of another replica's failure or of networks that took different paths).
pub fn is_parting(message: &str) -> bool {
    message.contains(PARTED)
}

/// Whether this thread's BatchNorm is synchronised with other replicas' (modules that would
/// skip an empty input must then still take part in the exchanges, with no rows).
pub fn synced() -> bool {
    SYNC.with(|c| c.borrow().is_some())
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

/// `relu(bn(x))` for rows `x` `(N, C)`; in training on the CPU one fused node (synchronised
/// with the other replicas inside [`with_synced_batch_norm`]), synchronised replicas elsewhere
/// the same function from tensor operations.
pub fn bn_relu(bn: &BatchNorm, x: &Tensor, train: bool) -> Result<Tensor> {
    bn_relu_on(bn, x, train, crate::cpu::fused_on(crate::cpu::Layer::BnRelu, x))
}

/// [`bn_relu`] of the rows `x` `(N, C)` followed by `zeros` rows of zeros, returning only the
/// rows of `x`: the statistics are those of all `N + zeros` rows, and the zero rows are taken to
/// get no gradient (their outputs are discarded). This is a padded per-point encoder's
/// BatchNorm (a linear layer without bias maps a padding slot to a zero row, which the batch
/// statistics count) computed on its real points alone. In training on the CPU the zero rows
/// enter only the sums (in closed form); elsewhere they are appended and cut off again.
pub fn bn_relu_padded(bn: &BatchNorm, x: &Tensor, zeros: usize, train: bool) -> Result<Tensor> {
    bn_relu_padded_on(bn, x, zeros, train, crate::cpu::fused_on(crate::cpu::Layer::BnRelu, x))
}

fn bn_relu_padded_on(bn: &BatchNorm, x: &Tensor, zeros: usize, train: bool, kernel: bool) -> Result<Tensor> {
    if zeros == 0 || !train {
        // In evaluation each row is normalised on its own (running statistics).
        return bn_relu_on(bn, x, train, kernel);
    }
    if kernel && x.rank() == 2 && bn.weight_and_bias().is_some() {
        return bn_relu_stats(bn, x, zeros, kernel);
    }
    let (n, c) = x.dims2()?;
    let padded = Tensor::cat(&[x, &Tensor::zeros((zeros, c), x.dtype(), x.device())?], 0)?;
    Ok(bn_relu_on(bn, &padded, train, kernel)?.narrow(0, 0, n)?)
}

/// [`bn_relu`], with the fused node's host kernel ([`BnRelu`]) when `kernel` (f32 rows on the
/// CPU), else its composite from tensor operations ([`bn_relu_composite`]) for synchronised
/// replicas and candle-nn's BatchNorm otherwise.
fn bn_relu_on(bn: &BatchNorm, x: &Tensor, train: bool, kernel: bool) -> Result<Tensor> {
    let sync = SYNC.with(|c| c.borrow().clone());
    // Elsewhere (a GPU) only synchronised replicas take this path: their statistics must be
    // exchanged, which candle-nn's BatchNorm does not do.
    let fused = train
        && (kernel || sync.is_some())
        && x.rank() == 2
        && (x.dim(0)? > 1 || sync.is_some())
        && bn.weight_and_bias().is_some();
    if fused {
        return bn_relu_stats(bn, x, 0, kernel);
    }
    if train && frozen() {
        return Ok(batch_norm_frozen(bn, x)?.relu()?);
    }
    Ok(bn.forward_t(x, train)?.relu()?)
}

/// The fused path of [`bn_relu_on`] over the rows `x` and `zeros` further zero rows (which enter
/// the statistics only).
fn bn_relu_stats(bn: &BatchNorm, x: &Tensor, zeros: usize, kernel: bool) -> Result<Tensor> {
    let sync = SYNC.with(|c| c.borrow().clone());
    let Some((gamma, beta)) = bn.weight_and_bias() else {
        return Err(crate::error::FusionError::Config("fused BatchNorm without weight and bias".into()));
    };
    let x = x.contiguous()?;
    let c = x.dim(1)?;
    let local = if kernel { with_cpu::<f32, _>(&x, OP, |v| Ok(sums(v, c)))? } else { device_sums(&x)? };
    let local = local.with_zeros(zeros);
    let layer = bn.running_mean().id();
    let (sums, sync) = match sync {
        None => (local, None),
        Some((group, rank)) => {
            let all = group.exchange(rank, (layer, false), local.flatten())?;
            (Sums::combine(&all, c)?, Some((group, rank)))
        }
    };
    let n = sums.n;
    let (mean, var) = sums.moments();
    // Running statistics as candle-nn updates them: biased mean, unbiased variance.
    let m = bn.momentum();
    let dev = x.device();
    if !frozen() && n > 0.0 {
        let unbias = if n > 1.0 { n / (n - 1.0) } else { 1.0 };
        let mean_t = Tensor::from_slice(&mean, c, dev)?;
        let var_t = Tensor::from_slice(&var, c, dev)?;
        let running_mean = ((bn.running_mean() * (1.0 - m))? + (&mean_t * m)?)?;
        let running_var = ((bn.running_var() * (1.0 - m))? + (&var_t * (m * unbias))?)?;
        Var::from_tensor(bn.running_mean())?.set(&running_mean)?;
        Var::from_tensor(bn.running_var())?.set(&running_var)?;
    }
    let inv: Vec<f32> = var.iter().map(|v| 1.0 / (v + bn.eps() as f32).sqrt()).collect();
    let sync = sync.map(|(group, rank)| Synced { group, rank, layer });
    let op = BnRelu { mean, inv, n, sync };
    if kernel {
        Ok(x.apply_op3(&gamma.contiguous()?, &beta.contiguous()?, op)?)
    } else {
        bn_relu_composite(&x, gamma, beta, op)
    }
}

/// [`sums`] of rows `(N, C)` on their device, in f64 as on the host (in f32 a channel at an
/// offset of 1e3 lost a digit of its variance): the statistics a replica off the CPU hands to
/// the exchange.
fn device_sums(x: &Tensor) -> candle_core::Result<Sums> {
    let (n, _) = x.dims2()?;
    let x = x.to_dtype(DType::F64)?;
    let sum = x.sum(0)?;
    let mean = (&sum / n.max(1) as f64)?;
    let m2 = x.broadcast_sub(&mean)?.sqr()?.sum(0)?;
    Ok(Sums { n: n as f64, sum: sum.to_vec1::<f64>()?, m2: m2.to_vec1::<f64>()? })
}

/// [`BnRelu`]'s function from candle's tensor operations, for devices without its kernel (the
/// synchronised replicas of a step on a GPU): x̂ = (x − μ)·inv with the batch's μ and inv as
/// constants, through [`Centre`] (identity forward; its backward subtracts the whole batch's
/// means of dx̂ and dx̂·x̂, exchanged between replicas, which is the path through μ and σ), then
/// `relu(γ·x̂ + β)`. The same values and gradients as [`BnRelu`], rounded differently.
fn bn_relu_composite(x: &Tensor, gamma: &Tensor, beta: &Tensor, op: BnRelu) -> Result<Tensor> {
    let dev = x.device();
    let c = op.mean.len();
    let mean = Tensor::from_slice(&op.mean, (1, c), dev)?;
    let inv = Tensor::from_slice(&op.inv, (1, c), dev)?;
    let xhat = x.broadcast_sub(&mean)?.broadcast_mul(&inv)?.contiguous()?;
    let xhat = xhat.apply_op1(Centre { n: op.n, sync: op.sync })?;
    Ok(xhat.broadcast_mul(&gamma.reshape((1, c))?)?.broadcast_add(&beta.reshape((1, c))?)?.relu()?)
}

/// The identity on x̂ whose backward pass is BatchNorm's through its statistics:
/// dx̂ − mean(dx̂) − x̂ · mean(dx̂ · x̂), the means over all `n` rows of the batch (this replica's
/// sums exchanged with the other replicas' when synchronised). Any device: the forward pass is a
/// copy, the backward pass tensor operations.
#[derive(Debug, Clone)]
struct Centre {
    n: f64,
    sync: Option<Synced>,
}

const CENTRE: &str = "hilo-bn-centre";

impl candle_core::CustomOp1 for Centre {
    fn name(&self) -> &'static str {
        CENTRE
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        Ok((CpuStorage::F32(f32_slice(s, l, CENTRE)?.to_vec()), l.shape().clone()))
    }

    #[cfg(feature = "cuda")]
    fn cuda_fwd(
        &self,
        s: &candle_core::CudaStorage,
        l: &Layout,
    ) -> candle_core::Result<(candle_core::CudaStorage, Shape)> {
        use candle_core::backend::BackendStorage;
        match l.contiguous_offsets() {
            Some((0, end)) if end == l.shape().elem_count() => Ok((s.try_clone(l)?, l.shape().clone())),
            _ => candle_core::bail!("{CENTRE}: a contiguous input from offset 0 expected"),
        }
    }

    fn bwd(&self, xhat: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let c = xhat.dim(1)?;
        let dev = xhat.device();
        let sums = |t: Tensor| -> candle_core::Result<Vec<f64>> { Ok(host(&t)?.into_iter().map(f64::from).collect()) };
        let mut local = sums(grad.sum(0)?)?;
        local.extend(sums((grad * xhat)?.sum(0)?)?);
        let all = match &self.sync {
            None => local,
            Some(s) => s.gradient_sums(local, c)?,
        };
        let n = self.n.max(1.0);
        let mean_of = |k: usize| -> Vec<f32> { all[k * c..(k + 1) * c].iter().map(|v| (v / n) as f32).collect() };
        let (mg, mgx) = (Tensor::from_vec(mean_of(0), (1, c), dev)?, Tensor::from_vec(mean_of(1), (1, c), dev)?);
        Ok(Some(grad.broadcast_sub(&mg)?.sub(&xhat.broadcast_mul(&mgx)?)?))
    }
}

/// Rows' count, per-channel sums and centred sums of squares (f64): what replicas exchange.
#[derive(Debug, Clone, PartialEq)]
struct Sums {
    n: f64,
    sum: Vec<f64>,
    m2: Vec<f64>,
}

impl Sums {
    fn flatten(&self) -> Vec<f64> {
        let mut v = Vec::with_capacity(1 + 2 * self.sum.len());
        v.push(self.n);
        v.extend_from_slice(&self.sum);
        v.extend_from_slice(&self.m2);
        v
    }

    /// The replicas' sums (each [`Self::flatten`]ed) merged in replica order with Chan's
    /// pairwise update: `M2 = M2_a + M2_b + δ² n_a n_b / n`, δ the difference of the means.
    fn combine(all: &[Vec<f64>], c: usize) -> candle_core::Result<Sums> {
        let mut acc = Sums { n: 0.0, sum: vec![0.0; c], m2: vec![0.0; c] };
        for v in all {
            if v.len() != 1 + 2 * c {
                return Err(candle_core::Error::Msg(format!(
                    "synchronised BatchNorm: a replica sent {} numbers for {c} channels",
                    v.len()
                )));
            }
            let (nb, sb, qb) = (v[0], &v[1..1 + c], &v[1 + c..]);
            if nb == 0.0 {
                continue;
            }
            let na = acc.n;
            let n = na + nb;
            for k in 0..c {
                if na > 0.0 {
                    let d = sb[k] / nb - acc.sum[k] / na;
                    acc.m2[k] += qb[k] + d * d * na * nb / n;
                } else {
                    acc.m2[k] = qb[k];
                }
                acc.sum[k] += sb[k];
            }
            acc.n = n;
        }
        Ok(acc)
    }

    /// These sums and `zeros` rows of zeros (Chan's update with a block of mean 0 and no spread).
    fn with_zeros(mut self, zeros: usize) -> Sums {
        if zeros == 0 {
            return self;
        }
        let (na, nb) = (self.n, zeros as f64);
        let n = na + nb;
        if na > 0.0 {
            for (q, s) in self.m2.iter_mut().zip(&self.sum) {
                let d = s / na;
                *q += d * d * na * nb / n;
            }
        }
        self.n = n;
        self
    }

    /// Mean and biased variance (zeros without rows).
    fn moments(&self) -> (Vec<f32>, Vec<f32>) {
        let n = self.n.max(1.0);
        (self.sum.iter().map(|s| (s / n) as f32).collect(), self.m2.iter().map(|q| (q / n) as f32).collect())
    }
}

/// Per-channel sums and centred sums of squares of rows `(N, C)`, accumulated in f64.
fn sums(x: &[f32], c: usize) -> Sums {
    let rows = x.len() / c.max(1);
    let mut sum = vec![0f64; c];
    for row in x.chunks_exact(c) {
        for (s, &v) in sum.iter_mut().zip(row) {
            *s += v as f64;
        }
    }
    let mean: Vec<f64> = sum.iter().map(|s| s / rows.max(1) as f64).collect();
    let mut m2 = vec![0f64; c];
    for row in x.chunks_exact(c) {
        for ((s, &v), m) in m2.iter_mut().zip(row).zip(&mean) {
            let d = v as f64 - m;
            *s += d * d;
        }
    }
    Sums { n: rows as f64, sum, m2 }
}

/// The fused node: `y = max(0, γ · (x − μ) · inv + β)` with the batch's μ and inv = 1/√(σ² + ε).
#[derive(Debug, Clone)]
struct BnRelu {
    mean: Vec<f32>,
    inv: Vec<f32>,
    /// Rows the statistics are over (all replicas' when synchronised).
    n: f64,
    sync: Option<Synced>,
}

/// The exchange a synchronised node's backward pass takes part in.
#[derive(Debug, Clone)]
struct Synced {
    group: Arc<BatchNormSync>,
    rank: usize,
    layer: TensorId,
}

impl Synced {
    /// This replica's per-channel gradient sums (`Σ dz` then `Σ dz · x̂`, 2·`c` numbers) left at the
    /// backward exchange, and all replicas' summed in replica order.
    fn gradient_sums(&self, local: Vec<f64>, c: usize) -> candle_core::Result<Vec<f64>> {
        let all = self.group.exchange(self.rank, (self.layer, true), local)?;
        let mut acc = vec![0f64; 2 * c];
        for v in all.iter() {
            if v.len() != 2 * c {
                candle_core::bail!("synchronised BatchNorm: a replica sent {} gradient sums for {c} channels", v.len());
            }
            acc.iter_mut().zip(v).for_each(|(a, b)| *a += b);
        }
        Ok(acc)
    }
}

const ROWS: usize = 512;
const OP: &str = "hilo-bn-relu";

fn host(t: &Tensor) -> candle_core::Result<Vec<f32>> {
    t.flatten_all()?.to_vec1::<f32>()
}

/// One row's channels of [`BnRelu::input_grad`]'s first pass: x̂ = (x − μ)·inv, dz = dy where
/// γ·x̂ + β ≥ 0 and +0.0 elsewhere (by a bit mask rather than a branch: the same values, and a
/// loop the compiler vectorises), dβ += dz and dγ += dz·x̂ in f64.
#[inline(always)]
fn gate_sums(
    dz: &mut [f32],
    (x, g): (&[f32], &[f32]),
    (mean, inv, gamma, beta): (&[f32], &[f32], &[f32], &[f32]),
    (db, dg): (&mut [f64], &mut [f64]),
) {
    for j in 0..dz.len() {
        let h = (x[j] - mean[j]) * inv[j];
        let on = 0u32.wrapping_sub((gamma[j] * h + beta[j] >= 0.0) as u32);
        let d = f32::from_bits(g[j].to_bits() & on);
        dz[j] = d;
        db[j] += d as f64;
        dg[j] += (d * h) as f64;
    }
}

impl BnRelu {
    /// dx, dγ and dβ from x and dy (`(N, C)` row-major each). dz = dy where the pre-activation
    /// z = γ·x̂ + β is ≥ 0 (candle's relu gradient), else 0; dβ = Σ dz, dγ = Σ dz·x̂ (this
    /// replica's sums, its parameter gradients), dx = γ·inv/N · (N·dz − dβ − x̂·dγ) with the whole
    /// batch's sums when synchronised. The first pass is branch-free (a zero where the unit is
    /// off, added to the f64 sums as the branch left them) so that it runs vectorised.
    fn input_grad(
        &self,
        xv: &[f32],
        gv: &[f32],
        gamma_v: &[f32],
        beta_v: &[f32],
        c: usize,
    ) -> candle_core::Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
        let n = xv.len() / c.max(1);
        // Every slice the inner loops index has length c, which lets them run without bounds checks.
        let (mean, inv, gamma_v, beta_v) = (&self.mean[..c], &self.inv[..c], &gamma_v[..c], &beta_v[..c]);
        let mut dz = vec![0f32; n * c];
        let (mut dbeta, mut dgamma) = (vec![0f64; c], vec![0f64; c]);
        let (dbeta_c, dgamma_c) = (&mut dbeta[..c], &mut dgamma[..c]);
        // Channels in groups of LANES (slices of a constant length, so that [`gate_sums`] is
        // unrolled and vectorised there), the rest as one shorter group; each channel's sums in
        // row order.
        const LANES: usize = 8;
        let grouped = c / LANES * LANES;
        let groups = (0..grouped).step_by(LANES).map(|k0| k0..k0 + LANES).chain(std::iter::once(grouped..c));
        let groups: Vec<std::ops::Range<usize>> = groups.filter(|r| !r.is_empty()).collect();
        for ((dzr, xr), gr) in dz.chunks_exact_mut(c).zip(xv.chunks_exact(c)).zip(gv.chunks_exact(c)) {
            for r in &groups {
                let r = r.clone();
                gate_sums(
                    &mut dzr[r.clone()],
                    (&xr[r.clone()], &gr[r.clone()]),
                    (&mean[r.clone()], &inv[r.clone()], &gamma_v[r.clone()], &beta_v[r.clone()]),
                    (&mut dbeta_c[r.clone()], &mut dgamma_c[r]),
                );
            }
        }
        let (db, dg): (Vec<f32>, Vec<f32>) =
            (dbeta.iter().map(|&v| v as f32).collect(), dgamma.iter().map(|&v| v as f32).collect());
        let (db_all, dg_all) = match &self.sync {
            None => (db.clone(), dg.clone()),
            Some(s) => {
                let all = s.gradient_sums([dbeta, dgamma].concat(), c)?;
                let (b, g) = all.split_at(c);
                (b.iter().map(|&v| v as f32).collect(), g.iter().map(|&v| v as f32).collect())
            }
        };
        let nf = self.n as f32;
        let scale: Vec<f32> = gamma_v.iter().zip(inv).map(|(g, i)| g * i / nf.max(1.0)).collect();
        // dx in place of dz: each element reads its own dz once.
        let mut dx = dz;
        dx.par_chunks_mut(ROWS * c).zip(xv.par_chunks(ROWS * c)).for_each(|(dxc, xc)| {
            for (dxr, xr) in dxc.chunks_exact_mut(c).zip(xc.chunks_exact(c)) {
                let (dxr, xr) = (&mut dxr[..c], &xr[..c]);
                let (scale, db_all, dg_all) = (&scale[..c], &db_all[..c], &dg_all[..c]);
                for k in 0..c {
                    let h = (xr[k] - mean[k]) * inv[k];
                    dxr[k] = scale[k] * (nf * dxr[k] - db_all[k] - h * dg_all[k]);
                }
            }
        });
        Ok((dx, dg, db))
    }
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
        let (x, grad) = (x.contiguous()?, grad.contiguous()?);
        let (gamma_v, beta_v) = (host(gamma)?, host(beta)?);
        // x and dy are read in place, not copied.
        let (dx, dg, db) = crate::cpu::with_cpu::<f32, _>(&x, OP, |xv| {
            crate::cpu::with_cpu::<f32, _>(&grad, OP, |gv| self.input_grad(xv, gv, &gamma_v, &beta_v, c))
        })?;
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

    /// Synchronised replicas normalise as one batch: rows split in four unequal parts (one
    /// empty, one a single row) on four threads give the whole batch's outputs, the running
    /// statistics of one update over all rows, each replica's dx rows of the whole batch's dx,
    /// and dγ, dβ whose sum over the replicas is the batch's, on rows with a common offset of
    /// 1e3 and a part whose mean is far from the others' (what Chan's merge must get right).
    #[test]
    fn synchronised_replicas_normalise_as_one_batch() {
        synchronised_replicas_as_one_batch(true);
    }

    /// The same with the replicas on the composite path (tensor operations and [`Centre`]'s
    /// backward), what synchronised replicas on a GPU run, against the host kernel's whole batch.
    #[test]
    fn synchronised_composite_replicas_normalise_as_one_batch() {
        synchronised_replicas_as_one_batch(false);
    }

    fn synchronised_replicas_as_one_batch(kernel: bool) {
        let dev = Device::Cpu;
        let c = 6usize;
        let parts = [0usize, 1, 37, 300];
        let n: usize = parts.iter().sum();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        let mut normal = |len: usize| -> Vec<f32> {
            (0..len).map(|_| rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng)).collect()
        };
        let mut v = normal(n * c);
        for (i, x) in v.iter_mut().enumerate() {
            let (row, k) = (i / c, i % c);
            *x += if k == 2 { 1e3 } else { 0.0 } + if row >= 38 { 0.0 } else { 5.0 };
        }
        let x = Tensor::from_vec(v, (n, c), &dev).unwrap();
        let up = Tensor::from_vec(normal(n * c), (n, c), &dev).unwrap();
        let gs = Tensor::from_slice(&[1.5f32, -0.7, 0.3, 2.0, 1.0, -1.2], c, &dev).unwrap();
        let bs = Tensor::from_slice(&[0.1f32, 0.2, -0.3, 0.0, 0.5, -0.1], c, &dev).unwrap();
        let set = |bn: &BatchNorm| {
            let (g, b) = bn.weight_and_bias().unwrap();
            Var::from_tensor(g).unwrap().set(&gs).unwrap();
            Var::from_tensor(b).unwrap().set(&bs).unwrap();
        };

        // The whole batch in one node.
        let vm = VarMap::new();
        let whole = bn(&vm, c);
        set(&whole);
        let xv = Var::from_tensor(&x).unwrap();
        let y = bn_relu(&whole, xv.as_tensor(), true).unwrap();
        let g = (&y * &up).unwrap().sum_all().unwrap().backward().unwrap();
        let (gamma, beta) = whole.weight_and_bias().unwrap();
        let (dx, dgamma, dbeta) =
            (g.get(xv.as_tensor()).unwrap().clone(), g.get(gamma).unwrap().clone(), g.get(beta).unwrap().clone());

        // The replicas, one thread each, on one set of variables.
        let vm = VarMap::new();
        let shared = bn(&vm, c);
        set(&shared);
        let sync = BatchNormSync::new(parts.len());
        let starts: Vec<usize> = parts.iter().scan(0, |s, p| Some(std::mem::replace(s, *s + p))).collect();
        let results: Vec<(Tensor, Tensor, Tensor, Tensor)> = std::thread::scope(|scope| {
            let handles: Vec<_> = parts
                .iter()
                .zip(&starts)
                .enumerate()
                .map(|(r, (&len, &start))| {
                    let (x, up, shared, sync) = (&x, &up, &shared, &sync);
                    scope.spawn(move || {
                        with_synced_batch_norm(sync, r, || {
                            let pass = || {
                                let xr = Var::from_tensor(&x.narrow(0, start, len).unwrap()).unwrap();
                                let y = bn_relu_on(shared, xr.as_tensor(), true, kernel).unwrap();
                                let loss = (&y * &up.narrow(0, start, len).unwrap()).unwrap().sum_all().unwrap();
                                let g = loss.backward().unwrap();
                                let (gamma, beta) = shared.weight_and_bias().unwrap();
                                // candle's backward pass leaves out the parameters of an empty
                                // replica's composite (their gradients are zero).
                                let param = |p: &Tensor| {
                                    let zero = || Tensor::zeros(c, DType::F32, &Device::Cpu).unwrap();
                                    g.get(p).cloned().or_else(|| (len == 0 && !kernel).then(zero)).unwrap()
                                };
                                (y, g.get(xr.as_tensor()).unwrap().clone(), param(gamma), param(beta))
                            };
                            if r == 0 { pass() } else { with_running_stats_frozen(pass) }
                        })
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert!(!synced(), "the scope restores the thread");
        let cat = |f: fn(&(Tensor, Tensor, Tensor, Tensor)) -> &Tensor| {
            Tensor::cat(&results.iter().map(f).collect::<Vec<_>>(), 0).unwrap()
        };
        // The reference's kernel computes x·a + b with a = γ·inv, b = β − μ·a: at the channel
        // offset by 1e3 that rounds at about 1e3 · |a| · 6e-8 = 2e-5, which the composite's x − μ
        // does not; so its outputs agree to 1e-4 rather than 1e-5.
        close(&cat(|r| &r.0), &y, if kernel { 1e-5 } else { 1e-4 }, "output");
        close(&cat(|r| &r.1), &dx, 1e-4, "dx");
        let sum = |f: fn(&(Tensor, Tensor, Tensor, Tensor)) -> &Tensor| {
            results.iter().map(f).fold(Tensor::zeros(c, DType::F32, &dev).unwrap(), |a, t| (a + t).unwrap())
        };
        close(&sum(|r| &r.2), &dgamma, 1e-4, "dgamma");
        close(&sum(|r| &r.3), &dbeta, 1e-4, "dbeta");
        close(shared.running_mean(), whole.running_mean(), 1e-6, "running mean");
        close(shared.running_var(), whole.running_var(), 1e-5, "running var");
    }

    /// Rows followed by zero rows the encoder leaves out ([`bn_relu_padded`]) normalise as the
    /// padded rows do: outputs, running statistics and the gradients of x, γ and β equal those
    /// of [`bn_relu`] over the rows with the zeros appended (their upstream gradient zero, as a
    /// masked padding slot's is), on the host kernel and on the composite path; and two
    /// synchronised replicas with different padding normalise as the padded batch.
    #[test]
    fn padded_rows_enter_the_statistics_alone() {
        let dev = Device::Cpu;
        let (n, c, zeros) = (203usize, 5usize, 611usize);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut normal = |len: usize| -> Vec<f32> {
            (0..len).map(|_| rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng)).collect()
        };
        let offset = Tensor::from_slice(&[0f32, 4.0, -3.0, 50.0, 0.5], (1, c), &dev).unwrap();
        let x = Tensor::from_vec(normal(n * c), (n, c), &dev).unwrap().broadcast_add(&offset).unwrap();
        let up = Tensor::from_vec(normal(n * c), (n, c), &dev).unwrap();
        let gs = Tensor::from_slice(&[1.5f32, -0.7, 0.3, 2.0, 1.0], c, &dev).unwrap();
        let bs = Tensor::from_slice(&[0.1f32, 0.2, -0.3, 0.4, -0.1], c, &dev).unwrap();
        let set = |bn: &BatchNorm| {
            let (g, b) = bn.weight_and_bias().unwrap();
            Var::from_tensor(g).unwrap().set(&gs).unwrap();
            Var::from_tensor(b).unwrap().set(&bs).unwrap();
        };
        let grads = |bn: &BatchNorm, xv: &Var, y: &Tensor, up: &Tensor| {
            let g = (y * up).unwrap().sum_all().unwrap().backward().unwrap();
            let (gamma, beta) = bn.weight_and_bias().unwrap();
            [g.get(xv.as_tensor()).unwrap().clone(), g.get(gamma).unwrap().clone(), g.get(beta).unwrap().clone()]
        };
        // The reference: the zero rows appended, their outputs discarded.
        let vm = VarMap::new();
        let whole = bn(&vm, c);
        set(&whole);
        let xw = Var::from_tensor(&x).unwrap();
        let padded = Tensor::cat(&[xw.as_tensor(), &Tensor::zeros((zeros, c), DType::F32, &dev).unwrap()], 0).unwrap();
        let yw = bn_relu(&whole, &padded, true).unwrap().narrow(0, 0, n).unwrap();
        let want = grads(&whole, &xw, &yw, &up);
        for kernel in [true, false] {
            let vm = VarMap::new();
            let b = bn(&vm, c);
            set(&b);
            let xv = Var::from_tensor(&x).unwrap();
            let y = bn_relu_padded_on(&b, xv.as_tensor(), zeros, true, kernel).unwrap();
            assert_eq!(y.dims(), &[n, c]);
            close(&y, &yw, 1e-5, "output");
            close(b.running_mean(), whole.running_mean(), 1e-6, "running mean");
            close(b.running_var(), whole.running_var(), 1e-5, "running var");
            for (got, (want, what)) in grads(&b, &xv, &y, &up).iter().zip(want.iter().zip(["dx", "dgamma", "dbeta"])) {
                close(got, want, 1e-4, what);
            }
        }
        // Two synchronised replicas: rows 0..80 with 100 zero rows, rows 80.. with the rest.
        let (split, pad0) = (80usize, 100usize);
        let vm = VarMap::new();
        let shared = bn(&vm, c);
        set(&shared);
        let sync = BatchNormSync::new(2);
        let parts = [(0, split, pad0), (split, n - split, zeros - pad0)];
        let results: Vec<(Tensor, [Tensor; 3])> = std::thread::scope(|scope| {
            let handles: Vec<_> = parts
                .iter()
                .enumerate()
                .map(|(r, &(start, len, pad))| {
                    let (x, up, shared, sync, grads) = (&x, &up, &shared, &sync, &grads);
                    scope.spawn(move || {
                        with_synced_batch_norm(sync, r, || {
                            let pass = || {
                                let xr = Var::from_tensor(&x.narrow(0, start, len).unwrap()).unwrap();
                                let y = bn_relu_padded(shared, xr.as_tensor(), pad, true).unwrap();
                                let g = grads(shared, &xr, &y, &up.narrow(0, start, len).unwrap());
                                (y, g)
                            };
                            if r == 0 { pass() } else { with_running_stats_frozen(pass) }
                        })
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let y = Tensor::cat(&[&results[0].0, &results[1].0], 0).unwrap();
        close(&y, &yw, 1e-5, "synchronised output");
        close(&Tensor::cat(&[&results[0].1[0], &results[1].1[0]], 0).unwrap(), &want[0], 1e-4, "synchronised dx");
        for (k, want) in want.iter().enumerate().skip(1) {
            close(&(&results[0].1[k] + &results[1].1[k]).unwrap(), want, 1e-4, "synchronised parameters");
        }
        close(shared.running_mean(), whole.running_mean(), 1e-6, "synchronised running mean");
        close(shared.running_var(), whole.running_var(), 1e-5, "synchronised running var");
    }

    /// Replicas that reach different layers, or one that ends its pass while another waits,
    /// fail with an error naming the cause instead of waiting for ever.
    #[test]
    fn diverging_replicas_are_an_error_not_a_hang() {
        let dev = Device::Cpu;
        let x = Tensor::from_vec((0..40).map(|v| v as f32).collect::<Vec<_>>(), (10, 4), &dev).unwrap();
        let (vm_a, vm_b) = (VarMap::new(), VarMap::new());
        let (bn_a, bn_b) = (bn(&vm_a, 4), bn(&vm_b, 4));
        // Different layers.
        let sync = BatchNormSync::new(2);
        let errors: Vec<String> = std::thread::scope(|scope| {
            let h: Vec<_> = [&bn_a, &bn_b]
                .into_iter()
                .enumerate()
                .map(|(r, layer)| {
                    let (x, sync) = (&x, &sync);
                    scope.spawn(move || {
                        with_synced_batch_norm(sync, r, || bn_relu(layer, x, true).unwrap_err().to_string())
                    })
                })
                .collect();
            h.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for e in &errors {
            assert!(e.contains("different paths") && e.contains("BatchNorm layer"), "{e}");
        }
        // One replica ends its pass without reaching the layer the other waits at.
        let sync = BatchNormSync::new(2);
        let waited = std::thread::scope(|scope| {
            let (x, sync, bn_a) = (&x, &sync, &bn_a);
            let waiting = scope.spawn(move || with_synced_batch_norm(sync, 0, || bn_relu(bn_a, x, true).map(|_| ())));
            scope.spawn(move || with_synced_batch_norm(sync, 1, || ()));
            waiting.join().unwrap()
        });
        let e = waited.unwrap_err().to_string();
        assert!(e.contains("ended its pass"), "{e}");
    }
}
