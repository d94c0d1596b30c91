//! `hilo study`: placement → a dataset per configuration (same traffic) → training of each
//! preset per configuration → detection and evaluation → report (Markdown, JSON, figures).
//!
//! Every stage keeps its output under `--out` and is skipped when it is already complete:
//! placements, datasets (resumable per scene), training runs (resumable per step), results.
//! The folder remembers the study's fingerprint (study file, profile, seeds); a folder that
//! holds another study is refused and nothing in it is overwritten.

use crate::simulate::{PlacementFile, write_with_progress};
use crate::study::{Configuration, Study};
use anyhow::{Context, Result, bail};
use candle_core::Device;
use hilo_dataset::simulate::SimulateConfig;
use hilo_eval::bootstrap::{BootstrapSummary, PairedSummary, bootstrap, paired_between};
use hilo_eval::{DetectionConfig, DetectionMetrics, EvalBox, GroundTruth};
use hilo_fusion::train::{TrainConfig, load_run, train};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct StudyArgs {
    /// Study TOML; the embedded default (the paper's configurations on the default
    /// intersection) when omitted.
    pub study: Option<PathBuf>,
    #[arg(long, default_value = "study")]
    pub out: PathBuf,
    /// quick (≤ 5 min: 2 configurations, 2 presets, few frames), default (≤ 30 min), or paper
    /// (37 scenes × 20 s × 20 Hz, six presets; hours here).
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Train every detector with this many seeds (means and ranges in the report).
    #[arg(long, default_value_t = 1)]
    pub seeds: u64,
    /// Presets to train (comma-separated), overriding the profile's.
    #[arg(long, value_delimiter = ',')]
    pub presets: Option<Vec<String>>,
}

/// Predictions of one detector: (sample token, boxes) in sample order.
pub type Predictions = Vec<(String, Vec<EvalBox>)>;
/// Predictions by (configuration, preset, seed).
pub type ResultsBy = BTreeMap<(String, String, u64), Predictions>;

/// Per configuration, the validation frame the report draws (the middle one) and its ground truth.
pub type Pictures = BTreeMap<String, (hilo_fusion::data::Frame, Vec<EvalBox>)>;

/// The scale of a study.
#[derive(Clone, Debug, Serialize)]
pub struct Profile {
    pub name: String,
    pub dataset: SimulateConfig,
    pub presets: Vec<String>,
    /// How many of the study's configurations (in order); all when None.
    pub configurations: Option<usize>,
    /// Only configurations with a radar (the paper's three).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub with_radar_only: bool,
    pub train_samples: usize,
    pub bootstrap: usize,
    /// Target cell size of the placement speed-against-error sweeps (the study's when None).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tradeoff_cell_m: Option<f32>,
}

pub fn profile(name: &str, study: &Study) -> Result<Profile> {
    let base = study.file.dataset.clone();
    let p = match name {
        "quick" => Profile {
            name: name.into(),
            dataset: SimulateConfig { scenes: 4, seconds: 8.0, rate_hz: 10.0, ..base },
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
            dataset: SimulateConfig { scenes: 37, seconds: 20.0, rate_hz: 20.0, ..base },
            presets: crate::train::registry()?
                .preset_names()
                .into_iter()
                .filter(|n| !n.ends_with("-no-early"))
                .collect(),
            configurations: None,
            with_radar_only: true,
            train_samples: 12_000,
            bootstrap: 1000,
            tradeoff_cell_m: None,
        },
        "tiny" => Profile {
            name: name.into(),
            dataset: SimulateConfig { scenes: 2, seconds: 1.5, rate_hz: 10.0, ..base },
            presets: vec!["centerpoint".into(), "pointpillars-lr".into()],
            configurations: Some(2),
            with_radar_only: false,
            train_samples: 8,
            bootstrap: 20,
            tradeoff_cell_m: Some(5.0),
        },
        other => bail!("--profile {other:?}: use quick, default or paper"),
    };
    Ok(p)
}

/// Frames of one input config: its background model, training and validation frames.
type Loaded =
    (Option<hilo_dataset::background::BackgroundModel>, Vec<hilo_fusion::data::Frame>, Vec<hilo_fusion::data::Frame>);

