//! The scale of a study: how many scenes, configurations, presets, seeds and training samples.
//! A profile is data (serialized into the study folder), so a stage run on its own, by a
//! workflow engine, sees exactly what the whole study sees.

use crate::error::{Result, StudyError};
use crate::study::Study;
use hilo_core::Valid;
use hilo_dataset::simulate::SimulateConfig;
use hilo_detector::Registry;
use hilo_detector::train::Sampling;
use serde::{Deserialize, Serialize};

/// The profiles a study can run at, by name (`quick`, `default`, `paper`; `tiny` for tests).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProfileName {
    Tiny,
    Quick,
    Default,
    Paper,
}

impl ProfileName {
    /// Every profile, smallest first.
    pub const ALL: [ProfileName; 4] = [ProfileName::Tiny, ProfileName::Quick, ProfileName::Default, ProfileName::Paper];

    pub fn as_str(self) -> &'static str {
        match self {
            ProfileName::Tiny => "tiny",
            ProfileName::Quick => "quick",
            ProfileName::Default => "default",
            ProfileName::Paper => "paper",
        }
    }
}

impl std::fmt::Display for ProfileName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for ProfileName {
    type Err = StudyError;

    fn from_str(s: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|p| p.as_str() == s).ok_or_else(|| StudyError::UnknownProfile { name: s.to_owned() })
    }
}

/// The scale of a study.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    pub name: ProfileName,
    /// The datasets' settings, checked when the profile is made.
    pub dataset: Valid<SimulateConfig>,
    /// Presets trained on every configuration they can run on (fusion presets need a radar).
    pub presets: Vec<String>,
    /// Ablation presets, trained on the study's first configuration with a radar only (the rig
    /// under study).
    pub ablations: Vec<String>,
    /// The study's first configurations only (all when None): a study lists its rigs in order
    /// of interest, and a profile that cannot afford them all runs the first ones.
    pub configurations: Option<usize>,
    /// Seeds per (configuration, preset) and training-traffic draw.
    pub seeds: usize,
    /// Training-traffic draws: each configuration's training scenes recorded again with other
    /// traffic (its validation scenes shared), and every detector of the profile trained on
    /// each (`seeds` per draw). With two or more, the verdict treats the draw as a random effect:
    /// a group's replicates are its draws, each the mean of its seeds.
    #[serde(default = "one_draw", skip_serializing_if = "is_one_draw")]
    pub traffic_draws: usize,
    /// Training samples per detector (None: each preset's default schedule).
    pub train_samples: Option<usize>,
    /// How training frames are drawn (None: each preset's default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sampling: Option<Sampling>,
    /// Points of the learning curve, as shares of the schedule (seed 0 of every group); each
    /// below 1 is a training of its own over that share of the samples.
    pub curve: Vec<f64>,
    /// Scene-bootstrap replicates.
    pub resamples: usize,
    /// Trainings run at once (each on a one-thread pool).
    pub trainings_at_once: usize,
    /// Target cell size of the placement speed-against-error sweeps (the study's when None).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tradeoff_cell_m: Option<f32>,
    /// How many of the study file's weather conditions (`[[conditions]]`, in order) run, all
    /// when None: their configurations recorded again in each and trained like the others.
    #[serde(default = "no_conditions", skip_serializing_if = "runs_no_condition", deserialize_with = "conditions_run")]
    pub conditions: Option<usize>,
    /// What this profile leaves out of the paper's design, and which profile adds it.
    pub leaves_out: String,
}

/// `--seeds` (1 to 100): each seed is a full set of trainings, so a larger count is a typo, and
/// one of millions would exhaust memory planning them.
pub fn seeds_arg(s: &str) -> std::result::Result<usize, String> {
    count_arg(s, 100, "a seed count")
}

/// `--traffic-draws` (1 to 10): each draw is a dataset per configuration and a full set of
/// trainings.
pub fn draws_arg(s: &str) -> std::result::Result<usize, String> {
    count_arg(s, 10, "a count of training-traffic draws")
}

fn count_arg(s: &str, max: usize, what: &str) -> std::result::Result<usize, String> {
    s.parse::<usize>()
        .ok()
        .filter(|n| (1..=max).contains(n))
        .ok_or_else(|| format!("{s} is not {what} from 1 to {max}"))
}

