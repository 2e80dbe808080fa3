//! The window's settings: [`StreamSettings`] (`[estimator.window]` in the configuration)
//! and which estimates it emits ([`Emitted`]).

use serde::{Deserialize, Serialize};

use crate::error::EstimateError;
use posestream_base::{OutOfDomain, check_range, check_real};

/// Which estimates the window emits for each new frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Emitted {
    /// Only the newest frame, at once (lag 0).
    Newest,
    /// Only the frame `lag` frames back (refined by the frames after it).
    Lagged,
    /// Both.
    Both,
}

/// Settings of the sliding window (`[estimator.window]` in the configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamSettings {
    /// Frames solved together (N).
    pub size: usize,
    /// Frames back of the refined estimate (L < N).
    pub lag: usize,
    /// Which estimates to emit.
    pub outputs: Emitted,
    /// EM iterations over the window per new frame at most.
    pub em_iterations: usize,
    /// Start each new frame from the previous frame's fit instead of its own
    /// initialisation. Off by default: on held-out motion it tracks a wrong start for the
    /// whole track (docs/streaming.md).
    pub warm_start: bool,
    /// Newest frames refined on their own first (anchored on the frame before them).
    pub local_frames: usize,
    /// EM iterations over those newest frames per new frame at most (0: none).
    pub local_iterations: usize,
    /// EM iterations per new frame over the newest `lag + 1` frames (anchored on the
    /// frame before them), so that every lagged estimate has been solved together with
    /// all `lag` frames after it (0: none; then only the whole window's EM, every
    /// `window_every` frames, reaches beyond the newest `local_frames`, and most lagged
    /// estimates go out without it). Off by default: beside 4 local iterations over the
    /// newest 3 frames it bought 0.7 mm at lag 10 on the training motion (47.1 -> 46.4
    /// mm) for 46 % more time per frame (docs/beyond-the-paper.md). Runs whatever
    /// [`StreamSettings::outputs`] is: it refines the newest frames too. No effect when
    /// `local_frames >= lag + 1` or `local_iterations = 0` (the local EM, or the whole
    /// window's on every frame, already covers them), nor before the track has `lag + 1`
    /// frames.
    pub lag_iterations: usize,
    /// Block-coordinate rounds (coefficients, then rotations) per M-step of that EM
    /// (the batch EM's `max_em_rounds` is 2): one is most of the gain at half the cost.
    pub lag_rounds: usize,
    /// Start the EM over the whole window on every n-th frame only (1: every frame); the
    /// frames between get only the EM over the newest frames and the window EM's
    /// remaining parts. A window EM starts only once the last one has ended: every
    /// `max(window_every, window_parts)` frames.
    pub window_every: usize,
    /// The window's EM runs in this many parts, on consecutive frames, oldest part
    /// first: each part is the EM over its share of the window's frames between frozen
    /// neighbours (the frames on both sides of it stay fixed and pull its ends through
    /// the smoothness terms: block coordinate descent over time). Spreads the cost of
    /// one window EM over several frames (1: the whole window at once; at most one part
    /// per frame of the window).
    pub window_parts: usize,
    /// Iterations of a new frame's initialisation at most (the estimator's
    /// `max_init_iterations` caps it too).
    pub init_iterations: usize,
    /// Coefficients the window's C-steps admit per frame and Newton step at most (the
    /// window is warm-started: few are needed; see `Params::admit_per_frame`).
    pub admit_per_frame: usize,
    /// A jump in the sequence number larger than this ends the track (a restart);
    /// smaller gaps are dropped frames and the track carries on.
    pub max_gap_frames: u64,
    /// A jump in capture time larger than this (seconds) ends the track.
    pub max_gap_seconds: f64,
    /// Factor from the E-step's 2D spread (per axis, model units) to a pose
    /// coordinate's standard deviation: the spread of a heat map's posterior is wider
    /// than the error of the fit to all maps. Calibrated on the training motions
    /// (docs/beyond-the-paper.md).
    pub std_scale: f64,
    /// The same factor for the depth coordinate.
    pub depth_std_scale: f64,
    /// A further factor on both for an estimate with no frames after it (lag 0), whose
    /// error is larger than a refined estimate's for the same E-step spread; an estimate
    /// with `k` of `lag` later frames gets `1 + (newest_std_scale - 1) (1 - k / lag)`.
    /// Calibrated on the training motions (docs/beyond-the-paper.md).
    pub newest_std_scale: f64,
}

impl Default for StreamSettings {
    fn default() -> Self {
        Self {
            size: 30,
            lag: 10,
            outputs: Emitted::Both,
            em_iterations: 1,
            warm_start: false,
            local_frames: 3,
            local_iterations: 4,
            lag_iterations: 0,
            lag_rounds: 1,
            window_every: 30,
            window_parts: 3,
            init_iterations: 5,
            admit_per_frame: 2,
            max_gap_frames: 10,
            max_gap_seconds: 1.0,
            std_scale: 0.18,
            depth_std_scale: 0.48,
            newest_std_scale: 1.07,
        }
    }
}

impl StreamSettings {
    /// Window sizes allowed at most: the window holds `size` frames of maps
    /// (`size x joints x height x width` f32 values per track).
    pub const MAX_SIZE: usize = 300;

    /// Checks every value is in its domain.
    pub fn validate(&self) -> Result<(), EstimateError> {
        self.check().map_err(EstimateError::from)
    }

    /// Checks every value is in its domain; the error names the key
    /// (`[estimator.window]` in the service configuration).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_range("size", self.size, 1, Self::MAX_SIZE)?;
        check_range("lag", self.lag, 0, self.size - 1)?;
        check_range("em_iterations", self.em_iterations, 1, 100)?;
        check_range("local_frames", self.local_frames, 1, self.size)?;
        check_range("local_iterations", self.local_iterations, 0, 100)?;
        check_range("lag_iterations", self.lag_iterations, 0, 100)?;
        check_range("lag_rounds", self.lag_rounds, 1, 100)?;
        check_range("window_every", self.window_every, 1, 10_000)?;
        check_range("window_parts", self.window_parts, 1, Self::MAX_SIZE)?;
        check_range("init_iterations", self.init_iterations, 1, 100_000)?;
        check_range("admit_per_frame", self.admit_per_frame, 1, 10_000)?;
        check_range("max_gap_frames", self.max_gap_frames, 1, 1_000_000)?;
        check_real("max_gap_seconds", self.max_gap_seconds, 0.0, 3600.0, true)?;
        // None so small that a deviation rounds to 0 (a consumer weighting by 1 / std^2
        // would get infinities): the calibrated factors are 0.18 / 0.48 / 1.07.
        check_real("std_scale", self.std_scale, 1e-3, 1e3, false)?;
        check_real("depth_std_scale", self.depth_std_scale, 1e-3, 1e3, false)?;
        check_real("newest_std_scale", self.newest_std_scale, 1e-3, 1e3, false)?;
        Ok(())
    }

    /// The factor [`StreamSettings::newest_std_scale`] gives an estimate with `later`
    /// frames after it: the full factor at 0, 1 from `lag` on.
    pub fn newest_std_factor(&self, later: usize) -> f64 {
        if self.lag == 0 || later >= self.lag {
            return if later == 0 {
                self.newest_std_scale
            } else {
                1.0
            };
        }
        let unseen = 1.0 - later as f64 / self.lag as f64;
        1.0 + (self.newest_std_scale - 1.0) * unseen
    }
}
