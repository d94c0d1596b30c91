//! `hilo study`: the whole study in one process, one of its stages alone (`place`, `simulate`,
//! `train`, `report`; `compare` for a sweep), or the study written as a Snakemake workflow
//! (`--workflow snakemake`). A sweep (a study file listing several scenes or catalogs, or a
//! directory of study files) runs each of its studies in a folder of its own under --out.

use crate::progress::Reporter;
use crate::stages::{EMBEDDED_STUDY, load_study};
use anyhow::{Context, Result};
use hilo_study::sweep::{Loaded, SweepRecord};
use hilo_study::{Plan, RunOptions, Study};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct StudyArgs {
    #[command(subcommand)]
    pub stage: Option<StageCommand>,
    /// Study TOML (the embedded default when omitted). One with `scenes = [...]` or `catalogs
    /// = [...]`, or a directory of study files, is a sweep: a study per scene × catalog (or
    /// file) in its folder under --out, and comparison.md across them.
    pub study: Option<PathBuf>,
    #[arg(long, default_value = "study")]
    pub out: PathBuf,
    /// quick (≤ 5 min), default (≤ 30 min) or paper (the paper's scale; hours here).
    #[arg(long, default_value = "default")]
    pub profile: hilo_study::ProfileName,
    /// Seeds per detector, 1 to 100 (overrides the profile's: 3 for default and paper).
    #[arg(long, value_parser = hilo_study::profile::seeds_arg)]
    pub seeds: Option<usize>,
    /// Training-traffic draws, 1 to 10 (overrides the profile's 1): training scenes recorded
    /// again with other traffic, every detector trained on each; the draw a random effect.
    #[arg(long, value_parser = hilo_study::profile::draws_arg)]
    pub traffic_draws: Option<usize>,
    /// Presets to train (comma-separated), overriding the profile's; ablations (e.g.
    /// `lirafusion-like-no-early`) train on the study's first configuration with a radar.
    #[arg(long, value_delimiter = ',')]
    pub presets: Option<Vec<String>>,
    /// Write the study as a workflow for this engine (`snakemake`) into --out, not running it.
    #[arg(long, value_enum)]
    pub workflow: Option<Engine>,
    /// Delete each study's datasets (data/, ~8 GB at the default profile) once its report is
    /// written; `hilo study report` on it then needs `hilo study simulate` first.
    #[arg(long)]
    pub drop_datasets: bool,
}

/// One stage of a study whose folder exists (made by `hilo study --workflow` or a run).
#[derive(clap::Subcommand, Debug)]
pub enum StageCommand {
    /// Place every configuration and measure placement's speed against error.
    Place(StageArgs),
    /// Record one configuration's dataset.
    Simulate {
        #[command(flatten)]
        args: StageArgs,
        /// The configuration, by name or slug.
        #[arg(long)]
        configuration: String,
        /// Its training-traffic draw (0, the study's own traffic, unless the study trains on
        /// several: `--traffic-draws`).
        #[arg(long, default_value_t = 0)]
        draw: u64,
    },
    /// Train one detector and run it on the validation split.
    Train {
        #[command(flatten)]
        args: StageArgs,
        /// The train stage, `<configuration slug>/<preset>-seed<k>` (as the Snakefile names it).
        #[arg(long)]
        job: String,
    },
    /// Assemble report.md, report.json and the figures from the stage outputs in --out.
    Report(StageArgs),
    /// Compare a sweep's studies (comparison.md, comparison.json) from their reports in --out.
    Compare(StageArgs),
    /// List the stages, their outputs and whether they are done.
    Plan(StageArgs),
}

