//! The study as a library: what `hilo study` runs, callable (and testable) in-process.
//!
//! The study is three crates, each depending on the one before:
//! - `hilo-plan`: the study file, profiles, the plan of stages with their content hashes, each
//!   stage (place, simulate, train), sweeps, ground truth and pictures (re-exported here under
//!   the same module names: [`study`], [`plan`], [`stages`], ...);
//! - `hilo-validate`: does the placement objective predict trained accuracy? (re-exported as
//!   [`validation`]);
//! - this crate: the verdict and the report, the in-process run and the workflow writer:
//!   - [`assemble`], [`stats`], [`verdict`]: the verdict from the stage outputs (common ground
//!     truth, scene bootstrap with the pooled seed variance net of the scene noise it holds,
//!     Welch–Satterthwaite degrees of freedom, Holm per family, calibration, the paper's claims
//!     with their visible-only and paper-averaged readings;
//!     the radar's claims again per weather condition, and the radar's value per $1,000);
//!   - [`report`]: `report.md`, `report.json`, charts and pictures (with the validation's
//!     section when one was run in the study's folder), and [`modelled`]: which field effects
//!     the study's sensors and rig model, as the report states them;
//!   - [`run`](mod@run): every stage in one process, with a progress callback, and [`compare`]: one
//!     comparison across a sweep's studies;
//!   - [`workflow`]: the study, a sweep or a validation as a Snakemake workflow.
//!
//! Nothing here parses command lines or draws progress bars: functions return values and
//! [`StudyError`]s, and long stages report through a callback.
//!
//! # Where `hilo study`'s arguments go
//!
//! Each argument, from where the command line is read to where it takes effect (paths under
//! `crates/`; past [`Plan::new`] every argument travels inside the [`Plan`], which the stages
//! and the report read and nothing changes):
//! - `STUDY`: `cli/src/study.rs` (`load`) → `cli/src/stages.rs` (the embedded default) or
//!   `plan/src/sweep.rs` (a file, or a sweep's shards) → `plan/src/study.rs` (`Study::parse`:
//!   every section checked once) → `study/src/run.rs` → `plan/src/plan.rs` (configurations,
//!   hashes, jobs) → `plan/src/stages.rs` → `study/src/assemble.rs`.
//! - `--profile`, `--seeds`, `--presets`: `plan/src/profile.rs` (the [`ProfileName`] parsed) →
//!   `cli/src/study.rs` (`profile_of`) → `plan/src/profile.rs` (`profile`, `choose_presets`) →
//!   `study/src/run.rs` → `plan/src/plan.rs` (the jobs) → `plan/src/stages.rs` and
//!   `study/src/report.rs` (what the profile leaves out).
//! - `--out`: `cli/src/study.rs` (claimed) → `core/src/folder.rs` → `study/src/run.rs` →
//!   `plan/src/plan.rs` (every stage's folder) → `study/src/report.rs` (written).
//! - `--workflow`: `cli/src/study.rs` → `study/src/workflow.rs`.

pub mod assemble;
pub mod compare;
pub mod modelled;
pub mod report;
pub mod run;
pub mod stats;
pub mod verdict;
pub mod workflow;

pub use hilo_plan::{
    charts, demo, error, files, gt, place, plan, profile, render, rig, road_users, stages, study, sweep, tradeoff,
};
pub use hilo_validate as validation;

pub use assemble::Report;
pub use hilo_plan::{Configuration, Plan, Profile, ProfileName, Progress, Result, Study, StudyError};
pub use run::{RunOptions, run, run_sweep};
