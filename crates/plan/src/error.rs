//! The errors of a study. Each variant says what is at fault in its own fields (the file and
//! field of a study file, the flag of a command, the folder, the stage's input), so a message
//! names the file, field, value and reason, and code can tell one kind from another.

use std::path::PathBuf;

/// Errors of a study; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    /// A value of a study file that is refused: the file, the field (with its section), the
    /// value and why.
    #[error("{file}: {field} = {value}: {reason}")]
    Setting { file: String, field: String, value: String, reason: String },
    /// A change a study file makes to a preset (`[detector_patch]`, `[train_schedule]`) that
    /// is refused.
    #[error("[{section}] on preset {preset}: {reason}")]
    PresetChange { section: &'static str, preset: String, reason: String },
    /// A command-line value that is refused (or the profile's, where the flag overrides it).
    #[error("{flag} {value}: {reason}")]
    Argument { flag: &'static str, value: String, reason: String },
    /// A name that is not among the known ones (a configuration, a training, a placement).
    #[error("{what} {name:?} is not in {place} ({known})")]
    Unknown { what: &'static str, name: String, place: String, known: String },
    /// A folder (or a file in it) that holds something other than what is asked of it.
    #[error("{}: {reason}", path.display())]
    Folder { path: PathBuf, reason: String },
    /// A stage's input that is not there yet, and what makes it.
    #[error("{}: {what}; {remedy}", path.display())]
    NotReady { path: PathBuf, what: String, remedy: String },
    /// What a workflow file cannot hold: `what` (a path, a stage name, a rule) and why.
    #[error("workflow: {what}: {reason}")]
    Workflow { what: String, reason: String },
    /// A step that failed, with what it was doing.
    #[error("{context}: {cause}")]
    Step { context: String, cause: Box<dyn std::error::Error + Send + Sync> },
    /// A value hilo could not write as JSON.
    #[error("writing JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// An invariant of hilo's own code that did not hold: a bug, whatever the input.
    #[error("internal error (a bug in hilo): {0}")]
    Internal(&'static str),
    /// A worker thread that panicked (its panic message went to stderr).
    #[error("a {0} worker panicked")]
    Panicked(&'static str),
    #[error("--profile {name:?}: use quick, default or paper")]
    UnknownProfile { name: String },
    #[error(transparent)]
    Raycast(#[from] hilo_raycast::RaycastError),
    #[error(transparent)]
    Sensor(#[from] hilo_sensor_models::SensorError),
    #[error(transparent)]
    Placement(#[from] hilo_placement_ip::PlacementError),
    #[error(transparent)]
    Dataset(#[from] hilo_dataset::DatasetError),
    #[error(transparent)]
    Fusion(#[from] hilo_detector::FusionError),
    #[error(transparent)]
    Detector(#[from] hilo_detector::DetectorError),
    #[error(transparent)]
    Eval(#[from] hilo_eval::EvalError),
    #[error("drawing {what}: {message}")]
    Picture { what: String, message: String },
}

impl StudyError {
    /// A failed step: `context` says what it was doing.
    pub fn step(context: impl Into<String>, cause: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> Self {
        StudyError::Step { context: context.into(), cause: cause.into() }
    }

    /// A refused value of the study file `file`.
    pub fn setting(file: &str, field: impl Into<String>, value: impl ToString, reason: impl Into<String>) -> Self {
        StudyError::Setting {
            file: file.to_owned(),
            field: field.into(),
            value: value.to_string(),
            reason: reason.into(),
        }
    }

    /// A stage's input at `path` that is not there yet (`what`), and what makes it.
    pub fn not_ready(path: impl Into<PathBuf>, what: impl Into<String>, remedy: impl Into<String>) -> Self {
        StudyError::NotReady { path: path.into(), what: what.into(), remedy: remedy.into() }
    }

    /// A folder that holds something else.
    pub fn folder(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        StudyError::Folder { path: path.into(), reason: reason.into() }
    }
}

pub type Result<T> = std::result::Result<T, StudyError>;
