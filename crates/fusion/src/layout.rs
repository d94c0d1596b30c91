//! Where a batch's bird's-eye-view features live: a dense map `(B, C, H, W)` over every cell of
//! the grid, or only the occupied cells, `(N, C)` (sparse).
//!
//! A roadside frame without its static background occupies a few hundred of the grid's 16,384
//! pillars; a dense backbone spends nearly all of its work on empty cells. The sparse layout
//! computes only at *sites*: at the pillar grid (level 0) the cells holding a point of either
//! modality; at level `l` (stride 2^l) the cells a 3×3 stride-2 convolution of level `l − 1`
//! reaches (so sites grow by one cell per level, as the receptive field does); at the head, the
//! sites of its level dilated by `head_dilation` cells, so that a box whose centre cell holds no
//! point (the far side of a bus) can still be found. Convolutions are gather–GEMM: a rulebook
//! lists, for each output site and each of the 3×3 taps, the input site it reads (or none, read
//! as zero); the features it names are gathered into an `(N_out, 9·C_in)` matrix, multiplied by
//! the kernel, and their gradient flows back through the gather as a scatter-add. On the CPU the
//! convolution is one autograd node ([`GatherConv`]: the gathered matrix is a buffer, not a
//! tensor of the graph, whose zeroed gradient candle's backward pass would otherwise allocate,
//! add into and scatter); on other devices it is candle's own `index_select` and `matmul`
//! ([`gather_conv_composite`], the reference the fused node is tested against), so the sparse
//! path runs unchanged on any device. There the gather's backward pass is itself a gather
//! ([`RowGather`]) through the inverted rulebook (each input row's readers, built on the host
//! with the rulebook: [`Rules`]), rather than candle's `index_add`, whose CUDA kernel runs one
//! thread per channel looping over every gathered row. Submanifold convolutions (stride 1) keep their
//! sites; BatchNorm normalises over the sites only, so empty cells stay exactly empty, unlike a
//! dense network where BatchNorm and its bias make every empty cell a value.
//!
//! Rulebooks are built on the host, on the batch thread, from the occupied cells ([`SparseHost`]),
//! and moved to the device once per batch ([`Layout::new`]).

use crate::cpu::{f32_slice, with_cpu};
use crate::error::Result;
use candle_core::{CpuStorage, CustomOp2, DType, Device, Tensor};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of the sparse layout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SparseConfig {
    /// Head sites: the occupied cells of the head's level, dilated by this many cells.
    pub head_dilation: usize,
}

impl Default for SparseConfig {
    fn default() -> Self {
        SparseConfig { head_dilation: 2 }
    }
}

/// "No input site": a gather reads zeros there, and the scatter of its gradient skips it.
pub const NONE: u32 = u32::MAX;

/// Sites and rulebooks of a batch, on the host.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseHost {
    pub batch: usize,
    /// Grid side at level 0 (the pillar grid).
    pub cells: usize,
    /// Per level l (stride 2^l): sites as flat cells `b · n_l² + row · n_l + col`, ascending.
    pub sites: Vec<Vec<u32>>,
    /// Per level: 3×3 stride-1 rulebook over the level's own sites (N_l × 9).
    pub subm: Vec<Vec<u32>>,
    /// Per level l ≥ 1: 3×3 stride-2 rulebook from level l − 1 (N_l × 9); empty at level 0.
    pub down: Vec<Vec<u32>>,
    /// The head's level, its sites (flat cells at that level) and their 3×3 rulebook.
    pub head_level: usize,
    pub head_sites: Vec<u32>,
    pub head_subm: Vec<u32>,
    /// Per level l: for l ≥ head level, each head site's parent at level l (or [`NONE`]);
    /// for l < head level, the 3×3 rulebook of a stride-2^(head − l) convolution (N_h × 9).
    pub head_from: Vec<Vec<u32>>,
    /// Per level l: the head's 3×3 rulebook read through the rows the neck holds for that
    /// level ([`parent_conv`]): entry `s · 9 + t` is `r · 9 + t` for the row `r` that head site
    /// `s` reads at tap `t` (its neighbour's parent at level l ≥ head level, or the neighbour
    /// itself below it, where the neck computes its rows at the head sites), or [`NONE`].
    pub head_taps: Vec<Vec<u32>>,
}

fn side(cells: usize, level: usize) -> usize {
    cells >> level
}

/// Index of each flat cell of a level in its site list, or NONE.
fn lookup(sites: &[u32], batch: usize, n: usize) -> Vec<u32> {
    let mut l = vec![NONE; batch * n * n];
    for (i, &s) in sites.iter().enumerate() {
        l[s as usize] = i as u32;
    }
    l
}

/// The 3×3 (padding 1) rulebook of a convolution of `stride` from sites on an `n_in` grid to
/// `out` sites on an `n_out` grid: entry (o, kh·3 + kw) is the input site at
/// (row·stride + kh − 1, col·stride + kw − 1), or NONE.
fn rulebook(look_in: &[u32], n_in: usize, out: &[u32], n_out: usize, stride: usize) -> Vec<u32> {
    let mut r = Vec::with_capacity(out.len() * 9);
    for &s in out {
        let s = s as usize;
        let (b, rc) = (s / (n_out * n_out), s % (n_out * n_out));
        let (row, col) = ((rc / n_out) as isize, (rc % n_out) as isize);
        for kh in 0..3isize {
            for kw in 0..3isize {
                let (ir, ic) = (row * stride as isize + kh - 1, col * stride as isize + kw - 1);
                r.push(if ir >= 0 && ic >= 0 && (ir as usize) < n_in && (ic as usize) < n_in {
                    look_in[b * n_in * n_in + ir as usize * n_in + ic as usize]
                } else {
                    NONE
                });
            }
        }
    }
    r
}