#[derive(clap::Args, Debug)]
pub struct StageArgs {
    /// The study folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// A path as one word of a shell line the user may paste (quoted where it needs it).
fn shell_quoted(p: &Path) -> String {
    let s = p.to_string_lossy();
    shlex::try_quote(&s).map_or_else(|_| format!("{s:?}"), |q| q.into_owned())
}

fn profile_of(args: &StudyArgs, study: &Study, registry: &hilo_detector::Registry) -> Result<hilo_study::Profile> {
    let chosen = (args.presets.as_deref(), args.seeds, args.traffic_draws);
    Ok(hilo_study::profile(args.profile, study, registry)?.overridden(chosen, registry))
}

/// What `hilo study [PATH]` names: the embedded default study, a study file, or a sweep.
fn load(path: Option<&Path>) -> Result<Loaded> {
    let Some(p) = path else { return Ok(Loaded::Study(load_study(None)?)) };
    // Absolute, so that a stage run from the study folder by a workflow engine finds it.
    let abs = std::fs::canonicalize(p).with_context(|| format!("study file {}", p.display()))?;
    hilo_study::sweep::load(&abs).with_context(|| format!("loading study {}", p.display()))
}

/// The embedded default study, as a folder that recorded it reopens it.
fn default_study() -> hilo_study::Result<Study> {
    Study::parse_embedded(crate::stages::DEFAULT_STUDY_TOML, EMBEDDED_STUDY)
}

/// The study and plan a folder records, checked against the study file as it is now.
fn open_folder(out: &Path, registry: &hilo_detector::Registry) -> Result<(Study, Plan)> {
    Ok(hilo_study::sweep::reopen(out, registry, default_study)?)
}

fn workflow() -> Result<hilo_study::workflow::Workflow> {
    let hilo = std::env::current_exe().context("locating the hilo executable")?;
    Ok(hilo_study::workflow::Workflow { hilo, gpu: cfg!(feature = "cuda") })
}

/// The workflow engines `--workflow` writes for.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Engine {
    Snakemake,
}

/// A study of one scene and catalog: run in-process, or written as a workflow.
fn one_study(
    args: &StudyArgs,
    study: &Study,
    registry: &hilo_detector::Registry,
    reporter: &mut Reporter,
) -> Result<()> {
    let profile = profile_of(args, study, registry)?;
    match args.workflow {
        None => {
            let opts = RunOptions { profile, out: args.out.clone(), drop_datasets: args.drop_datasets };
            hilo_study::run(study, registry, &opts, &mut |p| reporter.study(p))?;
            Ok(())
        }
        Some(Engine::Snakemake) => {
            let plan = Plan::new(study, registry, &profile, &args.out)?;
            plan.claim_folder(study)?;
            wrote(hilo_study::workflow::write(&plan, &workflow()?)?);
            eprintln!(
                "{} stages ({} trainings); run them with: cd {} && snakemake --cores 2",
                plan.stage_count(),
                plan.jobs.len(),
                shell_quoted(&args.out)
            );
            Ok(())
        }
    }
}

/// Says which files were written.
fn wrote(files: Vec<PathBuf>) {
    files.iter().for_each(|p| eprintln!("wrote {}", p.display()));
}

/// Claims a study's or validation's folder for this process (see `hilo_core::folder`): a whole
/// run holds it alone; a stage, as a workflow engine runs several side by side, shares it (the
/// dataset, training run or placements a stage writes are claimed alone below it). A command
/// that only reads the folder claims nothing.
fn claim(out: &Path, whole: bool) -> Result<hilo_core::folder::Claim> {
    use hilo_core::folder::Mode;
    Ok(hilo_core::folder::claim(out, if whole { Mode::Exclusive } else { Mode::Shared })?)
}

