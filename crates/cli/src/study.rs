//! `hilo study`: the whole study in one process, one of its stages alone (`place`, `simulate`,
//! `train`, `report`), or the study written as a Snakemake workflow (`--workflow snakemake`).

use crate::progress::Reporter;
use crate::stages::load_study;
use anyhow::{Context, Result, bail};
use hilo_study::plan::FolderRecord;
use hilo_study::{Plan, RunOptions, Study};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct StudyArgs {
    #[command(subcommand)]
    pub stage: Option<StageCommand>,
    /// Study TOML; the embedded default (the paper's configurations on the default
    /// intersection) when omitted.
    pub study: Option<PathBuf>,
    #[arg(long, default_value = "study")]
    pub out: PathBuf,
    /// quick (≤ 5 min), default (≤ 30 min) or paper (the paper's scale; hours here).
    #[arg(long, default_value = "default")]
    pub profile: String,
    /// Seeds per detector (overrides the profile's: 3 for default and paper).
    #[arg(long)]
    pub seeds: Option<usize>,
    /// Presets to train (comma-separated), overriding the profile's; `*-no-early` ablations
    /// train on the study's first configuration with a radar.
    #[arg(long, value_delimiter = ',')]
    pub presets: Option<Vec<String>>,
    /// Write the study as a workflow for this engine (`snakemake`) into --out instead of
    /// running it.
    #[arg(long)]
    pub workflow: Option<String>,
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
    /// List the stages, their outputs and whether they are done.
    Plan(StageArgs),
}

#[derive(clap::Args, Debug)]
pub struct StageArgs {
    /// The study folder.
    #[arg(long)]
    pub out: PathBuf,
}

fn embedded(source: &str) -> bool {
    source.starts_with("<embedded>")
}

fn profile_of(args: &StudyArgs, study: &Study, registry: &hilo_fusion::Registry) -> Result<hilo_study::Profile> {
    let mut profile = hilo_study::profile(&args.profile, study, registry)?;
    if let Some(p) = &args.presets {
        profile.presets = p.iter().filter(|x| !x.ends_with("-no-early")).cloned().collect();
        profile.ablations = p.iter().filter(|x| x.ends_with("-no-early")).cloned().collect();
    }
    if let Some(s) = args.seeds {
        profile.seeds = s;
    }
    Ok(profile)
}

/// The study and plan a folder records, checked against the study file as it is now.
fn open_folder(out: &Path, registry: &hilo_fusion::Registry) -> Result<(Study, Plan)> {
    let record = FolderRecord::read(out)?;
    let study = if embedded(&record.study) { load_study(None)? } else { load_study(Some(Path::new(&record.study)))? };
    let plan = Plan::new(&study, registry, &record.profile, out)?;
    if plan.fingerprint != record.fingerprint {
        bail!(
            "{}: the study changed since this folder was made (fingerprint {} recorded, {} now: study file, scene or catalog edited); run it into a new folder",
            out.join("study.json").display(),
            record.fingerprint,
            plan.fingerprint
        );
    }
    Ok((study, plan))
}

pub fn study(args: &StudyArgs) -> Result<()> {
    let registry = crate::train::registry()?;
    let mut reporter = Reporter::new();
    let Some(stage) = &args.stage else {
        let study = load_study(args.study.as_deref())?;
        let profile = profile_of(args, &study, &registry)?;
        return match args.workflow.as_deref() {
            None => {
                let opts = RunOptions { profile, out: args.out.clone() };
                hilo_study::run(&study, &registry, &opts, &mut |p| reporter.study(p))?;
                Ok(())
            }
            Some("snakemake") => {
                let plan = Plan::new(&study, &registry, &profile, &args.out)?;
                plan.claim_folder(&study.source)?;
                let hilo = std::env::current_exe().context("locating the hilo executable")?;
                let wf = hilo_study::workflow::Workflow { hilo, gpu: cfg!(feature = "cuda") };
                for p in hilo_study::workflow::write(&plan, &wf)? {
                    eprintln!("wrote {}", p.display());
                }
                eprintln!(
                    "{} stages ({} trainings); run them with: cd {} && snakemake --cores 2",
                    plan.jobs.len() + plan.configurations.len() + 2,
                    plan.jobs.len(),
                    args.out.display()
                );
                Ok(())
            }
            Some(other) => bail!("--workflow {other:?}: the supported engine is snakemake"),
        };
    };
    match stage {
        StageCommand::Place(a) => {
            let (study, plan) = open_folder(&a.out, &registry)?;
            hilo_study::stages::place(&study, &plan, &mut |p| reporter.study(p))?;
        }
        StageCommand::Simulate { args: a, configuration } => {
            let (study, plan) = open_folder(&a.out, &registry)?;
            let ci = plan.configuration(configuration)?;
            hilo_study::stages::simulate(&study, &plan, ci, &mut |p| reporter.study(p))?;
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
        StageCommand::Plan(a) => {
            let (_, plan) = open_folder(&a.out, &registry)?;
            let mark = |done: bool| if done { "done" } else { "to do" };
            let placed = plan.placement_outputs().iter().all(|p| p.exists());
            println!("place                     {}  {}", mark(placed), plan.placements.display());
            for (ci, c) in plan.configurations.iter().enumerate() {
                println!(
                    "simulate {:<16} {}  {}",
                    c.slug(),
                    mark(plan.data[ci].done().exists()),
                    plan.data[ci].dir.display()
                );
            }
            for j in &plan.jobs {
                println!("train {:<40} {}  {}", j.id, mark(j.done()), j.results.display());
            }
            println!(
                "report                    {}  {}",
                mark(plan.out.join("report.json").exists()),
                plan.out.join("report.json").display()
            );
        }
    }
    Ok(())
}
