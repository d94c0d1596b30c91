//! hilo's detector framework on Candle: the [`fusion::Fusion`] trait, its registry of plugins
//! and presets, shared detector modules ([`modules`]: pillar feature net, BEV backbone and neck,
//! heads), targets and losses, decoding, the LiDAR-only presets `centerpoint` and
//! `pointpillars` ([`presets`]), training ([`train`]) and inference ([`infer`]).
//!
//! Convolutions run on one of two layouts ([`layout`]): dense maps over the whole grid (on the
//! CPU an im2col matrix product with hilo's own custom ops, [`conv`]; candle's conv2d on other
//! devices), or only the occupied cells, as gather–GEMM convolutions along rulebooks built on
//! the host. What the network reads is part of the detector ([`data::InputConfig`]): LiDAR
//! without its static background, and the radar's last sweeps.
//!
//! Fusion plugins (raw, early, middle, late) live in their own crates under `plugins/` and only
//! depend on this one; each registers itself and its presets in a [`fusion::Registry`].
//!
//! Training and detection run on the CPU, or with the `cuda` feature on the first GPU
//! ([`default_device`]), with the same code: the CPU's fused nodes (the sparse convolution
//! [`layout::GatherConv`], BatchNorm + ReLU [`bnrelu`]) give way there to candle's operations,
//! and synchronised BatchNorm to the same function built from them. The schedules are sized for
//! two CPU cores: on one H200 a step of batch 2 is bound by kernel launches and host round trips,
//! and trains at about half the CPU's speed (README, "Detectors on two CPU cores").
//!
//! # What changed to converge on two CPU cores, and why
//!
//! Measured first (`hilo bench train`): at 4.2 samples/s a 1,400-sample schedule was a third of
//! an epoch, and the backward pass of the dense backbone over a 128 × 128 grid, most of it empty,
//! was most of every step. So the detector now models only what the scene needs:
//!
//! - **static background removed** ([`train::learn_background`]): the sensors never move, so each
//!   LiDAR's per-beam × azimuth-bin range of the static scene is learned from training frames and
//!   points at or beyond it are dropped (90% of the points). Tested against the background hilo
//!   ray-casts from the static scene: 100.000% of static points removed, 98.7% of road-user
//!   points kept;
//! - **radar static clutter removed** ([`data::RadarClutterConfig`]): a radar detection that
//!   does not move (|v_r| ≤ 0.15 m/s) with no LiDAR foreground point within 1 m is dropped. On
//!   the default dataset about 40% of radar detections are clutter of static structures and
//!   the ground, each an isolated cell that the sparse layout dilates at every level: removing
//!   them takes `lirafusion-like`'s head sites from 3,313 to 1,931 per batch and its speed from
//!   about 58 to 66–71 samples/s, at equal mAP (12,000 samples: 0.729 both). Tested against the
//!   simulation's known sources: 98.3% of clutter dropped, 96.5% of road-user detections kept,
//!   every moving one;
//! - **sparse layout** ([`layout`]): convolutions over occupied cells only (gather–GEMM–scatter
//!   along rulebooks), with a dilated head so box centres between occupied cells are reached;
//!   with the background gone a frame holds a few hundred cells. 4.2 → 70–87 samples/s for
//!   `centerpoint`, ~42 for `lirafusion-like`;
//! - **pillar and point caps sampled by seed** ([`data`]): a frame over the cap keeps a seeded
//!   sample of its cells and points (both LiDARs represented) and counts what it drops, instead of
//!   the first cells in row-major order and the first points in file order;
//! - **radar sweeps**: fusion presets can read the last K radar sweeps with a time-lag feature;
//!   measured at 6,000 class-balanced samples K = 1 (mAP 0.656) was not beaten by K = 3 (0.628) or
//!   K = 5 (0.631) and costs least, so K = 1 is the default;
//! - **ground-truth paste** ([`paste`], on in the default schedule): buses, trucks, golf carts
//!   and motorcycles of the training frames are cut out with their LiDAR and radar points and
//!   pasted, where they stood, into other training frames (filled up to 2, 2, 3 and 2 per frame,
//!   never overlapping a box). The rig never moves, so a pasted instance's points are what the rig
//!   measured at that place. This is what brought the fused preset to its plateau: the large
//!   vehicles it learned last are now in every step (`lirafusion-like`, 18,000 samples: 0.740 →
//!   0.810 mAP on average over four seeds, bus +0.11 and truck +0.08 on seed 0; `centerpoint`,
//!   12,000: 0.744 → 0.760), for 9–21% fewer samples per second;
//! - **class-balanced sampling** ([`train::Sampling::ClassBalanced`], CBGS-like frame resampling)
//!   is an option: it helps short schedules (6,000 samples: 0.683 against 0.644 uniform) and
//!   not long ones (12,000: 0.725 against 0.744), so the presets' default schedule is uniform;
//! - **default schedule** ([`train::TrainConfig::default`]): 12,000 samples in batches of 2,
//!   one-cycle to 6e-3, ground-truth paste; `lirafusion-like` the same over 24,000 samples
//!   with two data-parallel replicas and synchronised BatchNorm ([`presets::plateau_schedule`])
//!   and `centerpoint` over
//!   30,000 ([`presets::centerpoint_schedule`]), what fits five minutes on two cores of ~200
//!   GFLOP/s matrix-product peak (below; both were 18,000 samples with one replica before; a
//!   two-core machine of ~70 GFLOP/s took about ten minutes then, and since the changes below
//!   takes under five: 263.8–292.7 s). Before paste, `centerpoint`'s
//!   curve (1.5k 0.407, 3k 0.476, 6k 0.644, 12k 0.744, 24k 0.751, 48k 0.760) flattened at 12,000, and
//!   `lirafusion-like` stopped short of its plateau at 18,000 (four times longer gained +0.036 on
//!   average over four seeds, mostly the large vehicles); larger batches at higher rates (4 at
//!   1e-2: 0.710, 8 at 2e-2: 0.718), a higher peak rate (1.2e-2: 0.719, 2e-2: 0.721) and dropping
//!   rotation and flip augmentation (rare classes collapse) did not help. With paste and one
//!   replica `lirafusion-like` reaches 0.810 at 18,000 samples (four seeds) and four times
//!   longer gains +0.026, +0.002, +0.048, +0.013 (+0.022 on average): within 0.03 of its
//!   plateau on three seeds of four. `centerpoint` gains more
//!   from paste at long schedules than at short ones (0.778 at 18,000, 0.825 at 48,000): four
//!   times longer gains +0.040, +0.028 and +0.039 on three seeds (+0.036), so with one replica the
//!   LiDAR-only preset stopped short of its (higher) plateau; the study's learning curves say how
//!   far. Pasting more rare instances per frame (bus 3, truck 3, golf cart 4, motorcycle 3)
//!   widens that gap (18,000: 0.791 on average over three seeds; 72,000: 0.831 and 0.824, so
//!   +0.056 and +0.042), so the default fill stays. One training thread runs as fast as two
//!   (`lirafusion-like`, 18,000 samples: 322.3 s against 323.5 s, same weights): candle cannot
//!   split such small operations across cores;
//! - **data-parallel replicas** ([`train::TrainConfig::replicas`], 2 in the schedules of
//!   `centerpoint` and `lirafusion-like`): a batch of two runs as two replicas of one sample,
//!   each forward and backward pass on a core of its own (a one-thread pool, candle on one
//!   thread), their gradients averaged in replica order and the first replica's running
//!   statistics kept, as multi-GPU training does. The weights do not depend on the threads.
//!   1.50× the samples/s of one replica for both presets (66.5 → 99.6 and 65.2 → 97.9 in one
//!   idle bench series; two replicas of one sample cost a fifth to a third more compute than one
//!   batch of two). With BatchNorm over each replica's one sample they cost sample efficiency
//!   (seed 0 at 18,000 samples: 0.792 against 0.815 for `lirafusion-like`, 0.768 against 0.786
//!   for `centerpoint`), so the schedules synchronise it
//!   ([`train::TrainConfig::sync_batch_norm`], [`bnrelu::BatchNormSync`]): the replicas exchange
//!   each BatchNorm layer's per-channel sums in the fused node, forward and backward, and the
//!   step's gradient is the batch of two's (tested against one batch to float rounding). The
//!   barriers cost 4% (`centerpoint`) to 12% (`lirafusion-like`) of the samples/s in the bench
//!   (`lirafusion-like` 24,000 samples in 262.4 s and 272.5 s against 256.0 s and 244.3 s) and
//!   buy +0.03 mAP at the default schedules (0.829 and 0.827
//!   against 0.795 and 0.791; `centerpoint` 0.806 against 0.778 on seed 0). The README has their
//!   learning curves. A study trains its detectors side by side, one core each, so it keeps one
//!   replica;
//! - **fused CPU nodes** ([`layout::GatherConv`], [`bnrelu`]): candle's backward pass gives every
//!   node a zeroed gradient and adds into it, which was 31% of the training thread (perf,
//!   `centerpoint`); the sparse convolution and BatchNorm + ReLU are now one node each on the CPU,
//!   with closed-form gradients tested against candle's operations, and `hilo train` sets
//!   `RAYON_NUM_THREADS` so that candle stops re-reading the CPU topology on every matrix
//!   product. `centerpoint` 55.6 → 71.8 and `lirafusion-like` 43.1 → 56.1 samples/s on a machine
//!   whose matrix-product peak is ~200 GFLOP/s, at unchanged mAP (seed 0, 18,000 samples: 0.786
//!   and 0.815). Later the head's two 3×3 layers share one gather and one matrix product
//!   ([`modules::ConvBn::forward_pair`]) and BatchNorm + ReLU's backward pass runs vectorised:
//!   +15% (`centerpoint`) and +11–15% (`lirafusion-like`) samples/s on a machine of ~70 GFLOP/s.
//!   Then the head's 3×3 layers stopped reading a copy of each parent's row at every head site
//!   below it ([`modules::Neck`], [`layout::parent_conv`]): each block's neck rows are multiplied
//!   by the nine taps' kernels once per parent and each head site sums the products its
//!   neighbours' parents hold, the same function rounded differently, with 26% fewer forward
//!   multiply-adds (`centerpoint` 0.299 → 0.220 GFLOP per step) and 1.16–1.24× the training
//!   speed there. Other devices keep candle's operations;
//! - **the backbone's stride-8 block is its strided convolution alone** ([`presets::centerpoint`],
//!   whose backbone every fusion preset shares): its two further 3×3 layers at 128 channels were
//!   46% of the forward multiply-adds and half the optimizer's work. Without them a step does
//!   0.119 instead of 0.220 GFLOP forward (`centerpoint`) and the default schedules train
//!   1.43× (`centerpoint`, 486.0 → 338.9 s) and 1.35× (`lirafusion-like`, 465.4 → 344.7 s)
//!   faster on a two-core machine of ~70 GFLOP/s, `centerpoint` at mAP within what two runs of
//!   one schedule differ by (0.813 and 0.816 on seeds 0 and 1 against 0.805 and 0.803),
//!   `lirafusion-like` about 0.015 lower at 24,000 samples (0.819 and 0.819 against 0.840 and
//!   0.832) and higher at four times that (0.848 against 0.842); the README has the runs;
//! - **pillar encoders on the real points** ([`modules::PillarNet::encode`], the `early`
//!   plugin's joint encoder, [`bnrelu::bn_relu_padded`]): a pillar has 10 point slots and a
//!   roadside pillar fills about three of them, yet the per-point layers, the mask and the reductions
//!   ran on every slot. They now run on the real points ([`modules::PillarTensors::points`]),
//!   BatchNorm counting the padding slots as the zero rows they are in the padded form (in
//!   closed form, Chan's update), so the function is the padded one (tested against it:
//!   outputs, running statistics and every gradient). 1.06× (`centerpoint`) and 1.2×
//!   (`lirafusion-like`, whose pillar net + fusion went from 6.5 to 2.1 ms a step) the bench's
//!   samples/s;
//! - **the batch thread at idle priority** ([`train::train`]): training ran below the bench
//!   because the thread that prepares the next batch took a core from a replica, and the other
//!   replica waited for it at the next synchronised BatchNorm. On Linux it now runs in the idle
//!   scheduling class, on what the step leaves idle (the weights are the same to the byte):
//!   1.08× (`centerpoint`) and 1.06× (`lirafusion-like`). With both, the default schedules
//!   train in 263.8–292.7 s on two cores of ~70 GFLOP/s (seeds 0–2), under five minutes,
//!   and four times the schedule gains +0.020, +0.028 and +0.008 mAP (`centerpoint`, seeds
//!   0–2, mean +0.019) and +0.034, +0.023 and +0.015 (`lirafusion-like`, mean +0.024): both
//!   presets within the 0.03 plateau bar on the three-seed mean, one pair of six above it;
//! - **per-class loss normalisation** ([`detector::LossNorm`], an option, not adopted): each
//!   class's heatmap and regression losses divided by its own positives and the classes
//!   averaged, as CenterPoint's per-task heads do. On `centerpoint` four times its default
//!   schedule then gains +0.016 (seed 0; +0.040 and +0.031 with one normaliser), but because
//!   the plateau is lower (0.832 against 0.847 at 120,000 samples): at the default schedule the
//!   mAP is unchanged (0.816 and 0.806 against 0.806 and 0.810) and pedestrian AP falls by
//!   0.02–0.03, so every preset keeps one normaliser;
//! - **operators fixed**: `GatedChannel` gates each channel (it computed one scalar per
//!   modality), and seeded initialisation no longer overrides the weighted operator's α = 0.5.

pub mod bnrelu;
pub mod conformance;
pub mod conv;
pub mod data;
pub mod decode;
pub mod detector;
pub mod error;
pub mod fuse;
pub mod fusion;
pub mod grid;
pub mod infer;
pub mod layout;
pub mod loss;
pub mod modules;
pub mod paste;
pub mod presets;
pub mod targets;
pub mod train;

pub use detector::{Detector, DetectorConfig};
pub use error::{FusionError, Result};
pub use fusion::{Fusion, FusionInput, FusionOutput, Preset, Registry, Stage};

/// Where training and detection run: the first CUDA GPU when hilo is built with the `cuda`
/// feature and one is present, the CPU otherwise. The code is the same on both.
pub fn default_device() -> candle_core::Device {
    #[cfg(feature = "cuda")]
    if let Ok(d) = candle_core::Device::new_cuda(0) {
        return d;
    }
    candle_core::Device::Cpu
}