impl SparseHost {
    /// Sites and rulebooks for occupied level-0 cells (flat, any order, repeats allowed) of a
    /// batch, `levels` levels deep (the backbone's total stride is 2^(levels − 1)), a head at
    /// `head_level` with its sites dilated by `dilation`. An empty batch gets one site (the
    /// centre of frame 0, holding zeros) so that every tensor has a row.
    pub fn build(
        cells: usize,
        batch: usize,
        occupied: &[u32],
        levels: usize,
        head_level: usize,
        dilation: usize,
    ) -> Self {
        let mut s0: Vec<u32> = occupied.to_vec();
        s0.sort_unstable();
        s0.dedup();
        if s0.is_empty() {
            s0.push((cells / 2 * cells + cells / 2) as u32);
        }
        let levels = levels.max(head_level + 1);
        let mut sites = vec![s0];
        let mut looks = vec![lookup(&sites[0], batch, cells)];
        let mut down = vec![Vec::new()];
        for l in 1..levels {
            let (n_in, n) = (side(cells, l - 1), side(cells, l));
            // Output cells whose 3×3 stride-2 window holds an input site: rows r' with
            // 2r' − 1 ≤ r ≤ 2r' + 1.
            let mut out = Vec::new();
            for &s in &sites[l - 1] {
                let s = s as usize;
                let (b, rc) = (s / (n_in * n_in), s % (n_in * n_in));
                let (r, c) = (rc / n_in, rc % n_in);
                let span = |x: usize| -> Vec<usize> {
                    let mut v = vec![x / 2];
                    if x % 2 == 1 && x.div_ceil(2) < n {
                        v.push(x.div_ceil(2));
                    }
                    v
                };
                for rr in span(r) {
                    for cc in span(c) {
                        out.push((b * n * n + rr * n + cc) as u32);
                    }
                }
            }
            out.sort_unstable();
            out.dedup();
            down.push(rulebook(&looks[l - 1], n_in, &out, n, 2));
            looks.push(lookup(&out, batch, n));
            sites.push(out);
        }
        let subm = (0..levels).map(|l| rulebook(&looks[l], side(cells, l), &sites[l], side(cells, l), 1)).collect();
        // Head sites: the head level's sites dilated.
        let nh = side(cells, head_level);
        let d = dilation as isize;
        let mut head: Vec<u32> = Vec::with_capacity(sites[head_level].len() * (2 * dilation + 1).pow(2));
        for &s in &sites[head_level] {
            let s = s as usize;
            let (b, rc) = (s / (nh * nh), s % (nh * nh));
            let (r, c) = ((rc / nh) as isize, (rc % nh) as isize);
            for dr in -d..=d {
                for dc in -d..=d {
                    let (rr, cc) = (r + dr, c + dc);
                    if rr >= 0 && cc >= 0 && (rr as usize) < nh && (cc as usize) < nh {
                        head.push((b * nh * nh + rr as usize * nh + cc as usize) as u32);
                    }
                }
            }
        }
        head.sort_unstable();
        head.dedup();
        let head_look = lookup(&head, batch, nh);
        let head_subm = rulebook(&head_look, nh, &head, nh, 1);
        let head_from: Vec<Vec<u32>> = (0..levels)
            .map(|l| {
                let n = side(cells, l);
                if l >= head_level {
                    let f = 1usize << (l - head_level);
                    head.iter()
                        .map(|&s| {
                            let s = s as usize;
                            let (b, rc) = (s / (nh * nh), s % (nh * nh));
                            let (r, c) = (rc / nh / f, rc % nh / f);
                            looks[l][b * n * n + r * n + c]
                        })
                        .collect()
                } else {
                    rulebook(&looks[l], n, &head, nh, 1 << (head_level - l))
                }
            })
            .collect();
        let head_taps = (0..levels)
            .map(|l| {
                let taps = 9u32;
                head_subm
                    .iter()
                    .enumerate()
                    .map(|(k, &nb)| {
                        let row = if nb == NONE || l < head_level { nb } else { head_from[l][nb as usize] };
                        if row == NONE { NONE } else { row * taps + k as u32 % taps }
                    })
                    .collect()
            })
            .collect();
        SparseHost { batch, cells, sites, subm, down, head_level, head_sites: head, head_subm, head_from, head_taps }
    }

    /// Site index of every flat level-0 cell (NONE where not a site).
    pub fn level0_lookup(&self) -> Vec<u32> {
        lookup(&self.sites[0], self.batch, self.cells)
    }

    /// Batch index of each site of a level (or of the head, `None`).
    pub fn batch_of(&self, level: Option<usize>) -> Vec<u32> {
        let (sites, n) = match level {
            Some(l) => (&self.sites[l], side(self.cells, l)),
            None => (&self.head_sites, side(self.cells, self.head_level)),
        };
        sites.iter().map(|&s| (s as usize / (n * n)) as u32).collect()
    }
}

/// One level's (or the head's) tensors on the device.
#[derive(Debug, Clone)]
pub struct Plane {
    pub sites: usize,
    /// 3×3 stride-1 rulebook over the plane's sites, (N · 9).
    pub subm: Rules,
    /// Batch index per site (N,) and sites per batch element (B, 1), for per-frame means.
    pub batch_of: Tensor,
    pub counts: Tensor,
}

/// The sparse layout of a batch on the device.
#[derive(Debug, Clone)]
pub struct Sparse {
    pub batch: usize,
    pub levels: Vec<Plane>,
    /// `down[l]`: the stride-2 rulebook into level l (none at level 0).
    pub down: Vec<Option<Rules>>,
    pub head: Plane,
    /// Per level, [`SparseHost::head_from`]: a rulebook into the head sites for levels finer
    /// than the head, each head site's parent row (one tap) for the others.
    pub head_from: Vec<Rules>,
    /// Per level, [`SparseHost::head_taps`].
    pub head_taps: Vec<Rules>,
}

/// Where a batch's BEV features live.
#[derive(Debug, Clone)]
pub enum Layout {
    /// `(B, C, cells, cells)` maps.
    Dense { batch: usize, cells: usize },
    /// `(N_level, C)` rows at the sites of [`Sparse`].
    Sparse(Box<Sparse>),
}

fn u32s(v: &[u32], device: &Device) -> Result<Tensor> {
    Ok(Tensor::from_slice(v, v.len(), device)?)
}

fn plane(sites: usize, subm: &[u32], batch_of: Vec<u32>, batch: usize, device: &Device) -> Result<Plane> {
    let mut counts = vec![0f32; batch];
    for &b in &batch_of {
        counts[b as usize] += 1.0;
    }
    Ok(Plane {
        sites,
        subm: Rules::new(subm, sites, device)?,
        batch_of: u32s(&batch_of, device)?,
        counts: Tensor::from_vec(counts.into_iter().map(|c| c.max(1.0)).collect::<Vec<_>>(), (batch, 1), device)?,
    })
}

impl Layout {
    /// The layout of a batch: dense when `host` is None.
    pub fn new(batch: usize, cells: usize, host: Option<&SparseHost>, device: &Device) -> Result<Layout> {
        let Some(h) = host else { return Ok(Layout::Dense { batch, cells }) };
        let levels = (0..h.sites.len())
            .map(|l| plane(h.sites[l].len(), &h.subm[l], h.batch_of(Some(l)), batch, device))
            .collect::<Result<Vec<_>>>()?;
        let down =
            h.down
                .iter()
                .enumerate()
                .map(|(l, d)| {
                    if d.is_empty() || l == 0 {
                        Ok(None)
                    } else {
                        Rules::new(d, h.sites[l - 1].len(), device).map(Some)
                    }
                })
                .collect::<Result<_>>()?;
        let head = plane(h.head_sites.len(), &h.head_subm, h.batch_of(None), batch, device)?;
        let head_from =
            h.head_from.iter().zip(&h.sites).map(|(f, s)| Rules::new(f, s.len(), device)).collect::<Result<_>>()?;
        // Tap products are rows of the level's sites (of the head sites for finer levels).
        let head_taps = h
            .head_taps
            .iter()
            .enumerate()
            .map(|(l, t)| {
                let n = if l < h.head_level { h.head_sites.len() } else { h.sites[l].len() };
                Rules::new(t, n * 9, device)
            })
            .collect::<Result<_>>()?;
        Ok(Layout::Sparse(Box::new(Sparse { batch, levels, down, head, head_from, head_taps })))
    }

    pub fn is_sparse(&self) -> bool {
        matches!(self, Layout::Sparse(_))
    }

    /// Rows a level-0 scatter writes into: B · cells² (dense) or the level-0 sites.
    pub fn rows(&self) -> usize {
        match self {
            Layout::Dense { batch, cells } => batch * cells * cells,
            Layout::Sparse(s) => s.levels[0].sites,
        }
    }

