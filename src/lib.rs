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
//! | `posestream-base` | what every layer shares: range checks, panic containment, a frame's crop box and scores, the ports (`Source`, `Sink`) | [`base`] |
//! | `posestream-math` | skeleton, dictionary, camera, heat maps, solver, estimators (batch and streaming window), metres, accuracy against a truth | [`camera`], [`dictionary`], [`estimator`], [`geometry`], [`heatmaps`], [`metres`], [`accuracy`], [`skeleton`], [`solver`], [`streaming`] |
//! | `posestream-msgs` | the ROS 2 messages, recordings (MCAP), the files the math is loaded from (dictionaries, intrinsics), NPY and TOML files, limits | [`msgs`], [`recording`], [`npy`], [`files`], [`limits`] |
//! | `posestream-transport` | the backends of the ports: in-memory, MCAP, ROS 2, iceoryx2, Foxglove | [`transport`] |
//! | `posestream-detector` | camera images, landmark models, the image detector, pictures | [`detector`], [`images`], [`models`], [`render`] |
//! | `posestream-mocap` | BVH motion capture, synthesis, evaluation | [`mocap`], [`synth`], [`evaluation`] |
//!
//! ```no_run
//! use posestream::{Dictionary, Estimator, LoadDictionary, Params};
//! let dict = Dictionary::load("poseDict-all-K128.mat")?;
//! let estimator = Estimator::new(dict, Params::default())?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub use posestream_detector::{self as detector, images, models, render};
pub use posestream_math::{
    accuracy, camera, estimator, floor, fusion, geometry, heatmaps, learnt_floor, metres, skeleton,
    solver, streaming,
};
pub use posestream_mocap::{self as mocap, evaluation, synth};
pub use posestream_msgs::{self as msgs, files, limits, npy, recording};
pub use posestream_transport as transport;

pub use posestream_base::{self as base, CropBox, PixelMap};
pub use posestream_math::{
    Dictionary, Estimate, EstimateError, Estimates, Estimator, FrameEstimate, FrameMaps,
    HeatMapSequence, InitMethod, Intrinsics, Keypoints, MetricEstimate, Params, Report, Skeleton,
    StreamSettings, WindowEstimator,
};
pub use posestream_mocap::BvhError;
pub use posestream_msgs::error::{ArrayError, CameraError, DictionaryError};
pub use posestream_msgs::formats::{LoadDictionary, LoadIntrinsics};

/// Pose dictionaries: the type and its learning (`posestream-math`), and the files they
/// are loaded from and saved to (`posestream-msgs`' formats).
pub mod dictionary {
    pub use posestream_math::dictionary::*;
    pub use posestream_msgs::formats::{
        LoadDictionary, dictionary_json as json, dictionary_mat as mat,
    };
}

pub mod nodes;

/// The errors of every layer, in one place.
pub mod error {
    pub use posestream_base::domain::*;
    pub use posestream_base::panics::*;
    pub use posestream_math::error::*;
    pub use posestream_mocap::error::*;
    pub use posestream_msgs::error::*;
}
