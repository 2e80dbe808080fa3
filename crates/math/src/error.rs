//! Typed errors, one enum per failing operation.

use posestream_base::OutOfDomain;

/// The inputs handed to the estimator do not fit together.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EstimateError {
    /// The observation has another joint count than the dictionary.
    #[error("input has {found} joints but the dictionary has {expected}")]
    JointCount {
        /// Joints in the dictionary.
        expected: usize,
        /// Joints in the input.
        found: usize,
    },
    /// No frames were given.
    #[error("input has no frames")]
    NoFrames,
    /// A value is NaN or infinite.
    #[error("non-finite input value in frame {frame}, joint {joint}")]
    NonFinite {
        /// Frame index (in a stream: the frame's sequence number).
        frame: usize,
        /// Joint index.
        joint: usize,
    },
    /// Fewer than two joints are observed in a frame, so no pose can be fitted.
    #[error("frame {frame} has {observed} observed joints; at least 2 are needed")]
    TooFewJoints {
        /// Frame index.
        frame: usize,
        /// Number of joints with positive weight.
        observed: usize,
    },
    /// A heat map is all zero (after clipping negatives), so it locates nothing.
    #[error("heat map of frame {frame}, joint {joint} is all zero")]
    EmptyHeatMap {
        /// Frame index.
        frame: usize,
        /// Joint index.
        joint: usize,
    },
    /// The keypoints do not spread (all joints at one point), so the scale is undefined.
    #[error("keypoints have zero spread; cannot normalise")]
    Degenerate,
    /// A fitted pose has no size (every coefficient zero), so no metric scale can be set.
    #[error("frame {frame}: the fitted pose has zero size; cannot set a metric scale")]
    ZeroSize {
        /// Frame index.
        frame: usize,
    },
    /// A parameter is outside its domain.
    #[error("invalid parameter: {0}")]
    Parameter(String),
}

impl From<OutOfDomain> for EstimateError {
    fn from(e: OutOfDomain) -> Self {
        Self::Parameter(e.to_string())
    }
}
