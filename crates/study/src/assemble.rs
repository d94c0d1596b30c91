//! The verdict assembled from a study's stage outputs: every detector scored on the common
//! ground truth (and the visible-only one) under shared scene draws, the comparisons and the
//! paper's claims with Holm's adjustment per family, the test's calibration, learning curves
//! and the configurations' summaries.
//! Reads the result files a study folder holds, or takes them from memory when the stages just
//! ran in this process (the two give the same report: results are kept in sample order and JSON
//! numbers round-trip exactly).

use crate::stats::{Scores, scene_draws};
use crate::verdict::{Calibration, Claim, Comparison, Curve, Design, DetectorScores, Margins, PresetRoles, adjust};
use hilo_core::fs::{limit, read_json};
use hilo_detector::Registry;
use hilo_detector::data::{Frame, LoadOptions, load_split_frame};
use hilo_eval::bootstrap::{Reweighable, VelocityErrors};
use hilo_eval::{DetectionConfig, EvalBox, GroundTruth};
use hilo_placement_ip::Placement;
use hilo_plan::error::{Result, StudyError};
use hilo_plan::gt::{GtKind, SampleKey, ground_truth, rekey};
use hilo_plan::plan::{Job, Plan, Provenance};
use hilo_plan::profile::Profile;
use hilo_plan::stages::{DataRecord, JobOutput, Predictions, Progress, ResultMeta};
use hilo_plan::study::Study;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

fn nan() -> f64 {
    f64::NAN
}

/// The verdict's replicates per group: the seeds, or the training-traffic draws when there are
/// several (each the mean of its seeds, [`crate::verdict::draw_units`]).
pub(crate) fn replicates(prof: &Profile) -> usize {
    if prof.traffic_draws > 1 { prof.traffic_draws } else { prof.seeds }
}

/// A detector's place among its group's: seeds of draw 0 first (0 is seed 0 on the study's own
/// traffic, whose learning curve and pictures the report shows), then those of each further
/// training-traffic draw.
fn replicate(prof: &Profile, seed: u64, draw: u64) -> u64 {
    draw * prof.seeds.max(1) as u64 + seed
}

