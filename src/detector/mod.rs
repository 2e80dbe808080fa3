//! The image detector: camera frames to the estimator's [`crate::HeatMaps`] layout.
//!
//! - [`crop`]: person boxes and the crop resampled into the model's input;
//! - [`image`]: the detector itself (landmark model, tracking, heat-map messages);
//! - [`mapping`]: the network's channels to the dictionary's joints.

pub mod crop;
pub mod image;
pub mod mapping;

pub use image::{DetectorError, DetectorStats, ImageDetector, ImageSettings};