impl Profile {
    /// The profile with what the command line chose in its place: presets (`--presets`, see
    /// [`Profile::choose_presets`]), seeds and training-traffic draws.
    pub fn overridden(
        mut self,
        (presets, seeds, draws): (Option<&[String]>, Option<usize>, Option<usize>),
        registry: &Registry,
    ) -> Profile {
        if let Some(p) = presets {
            self.choose_presets(p, registry);
        }
        self.seeds = seeds.unwrap_or(self.seeds);
        self.traffic_draws = draws.unwrap_or(self.traffic_draws);
        self
    }

    /// The detectors `--presets` names in place of the profile's (the registry's ablations among
    /// them train as ablations); what the profile leaves out then says it was written for the
    /// profile's own detectors.
    pub fn choose_presets(&mut self, chosen: &[String], registry: &Registry) {
        let (ablations, presets) = chosen.iter().cloned().partition(|x| registry.ablation_of(x).is_some());
        (self.presets, self.ablations) = (presets, ablations);
        self.leaves_out = format!(
            "{} (said of the profile's own detectors: `--presets {}` chose them here)",
            self.leaves_out,
            chosen.join(",")
        );
    }
}

/// A profile written before training-traffic draws existed trained on the study's traffic only.
fn one_draw() -> usize {
    1
}

fn is_one_draw(n: &usize) -> bool {
    *n == 1
}

/// A profile written before weather conditions existed ran none.
fn no_conditions() -> Option<usize> {
    Some(0)
}

fn runs_no_condition(n: &Option<usize>) -> bool {
    *n == Some(0)
}

/// A count of conditions, null for all, or (as the first builds with conditions wrote it) a
/// flag: true for all, false for none.
fn conditions_run<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Option<usize>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Run {
        Flag(bool),
        Count(Option<usize>),
    }
    Ok(match Run::deserialize(d)? {
        Run::Flag(all) => (!all).then_some(0),
        Run::Count(n) => n,
    })
}

/// The presets of the default profile, as the registry names them ([`Registry::primary`]): the
/// LiDAR-only counterpart and the fusion preset under study, which share their head; the first
/// LiDAR-only preset alone where no fusion preset has a counterpart.
pub fn default_presets(registry: &Registry) -> Vec<String> {
    match registry.primary() {
        Some((fusion, lidar)) => vec![lidar.to_owned(), fusion.to_owned()],
        None => registry
            .detector_names()
            .into_iter()
            .filter(|p| registry.preset(p).is_ok_and(|x| !registry.uses_radar(&x.detector)))
            .take(1)
            .collect(),
    }
}

