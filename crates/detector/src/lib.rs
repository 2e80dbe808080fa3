//! The image detector: camera frames to the estimator's [`posestream_math::HeatMapSequence`] layout.
//!
//! - [`images`]: where camera frames come from (a folder, a video, image messages);
//! - [`models`]: the landmark networks (fetched, rewritten for tract);
//! - [`render`]: pictures of results;
//! - [`crop`]: person boxes and the crop resampled into the model's input;
//! - [`image`]: the detector itself (landmark model, tracking, heat-map messages);
//! - [`mapping`]: the network's channels to the dictionary's joints;
//! - [`tracker`]: who is who from frame to frame (tracks of boxes);
//! - [`appearance`]: what a person looks like (colour histograms of torso and legs).

pub mod appearance;
pub mod crop;
pub mod image;
pub mod images;
pub mod mapping;
pub mod models;
pub mod motion;
pub mod render;
pub mod tracker;

pub use image::{Detection, DetectorError, DetectorStats, ImageDetector, ImageSettings, Runtime};
