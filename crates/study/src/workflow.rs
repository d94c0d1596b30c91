//! A study's [`Plan`] as a Snakemake workflow: one rule per stage, its inputs and outputs the
//! stage files (relative to the study folder, where the workflow runs), its command the
//! single-stage `hilo study` command, with thread, memory and run-time hints. Snakemake then
//! schedules it locally, on Slurm or on Kubernetes without change; hilo runs no scheduler of
//! its own, and the stages are the same code and hashes as `hilo study` in one process.

use hilo_plan::error::{Result, StudyError};
use hilo_plan::plan::Plan;
use hilo_plan::profile::Profile;
use hilo_plan::sweep::Sweep;
use hilo_validate::ValidationPlan;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What a stage asks the scheduler for. Slurm and Kubernetes enforce `mem_mb` and `runtime`
/// (a job over them is killed), so the hints come from measurements with headroom.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Resources {
    pub threads: usize,
    pub mem_mb: usize,
    pub runtime_min: usize,
}

/// Peak memory with 50% headroom, rounded up to 100 MB, at least 500 MB.
fn mem(mb: f64) -> usize {
    ((mb * 1.5 / 100.0).ceil() as usize * 100).max(500)
}

/// Minutes with the given factor of headroom, plus 5.
fn minutes(seconds: f64, headroom: f64) -> usize {
    (seconds * headroom / 60.0).ceil() as usize + 5
}

// The stage models: lines through two measured runs of the workflow on a 2-core machine
// (release build, idle; `scripts/stage-resources.py` on the quick profile, 520 frames per
// configuration and 4 trainings, and the default one, 2,800 frames and 18 trainings): each
// stage's peak memory (its log's `peak memory`) and seconds, against what the stage handles;
// docs/measurements.md ("A study's resources on a cluster") has the runs.
// Beyond the default profile they are extrapolations, hence the headroom.

/// Placement: the same at both scales (it depends on the scene, not the profile).
pub const PLACE: Resources = Resources { threads: 2, mem_mb: 1_000, runtime_min: 10 };

/// Simulating one configuration of `frames` frames (training and validation): memory and time
/// linear in the frames (the 64-beam rig's, the slowest).
pub fn simulate(frames: usize) -> Resources {
    let f = frames as f64;
    Resources { threads: 2, mem_mb: mem(106.0 + 0.0505 * f), runtime_min: minutes(0.015 * f, 2.0) }
}

/// Training one detector on `frames` frames (all held in memory) for `samples` samples, one
/// thread: memory linear in the frames, time in the samples (the two-branch `lirafusion-like`'s,
/// two jobs side by side). Runtime allows for presets three times slower than the slowest
/// measured.
pub fn train(frames: usize, samples: usize) -> Resources {
    let (f, n) = (frames as f64, samples as f64);
    Resources { threads: 1, mem_mb: mem(71.0 + 0.291 * f), runtime_min: minutes(0.023 * n + 0.005 * f, 3.0) }
}

/// The report over `results` result sets (every training's detections, learning-curve points
/// included) of `val_frames` validation frames each: linear in the frames scored.
pub fn report(results: usize, val_frames: usize) -> Resources {
    let units = (results * val_frames) as f64;
    Resources { threads: 2, mem_mb: mem(163.0 + 0.0437 * units), runtime_min: minutes(0.001 * units, 3.0) }
}

/// Frames of one configuration's dataset: (training + validation, validation).
pub fn frames(plan: &Plan) -> (usize, usize) {
    frames_of(&plan.profile)
}

fn frames_of(profile: &Profile) -> (usize, usize) {
    let d = &profile.dataset;
    (d.total_frames(), d.val_scenes * d.val_frames_per_scene())
}

/// How the workflow calls hilo.
#[derive(Clone, Debug)]
pub struct Workflow {
    /// The `hilo` executable the rules run.
    pub hilo: PathBuf,
    /// Whether hilo was built with CUDA: training rules then ask for a GPU.
    pub gpu: bool,
}

fn rel(plan: &Plan, p: &Path) -> Result<String> {
    rel_to(&plan.out, p)
}

