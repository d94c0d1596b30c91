//! The study as a library: what `hilo study` runs, callable (and testable) in-process.
//!
//! - [`study`]: the study file (scene, catalog, placement and dataset settings, configurations,
//!   weather conditions), loaded with its scene and catalog and their content hashes;
//! - [`place`]: placement of every configuration over visibility computed once;
//! - [`rig`]: a placement's sensor rig and its dataset;
//! - [`gt`]: ground truth (nuScenes' visible-only, or the common one every rig is scored on);
//! - [`profile`], [`plan`]: a study's scale, and its stages with their content hashes (a weather
//!   condition's configurations are configurations of the plan: the base configuration's
//!   placement, a dataset in the condition's weather, the same detectors);
//! - [`stages`]: each stage on its own (place, simulate, train, report), as a workflow engine
//!   runs them; [`run`]: all of them in one process, with a progress callback;
//! - [`assemble`], [`stats`], [`verdict`]: the verdict from the stage outputs (common ground
//!   truth, scene bootstrap with pooled seed variance, Holm, calibration, the paper's claims;
//!   the radar's claims again per weather condition, and the radar's value per $1,000);
//! - [`tradeoff`]: placement's speed-against-error sweeps;
//! - [`validation`] and [`rank`]: does the placement objective predict trained accuracy? A set
//!   of placements of the study's scene, predictors computed without training, trained accuracy
//!   per placement, rank agreement with bootstrap intervals;
//! - [`report`] and [`render`]: `report.md`, `report.json`, charts and pictures;
//! - [`sweep`] and [`compare`]: one study over several scenes or catalogs (or a directory of
//!   studies), each a study of its own, and one comparison across them.
//!
//! Nothing here parses command lines or draws progress bars: functions return values and
//! [`StudyError`]s, and long stages report through a callback.

pub mod assemble;
pub mod charts;
pub mod compare;
pub mod demo;
pub mod error;
pub mod files;
pub mod gt;
pub mod place;
pub mod plan;
pub mod profile;
pub mod rank;
pub mod render;
pub mod report;
pub mod rig;
pub mod road_users;
pub mod run;
pub mod stages;
pub mod stats;
pub mod study;
pub mod sweep;
pub mod tradeoff;
pub mod validation;
pub mod verdict;
pub mod workflow;

pub use assemble::Report;
pub use error::{Result, StudyError};
pub use plan::Plan;
pub use profile::{Profile, ProfileName, profile};
pub use run::{RunOptions, run, run_sweep};
pub use stages::Progress;
pub use study::{Configuration, Study};
