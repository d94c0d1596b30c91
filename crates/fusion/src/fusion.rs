//! The `Fusion` trait, its registry, and the presets plugins register.
//!
//! A fusion plugin turns a batch's LiDAR and radar pillars into what the shared backbone and
//! head read: a BEV feature map for the raw, early and middle stages, or complete per-modality
//! head outputs for the late stage. Its contract has one required method, [`Fusion::forward`],
//! as candle's `Module` has; everything else the framework needs is derived (the channels of its
//! map, by one forward pass on a probe batch when the detector is built) or has a default.
//!
//! A plugin crate exports one registration function that adds its plugin (a name, its stage,
//! and a builder from its typed config and a `VarBuilder`) and the presets that use it
//! (a preset names the plugin, its config and the rest of the detector, and its training
//! schedule). Registering a name twice is an error; asking for an unknown name lists the known.

use crate::config::{DetectorConfig, Preset};
use crate::error::{FusionError, Result};
use crate::grid::BevGrid;
use crate::layout::Layout;
use crate::modules::{PillarNet, PillarTensors};
use candle_core::Tensor;
use candle_nn::VarBuilder;
use hilo_core::Detection;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Where in the detector the modalities meet (reported with results; the framework itself only
/// distinguishes a map from per-modality heads by what `forward` returns).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// LiDAR only: no fusion.
    None,
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
    /// Where the BEV features live: scatter pillars with [`PillarNet::forward`] (or
    /// [`Layout::zeros`] and [`Layout::from_rows`]); apply modules at [`Layout::level0`].
    pub layout: &'a Layout,
}

/// What a fusion stage produces.
#[derive(Debug)]
pub enum FusionOutput {
    /// The pillar-grid map (`(B, C, H, W)` dense, `(N_0, C)` sparse) for the shared backbone
    /// and head.
    Bev(Tensor),
    /// Late fusion: complete per-modality detectors' head outputs (class logits, regression) at
    /// the head's resolution; each is trained against the same targets, and their boxes are
    /// merged by [`Fusion::merge`]. Each head has one class channel per class of
    /// [`crate::DetectorConfig::classes`]: a plugin of [`Stage::Late`] reads their number from
    /// its config's `classes` field, which the detector sets when it is not the paper's six.
    Heads(Vec<(Tensor, Tensor)>),
}

/// A fusion plugin.
///
/// # Examples
///
/// LiDAR and radar BEV maps, added (a middle-stage plugin in a dozen lines):
///
/// ```
/// use hilo_fusion::{Fusion, FusionInput, FusionOutput, Result, modules::PillarNet};
///
/// #[derive(Debug)]
/// struct Sum { l: PillarNet, r: PillarNet }
///
/// impl Fusion for Sum {
///     fn forward(&self, x: &FusionInput, train: bool) -> Result<FusionOutput> {
///         let l = self.l.forward(x.lidar, x.layout, train)?;
///         let r = self.r.forward(x.radar, x.layout, train)?;
///         Ok(FusionOutput::Bev((l + r)?))
///     }
/// }
/// ```
pub trait Fusion: Send + Sync + std::fmt::Debug {
    /// Fuses a batch: the pillar-grid map, or per-modality head outputs (late fusion).
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput>;

    /// Whether the plugin reads radar (a LiDAR-only detector never loads it). Default: true.
    fn uses_radar(&self) -> bool {
        true
    }

    /// Merges the boxes decoded from each of `forward`'s heads for one frame, keeping at most
    /// `max` (late fusion's Ψ). Default: the first head's boxes.
    fn merge(&self, heads: Vec<Vec<Detection>>, max: usize) -> Vec<Detection> {
        let mut first = heads.into_iter().next().unwrap_or_default();
        first.truncate(max);
        first
    }
}

/// A plugin's typed config from its JSON; the error names the plugin, the field and the JSON.
pub fn parse_config<T: serde::de::DeserializeOwned>(plugin: &str, cfg: &serde_json::Value) -> Result<T> {
    serde_json::from_value(cfg.clone())
        .map_err(|e| FusionError::Config(format!("fusion plugin {plugin:?}: {e} in {cfg}")))
}

/// Builds a plugin from its config `C` (read from a detector config's `fusion_config` by serde,
/// a missing or unknown field named in the error) and the variables its weights live in. The
/// grid arrives with every batch ([`FusionInput::grid`]).
pub type Builder<C> = fn(C, VarBuilder) -> Result<Box<dyn Fusion>>;

/// A builder with its config's type erased: it parses the JSON itself.
type AnyBuilder = std::sync::Arc<dyn Fn(&serde_json::Value, VarBuilder) -> Result<Box<dyn Fusion>> + Send + Sync>;