    /// Level-0 features from `(rows, C)` scattered rows: `(B, C, H, W)` or `(N_0, C)` as is.
    pub fn from_rows(&self, flat: Tensor) -> Result<Tensor> {
        match self {
            Layout::Dense { batch, cells } => {
                let c = flat.dim(1)?;
                Ok(flat.reshape((*batch, *cells, *cells, c))?.permute((0, 3, 1, 2))?.contiguous()?)
            }
            Layout::Sparse(_) => Ok(flat),
        }
    }

    /// Zeros `(rows, channels)` for a level-0 scatter.
    pub fn zeros(&self, channels: usize, device: &Device) -> Result<Tensor> {
        Ok(Tensor::zeros((self.rows(), channels), DType::F32, device)?)
    }

    /// How a 3×3 stride-1 convolution at level 0 runs.
    pub fn level0(&self) -> At<'_> {
        match self {
            Layout::Dense { .. } => At::Dense,
            Layout::Sparse(s) => At::Sparse(&s.levels[0]),
        }
    }
}

/// How a module applies at one place of a layout: dense, or on a sparse plane (3×3 stride-1
/// convolutions use its rulebook; 1×1 ones act on rows).
#[derive(Debug, Clone, Copy)]
pub enum At<'a> {
    Dense,
    Sparse(&'a Plane),
}

impl At<'_> {
    /// Per-frame mean over the plane, broadcastable to `x`: `(B, C, 1, 1)` dense, `(N, C)`
    /// sparse (each site gets its frame's mean).
    pub fn frame_mean(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            At::Dense => Ok(x.mean_keepdim(3)?.mean_keepdim(2)?),
            At::Sparse(p) => {
                let c = x.dim(1)?;
                let b = p.counts.dim(0)?;
                let sums = Tensor::zeros((b, c), x.dtype(), x.device())?.index_add(&p.batch_of, x, 0)?;
                Ok(sums.broadcast_div(&p.counts)?.index_select(&p.batch_of, 0)?)
            }
        }
    }
}

/// A 3×3 convolution (padding 1) of sparse rows `x` (N_in, C_in) by `w` (C_out, C_in, 3, 3)
/// along a rulebook (N_out · 9): gather, one matrix product. Equal to a dense convolution at
/// the output sites when every other input cell is zero.
///
/// On the CPU the whole convolution is one autograd node ([`GatherConv`]); elsewhere it is
/// candle's `index_select` and `matmul` ([`gather_conv_composite`]).
pub fn gather_conv(x: &Tensor, w: &Tensor, rules: &Rules) -> Result<Tensor> {
    gather_conv_with(x, w, rules, Backward::default_on(x.device()))
}

/// An index map on the device: a rulebook (`N_out · taps` input rows) or any other list of
/// rows to gather ([`NONE`]: zeros), and, where the sparse path runs from candle's operations
/// (off the CPU, with [`Backward::Gather`]), its inverse for [`RowGather`]'s backward pass: for
/// each input row, the positions of the list that read it, padded with [`NONE`] to the most
/// any row is read (`reads`), `N_in · reads` entries.
#[derive(Debug, Clone)]
pub struct Rules {
    pub rows: Tensor,
    pub inverse: Option<Tensor>,
    pub reads: usize,
}

impl Rules {
    /// The list `rules` over `n_in` input rows on `device`, inverted where
    /// [`Backward::default_on`] `device` gathers.
    pub fn new(rules: &[u32], n_in: usize, device: &Device) -> Result<Rules> {
        let invert = !device.is_cpu() && Backward::default_on(device) == Backward::Gather;
        Self::with_inverse(rules, n_in, device, invert)
    }

    /// [`Rules::new`] with the inverse built or not as `invert` says (tests take both paths on
    /// the CPU).
    pub fn with_inverse(rules: &[u32], n_in: usize, device: &Device, invert: bool) -> Result<Rules> {
        let rows = u32s(rules, device)?;
        if !invert {
            return Ok(Rules { rows, inverse: None, reads: 0 });
        }
        let (inverse, reads) = padded_inverse(rules, n_in)?;
        Ok(Rules { rows, inverse: Some(u32s(&inverse, device)?), reads })
    }
}

/// For each of `n_in` input rows the positions of `rules` that read it, padded with [`NONE`] to
/// the most any row is read: `(N_in · reads, reads)`, `reads` ≥ 1.
fn padded_inverse(rules: &[u32], n_in: usize) -> Result<(Vec<u32>, usize)> {
    let mut count = vec![0usize; n_in];
    for &r in rules.iter().filter(|&&r| r != NONE) {
        let c = count
            .get_mut(r as usize)
            .ok_or_else(|| crate::error::FusionError::Config(format!("a rulebook reads row {r} of {n_in}")))?;
        *c += 1;
    }
    let reads = count.iter().copied().max().unwrap_or(0).max(1);
    let mut inverse = vec![NONE; n_in * reads];
    count.iter_mut().for_each(|c| *c = 0);
    for (p, &r) in rules.iter().enumerate().filter(|(_, r)| **r != NONE) {
        inverse[r as usize * reads + count[r as usize]] = p as u32;
        count[r as usize] += 1;
    }
    Ok((inverse, reads))
}

/// How a sparse convolution's backward pass forms the input's gradient. On the CPU the default
/// is [`Backward::Scatter`], the faster there (`hilo bench train --variant
/// sparse_backward=gather|scatter` compares them; docs/measurements.md has the runs): the gather
/// of the output gradient reads nine rows per input row, the scatter's adds stay in cache.
/// Elsewhere it is [`Backward::Gather`] ([`RowGather`]): candle's `index_add` on CUDA runs one
/// thread per channel, each looping over every gathered row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backward {
    /// Through the inverted rulebook: per tap a rulebook reads each input row at most once, so
    /// the input's gradient at row i is Σ_t grad[o_t(i)] · W_t over the outputs o_t(i) that
    /// read i through tap t: a gather of the output gradient's rows (`N_in`, taps · C_out) and
    /// one matrix product with the kernel, no scatter. Falls back to [`Backward::Scatter`] for
    /// a rulebook that reads a row twice through one tap.
    Gather,
    /// The gathered matrix's gradient (`N_out`, taps · C_in) by a matrix product, each row
    /// added into the input row its rule names.
    Scatter,
}

/// The process's choice: 0 each device's own default, 1 [`Backward::Gather`], 2
/// [`Backward::Scatter`].
static BACKWARD: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

impl Backward {
    /// The process's choice on `device`: what [`Backward::set_default`] chose (a benchmark's
    /// before/after lever), else [`Backward::Scatter`] on the CPU and [`Backward::Gather`]
    /// elsewhere.
    pub fn default_on(device: &Device) -> Self {
        match BACKWARD.load(std::sync::atomic::Ordering::Relaxed) {
            1 => Backward::Gather,
            2 => Backward::Scatter,
            _ if device.is_cpu() => Backward::Scatter,
            _ => Backward::Gather,
        }
    }

    /// Chooses the backward pass for every device, or (None) each device's own default. A
    /// layout built before the choice keeps its rulebooks' inverses (or their absence).
    pub fn set_default(b: Option<Backward>) {
        let v = match b {
            None => 0,
            Some(Backward::Gather) => 1,
            Some(Backward::Scatter) => 2,
        };
        BACKWARD.store(v, std::sync::atomic::Ordering::Relaxed);
    }
}

