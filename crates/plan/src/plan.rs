//! The plan of a study: its stages, each named by a content hash of everything that decides its
//! output (inputs, settings, and the code that computes it), so that any stage can be run alone,
//! twice, or on another machine, and a stage made by other code or other inputs is recomputed,
//! never silently reused.
//!
//! ```text
//! placements/<h>/            every configuration placed        h = code, scene, catalog, study
//! data/<slug>-<h>/           one configuration's dataset        h = placements, configuration, dataset settings
//!                            (a configuration in a weather condition: `<slug>_in_<condition>`, the
//!                            condition's weather in its settings, its base configuration's placement)
//! runs/<slug>/<preset>-seed<k>-<h>/   one trained detector      h = dataset, detector, schedule
//! results/<slug>/<preset>-seed<k>-<h>.json   its detections on the validation split (the run's h)
//! ```

use crate::error::{Result, StudyError};
use crate::files::hash;
use crate::profile::Profile;
use crate::study::{Configuration, Study};
use hilo_core::Valid;
use hilo_core::fs::{limit, read_json, write_json};
use hilo_dataset::simulate::SimulateConfig;
use hilo_detector::train::TrainConfig;
use hilo_detector::{DetectorConfig, Registry};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The code that ran: hilo's version and, when built from a checkout, its git commit (with a
/// hash of uncommitted changes).
pub fn code_version() -> String {
    let commit = env!("HILO_GIT_COMMIT");
    if commit.is_empty() {
        env!("CARGO_PKG_VERSION").to_owned()
    } else {
        format!("{}+{commit}", env!("CARGO_PKG_VERSION"))
    }
}

/// What decides floating-point results besides the code: the CPU features that select matrix
/// and math kernels, and the threads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    pub hilo_version: String,
    /// The git commit hilo was built from ("" outside a checkout), "-dirty-<hash>" with
    /// uncommitted changes.
    pub git_commit: String,
    pub arch: String,
    /// SIMD features present (the matrix-product and libm kernels are chosen by them at run
    /// time, so results may differ in the last bits between CPUs, and training then diverges).
    pub cpu_features: Vec<String>,
    pub threads: usize,
    /// Detectors trained at once (each on its own thread pool).
    pub trainings_at_once: usize,
}

impl Provenance {
    pub fn here(trainings_at_once: usize) -> Self {
        #[allow(unused_mut)]
        let mut features = Vec::new();
        #[cfg(target_arch = "x86_64")]
        for (name, on) in [
            ("sse4.2", std::arch::is_x86_feature_detected!("sse4.2")),
            ("avx", std::arch::is_x86_feature_detected!("avx")),
            ("avx2", std::arch::is_x86_feature_detected!("avx2")),
            ("fma", std::arch::is_x86_feature_detected!("fma")),
            ("avx512f", std::arch::is_x86_feature_detected!("avx512f")),
        ] {
            if on {
                features.push(name.to_owned());
            }
        }
        Provenance {
            hilo_version: env!("CARGO_PKG_VERSION").to_owned(),
            git_commit: env!("HILO_GIT_COMMIT").to_owned(),
            arch: std::env::consts::ARCH.to_owned(),
            cpu_features: features,
            threads: rayon::current_num_threads(),
            trainings_at_once,
        }
    }
}

/// The short form of a hash used in folder names.
pub fn short(h: &str) -> &str {
    &h[..h.len().min(12)]
}

/// A stage's hash from its parts: the code version first, always.
pub fn stage_hash(kind: &str, parts: &[&str]) -> String {
    let code = code_version();
    let mut all: Vec<&str> = vec![kind, &code];
    all.extend_from_slice(parts);
    hash(&all)
}

/// One configuration's dataset stage: `data/<slug>-<h>/`, complete when its `stage.json` exists.
#[derive(Clone, Debug)]
pub struct DataStage {
    pub dir: PathBuf,
    pub hash: String,
}

impl DataStage {
    /// Written last, when the dataset is complete (a workflow engine's output for the stage).
    pub fn done(&self) -> PathBuf {
        self.dir.join("stage.json")
    }
}