/// One trained detector's evaluation.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Entry {
    pub configuration: String,
    pub preset: String,
    pub seed: u64,
    /// The training-traffic draw it was trained on (0: the study's own traffic).
    #[serde(default, skip_serializing_if = "crate::verdict::is_zero")]
    pub draw: u64,
    /// On the common ground truth (every road user, seen or not), over the classes present.
    pub mean_ap: f64,
    pub nd_score: f64,
    /// Every evaluated class: the paper's six, and cyclists where the traffic carries them
    /// (null where the validation split has none).
    pub class_ap: BTreeMap<String, Option<f64>>,
    /// Velocity error (m/s, the devkit's mAVE over the classes present) and each class's AVE
    /// (null where the validation split has none), on the common ground truth.
    #[serde(default = "nan")]
    pub mean_ave: f64,
    #[serde(default)]
    pub class_ave: BTreeMap<String, Option<f64>>,
    /// mAP per range bin of the study's `[evaluation] range_bins_m`, by label, over the classes
    /// with ground truth in the bin (null where it holds none).
    #[serde(default)]
    pub map_by_range: Vec<(String, Option<f64>)>,
    /// The nuScenes convention: boxes with at least one point of this rig only.
    pub visible_only: VisibleOnly,
    pub train_s: f64,
    pub ms_per_frame: f64,
    pub samples: usize,
    /// Trainable parameters of the detector.
    pub parameters: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VisibleOnly {
    pub mean_ap: f64,
    pub nd_score: f64,
    pub class_ap: BTreeMap<String, Option<f64>>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConfigSummary {
    pub name: String,
    pub cost_usd: f64,
    pub has_radar: bool,
    pub central_coverage: f64,
    pub sensors: Vec<String>,
    pub placement_proven_optimal: bool,
    pub placement_s: f64,
    /// Whether the placement was optimised ([`hilo_placement_ip::Placement::solved`]).
    pub placement_solved: bool,
    /// Relative gap of an unproven placement.
    pub placement_gap: f64,
    /// How the placement was found (for a single-modality configuration: whose poses it took).
    pub placement_method: String,
    pub frames: usize,
    pub annotations: usize,
    /// Share of the common ground truth's boxes (within the evaluation ranges, validation
    /// split) that no sensor of this rig hit; and per class.
    pub unseen_share: f64,
    pub unseen_by_class: BTreeMap<String, f64>,
    /// The weather condition it was recorded in (`[[conditions]]`); None: the study's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<String>,
    /// The configuration whose placed sensors it keeps (`given`), placing only the rest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub given: Option<String>,
    /// Per radar, the mounting structure it stands on, and whether a LiDAR of the rig shares it
    /// (the radar then adds no viewpoint of its own).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub radar_mounts: Vec<(String, bool)>,
}

/// A class of the verdict's ground truth.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ClassInfo {
    pub name: String,
    /// Boxes within the evaluation range in the validation split.
    pub validation_boxes: usize,
    /// Whether it enters mAP (a class with no box would count as 0 for every rig).
    pub in_map: bool,
    /// Fewer than 50 boxes: its AP is noisy.
    pub few_boxes: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    pub study: String,
    pub profile: Profile,
    pub provenance: Provenance,
    /// `common`: every rig scored on every road user.
    pub ground_truth: String,
    pub validation_scenes: usize,
    pub seeds: usize,
    pub classes: Vec<ClassInfo>,
    /// The range bins of `map_by_range`: label and validation boxes per class inside.
    #[serde(default)]
    pub range_bins: Vec<(String, BTreeMap<String, usize>)>,
    pub configurations: Vec<ConfigSummary>,
    pub entries: Vec<Entry>,
    pub comparisons: Vec<Comparison>,
    pub claims: Vec<Claim>,
    /// The weather conditions the study ran (the first `[[conditions]]` the profile runs).
    #[serde(default)]
    pub conditions: Vec<hilo_plan::study::Condition>,
    /// What the radar adds and what it costs, in the study's own weather and in each condition.
    #[serde(default)]
    pub radar_value: Vec<crate::verdict::RadarValue>,
    /// The equivalence margin of the claims' TOST (the study file's `verdict.equivalence_margin`).
    #[serde(default)]
    pub margin: f64,
    /// The same for velocity errors, m/s (`verdict.velocity_equivalence_margin_m_s`).
    #[serde(default)]
    pub velocity_margin_m_s: f64,
    /// The study file's `[detector_patch]`: what every detector changed of its preset (None:
    /// the presets as they are).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector_patch: Option<serde_json::Value>,
    /// The study file's `[train_schedule]`: what every training changed of its preset's
    /// schedule (None: the presets' schedules).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_schedule: Option<serde_json::Value>,
    pub calibration: Calibration,
    /// Which field effects the study's sensors and rig model ([`crate::modelled`]); empty in
    /// reports written before it existed.
    #[serde(default)]
    pub modelled: Vec<crate::modelled::Modelled>,
    pub learning_curves: Vec<Curve>,
    /// Whether every preset ranks the configurations the same at half its training and at the
    /// end (seed 0), and the presets where it does not.
    pub ranking_stable: bool,
    pub ranking_changed: Vec<String>,
    pub cost_reduction: BTreeMap<String, f64>,
    /// Placement's speed against error: line-of-sight samples and solver time limits.
    pub tradeoffs: hilo_plan::tradeoff::Tradeoffs,
    /// Wall time of the process that wrote the report: the whole study when `hilo study` ran
    /// it, the report stage alone when a workflow engine did.
    pub seconds: f64,
}

/// Predictions by (configuration, preset, replicate): the replicate is the seed on the study's
/// own traffic, and counts on past the seeds for each further training-traffic draw.
pub type ResultsBy = BTreeMap<(String, String, u64), Predictions>;
/// Per configuration, the validation frame the report draws (the middle one), its sample key
/// and its common ground truth.
pub type Pictures = BTreeMap<String, (Frame, String, Vec<EvalBox>)>;

/// Everything the report draws besides [`Report`]: the predictions by (configuration, preset,
/// seed) and one validation frame per configuration.
#[derive(Debug)]
pub struct Assembled {
    pub report: Report,
    pub results: ResultsBy,
    pub pictures: Pictures,
}

