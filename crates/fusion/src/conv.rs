//! 2-D convolution for the CPU as im2col and one matrix product per batch, with the patch
//! extraction ([`Im2Col`]) and its adjoint ([`Col2Im`]) as candle custom ops. Candle's own CPU
//! convolution gathers patches one scalar at a time and computes the input gradient with a
//! direct transposed convolution; here rows of patches are copied as slices and both gradients
//! are matrix products (candle's autograd of `matmul`), which keep the cores busy where the
//! scalar gathers do not (the oracle test below compares values and both gradients with
//! candle's `conv2d`; docs/measurements.md has the speed). On other devices [`Conv`] calls candle's `conv2d`, so CUDA needs no change.

use crate::cpu::f32_slice;
pub use crate::cpu::{FORWARD_FLOPS, count_matmul};
use crate::error::{FusionError, Result};
use crate::layout::At;
use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};

use candle_nn::VarBuilder;
use rayon::prelude::*;

/// Geometry of a square-kernel convolution over (C, H, W) planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Geometry {
    pub channels: usize,
    pub h: usize,
    pub w: usize,
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
}

impl Geometry {
    /// Output height and width (candle's and PyTorch's formula).
    pub fn out(&self) -> (usize, usize) {
        ((self.h + 2 * self.pad - self.k) / self.stride + 1, (self.w + 2 * self.pad - self.k) / self.stride + 1)
    }

    /// Output columns [x0, x1) whose input column x·s + kw − p lies inside the plane.
    fn columns(&self, kw: usize, wo: usize) -> (usize, usize) {
        let (s, p, kw) = (self.stride as isize, self.pad as isize, kw as isize);
        let x0 = (p - kw + s - 1).div_euclid(s).clamp(0, wo as isize) as usize;
        let x1 = ((self.w as isize - 1 + p - kw).div_euclid(s) + 1).clamp(0, wo as isize) as usize;
        (x0, x1.max(x0))
    }

    /// Input row of output row `y` for kernel row `kh`, if inside the plane.
    fn row(&self, y: usize, kh: usize) -> Option<usize> {
        let iy = (y * self.stride + kh) as isize - self.pad as isize;
        (iy >= 0 && iy < self.h as isize).then_some(iy as usize)
    }

    /// Every run of one (channel) plane that the column matrix shares with its input: for tap
    /// (kh, kw) and output row y, output columns [x0, x1) read input row iy from column
    /// x0·s + kw − p on. Calls `f(tap, y, iy, x0, x1, kw)`; [`Im2Col`] copies these runs and
    /// [`Col2Im`] adds them back, so both walk the same index map.
    fn runs(&self, mut f: impl FnMut(usize, usize, usize, usize, usize, usize)) {
        let (ho, wo) = self.out();
        for kh in 0..self.k {
            for kw in 0..self.k {
                let (x0, x1) = self.columns(kw, wo);
                for y in 0..ho {
                    if let Some(iy) = self.row(y, kh) {
                        f(kh * self.k + kw, y, iy, x0, x1, kw);
                    }
                }
            }
        }
    }
}

/// (B, C, H, W) → (B, C·k·k, Ho·Wo): row (c, kh, kw) holds input (c, y·s + kh − p, x·s + kw − p).
#[derive(Debug, Clone, Copy)]
pub struct Im2Col(pub Geometry);

/// The adjoint of [`Im2Col`]: (B, C·k·k, Ho·Wo) → (B, C, H, W), overlapping patches summed.
#[derive(Debug, Clone, Copy)]
pub struct Col2Im(pub Geometry);

impl CustomOp1 for Im2Col {
    fn name(&self) -> &'static str {
        "hilo-im2col"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = self.0;
        let x = f32_slice(s, l, "im2col")?;
        let b = l.dims().first().copied().unwrap_or(0);
        let (ho, wo) = g.out();
        let (kk, plane) = (g.k * g.k, ho * wo);
        let mut out = vec![0f32; b * g.channels * kk * plane];
        // One (batch, channel) plane per task: its k·k rows of the column matrix.
        out.par_chunks_mut(kk * plane).enumerate().for_each(|(bc, rows)| {
            let src = &x[bc * g.h * g.w..(bc + 1) * g.h * g.w];
            g.runs(|tap, y, iy, x0, x1, kw| {
                let (srow, drow) =
                    (&src[iy * g.w..(iy + 1) * g.w], &mut rows[tap * plane + y * wo..tap * plane + (y + 1) * wo]);
                if g.stride == 1 {
                    let ix0 = x0 + kw - g.pad;
                    drow[x0..x1].copy_from_slice(&srow[ix0..ix0 + (x1 - x0)]);
                } else {
                    for (xo, d) in drow.iter_mut().enumerate().take(x1).skip(x0) {
                        *d = srow[xo * g.stride + kw - g.pad];
                    }
                }
            });
        });
        Ok((CpuStorage::F32(out), Shape::from((b, g.channels * kk, plane))))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&Col2Im(self.0))?))
    }
}