/// A registered plugin.
#[derive(Clone)]
pub struct Plugin {
    pub stage: Stage,
    build: AnyBuilder,
}

impl std::fmt::Debug for Plugin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Plugin").field("stage", &self.stage).finish_non_exhaustive()
    }
}

/// Plugins and presets by name.
#[derive(Clone, Debug, Default)]
pub struct Registry {
    plugins: BTreeMap<String, Plugin>,
    /// In registration order.
    presets: Vec<Preset>,
    /// Ablation preset → the preset it ablates.
    ablations: BTreeMap<String, String>,
    /// The fusion preset a study tests by default ([`Registry::set_primary`]).
    primary: Option<String>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Registry::default()
    }

    /// This crate's plugin (`lidar`) and presets (`centerpoint`, `pointpillars`).
    pub fn with_builtin() -> Self {
        let mut r = Registry::new();
        // A fresh registry holds none of these names yet.
        let _ = r.register("lidar", Stage::None, build_lidar_only);
        for p in crate::presets::lidar_only() {
            let _ = r.add_preset(p);
        }
        r
    }

    /// Adds a plugin: its name, its stage and its builder, which takes the plugin's own config
    /// type `C`.
    pub fn register<C: serde::de::DeserializeOwned + 'static>(
        &mut self,
        name: &str,
        stage: Stage,
        build: Builder<C>,
    ) -> Result<()> {
        if self.plugins.contains_key(name) {
            return Err(FusionError::Config(format!("fusion plugin {name:?} is registered twice")));
        }
        let plugin = name.to_owned();
        let build: AnyBuilder =
            std::sync::Arc::new(move |cfg: &serde_json::Value, vb: VarBuilder| build(parse_config(&plugin, cfg)?, vb));
        self.plugins.insert(name.to_owned(), Plugin { stage, build });
        Ok(())
    }

    /// Adds a preset; its plugin must be registered, and its config must build.
    pub fn add_preset(&mut self, p: Preset) -> Result<()> {
        let name = &p.detector.name;
        if self.presets.iter().any(|q| q.detector.name == *name) {
            return Err(FusionError::Config(format!("preset {name:?} is registered twice")));
        }
        if !self.plugins.contains_key(&p.detector.fusion) {
            return Err(FusionError::Config(format!(
                "preset {name:?} names fusion plugin {:?}, which is not registered; known: {}",
                p.detector.fusion,
                self.names().join(", ")
            )));
        }
        self.presets.push(p);
        Ok(())
    }

    /// Adds an ablation: a preset that removes a part of the preset `of` (registered
    /// before), declared by the plugin that knows what the part is. Studies train ablations on
    /// one rig only, against the preset they ablate.
    pub fn add_ablation(&mut self, of: &str, p: Preset) -> Result<()> {
        self.preset(of)?;
        let name = p.detector.name.clone();
        self.add_preset(p)?;
        self.ablations.insert(name, of.to_owned());
        Ok(())
    }

    /// The preset an ablation ablates (`None` for a preset that is not an ablation).
    pub fn ablation_of(&self, name: &str) -> Option<&str> {
        self.ablations.get(name).map(String::as_str)
    }

    /// The ablations of a preset, in name order.
    pub fn ablations_of(&self, of: &str) -> Vec<String> {
        self.ablations.iter().filter(|(_, base)| base.as_str() == of).map(|(a, _)| a.clone()).collect()
    }

    /// Every ablation's name, in name order.
    pub fn ablation_names(&self) -> Vec<String> {
        self.ablations.keys().cloned().collect()
    }

    /// The presets that are not ablations, in registration order.
    pub fn detector_names(&self) -> Vec<String> {
        self.presets.iter().map(|p| p.detector.name.clone()).filter(|n| !self.ablations.contains_key(n)).collect()
    }

    /// Plugin names.
    pub fn names(&self) -> Vec<String> {
        self.plugins.keys().cloned().collect()
    }

    /// Preset names, in registration order.
    pub fn preset_names(&self) -> Vec<String> {
        self.presets.iter().map(|p| p.detector.name.clone()).collect()
    }

    /// A preset's LiDAR-only counterpart: the first registered LiDAR-only preset (not an
    /// ablation) with the same head (target assignment and channels) at the same output stride,
    /// so that the two differ by the radar and its fusion alone. `None` for a LiDAR-only preset,
    /// an unknown name, or a head no LiDAR-only preset shares.
    pub fn lidar_counterpart(&self, preset: &str) -> Option<&str> {
        let f = &self.preset(preset).ok()?.detector;
        if !self.uses_radar(f) {
            return None;
        }
        self.presets
            .iter()
            .map(|p| &p.detector)
            .filter(|l| !self.uses_radar(l) && !self.ablations.contains_key(&l.name))
            .find(|l| {
                l.assignment == f.assignment
                    && l.head_channels == f.head_channels
                    && l.backbone.out_stride == f.backbone.out_stride
            })
            .map(|l| l.name.as_str())
    }

    /// Names the fusion preset a study tests by default (its "fusion detector"): a registered
    /// preset, not an ablation, that reads radar and has a LiDAR-only counterpart.
    pub fn set_primary(&mut self, preset: &str) -> Result<()> {
        if self.ablations.contains_key(preset) || self.lidar_counterpart(preset).is_none() {
            return Err(FusionError::Config(format!(
                "primary preset {preset:?}: give a registered fusion preset (not an ablation) with a LiDAR-only \
                 counterpart; known: {}",
                self.preset_names().join(", ")
            )));
        }
        self.primary = Some(preset.to_owned());
        Ok(())
    }

    /// The fusion preset a study tests by default and its LiDAR-only counterpart: the one
    /// [`Registry::set_primary`] named, else the first registered fusion preset that has a
    /// counterpart. `None` where no fusion preset has one.
    pub fn primary(&self) -> Option<(&str, &str)> {
        let named = self.primary.as_deref().into_iter();
        let fusion = named
            .chain(self.presets.iter().map(|p| p.detector.name.as_str()))
            .find(|p| !self.ablations.contains_key(*p) && self.lidar_counterpart(p).is_some())?;
        Some((fusion, self.lidar_counterpart(fusion)?))
    }

    /// A preset by name.
    pub fn preset(&self, name: &str) -> Result<&Preset> {
        self.presets.iter().find(|p| p.detector.name == name).ok_or_else(|| {
            FusionError::Config(format!("unknown detector {name:?}; known: {}", self.preset_names().join(", ")))
        })
    }

    /// The stage of a registered plugin.
    pub fn stage(&self, plugin: &str) -> Option<Stage> {
        self.plugins.get(plugin).map(|p| p.stage)
    }

    /// Whether a detector reads radar: every plugin but the LiDAR-only one does.
    pub fn uses_radar(&self, cfg: &DetectorConfig) -> bool {
        self.stage(&cfg.fusion).is_some_and(|s| s != Stage::None)
    }

    /// Builds the plugin `name` from its JSON config (a detector config's `fusion_config`).
    pub fn build(&self, name: &str, cfg: &serde_json::Value, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
        match self.plugins.get(name) {
            Some(p) => (p.build)(cfg, vb),
            None => {
                Err(FusionError::Config(format!("unknown fusion plugin {name:?}; known: {}", self.names().join(", "))))
            }
        }
    }
}

