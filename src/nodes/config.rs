//! The service configuration (`config/default.toml`): every parameter of the estimator,
//! the window, the topics and replay. Unknown keys are errors.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, load_toml};
use crate::solver::Params;
use crate::streaming::StreamSettings;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// The estimator node.
    pub estimator: EstimatorConfig,
    /// Topic names.
    pub topics: Topics,
    /// Replaying recordings.
    pub replay: ReplayConfig,
}

impl ServiceConfig {
    /// Reads a configuration file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        load_toml(path.as_ref())
    }
}

/// The estimator node (`[estimator]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorConfig {
    /// Pose dictionary (.json or the authors' .mat); relative to the working directory.
    pub dictionary: PathBuf,
    /// Solver weights and caps (`[estimator.params]`).
    pub params: Params,
    /// The sliding window (`[estimator.window]`).
    pub window: StreamSettings,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            dictionary: PathBuf::from("config/dictionaries/default-k128.json"),
            params: Params::default(),
            window: StreamSettings::default(),
        }
    }
}

/// Topic names (`[topics]`), ROS 2 style.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Topics {
    /// Heat maps from the detector.
    pub heatmaps: String,
    /// Skeletons from the estimator.
    pub skeletons: String,
    /// Ground-truth skeletons in synthetic recordings.
    pub ground_truth: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            heatmaps: "/posestream/heatmaps".into(),
            skeletons: "/posestream/skeletons".into(),
            ground_truth: "/posestream/ground_truth".into(),
        }
    }
}

/// How recordings are replayed (`[replay]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// `fast`: as fast as possible; `recorded`: at the recorded pace.
    pub rate: ReplayRate,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            rate: ReplayRate::Fast,
        }
    }
}

/// Replay pace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ReplayRate {
    /// As fast as possible.
    Fast,
    /// At the recorded pace (log times).
    Recorded,
}
