//! A camera whose extrinsics are wrong: its evidence misses the pose the other cameras
//! agree on, frame after frame.
//!
//! For each refined frame three cameras or more saw, [`super::FusedWindow`] notes each
//! camera's residual: the median distance between its heat maps' peaks and the fused
//! pose projected into it (the model's, before [`super::deviation`] moves its joints
//! towards the views: a wrong camera would pull them), as a fraction of the person's box in that image (so near and
//! far cameras compare). Noise keeps every camera's small and
//! alike; a camera turned or moved from where its extrinsics say is far off in every
//! frame, while the others fit. [`suspects`] names the cameras whose mean residual is
//! above [`ExtrinsicsCheck::min_residual`] and [`ExtrinsicsCheck::ratio`] times the
//! median of the others' (two cameras cannot tell which of them is wrong: three or more
//! are needed).

use serde::{Deserialize, Serialize};

use posestream_base::{OutOfDomain, check_range, check_real};

/// Settings of the check (`[estimator.fusion.extrinsics]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExtrinsicsCheck {
    /// Frames a camera must have been checked in before it can be named.
    pub min_frames: usize,
    /// A camera is named when its mean residual is this many times (more than 1) the
    /// median of the other cameras' (the upper one of two) ...
    pub ratio: f64,
    /// ... and at least this (a fraction of the person's box).
    pub min_residual: f64,
}

impl Default for ExtrinsicsCheck {
    fn default() -> Self {
        Self {
            min_frames: 30,
            ratio: 2.0,
            min_residual: 0.04,
        }
    }
}

impl ExtrinsicsCheck {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_range("min_frames", self.min_frames, 1, 1_000_000)?;
        check_real("ratio", self.ratio, 1.0, 1e6, true)?;
        check_real("min_residual", self.min_residual, 0.0, 100.0, false)
    }
}

/// One camera's residuals so far.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ViewResidual {
    /// Frames checked.
    pub frames: usize,
    /// Sum of their residuals (fractions of the person's box).
    pub sum: f64,
}

impl ViewResidual {
    /// Adds a frame's residual.
    pub fn add(&mut self, residual: f64) {
        if residual.is_finite() {
            self.frames += 1;
            self.sum += residual;
        }
    }

    /// Adds another's frames (another person's, say).
    pub fn merge(&mut self, other: &Self) {
        self.frames += other.frames;
        self.sum += other.sum;
    }

    /// The mean residual (NaN without frames).
    pub fn mean(&self) -> f64 {
        if self.frames == 0 {
            f64::NAN
        } else {
            self.sum / self.frames as f64
        }
    }
}

/// The cameras (indices into `residuals`) whose extrinsics disagree with the others'.
pub fn suspects(residuals: &[ViewResidual], check: &ExtrinsicsCheck) -> Vec<usize> {
    let checked: Vec<usize> = (0..residuals.len())
        .filter(|&v| residuals[v].frames >= check.min_frames)
        .collect();
    if checked.len() < 3 {
        return Vec::new();
    }
    checked
        .iter()
        .copied()
        .filter(|&v| {
            let mut others: Vec<f64> = checked
                .iter()
                .filter(|&&o| o != v)
                .map(|&o| residuals[o].mean())
                .collect();
            others.sort_by(f64::total_cmp);
            let median = others[others.len() / 2];
            let mine = residuals[v].mean();
            mine >= check.min_residual && mine >= check.ratio * median
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn residual(frames: usize, mean: f64) -> ViewResidual {
        ViewResidual {
            frames,
            sum: mean * frames as f64,
        }
    }

    #[test]
    fn the_camera_far_off_the_others_is_named_and_only_with_three_checked() {
        let check = ExtrinsicsCheck::default();
        let fine = [
            residual(100, 0.02),
            residual(100, 0.025),
            residual(100, 0.022),
        ];
        assert!(suspects(&fine, &check).is_empty());
        let one_off = [
            residual(100, 0.02),
            residual(100, 0.15),
            residual(100, 0.03),
        ];
        assert_eq!(suspects(&one_off, &check), [1]);
        // Two cameras cannot tell which is wrong; too few frames say nothing yet.
        assert!(suspects(&one_off[..2], &check).is_empty());
        let early = [residual(100, 0.02), residual(10, 0.15), residual(100, 0.03)];
        assert!(suspects(&early, &check).is_empty());
    }
}
