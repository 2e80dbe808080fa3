//! # posestream-math
//!
//! The math of posestream, and nothing else: it opens no file and catches no panic, knows
//! no transport and no image (it depends on none of ros2-client, iceoryx2, mcap, tract,
//! image or ureq); of posestream's crates only on the foundation, `posestream-base`.
//!
//!
//! Monocular 3D human pose estimation after Zhou et al., "Sparseness Meets Deepness: 3D
//! Human Pose Estimation from Monocular Video" (CVPR 2016): a sparse [`Dictionary`] of
//! 3D basis poses, a weak-perspective camera, temporal smoothness, and an EM algorithm
//! that treats the 2D joints as latent variables under heat maps ([`HeatMapSequence`]).
//!
//! The math lives in [`solver`] and knows nothing of files or transports; [`Estimator`]
//! is its entry point:
//!
//! ```
//! use posestream_math::skeleton::default_layout;
//! use posestream_math::{Dictionary, Estimator, Params};
//! // A dictionary of 8 bases over the default 17 joints; a real one comes from a file
//! // (`posestream_msgs::formats::LoadDictionary`: JSON, or the authors' MAT-files).
//! let bases = (0..8 * 3 * 17).map(|i| ((i * 37 % 101) as f64 / 101.0 - 0.5)).collect();
//! let dict = Dictionary::new(default_layout(), bases, vec![0.0; 3 * 17])?;
//! let estimator = Estimator::new(dict, Params::default())?;
//! // One frame of 17 joints, pixels (x right, y down).
//! let xy: Vec<f64> = (0..34).map(|i| (i * 7 % 13) as f64).collect();
//! let keypoints = posestream_math::Keypoints { joints: 17, xy, confidence: None };
//! let estimate = estimator.lift_keypoints(&keypoints)?;
//! println!("{} frames, objective {}", estimate.report.frames, estimate.report.objective);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Vocabulary: a *Pose* is 3 x p joint positions; a [`Dictionary`] holds basis poses over
//! a [`Skeleton`]; *heat maps* are a detector's per-joint score maps (a
//! [`HeatMapSequence`] holds F frames of them; one frame on the wire is the `HeatMaps`
//! message of `posestream-msgs`); a
//! [`solver::Window`] is the frames solved together.

pub mod accuracy;
pub mod batch;
pub mod camera;
pub mod dictionary;
pub mod error;
pub mod estimator;
pub mod floor;
pub mod fusion;
pub mod geometry;
pub mod heatmaps;
pub mod learnt_floor;
pub mod metres;
pub mod skeleton;
pub mod solver;
pub mod streaming;

pub use camera::Intrinsics;
pub use dictionary::Dictionary;
pub use error::EstimateError;
pub use estimator::{Estimate, Estimator, Keypoints, MetricEstimate, Report};
pub use heatmaps::HeatMapSequence;
pub use skeleton::Skeleton;
pub use solver::{InitMethod, Params};
pub use streaming::{Estimates, FrameEstimate, FrameMaps, StreamSettings, WindowEstimator};
