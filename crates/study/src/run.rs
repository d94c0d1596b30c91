//! A whole study: placement → a dataset per configuration (same traffic) → training of each
//! preset per configuration → detection and evaluation → report (Markdown, JSON, figures).
//!
//! Every stage keeps its output under the study folder and is skipped when it is already
//! complete: placements, datasets (resumable per scene), training runs (resumable per step),
//! results. The folder remembers the study's fingerprint (study file, profile, seeds); a folder
//! that holds another study is refused and nothing in it is overwritten. Progress goes to a
//! callback ([`Progress`]); nothing here prints.

use crate::error::{Result, StudyError};
use crate::files::{read_json, write_json};
use crate::place::{Placed, place_all, prepare_study, write_placements};
use crate::study::{Configuration, Study};
use candle_core::Device;
use hilo_dataset::simulate::SimulateConfig;
use hilo_eval::bootstrap::{BootstrapSummary, PairedSummary, bootstrap, paired_between};
use hilo_eval::{DetectionConfig, DetectionMetrics, EvalBox, GroundTruth};
use hilo_fusion::Registry;
use hilo_fusion::data::{Frame, LoadOptions, load_split};
use hilo_fusion::train::{TrainConfig, load_run, train};
use hilo_placement_ip::Placement;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What a running study tells its caller.
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// A stage starts or ends (one line for a person).
    Stage(&'a str),
    /// A long task moves: `done` of `total` units (frames, steps).
    Task { label: &'a str, done: usize, total: usize, unit: &'a str },
    /// The current task is over.
    TaskDone,
}

/// The scale of a study.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    pub name: String,
    pub dataset: SimulateConfig,
    pub presets: Vec<String>,
    /// How many of the study's configurations (in order); all when None.
    pub configurations: Option<usize>,
    /// Only configurations with a radar (the paper's three).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub with_radar_only: bool,
    pub train_samples: usize,
    pub bootstrap: usize,
    /// Target cell size of the placement speed-against-error sweeps (the study's when None).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tradeoff_cell_m: Option<f32>,
}

/// The profiles: `quick` (≤ 5 min), `default` (≤ 30 min), `paper` (the paper's scale), and
/// `tiny` (seconds; for tests).
pub fn profile(name: &str, study: &Study, registry: &Registry) -> Result<Profile> {
    let base = study.file.dataset.clone();
    let p = match name {
        "quick" => Profile {
            name: name.into(),
            dataset: SimulateConfig { scenes: 4, seconds: 8.0, rate_hz: 10.0, val_scenes: 5, val_seconds: 8.0, ..base },
            presets: vec!["centerpoint".into(), "pointpillars-lr".into()],
            configurations: Some(2),
            with_radar_only: false,
            train_samples: 240,
            bootstrap: 200,
            tradeoff_cell_m: None,
        },
        "default" => Profile {
            name: name.into(),
            dataset: base,
            presets: vec!["centerpoint".into(), "pointpillars-lr".into(), "lirafusion-like".into()],
            configurations: None,
            with_radar_only: false,
            train_samples: 600,
            bootstrap: 500,
            tradeoff_cell_m: None,
        },
        "paper" => Profile {
            name: name.into(),
            dataset: SimulateConfig { scenes: 37, seconds: 20.0, rate_hz: 20.0, sweep_rate_hz: 20.0, ..base },
            presets: registry.preset_names().into_iter().filter(|n| !n.ends_with("-no-early")).collect(),
            configurations: None,
            with_radar_only: true,
            train_samples: 12_000,
            bootstrap: 1000,
            tradeoff_cell_m: None,
        },
        "tiny" => Profile {
            name: name.into(),
            dataset: SimulateConfig { scenes: 2, seconds: 1.5, rate_hz: 10.0, val_scenes: 2, val_seconds: 1.5, ..base },
            presets: vec!["centerpoint".into(), "pointpillars-lr".into()],
            configurations: Some(2),
            with_radar_only: false,
            train_samples: 8,
            bootstrap: 20,
            tradeoff_cell_m: Some(5.0),
        },
        other => return Err(StudyError::Invalid(format!("--profile {other:?}: use quick, default or paper"))),
    };
    Ok(p)
}