/// How the points of a learning curve below the end are trained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CurveKind {
    /// Each point is a training of its own over that many samples, warmed up and annealed by
    /// the same one-cycle schedule shape: what that budget reaches. The study's learning curves,
    /// on which the plateau and the budget gate are read.
    Budget,
    /// Each point is the weights kept at that many samples of the one training
    /// (`TrainConfig::keep`): free, but mid-run, at a one-cycle learning rate still near its
    /// peak (0.81 of it halfway through a schedule warmed up over 0.3), so it understates what
    /// a training of that budget reaches. `hilo validate`'s rank check at b of 2b.
    Snapshot,
}

/// One detector: trained, then run on the validation split (a train stage). Its outputs are the
/// result file, the metadata beside it and, for the learning curve, one result file per
/// point; its run folders hold checkpoints, so an interrupted training resumes.
#[derive(Clone, Debug)]
pub struct Job {
    /// `<configuration slug>/<preset>-seed<k>` (`<preset>-draw<d>-seed<k>` on training-traffic
    /// draw d > 0): how a person or a workflow names it.
    pub id: String,
    /// Index into [`Plan::configurations`].
    pub configuration: usize,
    /// Index into [`Plan::data`]: the dataset it trains on (and detects on, whose validation
    /// scenes every draw of its configuration shares).
    pub data: usize,
    /// The training-traffic draw of its dataset (0: the study's own traffic).
    pub draw: u64,
    pub preset: String,
    pub seed: u64,
    pub run: PathBuf,
    pub results: PathBuf,
    pub detector: Valid<DetectorConfig>,
    pub train: Valid<TrainConfig>,
    /// Samples of the learning curve's points (the end excluded; seed 0 only), each trained
    /// as `curve_kind` says.
    pub curve: Vec<usize>,
    pub curve_kind: CurveKind,
}

impl Job {
    /// What detection keeps beside the result file (timing, parameters), so that a report needs
    /// no detector.
    pub fn meta(&self) -> PathBuf {
        self.results.with_extension("meta.json")
    }

    /// The result file of the weights kept at `samples`.
    pub fn curve_results(&self, samples: usize) -> PathBuf {
        let stem = self.results.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        self.results.with_file_name(format!("{stem}-at{samples}.json"))
    }

    /// The run folder of the learning curve's own training at `samples` (a [`CurveKind::Budget`]
    /// point): beside the job's, named after it.
    pub fn curve_run(&self, samples: usize) -> PathBuf {
        let name = self.run.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        self.run.with_file_name(format!("{name}-at{samples}"))
    }

    /// The schedule of the learning curve's own training at `samples`: the job's, over
    /// `samples` (so warmed up and annealed over them), keeping no weights on the way.
    pub fn curve_train(&self, samples: usize) -> Result<Valid<TrainConfig>> {
        TrainConfig { samples, keep: Vec::new(), ..(*self.train).clone() }
            .validate()
            .map_err(|e| StudyError::step(format!("{}: learning-curve point at {samples} samples", self.id), e))
    }

    /// Training steps the stage takes: its training's and, for [`CurveKind::Budget`], those of
    /// the learning curve's own trainings.
    pub fn steps(&self) -> usize {
        let own = match self.curve_kind {
            CurveKind::Budget => self.curve.iter().map(|s| s.div_ceil(self.train.batch.max(1))).sum::<usize>(),
            CurveKind::Snapshot => 0,
        };
        self.train.steps() + own
    }

    /// Training samples the stage sees, its learning curve's own trainings included.
    pub fn samples(&self) -> usize {
        self.steps() * self.train.batch.max(1)
    }

    /// Every file the stage writes, the metadata last.
    pub fn outputs(&self) -> Vec<PathBuf> {
        let mut v = vec![self.results.clone()];
        v.extend(self.curve.iter().map(|&s| self.curve_results(s)));
        v.push(self.meta());
        v
    }

    /// Whether its outputs all exist.
    pub fn done(&self) -> bool {
        self.outputs().iter().all(|p| p.exists())
    }
}

