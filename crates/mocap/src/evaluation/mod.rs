//! The evaluation behind `posestream eval` and `docs/results.md`: held-out motion seen by
//! virtual cameras, lifted by the estimator, scored as in the paper's tables.
//!
//! - Table 1 (given 2D): orthographic projections, a static camera and one orbiting at
//!   15 deg/s; the single-frame initialisation against Algorithm 1; P-MPJPE in mm.
//! - Table 3 (heat maps): a pinhole camera 5 m away, heat maps from the synthetic detector
//!   ([`crate::synth::heatmaps`]); single-frame initialisation from the arg-max, the EM,
//!   and the EM without temporal smoothness; P-MPJPE in mm and the 2D error in pixels of
//!   a 256-pixel crop.
//! - Per action (Table 2 style) and PCK (Table 4 style) on the heat-map runs.
//!
//! Each sequence gets its own camera azimuth (`47 deg x` its index), so the set covers
//! many views. Each subject is scaled to a body of known size (mean bone length
//! [`Settings::limb_length`], 0.25 m) before the cameras see it.

mod cases;
mod evaluator;
mod markdown;
mod scores;

pub use cases::{Case, Settings, mean_bone_length};
pub use evaluator::{Evaluator, HEATMAP_METHODS, evaluate, window_methods};
pub use markdown::markdown;
pub use scores::{CALIBRATION_Z, DictionaryResults, Mean, RatioHistogram, Score};
