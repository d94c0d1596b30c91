use std::path::PathBuf;

/// Errors of evaluation input; each names the file and, for a box, its sample token and field.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{path}: sample {sample:?}, box {index}: field `{field}` = {value}")]
    Field { path: PathBuf, sample: String, index: usize, field: String, value: String },
}