fn rel_to(base: &Path, p: &Path) -> Result<String> {
    let r = p.strip_prefix(base).map_err(|_| StudyError::Workflow {
        what: p.display().to_string(),
        reason: format!("outside the study folder {}", base.display()),
    })?;
    let s = r.to_string_lossy().into_owned();
    shell_word(&s)?;
    Ok(s)
}

/// A Python string literal of `s` (the Snakefile is Python): JSON's escaping, which Python
/// reads the same, so quotes, backslashes and newlines stay inside the string.
fn py_str(s: &str) -> String {
    serde_json::Value::String(s.to_owned()).to_string()
}

/// A comment line's text: one line whatever `s` holds (a newline in a folder name would end the
/// comment and run the rest as Python).
fn comment(s: &str) -> String {
    format!("{s:?}")
}

/// Stage paths, configuration slugs and job ids go into each rule's shell command and into
/// Snakemake's file patterns unquoted: they are built from slugs (ASCII letters, digits, `_`),
/// preset names and fixed file names, and this keeps them so, refusing anything else.
fn shell_word(s: &str) -> Result<&str> {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c)) {
        Ok(s)
    } else {
        Err(StudyError::Workflow {
            what: format!("{s:?}"),
            reason: "a stage path or name in a workflow must be ASCII letters, digits, '_', '-', '.' and '/'".into(),
        })
    }
}

fn list(items: &[String]) -> String {
    items.iter().map(|s| format!("\n        {},", py_str(s))).collect::<String>()
}

/// A rule name: letters, digits and `_`.
fn rule_name(parts: &[&str]) -> String {
    let s: String = parts.join("_").chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
    s.split('_').filter(|p| !p.is_empty()).collect::<Vec<_>>().join("_")
}

/// One rule of the Snakefile.
struct Rule {
    name: String,
    inputs: Vec<String>,
    outputs: Vec<String>,
    resources: Resources,
    gpu: bool,
    log: String,
    /// The hilo command of the stage (`study train --job …`), without `--out`.
    cmd: String,
    /// The study folder the stage works on, relative to the Snakefile's folder.
    out: String,
}

impl Rule {
    fn write(&self, out: &mut String) {
        let _ = write!(out, "\nrule {}:\n", self.name);
        if !self.inputs.is_empty() {
            let _ = writeln!(out, "    input:{}", list(&self.inputs));
        }
        let _ = writeln!(out, "    output:{}", list(&self.outputs));
        let _ = writeln!(out, "    log: {}", py_str(&format!("logs/{}.log", self.log)));
        // Snakemake measures each job (seconds, peak memory, I/O, CPU time) into this file.
        let _ = writeln!(out, "    benchmark: {}", py_str(&format!("benchmarks/{}.tsv", self.log)));
        let _ = writeln!(out, "    threads: {}", self.resources.threads);
        let gpu = if self.gpu { ", gpu=1" } else { "" };
        let _ = writeln!(
            out,
            "    resources: mem_mb={}, runtime={}{gpu}",
            self.resources.mem_mb, self.resources.runtime_min
        );
        // `:q` has Snakemake quote the executable's path for the shell (spaces, `$(...)`).
        let _ = writeln!(
            out,
            "    shell: \"RAYON_NUM_THREADS={{threads}} {{config[hilo]:q}} {} --out {} > {{log:q}} 2>&1\"",
            self.cmd, self.out
        );
    }
}

const HOW_TO_RUN: &str = "# Run it from this folder: `snakemake --cores 2` (locally), `snakemake --executor slurm --jobs 20`,\n\
     # or `snakemake --executor kubernetes --jobs 20 --default-storage-provider s3 ...`.\n\
     # Each rule is one stage (a hilo command run with --out this folder); outputs are written\n\
     # atomically and named by content hash, so a rerun redoes only unfinished stages (use\n\
     # --rerun-incomplete after a killed run). benchmarks/ receives each job's seconds and peak\n\
     # memory (max_rss, MB), as Snakemake measures them.";

