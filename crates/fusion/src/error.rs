use std::path::PathBuf;

/// Errors of the detector framework; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum FusionError {
    #[error("tensor computation: {0}")]
    Candle(#[from] candle_core::Error),
    /// An error of the dataset a detector reads (the detector crate's data loading).
    #[error(transparent)]
    Dataset(Box<dyn std::error::Error + Send + Sync>),
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{0}")]
    Config(String),
    #[error("checkpoint {path}: {message}")]
    Checkpoint { path: PathBuf, message: String },
}

impl FusionError {
    /// Wraps an error of the dataset layer, keeping it as the source.
    pub fn dataset(e: impl std::error::Error + Send + Sync + 'static) -> Self {
        FusionError::Dataset(Box::new(e))
    }
}

pub type Result<T> = std::result::Result<T, FusionError>;
