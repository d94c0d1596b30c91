//! hilo's detector runtime on Candle, on top of the fusion plugins' crate (`hilo-fusion`): a
//! [`Detector`] is a fusion stage from the registry, the shared BEV backbone and a head
//! ([`detector`]); frames are loaded from a dataset and augmented ([`data`], [`paste`]);
//! targets, losses and decoding ([`targets`], [`loss`], [`decode`]); training with
//! checkpoints and exact resume ([`train`]); inference ([`infer`]), with the boxes' velocity
//! read from the radar's Doppler where the detector asks for it ([`doppler`]); and
//! [`conformance`], the suite every plugin passes.
//!
//! What the network reads is part of the detector (`InputConfig`): LiDAR without its static
//! background ([`train::learn_background`]), radar without its static clutter, and the radar's
//! last sweeps. Training and detection run on the CPU, or with the `cuda` feature on the first
//! GPU ([`default_device`]), with the same code: the CPU's fused nodes (the sparse gather
//! convolution, BatchNorm + ReLU) give way there to candle's operations. The default schedules
//! are sized for two CPU cores; how they were chosen, with the measurements, is in the
//! repository's `docs/measurements.md`.
//!
//! The fusion crate's modules are re-exported here, so that `hilo_detector::grid` and
//! `hilo_fusion::grid` name the same thing. A road user whose velocity is unknown (no
//! annotation of it before or after the frame) trains its box and not its velocity
//! ([`targets::Targets::vel_mask`]), as the devkit leaves it out of AVE.

pub mod conformance;
pub mod data;
pub mod decode;
pub mod detector;
pub mod doppler;
pub mod error;
pub mod infer;
pub mod loss;
pub mod paste;
pub mod targets;
pub mod train;

pub use detector::Detector;
pub use error::{DetectorError, Result};
pub use hilo_fusion::{
    DetectorConfig, Fusion, FusionError, FusionInput, FusionOutput, Preset, Registry, Stage, TrainConfig,
};
pub use hilo_fusion::{bnrelu, config, conv, cpu, fuse, fusion, grid, layout, modules, pillars, presets};

/// Where training and detection run: the first CUDA GPU when hilo is built with the `cuda`
/// feature and one is present, the CPU otherwise. The code is the same on both.
pub fn default_device() -> candle_core::Device {
    #[cfg(feature = "cuda")]
    if let Ok(d) = candle_core::Device::new_cuda(0) {
        return d;
    }
    candle_core::Device::Cpu
}
