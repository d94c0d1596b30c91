//! The stages of a study's [`Plan`], each runnable on its own (by `hilo study place`,
//! `simulate`, `train`, `report`, or a workflow engine's job) or all in one process by
//! `hilo_study::run`. A stage whose outputs exist is skipped; every output is written atomically,
//! its completion marker last, so a stage killed part-way is redone (a dataset and a training
//! resume from what they kept) and a stage run twice writes the same bytes.

use crate::error::{Result, StudyError};
use crate::place::{Placed, place_all, prepare_study, write_placements};
use crate::plan::{CurveKind, Job, Plan};
use crate::study::Study;
use hilo_core::fs::{limit, read_json, write_json};
use hilo_dataset::background::BackgroundModel;
use hilo_detector::Registry;
use hilo_detector::data::{Frame, LoadOptions, load_split};
use hilo_detector::train::{TrainConfig, learn_background, load_run_at, train};
use hilo_eval::EvalBox;
use hilo_placement_ip::Placement;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::Mutex;

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

/// Predictions of one detector: (sample key, boxes) in key order.
pub type Predictions = Vec<(String, Vec<EvalBox>)>;

/// Stage 1: places every configuration (visibility once for every sensor type) and measures
/// placement's speed against error. Returns what it computed, or `None` when its outputs
/// existed.
pub fn place(study: &Study, plan: &Plan, progress: &mut dyn FnMut(Progress)) -> Result<Option<Placed>> {
    let mut placed = None;
    if !(0..plan.configurations.len()).all(|ci| plan.placement(ci).exists()) {
        progress(Progress::Stage("placement"));
        let prep = prepare_study(study)?;
        let p = place_all(study, prep, &mut |line| progress(Progress::Stage(line)))?;
        write_placements(study, &p, &plan.placements)?;
        placed = Some(p);
    }
    if !plan.tradeoffs.exists() {
        progress(Progress::Stage("placement speed against error (line-of-sight samples, solver time limits)"));
        let prep = placed.as_ref().filter(|_| plan.profile.tradeoff_cell_m.is_none()).map(|p| &p.prepared);
        let t = crate::tradeoff::compute(study, prep, plan.profile.tradeoff_cell_m)?;
        write_json(&plan.tradeoffs, &t)?;
    }
    Ok(placed)
}

/// What the simulate stage records when its dataset is complete.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DataRecord {
    pub configuration: String,
    pub frames: usize,
    pub annotations: usize,
}