/// A study's stages, every path and hash known before anything runs:
///
/// 1. `place`: every configuration's placement, and placement's speed-against-error sweeps;
/// 2. `simulate` (per configuration): its dataset, the same traffic for every configuration;
/// 3. `train` (per configuration × preset × seed): training, then detection on the validation
///    split;
/// 4. `report`: the verdict, assembled from the stage outputs.
///
/// A stage's hash covers the code and everything upstream of it (a dataset's hash is the
/// placement stage's hash, the configuration and the dataset settings, since a placement is a
/// deterministic function of those), so a workflow engine can name every file up front.
#[derive(Clone, Debug)]
pub struct Plan {
    pub profile: Profile,
    pub out: PathBuf,
    /// Hash of the study file, scene, catalog and profile: the folder holds this study only.
    pub fingerprint: String,
    /// The profile's configurations of the study, then (when the profile runs them) those of
    /// each weather condition, named "<configuration> in <condition>".
    pub configurations: Vec<Configuration>,
    /// Whether each configuration has a radar (the catalog's sensor kind decides).
    pub radar: Vec<bool>,
    /// Per configuration, the configuration whose placement it records (itself, or the one a
    /// weather condition records again).
    pub placed: Vec<usize>,
    /// Per configuration, its weather condition's name (None: the study's own weather).
    pub conditions: Vec<Option<String>>,
    /// Per dataset stage (as [`Plan::data`]), the settings it is recorded with (the
    /// condition's weather, the training-traffic draw).
    pub datasets: Vec<Valid<hilo_dataset::simulate::SimulateConfig>>,
    pub placements: PathBuf,
    pub tradeoffs: PathBuf,
    /// The dataset stages: each configuration's (in the order of `configurations`), then, when
    /// the profile trains on several training-traffic draws, the configurations again for each
    /// further draw ([`Plan::data_stage`]).
    pub data: Vec<DataStage>,
    pub jobs: Vec<Job>,
    /// Preset × configuration pairs left out, and why (a fusion preset on a rig without radar).
    pub skipped: Vec<String>,
}

