//! The study file (`fixtures/study.toml` is the default): the scene and sensor catalog, the
//! placement settings, the dataset settings, and the sensor configurations to compare.

use crate::error::{Result, StudyError};
use crate::files::hash;
use hilo_core::{FieldError, Valid};
use hilo_dataset::simulate::SimulateConfig;
use hilo_placement_ip::pipeline::PlacementConfig;
use hilo_raycast::Scene;
use hilo_sensor_models::spec::EMBEDDED_CATALOGS;
use hilo_sensor_models::{Catalog, SensorSpec};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyFile {
    /// Scene TOML (relative to the study file); the embedded default intersection when absent.
    #[serde(default)]
    pub scene: Option<PathBuf>,
    /// Sensor catalog TOML; the embedded default (the paper's Table I) when absent.
    #[serde(default)]
    pub catalog: Option<PathBuf>,
    #[serde(default)]
    pub placement: PlacementConfig,
    /// Traffic and recording settings of the datasets.
    #[serde(default)]
    pub dataset: SimulateConfig,
    /// How the verdict judges the claims.
    #[serde(default)]
    pub verdict: VerdictSettings,
    /// The placement set of `hilo validate` (the study's own stages do not read it).
    #[serde(default)]
    pub validation: ValidationSettings,
    /// Where each class is scored, and the report's range bins.
    #[serde(default)]
    pub evaluation: EvaluationSettings,
    pub configurations: Vec<Configuration>,
    /// Adverse conditions: configurations recorded again in another weather (`[[conditions]]`).
    #[serde(default)]
    pub conditions: Vec<Condition>,
    /// Changes to every detector the study trains (`[detector_patch]`): a JSON merge patch over
    /// each preset's detector config, as `hilo train --detector-patch` applies it (e.g. ten LiDAR
    /// sweeps and a heavier velocity loss, on datasets recorded with `[dataset] lidar_sweeps =
    /// true`). It may not change a preset's name or fusion plugin. None: the presets as they are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector_patch: Option<serde_json::Value>,
    /// Changes to every detector's training schedule (`[train_schedule]`): fields of `run.json`'s
    /// `train` over each preset's schedule, as `hilo train --train-config` takes them (a GPU's
    /// `batch = 16` and `lr_max = 0.012`, say). Fields named here win over the profile's sample
    /// count and sampling; the study sets the seeds, the kept checkpoints and one replica per
    /// training itself, so `seed`, `keep`, `replicas` and `sync_batch_norm` are refused. None:
    /// the presets' schedules.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_schedule: Option<serde_json::Value>,
    /// Which junction of an OpenDRIVE scene (`scene = "town.xodr"`) to study (`[junction]`: `id
    /// = "146"`, or `near = [x, y]` with `radius_m`); refused for a scene that is not OpenDRIVE.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub junction: Option<hilo_raycast::scene::opendrive::JunctionPick>,
    /// A calibrated objective fitted across junctions (`calibration.toml`, as `hilo validate
    /// --sites` writes it; hilo ships one in `fixtures/`): placement maximises it, and each
    /// placement gets its predicted mAP and how far the junction lies from the sites it was
    /// fitted on. Refused beside `[placement] calibration`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_file: Option<PathBuf>,
}

/// A weather condition of the study (`[[conditions]]`): the named configurations recorded again,
/// at the same poses and with the same traffic, in this weather, and the study's detectors
/// trained on them, so that the verdict judges the radar's claims and prices the radar per
/// condition. The configurations keep the study's own `[dataset.weather]` (clear by default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Condition {
    pub name: String,
    pub weather: hilo_sensor_models::Weather,
    /// The study's configurations recorded in this weather, by name.
    pub configurations: Vec<String>,
}

impl Condition {
    /// The name of configuration `base` recorded in this condition.
    pub fn label(&self, base: &str) -> String {
        format!("{base} in {}", self.name)
    }