/// [`gather_conv`] with the backward pass `backward` (on the CPU; elsewhere the rulebook's
/// inverse, present or not, decides).
pub fn gather_conv_with(x: &Tensor, w: &Tensor, rules: &Rules, backward: Backward) -> Result<Tensor> {
    let (co, ci, kh, kw) = w.dims4()?;
    let taps = kh * kw;
    crate::cpu::count_matmul(rules.rows.dim(0)? / taps, taps * ci, co);
    fused_on_cpu(x, w, GatherConv { rules: rules.rows.clone(), kernel: std::sync::OnceLock::new(), backward }, || {
        gather_conv_composite(x, w, rules)
    })
}

/// The rulebook inverted per tap: for each input row i and tap t, the output row that reads i
/// through t (or [`NONE`]), as `N_in · taps` entries; None when some tap reads a row twice.
fn inverse_rules(rules: &[u32], n_in: usize, taps: usize) -> Option<Vec<u32>> {
    let mut inv = vec![NONE; n_in * taps];
    for (o, site) in rules.chunks_exact(taps.max(1)).enumerate() {
        for (t, &r) in site.iter().enumerate() {
            if r != NONE {
                let slot = inv.get_mut(r as usize * taps + t)?;
                if *slot != NONE {
                    return None;
                }
                *slot = o as u32;
            }
        }
    }
    Some(inv)
}

/// A kernel `(C_out, C_in, taps)` on the host as the `(taps · C_out, C_in)` matrix that the
/// inverted gather's rows (taps major, as [`gather_rows`] lays out a row's taps) multiply.
fn kernel_taps_out(w: &[f32], co: usize, ci: usize, taps: usize) -> Vec<f32> {
    let mut out = vec![0f32; w.len()];
    for o in 0..co {
        for c in 0..ci {
            for t in 0..taps {
                out[(t * co + o) * ci + c] = w[(o * ci + c) * taps + t];
            }
        }
    }
    out
}

/// `op` on `x` and `w` as one node where both are f32 on the CPU (and the fused convolutions are
/// on, [`crate::cpu::fused`]); elsewhere `composite`.
fn fused_on_cpu(
    x: &Tensor,
    w: &Tensor,
    op: impl CustomOp2 + Send + Sync + 'static,
    composite: impl FnOnce() -> Result<Tensor>,
) -> Result<Tensor> {
    if crate::cpu::fused_on(crate::cpu::Layer::Conv, x) && w.dtype() == DType::F32 {
        Ok(x.contiguous()?.apply_op2(&w.contiguous()?, op)?)
    } else {
        composite()
    }
}

/// [`gather_conv`] from candle's own operations (gather, reshape, matrix product), each an
/// autograd node: the reference [`GatherConv`] is tested against, and the path on other devices.
/// The gather is [`RowGather`] where the rulebook carries its inverse, else `index_select`
/// (whose backward pass is candle's `index_add`).
pub fn gather_conv_composite(x: &Tensor, w: &Tensor, rules: &Rules) -> Result<Tensor> {
    let (_, ci, kh, kw) = w.dims4()?;
    let taps = kh * kw;
    let n_out = rules.rows.dim(0)? / taps;
    Ok(gather(x, rules)?.reshape((n_out, taps * ci))?.matmul(&kernel_matrix(w)?)?)
}

/// The rows of `x` that `rules` names (zeros for [`NONE`]): [`RowGather`] where the list
/// carries its inverse, else `index_select` (whose backward pass is candle's `index_add`).
pub fn gather(x: &Tensor, rules: &Rules) -> Result<Tensor> {
    let x = x.contiguous()?;
    Ok(match &rules.inverse {
        Some(inverse) => {
            x.apply_op1(RowGather { rules: rules.rows.clone(), inverse: inverse.clone(), reads: rules.reads })?
        }
        None => x.index_select(&rules.rows, 0)?,
    })
}

/// The rows of `x` `(N_in, C)` a list names (zeros for [`NONE`]) as one autograd node whose
/// backward pass is a gather, not a scatter-add: the input's gradient at row `i` is the sum of
/// the output gradient's rows at the positions that read `i` ([`Rules::inverse`], padded to
/// `reads` per row): a gather of `N_in · reads` rows and a sum, one thread per element on a
/// GPU, where candle's `index_add` runs one thread per channel looping over every row. A
/// rulebook reads a row at most once per tap (`reads` ≤ 9); a head site's parent is read by
/// the head sites below it. Forward: candle's own gather on the device.
#[derive(Debug, Clone)]
pub struct RowGather {
    rules: Tensor,
    inverse: Tensor,
    reads: usize,
}

const ROW_GATHER: &str = "hilo-row-gather";

impl candle_core::CustomOp1 for RowGather {
    fn name(&self) -> &'static str {
        ROW_GATHER
    }

    fn cpu_fwd(
        &self,
        s: &CpuStorage,
        l: &candle_core::Layout,
    ) -> candle_core::Result<(CpuStorage, candle_core::Shape)> {
        let x = f32_slice(s, l, ROW_GATHER)?;
        let (_, ci) = l.shape().dims2()?;
        let cols = with_cpu::<u32, _>(&self.rules, ROW_GATHER, |rules| Ok(gather_rows(x, ci, rules)))?;
        Ok((CpuStorage::F32(cols), candle_core::Shape::from((self.rules.dim(0)?, ci))))
    }

    #[cfg(feature = "cuda")]
    fn cuda_fwd(
        &self,
        s: &candle_core::CudaStorage,
        l: &candle_core::Layout,
    ) -> candle_core::Result<(candle_core::CudaStorage, candle_core::Shape)> {
        use candle_core::backend::BackendStorage;
        let (_, ci) = l.shape().dims2()?;
        let (rules, rl) = self.rules.storage_and_layout();
        let candle_core::Storage::Cuda(rules) = &*rules else {
            candle_core::bail!("{ROW_GATHER}: the rulebook is not on the input's device")
        };
        Ok((s.index_select(rules, l, rl, 0)?, candle_core::Shape::from((self.rules.dim(0)?, ci))))
    }

    fn bwd(&self, x: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let (n_in, ci) = x.dims2()?;
        let g = grad.detach().contiguous()?.index_select(&self.inverse, 0)?;
        Ok(Some(g.reshape((n_in, self.reads, ci))?.sum(1)?))
    }
}

/// (C_out, C_in, kh, kw) → (taps · C_in, C_out), taps major as the gather lays them out.
fn kernel_matrix(w: &Tensor) -> candle_core::Result<Tensor> {
    let (co, ci, kh, kw) = w.dims4()?;
    w.reshape((co, ci, kh * kw))?.permute((2, 1, 0))?.reshape((kh * kw * ci, co))
}

/// A sparse convolution as one autograd node (CPU, f32): the gathered `(N_out, taps · C_in)`
/// matrix is a buffer of the operation, not a tensor of the graph. candle's backward pass
/// gives every node's gradient a zero tensor and adds into it; for the composite path that
/// means zeroing and adding two gradients nine times the size of the input (the gathered
/// matrix and its reshape) per convolution, then a zeroed copy of the input's for the scatter.
/// In a profile of `centerpoint`'s training that bookkeeping was 31% of the training thread's
/// time. Here the backward pass computes the gathered matrix's gradient once (a matrix product)
/// and scatters it straight into the input's, and recomputes the gather for the kernel's; the
/// kernel's layouts are plain host loops.
#[derive(Debug, Clone)]
pub struct GatherConv {
    /// The rulebook, `N_out · taps` input rows ([`NONE`]: zeros).
    rules: Tensor,
    /// The kernel as the `(C_out, taps · C_in)` matrix, kept by the forward pass (which
    /// multiplies by its transpose, a strided view) for the backward one.
    kernel: std::sync::OnceLock<Tensor>,
    backward: Backward,
}