pub fn study(args: &StudyArgs) -> Result<()> {
    let registry = crate::train::registry()?;
    let mut reporter = Reporter::new();
    // A stage works in a study folder that exists (one that does not is named by the stage's
    // own error, with nothing created).
    let _claim = match &args.stage {
        None | Some(StageCommand::Plan(_)) => None,
        Some(
            StageCommand::Place(a)
            | StageCommand::Simulate { args: a, .. }
            | StageCommand::Train { args: a, .. }
            | StageCommand::Report(a)
            | StageCommand::Compare(a),
        ) => a.out.exists().then(|| claim(&a.out, false)).transpose()?,
    };
    let Some(stage) = &args.stage else {
        let loaded = load(args.study.as_deref())?;
        let _claim = claim(&args.out, true)?;
        let sweep = match loaded {
            Loaded::Study(study) => return one_study(args, &study, &registry, &mut reporter),
            Loaded::Sweep(sweep) => sweep,
        };
        let profile = |s: &Study| {
            profile_of(args, s, &registry).map_err(|e| hilo_study::StudyError::step(s.source.clone(), format!("{e:#}")))
        };
        return match args.workflow {
            None => {
                let (drop, out) = (args.drop_datasets, &args.out);
                let c = hilo_study::run_sweep(&sweep, &registry, &profile, out, drop, &mut |p| reporter.study(p))?;
                eprintln!("{} studies compared: {}", c.shards.len(), args.out.join("comparison.md").display());
                Ok(())
            }
            Some(Engine::Snakemake) => {
                let plans = hilo_study::run::sweep_plans(&sweep, &registry, &profile, &args.out)?;
                sweep.claim_folder(&args.out, &plans)?;
                wrote(hilo_study::workflow::write_sweep(&sweep, &plans, &args.out, &workflow()?)?);
                let stages: usize = plans.iter().map(Plan::stage_count).sum();
                let jobs: usize = plans.iter().map(|p| p.jobs.len()).sum();
                eprintln!(
                    "{} studies, {} stages ({jobs} trainings) and the comparison; run them with: cd {} && snakemake --cores 2",
                    sweep.shards.len(),
                    stages,
                    shell_quoted(&args.out)
                );
                Ok(())
            }
        };
    };
    match stage {
        StageCommand::Place(a) => {
            let (study, plan) = open_folder(&a.out, &registry)?;
            hilo_study::stages::place(&study, &plan, &mut |p| reporter.study(p))?;
        }
        StageCommand::Simulate { args: a, configuration, draw } => {
            let (study, plan) = open_folder(&a.out, &registry)?;
            let di = plan.data_index(plan.configuration(configuration)?, *draw)?;
            hilo_study::stages::simulate(&study, &plan, di, &mut |p| reporter.study(p))?;
        }
        StageCommand::Train { args: a, job } => {
            let (_, plan) = open_folder(&a.out, &registry)?;
            let job = plan.job(job)?;
            let label = format!("training {}", job.id);
            let cell = std::sync::Mutex::new(&mut reporter);
            let out = hilo_study::stages::train_one(&plan, job, &registry, &|f| {
                if let Ok(mut r) = cell.lock() {
                    r.task(&label, (f * 100.0) as usize, 100, "%");
                }
            })?;
            reporter.finish();
            eprintln!(
                "{}: {} samples in {:.0} s; wrote {}",
                job.id,
                out.meta.samples,
                out.meta.train_s,
                job.results.display()
            );
        }
        StageCommand::Report(a) => {
            let (study, plan) = open_folder(&a.out, &registry)?;
            hilo_study::run::report(&study, &plan, &registry, &mut |p| reporter.study(p))?;
        }
        StageCommand::Compare(a) => {
            let c = hilo_study::compare::compare(&a.out)?;
            wrote(hilo_study::compare::write(&a.out, &c)?);
        }
        StageCommand::Plan(a) if SweepRecord::path(&a.out).exists() => {
            println!("{}", hilo_study::sweep::status(&a.out, &registry, default_study)?);
        }
        StageCommand::Plan(a) => println!("{}", open_folder(&a.out, &registry)?.1.status()),
    }
    if let Some(mb) = hilo_core::machine::peak_resident_mb() {
        // For the stage's log: what a workflow engine should reserve for it.
        eprintln!("peak memory: {mb:.0} MB");
    }
    Ok(())
}