/// The rules of one study's stages. In a sweep (`shard` given), paths, logs and rule names
/// carry the study's name, whose folder sits beside the Snakefile.
fn rules(plan: &Plan, wf: &Workflow, shard: Option<&str>) -> Result<Vec<Rule>> {
    let prefix = |p: String| shard.map_or(p.clone(), |s| format!("{s}/{p}"));
    let path = |p: &Path| rel(plan, p).map(prefix);
    let name = |stage: &str, rest: &[&str]| {
        let mut parts = vec![stage];
        parts.extend(shard);
        parts.extend(rest);
        rule_name(&parts)
    };
    let log = |l: String| shard.map_or(l.clone(), |s| format!("{s}/{l}"));
    let out = shell_word(shard.unwrap_or("."))?.to_owned();
    let (all_frames, val_frames) = frames(plan);
    let results: usize = plan.jobs.iter().map(|j| 1 + j.curve.len()).sum();
    let placements: Vec<String> = plan.placement_outputs().iter().map(|p| path(p)).collect::<Result<_>>()?;
    let data: Vec<String> = plan.data.iter().map(|d| path(&d.done())).collect::<Result<_>>()?;
    let mut report_inputs = placements.clone();
    report_inputs.extend(data.iter().cloned());
    for j in &plan.jobs {
        for p in j.outputs() {
            report_inputs.push(path(&p)?);
        }
    }
    let mut rules = vec![
        Rule {
            name: name("report", &[]),
            inputs: report_inputs,
            outputs: vec![prefix("report.json".into()), prefix("report.md".into())],
            resources: report(results, val_frames),
            gpu: false,
            log: log("report".into()),
            cmd: "study report".into(),
            out: out.clone(),
        },
        Rule {
            name: name("place", &[]),
            inputs: Vec::new(),
            outputs: placements,
            resources: PLACE,
            gpu: false,
            log: log("place".into()),
            cmd: "study place".into(),
            out: out.clone(),
        },
    ];
    for (di, done) in data.iter().enumerate() {
        let (ci, draw) = plan.data_stage(di);
        let slug = shell_word(&plan.configurations[ci].slug())?.to_owned();
        let (tag, flag) = if draw == 0 {
            (slug.clone(), String::new())
        } else {
            (format!("{slug}-draw{draw}"), format!(" --draw {draw}"))
        };
        rules.push(Rule {
            name: name("simulate", &[&tag]),
            inputs: vec![path(&plan.placement(ci))?],
            outputs: vec![done.clone()],
            resources: simulate(all_frames),
            gpu: false,
            log: log(format!("simulate-{tag}")),
            cmd: format!("study simulate --configuration {slug}{flag}"),
            out: out.clone(),
        });
    }
    for j in &plan.jobs {
        let slug = plan.configurations[j.configuration].slug();
        let draw = if j.draw == 0 { String::new() } else { format!("draw{}", j.draw) };
        let mut parts = vec![slug.as_str(), j.preset.as_str()];
        if j.draw > 0 {
            parts.push(&draw);
        }
        let seed = format!("seed{}", j.seed);
        parts.push(&seed);
        rules.push(Rule {
            name: name("train", &parts),
            inputs: vec![data[j.data].clone()],
            outputs: j.outputs().iter().map(|p| path(p)).collect::<Result<_>>()?,
            resources: train(all_frames, j.samples()),
            gpu: wf.gpu,
            log: log(format!("train-{}", j.id.replace('/', "-"))),
            cmd: format!("study train --job {}", shell_word(&j.id)?),
            out: out.clone(),
        });
    }
    Ok(rules)
}

/// The Snakefile of a plan.
pub fn snakefile(plan: &Plan, wf: &Workflow) -> Result<String> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The study in {} as a Snakemake workflow, written by `hilo study --workflow snakemake`.\n{HOW_TO_RUN}\n\
         # Profile {}: {} configurations, {} trainings.",
        comment(&plan.out.display().to_string()),
        comment(plan.profile.name.as_str()),
        plan.configurations.len(),
        plan.jobs.len()
    );
    emit(&mut s, "report.json", &rules(plan, wf, None)?, &format!("the study in {}", plan.out.display()))?;
    Ok(s)
}

