//! # posestream
//!
//! Monocular 3D human pose estimation after Zhou et al., "Sparseness Meets Deepness: 3D
//! Human Pose Estimation from Monocular Video" (CVPR 2016), as a streaming service.
//!
//! This crate is the `posestream` program: its nodes ([`nodes`]) and command line
//! (`src/cli`). The layers below it are crates of their own, re-exported here under the
//! module names they are known by:
//!
//! | crate | holds | re-exported as |
//! |---|---|---|
//! | `posestream-math` | skeleton, dictionary, camera, heat maps, solver, estimator, streaming window, metrics | [`camera`], [`dictionary`], [`estimator`], [`geometry`], [`heatmaps`], [`metrics`], [`skeleton`], [`solver`], [`streaming`] |
//! | `posestream-msgs` | the ROS 2 messages, recordings (MCAP), NPY and TOML files, limits | [`msgs`], [`recording`], [`npy`], [`files`], [`limits`] |
//! | `posestream-transport` | the Source and Sink traits: in-memory, MCAP, ROS 2, iceoryx2 | [`transport`] |
//! | `posestream-detector` | camera images, landmark models, the image detector, pictures | [`detector`], [`images`], [`models`], [`render`] |
//! | `posestream-mocap` | BVH motion capture, synthesis, evaluation | [`mocap`], [`synth`], [`evaluation`] |
//!
//! ```no_run
//! use posestream::{Dictionary, Estimator, Params};
//! let dict = Dictionary::load("poseDict-all-K128.mat")?;
//! let estimator = Estimator::new(dict, Params::default())?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub use posestream_detector::{self as detector, images, models, render};
pub use posestream_math::{
    camera, dictionary, estimator, floor, fusion, geometry, heatmaps, learnt_floor, metric,
    metrics, skeleton, solver, streaming,
};
pub use posestream_mocap::{self as mocap, evaluation, synth};
pub use posestream_msgs::{self as msgs, files, limits, npy, recording};
pub use posestream_transport as transport;

pub use posestream_math::{
    CameraError, CropBox, Dictionary, DictionaryError, Estimate, EstimateError, Estimates,
    Estimator, FrameEstimate, FrameMaps, HeatMapSequence, InitMethod, Intrinsics, Keypoints,
    MetricEstimate, Params, PixelMap, Report, Skeleton, StreamSettings, WindowEstimator,
};
pub use posestream_mocap::BvhError;
pub use posestream_msgs::error::ArrayError;

pub mod nodes;

/// The errors of every layer, in one place.
pub mod error {
    pub use posestream_math::error::*;
    pub use posestream_mocap::error::*;
    pub use posestream_msgs::error::*;
}