impl Plan {
    pub fn new(study: &Study, registry: &Registry, profile: &Profile, out: &Path) -> Result<Plan> {
        if profile.seeds == 0 {
            return Err(StudyError::Argument { flag: "--seeds", value: "0".into(), reason: "give at least 1".into() });
        }
        for p in profile.presets.iter().chain(&profile.ablations) {
            registry.preset(p).map_err(|e| StudyError::Argument {
                flag: "--presets",
                value: format!("{p:?}"),
                reason: format!("(or profile {}'s preset): {e}", profile.name),
            })?;
        }
        study.file.validation.check(registry, &study.source)?;
        let pjson = serde_json::to_string(profile)?;
        let fingerprint = hash(&[&defining(&study.file), &pjson, &study.scene_hash, &study.catalog_hash]);
        let mut configurations: Vec<Configuration> =
            study.file.configurations.iter().take(profile.configurations.unwrap_or(usize::MAX)).cloned().collect();
        let mut skipped = Vec::new();
        let (conditioned, conditions, datasets) = conditioned(study, profile, &configurations, &mut skipped)?;
        let mut placed: Vec<usize> = (0..configurations.len()).collect();
        for (base, c) in conditioned {
            configurations.push(c);
            placed.push(base);
        }
        let radar: Vec<bool> = configurations.iter().map(|c| c.has_radar(&study.catalog)).collect();
        let traffic = placement_traffic(study);
        let place_hash = stage_hash(
            "placements",
            &[
                &study.scene_hash,
                &study.catalog_hash,
                &format!("{:?}{traffic}", study.placement),
                &format!("{:?}", study.file.configurations),
            ],
        );
        let placements = out.join("placements").join(short(&place_hash));
        let tradeoffs = placements
            .join(format!("tradeoffs-{}.json", profile.tradeoff_cell_m.map_or("study".into(), |c| c.to_string())));
        // One dataset per configuration and training-traffic draw, draw 0 first: `data[ci]` is
        // configuration ci's own, whose validation scenes every draw shares.
        let mut data = Vec::new();
        let mut drawn = Vec::new();
        for draw in 0..profile.traffic_draws.max(1) as u64 {
            for (c, dataset) in configurations.iter().zip(&datasets) {
                let dataset = SimulateConfig { train_traffic_draw: draw, ..dataset.clone().into_inner() }.validate()?;
                let h = stage_hash("data", &[&place_hash, &c.name, &format!("{dataset:?}")]);
                let name = if draw == 0 { c.slug() } else { format!("{}-draw{draw}", c.slug()) };
                data.push(DataStage { dir: out.join("data").join(format!("{name}-{}", short(&h))), hash: h });
                drawn.push(dataset);
            }
        }
        let datasets = drawn;
        let n_conf = configurations.len();
        let ablation_rig = radar.iter().position(|&r| r);
        let mut jobs = Vec::new();
        // What each training step may use, read once for every job below.
        let memory = hilo_core::machine::memory_bytes();
        for (ci, conf) in configurations.iter().enumerate() {
            let ablations = profile.ablations.iter().filter(|_| ablation_rig == Some(ci));
            for preset in profile.presets.iter().chain(ablations) {
                let p = registry.preset(preset)?;
                let detector_cfg = patched_detector(study, preset, &p.detector, &profile.dataset)?;
                let schedule = scheduled(study, preset, &p.train)?;
                // Fields the study's `[train_schedule]` names win over the profile's.
                let named = |f: &str| study.file.train_schedule.as_ref().is_some_and(|s| s.get(f).is_some());
                let (samples, sampling) = (
                    profile.train_samples.filter(|_| !named("samples")),
                    profile.sampling.filter(|_| !named("sampling")),
                );
                if registry.uses_radar(&p.detector) && !radar[ci] {
                    skipped.push(format!("{preset} on {}: skipped (the configuration has no radar)", conf.name));
                    continue;
                }
                for (seed, draw) in (0..profile.traffic_draws.max(1) as u64)
                    .flat_map(|d| (0..profile.seeds as u64).map(move |seed| (seed, d)))
                {
                    let di = draw as usize * n_conf + ci;
                    // One replica: the study trains its detectors side by side, one core each
                    // (`stages::train_all`), so a schedule's data-parallel replicas would run one
                    // after the other on that core, no faster (and synchronised BatchNorm, which
                    // needs them at once, could not run).
                    let mut tc = TrainConfig { seed, replicas: 1, sync_batch_norm: false, ..schedule.clone() };
                    if let Some(n) = samples {
                        tc.samples = n;
                    }
                    if let Some(s) = sampling {
                        tc.sampling = s;
                    }
                    let steps = tc.steps();
                    let mut curve: Vec<usize> = if seed == 0 && draw == 0 {
                        profile
                            .curve
                            .iter()
                            .map(|f| ((f * steps as f64).round() as usize).clamp(1, steps) * tc.batch)
                            .filter(|&s| s < steps * tc.batch)
                            .collect()
                    } else {
                        Vec::new()
                    };
                    curve.sort_unstable();
                    curve.dedup();
                    let detector = serde_json::to_string(&detector_cfg)?;
                    let schedule = serde_json::to_string(&tc)?;
                    // The curve's points are trainings of this stage (`CurveKind::Budget`).
                    let points = format!("budget curve {curve:?}");
                    let h = stage_hash("run", &[&data[di].hash, &detector, &schedule, &points]);
                    let drawn = if draw == 0 { String::new() } else { format!("-draw{draw}") };
                    let name = format!("{preset}{drawn}-seed{seed}-{}", short(&h));
                    let detector = detector_cfg.clone().validate()?;
                    detector.check_memory(tc.batch, memory)?;
                    jobs.push(Job {
                        id: format!("{}/{preset}{drawn}-seed{seed}", conf.slug()),
                        configuration: ci,
                        data: di,
                        draw,
                        preset: preset.clone(),
                        seed,
                        run: out.join("runs").join(conf.slug()).join(&name),
                        results: out.join("results").join(conf.slug()).join(format!("{name}.json")),
                        detector,
                        train: tc.validate()?,
                        curve,
                        curve_kind: CurveKind::Budget,
                    });
                }
            }
        }
        Ok(Plan {
            profile: profile.clone(),
            out: out.to_path_buf(),
            fingerprint,
            configurations,
            radar,
            placed,
            conditions,
            datasets,
            placements,
            tradeoffs,
            data,
            jobs,
            skipped,
        })
    }

    /// The configuration and training-traffic draw of dataset stage `di`.
    pub fn data_stage(&self, di: usize) -> (usize, u64) {
        let n = self.configurations.len().max(1);
        (di % n, (di / n) as u64)
    }

    /// The dataset stage of configuration `ci` on training-traffic draw `draw`.
    pub fn data_index(&self, ci: usize, draw: u64) -> Result<usize> {
        let di = draw as usize * self.configurations.len() + ci;
        if ci < self.configurations.len() && di < self.data.len() {
            return Ok(di);
        }
        Err(StudyError::Argument {
            flag: "--draw",
            value: draw.to_string(),
            reason: format!(
                "this study trains on {} training-traffic draw(s), 0 first",
                self.profile.traffic_draws.max(1)
            ),
        })
    }

