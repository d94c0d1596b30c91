//! The study as a library: what `hilo study` runs, callable (and testable) in-process.
//!
//! - [`study`]: the study file (scene, catalog, placement and dataset settings, configurations),
//!   loaded with its scene and catalog and their content hashes;
//! - [`place`]: placement of every configuration over visibility computed once;
//! - [`rig`]: a placement's sensor rig and its dataset;
//! - [`gt`]: ground truth (nuScenes' visible-only, or the common one every rig is scored on);
//! - [`run`]: the whole study with resumable stages and a progress callback;
//! - [`tradeoff`]: placement's speed-against-error sweeps;
//! - [`report`] and [`render`]: `report.md`, `report.json`, charts and pictures.
//!
//! Nothing here parses command lines or draws progress bars: functions return values and
//! [`StudyError`]s, and long stages report through a callback.

pub mod demo;
pub mod error;
pub mod files;
pub mod gt;
pub mod place;
pub mod render;
pub mod report;
pub mod rig;
pub mod run;
pub mod stats;
pub mod study;
pub mod tradeoff;

pub use error::{Result, StudyError};
pub use run::{Profile, Progress, Report, RunOptions, profile, run};
pub use study::{Configuration, Study};
