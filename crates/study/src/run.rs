//! A whole study in one process: the [`Plan`]'s stages in order (placement → a dataset per
//! configuration, same traffic → training and detection per configuration × preset × seed,
//! two detectors at a time → the verdict → report). Every stage is the one a workflow engine
//! runs on its own ([`hilo_plan::stages`]), with the same hashes and files, so the two paths give
//! the same report; here values pass between stages in memory.
//!
//! A stage whose outputs exist is skipped, so an interrupted study resumes and a stage made by
//! other code or inputs (another hash) is recomputed. A complete study ([`Plan::complete`]: its
//! report newer than every training) is not run again at all, so a sweep resumes past the
//! studies it finished even where their datasets were deleted. The folder records the study
//! (`study.json`); a folder that holds another study is refused and nothing in it is
//! overwritten.

use crate::assemble::{Assembled, Report, assemble};
use crate::compare::{self, Comparison};
use hilo_detector::Registry;
use hilo_plan::error::Result;
use hilo_plan::plan::Plan;
use hilo_plan::profile::Profile;
use hilo_plan::stages::{self, JobOutput, Progress};
use hilo_plan::study::Study;
use hilo_plan::sweep::Sweep;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// How a study is run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub profile: Profile,
    pub out: PathBuf,
    /// Delete the study's datasets once its report is written ([`drop_datasets`]).
    pub drop_datasets: bool,
}

