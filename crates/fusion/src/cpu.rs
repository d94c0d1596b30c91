//! CPU helpers shared by hilo's custom operations ([`crate::conv`], [`crate::layout`],
//! [`crate::bnrelu`]): borrowing a CPU tensor's values, and counting the forward FLOPs that
//! benchmarks report.

use candle_core::{CpuStorage, Layout, Tensor};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};

/// Multiply-add FLOPs (2 per multiply-add) of every convolution and pillar linear layer run in
/// this process's forward passes. Benchmarks read it to express a step's speed as GFLOP/s.
pub static FORWARD_FLOPS: AtomicU64 = AtomicU64::new(0);

/// hilo's fused layers: custom ops with a hand-written backward pass, one autograd node each,
/// where they can run (f32 on the CPU). Off, each takes its composite of candle's own
/// operations, the reference the fused op is tested against (`hilo bench train --variant
/// fused=off` times both; `fused=conv+bn_relu` keeps some on).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layer {
    /// The sparse and parent convolutions ([`crate::layout`]).
    Conv = 1,
    /// BatchNorm + ReLU over rows ([`crate::bnrelu`]).
    BnRelu = 2,
    /// The detector's focal and L1 losses.
    Loss = 4,
}

impl Layer {
    pub const ALL: [Layer; 3] = [Layer::Conv, Layer::BnRelu, Layer::Loss];

    /// The name `--variant fused=...` uses.
    pub fn name(self) -> &'static str {
        match self {
            Layer::Conv => "conv",
            Layer::BnRelu => "bn_relu",
            Layer::Loss => "loss",
        }
    }
}

/// A set of fused layers as `hilo train --fused` and `hilo bench train --variant fused=` name it:
/// `on` (all), `off` (none, every layer its composite), or layer names joined by `+`
/// (`conv+bn_relu`).
pub fn parse_layers(s: &str) -> Result<Vec<Layer>, String> {
    match s {
        "on" | "all" => Ok(Layer::ALL.to_vec()),
        "off" | "none" => Ok(Vec::new()),
        _ => {
            let mut layers = Vec::new();
            for name in s.split('+') {
                let layer = Layer::ALL.into_iter().find(|l| l.name() == name).ok_or_else(|| {
                    format!("unknown fused layer {name:?} in {s:?} (on, off, or any of conv+bn_relu+loss)")
                })?;
                if !layers.contains(&layer) {
                    layers.push(layer);
                }
            }
            Ok(layers)
        }
    }
}

/// A set of fused layers as a command line gives it (`hilo train --fused`), read by
/// [`parse_layers`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LayerSet(pub Vec<Layer>);

impl std::str::FromStr for LayerSet {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        parse_layers(s).map(LayerSet)
    }
}

/// The name of a set of fused layers, the inverse of [`parse_layers`]: `on`, `off`, or the
/// layers' names joined by `+` in [`Layer::ALL`]'s order.
pub fn layers_name(layers: &[Layer]) -> String {
    let on: Vec<Layer> = Layer::ALL.into_iter().filter(|l| layers.contains(l)).collect();
    match on.len() {
        0 => "off".into(),
        n if n == Layer::ALL.len() => "on".into(),
        _ => on.iter().map(|l| l.name()).collect::<Vec<_>>().join("+"),
    }
}

/// The fused layers that are on, one bit per [`Layer`]; all by default.
static FUSED: AtomicU8 = AtomicU8::new(7);

/// Whether the fused `layer` is on (see [`set_fused`]).
pub fn fused(layer: Layer) -> bool {
    FUSED.load(Ordering::Relaxed) & layer as u8 != 0
}

/// Turns on the fused `layers` and off the others, for the whole process: a benchmark's
/// before/after lever, and `hilo train --fused` (a training records the set in its run.json).
pub fn set_fused(layers: &[Layer]) {
    FUSED.store(layers.iter().fold(0, |m, l| m | *l as u8), Ordering::Relaxed);
}

/// Whether the fused `layer` runs on `x`: the layer on, `x` f32 on the CPU.
pub fn fused_on(layer: Layer, x: &Tensor) -> bool {
    fused(layer) && x.device().is_cpu() && x.dtype() == candle_core::DType::F32
}

/// The fused layers that are on.
pub fn fused_layers() -> Vec<Layer> {
    Layer::ALL.into_iter().filter(|l| fused(*l)).collect()
}

/// Whether [`count_matmul`] also logs each product's shape (for `hilo bench train`).
static RECORDING: AtomicBool = AtomicBool::new(false);
static SHAPES: Mutex<Vec<[usize; 3]>> = Mutex::new(Vec::new());

/// Counts the forward FLOPs of an `(m × k) · (k × n)` matrix product, and logs its shape while
/// [`record_matmul_shapes`] is on.
pub fn count_matmul(m: usize, k: usize, n: usize) {
    FORWARD_FLOPS.fetch_add(2 * (m * k * n) as u64, Ordering::Relaxed);
    if RECORDING.load(Ordering::Relaxed) {
        SHAPES.lock().unwrap_or_else(|e| e.into_inner()).push([m, k, n]);
    }
}

/// Starts (true) or stops logging the shapes `(m, k, n)` of the forward products that
/// [`count_matmul`] counts, process-wide like [`FORWARD_FLOPS`]: a benchmark replays them to
/// learn what candle's matrix product reaches at the sizes a step uses.
pub fn record_matmul_shapes(on: bool) {
    RECORDING.store(on, Ordering::Relaxed);
}

/// The shapes logged since the last call, in the order counted, and an empty log.
pub fn take_matmul_shapes() -> Vec<[usize; 3]> {
    std::mem::take(&mut *SHAPES.lock().unwrap_or_else(|e| e.into_inner()))
}

/// The f32 values of a contiguous CPU storage, as a custom op's `cpu_fwd` receives it.
pub fn f32_slice<'a>(s: &'a CpuStorage, l: &Layout, op: &str) -> candle_core::Result<&'a [f32]> {
    let CpuStorage::F32(data) = s else { candle_core::bail!("{op}: f32 tensors only") };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&data[a..b]),
        None => candle_core::bail!("{op}: contiguous input only"),
    }
}

/// [`f32_slice`] for the storage an in-place op writes.
pub fn f32_slice_mut<'a>(s: &'a mut CpuStorage, l: &Layout, op: &str) -> candle_core::Result<&'a mut [f32]> {
    let CpuStorage::F32(data) = s else { candle_core::bail!("{op}: f32 tensors only") };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&mut data[a..b]),
        None => candle_core::bail!("{op}: contiguous input only"),
    }
}

/// `f` on the values of a contiguous CPU tensor, borrowed rather than copied.
pub(crate) fn with_cpu<T: candle_core::WithDType, R>(
    t: &Tensor,
    op: &str,
    f: impl FnOnce(&[T]) -> candle_core::Result<R>,
) -> candle_core::Result<R> {
    let (storage, layout) = t.storage_and_layout();
    match (&*storage, layout.contiguous_offsets()) {
        (candle_core::Storage::Cpu(s), Some((a, b))) => f(&s.as_slice::<T>()?[a..b]),
        _ => candle_core::bail!("{op}: a contiguous CPU tensor expected"),
    }
}