/// Stage 2: configuration `ci`'s dataset (resumable scene by scene).
pub fn simulate(
    study: &Study,
    plan: &Plan,
    di: usize,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<DataRecord> {
    let stage = &plan.data[di];
    if let Ok(r) = read_json::<DataRecord>(&stage.done(), limit::TABLE) {
        return Ok(r);
    }
    let (ci, _) = plan.data_stage(di);
    let conf = &plan.configurations[ci];
    let ppath = plan.placement(ci);
    if !ppath.exists() {
        return Err(StudyError::NotReady {
            path: ppath,
            what: format!("no placement for {:?}", conf.name),
            remedy: "run the place stage first".into(),
        });
    }
    let placement = Placement::load(&ppath)?;
    record_dataset(study, &placement, &ppath, &plan.datasets[di], stage, &plan.data_label(di), progress)
}

/// Records `placement`'s dataset into `stage` (resumable scene by scene) and writes the stage's
/// completion record; `name` labels the progress and the record.
pub fn record_dataset(
    study: &Study,
    placement: &Placement,
    ppath: &std::path::Path,
    cfg: &hilo_core::Valid<hilo_dataset::simulate::SimulateConfig>,
    stage: &crate::plan::DataStage,
    name: &str,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<DataRecord> {
    let total = cfg.total_frames();
    let label = format!("dataset {name}");
    let summary = {
        let cell = Mutex::new(&mut *progress);
        crate::rig::simulate(study, placement, ppath, cfg, &stage.dir, "v1.0-trainval", &|done| {
            if let Ok(mut f) = cell.lock() {
                f(Progress::Task { label: &label, done, total, unit: "frames" })
            }
        })?
    };
    progress(Progress::TaskDone);
    progress(Progress::Stage(&format!(
        "dataset {name}: {} key frames, {} annotations ({} scenes resumed)",
        summary.frames, summary.annotations, summary.resumed_scenes
    )));
    let record =
        DataRecord { configuration: name.to_owned(), frames: summary.frames, annotations: summary.annotations };
    write_json(&stage.done(), &record)?;
    Ok(record)
}

/// The frames a detector's input reads: its background model (learned from the training
/// split), the training and the validation frames.
#[derive(Debug)]
pub struct Loaded {
    pub background: Option<BackgroundModel>,
    pub train: Vec<Frame>,
    pub val: Vec<Frame>,
}

/// Loads dataset stage `di`'s frames once per distinct detector input among `jobs`.
pub fn load_inputs(plan: &Plan, di: usize, jobs: &[&Job], registry: &Registry) -> Result<BTreeMap<String, Loaded>> {
    load_inputs_from(&plan.data[di].dir, jobs, registry)
}

/// Loads the frames of the dataset in `dir` once per distinct detector input among `jobs` (and
/// per modality: a LiDAR-only detector's frames keep only the boxes a LiDAR point hit).
pub fn load_inputs_from(dir: &std::path::Path, jobs: &[&Job], registry: &Registry) -> Result<BTreeMap<String, Loaded>> {
    let ds = hilo_dataset::Dataset::open(dir, "v1.0-trainval")?;
    let mut inputs = BTreeMap::new();
    for j in jobs {
        let key = input_key(j, registry);
        if let std::collections::btree_map::Entry::Vacant(slot) = inputs.entry(key) {
            let background = learn_background(&ds, "train", &j.detector)?;
            let lo = LoadOptions::of(&j.detector, registry, background.as_ref());
            let (train, _) = load_split(&ds, "train", &lo)?;
            let (val, _) = load_split(&ds, "val", &lo)?;
            slot.insert(Loaded { background, train, val });
        }
    }
    Ok(inputs)
}

fn input_key(job: &Job, registry: &Registry) -> String {
    let radar = registry.uses_radar(&job.detector);
    format!("{radar} {}", serde_json::to_string(&job.detector.input).unwrap_or_default())
}

/// What detection keeps beside a result file, so a report needs no detector.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ResultMeta {
    pub ms_per_frame: f64,
    pub parameters: usize,
    pub train_s: f64,
    pub samples: usize,
}

/// A train stage's outputs: predictions keyed by sample token (as in the result files).
#[derive(Debug)]
pub struct JobOutput {
    pub predictions: Predictions,
    pub meta: ResultMeta,
    pub curve: Vec<(usize, Predictions)>,
}

/// Stage 3: trains (or resumes) one detector, detects the validation split with it (and with
/// each point of its learning curve: a training of its own for [`CurveKind::Budget`], the kept
/// weights for [`CurveKind::Snapshot`]), writes the result files (the metadata last) and returns
/// the predictions. `tick` hears the stage's progress (its trainings' steps) as a share in [0, 1].
pub fn train_job(job: &Job, loaded: &Loaded, registry: &Registry, tick: &(dyn Fn(f64) + Sync)) -> Result<JobOutput> {
    let read = |path: &std::path::Path| -> Result<Predictions> { Ok(hilo_eval::read_submission(path, 500)?) };
    if job.done() {
        let meta: ResultMeta = read_json(&job.meta(), limit::TABLE)?;
        let curve = job.curve.iter().map(|&s| Ok((s, read(&job.curve_results(s))?))).collect::<Result<Vec<_>>>()?;
        return Ok(JobOutput { predictions: read(&job.results)?, meta, curve });
    }
    let total = job.steps().max(1) as f64;
    let run_training = |run: &std::path::Path, cfg: &hilo_core::Valid<TrainConfig>, before: usize| {
        let steps = cfg.steps();
        train(
            run,
            &job.detector,
            cfg,
            &loaded.train,
            loaded.background.as_ref(),
            registry,
            &hilo_detector::default_device(),
            &mut |r| {
                if r.step % 25 == 0 || r.step == steps {
                    tick((before + r.step) as f64 / total);
                }
                true
            },
        )
        .map_err(|e| StudyError::step(format!("training {} (seed {}) in {}", job.preset, job.seed, run.display()), e))
    };
    let info = run_training(&job.run, &job.train, 0)?;
    let detect = |run: &std::path::Path,
                  samples: Option<usize>,
                  path: &std::path::Path|
     -> Result<(Predictions, f64, usize)> {
        let (det, _, _) = load_run_at(run, registry, &hilo_detector::default_device(), samples)?;
        let (dets, per_frame) = hilo_detector::infer::detect_frames(&det, &loaded.val, 4, &mut |_| {})?;
        let mut pred = hilo_eval::boxes::from_detections(&dets);
        pred.sort_by(|a, b| a.0.cmp(&b.0));
        write_json(path, &hilo_eval::boxes::submission_json(&pred, serde_json::json!({ "detector": det.cfg.name })))?;
        Ok((pred, per_frame, det.parameters()))
    };
    let (predictions, per_frame, parameters) = detect(&job.run, None, &job.results)?;
    let mut curve = Vec::new();
    let mut before = job.train.steps();
    for &s in &job.curve {
        let pred = match job.curve_kind {
            CurveKind::Snapshot => detect(&job.run, Some(s), &job.curve_results(s))?.0,
            CurveKind::Budget => {
                let cfg = job.curve_train(s)?;
                run_training(&job.curve_run(s), &cfg, before)?;
                before += cfg.steps();
                detect(&job.curve_run(s), None, &job.curve_results(s))?.0
            }
        };
        curve.push((s, pred));
    }
    let meta =
        ResultMeta { ms_per_frame: per_frame * 1e3, parameters, train_s: info.seconds, samples: info.samples_seen };
    write_json(&job.meta(), &meta)?;
    Ok(JobOutput { predictions, meta, curve })
}

/// Stage 3 for one job on its own (a workflow engine's job): loads its frames, then
/// [`train_job`].
pub fn train_one(plan: &Plan, job: &Job, registry: &Registry, tick: &(dyn Fn(f64) + Sync)) -> Result<JobOutput> {
    if job.done() {
        let empty = Loaded { background: None, train: Vec::new(), val: Vec::new() };
        return train_job(job, &empty, registry, tick);
    }
    if !plan.data[job.data].done().exists() {
        return Err(StudyError::NotReady {
            path: plan.data[job.data].dir.clone(),
            what: format!("the dataset of {:?} is not complete", plan.data_label(job.data)),
            remedy: "run its simulate stage first".into(),
        });
    }
    let inputs = load_inputs(plan, job.data, &[job], registry)?;
    let loaded =
        inputs.get(&input_key(job, registry)).ok_or(StudyError::Internal("a training's frames were not loaded"))?;
    train_job(job, loaded, registry, tick)
}

/// Stage 3 for every job on dataset stage `di` (a configuration's, on one training-traffic
/// draw), in one process: frames loaded once per input, `workers` detectors at a time, each on
/// a one-thread pool (on two cores one training gains little from a second thread, and two at
/// once use both). Outputs in the order of `jobs`.
pub fn train_all(
    plan: &Plan,
    di: usize,
    registry: &Registry,
    workers: usize,
    tick: &(dyn Fn(&Job, f64) + Sync),
) -> Result<Vec<JobOutput>> {
    let jobs: Vec<&Job> = plan.jobs.iter().filter(|j| j.data == di).collect();
    train_jobs(&plan.data[di].dir, &jobs, registry, workers, tick)
}

/// Trains (or resumes) `jobs` on the dataset in `dir`, `workers` at a time (see [`train_all`]).
pub fn train_jobs(
    dir: &std::path::Path,
    jobs: &[&Job],
    registry: &Registry,
    workers: usize,
    tick: &(dyn Fn(&Job, f64) + Sync),
) -> Result<Vec<JobOutput>> {
    let todo: Vec<&Job> = jobs.iter().copied().filter(|j| !j.done()).collect();
    let inputs = if todo.is_empty() { BTreeMap::new() } else { load_inputs_from(dir, &todo, registry)? };
    let empty = Loaded { background: None, train: Vec::new(), val: Vec::new() };
    let queue = Mutex::new((0..jobs.len()).collect::<Vec<usize>>());
    let outcomes: Mutex<BTreeMap<usize, Result<JobOutput>>> = Mutex::new(BTreeMap::new());
    std::thread::scope(|scope| {
        for _ in 0..workers.clamp(1, jobs.len().max(1)) {
            scope.spawn(|| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build();
                let next = || queue.lock().ok().and_then(|mut q| if q.is_empty() { None } else { Some(q.remove(0)) });
                while let Some(i) = next() {
                    let job = jobs[i];
                    let loaded = inputs.get(&input_key(job, registry)).unwrap_or(&empty);
                    let work = || train_job(job, loaded, registry, &|f| tick(job, f));
                    let r = match &pool {
                        Ok(p) => p.install(work),
                        Err(_) => work(),
                    };
                    if let Ok(mut o) = outcomes.lock() {
                        o.insert(i, r);
                    }
                }
            });
        }
    });
    let outcomes = outcomes.into_inner().map_err(|_| StudyError::Panicked("training"))?;
    outcomes.into_values().collect()
}