const OP: &str = "hilo-gather-conv";

/// A kernel `(C_out, C_in, taps)` on the host as the `(C_out, taps · C_in)` matrix whose
/// transpose the gather multiplies (taps major within a row, as [`gather_rows`] lays out a
/// site's inputs). Each output channel's `C_in × taps` block is transposed on its own, so the
/// loop reads and writes within a few kilobytes, where a transpose of the whole kernel to
/// `(taps · C_in, C_out)` strides across it.
fn kernel_rows(w: &[f32], ci: usize, taps: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(w.len());
    for block in w.chunks_exact((ci * taps).max(1)) {
        for t in 0..taps {
            out.extend((0..ci).map(|c| block[c * taps + t]));
        }
    }
    out
}

/// The adjoint layout: a `(C_out, taps · C_in)` matrix back to a kernel `(C_out, C_in, taps)`.
fn kernel_from_rows(m: &[f32], ci: usize, taps: usize) -> Vec<f32> {
    let mut w = Vec::with_capacity(m.len());
    for block in m.chunks_exact((ci * taps).max(1)) {
        for c in 0..ci {
            w.extend((0..taps).map(|t| block[t * ci + c]));
        }
    }
    w
}

/// Rows of `x` (width `ci`) named by `rules`, zeros for [`NONE`]: `(rules.len(), ci)`. On one
/// thread (each data-parallel replica has one) the rows are written once, in order; on more,
/// chunks of rows are copied in parallel into a zeroed buffer.
fn gather_rows(x: &[f32], ci: usize, rules: &[u32]) -> Vec<f32> {
    const ROWS: usize = 256;
    let row = |r: u32| &x[r as usize * ci..(r as usize + 1) * ci];
    if rayon::current_num_threads() <= 1 || rules.len() <= ROWS {
        let mut cols = Vec::with_capacity(rules.len() * ci);
        for &r in rules {
            if r == NONE {
                cols.resize(cols.len() + ci, 0.0);
            } else {
                cols.extend_from_slice(row(r));
            }
        }
        return cols;
    }
    let mut cols = vec![0f32; rules.len() * ci];
    cols.par_chunks_mut(ROWS * ci).zip(rules.par_chunks(ROWS)).for_each(|(dst, rows)| {
        for (d, &r) in dst.chunks_exact_mut(ci).zip(rows) {
            if r != NONE {
                d.copy_from_slice(row(r));
            }
        }
    });
    cols
}

/// The adjoint of [`gather_rows`]: each row of `g` added to the input row its rule names.
/// Threads own disjoint column ranges, so the sum is deterministic.
fn scatter_rows(g: &[f32], ci: usize, rules: &[u32], n_in: usize) -> Vec<f32> {
    let threads = rayon::current_num_threads().clamp(1, ci.max(1));
    let width = ci.div_ceil(threads);
    let parts: Vec<(usize, Vec<f32>)> = (0..ci.div_ceil(width))
        .into_par_iter()
        .map(|p| {
            let (c0, c1) = (p * width, ((p + 1) * width).min(ci));
            let mut part = vec![0f32; n_in * (c1 - c0)];
            for (row, &r) in g.chunks_exact(ci).zip(rules) {
                if r != NONE {
                    let dst = &mut part[r as usize * (c1 - c0)..(r as usize + 1) * (c1 - c0)];
                    for (d, s) in dst.iter_mut().zip(&row[c0..c1]) {
                        *d += s;
                    }
                }
            }
            (c0, part)
        })
        .collect();
    if parts.len() == 1 {
        // One part holds every column: it is the result.
        return parts.into_iter().next().map(|(_, p)| p).unwrap_or_default();
    }
    let mut out = vec![0f32; n_in * ci];
    for (c0, part) in parts {
        let w = part.len() / n_in.max(1);
        for (dst, src) in out.chunks_exact_mut(ci).zip(part.chunks_exact(w.max(1))) {
            dst[c0..c0 + w].copy_from_slice(src);
        }
    }
    out
}

/// The kernel matrix a node's forward pass kept, or, should its backward pass run without
/// one, the same matrix laid out again from the kernel `w` by `layout`.
fn kept_kernel(
    kept: &std::sync::OnceLock<Tensor>,
    w: &Tensor,
    op: &str,
    shape: (usize, usize),
    layout: impl FnOnce(&[f32]) -> Vec<f32>,
) -> candle_core::Result<Tensor> {
    match kept.get() {
        Some(m) => Ok(m.clone()),
        None => Tensor::from_vec(with_cpu::<f32, _>(w, op, |wv| Ok(layout(wv)))?, shape, w.device()),
    }
}

/// A sparse convolution node's operands on the host: rows `(rows, C_in)` and a kernel
/// `(C_out, C_in, kh, kw)` of `taps = kh · kw`.
struct Operands<'a> {
    x: &'a [f32],
    w: &'a [f32],
    rows: usize,
    ci: usize,
    co: usize,
    taps: usize,
}

impl<'a> Operands<'a> {
    /// The slices and sizes, or an error naming `op` where the channels differ.
    fn of(
        xs: &'a CpuStorage,
        xl: &candle_core::Layout,
        ws: &'a CpuStorage,
        wl: &candle_core::Layout,
        op: &str,
    ) -> candle_core::Result<Self> {
        let (x, w) = (f32_slice(xs, xl, op)?, f32_slice(ws, wl, op)?);
        let (rows, ci) = xl.shape().dims2()?;
        let (co, wci, kh, kw) = wl.shape().dims4()?;
        if wci != ci {
            candle_core::bail!("{op}: input has {ci} channels, kernel {wci}")
        }
        Ok(Operands { x, w, rows, ci, co, taps: kh * kw })
    }
}

