//! Does the placement objective predict trained accuracy? (`hilo validate`)
//!
//! The placement IP proves its answer optimal for its objective; this crate asks whether the
//! objective orders placements as trained detectors do. It draws a set of placements of the
//! study's scene ([`set`]), computes predictors without training (the paper's objective, the
//! objective over the modalities a rig offers, LiDAR, radar and central coverage, and the
//! occupancy of the study's simulated traffic: the share of road users hit by at least k LiDAR
//! points, points per road user, the share with a radar point), simulates every placement with
//! the same traffic, trains one detector per placement and seed (the fusion preset where the
//! rig has a radar, its LiDAR-only counterpart with the same head otherwise) to 2b samples,
//! keeping the weights at b, scores both on the common ground truth under the study's scene
//! bootstrap, and reports Spearman's ρ and Kendall's τ of every predictor with mAP and
//! pedestrian AP, with intervals from a bootstrap over placements, scenes and trainings ([`rank`], [`resample`]),
//! and τ between the accuracies at b and 2b (does the budget rank placements as longer
//! training would?). Rigs of the set whose LiDARs stand at identical poses and that differ only
//! in their radars are compared pair by pair ([`same_lidars`]): what the radars add, with
//! nothing of the LiDARs' poses in it, and whether the objective's radar terms say so.
//!
//! A calibrated objective ([`calibrate`]) is fitted to these measurements and scored by
//! cross-fitting; `[placement] objective = "calibrated"` places with it
//! ([`hilo_placement_ip::calibrated`]). The rig it buys under the study's budget is then
//! trained as the members were and set beside its prediction and the best configuration of the
//! study at equal or lower cost ([`recommend`]); [`absorb`] adds that trained rig to the set and
//! fits again, so the next recommendation is placed by a fit that knows how the last one
//! trained (sets drawn before the rigs of five to eight sensors had one to four). Cross-fitting
//! within one set shares that set's traffic and junction and may have chosen the objective's
//! form from its residuals; `--transfer` predicts the placements of a second set (other seeds)
//! with the first set's weights frozen ([`calibrate::transfer`]), and `--sites` holds each of
//! several junctions' validations out in turn, fitting on the others ([`sites`]), each held-out
//! ρ set beside its site's noise ceiling ([`ceiling`]); a calibration
//! `--sites` wrote without this junction buys, its weights frozen, the rig a user at a new
//! junction would buy, trained here beside the set's rigs near its budget
//! ([`recommend::frozen`]). It runs in one process ([`run`]) or as a
//! workflow engine's jobs ([`plan`] draws the set and names the stages, [`simulate`] and
//! [`train_job`] run one each, `hilo_study::workflow::validation_snakefile` writes them); its stage
//! folders are named by hashes that include the code, so a run is resumed by the same build
//! (`--refit`, `--recommend` and `--absorb` read a finished run's `validation.json` with any
//! later build).
//!
//! Layout of its folder (every stage resumable; a stage's folder is named by the hash of
//! what decides it):
//!
//! ```text
//! set/<h>/set.json, <member>.json        the placement set and its predictors
//! data/<member>-<h>/                     a member's dataset (the study's traffic)
//! runs/<member>/<preset>-seed<k>-<h>/    a trained detector
//! results/<member>/…json                 its detections at 2b and at b
//! recommendation/<member>.json, .png     a recommendation (the set's own, or a frozen calibration's)
//!                                        and its mounts on the site (then data/, runs/, results/)
//! validation.json, validation.md, validation-*.png/svg
//! ```

pub mod calibrate;
pub mod ceiling;
pub mod occupancy;
pub mod rank;
pub mod recommend;
pub mod resample;
pub mod same_lidars;
pub mod set;
pub mod sites;

/// Synthetic validation sets for the tests of [`calibrate`] and [`sites`]: members without
/// sensors, with predictors and a measured mAP given, and the report around them.
#[cfg(test)]
#[allow(clippy::unwrap_used)]
pub(crate) mod testing {
    use super::{Trained, ValidationReport, ValidationSettings};
    use crate::rank::Agreement;
    use crate::set::Member;
    use rand::Rng;
    use std::collections::BTreeMap;

    /// Member `p{i}`: no sensors, these predictors, mAP `map` from one seed, and `replicates`
    /// scene-bootstrap scores within ±0.005 of it (drawn from `rng`).
    pub fn member(
        i: usize,
        predictors: BTreeMap<String, Option<f64>>,
        map: f64,
        replicates: usize,
        rng: &mut impl Rng,
    ) -> (Member, Trained) {
        let placement: hilo_placement_ip::Placement = serde_json::from_value(serde_json::json!({
            "name": format!("p{i}"), "sensors": [], "objective": 0.0, "bound": null, "gap": null,
            "proven_optimal": false, "solve_seconds": 0.0, "method": "", "solved": false,
            "greedy_objective": 0.0, "central_coverage": 0.0, "lidar_radar_overlap": 0.0,
            "cost_usd": 0.0, "targets": 0, "candidates": 0, "scene_hash": "", "catalog_hash": ""
        }))
        .unwrap();
        let m = Member {
            slug: format!("p{i}"),
            kind: "random".into(),
            configuration: String::new(),
            placement,
            predictors,
        };
        let t = Trained {
            preset: String::new(),
            map: vec![map],
            draw: Vec::new(),
            map_mean: map,
            map_at_b: vec![map],
            map_at_b_mean: map,
            pedestrian_ap_mean: map,
            pedestrian_ap: Vec::new(),
            class_ap: BTreeMap::new(),
            map_replicates: (0..replicates).map(|_| map + rng.random_range(-0.005..0.005)).collect(),
            pedestrian_replicates: vec![map; replicates],
            train_s: 0.0,
        };
        (m, t)
    }

    /// The coarse validation fixture's study (`fixtures/validation-coarse.toml`).
    pub fn study() -> hilo_plan::study::Study {
        let text = include_str!("../../../fixtures/validation-coarse.toml");
        hilo_plan::study::Study::parse(text, std::path::Path::new("."), "validation-coarse.toml").unwrap()
    }

    /// The report of `members` (study and profile named as given), nothing scored or fitted.
    pub fn report(members: Vec<(Member, Trained)>, resamples: usize, study: &str, profile: &str) -> ValidationReport {
        let none = Agreement { value: f64::NAN, lo: f64::NAN, hi: f64::NAN, n: 0 };
        ValidationReport {
            study: study.to_owned(),
            profile: profile.to_owned(),
            settings: ValidationSettings::default(),
            provenance: hilo_plan::plan::Provenance::here(1),
            validation_scenes: 0,
            resamples,
            members,
            predictors: Vec::new(),
            budget_spearman: none,
            budget_kendall: none,
            seed_spearman: None,
            draw_spearman: None,
            calibrated: None,
            recommendation: None,
            frozen: Vec::new(),
            transfer: None,
            seconds: 0.0,
        }
    }
}

use crate::rank::{Agreement, agreement};
use hilo_core::fs::{FileError, limit, read_json, write_json};
use hilo_detector::Registry;
use hilo_detector::train::TrainConfig;
use hilo_eval::DetectionConfig;
use hilo_eval::bootstrap::Reweighable;
use hilo_plan::error::{Result, StudyError};
use hilo_plan::files::hash;
use hilo_plan::gt::scene_draws;
use hilo_plan::gt::{GtKind, SampleKey, ground_truth, rekey};
use hilo_plan::plan::{CurveKind, DataStage, Job, Provenance, short, stage_hash};
use hilo_plan::profile::Profile;
use hilo_plan::stages::{Predictions, Progress};
use hilo_plan::study::Study;
use serde::{Deserialize, Serialize};
use set::Member;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The `[validation]` section of a study file (a section of the study file, defined with it).
pub use hilo_plan::study::ValidationSettings;

/// One member's trained accuracy: per seed, at b and at 2b.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trained {
    pub preset: String,
    /// mAP per training at 2b (draw 0's seeds, then each later training-traffic draw's), and
    /// its mean.
    pub map: Vec<f64>,
    /// The training-traffic draw of each training in `map` (empty: all on draw 0).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub draw: Vec<u64>,
    pub map_mean: f64,
    /// mAP per seed at b.
    pub map_at_b: Vec<f64>,
    pub map_at_b_mean: f64,
    pub pedestrian_ap_mean: f64,
    /// Pedestrian AP at 2b per training, in the order of `map` (empty in sets from before it
    /// was recorded).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pedestrian_ap: Vec<f64>,
    /// Per class, AP averaged over trainings at 2b.
    pub class_ap: BTreeMap<String, f64>,
    /// mAP and pedestrian AP at 2b (mean over trainings) under each scene-bootstrap replicate.
    pub map_replicates: Vec<f64>,
    pub pedestrian_replicates: Vec<f64>,
    pub train_s: f64,
}