impl CustomOp1 for Col2Im {
    fn name(&self) -> &'static str {
        "hilo-col2im"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = self.0;
        let cols = f32_slice(s, l, "col2im")?;
        let b = l.dims().first().copied().unwrap_or(0);
        let (ho, wo) = g.out();
        let (kk, plane) = (g.k * g.k, ho * wo);
        let mut out = vec![0f32; b * g.channels * g.h * g.w];
        // Each task owns one (batch, channel) input plane, so the sums need no synchronisation.
        out.par_chunks_mut(g.h * g.w).enumerate().for_each(|(bc, dst)| {
            let rows = &cols[bc * kk * plane..(bc + 1) * kk * plane];
            g.runs(|tap, y, iy, x0, x1, kw| {
                let (drow, srow) =
                    (&mut dst[iy * g.w..(iy + 1) * g.w], &rows[tap * plane + y * wo..tap * plane + (y + 1) * wo]);
                if g.stride == 1 {
                    let ix0 = x0 + kw - g.pad;
                    for (d, s) in drow[ix0..ix0 + (x1 - x0)].iter_mut().zip(&srow[x0..x1]) {
                        *d += s;
                    }
                } else {
                    for (xo, s) in srow.iter().enumerate().take(x1).skip(x0) {
                        drow[xo * g.stride + kw - g.pad] += s;
                    }
                }
            });
        });
        Ok((CpuStorage::F32(out), Shape::from((b, g.channels, g.h, g.w))))
    }
}

/// `x` (B, C, H, W) convolved with `w` (Co, C, k, k), no bias: im2col and a matrix product on
/// the CPU, candle's `conv2d` elsewhere.
pub fn conv2d(x: &Tensor, w: &Tensor, stride: usize, pad: usize) -> Result<Tensor> {
    let (b, c, h, wd) = x.dims4()?;
    let (co, _, k, _) = w.dims4()?;
    let g = Geometry { channels: c, h, w: wd, k, stride, pad };
    let (ho, wo) = g.out();
    count_matmul(b * ho * wo, c * k * k, co);
    if !x.device().is_cpu() {
        return Ok(x.conv2d(w, pad, stride, 1, 1)?);
    }
    let cols = if k == 1 && stride == 1 && pad == 0 {
        x.reshape((b, c, h * wd))?
    } else {
        x.contiguous()?.apply_op1(Im2Col(g))?
    };
    Ok(w.reshape((co, c * k * k))?.broadcast_matmul(&cols)?.reshape((b, co, ho, wo))?)
}

/// A convolution layer with the weight (and optional bias) under candle_nn's names, so
/// checkpoints are the same as with `candle_nn::Conv2d`.
#[derive(Debug, Clone)]
pub struct Conv {
    weight: Tensor,
    bias: Option<Tensor>,
    stride: usize,
    pad: usize,
}

impl Conv {
    pub fn new(
        cin: usize,
        cout: usize,
        k: usize,
        stride: usize,
        pad: usize,
        bias: bool,
        vb: VarBuilder,
    ) -> Result<Self> {
        let bound = 1.0 / ((cin * k * k) as f64).sqrt();
        let weight =
            vb.get_with_hints((cout, cin, k, k), "weight", candle_nn::init::Init::Uniform { lo: -bound, up: bound })?;
        let bias = if bias {
            Some(vb.get_with_hints(cout, "bias", candle_nn::init::Init::Uniform { lo: -bound, up: bound })?)
        } else {
            None
        };
        Ok(Conv { weight, bias, stride, pad })
    }

    /// Dense `(B, C, H, W)` maps, or sparse `(N, C)` rows on a plane: a 1×1 convolution is a
    /// matrix product there, a 3×3 one (stride 1) gathers along the plane's rulebook.
    pub fn forward(&self, x: &Tensor, at: At) -> Result<Tensor> {
        match at {
            At::Dense => {
                let y = conv2d(x, &self.weight, self.stride, self.pad)?;
                Ok(match &self.bias {
                    Some(b) => y.broadcast_add(&b.reshape((1, b.dim(0)?, 1, 1))?)?,
                    None => y,
                })
            }
            At::Sparse(plane) => {
                let (co, ci, k, _) = self.weight.dims4()?;
                if k == 1 {
                    count_matmul(x.dim(0)?, ci, co);
                    self.add_bias(x.matmul(&self.weight.reshape((co, ci))?.t()?)?)
                } else if self.stride == 1 {
                    self.forward_rules(x, &plane.subm)
                } else {
                    Err(FusionError::Config("a strided sparse convolution needs its rulebook (forward_rules)".into()))
                }
            }
        }
    }

    /// Sparse rows `(N_in, C)` along a rulebook (`N_out · k²`): `(N_out, C_out)`.
    pub fn forward_rules(&self, x: &Tensor, rules: &crate::layout::Rules) -> Result<Tensor> {
        self.add_bias(crate::layout::gather_conv(x, &self.weight, rules)?)
    }

    /// The kernel `(C_out, C_in, k, k)`.
    pub(crate) fn weight(&self) -> &Tensor {
        &self.weight
    }

    pub(crate) fn stride(&self) -> usize {
        self.stride
    }

    /// The bias `(C_out,)`, where the convolution has one.
    pub(crate) fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    fn add_bias(&self, y: Tensor) -> Result<Tensor> {
        Ok(match &self.bias {
            Some(b) => y.broadcast_add(b)?,
            None => y,
        })
    }
}