/// Assembles the verdict from the stage outputs in the plan's folder; `outputs` holds train
/// stages' outputs already in memory (by job id), anything else is read from its files.
pub fn assemble(
    study: &Study,
    plan: &Plan,
    registry: &Registry,
    mut outputs: BTreeMap<String, JobOutput>,
    seconds: &dyn Fn() -> f64,
    progress: &mut dyn FnMut(Progress),
) -> Result<Assembled> {
    let prof = &plan.profile;
    let configs = &plan.configurations;
    for p in plan.placement_outputs() {
        if !p.exists() {
            return Err(StudyError::not_ready(p, "missing", "run the place stage first"));
        }
    }
    let tradeoffs: hilo_plan::tradeoff::Tradeoffs = read_json(&plan.tradeoffs, limit::TABLE)?;
    let mut summaries = config_summaries(plan)?;
    // The ground truth every rig is scored on, and what it evaluates.
    let first = hilo_dataset::Dataset::open(&plan.data[0].dir, "v1.0-trainval")?;
    let (common, _) = ground_truth(&first, "val", GtKind::Common, SampleKey::SceneTime)?;
    let base_cfg = study.file.detection_config();
    let class_boxes = class_counts(&common, &base_cfg);
    let classes: Vec<ClassInfo> = class_boxes
        .iter()
        .map(|(k, &n)| ClassInfo { name: k.clone(), validation_boxes: n, in_map: n > 0, few_boxes: n < 50 })
        .collect();
    let mut eval_cfg = base_cfg.clone();
    eval_cfg.class_range.retain(|k, _| class_boxes.get(k).is_some_and(|n| *n > 0));
    let mut scenes: Vec<String> = common.samples.values().map(|i| i.scene.clone()).collect();
    scenes.sort();
    scenes.dedup();
    let draws = scene_draws(scenes.len(), prof.resamples, 0);
    // Each detector's predictions, keyed as the common ground truth is.
    let mut results_by: ResultsBy = BTreeMap::new();
    let mut metas: BTreeMap<(String, String, u64), ResultMeta> = BTreeMap::new();
    let mut curve_preds: BTreeMap<(String, String, usize), Predictions> = BTreeMap::new();
    let mut visible: BTreeMap<String, GroundTruth> = BTreeMap::new();
    let mut pictures: Pictures = BTreeMap::new();
    for (ci, conf) in configs.iter().enumerate() {
        let ds = hilo_dataset::Dataset::open(&plan.data[ci].dir, "v1.0-trainval")?;
        let (share, by_class) = hilo_plan::gt::unseen_share(&ds, "val", &base_cfg)?;
        summaries[ci].unseen_share = share;
        summaries[ci].unseen_by_class = by_class;
        let (vis, keys) = ground_truth(&ds, "val", GtKind::VisibleOnly, SampleKey::SceneTime)?;
        let jobs: Vec<&Job> = plan.jobs.iter().filter(|j| j.configuration == ci).collect();
        for job in &jobs {
            let out = match outputs.remove(&job.id) {
                Some(o) => o,
                None => read_outputs(job)?,
            };
            let key = (conf.name.clone(), job.preset.clone(), replicate(prof, job.seed, job.draw));
            for (samples, p) in out.curve {
                curve_preds.insert((conf.name.clone(), job.preset.clone(), samples), sorted(rekey(p, &keys)));
            }
            results_by.insert(key.clone(), sorted(rekey(out.predictions, &keys)));
            metas.insert(key, out.meta);
        }
        if let Some(pic) = jobs.first().map(|job| picture(job, registry, &ds, &keys, &common)).transpose()?.flatten() {
            pictures.insert(conf.name.clone(), pic);
        }
        visible.insert(conf.name.clone(), vis);
    }
    // Scores: every detector on the common ground truth, under the shared scene draws.
    progress(Progress::Stage(&format!(
        "scoring {} detectors on {} validation scenes ({} scene-bootstrap replicates)",
        results_by.len(),
        scenes.len(),
        prof.resamples
    )));
    let score = |pred: &Predictions| bootstrap_scores(&common, pred, &eval_cfg, &scenes, &draws);
    let mut entries = Vec::new();
    let mut det_scores = Vec::new();
    let mut planted = Vec::new();
    let mut range_bins = Vec::new();
    for ((conf, preset, r), pred) in &results_by {
        let (seed, draw) = (r % prof.seeds.max(1) as u64, r / prof.seeds.max(1) as u64);
        let bins = hilo_eval::evaluate_distance_bins(&common, pred, &eval_cfg, &study.file.evaluation.range_bins_m);
        if range_bins.is_empty() {
            range_bins = bins.iter().map(|b| (b.label.clone(), b.gt_boxes.clone())).collect();
        }
        let (full, vel, mut scores) = score(pred)?;
        let (visible_only, vis) = visible_scores(&visible[conf], pred, &eval_cfg, &scenes, &draws, &class_boxes)?;
        scores.extend(vis);
        let meta = &metas[&(conf.clone(), preset.clone(), *r)];
        let six = |values: &BTreeMap<String, f64>| per_class(&class_boxes, values);
        entries.push(Entry {
            configuration: conf.clone(),
            preset: preset.clone(),
            seed,
            draw,
            mean_ap: full.0,
            nd_score: full.1,
            class_ap: six(&full.2),
            mean_ave: vel.mean,
            class_ave: six(&vel.by_class),
            map_by_range: bins.iter().map(|b| (b.label.clone(), b.mean_ap_present())).collect(),
            visible_only,
            train_s: meta.train_s,
            ms_per_frame: meta.ms_per_frame,
            samples: meta.samples,
            parameters: meta.parameters,
        });
        let of = |scores| DetectorScores { configuration: conf.clone(), preset: preset.clone(), seed, draw, scores };
        det_scores.push(of(scores));
        // The planted difference: the same detector with a share of its boxes dropped.
        planted.push(of(score(&drop_share(pred, DROP, *r))?.2));
    }
    let pos = |c: &str| configs.iter().position(|x| x.name == c).unwrap_or(usize::MAX);
    entries.sort_by_key(|e| (pos(&e.configuration), e.preset.clone(), e.draw, e.seed));
    let learning_curves = learning_curves(&results_by, &curve_preds, &metas, &entries, &common, &eval_cfg, &scenes)?;
    let v = &study.file.verdict;
    let margins = Margins { ap: v.equivalence_margin, velocity_m_s: v.velocity_equivalence_margin_m_s };
    let (comparisons, mut claims, calibration) =
        verdict(prof, registry, &summaries, &det_scores, &planted, scenes.len(), margins);
    crate::verdict::budget_gate(&mut claims, &learning_curves);
    let cost = |name: &str| summaries.iter().find(|c| c.name == name).map(|c| c.cost_usd);
    let radar_value = crate::verdict::radar_value(&claims, &cost, replicates(prof));
    let ranking_changed = ranking_changes(&learning_curves, &prof.presets);
    let cost_reduction = cost_reduction(&summaries);
    let report = Report {
        study: study.source.clone(),
        profile: prof.clone(),
        provenance: Provenance::here(prof.trainings_at_once),
        ground_truth: "common".into(),
        detector_patch: study.file.detector_patch.clone(),
        train_schedule: study.file.train_schedule.clone(),
        validation_scenes: scenes.len(),
        seeds: prof.seeds,
        classes,
        range_bins,
        configurations: summaries,
        entries,
        comparisons,
        claims,
        conditions: study.file.conditions.iter().take(prof.conditions.unwrap_or(usize::MAX)).cloned().collect(),
        radar_value,
        margin: margins.ap,
        velocity_margin_m_s: margins.velocity_m_s,
        calibration,
        modelled: crate::modelled::modelled(study, &prof.dataset),
        learning_curves,
        ranking_stable: ranking_changed.is_empty(),
        ranking_changed,
        cost_reduction,
        tradeoffs,
        seconds: seconds(),
    };
    Ok(Assembled { report, results: results_by, pictures })
}

