//! The detector runtime's errors: what a plugin gets wrong ([`FusionError`], from the fusion
//! crate), what the dataset it reads gets wrong, and a checkpoint that does not fit.

use hilo_fusion::FusionError;
use std::path::PathBuf;

/// Errors of the detector runtime; each names the file, field or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum DetectorError {
    /// A plugin, preset or detector configuration, or a tensor computation.
    #[error(transparent)]
    Fusion(#[from] FusionError),
    /// The dataset the detector reads.
    #[error(transparent)]
    Dataset(#[from] hilo_dataset::DatasetError),
    /// A detector, its input or its run that does not fit the data or itself (a fusion preset
    /// on a dataset without radar, a head output of another kind): what and why.
    #[error("{0}")]
    Config(String),
    /// A checkpoint or run record that cannot be read back into this detector.
    #[error("checkpoint {path}: {message}")]
    Checkpoint { path: PathBuf, message: String },
}

impl From<candle_core::Error> for DetectorError {
    fn from(e: candle_core::Error) -> Self {
        DetectorError::Fusion(FusionError::Candle(e))
    }
}

impl From<hilo_core::fs::FileError> for DetectorError {
    fn from(e: hilo_core::fs::FileError) -> Self {
        DetectorError::Fusion(FusionError::File(e))
    }
}

pub type Result<T> = std::result::Result<T, DetectorError>;