    /// A dataset stage's label: its configuration's name, and its draw when not the first.
    pub fn data_label(&self, di: usize) -> String {
        let (ci, draw) = self.data_stage(di);
        let name = &self.configurations[ci].name;
        if draw == 0 { name.clone() } else { format!("{name} (training-traffic draw {draw})") }
    }

    /// Where configuration `ci`'s placement is written.
    pub fn placement(&self, ci: usize) -> PathBuf {
        self.placements.join(format!("{}.json", self.configurations[self.placed[ci]].slug()))
    }

    /// The place stage's outputs.
    pub fn placement_outputs(&self) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> =
            (0..self.configurations.len()).filter(|&ci| self.placed[ci] == ci).map(|ci| self.placement(ci)).collect();
        v.push(self.tradeoffs.clone());
        v
    }

    /// Every stage (place, simulate per configuration, train per job, report), whether its
    /// output exists, and that output's path: one line each, as `hilo study plan` prints them.
    pub fn status(&self) -> String {
        let mark = |done: bool| if done { "done" } else { "to do" };
        let placed = self.placement_outputs().iter().all(|p| p.exists());
        let mut lines = vec![format!("place                     {}  {}", mark(placed), self.placements.display())];
        for (di, d) in self.data.iter().enumerate() {
            let (ci, draw) = self.data_stage(di);
            let slug = self.configurations[ci].slug();
            let name = if draw == 0 { slug } else { format!("{slug} --draw {draw}") };
            lines.push(format!("simulate {:<16} {}  {}", name, mark(d.done().exists()), d.dir.display()));
        }
        for j in &self.jobs {
            lines.push(format!("train {:<40} {}  {}", j.id, mark(j.done()), j.results.display()));
        }
        let report = self.out.join("report.json");
        lines.push(format!("report                    {}  {}", mark(report.exists()), report.display()));
        lines.join("\n")
    }

    /// Whether the study is complete: every placement and every training done, and its report
    /// (`report.json` and `report.md`) written after the last of the trainings' outputs. Every
    /// stage's hash holds the code's commit and the folder holds one study, so such a report is
    /// the one this code would write again; its datasets are not needed to keep it (they may be
    /// deleted to free the disk, as a long sweep wants).
    pub fn complete(&self) -> bool {
        let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
        let (Some(json), Some(_)) = (modified(&self.out.join("report.json")), modified(&self.out.join("report.md")))
        else {
            return false;
        };
        self.placement_outputs().iter().all(|p| p.exists())
            && self.jobs.iter().all(|j| j.outputs().iter().all(|p| modified(p).is_some_and(|t| t <= json)))
    }

    /// The number of stages a workflow file holds for this plan (place, one simulate per
    /// dataset, one train per job, report).
    pub fn stage_count(&self) -> usize {
        self.jobs.len() + self.data.len() + 2
    }

    /// A configuration by name or slug.
    pub fn configuration(&self, name: &str) -> Result<usize> {
        self.configurations.iter().position(|c| c.name == name || c.slug() == name).ok_or_else(|| {
            let names: Vec<&str> = self.configurations.iter().map(|c| c.name.as_str()).collect();
            StudyError::Unknown {
                what: "configuration",
                name: name.to_owned(),
                place: "this study's plan".into(),
                known: format!("it has {names:?}"),
            }
        })
    }

    /// A train stage by its id (`<configuration slug>/<preset>-seed<k>`).
    pub fn job(&self, id: &str) -> Result<&Job> {
        self.jobs.iter().find(|j| j.id == id).ok_or_else(|| StudyError::Unknown {
            what: "train stage",
            name: id.to_owned(),
            place: "this study's plan".into(),
            known: format!("ids look like {:?}", self.jobs.first().map_or("<slug>/<preset>-seed0", |j| j.id.as_str())),
        })
    }

    /// The file that records which study the folder holds.
    pub fn record_path(&self) -> PathBuf {
        self.out.join("study.json")
    }

    /// Claims the folder for this study: creates it and records the study (where it came from)
    /// and the profile; refuses a folder that holds another study or anything else.
    pub fn claim_folder(&self, study: &Study) -> Result<()> {
        let marker = self.record_path();
        if marker.exists() {
            let old: FolderRecord = read_json(&marker, limit::TABLE)?;
            // A study refused before any stage finished left only its record (and perhaps
            // workflow files and logs): taking the folder over loses nothing, and the
            // corrected rerun must not be blocked by it.
            if old.fingerprint != self.fingerprint && holds_stage_output(&self.out) {
                return Err(StudyError::folder(
                    &self.out,
                    format!(
                        "holds another study (study file, profile or seeds differ: fingerprint {} there, {} now); choose another --out",
                        old.fingerprint, self.fingerprint
                    ),
                ));
            }
            if old.fingerprint == self.fingerprint {
                return Ok(());
            }
        } else if self.out.exists() && std::fs::read_dir(&self.out).map(|mut d| d.next().is_some()).unwrap_or(false) {
            return Err(StudyError::folder(&self.out, "exists and is not a study folder; choose another --out"));
        }
        std::fs::create_dir_all(&self.out).map_err(|e| hilo_core::fs::FileError::io(&self.out, e))?;
        let record = FolderRecord {
            fingerprint: self.fingerprint.clone(),
            study: study.source.clone(),
            shard: study.shard.clone(),
            profile: self.profile.clone(),
        };
        Ok(write_json(&marker, &record)?)
    }
}