/// One predictor's agreement with the accuracy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PredictorRow {
    pub predictor: String,
    pub spearman_map: Agreement,
    pub kendall_map: Agreement,
    pub spearman_pedestrian: Agreement,
    pub kendall_pedestrian: Agreement,
    /// Where it is undefined (rigs of one modality for the paper's objective).
    pub undefined_for: Vec<String>,
}

/// What `validation.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ValidationReport {
    pub study: String,
    pub profile: String,
    pub settings: ValidationSettings,
    pub provenance: Provenance,
    pub validation_scenes: usize,
    /// Scene-bootstrap replicates behind the intervals.
    pub resamples: usize,
    pub members: Vec<(Member, Trained)>,
    pub predictors: Vec<PredictorRow>,
    /// Does the budget rank placements as longer training would? mAP at b against mAP at 2b.
    pub budget_spearman: Agreement,
    pub budget_kendall: Agreement,
    /// Two trainings of the same placements (seed 0 against seed 1, mAP at 2b): how well any
    /// predictor could rank the set, given the training's own noise (None with one seed).
    #[serde(default)]
    pub seed_spearman: Option<Agreement>,
    /// Two training-traffic draws of the same placements (draw 0 against draw 1, each the mean
    /// of its seeds): the ceiling once the traffic a detector trained on varies too (None with
    /// one draw).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draw_spearman: Option<Agreement>,
    /// The calibrated objective, fitted on the set and scored by cross-fitting.
    #[serde(default)]
    pub calibrated: Option<calibrate::Calibrated>,
    /// The rig it buys under the study's budget, trained.
    #[serde(default)]
    pub recommendation: Option<recommend::Recommendation>,
    /// The rigs calibrations fitted at other junctions buy here, their weights frozen, trained
    /// (`hilo validate --recommend --calibration FILE [--budget USD]`), in order of budget.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frozen: Vec<recommend::Recommendation>,
    /// The calibrated objective of another validation set predicting this one, its weights
    /// frozen (`hilo validate --transfer`).
    #[serde(default)]
    pub transfer: Option<calibrate::Transfer>,
    pub seconds: f64,
}

/// The folder's record: which validation it holds, and what a stage run alone (by a workflow
/// engine's job) needs to take it up: the study's source, the profile and the settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct FolderRecord {
    fingerprint: String,
    /// The study file's absolute path, or the embedded default's name.
    study: String,
    #[serde(default)]
    profile: Option<Profile>,
    #[serde(default)]
    settings: Option<ValidationSettings>,
}

/// What the validation in `out` records for a stage run alone: its study's source (an absolute
/// path or the embedded default's name), profile and settings.
pub fn record(out: &Path) -> Result<(String, Profile, ValidationSettings)> {
    let r: FolderRecord = read_json(&out.join("validation-folder.json"), limit::TABLE)?;
    match (r.profile, r.settings) {
        (Some(profile), Some(settings)) => Ok((r.study, profile, settings)),
        _ => Err(StudyError::folder(
            out,
            "written by an older hilo that did not record the profile and settings; run the validation again in one process",
        )),
    }
}

/// Claims `out` for this validation (refuses a folder that holds anything else).
fn claim(out: &Path, fingerprint: &str, study: &Study, profile: &Profile, settings: &ValidationSettings) -> Result<()> {
    let record = out.join("validation-folder.json");
    let mine = FolderRecord {
        fingerprint: fingerprint.to_owned(),
        study: study.source.clone(),
        profile: Some(profile.clone()),
        settings: Some(settings.clone()),
    };
    if record.exists() {
        let old: FolderRecord = read_json(&record, limit::TABLE)?;
        if old.fingerprint != fingerprint {
            return Err(StudyError::folder(
                out,
                "holds another validation (study, settings or profile differ); choose another --out",
            ));
        }
        if old.profile.is_none() {
            write_json(&record, &mine)?;
        }
        return Ok(());
    }
    if out.exists() && std::fs::read_dir(out).map(|mut d| d.next().is_some()).unwrap_or(false) {
        return Err(StudyError::folder(out, "exists and is not a validation folder; choose another --out"));
    }
    std::fs::create_dir_all(out).map_err(|e| hilo_core::fs::FileError::io(out, e))?;
    Ok(write_json(&record, &mine)?)
}

/// The stages of a validation, known once its placement set is drawn: what `run` does in one
/// process and a workflow engine does as one job per placement (simulate) and per placement ×
/// seed (train).
#[derive(Clone, Debug)]
pub struct ValidationPlan {
    pub out: PathBuf,
    pub members: Vec<Member>,
    /// The set stage's folder (`set/<h>/`), its `set.json` written last.
    pub set_dir: PathBuf,
    /// Per training-traffic draw, per member, its dataset stage ([`ValidationPlan::data_index`]):
    /// draw 0 first, whose validation scenes every draw shares.
    pub data: Vec<DataStage>,
    /// Every training, `configuration` the member's index.
    pub jobs: Vec<Job>,
    /// The settings with both presets named ([`ValidationSettings::resolved`]).
    pub settings: ValidationSettings,
}

impl ValidationPlan {
    pub fn set_file(&self) -> PathBuf {
        self.set_dir.join("set.json")
    }

    /// The index in `data` of member `member`'s dataset on training-traffic draw `draw`.
    pub fn data_index(&self, member: usize, draw: u64) -> usize {
        data_index(self.members.len(), member, draw)
    }

    /// How progress names that dataset: the member's slug, with the draw after draw 0.
    fn data_name(&self, member: usize, draw: u64) -> String {
        let slug = &self.members[member].slug;
        if draw == 0 { slug.clone() } else { format!("{slug} (traffic draw {draw})") }
    }

    fn member(&self, slug: &str) -> Result<usize> {
        self.members.iter().position(|m| m.slug == slug).ok_or_else(|| StudyError::Unknown {
            what: "placement",
            name: slug.to_owned(),
            place: format!("the validation in {}", self.out.display()),
            known: format!("it has {}", self.members.iter().map(|m| m.slug.as_str()).collect::<Vec<_>>().join(", ")),
        })
    }
}

/// What defines the validation of `study` at `profile` with `settings`: the study's defining
/// sections as text (what the placement set depends on), and the fingerprint of all of it
/// with the scene and catalog.
fn fingerprint(
    study: &Study,
    registry: &Registry,
    profile: &Profile,
    settings: &ValidationSettings,
) -> Result<(String, String)> {
    let sjson = serde_json::to_string(settings)?;
    // The study's weather conditions are no part of the validation (its placements are recorded
    // in the study's own weather), so a profile that runs them defines the same validation.
    let pjson = serde_json::to_string(&Profile { conditions: Some(0), ..profile.clone() })?;
    // A configuration's `given` is no part of it either: the set places every configuration for
    // itself (and a folder made before a study named one still opens), and leaves out those
    // placed `apart` from a given rig ([`set::set_configurations`]).
    let configurations: Vec<_> = study
        .file
        .configurations
        .iter()
        .filter(|c| !c.apart)
        .map(|c| hilo_plan::study::Configuration { given: None, ..c.clone() })
        .collect();
    let defining = format!("{:?}{:?}{:?}", study.file.placement, study.file.dataset, configurations);
    // What changes the trainings (not the set) joins the fingerprint only when it changes what
    // the validation trains, so folders made before the validation read these sections, and a
    // study file that writes out the presets' own settings, still open.
    let mut trains = String::new();
    if changes_trainings(study, registry, profile, settings)? {
        if let Some(p) = &study.file.detector_patch {
            trains.push_str(&format!(" detector_patch: {p:?}"));
        }
        if let Some(t) = &study.file.train_schedule {
            trains.push_str(&format!(" train_schedule: {t:?}"));
        }
    }
    let fingerprint = hash(&[&format!("{defining}{trains}"), &sjson, &pjson, &study.scene_hash, &study.catalog_hash]);
    Ok((defining, fingerprint))
}

