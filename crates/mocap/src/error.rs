//! Errors of motion capture.

use std::path::PathBuf;

/// Reading a BVH motion-capture file failed.
#[derive(Debug, thiserror::Error)]
pub enum BvhError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The text is not valid BVH.
    #[error("line {line}: {detail}")]
    Syntax {
        /// 1-based line.
        line: usize,
        /// What is wrong.
        detail: String,
    },
    /// The MOTION section does not hold `frames x channels` values (e.g. a truncated file).
    #[error(
        "MOTION declares {declared} frames of {channels} channels ({} values) but holds {values} values{}",
        declared * channels,
        if *values < declared * channels { " (truncated?)" } else { "" }
    )]
    MotionSize {
        /// Frames declared by `Frames:`.
        declared: usize,
        /// Channels per frame from the hierarchy.
        channels: usize,
        /// Values found.
        values: usize,
    },
    /// An error inside a named file.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// The error.
        source: Box<BvhError>,
    },
}

impl BvhError {
    /// Wraps the error with the file it happened in.
    pub fn in_file(self, path: &std::path::Path) -> Self {
        match self {
            e @ (Self::Io { .. } | Self::InFile { .. }) => e,
            e => Self::InFile {
                path: path.to_path_buf(),
                source: Box::new(e),
            },
        }
    }
}
