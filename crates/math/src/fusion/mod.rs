//! Several cameras, one pose: the multi-view EM.
//!
//! The paper's model seen through several calibrated cameras. Per person and frame `t`
//! there is one pose, `P_tj = m R_t S_j(c_t) + T_t` in the world frame (metres): the
//! coefficients `c_t` of the [`Dictionary`](crate::Dictionary)'s bases, a rotation and a
//! position, and one size `m` per person. Each camera ([`ViewCamera`]: intrinsics and
//! where it stands) that saw the person in a frame brings its heat maps ([`ViewMaps`]).
//!
//! - **E-step, per view** ([`estep`]): the pose projected through the view's camera, full
//!   perspective, into its heat maps; the expected joint under the map and a Gaussian
//!   around the projection (the single-camera E-step, [`crate::solver::estep`], with its
//!   left/right swap mixture), turned into a ray from the camera. A camera whose image
//!   was taken `dt` after the frame's time sees the body moved on by its velocity.
//! - **M-step** ([`mstep`]): the pose against every view's rays (their distances, in the
//!   single-camera EM's normalised units), the temporal smoothness of the coefficients
//!   as the paper's, the L1 sparsity; the size from the frames two views or more saw.
//! - **Window** ([`FusedWindow`]): the single camera's schedule
//!   ([`crate::streaming`]): each new frame starts from the one before, EM iterations
//!   over the newest frames, every few frames over the whole
//!   window, the oldest frame its fixed anchor; the newest estimate goes out at once
//!   and the one [`FusionSettings::lag`] frames back refined.
//! - **Start** ([`start`]): the heat maps' peaks triangulated when two views see the
//!   person, otherwise one camera's monocular start (marked so in the estimate).
//!
//! - **Who is who** ([`matching`]): each camera's tracks grouped into people by geometry
//!   (their pose's reprojection, their rays' distances), without ids agreeing between
//!   cameras.
//!
//! - **The baseline** ([`triangulation`]): no model, each joint's peaks triangulated
//!   and a temporal median: what the fusion is measured against.
//!
//! - **Where the views agree** ([`deviation`]): each joint put out moved off the
//!   dictionary's shape towards its views' peaks, as far as they agree.
//!
//! - **Wrong extrinsics** ([`extrinsics`]): each camera's residuals against the fused
//!   poses; a camera far off while the others fit is named.
//!
//! Nothing here knows about transports.

pub mod camera;
pub mod deviation;
mod estep;
pub mod extrinsics;
mod frame;
pub mod matching;
mod mstep;
mod start;
pub mod triangulation;
mod window;

use serde::{Deserialize, Serialize};

pub use camera::ViewCamera;
pub use deviation::DeviationSettings;
pub use extrinsics::{ExtrinsicsCheck, ViewResidual, suspects};
pub use frame::FusedPose;
pub use matching::{MatchSettings, Matcher, TrackObservation};
pub use triangulation::{TriangulationSettings, Triangulator};
pub use window::FusedWindow;

use posestream_base::PixelMap;
use posestream_base::Scores;
use posestream_base::{OutOfDomain, check_range, check_real};

/// One camera's heat maps of a person in one frame.
#[derive(Debug, Clone, Copy)]
pub struct ViewMaps<'a> {
    /// The camera: its index in the window's cameras.
    pub view: usize,
    /// Capture time of the camera's image minus the frame's time, seconds (unsynchronised
    /// cameras: within half a frame of it; at most 1 s).
    pub dt: f64,
    /// Heat-map cells to image pixels (the crop the maps were computed in).
    pub to_image: PixelMap,
    /// Map height (rows).
    pub height: usize,
    /// Map width (columns).
    pub width: usize,
    /// p maps of `height x width`, row-major, joint-major.
    pub values: Scores<'a>,
}

/// One frame's fused estimate of a person.
#[derive(Debug, Clone, PartialEq)]
pub struct FusedEstimate {
    /// The frame's time, nanoseconds.
    pub stamp_ns: i64,
    /// Frames that came after it before this estimate was made (0: the newest).
    pub lag: usize,
    /// Joint positions, metres, world frame: `[x, y, z]` per joint.
    pub joints: Vec<f64>,
    /// Standard deviation of each joint's position per axis, metres: the views' 2D
    /// spreads at the joint's depth combined (seen by one view, plus the depth its
    /// assumed size leaves open, [`FusionSettings::scale_std`]). Not calibrated yet.
    pub joint_std: Vec<f64>,
    /// The cameras whose evidence the frame used (three joints or more).
    pub views: Vec<usize>,
    /// Fewer than two views: one camera's monocular estimate, placed by the size seen
    /// before or the assumed one.
    pub monocular: bool,
    /// The person's mean bone length as fitted, metres.
    pub mean_limb_length: f64,
}