    /// A named weather, configurations that exist, once each, and names that stay apart from
    /// the configurations' file names; the error names the field and value.
    fn check(&self, i: usize, file: &StudyFile) -> std::result::Result<(), FieldError> {
        let at = |field: &str, value: &dyn std::fmt::Display, reason: String| {
            FieldError::new(format!("conditions[{i}].{field}"), value, format!("{reason} (condition {:?})", self.name))
        };
        if slug(&self.name).is_empty() {
            return Err(FieldError::new(
                format!("conditions[{i}].name"),
                format!("{:?}", self.name),
                "has no ASCII letter or digit",
            ));
        }
        self.weather.check().map_err(|e| at(&format!("weather.{}", e.field), &e.value, e.reason.to_owned()))?;
        if self.weather == file.dataset.weather {
            return Err(at(
                "weather",
                &self.weather,
                "this is the study's own `[dataset.weather]`; nothing would change".into(),
            ));
        }
        if self.configurations.is_empty() {
            return Err(at("configurations", &"[]", "name the configurations to record in this weather".into()));
        }
        for (k, name) in self.configurations.iter().enumerate() {
            let field = format!("configurations[{k}]");
            let value = format!("{name:?}");
            if !file.configurations.iter().any(|c| c.name == *name) {
                let names: Vec<&str> = file.configurations.iter().map(|c| c.name.as_str()).collect();
                return Err(at(&field, &value, format!("is not a configuration of the study ({names:?})")));
            }
            if self.configurations[..k].contains(name) {
                return Err(at(&field, &value, "is named twice".into()));
            }
            let label = slug(&self.label(name));
            if let Some(c) = file.configurations.iter().find(|c| c.slug() == label) {
                return Err(at(
                    &field,
                    &value,
                    format!(
                        "in this condition becomes the file name {label:?}, as configuration {:?} does; rename one",
                        c.name
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The `[evaluation]` section of a study file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvaluationSettings {
    /// Evaluation range per class, m from the intersection's origin, over the nuScenes ranges
    /// (car, truck, bus 50 m; motorcycle, pedestrian, golf cart 40 m). At most the dataset's
    /// `annotate_radius_m`: past it no road user is annotated, so every detection would count
    /// as a false positive.
    pub class_range_m: BTreeMap<String, f64>,
    /// Edges of the report's range bins, m from the origin; a last, open bin is added while a
    /// class range reaches past the last edge.
    pub range_bins_m: Vec<f64>,
}

impl Default for EvaluationSettings {
    fn default() -> Self {
        EvaluationSettings { class_range_m: BTreeMap::new(), range_bins_m: hilo_eval::DISTANCE_EDGES_M.to_vec() }
    }
}

impl StudyFile {
    /// The evaluation's settings: [`EvaluationSettings::detection_config`], with cyclists
    /// ([`hilo_eval::DetectionConfig::with_cyclists`]) when the traffic carries them.
    pub fn detection_config(&self) -> hilo_eval::DetectionConfig {
        let cfg = self.evaluation.detection_config();
        if self.dataset.traffic.carries(hilo_core::Class::Bicycle) { cfg.with_cyclists() } else { cfg }
    }
}

impl EvaluationSettings {
    /// The devkit's settings with this section's class ranges.
    pub fn detection_config(&self) -> hilo_eval::DetectionConfig {
        let mut cfg = hilo_eval::DetectionConfig::default();
        for (class, range) in &self.class_range_m {
            cfg.class_range.insert(class.clone(), *range);
        }
        cfg
    }

    /// Known classes, ranges in (0, `annotate_radius_m`], bins that start at 0 or beyond and
    /// increase; the error names the field and value.
    fn check(&self, annotate_radius_m: f64) -> std::result::Result<(), FieldError> {
        let known: Vec<String> = hilo_core::Class::ALL.iter().map(|c| c.name().to_owned()).collect();
        for (class, range) in &self.class_range_m {
            let field = format!("evaluation.class_range_m.{class}");
            if !known.contains(class) {
                return Err(FieldError::new(
                    field,
                    range,
                    format!("not a class; the classes are {}", known.join(", ")),
                ));
            }
            if !(range.is_finite() && *range > 0.0 && *range <= annotate_radius_m) {
                return Err(FieldError::new(
                    field,
                    range,
                    format!("must be in (0, dataset.annotate_radius_m = {annotate_radius_m}] m"),
                ));
            }
        }
        let b = &self.range_bins_m;
        if b.len() > MAX_RANGE_BINS + 1 {
            // The count, not the list: a list this long would be the whole message.
            return Err(FieldError::new(
                "evaluation.range_bins_m",
                format!("({} edges)", b.len()),
                format!("give at most {} (each bin is scored for every detector and seed)", MAX_RANGE_BINS + 1),
            ));
        }
        let bins = |reason: String| FieldError::new("evaluation.range_bins_m", format!("{b:?}"), reason);
        if b.len() < 2 || !b.iter().all(|e| e.is_finite()) || b[0] < 0.0 || b.windows(2).any(|w| w[1] <= w[0]) {
            return Err(bins("needs at least two finite edges, from 0 m or more, increasing".into()));
        }
        Ok(())
    }
}

/// The `[validation]` section of a study file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ValidationSettings {
    /// Placements in the set (at least 10; 30 by default): every configuration's optimum and
    /// greedy placement, then perturbed and random ones up to this many, and at least a quarter
    /// of this many of those (so a study with many configurations draws a larger set).
    pub placements: usize,
    /// Seed of the random and perturbed placements.
    pub seed: u64,
    /// Tilts offered to LiDARs and radars (degrees down): tilt is a decision variable here.
    pub lidar_tilts_deg: Vec<f32>,
    pub radar_tilts_deg: Vec<f32>,
    /// The detector trained on rigs without a radar, and the one on rigs with one (they should
    /// share head and assignment, so the rig is what differs). When not given, the registry's
    /// ([`hilo_detector::Registry::primary`]: `centerpoint` and `lirafusion-like` in hilo's);
    /// a validation records the names it used.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar_preset: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fusion_preset: Option<String>,
    /// Trainings per placement and training-traffic draw.
    pub seeds: usize,
    /// Training-traffic draws: each placement's training scenes recorded again with other
    /// traffic (its validation scenes shared, so every training is scored on the same scenes),
    /// and `seeds` trainings on each. With two or more, the report sets draw 0 against draw 1
    /// as it sets seed 0 against seed 1: how far a placement's measured accuracy depends on the
    /// traffic its detector happened to train on.
    #[serde(default = "one_draw", skip_serializing_if = "is_one_draw")]
    pub traffic_draws: usize,
    /// Rigs drawn near the budget: this many more placements whose cost lies within ±10% of
    /// the study's budget, of type counts drawn among those the budget allows, alternately at
    /// greedy and at random poses. With a calibrated recommendation they are what its regret
    /// is measured against (0: none).
    #[serde(skip_serializing_if = "is_zero")]
    pub near_budget: usize,
    /// The budget b: detectors train to 2b samples and are scored at b and at 2b.
    pub samples: usize,
    /// k of the occupancy predictor: a road user counts when hit by at least k LiDAR points.
    pub min_points: u32,
}

impl Default for ValidationSettings {
    fn default() -> Self {
        ValidationSettings {
            placements: 30,
            seed: 0,
            lidar_tilts_deg: vec![6.0, 10.0, 14.0],
            radar_tilts_deg: vec![4.0, 8.0, 12.0],
            lidar_preset: None,
            fusion_preset: None,
            seeds: 2,
            traffic_draws: 1,
            near_budget: 0,
            samples: 6_000,
            min_points: 5,
        }
    }
}

fn one_draw() -> usize {
    1
}

fn is_one_draw(n: &usize) -> bool {
    *n == 1
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

impl ValidationSettings {
    /// The settings with both presets named: those not given are the registry's fusion preset
    /// and its LiDAR-only counterpart. Checked ([`ValidationSettings::check`]); `source` names
    /// the study file.
    pub fn resolved(&self, registry: &hilo_detector::Registry, source: &str) -> Result<ValidationSettings> {
        let primary = registry.primary();
        let pick = |given: &Option<String>, key: &str, fusion: bool| match (given, primary) {
            (Some(p), _) => Ok(p.clone()),
            (None, Some((f, l))) => Ok(if fusion { f } else { l }.to_owned()),
            (None, None) => Err(StudyError::setting(
                source,
                format!("validation.{key}"),
                "(not given)",
                "no registered fusion preset has a LiDAR-only counterpart to default to; name one",
            )),
        };
        let resolved = ValidationSettings {
            lidar_preset: Some(pick(&self.lidar_preset, "lidar_preset", false)?),
            fusion_preset: Some(pick(&self.fusion_preset, "fusion_preset", true)?),
            ..self.clone()
        };
        resolved.check(registry, source)?;
        Ok(resolved)
    }

    /// The preset trained on a rig with a radar (`radar`) or without one.
    pub fn preset_for(&self, radar: bool) -> Result<&str> {
        let given = if radar { &self.fusion_preset } else { &self.lidar_preset };
        given.as_deref().ok_or(StudyError::Internal(if radar {
            "validation.fusion_preset used before the settings were resolved"
        } else {
            "validation.lidar_preset used before the settings were resolved"
        }))
    }

    /// Checks the values a study file may get wrong (the presets where given); `source` names
    /// the file. Every study plan checks its `[validation]` section, so `hilo study` refuses a
    /// section `hilo validate` would.
    pub fn check(&self, registry: &hilo_detector::Registry, source: &str) -> std::result::Result<(), StudyError> {
        let bad = |field: &str, value: String, reason: String| {
            StudyError::setting(source, format!("validation.{field}"), value, reason)
        };
        if !(10..=500).contains(&self.placements) {
            return Err(bad("placements", self.placements.to_string(), "give 10 to 500".into()));
        }
        if !(1..=20).contains(&self.seeds) {
            return Err(bad("seeds", self.seeds.to_string(), "give 1 to 20".into()));
        }
        if self.near_budget > 100 {
            return Err(bad("near_budget", self.near_budget.to_string(), "give 0 to 100".into()));
        }
        if !(1..=10).contains(&self.traffic_draws) {
            return Err(bad("traffic_draws", self.traffic_draws.to_string(), "give 1 to 10".into()));
        }
        // Detectors train to 2b: b is bounded so that 2b is a schedule (and cannot overflow).
        let most = hilo_detector::config::limits::SAMPLES / 2;
        if !(2..=most).contains(&self.samples) {
            return Err(bad("samples", self.samples.to_string(), format!("give 2 to {most}")));
        }
        if self.min_points == 0 {
            return Err(bad("min_points", "0".into(), "give at least 1".into()));
        }
        for (key, tilts) in [("lidar_tilts_deg", &self.lidar_tilts_deg), ("radar_tilts_deg", &self.radar_tilts_deg)] {
            if tilts.is_empty() || tilts.len() > 16 {
                return Err(bad(key, format!("{tilts:?}"), format!("{} tilts; give 1 to 16", tilts.len())));
            }
            if let Some(a) = tilts.iter().find(|a| !(a.is_finite() && a.abs() <= 90.0)) {
                return Err(bad(key, format!("{tilts:?}"), format!("holds {a}: tilts are degrees within ±90")));
            }
        }
        for (key, given, radar) in
            [("lidar_preset", &self.lidar_preset, false), ("fusion_preset", &self.fusion_preset, true)]
        {
            let Some(p) = given else { continue };
            let preset = registry.preset(p).map_err(|e| bad(key, format!("{p:?}"), e.to_string()))?;
            // The fusion preset is what rigs with a radar train: one that reads no radar would
            // score them without it.
            match (radar, registry.uses_radar(&preset.detector)) {
                (false, true) => return Err(bad(key, format!("{p:?}"), "needs a radar".into())),
                (true, false) => {
                    let example = registry.primary().map_or(String::new(), |(f, _)| format!(" (e.g. {f:?})"));
                    return Err(bad(
                        key,
                        format!("{p:?}"),
                        format!("reads no radar; give a preset that fuses LiDAR and radar{example}"),
                    ));
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// The catalog an embedded study names: one of the catalogs hilo embeds, by file name.
fn embedded_catalog(name: &Path, source: &str) -> Result<Catalog> {
    match name.to_str().and_then(Catalog::embedded) {
        Some(c) => Ok(c?),
        None => {
            let names = EMBEDDED_CATALOGS.map(|(n, _)| n).join(", ");
            let why = format!("names no catalog hilo embeds ({names}); an embedded study reads no files");
            Err(StudyError::setting(source, "catalog", format!("{name:?}"), why))
        }
    }
}

/// The key of a study file that names the study it builds on.
pub const EXTENDS_KEY: &str = "extends";

/// A study file's text with the study it extends beneath it. `extends = "../study.toml"` reads
/// that file (relative to this one's folder; it may not extend another in turn) and lays this
/// file over it: a table (`[dataset]`, `[dataset.traffic]`) merges field by field, anything else
/// (a value, a list, `[[configurations]]`) replaces the base's, and `scenes` / `catalogs` here
/// replace the base's `scene` / `catalog`. Relative paths in either resolve against this file's
/// folder. A file without `extends` is returned as it is.
pub fn read_study_text(path: &Path) -> Result<String> {
    let read = |p: &Path| {
        hilo_core::fs::read_text_bounded(p, hilo_core::fs::limit::CONFIG)
            .map_err(|e| hilo_core::fs::FileError::io(p, e))
    };
    let text = read(path)?;
    // A file that does not parse is reported by the parser that reads it next, with its line.
    let Ok(mut top) = toml::from_str::<toml::Table>(&text) else { return Ok(text) };
    let Some(base) = top.remove(EXTENDS_KEY) else { return Ok(text) };
    let source = path.display().to_string();
    let toml::Value::String(base) = base else {
        return Err(StudyError::setting(&source, EXTENDS_KEY, base, "give the path of a study file"));
    };
    let base_path = path.parent().unwrap_or(Path::new(".")).join(&base);
    let content = |p: &Path, e: &dyn std::fmt::Display| {
        StudyError::from(hilo_core::fs::FileError::content(p, format!("invalid study: {e}")))
    };
    let mut merged: toml::Table = toml::from_str(&read(&base_path)?).map_err(|e| content(&base_path, &e))?;
    if merged.contains_key(EXTENDS_KEY) {
        return Err(StudyError::setting(
            &source,
            EXTENDS_KEY,
            format!("{base:?}"),
            "that study extends another in turn; extend the study at the bottom directly",
        ));
    }
    for key in LIST_KEYS {
        if top.contains_key(key) {
            merged.remove(key.trim_end_matches('s'));
        }
    }
    overlay(&mut merged, top);
    toml::to_string(&merged).map_err(|e| content(path, &e))
}

/// `top` laid over `base`: tables merge key by key, any other value replaces.
fn overlay(base: &mut toml::Table, top: toml::Table) {
    for (key, value) in top {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(t)) => overlay(b, t),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// The traffic against the scene's layout (arms named, parking lanes for parking) before anything
/// runs, a bad setting named as the study file names it (`dataset.traffic.…`).
fn check_traffic(traffic: &hilo_dataset::traffic::TrafficConfig, scene: &Scene, source: &str) -> Result<()> {
    traffic.validate(&scene.layout).map_err(|e| match e {
        hilo_dataset::DatasetError::Setting { field, value, reason } => {
            StudyError::setting(source, format!("dataset.{field}"), &value, reason)
        }
        e => e.into(),
    })
}

/// The most range bins a study's `[evaluation]` may ask for.
pub const MAX_RANGE_BINS: usize = 64;

/// The `[verdict]` section of a study file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VerdictSettings {
    /// A difference smaller than this (in the metric's units: 0.02 = 2 points of mAP) is no
    /// difference that matters: a claim whose TOST shows it within ±margin is "equivalent".
    pub equivalence_margin: f64,
    /// The same for velocity errors (mAVE, car AVE), in m/s.
    pub velocity_equivalence_margin_m_s: f64,
}

impl Default for VerdictSettings {
    fn default() -> Self {
        VerdictSettings { equivalence_margin: 0.02, velocity_equivalence_margin_m_s: 0.1 }
    }
}

/// One sensor configuration to place.
#[derive(Clone, PartialEq, Serialize, Deserialize)]
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
    /// Another configuration whose placed sensors this one keeps, at their poses, placing only
    /// the rest: a rig and the same rig with a radar added then differ by the radar alone. It is
    /// placed first wherever it stands in the file; it may be placed given another in turn (a
    /// chain: LiDARs, then a radar, then a second radar), never in a cycle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub given: Option<String>,
    /// With `given`: each sensor placed beyond the given rig's stands on a mounting structure
    /// that holds none of the given rig's sensors of its type (a second radar on another pole,
    /// so that two lines of sight meet a road user, not one pole's two headings).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub apart: bool,
}

/// The derived form, with `apart` only when set: the plan's content hashes and the validation's
/// fingerprint read this text, so a study that does not set it keeps its hashes.
impl std::fmt::Debug for Configuration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Configuration");
        d.field("name", &self.name)
            .field("sensors", &self.sensors)
            .field("budget_usd", &self.budget_usd)
            .field("types", &self.types)
            .field("min", &self.min)
            .field("max", &self.max)
            .field("given", &self.given);
        if self.apart {
            d.field("apart", &self.apart);
        }
        d.finish()
    }
}

impl Configuration {
    /// The sensor types this configuration may use.
    pub fn type_names(&self) -> Vec<String> {
        if self.budget_usd.is_some() { self.types.clone() } else { self.sensors.keys().cloned().collect() }
    }

    /// A file-name-safe form of the name.
    pub fn slug(&self) -> String {
        slug(&self.name)
    }

    /// Whether it may use a radar: any of its types is a radar in the catalog.
    pub fn has_radar(&self, catalog: &Catalog) -> bool {
        self.type_names().iter().any(|t| matches!(catalog.get(t), Ok(SensorSpec::Radar(_))))
    }

    /// Whether it may use a LiDAR.
    pub fn has_lidar(&self, catalog: &Catalog) -> bool {
        self.type_names().iter().any(|t| matches!(catalog.get(t), Ok(SensorSpec::Lidar(_))))
    }
}

/// The study-file keys that make it a sweep ([`crate::sweep`]): lists of files.
pub const LIST_KEYS: [&str; 2] = ["scenes", "catalogs"];

/// The study-file key of a sweep over weather conditions: a table of named conditions.
pub const WEATHERS_KEY: &str = "weathers";

/// The configurations configuration `i`'s `given` links pass through, `i` first, and the
/// position in that path the last link returns to when they close a cycle. A link to a name
/// no configuration has ends the path (the check refuses it on its own).
fn given_chain(confs: &[Configuration], i: usize) -> (Vec<usize>, Option<usize>) {
    let mut path = vec![i];
    let mut at = i;
    while let Some(next) = confs[at].given.as_ref().and_then(|g| confs.iter().position(|c| &c.name == g)) {
        if let Some(k) = path.iter().position(|&j| j == next) {
            return (path, Some(k));
        }
        path.push(next);
        at = next;
    }
    (path, None)
}

/// The cycle that configuration `i`'s `given` links close, as "a → b → a" (None: they end).
fn given_cycle(confs: &[Configuration], i: usize) -> Option<String> {
    let (path, back) = given_chain(confs, i);
    let k = back?;
    let names: Vec<&str> = path[k..].iter().chain(std::iter::once(&path[k])).map(|&j| confs[j].name.as_str()).collect();
    Some(names.join(" → "))
}

/// Each configuration's depth in its chain of `given` links (0: given nothing), for placing
/// every configuration after the one it keeps (the check refuses cycles).
pub fn given_depths(confs: &[Configuration]) -> Vec<usize> {
    (0..confs.len()).map(|i| given_chain(confs, i).0.len() - 1).collect()
}

/// A file-name-safe form of a name: lowercase ASCII letters and digits, runs of anything else
/// as one `_`.
pub fn slug(name: &str) -> String {
    let s: String =
        name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
    s.split('_').filter(|p| !p.is_empty()).collect::<Vec<_>>().join("_")
}

/// A loaded study: the file, where its relative paths resolve, its scene and catalog.
#[derive(Clone, Debug)]
pub struct Study {
    /// The file as written; [`Study::dataset`] and [`Study::placement`] are its settings,
    /// checked once when the study is loaded.
    pub file: StudyFile,
    pub dataset: Valid<SimulateConfig>,
    pub placement: Valid<PlacementConfig>,
    pub dir: PathBuf,
    /// Where it came from, for messages.
    pub source: String,
    pub scene: Scene,
    pub catalog: Catalog,
    /// Content hashes of the scene and the catalog.
    pub scene_hash: String,
    pub catalog_hash: String,
    /// Its name within a study file that lists several scenes or catalogs (a sweep,
    /// [`crate::sweep`]); None for a study file of one scene and catalog.
    pub shard: Option<String>,
    /// The file `calibration_file` names, read and checked; its weights are the placement's.
    pub calibration: Option<hilo_placement_ip::calibrated::file::CalibrationFile>,
}

/// Reads the file `calibration_file` names (if any) and places with its weights: the calibrated
/// objective with them, refused beside `[placement] calibration`.
fn apply_calibration(
    file: &mut StudyFile,
    resolve: &dyn Fn(&Path) -> PathBuf,
    source: &str,
) -> Result<Option<hilo_placement_ip::calibrated::file::CalibrationFile>> {
    let Some(p) = &file.calibration_file else { return Ok(None) };
    if file.placement.calibration.is_some() {
        return Err(StudyError::setting(
            source,
            "calibration_file",
            p.display(),
            "the study also gives [placement] calibration: give one of the two",
        ));
    }
    let f = load_calibration(&resolve(p))?;
    file.placement.objective = hilo_placement_ip::pipeline::ObjectiveKind::Calibrated;
    file.placement.calibration = Some(f.weights);
    Ok(Some(f))
}

/// Reads a calibration file; the error names the file and what is wrong in it.
pub fn load_calibration(path: &Path) -> Result<hilo_placement_ip::calibrated::file::CalibrationFile> {
    load_calibration_text(path).map(|(file, _)| file)
}

/// [`load_calibration`], and the file's text as read (what names the file's content).
pub fn load_calibration_text(path: &Path) -> Result<(hilo_placement_ip::calibrated::file::CalibrationFile, String)> {
    let text = hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::CONFIG)
        .map_err(|e| StudyError::from(hilo_core::fs::FileError::io(path, e)))?;
    let file = hilo_placement_ip::calibrated::file::CalibrationFile::from_toml(&text).map_err(|message| {
        StudyError::from(hilo_core::fs::FileError::Content {
            path: path.to_path_buf(),
            message: format!("not a calibration file (as `hilo validate --sites` writes): {message}"),
        })
    })?;
    Ok((file, text))
}

/// Refuses a NaN or infinity in a study file's `[detector_patch]` or `[train_schedule]`. JSON
/// has none: serde would turn one into `null`, which a merge patch reads as "remove the field",
/// so the preset's value would be used without a word.
pub(crate) fn refuse_non_finite(table: &toml::Table, source: &str) -> Result<()> {
    for key in ["detector_patch", "train_schedule"] {
        if let Some((field, v)) = table.get(key).and_then(|v| non_finite(v, key)) {
            return Err(StudyError::from(hilo_core::fs::FileError::Content {
                path: PathBuf::from(source),
                message: format!("{field} = {v}: must be a finite number"),
            }));
        }
    }
    Ok(())
}

/// The first float in `v` that is NaN or infinite, with its dotted path under `at`.
fn non_finite(v: &toml::Value, at: &str) -> Option<(String, f64)> {
    match v {
        toml::Value::Float(x) if !x.is_finite() => Some((at.to_string(), *x)),
        toml::Value::Table(t) => t.iter().find_map(|(k, v)| non_finite(v, &format!("{at}.{k}"))),
        toml::Value::Array(a) => a.iter().enumerate().find_map(|(i, v)| non_finite(v, &format!("{at}[{i}]"))),
        _ => None,
    }
}

impl Study {
    /// Reads a study file.
    pub fn load(path: &Path) -> Result<Study> {
        let text = read_study_text(path)?;
        Study::parse(&text, path.parent().unwrap_or(Path::new(".")), &path.display().to_string())
    }

    /// A study from TOML text whose relative paths resolve against `dir`.
    pub fn parse(text: &str, dir: &Path, source: &str) -> Result<Study> {
        Study::build(Study::parse_file(text, source)?, dir, source, false)
    }

    /// The embedded default study (or another embedded one): its `catalog` names one of the
    /// catalogs hilo embeds (`sensors.toml`, `sensors-datasheet.toml`), not a file; any other
    /// relative path resolves against the working folder.
    pub fn parse_embedded(text: &str, source: &str) -> Result<Study> {
        Study::build(Study::parse_file(text, source)?, Path::new("."), source, true)
    }

    /// The study file of TOML text, before its settings are checked.
    fn parse_file(text: &str, source: &str) -> Result<StudyFile> {
        if let Ok(table) = toml::from_str::<toml::Table>(text) {
            if let Some(key) = LIST_KEYS.iter().chain(&[WEATHERS_KEY]).find(|k| table.contains_key(**k)) {
                return Err(StudyError::from(hilo_core::fs::FileError::Content {
                    path: PathBuf::from(source),
                    message: format!(
                        "`{key}` lists several; this file is a sweep of studies: load it with `hilo study` (hilo_study::sweep::load)"
                    ),
                }));
            }
            refuse_non_finite(&table, source)?;
        }
        toml::from_str(text).map_err(|e| {
            StudyError::from(hilo_core::fs::FileError::Content {
                path: PathBuf::from(source),
                message: format!("invalid study: {e}"),
            })
        })
    }

    /// A study from its parsed file: validates it and loads its scene and catalog.
    pub fn from_file(file: StudyFile, dir: &Path, source: &str) -> Result<Study> {
        Study::build(file, dir, source, false)
    }

    /// [`Study::from_file`], its catalog an embedded one when `embedded`.
    fn build(mut file: StudyFile, dir: &Path, source: &str, embedded: bool) -> Result<Study> {
        let bad = |field: String, value: &dyn std::fmt::Display, reason: String| {
            StudyError::setting(source, field, value, reason)
        };
        let field_error = |e: FieldError| StudyError::setting(source, e.field, e.value, e.reason);
        if file.configurations.is_empty() {
            return Err(bad("configurations".into(), &"[]", "give at least one [[configurations]]".into()));
        }
        let mut names: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        for (i, c) in file.configurations.iter().enumerate() {
            let name = format!("{:?}", c.name);
            let slug = c.slug();
            if slug.is_empty() {
                return Err(bad(
                    format!("configurations[{i}].name"),
                    &name,
                    "has no ASCII letter or digit; the name becomes file and folder names".into(),
                ));
            }
            if let Some(&j) = names.get(&slug) {
                let other = &file.configurations[j].name;
                let why = if *other == c.name {
                    format!("repeats configurations[{j}].name")
                } else {
                    format!(
                        "and configurations[{j}].name = {other:?} both become the file name {slug:?} (only ASCII letters and digits are kept; the rest becomes '_')"
                    )
                };
                return Err(bad(format!("configurations[{i}].name"), &name, why));
            }
            names.insert(slug, i);
            let at = |key: &str, value: &dyn std::fmt::Display, reason: &str| {
                bad(format!("configurations[{i}].{key}"), value, format!("{reason} (configuration {name})"))
            };
            match (c.budget_usd, c.sensors.is_empty()) {
                (Some(b), true) if b.is_finite() && b > 0.0 && !c.types.is_empty() => {}
                (Some(b), true) => {
                    return Err(at("budget_usd", &b, "needs a positive budget and a `types` list"));
                }
                (None, false) => {}
                _ => {
                    return Err(at(
                        "sensors",
                        &format!("{:?}", c.sensors),
                        "give either `sensors` or `budget_usd` with `types`",
                    ));
                }
            }
            if c.budget_usd.is_none() && c.sensors.values().all(|n| *n == 0) {
                return Err(at(
                    "sensors",
                    &format!("{:?}", c.sensors),
                    "every sensor count is 0; a configuration needs a sensor",
                ));
            }
            if c.apart && c.given.is_none() {
                return Err(at("apart", &"true", "places sensors apart from a given rig's; name one with `given`"));
            }
            if let Some(g) = &c.given {
                let value = format!("{g:?}");
                let Some(base) =
                    file.configurations.iter().enumerate().find(|(j, o)| *j != i && &o.name == g).map(|x| x.1)
                else {
                    return Err(at("given", &value, "names no other configuration of this study"));
                };
                // A chain is placed from its bottom up; a cycle has no bottom.
                if let Some(cycle) = given_cycle(&file.configurations, i) {
                    return Err(at("given", &value, &format!("closes a cycle of given configurations: {cycle}")));
                }
                // The given rig's sensors must fit this one: counts of its types at most this one's.
                let fits = base.budget_usd.is_none()
                    && base.sensors.iter().all(|(t, n)| match c.budget_usd {
                        Some(_) => *n == 0 || c.types.contains(t),
                        None => c.sensors.get(t).copied().unwrap_or(0) >= *n,
                    });
                if !fits {
                    return Err(at(
                        "given",
                        &value,
                        "must be a configuration of fixed counts whose sensors this one can hold (each of its types, as many)",
                    ));
                }
            }
        }
        let m = file.verdict.equivalence_margin;
        if !(m > 0.0 && m < 1.0) {
            return Err(bad("verdict.equivalence_margin".into(), &m, "must be in (0, 1)".into()));
        }
        file.evaluation.check(file.dataset.annotate_radius_m as f64).map_err(field_error)?;
        let v = file.verdict.velocity_equivalence_margin_m_s;
        if !(v > 0.0 && v < 10.0) {
            return Err(bad("verdict.velocity_equivalence_margin_m_s".into(), &v, "must be in (0, 10) m/s".into()));
        }
        for (i, c) in file.conditions.iter().enumerate() {
            c.check(i, &file).map_err(field_error)?;
            if let Some(j) = file.conditions[..i].iter().position(|o| slug(&o.name) == slug(&c.name)) {
                return Err(bad(
                    format!("conditions[{i}].name"),
                    &format!("{:?}", c.name),
                    format!("conditions[{j}] has the same name (as a file name)"),
                ));
            }
        }
        let dataset = file.dataset.clone().validate()?;
        let resolve = |p: &Path| if p.is_absolute() { p.to_path_buf() } else { dir.join(p) };
        let calibration = apply_calibration(&mut file, &resolve, source)?;
        let placement = file.placement.clone().validate()?;
        let scene = match &file.scene {
            Some(p) => Scene::load_with(&resolve(p), file.junction.as_ref())?,
            None if file.junction.is_some() => {
                return Err(bad(
                    "junction".into(),
                    &"(given)",
                    "names a junction of an OpenDRIVE scene, and this study gives no scene (scene = \"town.xodr\")"
                        .into(),
                ));
            }
            None => Scene::default_fixture()?,
        };
        check_traffic(&dataset.traffic, &scene, source)?;
        let catalog = match &file.catalog {
            Some(p) if embedded => embedded_catalog(p, source)?,
            Some(p) => Catalog::load(&resolve(p))?,
            None => Catalog::default_catalog()?,
        };
        for (i, c) in file.configurations.iter().enumerate() {
            for t in c.type_names() {
                catalog
                    .get(&t)
                    .map_err(|e| bad(format!("configurations[{i}].sensors"), &format!("{t:?}"), e.to_string()))?;
            }
        }
        let scene_hash = scene_hash(&scene);
        let catalog_hash = hash(&[&format!("{:?}", catalog.sensors())]);
        Ok(Study {
            file,
            dataset,
            placement,
            dir: dir.to_path_buf(),
            source: source.to_owned(),
            scene,
            catalog,
            scene_hash,
            catalog_hash,
            shard: None,
            calibration,
        })
    }

    /// Every sensor type any configuration names, sorted, once each.
    pub fn type_names(&self) -> Vec<String> {
        let mut all: Vec<String> = self.file.configurations.iter().flat_map(|c| c.type_names()).collect();
        all.sort();
        all.dedup();
        all
    }

    /// A configuration by name.
    pub fn configuration(&self, name: &str) -> Result<&Configuration> {
        self.file.configurations.iter().find(|c| c.name == name || c.slug() == name).ok_or_else(|| {
            StudyError::Unknown {
                what: "configuration",
                name: name.to_owned(),
                place: self.source.clone(),
                known: format!(
                    "configurations: {}",
                    self.file.configurations.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
                ),
            }
        })
    }
}

/// A content hash of a scene: its configuration and every static triangle (imported meshes
/// included), so a placement made for a scene is never used with another.
pub fn scene_hash(scene: &Scene) -> String {
    let config = serde_json::to_string(&scene.config).unwrap_or_default();
    let mut bits = String::with_capacity(scene.mesh.triangles.len() * 8);
    let mut acc: u64 = 0xcbf2_9ce4_8422_2325;
    for t in &scene.mesh.triangles {
        for v in t {
            for c in v.to_array() {
                acc = (acc ^ c.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    bits.push_str(&format!("{acc:016x}:{}", scene.mesh.triangles.len()));
    hash(&[&config, &bits])
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn parse(extra: &str) -> Result<Study> {
        let text = format!("{}\n{extra}", include_str!("../../../fixtures/study.toml"));
        Study::parse_embedded(&text, "s.toml")
    }

    /// Traffic with cyclists evaluates them at nuScenes' 40 m (or the section's range), and
    /// every detector of the study gets their head channel; traffic without has neither.
    #[test]
    fn cyclists_in_the_traffic_are_evaluated_and_detected() {
        let plain = parse("").unwrap();
        let fixture = include_str!("../../../fixtures/study.toml");
        let mix = "golf_cart = 0.12 }";
        assert_eq!(fixture.matches(mix).count(), 1);
        let text = fixture.replace(mix, "golf_cart = 0.12, bicycle = 0.1 }");
        let with = Study::parse_embedded(&text, "s.toml").unwrap();
        assert!(!plain.file.detection_config().class_range.contains_key("bicycle"));
        assert_eq!(with.file.detection_config().class_range["bicycle"], 40.0);
        let own = format!("{text}\n[evaluation]\nclass_range_m = {{ bicycle = 30.0 }}\n");
        assert_eq!(Study::parse_embedded(&own, "s.toml").unwrap().file.detection_config().class_range["bicycle"], 30.0);
        let registry = hilo_detector::Registry::with_builtin();
        let preset = &registry.preset("centerpoint").unwrap().detector;
        for (study, cyclists) in [(&plain, false), (&with, true)] {
            let det = crate::plan::patched_detector(study, "centerpoint", preset, &study.file.dataset).unwrap();
            assert_eq!(det.cyclists, cyclists);
        }
    }

    /// `[evaluation]` ranges override the nuScenes ones class by class; an unknown class, a range
    /// past the annotated radius, a bad verdict margin or bins that do not increase are refused
    /// with the field and value.
    #[test]
    fn evaluation_and_verdict_settings_are_checked() {
        let s =
            parse("[evaluation]\nclass_range_m = { car = 70.0 }\nrange_bins_m = [0.0, 30.0, 50.0, 70.0]\n").unwrap();
        let cfg = s.file.evaluation.detection_config();
        assert_eq!((cfg.class_range["car"], cfg.class_range["bus"], cfg.class_range["pedestrian"]), (70.0, 50.0, 40.0));
        assert_eq!(parse("").unwrap().file.evaluation.range_bins_m, vec![0.0, 30.0, 50.0]);
        for (extra, needle) in [
            ("[evaluation]\nclass_range_m = { tram = 30.0 }\n", "class_range_m.tram"),
            ("[evaluation]\nclass_range_m = { car = 90.0 }\n", "annotate_radius_m = 70"),
            ("[evaluation]\nrange_bins_m = [0.0, 50.0, 30.0]\n", "range_bins_m = [0.0, 50.0, 30.0]"),
            ("[evaluation]\nrange_bins_m = [10.0]\n", "range_bins_m"),
            ("[verdict]\nvelocity_equivalence_margin_m_s = 0.0\n", "velocity_equivalence_margin_m_s = 0"),
        ] {
            let e = parse(extra).err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains(needle) && e.contains("s.toml"), "{extra:?}: {e}");
        }
    }

    /// The traffic is checked against the scene when the study loads: parking needs a scene
    /// with parking lanes, an approach rate an arm of that name; the parking study loads.
    #[test]
    fn the_traffic_is_checked_against_the_scene() {
        for (extra, needle) in [
            ("[dataset.traffic.parking]\noccupancy = 0.5\n", "dataset.traffic.parking"),
            ("[dataset.traffic.approach_vehicles_per_hour]\nsouthwest = 10.0\n", "southwest"),
        ] {
            let e = parse(extra).err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains(needle) && e.contains("s.toml"), "{extra:?}: {e}");
        }
        let e = parse("[dataset.traffic.parking]\n").err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("parking_lane_width_m"), "{e}");
        // A demand level in place of the rates; beside a rate of its own it is refused.
        let with = |rate: &str| {
            let text = include_str!("../../../fixtures/study.toml").replacen(
                "vehicles_per_hour = 500.0",
                &format!("demand = \"peak\"\n{rate}"),
                1,
            );
            Study::parse_embedded(&text, "s.toml")
        };
        let s = with("").unwrap();
        assert_eq!(s.dataset.traffic.demand, Some(hilo_dataset::traffic::Demand::Peak));
        let e = with("vehicles_per_hour = 600.0").err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("s.toml") && e.contains("traffic.vehicles_per_hour") && e.contains("600"), "{e}");
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        for (file, level) in [
            ("peak-study.toml", hilo_dataset::traffic::Demand::Peak),
            ("off-peak-study.toml", hilo_dataset::traffic::Demand::OffPeak),
        ] {
            assert_eq!(Study::load(&fixtures.join(file)).unwrap().dataset.traffic.demand, Some(level), "{file}");
        }
        let s = Study::load(&fixtures.join("parking-study.toml")).unwrap();
        assert_eq!(s.dataset.traffic.parking.as_ref().map(|p| p.occupancy), Some(0.7));
        assert!(s.scene.layout.arms.iter().all(|a| a.parking_lane_m == 2.4));
    }

    /// `[[conditions]]` name configurations of the study, once each, in a weather other than
    /// the study's own; anything else is refused with the field and value.
    #[test]
    fn conditions_are_checked() {
        let fog = |configs: &str, weather: &str| {
            format!("[[conditions]]\nname = \"dense fog\"\nweather = {{ {weather} }}\nconfigurations = [{configs}]\n")
        };
        let s = parse(&fog("\"2x lidar-16\"", "fog_visibility_m = 50.0")).unwrap();
        let c = &s.file.conditions.iter().find(|c| c.name == "dense fog").unwrap();
        assert_eq!(c.label("2x lidar-16"), "2x lidar-16 in dense fog");
        assert_eq!(c.weather.to_string(), "fog (visibility 50 m)");
        for (extra, needle) in [
            (
                fog("\"3x lidar-16\"", "fog_visibility_m = 50.0"),
                "configurations[0] = \"3x lidar-16\": is not a configuration",
            ),
            (fog("\"2x lidar-16\", \"2x lidar-16\"", "fog_visibility_m = 50.0"), "named twice"),
            (fog("", "fog_visibility_m = 50.0"), "configurations = []"),
            (fog("\"2x lidar-16\"", ""), "the study's own `[dataset.weather]`"),
            (fog("\"2x lidar-16\"", "fog_visibility_m = 5.0"), "fog_visibility_m = 5"),
            (fog("\"2x lidar-16\"", "snow = 1.0"), "snow"),
            (
                format!("{}{}", fog("\"2x lidar-16\"", "rain_mm_h = 5.0"), fog("\"1x lidar-64\"", "rain_mm_h = 9.0")),
                "name = \"dense fog\": conditions[2] has the same name",
            ),
            (
                "[[configurations]]\nname = \"2x lidar-16 in fog\"\nsensors = { \"lidar-16\" = 2 }\n".to_string(),
                "becomes the file name \"2x_lidar_16_in_fog\"",
            ),
        ] {
            let e = parse(&extra).err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains(needle) && e.contains("s.toml"), "{extra:?}: {e}");
        }
    }

    /// The embedded default study reads its catalog among the embedded ones: the same study as
    /// `fixtures/study.toml` read from its folder; a catalog hilo does not embed is refused by
    /// name, not looked for in the working folder.
    #[test]
    fn the_embedded_default_study_is_the_fixture_with_its_catalog_embedded() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        let file = Study::load(&fixtures.join("study.toml")).unwrap();
        let embedded = parse("").unwrap();
        assert_eq!(embedded.catalog_hash, file.catalog_hash);
        assert_eq!(format!("{:?}", embedded.dataset), format!("{:?}", file.dataset));
        assert_eq!(embedded.file.configurations, file.file.configurations);
        let paper = Study::load(&fixtures.join("paper-sensors-study.toml")).unwrap();
        assert_ne!(embedded.catalog_hash, paper.catalog_hash);
        let text = include_str!("../../../fixtures/study.toml");
        let mine = text.replace("catalog = \"sensors-datasheet.toml\"", "catalog = \"mine.toml\"");
        let e = Study::parse_embedded(&mine, "s.toml").unwrap_err().to_string();
        assert!(e.contains("catalog") && e.contains("mine.toml") && e.contains("sensors-datasheet.toml"), "{e}");
    }

    /// The paper-sensors study is the default study with every field setting off: the same file
    /// but for the catalog, the `[dataset]` settings of a field rig, and the validation scenes
    /// the field sensors need; a setting changed in one and not the other fails.
    #[test]
    fn the_paper_sensors_study_is_the_default_but_its_sensors() {
        let table = |name: &str| -> toml::Table {
            let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures").join(name);
            toml::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
        };
        let (mut field, paper) = (table("study.toml"), table("paper-sensors-study.toml"));
        assert_eq!(
            field.remove("catalog").and_then(|c| c.as_str().map(str::to_owned)).as_deref(),
            Some("sensors-datasheet.toml")
        );
        let dataset = field.get_mut("dataset").and_then(|d| d.as_table_mut()).unwrap();
        for key in ["calibration_error", "time_sync_error_s", "rolling_shutter", "vehicle_paint", "foliage"] {
            assert!(dataset.remove(key).is_some(), "{key}");
        }
        assert_eq!(dataset.insert("val_scenes".into(), 20.into()), Some(30.into()));
        assert_eq!(field, paper);
    }

    /// `calibration_file` places with the shipped calibration: the calibrated objective with
    /// its weights, and the file kept for the predictions; refused beside `[placement]
    /// calibration`; a missing or malformed file is refused with its path.
    #[test]
    fn a_calibration_file_sets_the_objective_and_bad_ones_are_refused() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        let with = |key: &str, extra: &str| {
            let text = format!("{key}\n{}\n{extra}", include_str!("../../../fixtures/study.toml"));
            Study::parse(&text, &fixtures, "s.toml")
        };
        let s = with("calibration_file = \"calibration-sites.toml\"", "").unwrap();
        let f = s.calibration.as_ref().unwrap();
        assert_eq!(s.placement.objective, hilo_placement_ip::pipeline::ObjectiveKind::Calibrated);
        assert_eq!(s.placement.calibration, Some(f.weights));
        assert!(f.fitted_on.len() >= 4);
        let text = include_str!("../../../fixtures/study.toml").replace(
            "[placement]\n",
            "[placement]\ncalibration = { lidar = 1.0, radar = 0.0 }\nobjective = \"calibrated\"\n",
        );
        let e = Study::parse(&format!("calibration_file = \"calibration-sites.toml\"\n{text}"), &fixtures, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("calibration_file") && e.contains("give one of the two"), "{e}");
        let e = with("calibration_file = \"no-such-calibration.toml\"", "").unwrap_err().to_string();
        assert!(e.contains("no-such-calibration.toml"), "{e}");
        let e = with("calibration_file = \"study.toml\"", "").unwrap_err().to_string();
        assert!(e.contains("study.toml") && e.contains("not a calibration file"), "{e}");
    }
}