/// What of the study's traffic the placements depend on, for their hash: with a calibrated
/// objective over road users the traffic's settings decide the placements too (and only then,
/// so other hashes stay), and the point-count term's k (`[validation] min_points`) with them (the
/// footprint term reads the same traffic); a
/// calibration file's prediction model decides what each placement predicts.
fn placement_traffic(study: &Study) -> String {
    let file = study.calibration.as_ref().map_or(String::new(), |c| format!(" calibration file {c:?}"));
    file + &match (study.placement.objective, &study.placement.calibration) {
        (hilo_placement_ip::pipeline::ObjectiveKind::Calibrated, Some(w)) if w.reads_points() => {
            format!("{:?} points k = {}", study.dataset, study.file.validation.min_points)
        }
        (hilo_placement_ip::pipeline::ObjectiveKind::Calibrated, Some(w)) if w.reads_extents() => {
            format!("{:?} footprint", study.dataset)
        }
        (hilo_placement_ip::pipeline::ObjectiveKind::Calibrated, Some(w)) if w.reads_road_users() => {
            format!("{:?}", study.dataset)
        }
        _ => String::new(),
    }
}

/// The configurations the study's weather conditions record again (each with the index of the
/// configuration it copies), and every configuration's condition and dataset settings: the
/// profile's configurations first, in the study's own weather. A condition's configuration the
/// profile leaves out is skipped, and said so in `skipped`.
#[allow(clippy::type_complexity)]
fn conditioned(
    study: &Study,
    profile: &Profile,
    base: &[Configuration],
    skipped: &mut Vec<String>,
) -> Result<(Vec<(usize, Configuration)>, Vec<Option<String>>, Vec<Valid<hilo_dataset::simulate::SimulateConfig>>)> {
    let mut out = Vec::new();
    let mut conditions = vec![None; base.len()];
    let mut datasets = vec![profile.dataset.clone(); base.len()];
    for cond in study.file.conditions.iter().take(profile.conditions.unwrap_or(usize::MAX)) {
        let dataset =
            hilo_dataset::simulate::SimulateConfig { weather: cond.weather, ..profile.dataset.clone().into_inner() }
                .validate()
                .map_err(|e| StudyError::step(format!("{}: conditions ({:?})", study.source, cond.name), e))?;
        for name in &cond.configurations {
            let Some(bi) = base.iter().position(|c| c.name == *name) else {
                skipped.push(format!(
                    "{}: skipped (profile {} leaves the configuration {name:?} out)",
                    cond.label(name),
                    profile.name
                ));
                continue;
            };
            // Its given rig is that rig's copy in the same weather (the poses are the clear-air
            // ones either way).
            let given = base[bi].given.as_ref().map(|g| cond.label(g));
            out.push((bi, Configuration { name: cond.label(name), given, ..base[bi].clone() }));
            conditions.push(Some(cond.name.clone()));
            datasets.push(dataset.clone());
        }
    }
    Ok((out, conditions, datasets))
}

