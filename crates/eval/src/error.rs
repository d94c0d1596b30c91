use std::path::PathBuf;

/// Errors of evaluation input; each names the file and, for a box, its sample token and field.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("cannot read {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Json { path: PathBuf, message: String },
    #[error("{path}: sample {sample:?}, box {index}: field `{field}` = {value}")]
    Field { path: PathBuf, sample: String, index: usize, field: String, value: String },
}