/// Settings of the multi-view window (`[estimator.fusion]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionSettings {
    /// Frames in the window (the oldest is the anchor of the others).
    pub size: usize,
    /// Frames back of the refined estimate (0: none; less than `size`).
    pub lag: usize,
    /// Newest frames refined on each new frame.
    pub local_frames: usize,
    /// EM iterations over them per new frame.
    pub local_iterations: usize,
    /// The whole window's EM every this many frames.
    pub window_every: usize,
    /// Its iterations.
    pub em_iterations: usize,
    /// M-step rounds (rigid, coefficients) per EM iteration.
    pub rounds: usize,
    /// APG steps per coefficient step.
    pub apg_steps: usize,
    /// M-step rounds on a person's first frame, against the peaks' rays.
    pub start_rounds: usize,
    /// L1 weight on the coefficients (the single-camera EM's units).
    pub alpha: f64,
    /// Temporal smoothness of the coefficients (the single-camera EM's units).
    pub beta: f64,
    /// Assumed mean bone length, metres: the size of a person no two views have seen.
    pub mean_limb_length: f64,
    /// The fitted size stays within this factor of the assumed one.
    pub size_range: f64,
    /// Relative standard deviation of the assumed size (the depth of one view's
    /// estimate).
    pub scale_std: f64,
    /// A peak above this starts a joint's ray on a person's first frame.
    pub peak_threshold: f32,
    /// A frame one view saw has its depth along that view moved towards its neighbours'
    /// by `d / (1 + d)` of the difference (0: not).
    pub depth_smoothing: f64,
    /// A gap longer than this, seconds, starts a new track.
    pub max_gap_seconds: f64,
    /// A camera's view of the frame before that is missing from a frame (a camera at a
    /// lower rate, a dropped frame) stands in for it, once, at its time offset, when the
    /// frames are at most this far apart, seconds (0: never).
    pub bridge_seconds: f64,
    /// Who is who across cameras (`[estimator.fusion.matching]`).
    pub matching: MatchSettings,
    /// The check of the cameras' extrinsics (`[estimator.fusion.extrinsics]`).
    pub extrinsics: ExtrinsicsCheck,
    /// How far the views move the joints off the dictionary's shape
    /// (`[estimator.fusion.deviation]`).
    pub deviation: DeviationSettings,
}

impl Default for FusionSettings {
    fn default() -> Self {
        Self {
            size: 12,
            lag: 10,
            local_frames: 2,
            local_iterations: 2,
            window_every: 5,
            em_iterations: 1,
            rounds: 2,
            apg_steps: 2,
            start_rounds: 30,
            alpha: 0.1,
            beta: 20.0,
            mean_limb_length: 0.25,
            size_range: 1.5,
            scale_std: 0.1,
            peak_threshold: 0.1,
            depth_smoothing: 2.0,
            max_gap_seconds: 0.5,
            bridge_seconds: 0.1,
            matching: MatchSettings::default(),
            extrinsics: ExtrinsicsCheck::default(),
            deviation: DeviationSettings::default(),
        }
    }
}

impl FusionSettings {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_range("size", self.size, 2, 300)?;
        check_range("lag", self.lag, 0, self.size - 1)?;
        check_range("local_frames", self.local_frames, 1, self.size)?;
        check_range("local_iterations", self.local_iterations, 1, 100)?;
        check_range("window_every", self.window_every, 1, 10_000)?;
        check_range("em_iterations", self.em_iterations, 0, 100)?;
        check_range("rounds", self.rounds, 1, 100)?;
        check_range("apg_steps", self.apg_steps, 1, 1000)?;
        check_range("start_rounds", self.start_rounds, 0, 10_000)?;
        check_real("alpha", self.alpha, 0.0, 1e3, false)?;
        check_real("beta", self.beta, 0.0, 1e6, false)?;
        check_real("mean_limb_length", self.mean_limb_length, 0.0, 10.0, true)?;
        check_real("size_range", self.size_range, 1.0, 10.0, false)?;
        check_real("scale_std", self.scale_std, 0.0, 1.0, false)?;
        check_real(
            "peak_threshold",
            f64::from(self.peak_threshold),
            0.0,
            1e30,
            false,
        )?;
        check_real("depth_smoothing", self.depth_smoothing, 0.0, 1e6, false)?;
        check_real("max_gap_seconds", self.max_gap_seconds, 0.0, 3600.0, true)?;
        check_real("bridge_seconds", self.bridge_seconds, 0.0, 0.5, false)?;
        self.matching.check().map_err(|e| e.within("matching"))?;
        self.deviation.check().map_err(|e| e.within("deviation"))?;
        self.extrinsics.check().map_err(|e| e.within("extrinsics"))
    }
}
