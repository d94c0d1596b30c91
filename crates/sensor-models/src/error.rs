use std::path::PathBuf;

/// Errors of sensor specs and scan simulation; each names the file, field and value at fault.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{path}: field `{field}` = {value}: {reason}")]
    Invalid { path: PathBuf, field: String, value: String, reason: String },
    #[error("unknown sensor {name:?} in {catalog}; known sensors: {known}")]
    UnknownSensor { name: String, catalog: PathBuf, known: String },
    #[error("sensor {name:?} is not a {expected}")]
    WrongKind { name: String, expected: &'static str },
    #[error("sensor at {position:?} is inside {what}: every direction hits it within {within_m} m; move the mount")]
    InsideGeometry { position: [f32; 3], what: String, within_m: f32 },
    #[error("invalid sensor pose: {0}")]
    Pose(String),
    #[error("{path}: {message}")]
    PointFile { path: PathBuf, message: String },
    #[error(transparent)]
    Raycast(#[from] hilo_raycast::RaycastError),
}