/// One trained detector's evaluation.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Entry {
    pub configuration: String,
    pub preset: String,
    pub seed: u64,
    pub mean_ap: f64,
    pub nd_score: f64,
    pub class_ap: BTreeMap<String, f64>,
    pub bootstrap: BootstrapSummary,
    pub train_seconds: f64,
    pub ms_per_frame: f64,
    pub samples: usize,
    /// Trainable parameters of the detector.
    pub parameters: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConfigSummary {
    pub name: String,
    pub cost_usd: f64,
    pub central_coverage: f64,
    pub sensors: Vec<String>,
    pub placement_proven_optimal: bool,
    pub placement_seconds: f64,
    /// Whether the placement was optimised (a single-modality configuration takes a sibling's
    /// poses instead).
    pub placement_solved: bool,
    /// Relative gap of an unproven placement.
    pub placement_gap: f64,
    /// How the placement was found (for a single-modality configuration: whose poses it took).
    pub placement_method: String,
    pub frames: usize,
    pub annotations: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Comparison {
    pub preset: String,
    pub a: String,
    pub b: String,
    pub paired: PairedSummary,
    pub pedestrian_ap_a: f64,
    pub pedestrian_ap_b: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Report {
    pub study: String,
    pub profile: Profile,
    pub seeds: u64,
    pub configurations: Vec<ConfigSummary>,
    pub entries: Vec<Entry>,
    pub comparisons: Vec<Comparison>,
    pub cost_reduction: BTreeMap<String, f64>,
    /// Placement's speed against error: line-of-sight samples and solver time limits.
    pub tradeoffs: crate::tradeoff::Tradeoffs,
    pub seconds: f64,
}

/// Predictions of one detector: (sample token, boxes) in sample order.
pub type Predictions = Vec<(String, Vec<EvalBox>)>;
/// Predictions by (configuration, preset, seed).
pub type ResultsBy = BTreeMap<(String, String, u64), Predictions>;
/// Per configuration, the validation frame the report draws (the middle one) and its ground truth.
pub type Pictures = BTreeMap<String, (Frame, Vec<EvalBox>)>;

/// How a study is run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub profile: Profile,
    pub seeds: u64,
    pub out: PathBuf,
}

fn fingerprint(study: &Study, p: &Profile, seeds: u64) -> Result<String> {
    let profile = serde_json::to_string(p).map_err(|e| StudyError::Invalid(e.to_string()))?;
    let text = format!("{:?}|{}|{}", study.file, profile, seeds);
    Ok(crate::files::hash(&[&text]))
}

/// Frames of one input config: its background model, training and validation frames.
type Loaded = (Option<hilo_dataset::background::BackgroundModel>, Vec<Frame>, Vec<Frame>);

fn uses_radar(registry: &Registry, preset: &str) -> bool {
    registry.preset(preset).is_ok_and(|p| registry.uses_radar(&p.detector))
}

/// What the detection stage keeps beside a result file, so a resumed study needs no detector.
#[derive(Serialize, Deserialize)]
struct ResultMeta {
    ms_per_frame: f64,
    parameters: usize,
}

/// Runs (or resumes) a study in `opts.out` and writes its report.
pub fn run(
    study: &Study,
    registry: &Registry,
    opts: &RunOptions,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Report> {
    let t0 = std::time::Instant::now();
    let prof = &opts.profile;
    if opts.seeds == 0 {
        return Err(StudyError::Invalid("--seeds must be at least 1".into()));
    }
    for p in &prof.presets {
        registry
            .preset(p)
            .map_err(|e| StudyError::Invalid(format!("--presets / profile {}: preset {p:?}: {e}", prof.name)))?;
    }
    let out = &opts.out;
    let fp = fingerprint(study, prof, opts.seeds)?;
    let marker = out.join("study.json");
    if marker.exists() {
        let old: serde_json::Value = read_json(&marker)?;
        if old.get("fingerprint").and_then(|v| v.as_str()) != Some(fp.as_str()) {
            return Err(StudyError::Invalid(format!(
                "{} holds another study (study file, profile or seeds differ: fingerprint {} there, {fp} now); choose another --out",
                out.display(),
                old.get("fingerprint").and_then(|v| v.as_str()).unwrap_or("?")
            )));
        }
    } else if out.exists() && std::fs::read_dir(out).map(|mut d| d.next().is_some()).unwrap_or(false) {
        return Err(StudyError::Invalid(format!(
            "{} exists and is not a study folder; choose another --out",
            out.display()
        )));
    }
    std::fs::create_dir_all(out).map_err(|e| StudyError::io(out, e))?;
    write_json(
        &marker,
        &serde_json::json!({ "fingerprint": fp, "study": study.source, "profile": prof.name, "seeds": opts.seeds }),
    )?;
    let catalog = &study.catalog;
    let configs: Vec<Configuration> = study
        .file
        .configurations
        .iter()
        .filter(|c| !prof.with_radar_only || c.has_radar(catalog))
        .take(prof.configurations.unwrap_or(usize::MAX))
        .cloned()
        .collect();
    if prof.name == "paper" {
        let frames = prof.dataset.total_frames();
        let hours = (configs.len() * prof.presets.len() * opts.seeds as usize) as f64 * prof.train_samples as f64
            / 4.0
            / 3600.0
            + (configs.len() * frames) as f64 / 130.0 / 3600.0;
        progress(Progress::Stage(&format!(
            "paper profile: {} configurations × {} presets × {} seeds, {frames} frames each; about {hours:.1} h on this machine (4 samples/s training, 130 frames/s simulation)",
            configs.len(),
            prof.presets.len(),
            opts.seeds
        )));
    }
    // 1. Placement: visibility once for every sensor type, every configuration solved.
    let placements_dir = out.join("placements");
    let all_placed = configs.iter().all(|c| placements_dir.join(format!("{}.json", c.slug())).exists());
    let mut placed: Option<Placed> = None;
    if !all_placed {
        progress(Progress::Stage("placement"));
        let prep = prepare_study(study)?;
        let p = place_all(study, prep, &mut |line| progress(Progress::Stage(line)))?;
        write_placements(study, &p, &placements_dir)?;
        placed = Some(p);
    }
    let tradeoff_path = placements_dir.join("tradeoffs.json");
    let tradeoffs: crate::tradeoff::Tradeoffs = match read_json(&tradeoff_path) {
        Ok(t) => t,
        Err(_) => {
            progress(Progress::Stage("placement speed against error (line-of-sight samples, solver time limits)"));
            let prep = match &placed {
                Some(p) if prof.tradeoff_cell_m.is_none() => Some(&p.prepared),
                _ => None,
            };
            let t = crate::tradeoff::compute(study, prep, prof.tradeoff_cell_m)?;
            write_json(&tradeoff_path, &t)?;
            t
        }
    };
    let eval_cfg = DetectionConfig::default();
    let mut summaries = Vec::new();
    let mut entries = Vec::new();
    let mut results_by: ResultsBy = BTreeMap::new();
    let mut gts: BTreeMap<String, GroundTruth> = BTreeMap::new();
    let mut pictures: Pictures = BTreeMap::new();
    // Whole-study progress: detectors to train, and an ETA from the ones done so far.
    let total_detectors: usize = configs
        .iter()
        .map(|c| prof.presets.iter().filter(|p| !uses_radar(registry, p) || c.has_radar(catalog)).count())
        .sum::<usize>()
        * opts.seeds as usize;
    let mut done_detectors = 0usize;
    let t_detectors = std::time::Instant::now();
    for conf in &configs {
        let slug = conf.slug();
        let ppath = placements_dir.join(format!("{slug}.json"));
        let placement = Placement::load(&ppath)?;
        // 2. Dataset (same traffic seeds for every configuration).
        let data = out.join("data").join(&slug);
        let total = prof.dataset.total_frames();
        let label = format!("dataset {}", conf.name);
        let summary = {
            let report = |done: usize| progress(Progress::Task { label: &label, done, total, unit: "frames" });
            let cell = std::sync::Mutex::new(report);
            crate::rig::simulate(study, &placement, &ppath, &prof.dataset, &data, "v1.0-trainval", &|done| {
                if let Ok(mut f) = cell.lock() {
                    f(done)
                }
            })?
        };
        progress(Progress::TaskDone);
        progress(Progress::Stage(&format!(
            "dataset {}: {} frames, {} annotations ({} scenes resumed)",
            conf.name, summary.frames, summary.annotations, summary.resumed_scenes
        )));
        summaries.push(ConfigSummary {
            name: conf.name.clone(),
            cost_usd: placement.cost_usd,
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
            placement_seconds: placement.solve_seconds,
            placement_solved: placement.solved,
            placement_gap: placement.gap,
            placement_method: placement.method.clone(),
            frames: summary.frames,
            annotations: summary.annotations,
        });
        let ds = hilo_dataset::Dataset::open(&data, "v1.0-trainval")?;
        // Frames as each preset's input reads them (background removed or not, radar sweeps),
        // loaded once per distinct input.
        let mut inputs: BTreeMap<String, Loaded> = BTreeMap::new();
        let (gt, _) = crate::gt::ground_truth(&ds, "val", crate::gt::GtKind::VisibleOnly, crate::gt::SampleKey::Token)?;
        gts.insert(conf.name.clone(), gt.clone());
        for preset in &prof.presets {
            if uses_radar(registry, preset) && !conf.has_radar(catalog) {
                progress(Progress::Stage(&format!(
                    "{} on {}: skipped (the configuration has no radar)",
                    preset, conf.name
                )));
                continue;
            }
            for seed in 0..opts.seeds {
                // 3. Training (resumes; returns at once when finished).
                let run = out.join("runs").join(&slug).join(format!("{preset}-seed{seed}"));
                let det_cfg = registry.preset(preset)?.detector.clone();
                let key = serde_json::to_string(&det_cfg.input).map_err(|e| StudyError::Invalid(e.to_string()))?;
                if !inputs.contains_key(&key) {
                    let bg = hilo_fusion::train::learn_background(&ds, "train", &det_cfg.input)?;
                    let opts = LoadOptions::new(&det_cfg.input, bg.as_ref());
                    let (tr, _) = load_split(&ds, "train", &opts)?;
                    let (va, _) = load_split(&ds, "val", &opts)?;
                    inputs.insert(key.clone(), (bg, tr, va));
                }
                let Some((background, train_frames, val_frames)) = inputs.get(&key) else { continue };
                if let (false, Some(f)) = (pictures.contains_key(&conf.name), val_frames.get(val_frames.len() / 2)) {
                    pictures.insert(
                        conf.name.clone(),
                        (f.clone(), gt.boxes.get(&f.sample_token).cloned().unwrap_or_default()),
                    );
                }
                let tc = TrainConfig { samples: prof.train_samples, seed, ..TrainConfig::default() };
                let label = format!("train {preset} on {}", conf.name);
                let steps = tc.steps();
                let info =
                    train(&run, &det_cfg, &tc, train_frames, background.as_ref(), registry, &Device::Cpu, &mut |r| {
                        progress(Progress::Task { label: &label, done: r.step, total: steps, unit: "steps" });
                        true
                    })
                    .map_err(|e| StudyError::Invalid(format!("training {preset} on {}: {e}", conf.name)))?;
                progress(Progress::TaskDone);
                // 4. Detection (skipped when the results exist).
                let res_path = out.join("results").join(&slug).join(format!("{preset}-seed{seed}.json"));
                let meta_path = res_path.with_extension("meta.json");
                let (pred, meta) = match (read_json::<ResultMeta>(&meta_path), res_path.exists()) {
                    (Ok(meta), true) => (hilo_eval::read_submission(&res_path, 500)?, meta),
                    _ => {
                        let (det, _, _) = load_run(&run, registry, &Device::Cpu)?;
                        let (dets, per_frame) = hilo_fusion::infer::detect_frames(&det, val_frames, 4, &mut |_| {})?;
                        // In the order the submission file keeps (sample tokens sorted), so that a
                        // resumed study, which reads the file back, scores exactly the same.
                        let mut pred = hilo_eval::boxes::from_detections(&dets);
                        pred.sort_by(|a, b| a.0.cmp(&b.0));
                        let json =
                            hilo_eval::boxes::submission_json(&pred, serde_json::json!({ "detector": det.cfg.name }));
                        write_json(&res_path, &json)?;
                        let meta = ResultMeta { ms_per_frame: per_frame * 1e3, parameters: det.parameters() };
                        write_json(&meta_path, &meta)?;
                        (pred, meta)
                    }
                };
                // 5. Evaluation.
                let m: DetectionMetrics = hilo_eval::evaluate_files(&gt, &pred, &eval_cfg);
                let bs = bootstrap(&gt, &pred, &eval_cfg, prof.bootstrap, 0.95, 0);
                let class_ap = m
                    .label_aps
                    .iter()
                    .map(|(k, v)| (k.clone(), v.values().sum::<f64>() / v.len().max(1) as f64))
                    .collect();
                done_detectors += 1;
                let per = t_detectors.elapsed().as_secs_f64() / done_detectors as f64;
                progress(Progress::Stage(&format!(
                    "{preset} on {} (seed {seed}): mAP {:.3}, NDS {:.3}, {:.0} s training; {done_detectors}/{total_detectors} detectors, study ETA {:.0} min",
                    conf.name,
                    m.mean_ap,
                    m.nd_score,
                    info.seconds,
                    per * (total_detectors - done_detectors) as f64 / 60.0
                )));
                entries.push(Entry {
                    configuration: conf.name.clone(),
                    preset: preset.clone(),
                    seed,
                    mean_ap: m.mean_ap,
                    nd_score: m.nd_score,
                    class_ap,
                    bootstrap: bs,
                    train_seconds: info.seconds,
                    ms_per_frame: meta.ms_per_frame,
                    samples: info.samples_seen,
                    parameters: meta.parameters,
                });
                results_by.insert((conf.name.clone(), preset.clone(), seed), pred);
            }
        }
    }
    // Paired comparisons: the cheapest configuration against each other one, per preset (seed 0).
    let mut comparisons = Vec::new();
    if let Some(cheap) = summaries.iter().min_by(|a, b| a.cost_usd.total_cmp(&b.cost_usd)) {
        for other in summaries.iter().filter(|s| s.name != cheap.name) {
            for preset in &prof.presets {
                let (Some(a), Some(b)) = (
                    results_by.get(&(other.name.clone(), preset.clone(), 0)),
                    results_by.get(&(cheap.name.clone(), preset.clone(), 0)),
                ) else {
                    continue;
                };
                // Same traffic and scene names, different tokens: each configuration on its own
                // ground truth (the boxes its sensors saw), the same scenes drawn for both.
                let (Some(ga), Some(gb)) = (gts.get(&other.name), gts.get(&cheap.name)) else { continue };
                let p = paired_between(ga, a, gb, b, &eval_cfg, prof.bootstrap, 0.95, 0);
                let ped = |cfg: &str| {
                    entries
                        .iter()
                        .find(|e| e.configuration == cfg && e.preset == *preset && e.seed == 0)
                        .and_then(|e| e.class_ap.get("pedestrian").copied())
                        .unwrap_or(f64::NAN)
                };
                comparisons.push(Comparison {
                    preset: preset.clone(),
                    a: other.name.clone(),
                    b: cheap.name.clone(),
                    paired: p,
                    pedestrian_ap_a: ped(&other.name),
                    pedestrian_ap_b: ped(&cheap.name),
                });
            }
        }
    }
    let mut cost_reduction = BTreeMap::new();
    if let Some(cheap) = summaries.iter().min_by(|a, b| a.cost_usd.total_cmp(&b.cost_usd)) {
        for s in summaries.iter().filter(|s| s.name != cheap.name) {
            cost_reduction.insert(s.name.clone(), 1.0 - cheap.cost_usd / s.cost_usd);
        }
    }
    let report = Report {
        study: study.source.clone(),
        profile: prof.clone(),
        seeds: opts.seeds,
        configurations: summaries,
        entries,
        comparisons,
        cost_reduction,
        tradeoffs,
        seconds: t0.elapsed().as_secs_f64(),
    };
    crate::report::write(out, &report, &results_by, &pictures, &placements_dir, &configs)?;
    progress(Progress::Stage(&format!("report: {} ({:.0} s)", out.join("report.md").display(), report.seconds)));
    Ok(report)
}

/// Where a study keeps a configuration's dataset.
pub fn data_dir(out: &Path, conf: &Configuration) -> PathBuf {
    out.join("data").join(conf.slug())
}