/// One detector's (mAP, NDS, class AP) and velocity errors on the common ground truth, and its
/// scores under every scene draw, by metric: mAP, pedestrian AP, mAVE and car AVE.
fn bootstrap_scores(
    common: &GroundTruth,
    pred: &Predictions,
    eval_cfg: &DetectionConfig,
    scenes: &[String],
    draws: &[Vec<u32>],
) -> Result<(hilo_eval::bootstrap::Replicate, VelocityErrors, BTreeMap<String, Scores>)> {
    let r = Reweighable::new(common, pred, eval_cfg, scenes).map_err(|e| StudyError::step("scoring detections", e))?;
    let (full, vel) = r.full_with_velocity(eval_cfg);
    let under = r.under_with_velocity(eval_cfg, draws);
    let ped = |x: &hilo_eval::bootstrap::Replicate| x.2.get("pedestrian").copied().unwrap_or(f64::NAN);
    let car = |v: &VelocityErrors| v.by_class.get("car").copied().unwrap_or(f64::NAN);
    let scores = BTreeMap::from([
        ("mAP".to_string(), Scores { full: full.0, replicates: under.iter().map(|x| x.0.0).collect() }),
        (
            "pedestrian AP".to_string(),
            Scores { full: ped(&full), replicates: under.iter().map(|x| ped(&x.0)).collect() },
        ),
        ("mAVE".to_string(), Scores { full: vel.mean, replicates: under.iter().map(|x| x.1.mean).collect() }),
        ("car AVE".to_string(), Scores { full: car(&vel), replicates: under.iter().map(|x| car(&x.1)).collect() }),
    ]);
    Ok((full, vel, scores))
}