/// Runs (or resumes) a study in `opts.out` and writes its report.
pub fn run(
    study: &Study,
    registry: &Registry,
    opts: &RunOptions,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Report> {
    let plan = Plan::new(study, registry, &opts.profile, &opts.out)?;
    plan.claim_folder(study)?;
    let report = run_plan(study, &plan, registry, progress)?;
    if opts.drop_datasets {
        drop_datasets(&plan, progress)?;
    }
    Ok(report)
}

/// Runs (or resumes) every study of a sweep, each in its folder under `out` with its own plan
/// (`profile` gives each study's profile), then writes the comparison across them. With `drop`,
/// each study's datasets are deleted once its report is written ([`drop_datasets`]), so the
/// sweep holds one study's datasets at a time.
pub fn run_sweep(
    sweep: &Sweep,
    registry: &Registry,
    profile: &dyn Fn(&Study) -> Result<Profile>,
    out: &Path,
    drop: bool,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Comparison> {
    let plans = sweep_plans(sweep, registry, profile, out)?;
    sweep.claim_folder(out, &plans)?;
    for (shard, plan) in sweep.shards.iter().zip(&plans) {
        progress(Progress::Stage(&format!("study {} of the sweep: {}", shard.name, plan.out.display())));
        run_plan(&shard.study, plan, registry, progress)?;
        if drop {
            drop_datasets(plan, progress)?;
        }
    }
    let c = compare::compare(out)?;
    for p in compare::write(out, &c)? {
        progress(Progress::Stage(&format!("comparison: {}", p.display())));
    }
    Ok(c)
}

/// Deletes the datasets of a complete study ([`Plan::complete`]; an incomplete one keeps them),
/// returning the bytes freed. Its report, placements and detections stay, and a rerun does not
/// need them; `hilo study report` does, and `hilo study simulate` remakes them byte for byte.
pub fn drop_datasets(plan: &Plan, progress: &mut (dyn FnMut(Progress) + Send)) -> Result<u64> {
    if !plan.complete() {
        return Ok(0);
    }
    let there: Vec<&Path> = plan.data.iter().map(|d| d.dir.as_path()).filter(|d| d.exists()).collect();
    if there.is_empty() {
        return Ok(0);
    }
    let mut freed = 0;
    for dir in there {
        freed += bytes_under(dir);
        std::fs::remove_dir_all(dir).map_err(|e| hilo_core::fs::FileError::io(dir, e))?;
    }
    // The folder itself when nothing else is in it (another code's datasets stay).
    let _ = std::fs::remove_dir(plan.out.join("data"));
    progress(Progress::Stage(&format!(
        "datasets deleted: {:.1} GB freed in {}",
        freed as f64 / 1e9,
        plan.out.join("data").display()
    )));
    Ok(freed)
}

/// The bytes of the files under `dir` (links not followed; what cannot be read counts 0).
fn bytes_under(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .filter_map(|e| e.ok())
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => bytes_under(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// The plan of each study of a sweep, in its folder under `out`.
pub fn sweep_plans(
    sweep: &Sweep,
    registry: &Registry,
    profile: &dyn Fn(&Study) -> Result<Profile>,
    out: &Path,
) -> Result<Vec<Plan>> {
    sweep
        .shards
        .iter()
        .map(|s| Plan::new(&s.study, registry, &profile(&s.study)?, &Sweep::shard_out(out, &s.name)))
        .collect()
}

/// Runs the stages of a plan whose folder is claimed.
fn run_plan(
    study: &Study,
    plan: &Plan,
    registry: &Registry,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Report> {
    let t0 = std::time::Instant::now();
    for s in &plan.skipped {
        progress(Progress::Stage(s));
    }
    if plan.complete() {
        let path = plan.out.join("report.json");
        progress(Progress::Stage(&format!(
            "complete: {} is newer than every training's output (reused, datasets not needed)",
            path.display()
        )));
        return Ok(hilo_core::fs::read_json(&path, hilo_core::fs::limit::TABLE)?);
    }
    drop(stages::place(study, plan, progress)?);
    for di in 0..plan.data.len() {
        stages::simulate(study, plan, di, progress)?;
    }
    let total_steps: usize = plan.jobs.iter().map(|j| j.steps()).sum();
    let label = format!("training {} detectors, {} at a time", plan.jobs.len(), plan.profile.trainings_at_once);
    let steps_done: Mutex<BTreeMap<String, usize>> = Mutex::new(BTreeMap::new());
    let mut outputs: BTreeMap<String, JobOutput> = BTreeMap::new();
    for di in 0..plan.data.len() {
        let shared = Mutex::new(&mut *progress);
        let tick = |job: &hilo_plan::plan::Job, f: f64| {
            let Ok(mut s) = steps_done.lock() else { return };
            s.insert(job.id.clone(), (f * job.steps() as f64).round() as usize);
            let done: usize = s.values().sum();
            drop(s);
            if let Ok(mut p) = shared.lock() {
                p(Progress::Task { label: &label, done, total: total_steps, unit: "steps" });
            }
        };
        let outs = stages::train_all(plan, di, registry, plan.profile.trainings_at_once, &tick)?;
        let jobs: Vec<&hilo_plan::plan::Job> = plan.jobs.iter().filter(|j| j.data == di).collect();
        for (job, out) in jobs.into_iter().zip(outs) {
            progress(Progress::Stage(&format!(
                "{} (seed {}) on {}: {} samples in {:.0} s",
                job.preset,
                job.seed,
                plan.data_label(di),
                out.meta.samples,
                out.meta.train_s
            )));
            if let Ok(mut s) = steps_done.lock() {
                s.insert(job.id.clone(), job.steps());
            }
            outputs.insert(job.id.clone(), out);
        }
    }
    progress(Progress::TaskDone);
    let elapsed = || t0.elapsed().as_secs_f64();
    write_report(study, plan, registry, outputs, &elapsed, progress)
}

/// The report stage on its own: assembles `report.md`, `report.json` and the figures from the
/// stage outputs already in the plan's folder.
pub fn report(
    study: &Study,
    plan: &Plan,
    registry: &Registry,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Report> {
    let t0 = std::time::Instant::now();
    let elapsed = || t0.elapsed().as_secs_f64();
    write_report(study, plan, registry, BTreeMap::new(), &elapsed, progress)
}

fn write_report(
    study: &Study,
    plan: &Plan,
    registry: &Registry,
    outputs: BTreeMap<String, JobOutput>,
    seconds: &dyn Fn() -> f64,
    progress: &mut (dyn FnMut(Progress) + Send),
) -> Result<Report> {
    let Assembled { report, results, pictures } = assemble(study, plan, registry, outputs, seconds, progress)?;
    crate::report::write(&plan.out, &report, &results, &pictures, &plan.placements, &plan.configurations)?;
    progress(Progress::Stage(&format!("report: {} ({:.0} s)", plan.out.join("report.md").display(), report.seconds)));
    Ok(report)
}
