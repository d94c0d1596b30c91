/// Errors of placement: bad settings and instances, infeasible limits, solver failures.
#[derive(Debug, thiserror::Error)]
pub enum PlacementError {
    /// A placement setting refused: its field (with its section), the value, and why.
    #[error("{field} = {value}: {reason}")]
    Setting { field: String, value: String, reason: String },
    /// What a solver or search cannot take: the instance's part at fault (its targets, an
    /// option, the scene's mounts, the search asked for), and why.
    #[error("{what}: {reason}")]
    Instance { what: String, reason: String },
    /// A placement file that cannot be read, or is not a placement.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    /// A placement made for another scene or catalog than the one it is used with.
    #[error("{}: placement {name:?} was made {reason}", source_file.display())]
    MadeFor { source_file: std::path::PathBuf, name: String, reason: String },
    /// A placement hilo could not write as JSON.
    #[error("writing JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A model that could not be exported for another solver.
    #[error("{}: {reason}", path.display())]
    Export { path: std::path::PathBuf, reason: String },
    #[error("infeasible: {0}")]
    Infeasible(String),
    #[error("solver: {0}")]
    Solver(String),
    #[error(transparent)]
    Sensor(#[from] hilo_sensor_models::SensorError),
    #[error(transparent)]
    Raycast(#[from] hilo_raycast::RaycastError),
}

impl PlacementError {
    /// A refused setting.
    pub fn setting(field: impl Into<String>, value: impl ToString, reason: impl Into<String>) -> Self {
        PlacementError::Setting { field: field.into(), value: value.to_string(), reason: reason.into() }
    }

    /// What a solver cannot take.
    pub fn instance(what: impl Into<String>, reason: impl Into<String>) -> Self {
        PlacementError::Instance { what: what.into(), reason: reason.into() }
    }
}