/// A detector under the nuScenes convention (`visible`: the boxes with a point of its rig): its
/// scores on all scenes, and under the same scene draws named as [`crate::verdict::visible_only`]
/// names them (the claims' other reading).
fn visible_scores(
    visible: &GroundTruth,
    pred: &Predictions,
    eval_cfg: &DetectionConfig,
    scenes: &[String],
    draws: &[Vec<u32>],
    class_boxes: &BTreeMap<String, usize>,
) -> Result<(VisibleOnly, BTreeMap<String, Scores>)> {
    let (full, _, mut vis) = bootstrap_scores(visible, pred, eval_cfg, scenes, draws)?;
    let scores = crate::verdict::METRICS
        .iter()
        .filter_map(|m| Some((crate::verdict::visible_only(m), vis.remove(*m)?)))
        .collect();
    Ok((VisibleOnly { mean_ap: full.0, nd_score: full.1, class_ap: per_class(class_boxes, &full.2) }, scores))
}

/// A value per class of `class_boxes` (None where the class has no validation box or no value).
fn per_class(class_boxes: &BTreeMap<String, usize>, values: &BTreeMap<String, f64>) -> BTreeMap<String, Option<f64>> {
    class_boxes.iter().map(|(k, n)| (k.clone(), values.get(k).copied().filter(|v| *n > 0 && !v.is_nan()))).collect()
}

/// Validation boxes per class within the evaluation ranges (every class of the config, 0 where
/// none).
fn class_counts(common: &GroundTruth, base: &DetectionConfig) -> BTreeMap<String, usize> {
    let mut class_boxes: BTreeMap<String, usize> = base.class_range.keys().map(|k| (k.clone(), 0)).collect();
    for (s, boxes) in &common.boxes {
        let ego = common.samples.get(s).map_or([0.0; 3], |i| i.ego_translation);
        for b in hilo_eval::filter_boxes(boxes, ego, &base.class_range) {
            *class_boxes.entry(b.detection_name.clone()).or_default() += 1;
        }
    }
    class_boxes
}

/// The picture of a configuration: the middle validation frame as the job's detector input
/// reads it, its sample key and its common ground-truth boxes.
fn picture(
    job: &Job,
    registry: &Registry,
    ds: &hilo_dataset::Dataset,
    keys: &BTreeMap<String, String>,
    common: &GroundTruth,
) -> Result<Option<(Frame, String, Vec<EvalBox>)>> {
    let background = match &job.detector.input.background {
        Some(_) => Some(read_json(&hilo_detector::train::background_path(&job.run), limit::TABLE)?),
        None => None,
    };
    let lo = LoadOptions::of(&job.detector, registry, background.as_ref());
    let Some(f) = load_split_frame(ds, "val", &lo, keys.len() / 2)? else { return Ok(None) };
    let k = keys.get(&f.sample_token).cloned().unwrap_or_default();
    let boxes = common.boxes.get(&k).cloned().unwrap_or_default();
    Ok(Some((f, k, boxes)))
}