/// The config file, the default target and the rules; two rules may not share a name (names
/// are built from slugs, whose `_` can make two different stages read alike).
fn emit(s: &mut String, target: &str, rules: &[Rule], what: &str) -> Result<()> {
    let _ = write!(
        s,
        "\nconfigfile: \"config.yaml\"\n\nrule all:\n    input: {}\n    default_target: True\n",
        py_str(target)
    );
    let mut names = std::collections::BTreeSet::new();
    for r in rules {
        if !names.insert(r.name.as_str()) {
            return Err(StudyError::Workflow {
                what: format!("rule {}", r.name),
                reason: format!("two stages of {what} would share it: rename a study file or configuration"),
            });
        }
        r.write(s);
    }
    Ok(())
}

/// The Snakefile of a sweep in `out`: every study's stages (each in its folder `<name>/`) and
/// the comparison across them, one workflow.
pub fn sweep_snakefile(sweep: &Sweep, plans: &[Plan], wf: &Workflow) -> Result<String> {
    const COMPARE: Resources = Resources { threads: 1, mem_mb: 500, runtime_min: 5 };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The sweep {} ({} studies) as a Snakemake workflow, written by `hilo study --workflow snakemake`.\n{HOW_TO_RUN}\n\
         # The last rule compares the studies: comparison.md and comparison.json.",
        comment(&sweep.source),
        sweep.shards.len()
    );
    let mut all = vec![Rule {
        name: "compare".into(),
        inputs: sweep.shards.iter().map(|sh| format!("{}/report.json", sh.name)).collect(),
        outputs: vec!["comparison.json".into(), "comparison.md".into()],
        resources: COMPARE,
        gpu: false,
        log: "compare".into(),
        cmd: "study compare".into(),
        out: ".".into(),
    }];
    for (sh, plan) in sweep.shards.iter().zip(plans) {
        all.extend(rules(plan, wf, Some(&sh.name))?);
    }
    emit(&mut s, "comparison.json", &all, &format!("the sweep {}", sweep.source))?;
    Ok(s)
}

/// The Snakefile of a validation (its placement set already drawn): one job per placement's
/// dataset and per training of the set, then the last step in one process (`hilo validate
/// --resume`: scores, the calibrated fit, and the recommendation placed, simulated and trained).
pub fn validation_snakefile(plan: &ValidationPlan, profile: &Profile, wf: &Workflow) -> Result<String> {
    let base = &plan.out;
    let (all_frames, val_frames) = frames_of(profile);
    let set = rel_to(base, &plan.set_file())?;
    let data: Vec<String> = plan.data.iter().map(|d| rel_to(base, &d.done())).collect::<Result<_>>()?;
    let samples = plan.jobs.iter().map(|j| j.samples()).max().unwrap_or(0);
    let trainer = train(all_frames, samples);
    let mut last_inputs = data.clone();
    let mut rules = Vec::new();
    for j in &plan.jobs {
        let outputs: Vec<String> = j.outputs().iter().map(|p| rel_to(base, p)).collect::<Result<_>>()?;
        last_inputs.extend(outputs.iter().cloned());
        let id = shell_word(&j.id)?;
        rules.push(Rule {
            name: rule_name(&["train", &j.id]),
            inputs: vec![data[j.data].clone()],
            outputs,
            resources: trainer,
            gpu: wf.gpu,
            log: format!("train-{}", id.replace('/', "-")),
            cmd: format!("validate --train {id}"),
            out: ".".into(),
        });
    }
    for (mi, m) in plan.members.iter().enumerate() {
        let slug = shell_word(&m.slug)?;
        // One job records the placement's dataset on every training-traffic draw.
        let draws = (0..plan.settings.traffic_draws as u64).map(|d| data[plan.data_index(mi, d)].clone());
        rules.push(Rule {
            name: rule_name(&["simulate", slug]),
            inputs: vec![set.clone()],
            outputs: draws.collect(),
            resources: simulate(all_frames),
            gpu: false,
            log: format!("simulate-{slug}"),
            cmd: format!("validate --simulate {slug}"),
            out: ".".into(),
        });
    }
    // Scoring every placement, then the recommendation's dataset and trainings (its seeds at
    // once): the sum of their hints, the largest memory.
    let results = plan.jobs.len() * 2;
    let (rep, sim) = (report(results, val_frames), simulate(all_frames));
    let last = Resources {
        threads: 2,
        mem_mb: rep.mem_mb.max(sim.mem_mb).max(2 * trainer.mem_mb),
        runtime_min: rep.runtime_min + sim.runtime_min + trainer.runtime_min,
    };
    rules.insert(
        0,
        Rule {
            name: "validation".into(),
            inputs: last_inputs,
            outputs: vec!["validation.json".into(), "validation.md".into()],
            resources: last,
            gpu: wf.gpu,
            log: "validation".into(),
            cmd: "validate --resume".into(),
            out: ".".into(),
        },
    );
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# The validation in {} as a Snakemake workflow, written by `hilo validate --workflow snakemake`.\n{HOW_TO_RUN}\n\
         # Profile {}: {} placements, {} trainings; the placement set is drawn (set/), the last rule scores\n\
         # them, fits the calibrated objective and trains its recommendation.",
        comment(&base.display().to_string()),
        comment(profile.name.as_str()),
        plan.members.len(),
        plan.jobs.len()
    );
    emit(&mut s, "validation.json", &rules, &format!("the validation in {}", base.display()))?;
    Ok(s)
}