#[derive(clap::Args, Debug)]
pub struct ValidateArgs {
    /// Study TOML (its `[validation]` section sets the placement set); the embedded default
    /// when omitted.
    pub study: Option<PathBuf>,
    #[arg(long, default_value = "validation")]
    pub out: PathBuf,
    /// The scale of the datasets and the scene bootstrap: quick, default or paper.
    #[arg(long, default_value = "default")]
    pub profile: hilo_study::ProfileName,
    /// Placements in the set (overrides `validation.placements`).
    #[arg(long)]
    pub placements: Option<usize>,
    /// Trainings per placement and traffic draw (overrides `validation.seeds`).
    #[arg(long)]
    pub seeds: Option<usize>,
    /// Training-traffic draws per placement, `--seeds` trainings on each (overrides `validation.traffic_draws`).
    #[arg(long, value_parser = hilo_study::profile::draws_arg)]
    pub traffic_draws: Option<usize>,
    /// The budget b in samples (overrides `validation.samples`): trained to 2b, scored at b and 2b.
    #[arg(long)]
    pub samples: Option<usize>,
    /// Only recompute the predictors and refit from --out's validation.json (no simulation, no training).
    #[arg(long)]
    pub refit: bool,
    /// Refit as --refit does, then place the rig the calibrated objective buys under the
    /// study's budget and simulate, train and score it as the set was (resumes from --out).
    #[arg(long, conflicts_with = "refit")]
    pub recommend: bool,
    /// With --recommend: place and predict with this calibration's frozen weights (from `validate --sites`).
    #[arg(long, value_name = "CALIBRATION_TOML", requires = "recommend", conflicts_with = "absorb")]
    pub calibration: Option<PathBuf>,
    /// With --calibration: the budget in USD (the study's budgeted configuration's when omitted).
    #[arg(long, requires = "calibration")]
    pub budget: Option<f64>,
    /// Add --out's trained recommendation to the placement set and fit again; with
    /// --recommend, then place and train the rig the new fit buys (one more turn of the loop).
    #[arg(long, conflicts_with = "refit")]
    pub absorb: bool,
    /// Predict --out's finished set (after --refit or --recommend when given) with the calibrated
    /// objective of another finished validation (its `validation.json`), its weights frozen.
    #[arg(long, value_name = "VALIDATION_JSON")]
    pub transfer: Option<PathBuf>,
    /// Draw the placement set, then write the validation as a workflow (`snakemake`) into --out.
    #[arg(long, value_enum, conflicts_with_all = ["refit", "recommend", "absorb", "transfer"])]
    pub workflow: Option<Engine>,
    /// One stage of the validation in --out (as its Snakefile runs it): record this placement's dataset.
    #[arg(long, conflicts_with_all = ["refit", "recommend", "absorb", "workflow", "train", "resume", "transfer"])]
    pub simulate: Option<String>,
    /// One stage of the validation in --out: this training (`<placement>/<preset>[-draw<d>]-seed<k>`).
    #[arg(long, conflicts_with_all = ["refit", "recommend", "absorb", "workflow", "resume", "transfer"])]
    pub train: Option<String>,
    /// Run what remains of the validation in --out with the study, profile and settings it
    /// records (the Snakefile's last step: scores, fit, recommendation).
    #[arg(long, conflicts_with_all = ["refit", "recommend", "absorb", "workflow", "transfer"])]
    pub resume: bool,
    /// Leave one site out over these finished validations (each a site's validation.json, three or
    /// more), beside baselines that need no fit; writes sites.json, sites.md and calibration.toml.
    #[arg(long, value_name = "VALIDATION_JSON", num_args = 1.., conflicts_with_all = ["study", "refit", "recommend", "absorb", "workflow", "transfer", "resume", "simulate", "train"])]
    pub sites: Vec<PathBuf>,
}

/// A stage of the validation in `out`, run alone: the study, profile and settings it records.
fn validation_stage(args: &ValidateArgs) -> Result<()> {
    let (source, profile, settings) = hilo_study::validation::record(&args.out)?;
    let path = (source != EMBEDDED_STUDY).then(|| PathBuf::from(&source));
    let study = load_study(path.as_deref())?;
    let registry = crate::train::registry()?;
    let mut reporter = Reporter::new();
    let mut progress = |p: hilo_study::stages::Progress<'_>| reporter.study(p);
    if args.resume {
        let report = hilo_study::validation::run(&study, &registry, &profile, &settings, &args.out, &mut progress)?;
        wrote(hilo_study::validation::write(&args.out, &report)?);
        return Ok(());
    }
    let plan = hilo_study::validation::plan(&study, &registry, &profile, &settings, &args.out, &mut progress)?;
    if let Some(slug) = &args.simulate {
        hilo_study::validation::simulate(&study, &profile, &plan, slug, &mut progress)?;
    }
    if let Some(id) = &args.train {
        hilo_study::validation::train_job(&registry, &profile, &plan, id, &mut progress)?;
    }
    Ok(())
}

