//! What a hilo fusion plugin is written against: the [`Fusion`] trait and its input and output
//! ([`fusion`]), the [`Registry`] a plugin adds itself and its presets to, the plain configs a
//! preset is made of ([`config`], and the LiDAR-only presets plugins build on, [`presets`]),
//! and the building blocks on Candle: the BEV grid ([`grid`]), pillars ([`pillars`]), the dense
//! and sparse layouts and their convolutions ([`layout`], [`conv`]), BatchNorm + ReLU
//! ([`bnrelu`]), the shared modules (pillar feature net, backbone and neck, heads: [`modules`])
//! and fuse operators ([`fuse`]).
//!
//! The detector runtime, data loading, training, inference and the conformance suite every
//! plugin passes live in the `hilo-detector` crate, on top of this one. A plugin crate depends
//! on this crate only.
//!
//! Convolutions run on one of two layouts: dense maps over the whole grid (on the CPU an
//! im2col matrix product with hilo's own custom ops; candle's conv2d on other devices), or only
//! the occupied cells, as gather–GEMM convolutions along rulebooks built on the host.
//!
//! # Start here
//!
//! A plugin implements [`Fusion`] (one required method, `forward`), is built from its own
//! config type (read by serde from the detector config) and a `VarBuilder`
//! ([`fusion::Builder`]), and registers itself, its presets and
//! its ablations with [`Registry::register`], [`Registry::add_preset`] and
//! [`Registry::add_ablation`].

pub mod bnrelu;
pub mod config;
pub mod conv;
pub mod cpu;
pub mod error;
pub mod fuse;
pub mod fusion;
pub mod grid;
pub mod layout;
pub mod limits;
pub mod modules;
pub mod pillars;
pub mod presets;

pub use config::{DetectorConfig, Preset, TrainConfig};
pub use error::{FusionError, Result};
pub use fusion::{Fusion, FusionInput, FusionOutput, Registry, Stage};