/// Whether the study's `[detector_patch]` or `[train_schedule]` makes the validation's presets
/// (its LiDAR-only and its fusion preset) train otherwise than as the presets do.
fn changes_trainings(
    study: &Study,
    registry: &Registry,
    profile: &Profile,
    settings: &ValidationSettings,
) -> Result<bool> {
    if study.file.detector_patch.is_none() && study.file.train_schedule.is_none() {
        return Ok(false);
    }
    for radar in [false, true] {
        // Settings recorded before the presets were resolved: the sections count as given.
        let Ok(name) = settings.preset_for(radar) else { return Ok(true) };
        let p = registry.preset(name)?;
        let det = hilo_plan::plan::patched_detector(study, name, &p.detector, &profile.dataset)?;
        let train = hilo_plan::plan::scheduled(study, name, &p.train)?;
        if serde_json::to_value(&det)? != serde_json::to_value(&p.detector)?
            || serde_json::to_value(&train)? != serde_json::to_value(&p.train)?
        {
            return Ok(true);
        }
    }
    Ok(false)
}

/// Refuses `study` for work on the finished validation in `out` (`--refit`, `--absorb`) unless
/// it is the study validated there: its scene, catalog, placement, traffic, configurations and
/// training sections, under the recorded profile and settings. Another study's predictors
/// would be fitted against trainings they did not produce.
fn check_same_study(study: &Study, registry: &Registry, out: &Path) -> std::result::Result<(), StudyError> {
    let r: FolderRecord = read_json(&out.join("validation-folder.json"), limit::TABLE)?;
    let (Some(profile), Some(settings)) = (&r.profile, &r.settings) else { return Ok(()) };
    if fingerprint(study, registry, profile, settings)?.1 != r.fingerprint {
        return Err(StudyError::folder(
            out,
            format!(
                "the study given ({}) is not the one validated there ({}): its scene, catalog, placement, \
                 [dataset] traffic, configurations or training sections differ; give the validated study, or \
                 validate this one in another folder",
                study.source, r.study
            ),
        ));
    }
    Ok(())
}

