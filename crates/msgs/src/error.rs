//! Errors of the file formats.

use std::path::PathBuf;

/// Reading, validating or writing an input/output array failed.
#[derive(Debug, thiserror::Error)]
pub enum ArrayError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a valid NPY file, or holds a dtype other than f32/f64.
    #[error("{path}: not a readable .npy array of f32 or f64: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What the NPY reader said.
        reason: String,
    },
    /// The array has the wrong number of dimensions or wrong sizes.
    #[error("{path}: expected shape {expected}, found {found:?}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// The expected shape, in words.
        expected: String,
        /// The shape found.
        found: Vec<u64>,
    },
    /// The array holds NaN or infinity.
    #[error("{path}: non-finite value at flat index {index}")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// Flat index of the first bad value.
        index: usize,
    },
    /// The array has no elements.
    #[error("{path}: the array is empty")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// Values are outside their domain (negative heat, all-zero maps, confidence outside [0, 1]).
    #[error("{path}: {detail}")]
    Domain {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}
