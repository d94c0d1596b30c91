use std::path::PathBuf;

/// Dataset errors; each names the file, table, token or field at fault.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("table {table}: record {token:?} field `{field}` refers to {target} {missing:?}, which does not exist")]
    Dangling { table: &'static str, token: String, field: &'static str, target: &'static str, missing: String },
    #[error("table {table}: record {token:?} field `{field}` = {value}: {reason}")]
    Record { table: &'static str, token: String, field: &'static str, value: String, reason: String },
    #[error("{path}: {message}")]
    PointFile { path: PathBuf, message: String },
    /// A setting of the dataset or its traffic (`dataset.scenes`, `traffic.left_share`, the
    /// version folder's name) refused: its field, value and why.
    #[error("{field} = {value}: {reason}")]
    Setting { field: String, value: String, reason: String },
    /// A dataset folder that holds something other than this dataset: what, and why.
    #[error("{} {reason}", path.display())]
    Folder { path: PathBuf, reason: String },
    /// A scene handed to the writer that cannot be written as nuScenes: which, and why.
    #[error("scene {scene:?}: {reason}")]
    Scene { scene: String, reason: String },
    /// A writer input that names something twice or not at all (a sensor channel, a split's
    /// scene, an attribute): what, and why.
    #[error("{what}: {reason}")]
    Writer { what: String, reason: String },
    /// A sensor that could not scan a sweep.
    #[error("sensor {channel}: {source}")]
    Sensor { channel: String, source: Box<hilo_sensor_models::SensorError> },
    /// The road users of a sweep that could not be placed in the ray engine.
    #[error("scene {scene} sweep {sweep}: {source}")]
    Actors { scene: String, sweep: usize, source: Box<hilo_raycast::RaycastError> },
}

impl From<hilo_core::FieldError> for DatasetError {
    fn from(e: hilo_core::FieldError) -> Self {
        DatasetError::Setting { field: e.field, value: e.value, reason: e.reason }
    }
}

impl DatasetError {
    /// A refused setting.
    pub fn setting(field: impl Into<String>, value: impl ToString, reason: impl Into<String>) -> Self {
        DatasetError::Setting { field: field.into(), value: value.to_string(), reason: reason.into() }
    }
}