/// Whether a study folder holds a file a stage wrote: anything but the folder's record, the
/// workflow files and the logs of a workflow engine.
fn holds_stage_output(out: &Path) -> bool {
    const NOT_OUTPUT: [&str; 6] = ["study.json", "Snakefile", "config.yaml", "logs", "benchmarks", ".snakemake"];
    std::fs::read_dir(out).is_ok_and(|d| {
        d.filter_map(|e| e.ok())
            .filter(|e| !NOT_OUTPUT.iter().any(|n| e.file_name() == *n))
            .any(|e| e.file_type().is_ok_and(|t| !t.is_dir()) || hilo_core::fs::holds_file(&e.path()))
    })
}

/// What a study folder records about its study (`study.json`): enough for a single stage, run
/// by a workflow engine in another process, to rebuild the same plan.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FolderRecord {
    pub fingerprint: String,
    /// The study file's path (absolute), or `<embedded>/…` for a built-in study.
    pub study: String,
    /// The study's name within a study file that lists several scenes or catalogs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<String>,
    pub profile: Profile,
}

impl FolderRecord {
    /// Reads `<out>/study.json`.
    pub fn read(out: &Path) -> Result<FolderRecord> {
        let p = out.join("study.json");
        if !p.exists() {
            return Err(StudyError::NotReady {
                path: out.to_path_buf(),
                what: "not a study folder (no study.json)".into(),
                remedy: format!("run `hilo study --out {}` or `--workflow snakemake` first", out.display()),
            });
        }
        Ok(read_json(&p, limit::TABLE)?)
    }
}

/// A preset's detector config with the study's `[detector_patch]` applied (the preset's own
/// without one), detecting cyclists when the dataset's traffic carries them. The patch may not
/// rename the preset or change its fusion plugin (the verdict reads both), and stacked LiDAR
/// sweeps need datasets that record them.
pub fn patched_detector(
    study: &Study,
    preset: &str,
    det: &DetectorConfig,
    dataset: &hilo_dataset::simulate::SimulateConfig,
) -> Result<DetectorConfig> {
    // Traffic with cyclists gives every detector the cyclist's head channel.
    let cyclists = dataset.traffic.carries(hilo_core::Class::Bicycle);
    let Some(patch) = &study.file.detector_patch else {
        return Ok(DetectorConfig { cyclists: det.cyclists || cyclists, ..det.clone() });
    };
    let bad =
        |reason: String| StudyError::PresetChange { section: "detector_patch", preset: preset.to_owned(), reason };
    let mut p = det.with_patch(patch).map_err(|e| bad(e.to_string()))?;
    p.cyclists |= cyclists;
    if p.name != det.name || p.fusion != det.fusion {
        return Err(bad(format!(
            "changes the preset's name or fusion plugin ({:?}, {:?} from {:?}, {:?}); patch a preset's settings, not what it is",
            p.name, p.fusion, det.name, det.fusion
        )));
    }
    if p.input.lidar_sweeps > 1 && !dataset.lidar_sweeps {
        return Err(bad(format!(
            "input.lidar_sweeps = {} stacks LiDAR sweeps, but [dataset] lidar_sweeps = false records LiDAR only at key frames (the validation split's are 1 / val_rate_hz apart); set `lidar_sweeps = true` under [dataset]",
            p.input.lidar_sweeps
        )));
    }
    Ok(p)
}

/// A preset's training schedule with the study's `[train_schedule]` fields over it (the
/// preset's own without the section). Fields the study sets itself per job (the seed, the kept
/// checkpoints, one replica per training) are refused rather than silently replaced.
pub fn scheduled(study: &Study, preset: &str, train: &TrainConfig) -> Result<TrainConfig> {
    let Some(fields) = &study.file.train_schedule else { return Ok(train.clone()) };
    let bad =
        |reason: String| StudyError::PresetChange { section: "train_schedule", preset: preset.to_owned(), reason };
    for own in ["seed", "keep", "replicas", "sync_batch_norm"] {
        if let Some(v) = fields.get(own) {
            return Err(bad(format!(
                "{own} = {v}: the study sets it for each training (seeds from the profile, the learning curve's checkpoints, one replica per training)"
            )));
        }
    }
    train
        .with_fields(fields)
        .map_err(|e| bad(e.to_string()))?
        .validate()
        .map(|v| v.into_inner())
        .map_err(|e| bad(e.to_string()))
}