/// The profiles: `quick` (≤ 5 min), `default` (≤ 30 min), `paper` (the paper's scale), and
/// `tiny` (seconds; for tests).
pub fn profile(name: ProfileName, study: &Study, registry: &Registry) -> Result<Profile> {
    let base = study.dataset.clone().into_inner();
    // The LiDARs' beam width costs about twenty times a thin ray's casting and moved nothing
    // measurable in the realism ablation (docs/realism.md): the paper profile casts it, the
    // others cast rays of no width unless the study's `[dataset]` says.
    let beams = beam_lidars(study);
    let decided = base.lidar_beam_width.is_none() && !beams.is_empty();
    let cast = |width: bool| SimulateConfig {
        lidar_beam_width: if decided { Some(width) } else { base.lidar_beam_width },
        ..base.clone()
    };
    let (thin, wide) = (cast(false), cast(true));
    let beam_note = if decided {
        format!(
            "; the beams' width of {} (rays of no width here; `lidar_beam_width = true` under `[dataset]` casts it)",
            beams.join(", ")
        )
    } else {
        String::new()
    };
    // Every detector and every ablation the plugins register, for the paper profile: the
    // default profile's presets first (the verdict takes the first fusion preset as the one
    // under study), then the others in registration order.
    let default = default_presets(registry);
    let mut detectors = default.clone();
    detectors.extend(registry.detector_names().into_iter().filter(|p| !default.contains(p)));
    let ablations = registry.ablation_names();
    let p = match name {
        ProfileName::Quick => Profile {
            name,
            dataset: SimulateConfig { scenes: 4, seconds: 10.0, rate_hz: 10.0, val_scenes: 6, val_seconds: 10.0, ..thin.clone() }
                .validate()?,
            presets: default.iter().take(1).cloned().collect(),
            ablations: vec![],
            configurations: Some(2),
            seeds: 2,
            traffic_draws: 1,
            train_samples: Some(1_600),
            sampling: None,
            curve: vec![0.5, 1.0],
            resamples: 200,
            trainings_at_once: 2,
            tradeoff_cell_m: Some(2.0),
            conditions: Some(0),
            leaves_out: format!("the study's configurations after its first two, its weather conditions, the fusion detectors, a third seed and longer training: the default profile adds them{beam_note}"),
        },
        ProfileName::Default => Profile {
            name,
            dataset: thin.clone().validate()?,
            presets: default.clone(),
            ablations: registry.primary().map(|(fusion, _)| registry.ablations_of(fusion)).unwrap_or_default(),
            configurations: Some(5),
            seeds: 3,
            traffic_draws: 1,
            train_samples: Some(6_000),
            sampling: Some(Sampling::ClassBalanced),
            curve: vec![0.25, 0.5, 1.0],
            resamples: 400,
            trainings_at_once: 2,
            tradeoff_cell_m: None,
            conditions: Some(1),
            leaves_out: format!("the study's configurations after its first five, its weather conditions after the first, the other detector presets (pointpillars, pointpillars-lr, l4dr-like, bi-lrfusion-like, late) and the l4dr-like ablation, and each preset's default schedule (6,000 samples here against 30,000 for centerpoint, 24,000 for lirafusion-like, 12,000 for the others){beam_note}: `--profile paper` adds them; 6,000 samples leave every detector short of its plateau (the learning curves show it)"),
        },
        ProfileName::Paper => Profile {
            name,
            dataset: SimulateConfig { scenes: 30, seconds: 20.0, rate_hz: 20.0, sweep_rate_hz: 20.0, val_scenes: 20, ..wide }
                .validate()?,
            presets: detectors,
            ablations,
            configurations: None,
            seeds: 3,
            traffic_draws: 1,
            train_samples: None,
            sampling: None,
            curve: vec![0.25, 0.5, 1.0],
            resamples: 1000,
            trainings_at_once: 2,
            tradeoff_cell_m: None,
            conditions: None,
            leaves_out: "nothing of the paper's design; its 37 scenes at 20 Hz are 30 training scenes at 20 Hz and 20 validation scenes at 2 Hz here".into(),
        },
        ProfileName::Tiny => Profile {
            name,
            dataset: SimulateConfig { scenes: 2, seconds: 1.5, rate_hz: 10.0, val_scenes: 5, val_seconds: 1.0, ..thin.clone() }
                .validate()?,
            presets: vec!["centerpoint".into(), "pointpillars-lr".into()],
            ablations: vec![],
            configurations: Some(2),
            seeds: 2,
            traffic_draws: 1,
            train_samples: Some(8),
            sampling: None,
            curve: vec![0.5, 1.0],
            resamples: 40,
            trainings_at_once: 2,
            tradeoff_cell_m: Some(5.0),
            conditions: Some(0),
            leaves_out: "everything that takes time: a test profile".into(),
        },
    };
    Ok(p)
}