/// Writes a validation's `Snakefile` and `config.yaml` into its folder.
pub fn write_validation(plan: &ValidationPlan, profile: &Profile, wf: &Workflow) -> Result<Vec<PathBuf>> {
    write_files(&plan.out, &validation_snakefile(plan, profile, wf)?, wf)
}

/// `config.yaml`: the hilo executable the rules call.
pub fn config_yaml(wf: &Workflow) -> Result<String> {
    let exe = wf.hilo.to_str().ok_or_else(|| StudyError::Workflow {
        what: wf.hilo.display().to_string(),
        reason: "the hilo executable's path is not UTF-8".into(),
    })?;
    // A JSON string is a YAML double-quoted scalar: quotes, backslashes and newlines escaped.
    Ok(format!(
        "# The hilo executable every rule runs (the same build for every stage: hashes cover the code).\nhilo: {}\n",
        py_str(exe)
    ))
}

/// Writes `Snakefile` and `config.yaml` into the plan's folder (already claimed for the study).
pub fn write(plan: &Plan, wf: &Workflow) -> Result<Vec<PathBuf>> {
    write_files(&plan.out, &snakefile(plan, wf)?, wf)
}

/// Writes a sweep's `Snakefile` and `config.yaml` into `out` (already claimed for the sweep).
pub fn write_sweep(sweep: &Sweep, plans: &[Plan], out: &Path, wf: &Workflow) -> Result<Vec<PathBuf>> {
    write_files(out, &sweep_snakefile(sweep, plans, wf)?, wf)
}

fn write_files(out: &Path, snakefile: &str, wf: &Workflow) -> Result<Vec<PathBuf>> {
    let snake = out.join("Snakefile");
    let cfg = out.join("config.yaml");
    hilo_core::fs::write_atomic(&snake, snakefile.as_bytes())?;
    hilo_core::fs::write_atomic(&cfg, config_yaml(wf)?.as_bytes())?;
    Ok(vec![snake, cfg])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hints_cover_what_the_measured_runs_needed_with_headroom() {
        // (frames, peak MB) of the simulate and train stages, (results × frames, peak MB) of the
        // report, measured on the quick and default profiles.
        for (f, mb) in [(520, 132.0), (2_800, 247.0)] {
            assert!(simulate(f).mem_mb as f64 >= 1.4 * mb, "simulate {f}");
        }
        for (f, mb) in [(520, 222.0), (2_800, 885.0)] {
            assert!(train(f, 6_000).mem_mb as f64 >= 1.4 * mb, "train {f}");
        }
        assert!(report(6, 120).mem_mb as f64 >= 1.4 * 194.0);
        assert!(report(30, 800).mem_mb as f64 >= 1.4 * 1_212.0);
        assert!(train(2_800, 6_000).runtime_min as f64 * 60.0 >= 2.0 * 137.0, "the slowest measured training");
        // More data asks for more, never less.
        assert!(train(12_800, 12_000).mem_mb > train(2_800, 6_000).mem_mb);
        assert!(report(125, 800).mem_mb > report(30, 800).mem_mb);
        assert_eq!(mem(10.0), 500);
        assert_eq!(mem(1_000.0), 1_500);
    }
}