/// What the rig under study (the cheapest configuration with a radar; the cheapest of all when
/// none has one) saves against each other one, as a share of its cost (negative where it costs
/// more).
fn cost_reduction(summaries: &[ConfigSummary]) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    // In the study's own weather: a condition's copy of a rig costs what the rig does.
    let own = || summaries.iter().filter(|s| s.condition.is_none());
    let cheapest =
        |radar: bool| own().filter(|s| s.has_radar || !radar).min_by(|a, b| a.cost_usd.total_cmp(&b.cost_usd));
    if let Some(cheap) = cheapest(true).or_else(|| cheapest(false)) {
        for s in own().filter(|s| s.name != cheap.name) {
            out.insert(s.name.clone(), 1.0 - cheap.cost_usd / s.cost_usd);
        }
    }
    out
}

/// The share of a detector's boxes dropped for the planted difference of the calibration.
const DROP: f64 = 0.05;

/// Each configuration's placement and dataset, as the report lists them (the unseen shares are
/// filled in with the validation data).
fn config_summaries(plan: &Plan) -> Result<Vec<ConfigSummary>> {
    let configs = &plan.configurations;
    let mut summaries = Vec::new();
    for (ci, conf) in configs.iter().enumerate() {
        let placement = Placement::load(&plan.placement(ci))?;
        let data: DataRecord = read_json(&plan.data[ci].done(), limit::TABLE).map_err(|_| StudyError::NotReady {
            path: plan.data[ci].dir.clone(),
            what: format!("the dataset of {:?} is not complete", conf.name),
            remedy: "run its simulate stage first".into(),
        })?;
        summaries.push(ConfigSummary {
            name: conf.name.clone(),
            cost_usd: placement.cost_usd,
            has_radar: plan.radar[ci],
            central_coverage: placement.central_coverage,
            sensors: placement
                .sensors
                .iter()
                .map(|s| {
                    format!(
                        "{} at ({:.1}, {:.1}, {:.1}) m",
                        s.ty, s.pose.position.x, s.pose.position.y, s.pose.position.z
                    )
                })
                .collect(),
            placement_proven_optimal: placement.proven_optimal,
            placement_s: placement.solve_seconds,
            placement_solved: placement.solved,
            placement_gap: placement.gap,
            placement_method: placement.method.clone(),
            frames: data.frames,
            annotations: data.annotations,
            unseen_share: f64::NAN,
            unseen_by_class: BTreeMap::new(),
            condition: plan.conditions[ci].clone(),
            given: conf.given.clone(),
            radar_mounts: radar_mounts(&placement),
        });
    }
    Ok(summaries)
}

/// Each radar's mounting structure, and whether one of the rig's LiDARs stands on it too.
fn radar_mounts(p: &Placement) -> Vec<(String, bool)> {
    use hilo_placement_ip::Modality;
    let lidar = |structure: &str| p.sensors.iter().any(|s| s.modality == Modality::Lidar && s.structure == structure);
    p.sensors
        .iter()
        .filter(|s| s.modality == Modality::Radar)
        .map(|s| (s.structure.clone(), lidar(&s.structure)))
        .collect()
}

