//! Files a study writes: atomically (a temporary file beside the target, then a rename), so a
//! reader never sees half a file, an interrupted run leaves the old one intact, and a failed
//! write leaves no temporary file behind.

use crate::error::{Result, StudyError};
use std::path::Path;

/// Writes `bytes` to `path` atomically ([`hilo_core::fs::write_atomic`]), naming the file in errors.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    hilo_core::fs::write_atomic(path, bytes).map_err(|e| StudyError::io(path, e))
}

/// [`write_atomic`] of a value as pretty JSON.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(value)
        .map_err(|e| StudyError::File { path: path.to_path_buf(), message: e.to_string() })?;
    write_atomic(path, &bytes)
}

/// Reads a JSON file into `T`; the error names the file and serde's field and position.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        hilo_core::fs::read_text_bounded(path, hilo_core::fs::limit::TABLE).map_err(|e| StudyError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| StudyError::File { path: path.to_path_buf(), message: e.to_string() })
}

/// A content hash of strings (32 hex digits, the dataset's token function).
pub fn hash(parts: &[&str]) -> String {
    hilo_dataset::writer::token(parts)
}
