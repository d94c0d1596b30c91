use std::path::PathBuf;

/// Errors of scene loading and geometry building. Each names the file and the field or element
/// at fault, and the offending value.
#[derive(Debug, thiserror::Error)]
pub enum RaycastError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{path}: field `{field}` = {value}: {reason}")]
    Invalid { path: PathBuf, field: String, value: String, reason: String },
    #[error("{path}: mesh: {message}")]
    Mesh { path: PathBuf, message: String },
    #[error("geometry: {0}")]
    Geometry(String),
}