/// The verdict: comparisons, the paper's claims (each a Holm family) and the calibration of
/// the test on A/A pairs and the planted difference.
fn verdict(
    prof: &Profile,
    registry: &Registry,
    summaries: &[ConfigSummary],
    det_scores: &[DetectorScores],
    planted: &[DetectorScores],
    scenes: usize,
    margins: crate::verdict::Margins,
) -> (Vec<Comparison>, Vec<Claim>, Calibration) {
    // How many radars each rig has (a report written before `radar_mounts` says only whether).
    let conf_roles: Vec<(String, f64, usize)> = summaries
        .iter()
        .map(|s| (s.name.clone(), s.cost_usd, if s.has_radar { s.radar_mounts.len().max(1) } else { 0 }))
        .collect();
    let conditions: BTreeMap<String, String> =
        summaries.iter().filter_map(|s| Some((s.name.clone(), s.condition.clone()?))).collect();
    let roles = PresetRoles::of(prof, registry);
    let given: BTreeMap<String, String> =
        summaries.iter().filter_map(|s| Some((s.name.clone(), s.given.clone()?))).collect();
    // With several training-traffic draws, the draw is the replicate (a random effect).
    let units = crate::verdict::draw_units(det_scores);
    let planted = crate::verdict::draw_units(planted);
    let design = Design {
        given: &given,
        scores: &units,
        configurations: &conf_roles,
        conditions: &conditions,
        presets: &prof.presets,
        ablations: &prof.ablations,
        ablation_of: &roles.ablation_of,
        uses_radar: &roles.uses_radar,
        counterpart: &roles.counterpart,
        pointpillars_head: &roles.pointpillars_head,
        scenes,
        level: 0.95,
    };
    let mut comparisons = design.comparisons();
    let mut claims = design.claims();
    adjust(&mut claims, &mut comparisons, crate::verdict::ALPHA, margins);
    let mut calibration = calibrate(&design, &planted, DROP);
    calibration.traffic_draws = crate::verdict::METRICS
        .iter()
        .filter_map(|m| Some((m.to_string(), crate::verdict::draw_variance(det_scores, m)?)))
        .collect();
    (comparisons, claims, calibration)
}

/// The learning curve of seed 0 of every group: mAP of the training at each of the curve's
/// budgets (each a training of its own, [`hilo_plan::plan::CurveKind::Budget`]) and of the full
/// schedule, and what the last doubling added.
fn learning_curves(
    results_by: &ResultsBy,
    curve_preds: &BTreeMap<(String, String, usize), Predictions>,
    metas: &BTreeMap<(String, String, u64), ResultMeta>,
    entries: &[Entry],
    common: &GroundTruth,
    eval_cfg: &DetectionConfig,
    scenes: &[String],
) -> Result<Vec<Curve>> {
    let mut learning_curves = Vec::new();
    for ((conf, preset, seed), _) in results_by.iter().filter(|(k, _)| k.2 == 0) {
        let mut points: Vec<(usize, f64)> = Vec::new();
        for ((c, p, samples), pred) in curve_preds {
            if c == conf && p == preset {
                points.push((*samples, score_full(common, pred, eval_cfg, scenes)?));
            }
        }
        let end = metas[&(conf.clone(), preset.clone(), *seed)].samples;
        points.push((
            end,
            entries
                .iter()
                .find(|e| &e.configuration == conf && &e.preset == preset && e.seed == 0 && e.draw == 0)
                .map_or(f64::NAN, |e| e.mean_ap),
        ));
        points.sort_by_key(|p| p.0);
        let half = points.iter().min_by_key(|p| (2 * p.0).abs_diff(end)).map_or(f64::NAN, |p| p.1);
        let last = points.last().map_or(f64::NAN, |p| p.1);
        learning_curves.push(Curve {
            configuration: conf.clone(),
            preset: preset.clone(),
            points,
            gain_last_doubling: last - half,
            own_schedules: true,
        });
    }
    Ok(learning_curves)
}

fn sorted(mut p: Predictions) -> Predictions {
    p.sort_by(|a, b| a.0.cmp(&b.0));
    p
}

/// A train stage's outputs read back from its files.
fn read_outputs(job: &Job) -> Result<JobOutput> {
    if !job.done() {
        return Err(StudyError::NotReady {
            path: job.meta(),
            what: "missing".into(),
            remedy: format!("run the train stage {} first", job.id),
        });
    }
    let read = |p: &std::path::Path| -> Result<Predictions> { Ok(hilo_eval::read_submission(p, 500)?) };
    let curve = job.curve.iter().map(|&s| Ok((s, read(&job.curve_results(s))?))).collect::<Result<Vec<_>>>()?;
    Ok(JobOutput { predictions: read(&job.results)?, meta: read_json(&job.meta(), limit::TABLE)?, curve })
}

