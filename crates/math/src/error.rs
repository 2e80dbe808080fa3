//! Typed errors, one enum per failing operation.

use std::path::PathBuf;

/// Loading or validating a [`Dictionary`](crate::Dictionary) failed.
#[derive(Debug, thiserror::Error)]
pub enum DictionaryError {
    /// The file could not be read.
    #[error("cannot read dictionary {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a MATLAB v5/v7 MAT-file the reader understands.
    #[error("{path} is not a readable MATLAB MAT-file: {reason}")]
    Mat {
        /// The file.
        path: PathBuf,
        /// What the MAT reader said.
        reason: String,
    },
    /// The file is not valid posestream dictionary JSON.
    #[error("{path} is not a valid posestream dictionary: {source}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: serde_json::Error,
    },
    /// A variable or field the format requires is absent or of the wrong kind.
    #[error("dictionary {path}: missing or malformed `{what}`")]
    Missing {
        /// The file.
        path: PathBuf,
        /// The variable or field.
        what: String,
    },
    /// Sizes do not agree (e.g. B is not 3k x p, or the skeleton has another joint count).
    #[error("dictionary {path}: {detail}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// What disagrees.
        detail: String,
    },
    /// The bases or mean contain NaN or infinity.
    #[error("dictionary {path}: non-finite value in `{what}`")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// The variable.
        what: String,
    },
    /// The skeleton is not a tree over the joints (bad index, cycle, several roots).
    #[error("dictionary {path}: invalid skeleton: {detail}")]
    Skeleton {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// The file extension names no known dictionary format.
    #[error("dictionary {path}: unknown format (expected .mat or .json)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
}

/// Reading camera intrinsics failed.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The file could not be read.
    #[error("cannot read intrinsics {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not valid intrinsics JSON, or holds impossible values.
    #[error("intrinsics {path}: {detail}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}

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

/// A configured value outside its domain: `{key} must be {domain}, got {value}`.
///
/// Every key of a configuration section has a domain; [`OutOfDomain::within`] prefixes
/// the section, so the error names the key as the file spells it
/// (`estimator.window.size must be in 1..=300, got 1000000000`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key} must be {domain}, got {value}")]
pub struct OutOfDomain {
    /// The key (`size`, or with its section `estimator.window.size`).
    pub key: String,
    /// The domain in words (`in 1..=300`, `finite and > 0`).
    pub domain: String,
    /// The value found.
    pub value: String,
}

impl OutOfDomain {
    /// `key` outside `domain`, holding `value`.
    pub fn new(key: &str, domain: impl Into<String>, value: impl std::fmt::Display) -> Self {
        Self {
            key: key.to_string(),
            domain: domain.into(),
            value: value.to_string(),
        }
    }

    /// The same error with the key inside `section` (`estimator.window`).
    pub fn within(mut self, section: &str) -> Self {
        self.key = format!("{section}.{}", self.key);
        self
    }
}

impl From<OutOfDomain> for EstimateError {
    fn from(e: OutOfDomain) -> Self {
        Self::Parameter(e.to_string())
    }
}

/// Checks that an integer `value` of `key` lies in `lo..=hi`.
pub fn check_range<T: PartialOrd + std::fmt::Display>(
    key: &str,
    value: T,
    lo: T,
    hi: T,
) -> Result<(), OutOfDomain> {
    if value < lo || value > hi {
        return Err(OutOfDomain::new(key, format!("in {lo}..={hi}"), value));
    }
    Ok(())
}

/// Checks that a real `value` of `key` is finite and lies in `[lo, hi]` (or `(lo, hi]`
/// when `open_below`).
pub fn check_real(
    key: &str,
    value: f64,
    lo: f64,
    hi: f64,
    open_below: bool,
) -> Result<(), OutOfDomain> {
    let above = if open_below { value > lo } else { value >= lo };
    if !(value.is_finite() && above && value <= hi) {
        let bracket = if open_below { '(' } else { '[' };
        return Err(OutOfDomain::new(
            key,
            format!("finite, in {bracket}{lo}, {hi}]"),
            value,
        ));
    }
    Ok(())
}

thread_local! {
    static CONTAINING: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Runs `f`, a call into a dependency's parser of outside data that is known to panic on
/// some malformed inputs (`matrw`, the `mcap` reader's arithmetic), and turns a panic
/// into `Err` with its message. While `f` runs, [`panic_is_contained`] is true on this
/// thread, so a panic hook can tell a contained parser failure (a bad file: one error
/// follows) from a bug of ours (logged at error level).
pub fn contain_panics<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    CONTAINING.with(|c| c.set(c.get() + 1));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    CONTAINING.with(|c| c.set(c.get().saturating_sub(1)));
    result.map_err(|payload| panic_text(payload.as_ref()))
}

/// True while [`contain_panics`] runs its function on this thread.
pub fn panic_is_contained() -> bool {
    CONTAINING.with(|c| c.get() > 0)
}

/// The text of a panic's payload (`panic!("…")` gives a `&str` or a `String`).
pub fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into())
}