/// `hilo validate`: does the placement objective predict trained accuracy?
pub fn validate(args: &ValidateArgs) -> Result<()> {
    if !args.sites.is_empty() {
        let _claim = claim(&args.out, true)?;
        let r = hilo_study::validation::sites(&args.sites, &args.out, 0)?;
        let (m, b) = (r.mean_spearman, r.best_baseline_spearman);
        eprintln!(
            "wrote {}/sites.md: mean held-out ρ {m:+.2}, best baseline {} {b:+.2}",
            args.out.display(),
            r.best_baseline
        );
        return Ok(());
    }
    let stage = args.simulate.is_some() || args.train.is_some();
    let in_folder = stage || args.resume || args.transfer.is_some() || args.refit || args.recommend || args.absorb;
    // What works in a finished (or started) validation claims it when it exists; a new
    // validation claims its folder once the study has loaded.
    let _claim = if in_folder { args.out.exists().then(|| claim(&args.out, !stage)).transpose()? } else { None };
    if stage || args.resume {
        return validation_stage(args);
    }
    if let Some(source) = args.transfer.as_deref().filter(|_| !args.refit && !args.recommend && !args.absorb) {
        let mut report = hilo_study::validation::read(&args.out)?;
        report.transfer = Some(hilo_study::validation::transfer(&report, source)?);
        wrote(hilo_study::validation::write(&args.out, &report)?);
        return Ok(());
    }
    if args.refit || args.recommend || args.absorb {
        let study = load_study(args.study.as_deref())?;
        let registry = crate::train::registry()?;
        let mut report = if args.absorb {
            hilo_study::validation::absorb(&study, &registry, &args.out)?
        } else {
            hilo_study::validation::refit(&study, &registry, &args.out)?
        };
        if let Some(source) = &args.transfer {
            report.transfer = Some(hilo_study::validation::transfer(&report, source)?);
        }
        if args.recommend {
            let profile = hilo_study::profile(report.profile.parse()?, &study, &registry)?;
            let mut reporter = Reporter::new();
            let mut on = |p: hilo_study::Progress| reporter.study(p);
            use hilo_study::validation::recommend;
            if let Some(path) = &args.calibration {
                recommend::frozen(&study, &registry, &profile, &mut report, (path, args.budget), &args.out, &mut on)?;
            } else {
                report.recommendation = recommend::recommend(&study, &registry, &profile, &report, &args.out, &mut on)?;
            }
        }
        hilo_study::validation::recommend::pictures(&study, &args.out, &report)?;
        wrote(hilo_study::validation::write(&args.out, &report)?);
        return Ok(());
    }
    let registry = crate::train::registry()?;
    let study = load_study(args.study.as_deref())?;
    let profile = hilo_study::profile(args.profile, &study, &registry)?;
    let mut settings = study.file.validation.clone();
    if let Some(n) = args.placements {
        settings.placements = n;
    }
    settings.seeds = args.seeds.unwrap_or(settings.seeds);
    settings.traffic_draws = args.traffic_draws.unwrap_or(settings.traffic_draws);
    if let Some(n) = args.samples {
        settings.samples = n;
    }
    let _claim = claim(&args.out, true)?;
    let mut reporter = Reporter::new();
    match args.workflow {
        None => {}
        Some(Engine::Snakemake) => {
            let plan = hilo_study::validation::plan(&study, &registry, &profile, &settings, &args.out, &mut |p| {
                reporter.study(p)
            })?;
            wrote(hilo_study::workflow::write_validation(&plan, &profile, &workflow()?)?);
            eprintln!(
                "{} placements, {} trainings; run them with: cd {} && snakemake --cores 2",
                plan.members.len(),
                plan.jobs.len(),
                shell_quoted(&args.out)
            );
            return Ok(());
        }
    }
    let report =
        hilo_study::validation::run(&study, &registry, &profile, &settings, &args.out, &mut |p| reporter.study(p))?;
    wrote(hilo_study::validation::write(&args.out, &report)?);
    Ok(())
}
