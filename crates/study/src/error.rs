use std::path::PathBuf;

/// Errors of a study; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("cannot read or write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("{0}")]
    Invalid(String),
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
    Eval(#[from] hilo_eval::EvalError),
    #[error("drawing {what}: {message}")]
    Picture { what: String, message: String },
}

pub type Result<T> = std::result::Result<T, StudyError>;

impl StudyError {
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        StudyError::Io { path: path.to_path_buf(), source }
    }
}
