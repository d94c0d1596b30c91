//! The study file (`fixtures/study.toml`): scene, catalog, placement settings, configurations.

use anyhow::{Context, Result, bail};
use hilo_placement_ip::pipeline::PlacementConfig;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const DEFAULT_STUDY_TOML: &str = include_str!("../../../fixtures/study.toml");

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyFile {
    #[serde(default)]
    pub scene: Option<PathBuf>,
    #[serde(default)]
    pub catalog: Option<PathBuf>,
    #[serde(default)]
    pub placement: PlacementConfig,
    /// Traffic and recording settings for `hilo simulate`.
    #[serde(default)]
    pub dataset: hilo_dataset::simulate::SimulateConfig,
    pub configurations: Vec<Configuration>,
}

/// One sensor configuration to place.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Configuration {
    pub name: String,
    /// Fixed counts per sensor type.
    #[serde(default)]
    pub sensors: BTreeMap<String, u32>,
    /// A budget over `types` instead of fixed counts.
    #[serde(default)]
    pub budget_usd: Option<f64>,
    #[serde(default)]
    pub types: Vec<String>,
    #[serde(default)]
    pub min: BTreeMap<String, u32>,
    #[serde(default)]
    pub max: BTreeMap<String, u32>,
}

impl Configuration {
    /// The sensor types this configuration may use.
    pub fn type_names(&self) -> Vec<String> {
        if self.budget_usd.is_some() { self.types.clone() } else { self.sensors.keys().cloned().collect() }
    }

    /// A file-name-safe form of the name.
    pub fn slug(&self) -> String {
        let s: String =
            self.name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
        s.split('_').filter(|p| !p.is_empty()).collect::<Vec<_>>().join("_")
    }
}

/// A loaded study: the file, and the folder its relative paths are resolved against.
#[derive(Clone, Debug)]
pub struct Study {
    pub file: StudyFile,
    pub dir: PathBuf,
    pub source: String,
}

impl Study {
    pub fn load(path: Option<&Path>) -> Result<Self> {
        let (text, dir, source) = match path {
            Some(p) => (
                std::fs::read_to_string(p).with_context(|| format!("reading study {}", p.display()))?,
                p.parent().map(Path::to_path_buf).unwrap_or_default(),
                p.display().to_string(),
            ),
            None => (DEFAULT_STUDY_TOML.to_owned(), PathBuf::from("."), "<embedded>/fixtures/study.toml".to_owned()),
        };
        let file: StudyFile = toml::from_str(&text).with_context(|| format!("{source}: invalid study"))?;
        if file.configurations.is_empty() {
            bail!("{source}: no [[configurations]]");
        }
        let mut names = std::collections::HashSet::new();
        for (i, c) in file.configurations.iter().enumerate() {
            if !names.insert(c.slug()) {
                bail!("{source}: configurations[{i}].name = {:?} repeats another configuration's name", c.name);
            }
            match (c.budget_usd, c.sensors.is_empty()) {
                (Some(b), true) if b.is_finite() && b > 0.0 && !c.types.is_empty() => {}
                (Some(b), true) => bail!(
                    "{source}: configurations[{i}] ({}): budget_usd = {b} needs a positive budget and a `types` list",
                    c.name
                ),
                (None, false) => {}
                _ => bail!(
                    "{source}: configurations[{i}] ({}): give either `sensors` or `budget_usd` with `types`",
                    c.name
                ),
            }
        }
        Ok(Study { file, dir, source })
    }

    /// Every sensor type any configuration names, sorted, once each.
    pub fn type_names(&self) -> Vec<String> {
        let mut all: Vec<String> = self.file.configurations.iter().flat_map(|c| c.type_names()).collect();
        all.sort();
        all.dedup();
        all
    }

    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() { p.to_path_buf() } else { self.dir.join(p) }
    }
}