impl CustomOp2 for GatherConv {
    fn name(&self) -> &'static str {
        OP
    }

    fn cpu_fwd(
        &self,
        xs: &CpuStorage,
        xl: &candle_core::Layout,
        ws: &CpuStorage,
        wl: &candle_core::Layout,
    ) -> candle_core::Result<(CpuStorage, candle_core::Shape)> {
        let Operands { x, w, ci, co, taps, .. } = Operands::of(xs, xl, ws, wl, OP)?;
        let cols = with_cpu::<u32, _>(&self.rules, OP, |rules| Ok(gather_rows(x, ci, rules)))?;
        let n_out = cols.len() / (taps * ci).max(1);
        let dev = candle_core::Device::Cpu;
        let wm = Tensor::from_vec(kernel_rows(w, ci, taps), (co, taps * ci), &dev)?;
        let y = Tensor::from_vec(cols, (n_out, taps * ci), &dev)?.matmul(&wm.t()?)?;
        // A node's forward pass runs once; should it run again, the kernel is the same.
        let _ = self.kernel.set(wm);
        Ok((CpuStorage::F32(y.flatten_all()?.to_vec1::<f32>()?), candle_core::Shape::from((n_out, co))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (x, w, grad) = (x.detach().contiguous()?, w.detach().contiguous()?, grad.detach().contiguous()?);
        let (n_in, ci) = x.dims2()?;
        let (co, _, kh, kw) = w.dims4()?;
        let taps = kh * kw;
        let inverse = match self.backward {
            Backward::Gather => with_cpu::<u32, _>(&self.rules, OP, |rules| Ok(inverse_rules(rules, n_in, taps)))?,
            Backward::Scatter => None,
        };
        let gx = match inverse {
            // d x = (grad gathered through the inverted rulebook) · kernel.
            Some(inv) => {
                let gcols = with_cpu::<f32, _>(&grad, OP, |g| Ok(gather_rows(g, co, &inv)))?;
                let wt = with_cpu::<f32, _>(&w, OP, |wv| Ok(kernel_taps_out(wv, co, ci, taps)))?;
                let gcols = Tensor::from_vec(gcols, (n_in, taps * co), x.device())?;
                gcols.matmul(&Tensor::from_vec(wt, (taps * co, ci), x.device())?)?.flatten_all()?.to_vec1::<f32>()?
            }
            // d cols = grad · kernelᵀ, scattered back along the rulebook.
            None => {
                let wm = kept_kernel(&self.kernel, &w, OP, (co, taps * ci), |wv| kernel_rows(wv, ci, taps))?;
                let gcols = grad.matmul(&wm)?;
                with_cpu::<u32, _>(&self.rules, OP, |rules| {
                    with_cpu::<f32, _>(&gcols, OP, |g| Ok(scatter_rows(g, ci, rules, n_in)))
                })?
            }
        };
        // d kernel = colsᵀ · grad, the gather recomputed rather than kept from the forward pass.
        let cols = with_cpu::<u32, _>(&self.rules, OP, |rules| {
            with_cpu::<f32, _>(&x, OP, |xv| Ok(gather_rows(xv, ci, rules)))
        })?;
        let n_out = cols.len() / (taps * ci).max(1);
        let gwm = grad.t()?.matmul(&Tensor::from_vec(cols, (n_out, taps * ci), x.device())?)?;
        let gw = with_cpu::<f32, _>(&gwm, OP, |m| Ok(kernel_from_rows(m, ci, taps)))?;
        let gw = Tensor::from_vec(gw, (co, ci, kh, kw), x.device())?;
        Ok((Some(Tensor::from_vec(gx, (n_in, ci), x.device())?), Some(gw)))
    }
}

/// A 3×3 stride-1 convolution at the head sites of rows that live elsewhere: `v` `(N_v, C_in)`
/// holds one row per parent (a coarser level's site, whose value every head site below it
/// shares) and `taps` (N_head · 9, [`SparseHost::head_taps`]) names, for each head site and
/// tap, the row `r · 9 + t` of the tap products `v · W_t` to add (or [`NONE`]). The same
/// function as [`gather_conv`] of `v` gathered to the head sites first, with the products
/// taken once per parent instead of once per head site and tap: the neck's coarser blocks
/// reach the head through their parents (a level-3 row is shared by up to 64 head cells), so
/// `centerpoint`'s head convolution costs about a tenth of the multiply-adds.
///
/// On the CPU it is one autograd node ([`ParentConv`]); elsewhere candle's `matmul`,
/// `index_select` and `sum` ([`parent_conv_composite`]).
pub fn parent_conv(v: &Tensor, w: &Tensor, taps: &Rules) -> Result<Tensor> {
    let (co, ci, kh, kw) = w.dims4()?;
    crate::cpu::count_matmul(v.dim(0)?, ci, kh * kw * co);
    fused_on_cpu(v, w, ParentConv { taps: taps.rows.clone(), kernel: std::sync::OnceLock::new() }, || {
        parent_conv_composite(v, w, taps)
    })
}

/// [`parent_conv`] from candle's own operations: the tap products `(N_v · 9, C_out)`, the rows
/// the head sites read, summed over the taps. The reference [`ParentConv`] is tested against,
/// and the path on other devices.
pub fn parent_conv_composite(v: &Tensor, w: &Tensor, taps: &Rules) -> Result<Tensor> {
    let (co, ci, kh, kw) = w.dims4()?;
    let t = kh * kw;
    let n_head = taps.rows.dim(0)? / t;
    let wm = w.reshape((co, ci, t))?.permute((1, 2, 0))?.reshape((ci, t * co))?;
    let products = v.contiguous()?.matmul(&wm)?.reshape((v.dim(0)? * t, co))?;
    Ok(gather(&products, taps)?.reshape((n_head, t, co))?.sum(1)?)
}

/// A kernel `(C_out, C_in, taps)` as the `(C_in, taps · C_out)` matrix of [`ParentConv`]'s tap
/// products (tap major within a row).
fn tap_columns(w: &[f32], ci: usize, taps: usize) -> Vec<f32> {
    let co = w.len() / (ci * taps).max(1);
    let mut m = vec![0f32; w.len()];
    for (o, block) in w.chunks_exact((ci * taps).max(1)).enumerate() {
        for (i, row) in block.chunks_exact(taps).enumerate() {
            for (t, &x) in row.iter().enumerate() {
                m[i * taps * co + t * co + o] = x;
            }
        }
    }
    m
}

/// The adjoint layout of [`tap_columns`]: back to `(C_out, C_in, taps)`.
fn tap_columns_to_kernel(m: &[f32], ci: usize, taps: usize) -> Vec<f32> {
    let co = m.len() / (ci * taps).max(1);
    let mut w = vec![0f32; m.len()];
    for (o, block) in w.chunks_exact_mut((ci * taps).max(1)).enumerate() {
        for (i, row) in block.chunks_exact_mut(taps).enumerate() {
            for (t, x) in row.iter_mut().enumerate() {
                *x = m[i * taps * co + t * co + o];
            }
        }
    }
    w
}

/// [`parent_conv`] as one autograd node (CPU, f32): the tap products are a buffer of the
/// operation, and the backward pass adds each head site's gradient into the product rows it
/// read (one pass, in order, so the sums do not depend on threads), then takes the two matrix
/// products of the inputs' gradients.
#[derive(Debug, Clone)]
pub struct ParentConv {
    /// `N_head · taps` rows of the tap products ([`NONE`]: nothing).
    taps: Tensor,
    /// The kernel as the `(C_in, taps · C_out)` matrix, kept by the forward pass.
    kernel: std::sync::OnceLock<Tensor>,
}

const PARENT_OP: &str = "hilo-parent-conv";

impl CustomOp2 for ParentConv {
    fn name(&self) -> &'static str {
        PARENT_OP
    }

    fn cpu_fwd(
        &self,
        vs: &CpuStorage,
        vl: &candle_core::Layout,
        ws: &CpuStorage,
        wl: &candle_core::Layout,
    ) -> candle_core::Result<(CpuStorage, candle_core::Shape)> {
        let Operands { x: v, w, rows: n_v, ci, co, taps } = Operands::of(vs, vl, ws, wl, PARENT_OP)?;
        let dev = candle_core::Device::Cpu;
        let wm = Tensor::from_vec(tap_columns(w, ci, taps), (ci, taps * co), &dev)?;
        let products = Tensor::from_vec(v.to_vec(), (n_v, ci), &dev)?.matmul(&wm)?;
        let y = with_cpu::<u32, _>(&self.taps, PARENT_OP, |rules| {
            with_cpu::<f32, _>(&products, PARENT_OP, |p| {
                let rows = p.len() / co.max(1);
                let mut y = vec![0f32; rules.len() / taps.max(1) * co];
                for (out, site) in y.chunks_exact_mut(co.max(1)).zip(rules.chunks_exact(taps.max(1))) {
                    for &r in site {
                        if r == NONE {
                            continue;
                        }
                        let r = r as usize;
                        if r >= rows {
                            candle_core::bail!("{PARENT_OP}: tap row {r} of {rows}")
                        }
                        for (o, x) in out.iter_mut().zip(&p[r * co..(r + 1) * co]) {
                            *o += x;
                        }
                    }
                }
                Ok(y)
            })
        })?;
        let _ = self.kernel.set(wm);
        let n_head = y.len() / co.max(1);
        Ok((CpuStorage::F32(y), candle_core::Shape::from((n_head, co))))
    }

    fn bwd(
        &self,
        v: &Tensor,
        w: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (v, w, grad) = (v.detach().contiguous()?, w.detach().contiguous()?, grad.detach().contiguous()?);
        let (n_v, ci) = v.dims2()?;
        let (co, _, kh, kw) = w.dims4()?;
        let taps = kh * kw;
        let wm = kept_kernel(&self.kernel, &w, PARENT_OP, (ci, taps * co), |wv| tap_columns(wv, ci, taps))?;
        // d products: each head site's gradient added into the rows it read.
        let gp = with_cpu::<u32, _>(&self.taps, PARENT_OP, |rules| {
            with_cpu::<f32, _>(&grad, PARENT_OP, |g| {
                let mut gp = vec![0f32; n_v * taps * co];
                for (gs, site) in g.chunks_exact(co.max(1)).zip(rules.chunks_exact(taps.max(1))) {
                    for &r in site {
                        if r != NONE && (r as usize) < n_v * taps {
                            let r = r as usize;
                            for (d, x) in gp[r * co..(r + 1) * co].iter_mut().zip(gs) {
                                *d += x;
                            }
                        }
                    }
                }
                Ok(gp)
            })
        })?;
        let gp = Tensor::from_vec(gp, (n_v, taps * co), v.device())?;
        let gv = gp.matmul(&wm.t()?)?;
        let gwm = v.t()?.matmul(&gp)?;
        let gw = with_cpu::<f32, _>(&gwm.contiguous()?, PARENT_OP, |m| Ok(tap_columns_to_kernel(m, ci, taps)))?;
        Ok((Some(gv), Some(Tensor::from_vec(gw, (co, ci, kh, kw), v.device())?)))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Sites from `occupied` random cells of a `b × cells²` grid (3 levels), and uniform
    /// features `(N_0, ci)` at level 0, drawn in that order from `rng`.
    fn random_sites(
        rng: &mut rand_chacha::ChaCha8Rng,
        b: usize,
        cells: usize,
        occupied: usize,
        ci: usize,
    ) -> (SparseHost, Vec<f32>) {
        let cells_hit: Vec<u32> = (0..occupied).map(|_| rng.random_range(0..(b * cells * cells) as u32)).collect();
        let h = SparseHost::build(cells, b, &cells_hit, 3, 0, 1);
        let x = (0..h.sites[0].len() * ci).map(|_| rng.random_range(-1.0..1.0)).collect();
        (h, x)
    }

    /// A sparse convolution equals candle's dense conv2d at the output sites, for stride 1 and
    /// stride 2, when the dense input is zero off the input sites.
    #[test]
    fn gather_conv_matches_dense_conv2d_at_the_sites() {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let (b, cells, ci, co) = (2usize, 16usize, 3usize, 4usize);
        let (h, x) = random_sites(&mut rng, b, cells, 40, ci);
        let n0 = h.sites[0].len();
        let xs = Tensor::from_vec(x.clone(), (n0, ci), &dev).unwrap();
        // The dense input: zeros off the sites.
        let mut dense = vec![0f32; b * ci * cells * cells];
        for (i, &s) in h.sites[0].iter().enumerate() {
            let (bb, rc) = (s as usize / (cells * cells), s as usize % (cells * cells));
            for c in 0..ci {
                dense[(bb * ci + c) * cells * cells + rc] = x[i * ci + c];
            }
        }
        let xd = Tensor::from_vec(dense, (b, ci, cells, cells), &dev).unwrap();
        let w = Tensor::randn(0f32, 1.0, (co, ci, 3, 3), &dev).unwrap();
        for (stride, rules, out_sites, n) in
            [(1usize, &h.subm[0], &h.sites[0], cells), (2, &h.down[1], &h.sites[1], cells / 2)]
        {
            let n_in = if stride == 1 { n0 } else { h.sites[0].len() };
            let ys = gather_conv(&xs, &w, &Rules::new(rules, n_in, &dev).unwrap()).unwrap().to_vec2::<f32>().unwrap();
            let yd = xd.conv2d(&w, 1, stride, 1, 1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (i, &s) in out_sites.iter().enumerate() {
                let (bb, rc) = (s as usize / (n * n), s as usize % (n * n));
                for c in 0..co {
                    let want = yd[(bb * co + c) * n * n + rc];
                    assert!(
                        (ys[i][c] - want).abs() < 1e-4,
                        "stride {stride}, site {s}, channel {c}: {} vs {want}",
                        ys[i][c]
                    );
                }
            }
            if stride == 1 {
                continue;
            }
            // A strided (not submanifold) convolution: off its output sites the dense result is
            // zero, so nothing is lost by not computing it.
            let on: std::collections::HashSet<usize> = out_sites.iter().map(|&s| s as usize).collect();
            for bb in 0..b {
                for rc in 0..n * n {
                    if !on.contains(&(bb * n * n + rc)) {
                        for c in 0..co {
                            assert_eq!(yd[(bb * co + c) * n * n + rc], 0.0);
                        }
                    }
                }
            }
        }
    }

    /// The fused node equals the composite of candle's operations: output, and the gradients
    /// of the input and the kernel, for a submanifold (stride 1) and a strided rulebook, with
    /// rulebook rows that read nothing (`NONE`) and input rows read by several outputs.
    /// The inverted rulebook names, per input row and tap, the one output that reads it; a
    /// rulebook that reads a row twice through one tap has none (the scatter is used).
    #[test]
    fn the_rulebook_inverts_per_tap_or_refuses() {
        // Two outputs, two taps: output 0 reads rows 2, 0; output 1 reads row 1 and nothing.
        let inv = inverse_rules(&[2, 0, 1, NONE], 3, 2).unwrap();
        assert_eq!(inv, vec![NONE, 0, 1, NONE, 0, NONE]);
        assert!(inverse_rules(&[1, 0, 1, NONE], 3, 2).is_none(), "row 1 read twice through tap 0");
        assert!(inverse_rules(&[1, 0, 2, 0], 3, 2).is_none(), "row 0 read twice through tap 1");
        // The padded inverse takes any list: row 0 read at 1 and 3, row 1 at 0 and 2, row 2
        // by none; out of range is an error, not a panic.
        assert_eq!(padded_inverse(&[1, 0, 1, 0, NONE], 3).unwrap(), (vec![1, 3, 0, 2, NONE, NONE], 2));
        assert_eq!(padded_inverse(&[NONE], 2).unwrap(), (vec![NONE, NONE], 1));
        assert!(padded_inverse(&[3], 3).is_err());
    }

    #[test]
    fn fused_gather_conv_equals_candle_ops_with_gradients() {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (b, cells, ci, co) = (2usize, 32usize, 5usize, 6usize);
        let (h, x) = random_sites(&mut rng, b, cells, 300, ci);
        let n0 = h.sites[0].len();
        for rules in [&h.subm[0], &h.down[1]] {
            assert!(rules.contains(&NONE) && rules.iter().any(|&r| r != NONE));
            let r = Rules::with_inverse(rules, n0, &dev, false).unwrap();
            let inverted = Rules::with_inverse(rules, n0, &dev, true).unwrap();
            assert!((1..=9).contains(&inverted.reads), "a rulebook reads a row at most once per tap");
            let n_out = rules.len() / 9;
            let mut uniform = |len: usize| -> Vec<f32> { (0..len).map(|_| rng.random_range(-1.0..1.0)).collect() };
            let up = Tensor::from_vec(uniform(n_out * co), (n_out, co), &dev).unwrap();
            let w0 = Tensor::from_vec(uniform(co * ci * 9), (co, ci, 3, 3), &dev).unwrap();
            // Fused with either backward pass, or the composite with `index_add` (None, false)
            // or with the gather through the inverse (None, true).
            let run = |fused: Option<Backward>, inverse: bool| {
                let xv = candle_core::Var::from_vec(x.clone(), (n0, ci), &dev).unwrap();
                let wv = candle_core::Var::from_tensor(&w0.copy().unwrap()).unwrap();
                let y = match fused {
                    Some(b) => gather_conv_with(xv.as_tensor(), wv.as_tensor(), &r, b).unwrap(),
                    None => {
                        let rr = if inverse { &inverted } else { &r };
                        gather_conv_composite(xv.as_tensor(), wv.as_tensor(), rr).unwrap()
                    }
                };
                let g = (&y * &up).unwrap().sum_all().unwrap().backward().unwrap();
                let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
                (flat(&y), flat(g.get(xv.as_tensor()).unwrap()), flat(g.get(wv.as_tensor()).unwrap()))
            };
            // Both backward passes; the rulebooks read each row at most once per tap, so the
            // gather-only one does not fall back.
            assert!(inverse_rules(rules, n0, 9).is_some());
            let reference = run(None, false);
            for (b, inverse) in [(Some(Backward::Gather), false), (Some(Backward::Scatter), false), (None, true)] {
                let fused = run(b, inverse);
                for (what, a, c) in
                    [("y", &fused.0, &reference.0), ("dx", &fused.1, &reference.1), ("dw", &fused.2, &reference.2)]
                {
                    assert_eq!(a.len(), c.len());
                    for (i, (p, q)) in a.iter().zip(c.iter()).enumerate() {
                        assert!((p - q).abs() <= 1e-4 * (1.0 + q.abs()), "{b:?} {what}[{i}]: {p} vs {q}");
                    }
                }
            }
        }
    }

    #[test]
    fn head_sites_cover_the_dilated_cells_and_read_their_parents() {
        // One occupied cell at (5, 6) of a 16 × 16 grid, head at level 0 dilated by 2.
        let h = SparseHost::build(16, 1, &[5 * 16 + 6], 4, 0, 2);
        assert_eq!(h.head_sites.len(), 25);
        // An odd row or column is read by two stride-2 windows: (5, 6) → rows 2 and 3, column 3.
        assert_eq!(h.sites[1], vec![2 * 8 + 3, 3 * 8 + 3]);
        let h2 = SparseHost::build(16, 1, &[5 * 16 + 5], 2, 0, 0);
        assert_eq!(h2.sites[1], vec![2 * 8 + 2, 2 * 8 + 3, 3 * 8 + 2, 3 * 8 + 3]);
        // Parent links: every head site's level-1 parent is its cell halved, if a site.
        for (i, &s) in h.head_sites.iter().enumerate() {
            let (r, c) = (s as usize / 16, s as usize % 16);
            let parent = h.head_from[1][i];
            let want = h.sites[1].iter().position(|&p| p as usize == (r / 2) * 8 + c / 2).map_or(NONE, |k| k as u32);
            assert_eq!(parent, want);
        }
        // An empty batch still has one site.
        let e = SparseHost::build(16, 2, &[], 3, 0, 1);
        assert_eq!(e.sites[0].len(), 1);
    }

    /// The parent convolution's fused node equals the composite of candle's operations:
    /// output, and the gradients of the rows and the kernel, with taps that read nothing
    /// (`NONE`), rows read by many head sites and rows read by none.
    #[test]
    fn fused_parent_conv_equals_candle_ops_with_gradients() {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (n_v, n_head, ci, co) = (7usize, 40usize, 5usize, 6usize);
        // Rows 0..n_v − 1 only, so the last row is read by no head site.
        let taps: Vec<u32> = (0..n_head * 9)
            .map(|k| {
                if rng.random_range(0..4) == 0 {
                    NONE
                } else {
                    rng.random_range(0..n_v as u32 - 1) * 9 + (k % 9) as u32
                }
            })
            .collect();
        let t = Rules::with_inverse(&taps, n_v * 9, &dev, false).unwrap();
        let inverted = Rules::with_inverse(&taps, n_v * 9, &dev, true).unwrap();
        assert!(inverted.reads > 1, "a tap product read by several head sites");
        let mut uniform = |len: usize| -> Vec<f32> { (0..len).map(|_| rng.random_range(-1.0..1.0)).collect() };
        let (v0, w0, up) = (uniform(n_v * ci), uniform(co * ci * 9), uniform(n_head * co));
        let up = Tensor::from_vec(up, (n_head, co), &dev).unwrap();
        // The fused node (0), the composite with `index_add` (1) and with the gather through
        // the inverse (2).
        let run = |path: usize| {
            let vv = candle_core::Var::from_vec(v0.clone(), (n_v, ci), &dev).unwrap();
            let wv = candle_core::Var::from_vec(w0.clone(), (co, ci, 3, 3), &dev).unwrap();
            let y = match path {
                0 => parent_conv(vv.as_tensor(), wv.as_tensor(), &t).unwrap(),
                1 => parent_conv_composite(vv.as_tensor(), wv.as_tensor(), &t).unwrap(),
                _ => parent_conv_composite(vv.as_tensor(), wv.as_tensor(), &inverted).unwrap(),
            };
            let g = (&y * &up).unwrap().sum_all().unwrap().backward().unwrap();
            let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            (flat(&y), flat(g.get(vv.as_tensor()).unwrap()), flat(g.get(wv.as_tensor()).unwrap()))
        };
        let reference = run(1);
        for path in [0, 2] {
            let other = run(path);
            assert!(other.1[(n_v - 1) * ci..].iter().all(|&g| g == 0.0), "an unread row has no gradient");
            for (what, a, b) in
                [("y", &other.0, &reference.0), ("dv", &other.1, &reference.1), ("dw", &other.2, &reference.2)]
            {
                assert_eq!(a.len(), b.len());
                assert!(b.iter().any(|v| v.abs() > 1e-3), "{what} is not all zeros");
                for (i, (p, q)) in a.iter().zip(b.iter()).enumerate() {
                    assert!((p - q).abs() <= 1e-4 * (1.0 + q.abs()), "path {path} {what}[{i}]: {p} vs {q}");
                }
            }
        }
    }
}