fn uses_radar(registry: &hilo_fusion::Registry, preset: &str) -> bool {
    registry.preset(preset).is_ok_and(|p| registry.uses_radar(&p.detector))
}

fn has_radar(c: &Configuration) -> bool {
    c.type_names().iter().any(|t| t.starts_with("radar"))
}

/// One trained detector's evaluation.
#[derive(Clone, Debug, Serialize)]
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

#[derive(Clone, Debug, Serialize)]
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

#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    pub preset: String,
    pub a: String,
    pub b: String,
    pub paired: PairedSummary,
    pub pedestrian_ap_a: f64,
    pub pedestrian_ap_b: f64,
}

#[derive(Clone, Debug, Serialize)]
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

fn fingerprint(study: &Study, p: &Profile, seeds: u64) -> Result<String> {
    let text = format!("{:?}|{}|{}", study.file, serde_json::to_string(p)?, seeds);
    Ok(hilo_dataset::writer::token(&[&text]))
}

fn stage(msg: &str) {
    eprintln!("[study] {msg}");
}

pub fn run(args: &StudyArgs) -> Result<Report> {
    let t0 = std::time::Instant::now();
    let study = Study::load(args.study.as_deref())?;
    let mut prof = profile(&args.profile, &study)?;
    if let Some(p) = &args.presets {
        prof.presets = p.clone();
    }
    if args.seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    for p in &prof.presets {
        crate::train::registry()?
            .preset(p)
            .with_context(|| format!("--presets / profile {}: preset {p:?}", prof.name))?;
    }
    let out = &args.out;
    let fp = fingerprint(&study, &prof, args.seeds)?;
    let marker = out.join("study.json");
    if marker.exists() {
        let old: serde_json::Value = serde_json::from_slice(&std::fs::read(&marker)?)
            .with_context(|| format!("reading {}", marker.display()))?;
        if old.get("fingerprint").and_then(|v| v.as_str()) != Some(fp.as_str()) {
            bail!(
                "{} holds another study (study file, profile or seeds differ: fingerprint {} there, {fp} now); choose another --out",
                out.display(),
                old.get("fingerprint").and_then(|v| v.as_str()).unwrap_or("?")
            );
        }
    } else if out.exists() && std::fs::read_dir(out).map(|mut d| d.next().is_some()).unwrap_or(false) {
        bail!("{} exists and is not a study folder; choose another --out", out.display());
    }
    std::fs::create_dir_all(out)?;
    crate::write_atomic(
        &marker,
        serde_json::to_string_pretty(
            &serde_json::json!({ "fingerprint": fp, "study": study.source, "profile": prof.name, "seeds": args.seeds }),
        )?
        .as_bytes(),
    )?;
    let configs: Vec<Configuration> = study
        .file
        .configurations
        .iter()
        .filter(|c| !prof.with_radar_only || has_radar(c))
        .take(prof.configurations.unwrap_or(usize::MAX))
        .cloned()
        .collect();
    if prof.name == "paper" {
        let frames = prof.dataset.scenes * prof.dataset.frames_per_scene();
        let hours = (configs.len() * prof.presets.len() * args.seeds as usize) as f64 * prof.train_samples as f64
            / 4.0
            / 3600.0
            + (configs.len() * frames) as f64 / 130.0 / 3600.0;
        stage(&format!(
            "paper profile: {} configurations × {} presets × {} seeds, {frames} frames each; about {hours:.1} h on this machine (4 samples/s training, 130 frames/s simulation)",
            configs.len(),
            prof.presets.len(),
            args.seeds
        ));
    }
    // 1. Placement.
    let placements = out.join("placements");
    let all_placed = configs.iter().all(|c| placements.join(format!("{}.json", c.slug())).exists());
    if !all_placed {
        stage("placement");
        let study_path = args.study.clone();
        crate::place::run(&crate::place::PlaceArgs {
            study: study_path,
            out: placements.clone(),
            json: false,
            export: None,
        })?;
    }
    let scene = crate::load_scene(study.file.scene.as_ref().map(|p| study.resolve(p)).as_deref())?;
    let catalog = match &study.file.catalog {
        Some(p) => hilo_sensor_models::Catalog::load(&study.resolve(p))?,
        None => hilo_sensor_models::Catalog::default_catalog()?,
    };
    let tradeoff_path = placements.join("tradeoffs.json");
    let tradeoffs: crate::tradeoff::Tradeoffs = match std::fs::read(&tradeoff_path) {
        Ok(bytes) => serde_json::from_slice(&bytes).with_context(|| format!("reading {}", tradeoff_path.display()))?,
        Err(_) => {
            stage("placement speed against error (line-of-sight samples, solver time limits)");
            let t = crate::tradeoff::compute(&study, &scene, &catalog, prof.tradeoff_cell_m)?;
            crate::write_atomic(&tradeoff_path, serde_json::to_string_pretty(&t)?.as_bytes())?;
            t
        }
    };
    let registry = crate::train::registry()?;
    let eval_cfg = DetectionConfig::default();
    let mut summaries = Vec::new();
    let mut entries = Vec::new();
    let mut results_by: ResultsBy = BTreeMap::new();
    let mut gts: BTreeMap<String, GroundTruth> = BTreeMap::new();
    let mut pictures: Pictures = BTreeMap::new();
    // Whole-study progress: detectors to train, and an ETA from the ones done so far.
    let total_detectors: usize = configs
        .iter()
        .map(|c| prof.presets.iter().filter(|p| !uses_radar(&registry, p) || has_radar(c)).count())
        .sum::<usize>()
        * args.seeds as usize;
    let mut done_detectors = 0usize;
    let t_detectors = std::time::Instant::now();
    for conf in &configs {
        let slug = conf.slug();
        let ppath = placements.join(format!("{slug}.json"));
        let placement = PlacementFile::load(&ppath)?;
        let pjson: serde_json::Value = serde_json::from_slice(&std::fs::read(&ppath)?)?;
        let rig = placement.rig(&catalog, &scene, &ppath)?;
        // 2. Dataset (same traffic seeds for every configuration).
        let data = out.join("data").join(&slug);
        let summary = write_with_progress(
            &scene,
            &rig,
            &prof.dataset,
            &data,
            "v1.0-trainval",
            &placement.name,
            &format!("dataset {}", conf.name),
        )?;
        stage(&format!(
            "dataset {}: {} frames, {} annotations ({} scenes resumed)",
            conf.name, summary.frames, summary.annotations, summary.resumed_scenes
        ));
        summaries.push(ConfigSummary {
            name: conf.name.clone(),
            cost_usd: pjson["cost_usd"].as_f64().unwrap_or(f64::NAN),
            central_coverage: pjson["central_coverage"].as_f64().unwrap_or(f64::NAN),
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
            placement_proven_optimal: pjson["proven_optimal"].as_bool().unwrap_or(false),
            placement_seconds: pjson["solve_seconds"].as_f64().unwrap_or(f64::NAN),
            placement_solved: !crate::place::single_modality(conf, &catalog),
            placement_gap: pjson["gap"].as_f64().unwrap_or(f64::NAN),
            placement_method: pjson["method"].as_str().unwrap_or_default().to_owned(),
            frames: summary.frames,
            annotations: summary.annotations,
        });
        let ds = hilo_dataset::Dataset::open(&data, "v1.0-trainval")?;
        // Frames as each preset's input reads them (background removed or not, radar sweeps),
        // loaded once per distinct input.
        let mut inputs: BTreeMap<String, Loaded> = BTreeMap::new();
        let mut gt = hilo_eval::ground_truth_from_dataset(&ds, "val")?;
        // Scene names (not tokens) so that configurations' scenes can be paired.
        let scene_name: BTreeMap<&str, &str> =
            ds.tables.scene.iter().map(|s| (s.token.as_str(), s.name.as_str())).collect();
        for info in gt.samples.values_mut() {
            if let Some(n) = scene_name.get(info.scene.as_str()) {
                info.scene = (*n).to_owned();
            }
        }
        gts.insert(conf.name.clone(), gt.clone());
        for preset in &prof.presets {
            if uses_radar(&registry, preset) && !has_radar(conf) {
                stage(&format!("{} on {}: skipped (the configuration has no radar)", preset, conf.name));
                continue;
            }
            for seed in 0..args.seeds {
                // 3. Training (resumes; returns at once when finished).
                let run = out.join("runs").join(&slug).join(format!("{preset}-seed{seed}"));
                let det_cfg = registry.preset(preset)?.detector.clone();
                let key = serde_json::to_string(&det_cfg.input)?;
                if !inputs.contains_key(&key) {
                    let bg = hilo_fusion::train::learn_background(&ds, "train", &det_cfg.input)?;
                    let opts = hilo_fusion::data::LoadOptions::new(&det_cfg.input, bg.as_ref());
                    let (tr, _) = hilo_fusion::data::load_split(&ds, "train", &opts)?;
                    let (va, _) = hilo_fusion::data::load_split(&ds, "val", &opts)?;
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
                let bar = indicatif::ProgressBar::new(tc.steps() as u64);
                bar.set_style(
                    indicatif::ProgressStyle::with_template("{msg} [{bar:25}] {pos}/{len} steps, ETA {eta}")
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
                );
                let label = format!("train {preset} on {}", conf.name);
                let info =
                    train(&run, &det_cfg, &tc, train_frames, background.as_ref(), &registry, &Device::Cpu, &mut |r| {
                        bar.set_position(r.step as u64);
                        bar.set_message(format!("{label} loss {:.3}", r.loss));
                        true
                    })
                    .with_context(|| format!("training {preset} on {}", conf.name))?;
                bar.finish_and_clear();
                // 4. Detection (skipped when the results exist).
                let res_path = out.join("results").join(&slug).join(format!("{preset}-seed{seed}.json"));
                let meta_path = res_path.with_extension("meta.json");
                if !(res_path.exists() && meta_path.exists()) {
                    let (det, _, _) = load_run(&run, &registry, &Device::Cpu)?;
                    let (dets, per_frame) = hilo_fusion::infer::detect_frames(&det, val_frames, 4, &mut |_| {})?;
                    let json = hilo_eval::boxes::submission_json(
                        &hilo_eval::boxes::from_detections(&dets),
                        serde_json::json!({ "detector": det.cfg.name }),
                    );
                    crate::write_atomic(&res_path, serde_json::to_string(&json)?.as_bytes())?;
                    crate::write_atomic(
                        &meta_path,
                        serde_json::to_string(&serde_json::json!({ "ms_per_frame": per_frame * 1e3 }))?.as_bytes(),
                    )?;
                }
                let meta: serde_json::Value = serde_json::from_slice(&std::fs::read(&meta_path)?)?;
                let pred = hilo_eval::read_submission(&res_path, 500)?;
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
                stage(&format!(
                    "{preset} on {} (seed {seed}): mAP {:.3}, NDS {:.3}, {:.0} s training; {done_detectors}/{total_detectors} detectors, study ETA {:.0} min",
                    conf.name,
                    m.mean_ap,
                    m.nd_score,
                    info.seconds,
                    per * (total_detectors - done_detectors) as f64 / 60.0
                ));
                entries.push(Entry {
                    configuration: conf.name.clone(),
                    preset: preset.clone(),
                    seed,
                    mean_ap: m.mean_ap,
                    nd_score: m.nd_score,
                    class_ap,
                    bootstrap: bs,
                    train_seconds: info.seconds,
                    ms_per_frame: meta["ms_per_frame"].as_f64().unwrap_or(f64::NAN),
                    samples: info.samples_seen,
                    parameters: hilo_fusion::Detector::new(&det_cfg, &registry, &Device::Cpu, 0)?.parameters(),
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
        seeds: args.seeds,
        configurations: summaries,
        entries,
        comparisons,
        cost_reduction,
        tradeoffs,
        seconds: t0.elapsed().as_secs_f64(),
    };
    crate::report::write(out, &report, &results_by, &pictures, &placements, &configs)?;
    stage(&format!("report: {} ({:.0} s)", out.join("report.md").display(), report.seconds));
    Ok(report)
}
