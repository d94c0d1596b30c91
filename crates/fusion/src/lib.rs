//! hilo's detector framework on Candle: the [`fusion::Fusion`] trait, its registry of plugins
//! and presets, shared detector modules ([`modules`]: pillar feature net, BEV backbone and neck,
//! heads), targets and losses, decoding, the LiDAR-only presets `centerpoint` and
//! `pointpillars` ([`presets`]), training ([`train`]) and inference ([`infer`]).
//!
//! Convolutions run on one of two layouts ([`layout`]): dense maps over the whole grid (on the
//! CPU an im2col matrix product with hilo's own custom ops, [`conv`]; candle's conv2d on other
//! devices), or only the occupied cells, as gather–GEMM convolutions along rulebooks built on
//! the host. What the network reads is part of the detector ([`data::InputConfig`]): LiDAR
//! without its static background ([`train::learn_background`]), radar without its static
//! clutter ([`data::RadarClutterConfig`]), and the radar's last sweeps.
//!
//! Fusion plugins (raw, early, middle, late) live in their own crates under `plugins/` and only
//! depend on this one; each registers itself and its presets in a [`fusion::Registry`], and
//! [`conformance`] is the suite every plugin passes.
//!
//! Training and detection run on the CPU, or with the `cuda` feature on the first GPU
//! ([`default_device`]), with the same code: the CPU's fused nodes (the sparse convolution
//! [`layout::GatherConv`], BatchNorm + ReLU [`bnrelu`]) give way there to candle's operations.
//! The schedules ([`presets`], [`train::TrainConfig`]) are sized for two CPU cores: the default
//! ones train in under five minutes there, close to their plateau. Why each design choice was
//! made, with its measurements, is in the repository's `docs/measurements.md`.
//!
//! # Start here
//!
//! A plugin implements [`Fusion`] (one required method, `forward`), is built from its JSON
//! config and a `VarBuilder`, and registers itself and its presets with
//! [`Registry::register`] and [`Registry::add_preset`]; [`train::train`] trains any preset
//! and [`infer::detect_frames`] runs it.

pub mod bnrelu;
pub mod conformance;
pub mod conv;
pub mod cpu;
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
