//! hilo's detector framework on Candle: the [`fusion::Fusion`] trait and its registry, shared
//! detector modules ([`modules`]: pillar feature net, BEV backbone and neck, heads), targets
//! and losses, decoding, the LiDAR-only presets `centerpoint` and `pointpillars`
//! ([`detector::preset`]), training on CPU ([`train`]) and inference to the nuScenes
//! submission format ([`infer`]). Convolutions go through [`conv`]: on the CPU an im2col
//! matrix product with its own custom ops (candle's CPU conv2d was most of a training step),
//! candle's conv2d on other devices.
//!
//! Fusion plugins (raw, early, middle, late) live in their own crates under `plugins/` and only
//! depend on this one; they register themselves in a [`fusion::Registry`].

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
pub mod loss;
pub mod modules;
pub mod targets;
pub mod train;

pub use detector::{Detector, DetectorConfig, preset};
pub use error::{FusionError, Result};
pub use fusion::{Fusion, FusionInput, FusionOutput, Registry, Stage};