/// The LiDAR-only "fusion": PointPillars' pillar feature net on LiDAR pillars.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LidarOnlyConfig {
    pub channels: usize,
}

impl Default for LidarOnlyConfig {
    fn default() -> Self {
        LidarOnlyConfig { channels: 32 }
    }
}

#[derive(Debug)]
pub struct LidarOnly {
    net: PillarNet,
}

fn build_lidar_only(c: LidarOnlyConfig, vb: VarBuilder) -> Result<Box<dyn Fusion>> {
    let net = PillarNet::new(crate::config::LIDAR_PILLAR_WIDTH, c.channels, vb.pp("lidar_pfn"))?;
    Ok(Box::new(LidarOnly { net }))
}

impl Fusion for LidarOnly {
    fn forward(&self, input: &FusionInput, train: bool) -> Result<FusionOutput> {
        Ok(FusionOutput::Bev(self.net.forward(input.lidar, input.layout, train)?))
    }
    fn uses_radar(&self) -> bool {
        false
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn named(name: &str) -> Preset {
        let mut p = crate::presets::lidar_only().remove(0);
        p.detector.name = name.into();
        p
    }

    #[test]
    fn ablations_name_the_preset_they_ablate_and_are_kept_apart() {
        let mut r = Registry::with_builtin();
        r.add_ablation("centerpoint", named("centerpoint-thin")).unwrap();
        assert_eq!(r.ablation_of("centerpoint-thin"), Some("centerpoint"));
        assert_eq!(r.ablation_of("centerpoint"), None);
        assert_eq!(r.ablations_of("centerpoint"), vec!["centerpoint-thin".to_string()]);
        assert_eq!(r.detector_names(), vec!["centerpoint".to_string(), "pointpillars".to_string()]);
        assert!(r.preset_names().contains(&"centerpoint-thin".to_string()));
        // An ablation of a preset nobody registered, or a name taken, is refused.
        let e = r.add_ablation("no-such", named("x")).unwrap_err().to_string();
        assert!(e.contains("no-such"), "{e}");
        assert!(r.add_ablation("centerpoint", named("pointpillars")).is_err());
        assert_eq!(r.ablation_names(), vec!["centerpoint-thin".to_string()]);
    }
}
