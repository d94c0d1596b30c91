use std::path::PathBuf;

/// Errors of the detector framework; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum FusionError {
    #[error("tensor computation: {0}")]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    Dataset(#[from] hilo_dataset::DatasetError),
    #[error("cannot read or write {path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("{0}")]
    Config(String),
    #[error("checkpoint {path}: {message}")]
    Checkpoint { path: PathBuf, message: String },
}

pub type Result<T> = std::result::Result<T, FusionError>;
