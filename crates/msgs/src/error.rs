//! Errors of the file formats.

use std::path::PathBuf;

/// Reading, validating or writing an input/output array failed.
#[derive(Debug, thiserror::Error)]
pub enum ArrayError {
    /// The file could not be opened, read or written.
    #[error("{path}: {}", crate::files::io_text(source))]
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

/// Loading or validating a dictionary ([`posestream_math::Dictionary`]) failed.
#[derive(Debug, thiserror::Error)]
pub enum DictionaryError {
    /// The file could not be read (or written: [`crate::formats::dictionary_json::save`]).
    #[error("dictionary {path}: {}", crate::files::io_text(source))]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a MATLAB v5/v7 MAT-file the reader understands.
    #[error("{path} is not a readable MATLAB MAT-file: {reason}")]
    Mat {
        /// The file.
        path: PathBuf,
        /// What the MAT reader said.
        reason: String,
    },
    /// The file is not valid posestream dictionary JSON.
    #[error("{path} is not a valid posestream dictionary: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: serde_json::Error,
    },
    /// A variable or field the format requires is absent or of the wrong kind.
    #[error("dictionary {path}: missing or malformed `{what}`")]
    Missing {
        /// The file.
        path: PathBuf,
        /// The variable or field.
        what: String,
    },
    /// Sizes do not agree (e.g. B is not 3k x p, or the skeleton has another joint count).
    #[error("dictionary {path}: {detail}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// What disagrees.
        detail: String,
    },
    /// The bases or mean contain NaN or infinity.
    #[error("dictionary {path}: non-finite value in `{what}`")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// The variable.
        what: String,
    },
    /// The skeleton is not a tree over the joints (bad index, cycle, several roots).
    #[error("dictionary {path}: invalid skeleton: {detail}")]
    Skeleton {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// The file extension names no known dictionary format.
    #[error("dictionary {path}: unknown format (expected .mat or .json)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
}

/// Reading camera intrinsics failed.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The file could not be read.
    #[error("cannot read intrinsics {path}: {}", crate::files::io_text(source))]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not valid intrinsics JSON, or holds impossible values.
    #[error("intrinsics {path}: {detail}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}
