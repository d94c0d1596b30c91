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
//! the kernel, and their gradient flows back through the gather as a scatter-add. These are
//! candle's own `index_select`, `matmul` and `index_add`, so the sparse path runs unchanged on
//! any device. Submanifold convolutions (stride 1) keep their sites; BatchNorm normalises over
//! the sites only, so empty cells stay exactly empty, unlike a dense network where BatchNorm and
//! its bias make every empty cell a value.
//!
//! Rulebooks are built on the host, on the batch thread, from the occupied cells ([`SparseHost`]),
//! and moved to the device once per batch ([`Layout::new`]).

use crate::error::Result;
use candle_core::{DType, Device, Tensor};
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
        let head_from = (0..levels)
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
        SparseHost { batch, cells, sites, subm, down, head_level, head_sites: head, head_subm, head_from }
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
    pub subm: Tensor,
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
    pub down: Vec<Option<Tensor>>,
    pub head: Plane,
    pub head_from: Vec<Tensor>,
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
        subm: u32s(subm, device)?,
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
        let down = h
            .down
            .iter()
            .map(|d| if d.is_empty() { Ok(None) } else { u32s(d, device).map(Some) })
            .collect::<Result<_>>()?;
        let head = plane(h.head_sites.len(), &h.head_subm, h.batch_of(None), batch, device)?;
        let head_from = h.head_from.iter().map(|f| u32s(f, device)).collect::<Result<_>>()?;
        Ok(Layout::Sparse(Box::new(Sparse { batch, levels, down, head, head_from })))
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
pub fn gather_conv(x: &Tensor, w: &Tensor, rules: &Tensor) -> Result<Tensor> {
    let (co, ci, kh, kw) = w.dims4()?;
    let taps = kh * kw;
    let n_out = rules.dim(0)? / taps;
    crate::conv::count_matmul(n_out, taps * ci, co);
    let cols = x.contiguous()?.index_select(rules, 0)?.reshape((n_out, taps * ci))?;
    // (C_out, C_in, 3, 3) → (9 · C_in, C_out), taps major as the gather lays them out.
    let wm = w.reshape((co, ci, taps))?.permute((2, 1, 0))?.reshape((taps * ci, co))?;
    Ok(cols.matmul(&wm)?)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A sparse convolution equals candle's dense conv2d at the output sites, for stride 1 and
    /// stride 2, when the dense input is zero off the input sites.
    #[test]
    fn gather_conv_matches_dense_conv2d_at_the_sites() {
        let dev = Device::Cpu;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let (b, cells, ci, co) = (2usize, 16usize, 3usize, 4usize);
        let occupied: Vec<u32> = (0..40).map(|_| rng.random_range(0..(b * cells * cells) as u32)).collect();
        let h = SparseHost::build(cells, b, &occupied, 3, 0, 1);
        let n0 = h.sites[0].len();
        let x: Vec<f32> = (0..n0 * ci).map(|_| rng.random_range(-1.0..1.0)).collect();
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
            let ys = gather_conv(&xs, &w, &u32s(rules, &dev).unwrap()).unwrap().to_vec2::<f32>().unwrap();
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
}
