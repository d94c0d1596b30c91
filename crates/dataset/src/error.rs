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
    #[error("invalid dataset input: {0}")]
    Invalid(String),
}
