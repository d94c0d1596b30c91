//! The `Fusion` trait and its registry.
//!
//! A fusion plugin turns a batch's LiDAR and radar pillars into what the shared head reads: a
//! BEV feature map `(B, C, H, W)` for the raw, early and middle stages, or boxes for the late
//! stage. Plugins are built by name from a serde (JSON) config and a candle `VarBuilder`;
//! registering a name twice is an error, and asking for an unknown name lists the known ones.

use crate::error::{FusionError, Result};
use crate::grid::BevGrid;
use crate::modules::{PillarNet, PillarTensors};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Where in the detector the modalities meet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Points of both modalities, encoded per modality, unioned before the shared pillars.
    Raw,
    /// A joint voxel/pillar encoding of mixed features.
    Early,
    /// Per-modality BEV maps fused by a learned operator.
    Middle,
    /// Per-modality detectors whose boxes are merged.
    Late,
}

/// A batch as the fusion stage sees it.
#[derive(Debug)]
pub struct FusionInput<'a> {
    pub lidar: &'a PillarTensors,
    pub radar: &'a PillarTensors,
    pub batch: usize,
    pub grid: BevGrid,
}

/// What a fusion stage produces.
#[derive(Debug)]
pub enum FusionOutput {
    /// (B, C, H, W) on the pillar grid, for the shared backbone and head.
    Bev(Tensor),
    /// Late fusion: complete per-modality detectors' head outputs (class logits, regression),
    /// each on the head's grid; the detector trains each against the same targets and merges
    /// their boxes (see [`crate::decode::merge_late`]).
    Heads(Vec<(Tensor, Tensor)>),
}

pub trait Fusion: Send + Sync + std::fmt::Debug {
    fn stage(&self) -> Stage;
    /// Channels of the BEV map.
    fn out_channels(&self) -> usize;
    /// Whether the plugin reads radar (LiDAR-only detectors never see it).
    fn uses_radar(&self) -> bool;
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput>;
}

/// A plugin's typed config from its JSON; the error names the plugin, the field and the JSON.
pub fn parse_config<T: serde::de::DeserializeOwned>(plugin: &str, cfg: &serde_json::Value) -> Result<T> {
    serde_json::from_value(cfg.clone())
        .map_err(|e| FusionError::Config(format!("fusion plugin {plugin:?}: {e} in {cfg}")))
}

/// Builds a plugin from its JSON config on a grid.
pub type Builder = fn(&serde_json::Value, &BevGrid, VarBuilder) -> Result<Box<dyn Fusion>>;

/// Plugins by name.
#[derive(Clone, Debug, Default)]
pub struct Registry {
    builders: BTreeMap<String, Builder>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Registry::default()
    }

    /// The plugins of this crate (`lidar`).
    pub fn with_builtin() -> Self {
        let mut r = Registry::new();
        // A fresh registry cannot hold the name yet.
        let _ = r.register("lidar", build_lidar_only);
        r
    }

    pub fn register(&mut self, name: &str, builder: Builder) -> Result<()> {
        if self.builders.contains_key(name) {
            return Err(FusionError::Config(format!("fusion plugin {name:?} is registered twice")));
        }
        self.builders.insert(name.to_owned(), builder);
        Ok(())
    }

    pub fn names(&self) -> Vec<String> {
        self.builders.keys().cloned().collect()
    }

    pub fn build(
        &self,
        name: &str,
        cfg: &serde_json::Value,
        grid: &BevGrid,
        vb: VarBuilder,
    ) -> Result<Box<dyn Fusion>> {
        match self.builders.get(name) {
            Some(b) => b(cfg, grid, vb),
            None => {
                Err(FusionError::Config(format!("unknown fusion plugin {name:?}; known: {}", self.names().join(", "))))
            }
        }
    }
}

/// The LiDAR-only "fusion": PointPillars' pillar feature net on LiDAR pillars.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarOnlyConfig {
    pub channels: usize,
}

#[derive(Debug)]
pub struct LidarOnly {
    net: PillarNet,
    cells: usize,
}

fn build_lidar_only(cfg: &serde_json::Value, grid: &BevGrid, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    let c: LidarOnlyConfig = parse_config("lidar", cfg)?;
    let net = PillarNet::new(crate::data::LIDAR_FEATURES + 5, c.channels, vb.pp("lidar_pfn"))?;
    Ok(Box::new(LidarOnly { net, cells: grid.cells() }))
}

impl Fusion for LidarOnly {
    fn stage(&self) -> Stage {
        Stage::Raw
    }
    fn out_channels(&self) -> usize {
        self.net.channels
    }
    fn uses_radar(&self) -> bool {
        false
    }
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        Ok(FusionOutput::Bev(self.net.forward(input.lidar, input.batch, self.cells, train)?))
    }
}