/// The LiDARs of the study's configurations whose catalog entry gives a beam width, by name.
pub fn beam_lidars(study: &Study) -> Vec<String> {
    study
        .type_names()
        .into_iter()
        .filter(|n| matches!(study.catalog.get(n), Ok(hilo_sensor_models::SensorSpec::Lidar(l)) if l.beam.is_some()))
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A profile reads how many conditions it runs from a count, null (all), the flag the first
    /// builds wrote, or nothing (a profile from before conditions: none); it writes no field
    /// when it runs none, so such a profile's JSON (and a folder's fingerprint) is unchanged.
    #[test]
    fn the_conditions_field_reads_every_form_it_was_written_in() {
        let study = Study::parse_embedded(include_str!("../../../fixtures/study.toml"), "s.toml").unwrap();
        let registry = Registry::with_builtin();
        let quick = profile(ProfileName::Quick, &study, &registry).unwrap();
        let json = serde_json::to_value(&quick).unwrap();
        assert!(json.get("conditions").is_none());
        let with = |v: serde_json::Value| {
            let mut j = json.clone();
            j["conditions"] = v;
            serde_json::from_value::<Profile>(j).unwrap().conditions
        };
        assert_eq!(serde_json::from_value::<Profile>(json.clone()).unwrap().conditions, Some(0));
        assert_eq!(with(serde_json::json!(true)), None);
        assert_eq!(with(serde_json::json!(false)), Some(0));
        assert_eq!(with(serde_json::json!(1)), Some(1));
        assert_eq!(with(serde_json::Value::Null), None);
        let default = profile(ProfileName::Default, &study, &registry).unwrap();
        assert_eq!(default.conditions, Some(1));
        let back: Profile = serde_json::from_str(&serde_json::to_string(&default).unwrap()).unwrap();
        assert_eq!(back, default);
    }

    /// `--presets` replaces the profile's detectors, and what the profile leaves out says that
    /// it speaks of the profile's own.
    #[test]
    fn chosen_presets_replace_the_profiles_and_say_so() {
        let study = Study::parse_embedded(include_str!("../../../fixtures/study.toml"), "s.toml").unwrap();
        let registry = Registry::with_builtin();
        let mut p = profile(ProfileName::Quick, &study, &registry).unwrap();
        let before = p.leaves_out.clone();
        p.choose_presets(&["centerpoint".into(), "pointpillars".into()], &registry);
        assert_eq!(p.presets, ["centerpoint", "pointpillars"]);
        assert!(p.ablations.is_empty());
        assert_eq!(
            p.leaves_out,
            format!(
                "{before} (said of the profile's own detectors: `--presets centerpoint,pointpillars` chose them here)"
            )
        );
    }

    /// The beams' width: the paper profile casts it, the others rays of no width, unless the
    /// study's `[dataset]` says; a study whose LiDARs give no width is left as it was (its
    /// datasets' fingerprints unchanged), and what the profile leaves out says so.
    #[test]
    fn the_beams_width_is_the_paper_profiles_unless_the_study_says() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        let registry = Registry::with_builtin();
        let tmp = tempfile::tempdir().unwrap();
        let parse = |extra: &str| {
            let (base, catalog) = (dir.join("study.toml"), dir.join("sensors-datasheet.toml"));
            let f = tmp.path().join("s.toml");
            std::fs::write(&f, format!("extends = {base:?}\ncatalog = {catalog:?}\n{extra}")).unwrap();
            Study::load(&f).unwrap()
        };
        let field = parse("");
        assert_eq!(beam_lidars(&field), ["lidar-16", "lidar-32", "lidar-64"]);
        let width = |s: &Study, name| profile(name, s, &registry).unwrap().dataset.lidar_beam_width;
        for name in [ProfileName::Tiny, ProfileName::Quick, ProfileName::Default] {
            assert_eq!(width(&field, name), Some(false), "{name}");
        }
        assert_eq!(width(&field, ProfileName::Paper), Some(true));
        let default = profile(ProfileName::Default, &field, &registry).unwrap();
        assert!(
            default.leaves_out.contains("the beams' width of lidar-16, lidar-32, lidar-64"),
            "{}",
            default.leaves_out
        );
        let paper = profile(ProfileName::Paper, &field, &registry).unwrap();
        assert!(!paper.leaves_out.contains("width"));
        // The study's own choice stands in every profile, and is not called left out.
        for (extra, want) in
            [("[dataset]\nlidar_beam_width = true", true), ("[dataset]\nlidar_beam_width = false", false)]
        {
            let s = parse(extra);
            for name in ProfileName::ALL {
                let p = profile(name, &s, &registry).unwrap();
                assert_eq!(p.dataset.lidar_beam_width, Some(want), "{extra} {name}");
                assert!(!p.leaves_out.contains("beams' width"), "{}", p.leaves_out);
            }
        }
        // The paper's sensors give no width: every profile leaves the setting unset.
        let ideal = Study::load(&dir.join("paper-sensors-study.toml")).unwrap();
        assert!(beam_lidars(&ideal).is_empty());
        for name in ProfileName::ALL {
            assert_eq!(width(&ideal, name), None, "{name}");
        }
    }

    #[test]
    fn profile_names_round_trip_and_unknown_ones_are_named() {
        for p in ProfileName::ALL {
            assert_eq!(p.to_string().parse::<ProfileName>().unwrap(), p);
            assert_eq!(serde_json::to_value(p).unwrap(), serde_json::json!(p.as_str()));
        }
        let e = "huge".parse::<ProfileName>().unwrap_err().to_string();
        assert!(e.contains("\"huge\"") && e.contains("quick, default or paper"), "{e}");
    }
}
