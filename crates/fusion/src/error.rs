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
    /// A configuration value refused: its field (with its section), the value and why.
    #[error(transparent)]
    Field(#[from] hilo_core::FieldError),
    /// A plugin's or preset's configuration that cannot be built from, in words.
    #[error("{0}")]
    Config(String),
}

impl FusionError {
    /// A refused value: `field` (with its section), the value and why.
    pub fn field(field: impl Into<String>, value: impl ToString, reason: impl Into<String>) -> Self {
        FusionError::Field(hilo_core::FieldError::new(field, value, reason))
    }
}

pub type Result<T> = std::result::Result<T, FusionError>;
