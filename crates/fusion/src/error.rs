/// What a plugin (or a preset, or the building blocks it uses) can get wrong: its config, a
/// tensor computation, a file. The detector runtime's own errors (the dataset it reads, a
/// checkpoint) are `hilo_detector::DetectorError`, which wraps these.
#[derive(Debug, thiserror::Error)]
pub enum FusionError {
    #[error("tensor computation: {0}")]
    Candle(#[from] candle_core::Error),
    /// A file that could not be read or written, or whose content is malformed.
    #[error(transparent)]
    File(#[from] hilo_core::fs::FileError),
    #[error("{0}")]
    Config(String),
}

pub type Result<T> = std::result::Result<T, FusionError>;