/// The parts of a study file that define what its stages compute, as text for the folder's
/// fingerprint: everything but the `[verdict]` settings, which only change how the report
/// judges (a new margin rewrites the report, not the trained detectors), and the `[validation]`
/// settings, which only `hilo validate` reads. Written as the file's
/// derived `Debug` was before the section existed (and without `conditions` or
/// `detector_patch` when there are none), so folders made then still open.
fn defining(f: &crate::study::StudyFile) -> String {
    let conditions = if f.conditions.is_empty() { String::new() } else { format!(", conditions: {:?}", f.conditions) };
    let patch = f.detector_patch.as_ref().map_or(String::new(), |p| format!(", detector_patch: Some({p:?})"));
    let schedule = f.train_schedule.as_ref().map_or(String::new(), |s| format!(", train_schedule: Some({s:?})"));
    let junction = f.junction.as_ref().map_or(String::new(), |j| format!(", junction: Some({j:?})"));
    let calibration = f.calibration_file.as_ref().map_or(String::new(), |c| format!(", calibration_file: Some({c:?})"));
    format!(
        "StudyFile {{ scene: {:?}, catalog: {:?}, placement: {:?}, dataset: {:?}, configurations: {:?}{conditions}{patch}{schedule}{junction}{calibration} }}",
        f.scene, f.catalog, f.placement, f.dataset, f.configurations
    )
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The fingerprint's text is the study file's own `Debug` without its `[verdict]`,
    /// `[validation]` and `[evaluation]` sections (they change no stage, only the report): a
    /// field added to the file and left out here (or the other way round) fails.
    #[test]
    fn the_fingerprint_reads_every_field_but_the_verdict_settings() {
        let text = include_str!("../../../fixtures/study.toml");
        let file: crate::study::StudyFile = toml::from_str(text).unwrap();
        // The file's `Debug` without the report-only sections and the given absent fields.
        let shown = |f: &crate::study::StudyFile, absent: &[&str]| {
            let mut t = format!("{f:?}")
                .replace(&format!(", verdict: {:?}", f.verdict), "")
                .replace(&format!(", validation: {:?}", f.validation), "")
                .replace(&format!(", evaluation: {:?}", f.evaluation), "");
            for a in absent {
                t = t.replace(a, "");
            }
            t
        };
        let none = [", detector_patch: None", ", train_schedule: None", ", junction: None", ", calibration_file: None"];
        let whole = shown(&file, &none);
        assert_eq!(defining(&file), whole);
        // A calibration file is part of it.
        let calibrated =
            crate::study::StudyFile { calibration_file: Some("calibration-sites.toml".into()), ..file.clone() };
        assert_eq!(defining(&calibrated), shown(&calibrated, &none[..3]));
        // The junction of an OpenDRIVE scene is part of it.
        let junction = crate::study::StudyFile {
            junction: Some(hilo_raycast::scene::opendrive::JunctionPick::id("146")),
            ..file.clone()
        };
        assert_eq!(
            defining(&junction),
            shown(&junction, &[", detector_patch: None", ", train_schedule: None", ", calibration_file: None"])
        );
        // A detector patch is part of it.
        let patched = crate::study::StudyFile {
            detector_patch: Some(serde_json::json!({ "velocity_weight": 2.0 })),
            ..file.clone()
        };
        assert_eq!(
            defining(&patched),
            shown(&patched, &[", train_schedule: None", ", junction: None", ", calibration_file: None"])
        );
        // So is a training schedule.
        let scheduled =
            crate::study::StudyFile { train_schedule: Some(serde_json::json!({ "batch": 16 })), ..file.clone() };
        assert_eq!(
            defining(&scheduled),
            shown(&scheduled, &[", detector_patch: None", ", junction: None", ", calibration_file: None"])
        );
        // Without conditions the text is what it was before they existed.
        let bare = crate::study::StudyFile { conditions: Vec::new(), ..file };
        let whole = shown(
            &bare,
            &[
                ", conditions: []",
                ", detector_patch: None",
                ", train_schedule: None",
                ", junction: None",
                ", calibration_file: None",
            ],
        );
        assert_eq!(defining(&bare), whole);
    }
}
