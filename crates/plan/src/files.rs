//! Content hashes of a study's inputs and outputs. Files are read and written with
//! `hilo_core::fs` (atomic writes, bounded reads, errors that name the file).

/// A content hash of strings (32 hex digits, the dataset's token function).
pub fn hash(parts: &[&str]) -> String {
    hilo_dataset::writer::token(parts)
}
