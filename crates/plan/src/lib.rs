//! A study's file, plan and stages: what `hilo study` runs before any verdict.
//!
//! - [`study`]: the study file (scene, catalog, placement and dataset settings, configurations,
//!   weather conditions, and the sections the verdict, evaluation and validation read), loaded
//!   with its scene and catalog and their content hashes;
//! - [`profile`](mod@profile), [`plan`]: a study's scale, and its stages with their content hashes (a weather
//!   condition's configurations are configurations of the plan: the base configuration's
//!   placement, a dataset in the condition's weather, the same detectors);
//! - [`place`]: placement of every configuration over visibility computed once; [`tradeoff`]:
//!   placement's speed-against-error sweeps;
//! - [`rig`]: a placement's sensor rig and its dataset; [`road_users`]: the study's traffic,
//!   stepped without sensors;
//! - [`stages`]: each stage on its own (place, simulate, train), as a workflow engine runs them,
//!   reporting through a [`Progress`] callback;
//! - [`gt`]: ground truth (nuScenes' visible-only, or the common one every rig is scored on) and
//!   the scene bootstrap's draws;
//! - [`sweep`]: one study file over several scenes, catalogs or weathers, each a study of its own;
//! - [`render`], [`charts`] and [`demo`]: pictures of scenes, placements and scans, the charts
//!   every report draws, and the road users `hilo scan` places.
//!
//! The verdict, the report and the in-process run are the `hilo-study` crate's, on top of this
//! one and of `hilo-validate`. Nothing here parses command lines or draws progress bars:
//! functions return values and [`StudyError`]s, and long stages report through a callback.

pub mod charts;
pub mod demo;
pub mod error;
pub mod files;
pub mod gt;
pub mod place;
pub mod plan;
pub mod profile;
pub mod render;
pub mod rig;
pub mod road_users;
pub mod stages;
pub mod study;
pub mod sweep;
pub mod tradeoff;

pub use error::{Result, StudyError};
pub use plan::Plan;
pub use profile::{Profile, ProfileName, profile};
pub use stages::Progress;
pub use study::{Configuration, Study};
