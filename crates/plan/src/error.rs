/// Errors of a study; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{0}")]
    Invalid(String),
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
    Eval(#[from] hilo_eval::EvalError),
    #[error("drawing {what}: {message}")]
    Picture { what: String, message: String },
}

pub type Result<T> = std::result::Result<T, StudyError>;