fn score_full(gt: &GroundTruth, pred: &Predictions, cfg: &DetectionConfig, scenes: &[String]) -> Result<f64> {
    Ok(Reweighable::new(gt, pred, cfg, scenes).map_err(|e| StudyError::step("scoring detections", e))?.full(cfg).0)
}

/// The predictions with a share of every sample's boxes dropped (seeded): a known degradation.
fn drop_share(pred: &Predictions, share: f64, seed: u64) -> Predictions {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xd20b ^ seed);
    pred.iter()
        .map(|(k, boxes)| (k.clone(), boxes.iter().filter(|_| !rng.random_bool(share)).cloned().collect()))
        .collect()
}

/// The test's false-positive rate on A/A pairs and its power on a planted degradation.
fn calibrate(design: &Design, planted: &[DetectorScores], share: f64) -> Calibration {
    let alpha = 0.05;
    // Per group of A/A pairs: (significant, pairs).
    let clusters: Vec<(usize, usize)> =
        design.aa_pairs().iter().map(|g| (g.iter().filter(|t| t.estimable && t.p < alpha).count(), g.len())).collect();
    let (fp, pairs) = clusters.iter().fold((0, 0), |(f, n), c| (f + c.0, n + c.1));
    let sv = design.seed_variance("mAP");
    // Per (configuration, preset): the detectors' scores, and the same with boxes dropped.
    type Arms<'a> = (Vec<&'a Scores>, Vec<&'a Scores>);
    let mut groups: BTreeMap<(&str, &str), Arms> = BTreeMap::new();
    for d in design.scores {
        if let Some(s) = d.scores.get("mAP") {
            groups.entry((&d.configuration, &d.preset)).or_default().0.push(s);
        }
    }
    for d in planted {
        if let (Some(s), Some(g)) =
            (d.scores.get("mAP"), groups.get_mut(&(d.configuration.as_str(), d.preset.as_str())))
        {
            g.1.push(s);
        }
    }
    let tests: Vec<_> = groups
        .values()
        .filter(|(a, b)| !a.is_empty() && a.len() == b.len())
        .map(|(a, b)| crate::stats::compare(a, b, sv, design.scenes, design.level))
        .collect();
    let found = tests.iter().filter(|t| t.estimable && t.p < alpha && t.estimate < 0.0).count();
    let interval = crate::stats::binomial_interval(fp, pairs, 0.95);
    let by_groups = crate::stats::cluster_rate_interval(&clusters, 0.95, 10_000, 0xaa);
    let envelope = by_groups.map_or(interval, |g| (interval.0.min(g.0), interval.1.max(g.1)));
    Calibration {
        alpha,
        pairs,
        false_positives: fp,
        false_positive_rate: fp as f64 / pairs.max(1) as f64,
        false_positive_interval: interval,
        false_positive_interval_groups: by_groups,
        held_out: true,
        reading: (pairs > 0).then(|| crate::verdict::CalibrationReading::of(envelope, alpha)),
        planted_drop_share: share,
        planted_pairs: tests.len(),
        planted_mean_effect: tests.iter().map(|t| t.estimate).sum::<f64>() / tests.len().max(1) as f64,
        power: found as f64 / tests.len().max(1) as f64,
        seed_variance: crate::verdict::METRICS.iter().map(|m| (m.to_string(), design.seed_variance(m))).collect(),
        traffic_draws: BTreeMap::new(),
    }
}

/// Presets whose ranking of the configurations differs between half their training and the end.
fn ranking_changes(curves: &[Curve], presets: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    for p in presets {
        let mine: Vec<&Curve> = curves.iter().filter(|c| &c.preset == p).collect();
        let rank = |at_half: bool| {
            let mut v: Vec<(&str, f64)> = mine
                .iter()
                .map(|c| {
                    let end = c.points.last().map_or(0, |x| x.0);
                    let x =
                        if at_half { c.points.iter().min_by_key(|q| (2 * q.0).abs_diff(end)) } else { c.points.last() };
                    (c.configuration.as_str(), x.map_or(f64::NAN, |q| q.1))
                })
                .collect();
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            v.into_iter().map(|x| x.0).collect::<Vec<_>>()
        };
        if mine.len() >= 2 && rank(true) != rank(false) {
            out.push(p.clone());
        }
    }
    out
}
