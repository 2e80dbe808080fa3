//! [`CliError`]: everything that can stop a command, one line each.

use std::path::{Path, PathBuf};

use posestream::detector::DetectorError;
use posestream::mocap::{SkeletonMappingError, SplitError};
use posestream::models::FetchError;
use posestream::msgs::toml_file::ConfigError;
use posestream::nodes::SetupError;
use posestream::nodes::replay::ReplayError;
use posestream::nodes::service::ServiceError;
use posestream::recording::RecordingError;
use posestream::transport::TransportError;
use posestream::{ArrayError, BvhError, CameraError, DictionaryError, EstimateError};

/// Why a command failed. `main` prints it as `posestream: error: {this}` and exits 1.
///
/// The layers' errors convert with `?` (their text is this error's text); the variants
/// with fields are what the command line itself finds wrong.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// A dictionary could not be read.
    #[error(transparent)]
    Dictionary(#[from] DictionaryError),
    /// An array file (NPY) could not be read or written, or holds the wrong thing.
    #[error(transparent)]
    Array(#[from] ArrayError),
    /// The estimator refused its input or parameters.
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    /// Camera intrinsics could not be read.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// A BVH file could not be read.
    #[error(transparent)]
    Bvh(#[from] BvhError),
    /// A skeleton mapping could not be read or applied.
    #[error(transparent)]
    SkeletonMapping(#[from] SkeletonMappingError),
    /// A training/held-out split could not be read.
    #[error(transparent)]
    Split(#[from] SplitError),
    /// A recording could not be read or written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The service configuration could not be read.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A node could not be set up from the configuration.
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// A service could not start, or stopped on an error.
    #[error(transparent)]
    Service(#[from] ServiceError),
    /// A replay could not start, or stopped on an error.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// A transport could not be set up, or broke.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The image detector could not be set up.
    #[error(transparent)]
    Detector(#[from] DetectorError),
    /// The detector's models could not be fetched.
    #[error(transparent)]
    Models(#[from] FetchError),
    /// A picture could not be encoded or written.
    #[error("{}: {source}", path.display())]
    Picture {
        /// The picture's file.
        path: PathBuf,
        /// The cause.
        source: image::ImageError,
    },
    /// A file's content that the estimator refuses.
    #[error("{}: {source}", path.display())]
    InFile {
        /// The file.
        path: PathBuf,
        /// What the estimator said.
        source: EstimateError,
    },
    /// A file could not be opened or created (the cause says which).
    #[error(transparent)]
    Output(#[from] posestream::files::OutputError),
    /// A file could not be read or written.
    #[error("{}: {}", path.display(), posestream::files::io_text(source))]
    File {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A file or folder could not be created or written.
    #[error("cannot {action} {}: {}", path.display(), posestream::files::io_text(source))]
    Io {
        /// `create` or `write`.
        action: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// JSON could not be read or written.
    #[error("{}: {source}", path.display())]
    Json {
        /// The file (or the input the JSON describes).
        path: PathBuf,
        /// The cause.
        source: serde_json::Error,
    },
    /// Options that do not fit together or lie outside their domain.
    #[error("{0}")]
    Usage(String),
    /// The inputs hold nothing the command can work on (an empty split, a recording
    /// without the frames asked for).
    #[error("{0}")]
    Nothing(String),
    /// A computation on valid input did not succeed (a dictionary that cannot be
    /// learned, a view that cannot be synthesised).
    #[error("{0}")]
    Failed(String),
}

impl CliError {
    /// `source`, found in the file `path`.
    pub fn in_file(path: &Path, source: EstimateError) -> Self {
        Self::InFile {
            path: path.to_path_buf(),
            source,
        }
    }

    /// `path` could not be created.
    pub fn create(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            action: "create",
            path: path.to_path_buf(),
            source,
        }
    }
}