/// Claims `out` for the validation of `study` at the scale of `profile`, draws (or reads) its
/// placement set and names every stage.
pub fn plan(
    study: &Study,
    registry: &Registry,
    profile: &Profile,
    settings: &ValidationSettings,
    out: &Path,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<ValidationPlan> {
    let settings = &settings.resolved(registry, &study.source)?;
    let sjson = serde_json::to_string(settings)?;
    let (defining, fingerprint) = fingerprint(study, registry, profile, settings)?;
    claim(out, &fingerprint, study, profile, settings)?;
    // 1. The set.
    let set_hash = stage_hash("validation-set", &[&defining, &sjson, &study.scene_hash, &study.catalog_hash]);
    let set_dir = out.join("set").join(short(&set_hash));
    let set_file = set_dir.join("set.json");
    let members: Vec<Member> = match read_json(&set_file, limit::TABLE) {
        Ok(m) => m,
        Err(_) => {
            progress(Progress::Stage("validation: drawing the placement set"));
            let m = set::placement_set(study, settings, &mut |l| progress(Progress::Stage(l)))?;
            for x in &m {
                hilo_core::fs::write_atomic(
                    &set_dir.join(format!("{}.json", x.slug)),
                    x.placement.to_json()?.as_bytes(),
                )?;
            }
            write_json(&set_file, &m)?;
            m
        }
    };
    // 2. Datasets per member and training-traffic draw, the study's traffic; 3. trainings.
    let mut data = Vec::new();
    for draw in 0..settings.traffic_draws as u64 {
        for m in &members {
            data.push(member_data(out, &set_hash, &m.slug, &profile.dataset, draw)?.0);
        }
    }
    let jobs = jobs(study, &members, &data, registry, profile, settings, out)?;
    Ok(ValidationPlan { out: out.to_owned(), members, set_dir, data, jobs, settings: settings.clone() })
}

/// The dataset stage of a placement named `slug` on training-traffic draw `draw` (draw 0 the
/// study's own traffic; another draw records the training scenes with other traffic and keeps
/// the validation scenes), `decides` what else names it, with the dataset settings it records.
pub(crate) fn member_data(
    out: &Path,
    decides: &str,
    slug: &str,
    dataset: &hilo_core::Valid<hilo_dataset::simulate::SimulateConfig>,
    draw: u64,
) -> Result<(DataStage, hilo_core::Valid<hilo_dataset::simulate::SimulateConfig>)> {
    let dataset = drawn(dataset, draw)?;
    let h = stage_hash("data", &[decides, slug, &format!("{dataset:?}")]);
    let name = if draw == 0 { slug.to_owned() } else { format!("{slug}-draw{draw}") };
    Ok((DataStage { dir: out.join("data").join(format!("{name}-{}", short(&h))), hash: h }, dataset))
}

/// `dataset` with its training scenes on training-traffic draw `draw`.
fn drawn(
    dataset: &hilo_core::Valid<hilo_dataset::simulate::SimulateConfig>,
    draw: u64,
) -> Result<hilo_core::Valid<hilo_dataset::simulate::SimulateConfig>> {
    Ok(hilo_dataset::simulate::SimulateConfig { train_traffic_draw: draw, ..(**dataset).clone() }.validate()?)
}

/// The index in a validation's dataset stages of member `member` of `members` on draw `draw`:
/// draw by draw, members in order within each.
fn data_index(members: usize, member: usize, draw: u64) -> usize {
    draw as usize * members + member
}

/// Records one member's datasets, one per training-traffic draw (each skipped when done).
pub fn simulate(
    study: &Study,
    profile: &Profile,
    plan: &ValidationPlan,
    slug: &str,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<()> {
    let i = plan.member(slug)?;
    let m = &plan.members[i];
    let ppath = plan.set_dir.join(format!("{}.json", m.slug));
    for draw in 0..plan.settings.traffic_draws as u64 {
        let d = &plan.data[plan.data_index(i, draw)];
        if d.done().exists() {
            continue;
        }
        let dataset = drawn(&profile.dataset, draw)?;
        hilo_plan::stages::record_dataset(
            study,
            &m.placement,
            &ppath,
            &dataset,
            d,
            &plan.data_name(i, draw),
            progress,
        )?;
    }
    Ok(())
}

/// Trains the jobs of one member (all of them, or the one named `only`), skipping those done:
/// each draw's on that draw's dataset.
pub fn train(
    registry: &Registry,
    profile: &Profile,
    plan: &ValidationPlan,
    member: usize,
    only: Option<&str>,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Vec<(Job, hilo_plan::stages::JobOutput)>> {
    let mut outs = Vec::new();
    for draw in 0..plan.settings.traffic_draws as u64 {
        let di = plan.data_index(member, draw);
        let mine: Vec<&Job> = plan
            .jobs
            .iter()
            .filter(|j| j.configuration == member && j.data == di && only.is_none_or(|id| j.id == id))
            .collect();
        if mine.is_empty() {
            continue;
        }
        let label = format!("training on {} ({} of {})", plan.data_name(member, draw), member + 1, plan.members.len());
        outs.extend(train_on(registry, profile, &plan.data[di].dir, mine, &label, progress)?);
    }
    Ok(outs)
}

/// Trains `jobs` on the dataset in `data` (skipping those done), telling `progress` their share
/// done under `label`: one placement's trainings, of the set or the recommendation.
pub(crate) fn train_on(
    registry: &Registry,
    profile: &Profile,
    data: &Path,
    jobs: Vec<&Job>,
    label: &str,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Vec<(Job, hilo_plan::stages::JobOutput)>> {
    let shared = std::sync::Mutex::new(&mut *progress);
    let tick = |_: &Job, f: f64| {
        if let Ok(mut p) = shared.lock() {
            p(Progress::Task { label, done: (f * 1000.0) as usize, total: 1000, unit: "‰" });
        }
    };
    let outs = hilo_plan::stages::train_jobs(data, &jobs, registry, profile.trainings_at_once, &tick)?;
    progress(Progress::TaskDone);
    Ok(jobs.into_iter().cloned().zip(outs).collect())
}

/// Trains one job by its id (`<member>/<preset>-seed<k>`, as the Snakefile names it).
pub fn train_job(
    registry: &Registry,
    profile: &Profile,
    plan: &ValidationPlan,
    id: &str,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<()> {
    let j = plan.jobs.iter().find(|j| j.id == id).ok_or_else(|| StudyError::Unknown {
        what: "training",
        name: id.to_owned(),
        place: format!("the validation in {}", plan.out.display()),
        known: format!("{} trainings", plan.jobs.len()),
    })?;
    train(registry, profile, plan, j.configuration, Some(id), progress).map(|_| ())
}

/// Runs (or resumes) the validation of `study` in `out` at the scale of `profile` (its dataset
/// settings, sampling, scene-bootstrap replicates and trainings at once).
pub fn run(
    study: &Study,
    registry: &Registry,
    profile: &Profile,
    settings: &ValidationSettings,
    out: &Path,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<ValidationReport> {
    let t0 = std::time::Instant::now();
    let plan = plan(study, registry, profile, settings, out, progress)?;
    // The presets by name (the registry's where the study file gives none), as the report records them.
    let settings = &plan.settings.clone();
    for m in &plan.members {
        simulate(study, profile, &plan, &m.slug, progress)?;
    }
    let mut outputs = Vec::new();
    for mi in 0..plan.members.len() {
        outputs.push(train(registry, profile, &plan, mi, None, progress)?);
    }
    // 4. Scores on the common ground truth, predictors of the traffic, agreement.
    progress(Progress::Stage("validation: scoring"));
    // Recommendations an earlier run added to the set stay in it.
    let prev = out.join("validation.json").exists().then(|| read(out)).transpose()?;
    let added = absorbed(study, prev.as_ref(), settings, plan.members.len())?;
    let mut report = score(study, profile, settings, plan.members, added, &plan.data, outputs)?;
    // 5. The rig the calibrated objective buys, trained as the members were.
    report.recommendation = recommend::recommend(study, registry, profile, &report, out, progress)?;
    // Frozen recommendations trained in this folder before stay, compared with the set again.
    if let Some(prev) = prev {
        report.frozen = prev.frozen;
        recommend::compare_again(study, &mut report);
    }
    recommend::pictures(study, out, &report)?;
    report.seconds = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// The trainings of `members`: the preset for each rig, the study's `[detector_patch]` and
/// `[train_schedule]` over it as the study applies them, except the sample count, which is the
/// validation's budget (2b, keeping the weights at b) whatever the schedule names.
fn jobs(
    study: &Study,
    members: &[Member],
    data: &[DataStage],
    registry: &Registry,
    profile: &Profile,
    settings: &ValidationSettings,
    out: &Path,
) -> Result<Vec<Job>> {
    let mut jobs = Vec::new();
    let named_sampling = study.file.train_schedule.as_ref().is_some_and(|s| s.get("sampling").is_some());
    // What each training step may use, read once for every job below.
    let memory = hilo_core::machine::memory_bytes();
    for (mi, m) in members.iter().enumerate() {
        let radar = m.placement.sensors.iter().any(|s| s.modality == hilo_placement_ip::Modality::Radar);
        let preset = settings.preset_for(radar)?;
        let p = registry.preset(preset)?;
        let detector_cfg = hilo_plan::plan::patched_detector(study, preset, &p.detector, &profile.dataset)?;
        let schedule = hilo_plan::plan::scheduled(study, preset, &p.train)?;
        let trainings =
            (0..settings.traffic_draws as u64).flat_map(|d| (0..settings.seeds as u64).map(move |s| (d, s)));
        for (draw, seed) in trainings {
            let di = data_index(members.len(), mi, draw);
            let stage = data.get(di).ok_or(StudyError::Internal("a validation job without its draw's dataset"))?;
            let mut tc = TrainConfig { seed, replicas: 1, sync_batch_norm: false, ..schedule.clone() };
            tc.samples = 2 * settings.samples;
            if let Some(s) = profile.sampling.filter(|_| !named_sampling) {
                tc.sampling = s;
            }
            let at_b = (settings.samples / tc.batch).max(1) * tc.batch;
            tc.keep = vec![at_b];
            let detector = serde_json::to_string(&detector_cfg)?;
            let schedule = serde_json::to_string(&tc)?;
            let h = stage_hash("run", &[&stage.hash, &detector, &schedule]);
            let trained =
                if draw == 0 { format!("{preset}-seed{seed}") } else { format!("{preset}-draw{draw}-seed{seed}") };
            let name = format!("{trained}-{}", short(&h));
            let detector = detector_cfg.clone().validate()?;
            detector.check_memory(tc.batch, memory)?;
            jobs.push(Job {
                id: format!("{}/{trained}", m.slug),
                configuration: mi,
                data: di,
                draw,
                preset: preset.to_owned(),
                seed,
                run: out.join("runs").join(&m.slug).join(&name),
                results: out.join("results").join(&m.slug).join(format!("{name}.json")),
                detector,
                train: tc.validate()?,
                // A snapshot, not a training of b samples of its own: the rank check at b is
                // free, and is read as "does the ranking hold on from mid-run" (see `CurveKind`).
                curve: vec![at_b],
                curve_kind: CurveKind::Snapshot,
            });
        }
    }
    Ok(jobs)
}

type Outputs = Vec<Vec<(Job, hilo_plan::stages::JobOutput)>>;

/// What every placement is scored against: the common ground truth of the validation traffic
/// (every road user in range, the same whatever the rig), under the study's scene bootstrap.
pub(crate) struct Scorer {
    common: hilo_eval::boxes::GroundTruth,
    cfg: DetectionConfig,
    scenes: Vec<String>,
    draws: Vec<Vec<u32>>,
    min_points: u32,
}

impl Scorer {
    /// From any dataset of the validation (they share the traffic), scored at the study's
    /// evaluation ranges.
    pub(crate) fn new(
        data: &Path,
        profile: &Profile,
        settings: &ValidationSettings,
        detection: &hilo_eval::DetectionConfig,
    ) -> Result<Self> {
        let first = hilo_dataset::Dataset::open(data, "v1.0-trainval")?;
        let (common, _) = ground_truth(&first, "val", GtKind::Common, SampleKey::SceneTime)?;
        let mut cfg = detection.clone();
        let in_gt: std::collections::BTreeSet<&str> =
            common.boxes.values().flatten().map(|b| b.detection_name.as_str()).collect();
        cfg.class_range.retain(|k, _| in_gt.contains(k.as_str()));
        let mut scenes: Vec<String> = common.samples.values().map(|i| i.scene.clone()).collect();
        scenes.sort();
        scenes.dedup();
        let draws = scene_draws(scenes.len(), profile.resamples, 0);
        Ok(Scorer { common, cfg, scenes, draws, min_points: settings.min_points })
    }

    /// One placement's trained accuracy (its jobs' detections, one per training) and the
    /// occupancy predictors of its dataset (`data`: draw 0's; every draw has its validation scenes).
    pub(crate) fn trained(
        &self,
        data: &Path,
        outs: &[(Job, hilo_plan::stages::JobOutput)],
    ) -> Result<(Trained, BTreeMap<String, Option<f64>>)> {
        let (cfg, draws) = (&self.cfg, &self.draws);
        let ds = hilo_dataset::Dataset::open(data, "v1.0-trainval")?;
        let occ = occupancy::occupancy(&ds, "val", cfg, self.min_points)?;
        let (_, keys) = ground_truth(&ds, "val", GtKind::VisibleOnly, SampleKey::SceneTime)?;
        let rescore = |p: &Predictions| -> Result<Reweighable> {
            let mut p = rekey(p.clone(), &keys);
            p.sort_by(|a, b| a.0.cmp(&b.0));
            Reweighable::new(&self.common, &p, cfg, &self.scenes).map_err(|e| StudyError::step("scoring detections", e))
        };
        let (mut map, mut at_b, mut ped, mut train_s) = (Vec::new(), Vec::new(), Vec::new(), 0.0);
        let mut class_ap: BTreeMap<String, f64> = BTreeMap::new();
        let (mut mr, mut pr) = (vec![0.0; draws.len()], vec![0.0; draws.len()]);
        let n = outs.len() as f64;
        let preset = outs.first().map(|(j, _)| j.preset.clone()).unwrap_or_default();
        let mut draw = Vec::new();
        for (j, o) in outs {
            let r = rescore(&o.predictions)?;
            let full = r.full(cfg);
            map.push(full.0);
            draw.push(j.draw);
            ped.push(full.2.get("pedestrian").copied().unwrap_or(f64::NAN));
            for (k, v) in &full.2 {
                *class_ap.entry(k.clone()).or_default() += v / n;
            }
            for (i, x) in r.under(cfg, draws).iter().enumerate() {
                mr[i] += x.0 / n;
                pr[i] += x.2.get("pedestrian").copied().unwrap_or(f64::NAN) / n;
            }
            if let Some((_, p)) = o.curve.first() {
                at_b.push(rescore(p)?.full(cfg).0);
            }
            train_s += o.meta.train_s;
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let trained = Trained {
            preset,
            map_mean: mean(&map),
            map_at_b_mean: mean(&at_b),
            pedestrian_ap_mean: mean(&ped),
            pedestrian_ap: ped,
            map,
            draw: if draw.iter().all(|&d| d == 0) { Vec::new() } else { draw },
            map_at_b: at_b,
            class_ap,
            map_replicates: mr,
            pedestrian_replicates: pr,
            train_s,
        };
        Ok((trained, occ.predictors()))
    }
}

fn score(
    study: &Study,
    profile: &Profile,
    settings: &ValidationSettings,
    mut members: Vec<Member>,
    added: Vec<(Member, Trained)>,
    data: &[DataStage],
    outputs: Outputs,
) -> Result<ValidationReport> {
    let scorer = Scorer::new(&data[0].dir, profile, settings, &study.file.detection_config())?;
    let mut trained = Vec::new();
    // Draw 0's datasets come first; every draw shares their validation scenes.
    for ((m, d), outs) in members.iter_mut().zip(data).zip(outputs) {
        let (t, occupancy) = scorer.trained(&d.dir, &outs)?;
        m.predictors.extend(occupancy);
        trained.push(t);
    }
    let members: Vec<(Member, Trained)> = members.into_iter().zip(trained).chain(added).collect();
    let (predictors, budget_spearman, budget_kendall, seed_spearman) = agreements(&members);
    let mut report = ValidationReport {
        study: study.source.clone(),
        profile: profile.name.to_string(),
        settings: settings.clone(),
        provenance: Provenance::here(profile.trainings_at_once),
        validation_scenes: scorer.scenes.len(),
        resamples: scorer.draws.len(),
        members,
        predictors,
        budget_spearman,
        budget_kendall,
        seed_spearman,
        draw_spearman: None,
        calibrated: None,
        recommendation: None,
        frozen: Vec::new(),
        transfer: None,
        // Set by the caller, who knows when the run began.
        seconds: 0.0,
    };
    report.draw_spearman = draw_spearman(&report.members);
    report.calibrated = calibrate::calibrate(&report, settings.seed);
    Ok(report)
}

/// Every predictor's agreement with mAP and pedestrian AP, the budget's (mAP at b against 2b),
/// with intervals from the members' scenes and trainings resampled ([`resample`]), and seed 0's with seed 1's
/// (intervals over placements alone).
fn agreements(members: &[(Member, Trained)]) -> (Vec<PredictorRow>, Agreement, Agreement, Option<Agreement>) {
    let trained: Vec<&Trained> = members.iter().map(|(_, t)| t).collect();
    let (map_t, ped_t) = (resample::map_replicates(&trained, 0), resample::pedestrian_replicates(&trained, 0));
    let draws = map_t.len().min(ped_t.len());
    let acc: Vec<f64> = members.iter().map(|(_, t)| t.map_mean).collect();
    let ped: Vec<f64> = members.iter().map(|(_, t)| t.pedestrian_ap_mean).collect();
    let mut names: Vec<String> =
        members.first().map(|(m, _)| m.predictors.keys().cloned().collect()).unwrap_or_default();
    let order = [
        set::PAPER_OBJECTIVE,
        set::OWN_OBJECTIVE,
        set::LIDAR_COVERAGE,
        set::RADAR_COVERAGE,
        set::CENTRAL_COVERAGE,
        set::LIDAR_SATURATED,
        set::RADAR_SATURATED,
        set::LIDAR_TWO_VIEWS,
        set::RADAR_TWO_VIEWS,
        set::LIDAR_DENSE,
        set::RADAR_DENSE,
        occupancy::HIT_SHARE,
        occupancy::POINTS_PER_USER,
        occupancy::RADAR_SHARE,
    ];
    names.sort_by_key(|n| (order.iter().position(|o| o == n).unwrap_or(order.len()), n.clone()));
    // Every row under the same resamples (seed 0): rows are paired, and a predictor's interval
    // does not move when another predictor is added before it.
    let rows = names
        .iter()
        .map(|name| {
            let x: Vec<f64> =
                members.iter().map(|(m, _)| m.predictors.get(name).copied().flatten().unwrap_or(f64::NAN)).collect();
            let (spearman_map, kendall_map) = agreement(&x, &acc, &map_t, 0.95, 0);
            let (spearman_pedestrian, kendall_pedestrian) = agreement(&x, &ped, &ped_t, 0.95, 0);
            let undefined_for =
                members.iter().zip(&x).filter(|(_, v)| !v.is_finite()).map(|((m, _), _)| m.slug.clone()).collect();
            PredictorRow {
                predictor: name.clone(),
                spearman_map,
                kendall_map,
                spearman_pedestrian,
                kendall_pedestrian,
                undefined_for,
            }
        })
        .collect();
    let at_b: Vec<f64> = members.iter().map(|(_, t)| t.map_at_b_mean).collect();
    let (budget_spearman, budget_kendall) = agreement(&at_b, &acc, &map_t, 0.95, 99);
    // Seed 0 against seed 1, both on draw 0's traffic.
    let pairs: Option<Vec<(f64, f64)>> = members
        .iter()
        .map(|(_, t)| {
            let mut on_first = t.map.iter().enumerate().filter(|(i, _)| t.draw_of(*i) == 0).map(|(_, v)| *v);
            Some((on_first.next()?, on_first.next()?))
        })
        .collect();
    let seed_spearman = pairs.filter(|p| !p.is_empty()).map(|p| {
        let (a, b): (Vec<f64>, Vec<f64>) = p.into_iter().unzip();
        agreement(&a, &b, &vec![b.clone(); draws.max(1)], 0.95, 98).0
    });
    (rows, budget_spearman, budget_kendall, seed_spearman)
}

/// Draw 0 against draw 1 (each placement's mean over its seeds on each): how well any predictor
/// could rank the set, given the traffic a detector happened to train on as well as its seed
/// (None with one draw). Its interval is over placements alone.
fn draw_spearman(members: &[(Member, Trained)]) -> Option<Agreement> {
    let means: Option<Vec<(f64, f64)>> =
        members.iter().map(|(_, t)| Some((t.draw_mean(0)?, t.draw_mean(1)?))).collect();
    let (a, b): (Vec<f64>, Vec<f64>) = means.filter(|m| !m.is_empty())?.into_iter().unzip();
    let resamples = members.iter().map(|(_, t)| t.map_replicates.len()).min().unwrap_or(0).max(1);
    Some(agreement(&a, &b, &vec![b.clone(); resamples], 0.95, 97).0)
}

impl Trained {
    /// The training-traffic draw of training `i` of `map`.
    pub fn draw_of(&self, i: usize) -> u64 {
        self.draw.get(i).copied().unwrap_or(0)
    }

    /// mAP at 2b averaged over the trainings on draw `draw` (None when it has none).
    pub fn draw_mean(&self, draw: u64) -> Option<f64> {
        let on: Vec<f64> =
            self.map.iter().enumerate().filter(|(i, _)| self.draw_of(*i) == draw).map(|(_, v)| *v).collect();
        (!on.is_empty()).then(|| on.iter().sum::<f64>() / on.len() as f64)
    }
}

/// Reads `<out>/validation.json`, computes the placement predictors again with this build (a
/// validation run by an older build gains the predictors added since) and fits the calibrated
/// objective again: no simulation, no training.
pub fn refit(study: &Study, registry: &Registry, out: &Path) -> Result<ValidationReport> {
    check_same_study(study, registry, out)?;
    refit_report(study, read(out)?)
}

/// [`refit`] on a report in hand.
fn refit_report(study: &Study, mut r: ValidationReport) -> Result<ValidationReport> {
    let members: Vec<Member> = r.members.iter().map(|(m, _)| m.clone()).collect();
    let again = set::recompute(study, &r.settings, &members)?;
    // A transfer scored on other predictors is not this set's.
    if again != members {
        r.transfer = None;
    }
    for ((m, _), a) in r.members.iter_mut().zip(again) {
        *m = a;
    }
    (r.predictors, r.budget_spearman, r.budget_kendall, r.seed_spearman) = agreements(&r.members);
    r.draw_spearman = draw_spearman(&r.members);
    let before = r.calibrated.as_ref().map(calibrate::weights);
    r.calibrated = calibrate::calibrate(&r, r.settings.seed);
    // A recommendation trained for other weights is not this fit's; one kept is compared
    // again (the set's rigs and this build's intervals).
    if r.calibrated.as_ref().map(calibrate::weights) != before {
        r.recommendation = None;
    }
    recommend::compare_again(study, &mut r);
    Ok(r)
}

/// Adds the trained recommendation of `out`'s validation to its set, a placement like the
/// others (the one the fit chose, trained as they were), and fits again ([`refit`]): the
/// calibrated objective then knows how the rig it bought trained, and the next recommendation
/// is placed by that fit — the loop closed once more. A budget buys seven or eight sensors,
/// where the fit's saturating terms are least certain (sets drawn before the rigs of five to
/// eight sensors had one to four); each rig added is evidence where the optimiser goes. It stays in `validation.json`
/// (its placement, dataset and trainings in `recommendation/`, `data/`, `runs/`), and a rerun of
/// the validation keeps it. An error when no recommendation was trained.
pub fn absorb(study: &Study, registry: &Registry, out: &Path) -> Result<ValidationReport> {
    check_same_study(study, registry, out)?;
    let mut r = read(out)?;
    let Some(rec) = r.recommendation.take() else {
        return Err(StudyError::NotReady {
            path: out.join("validation.json"),
            what: "no trained recommendation to add to the set".into(),
            remedy: "run --recommend first".into(),
        });
    };
    r.members.push((rec.member, rec.trained));
    r.transfer = None;
    refit_report(study, r)
}

/// The recommendations an earlier run of the validation added to its set ([`absorb`]): the
/// members of its report `prev` after the `drawn` placements of the set, with their
/// predictors computed again by this build; none without an earlier report.
fn absorbed(
    study: &Study,
    prev: Option<&ValidationReport>,
    settings: &ValidationSettings,
    drawn: usize,
) -> Result<Vec<(Member, Trained)>> {
    let Some(prev) = prev else { return Ok(Vec::new()) };
    let extra: Vec<(Member, Trained)> = prev.members.iter().skip(drawn).cloned().collect();
    let members: Vec<Member> = extra.iter().map(|(m, _)| m.clone()).collect();
    let again = set::recompute_from(study, settings, &members, drawn)?;
    Ok(again.into_iter().zip(extra).map(|(m, (_, t))| (m, t)).collect())
}

/// Reads `<out>/validation.json`, a finished validation's record.
pub fn read(out: &Path) -> Result<ValidationReport> {
    read_report(&out.join("validation.json"))
}

/// Reads a `validation.json` and refuses accuracies no detector can have (a share outside
/// [0, 1], or not a number), naming the member and the field: a fit on them would be fitted to
/// an edit, not to a training.
fn read_report(path: &Path) -> Result<ValidationReport> {
    let text = hilo_core::fs::read_text_bounded(path, limit::TABLE).map_err(|e| FileError::io(path, e))?;
    parse_report(&text, path)
}

/// [`read_report`] of text already read; `path` names it in errors.
pub fn parse_report(text: &str, path: &Path) -> Result<ValidationReport> {
    let r: ValidationReport = serde_json::from_str(text).map_err(|e| FileError::content(path, e))?;
    for (m, t) in &r.members {
        let shares = t.map.iter().chain(&t.map_at_b).map(|v| ("map", *v)).chain([
            ("map_mean", t.map_mean),
            ("map_at_b_mean", t.map_at_b_mean),
            ("pedestrian_ap_mean", t.pedestrian_ap_mean),
        ]);
        let classes = t.class_ap.iter().map(|(c, v)| (c.as_str(), *v));
        if let Some((field, v)) = shares.chain(classes).find(|(_, v)| !(0.0..=1.0).contains(v)) {
            return Err(StudyError::from(FileError::content(
                path,
                format!("member {:?}: {field} = {v} is not an accuracy in [0, 1]", m.slug),
            )));
        }
    }
    Ok(r)
}

/// Scores the validation `r` with the calibrated objective of the finished validation in
/// `source` (a `validation.json`), its weights frozen ([`calibrate::transfer`]). A source that
/// is the same set (this folder's own file, or a copy of it) is refused: its fit has seen
/// every placement, so the score would be in-sample, not a transfer.
pub fn transfer(r: &ValidationReport, source: &Path) -> Result<calibrate::Transfer> {
    let src = read_report(source)?;
    let same_members = src.members.len() == r.members.len()
        && src.members.iter().zip(&r.members).all(|((a, ta), (b, tb))| a.slug == b.slug && ta == tb);
    if same_members {
        return Err(StudyError::folder(
            source,
            "holds the same placements and trainings as this validation; a transfer scores a fit on a set it \
             never saw, so give another validation's validation.json",
        ));
    }
    calibrate::transfer(&src, r, &source.display().to_string())
        .map_err(|e| StudyError::step(source.display().to_string(), e))
}

/// Writes `validation.json`, `validation.md` and the scatter charts into `out`; returns the
/// files written.
pub fn write(out: &Path, r: &ValidationReport) -> Result<Vec<PathBuf>> {
    let json = out.join("validation.json");
    write_json(&json, r)?;
    let md = out.join("validation.md");
    hilo_core::fs::write_atomic(&md, markdown(r).as_bytes())?;
    let mut files = vec![json, md];
    for name in [set::PAPER_OBJECTIVE, set::OWN_OBJECTIVE, occupancy::HIT_SHARE, set::LIDAR_POINTS_CAPPED] {
        let stem = format!("validation-{}", hilo_plan::study::slug(name));
        if scatter(out, &stem, r, name)? {
            files.push(out.join(format!("{stem}.png")));
        }
    }
    Ok(files)
}

pub(crate) fn fmt_agreement(a: &Agreement) -> String {
    if a.value.is_finite() { format!("{:+.2} [{:+.2}, {:+.2}]", a.value, a.lo, a.hi) } else { "–".into() }
}

/// The report section "Does the objective predict accuracy?".
pub fn markdown(r: &ValidationReport) -> String {
    let mut s = String::new();
    let lidar_only =
        r.members.iter().filter(|(m, _)| m.predictors.get(set::PAPER_OBJECTIVE).is_some_and(|v| v.is_none())).count();
    s.push_str("# Does the objective predict accuracy?\n\n");
    s.push_str(&format!(
        "{} placements of {} ({} of one modality), each trained {} time(s){} at {} samples (scored at b = {} and 2b), \
         profile `{}` ({} validation scenes), {:.0} s. Rank agreement of each predictor with the mean trained mAP and \
         pedestrian AP; 95% intervals from {} bootstrap replicates over {}.\n\n",
        r.members.len(),
        r.study,
        lidar_only,
        r.settings.seeds,
        match r.settings.traffic_draws {
            1 => String::new(),
            d => format!(" on each of {d} training-traffic draws (the validation scenes shared)"),
        },
        2 * r.settings.samples,
        r.settings.samples,
        r.profile,
        r.validation_scenes,
        r.seconds,
        r.resamples,
        resample::units(&r.members.iter().map(|(_, t)| t).collect::<Vec<&Trained>>()),
    ));
    s.push_str("| predictor | ρ with mAP | τ with mAP | ρ with pedestrian AP | τ with pedestrian AP | placements |\n|---|---:|---:|---:|---:|---:|\n");
    for p in &r.predictors {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} |\n",
            p.predictor,
            fmt_agreement(&p.spearman_map),
            fmt_agreement(&p.kendall_map),
            fmt_agreement(&p.spearman_pedestrian),
            fmt_agreement(&p.kendall_pedestrian),
            p.spearman_map.n
        ));
    }
    s.push_str(&format!(
        "\nThe paper's objective is undefined (zero whatever the poses) for the {lidar_only} rig(s) of one modality and is \
         ranked over the others. The budget: mAP at b against mAP at 2b, Spearman ρ {}, Kendall τ {} \
         (the weights at b are those of each 2b training halfway, at a one-cycle learning rate still near its \
         peak, not a training of b samples of its own; τ ≥ 0.8 means the ranking is settled halfway through \
         the training).\n\n",
        fmt_agreement(&r.budget_spearman),
        fmt_agreement(&r.budget_kendall)
    ));
    if let Some(a) = &r.seed_spearman {
        s.push_str(&format!(
            "The training's own noise: two trainings of every placement (seed 0 against seed 1) rank the set at \
             Spearman ρ {} — what a perfect predictor of one training's mAP would reach, and a little below what it \
             would reach against their mean.\n\n",
            fmt_agreement(a)
        ));
    }
    if let Some(a) = &r.draw_spearman {
        s.push_str(&format!(
            "The traffic's share: every placement's detectors trained on another draw of training traffic (draw 0 \
             against draw 1, each the mean of its seeds, scored on the same validation scenes) rank the set at \
             Spearman ρ {} — the ceiling for a predictor of a placement measured on one draw of traffic.\n\n",
            fmt_agreement(a)
        ));
    }
    let trained: Vec<&Trained> = r.members.iter().map(|(_, t)| t).collect();
    if let Some(c) = ceiling::ceiling(&trained, r.settings.seed) {
        s.push_str(&format!(
            "The ceiling for the mean of every placement's trainings: {} — the Spearman–Brown reliability of the \
             mean of the parts, square-rooted: the most any predictor can agree with the measured mAP \
             (its assumptions: `hilo_validate::ceiling`).\n\n",
            c.describe()
        ));
    }
    if let Some(c) = &r.calibrated {
        s.push_str(&calibrated_markdown(r, c));
    }
    if let Some(t) = &r.transfer {
        s.push_str(&transfer_markdown(t));
    }
    for rec in r.recommendation.iter().chain(&r.frozen) {
        s.push_str(&recommend::markdown(rec));
    }
    s.push_str(&same_lidars::markdown(r));
    s.push_str("## Every placement\n\n");
    s.push_str("| placement | kind | sensors | cost (USD) | paper objective | LiDAR coverage | occupancy | detector | mAP at b | mAP at 2b (trainings) | pedestrian AP |\n|---|---|---|---:|---:|---:|---:|---|---:|---:|---:|\n");
    for (m, t) in &r.members {
        let p = |k: &str| m.predictors.get(k).copied().flatten();
        let sensors: BTreeMap<&str, usize> = m.placement.sensors.iter().fold(BTreeMap::new(), |mut a, x| {
            *a.entry(x.ty.as_str()).or_default() += 1;
            a
        });
        let sensors: Vec<String> = sensors.iter().map(|(k, n)| format!("{n}× {k}")).collect();
        s.push_str(&format!(
            "| {} | {} | {} | {:.0} | {} | {} | {} | {} | {:.3} | {:.3} ({}) | {:.3} |\n",
            m.slug,
            m.kind,
            sensors.join(" + "),
            m.placement.cost_usd,
            p(set::PAPER_OBJECTIVE).map_or("–".into(), |v| format!("{v:.0}")),
            p(set::LIDAR_COVERAGE).map_or("–".into(), |v| format!("{:.1}%", 100.0 * v)),
            p(occupancy::HIT_SHARE).map_or("–".into(), |v| format!("{:.1}%", 100.0 * v)),
            t.preset,
            t.map_at_b_mean,
            t.map_mean,
            trainings(t),
            t.pedestrian_ap_mean
        ));
    }
    s
}

/// A member's mAP per training at 2b: seeds joined by commas, training-traffic draws by slashes.
fn trainings(t: &Trained) -> String {
    let mut by_draw: BTreeMap<u64, Vec<String>> = BTreeMap::new();
    for (i, v) in t.map.iter().enumerate() {
        by_draw.entry(t.draw_of(i)).or_default().push(format!("{v:.3}"));
    }
    by_draw.values().map(|v| v.join(", ")).collect::<Vec<_>>().join(" / ")
}

/// Whether a member is a recommendation added to the set ([`absorb`]) rather than drawn.
fn is_absorbed(m: &Member) -> bool {
    m.kind.starts_with("calibrated")
}

/// The recommendations in the set, and the held-out ρ over the drawn placements alone (an
/// added rig is chosen by a fit, at the top of the range, and could carry ρ on its own).
fn absorbed_markdown(r: &ValidationReport, c: &calibrate::Calibrated) -> String {
    let added: Vec<&str> = r.members.iter().filter(|(m, _)| is_absorbed(m)).map(|(m, _)| m.slug.as_str()).collect();
    if added.is_empty() || c.held_out.len() != r.members.len() {
        return String::new();
    }
    let (p, m): (Vec<f64>, Vec<f64>) = r
        .members
        .iter()
        .zip(&c.held_out)
        .filter(|((m, _), _)| !is_absorbed(m))
        .map(|(_, h)| (h.predicted, h.measured))
        .unzip();
    format!(
        "{} of these placements are recommendations of earlier fits, trained and added to the set (`--absorb`): {}. \
         Over the {} drawn placements alone, the same out-of-fold predictions rank at Spearman ρ {:+.2}.\n\n",
        added.len(),
        added.join(", "),
        p.len(),
        crate::rank::spearman(&p, &m)
    )
}

fn calibrated_markdown(r: &ValidationReport, c: &calibrate::Calibrated) -> String {
    let mut s = String::from("## A calibrated objective\n\n");
    let terms: Vec<String> = c.features.iter().zip(&c.weights).map(|(f, w)| format!("{w:.3} × {f}")).collect();
    let held = if c.folds > 0 {
        format!("Each placement predicted by the fit on the other {} folds of {} (cross-fitting)", c.folds - 1, c.folds)
    } else {
        format!("On the {} held-out placements", c.held_out.len())
    };
    s.push_str(&format!(
        "Fitted on {} placements (least squares, weights ≥ 0; residual SD {:.3} mAP, {} degrees of freedom): \
         predicted mAP = {:.3} + {}. {held}: Spearman ρ {}, Kendall τ {} with measured mAP \
         (the paper's objective on the same placements, where defined: ρ {}); {} of {} measured values inside their \
         95% prediction interval.\n\n",
        c.fit_on.len(),
        c.residual_sd,
        c.df,
        c.intercept,
        terms.join(" + "),
        fmt_agreement(&c.held_out_spearman),
        fmt_agreement(&c.held_out_kendall),
        fmt_agreement(&c.paper_held_out_spearman),
        c.covered,
        c.held_out.len()
    ));
    if !c.reshuffled_spearman.is_empty() {
        let mut v = c.reshuffled_spearman.clone();
        v.sort_by(f64::total_cmp);
        let median = if v.len() % 2 == 1 { v[v.len() / 2] } else { 0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2]) };
        s.push_str(&format!(
            "The deal of the placements into folds moves that ρ on its own: under {} other deals (same placements, same \
             mAP) it ranges from {:+.2} to {:+.2}, median {:+.2}.\n\n",
            v.len(),
            v[0],
            v[v.len() - 1],
            median
        ));
    }
    s.push_str(&absorbed_markdown(r, c));
    let w = calibrate::weights(c);
    if c.weights.iter().all(|v| *v == 0.0) {
        s.push_str(
            "No coverage term predicts mAP better than the mean of the set (by leave-one-out error): the \
             calibrated objective has nothing to place for, and no recommendation is trained.\n\n",
        );
        return s;
    }
    // The weights a study file takes: the region terms always (they name the objective's form),
    // the road-user terms where the fit uses them.
    let named: Vec<String> = w
        .named()
        .iter()
        .enumerate()
        .filter(|(k, (_, v))| *k < 6 || *v > 0.0)
        .map(|(_, (name, v))| format!("{name} = {v:.4}"))
        .collect();
    s.push_str(&format!(
        "The features were chosen by leave-one-out error of the fit on every placement (RMSE {:.3} mAP). To place with it, \
         in the study file: `[placement]` `objective = \"calibrated\"` and `calibration = {{ {} }}`.\n\n",
        c.loo_rmse,
        named.join(", ")
    ));
    s.push_str(&predictions_table("placement (predicted out of fold)", &c.held_out));
    s
}

/// Predicted mAP with its interval against measured, a row per placement.
fn predictions_table(first: &str, rows: &[calibrate::HeldOut]) -> String {
    let mut s = format!("| {first} | predicted mAP [95% interval] | measured |\n|---|---:|---:|\n");
    for h in rows {
        s.push_str(&format!(
            "| {} | {:.3} [{:.3}, {:.3}] | {:.3} |\n",
            h.placement, h.predicted, h.lo, h.hi, h.measured
        ));
    }
    s.push('\n');
    s
}

fn transfer_markdown(t: &calibrate::Transfer) -> String {
    let mut s = String::from("## Does the fit carry to another set?\n\n");
    let terms: Vec<String> =
        t.features.iter().zip(&t.weights).filter(|(_, w)| **w != 0.0).map(|(f, w)| format!("{w:.3} × {f}")).collect();
    let commit =
        if t.source_commit.is_empty() { "unknown code".to_owned() } else { format!("code {}", t.source_commit) };
    s.push_str(&format!(
        "The calibrated objective fitted on `{}` (study {}, validation seed {}, {commit}), its weights \
         frozen: predicted mAP = {:.3} + {}. On this set (its own traffic, random and perturbed rigs \
         and trainings; the configurations' optima may share their poses with the fitted set's): Spearman ρ {}, Kendall τ {} with measured mAP; {} of {} \
         measured values inside their 95% prediction interval; measured − predicted {:+.3} on average \
         (RMSE {:.3}). Rank agreement says whether the fit orders rigs as trained detectors do \
         elsewhere; the mean error, whether its level carries too.\n\n",
        t.source,
        t.source_study,
        t.source_seed,
        t.intercept,
        if terms.is_empty() { "0".to_owned() } else { terms.join(" + ") },
        fmt_agreement(&t.spearman),
        fmt_agreement(&t.kendall),
        t.covered,
        t.predicted.len(),
        t.mean_error,
        t.rmse
    ));
    s.push_str(&predictions_table("placement", &t.predicted));
    s
}

/// A scatter of one predictor against mAP (rigs with and without radar apart, seed range as
/// error bars) with its least-squares line; false when the predictor has too few values.
fn scatter(out: &Path, stem: &str, r: &ValidationReport, name: &str) -> Result<bool> {
    use hilo_plan::charts::{Series, XY, save};
    let mut with = Vec::new();
    let mut without = Vec::new();
    for (m, t) in &r.members {
        let Some(x) = m.predictors.get(name).copied().flatten().filter(|v| v.is_finite()) else { continue };
        let lo = t.map.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = t.map.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let radar = m.placement.sensors.iter().any(|s| s.modality == hilo_placement_ip::Modality::Radar);
        (if radar { &mut with } else { &mut without }).push((x, t.map_mean, lo, hi));
    }
    let all: Vec<&(f64, f64, f64, f64)> = with.iter().chain(&without).collect();
    if all.len() < 3 {
        return Ok(false);
    }
    let (xmin, xmax) = all.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| (a.0.min(p.0), a.1.max(p.0)));
    let (ymin, ymax) = all.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| (a.0.min(p.2), a.1.max(p.3)));
    let n = all.len() as f64;
    let (mx, my) = (all.iter().map(|p| p.0).sum::<f64>() / n, all.iter().map(|p| p.1).sum::<f64>() / n);
    let sxx: f64 = all.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let slope = if sxx > 0.0 { all.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>() / sxx } else { 0.0 };
    let line = |x: f64| my + slope * (x - mx);
    let series = vec![
        Series { label: "rigs with a radar".into(), points: with, line: false },
        Series { label: "LiDAR-only rigs".into(), points: without, line: false },
        Series {
            label: "least-squares line".into(),
            points: vec![(xmin, line(xmin), line(xmin), line(xmin)), (xmax, line(xmax), line(xmax), line(xmax))],
            line: true,
        },
    ];
    let pad = |a: f64, b: f64| (b - a).abs().max(1e-9) * 0.05;
    let title = format!("{name} against trained mAP");
    let chart = XY {
        title: &title,
        x_label: name,
        y_label: "mAP (mean over trainings; bars: their range)",
        x: (xmin - pad(xmin, xmax), xmax + pad(xmin, xmax)),
        y: ((ymin - pad(ymin, ymax)).max(0.0), (ymax + pad(ymin, ymax)).min(1.0)),
        series: &series,
        x_fmt: &|v| if v.abs() >= 100.0 { format!("{v:.0}") } else { format!("{v:.2}") },
        notes: &[],
    };
    save(out, stem, &chart)?;
    Ok(true)
}

/// `hilo validate --sites`: the finished validations at `paths` (each a `validation.json`, one
/// per site), each held out in turn ([`sites::leave_one_site_out`]); writes `sites.json`,
/// `sites.md` and `calibration.toml` (the objective to place with at another junction, which a
/// study file names with `calibration_file`) into `out` and returns the report.
pub fn sites(paths: &[PathBuf], out: &Path, seed: u64) -> Result<sites::SitesReport> {
    let reports = paths.iter().map(|p| read_report(p)).collect::<Result<Vec<_>>>()?;
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    let given: Vec<(&str, &ValidationReport)> = names.iter().map(String::as_str).zip(&reports).collect();
    let r = sites::leave_one_site_out(&given, seed).map_err(|e| StudyError::step("leave one site out", e))?;
    std::fs::create_dir_all(out).map_err(|e| FileError::io(out, e))?;
    write_json(&out.join("sites.json"), &r)?;
    hilo_core::fs::write_atomic(&out.join("sites.md"), sites::markdown(&r).as_bytes())?;
    let toml = r.shipped.to_toml().map_err(|e| StudyError::step("calibration.toml", e))?;
    let header = "# The calibrated objective `hilo validate --sites` fitted across the sites below: name this file\n\
                  # in a study file (calibration_file = \"calibration.toml\") to place with it and to predict each\n\
                  # rig's mAP, with how far the study's junction lies from these sites.\n";
    hilo_core::fs::write_atomic(&out.join("calibration.toml"), format!("{header}{toml}").as_bytes())?;
    Ok(r)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Members whose trainings are `map` on `draw` (in that order).
    fn trained(map: &[(u64, f64)]) -> Trained {
        let mut rng = rand::rngs::StdRng::seed_from_u64(0);
        let (_, mut t) = testing::member(0, BTreeMap::new(), 0.0, 20, &mut rng);
        t.map = map.iter().map(|x| x.1).collect();
        t.draw = map.iter().map(|x| x.0).collect();
        t
    }

    /// Seeds pair within draw 0, draws pair by their seeds' means; a set of one draw has no draw
    /// agreement, and the trainings read per draw.
    #[test]
    fn seeds_pair_within_a_draw_and_draws_by_their_means() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        // Draw 0 orders the placements one way, draw 1 the opposite way; seed 0 and seed 1 of
        // draw 0 agree exactly.
        let members: Vec<(Member, Trained)> = (0..8)
            .map(|i| {
                let (m, _) = testing::member(i, BTreeMap::new(), 0.0, 20, &mut rng);
                let (up, down) = (0.1 * i as f64, 0.8 - 0.1 * i as f64);
                (m, trained(&[(0, up), (0, up + 0.01), (1, down), (1, down + 0.02)]))
            })
            .collect();
        let (_, _, _, seed) = agreements(&members);
        assert!((seed.unwrap().value - 1.0).abs() < 1e-12);
        let draw = draw_spearman(&members).unwrap();
        assert!((draw.value + 1.0).abs() < 1e-12, "{draw:?}");
        assert_eq!(draw.n, 8);
        let t = &members[2].1;
        assert!((t.draw_mean(0).unwrap() - 0.205).abs() < 1e-12);
        assert!((t.draw_mean(1).unwrap() - 0.61).abs() < 1e-12);
        assert_eq!(t.draw_mean(2), None);
        assert_eq!(trainings(t), "0.200, 0.210 / 0.600, 0.620");
        // One draw: no draw agreement; one seed per draw: no seed pair (draw 1 is no second seed).
        let one: Vec<(Member, Trained)> =
            members.iter().map(|(m, t)| (m.clone(), Trained { draw: Vec::new(), ..t.clone() })).collect();
        assert_eq!(draw_spearman(&one), None);
        let single: Vec<(Member, Trained)> =
            members.iter().map(|(m, t)| (m.clone(), trained(&[(0, t.map[0]), (1, t.map[2])]))).collect();
        assert_eq!(agreements(&single).3, None);
        assert!(draw_spearman(&single).is_some());
    }
}
