//! The estimator of Zhou et al. (CVPR 2016), §2–3.
//!
//! Model: frame `t` has coefficients `c_t` (k), a rotation `R_t` in SO(3) and a
//! translation `T_t` (2). The pose is `S_t = sum_i c_it B_i`; its weak-perspective image
//! is `Pi R_t S_t + T_t 1'` with `Pi` the first two rows of the identity. The objective
//! over a [`Window`] of F frames, with per-joint weights `w_tj` (1 in the paper; the
//! keypoints' confidence on given 2D joints; from the E-step on heat maps,
//! [`Params::confidence_spread`]), is
//!
//! ```text
//! J = 1/2 sum_t sum_j w_tj |W_tj - Pi R_t S_tj - T_t|^2
//!   + alpha ||C||_1 + beta/2 sum_t |c_t - c_t+1|^2 + gamma/2 sum_t ||R_t - R_t+1||_F^2
//! ```
//!
//! - [`coefficients`]: the C-step, by default an active-set method with Newton steps
//!   over the window (APG, the paper's method, and coordinate descent stay available);
//! - [`rotations`]: the R-step, block Riemannian Newton on SO(3) with backtracking;
//! - [`bcd`]: Algorithm 1, block coordinate descent (C, R, T) given 2D joints;
//! - [`init`]: per-frame initialisation, convex relaxation (ADMM) or alternation;
//! - [`estep`]: the E-step over heat maps; [`em`]: Algorithm 2;
//! - [`perspective`]: the perspective adjustment, metric poses under a pinhole camera.
//!
//! Units: every step works in normalised image units (see [`normalise`]); weights are
//! those of the authors' release (alpha 0.5, beta 20, gamma 2, sigma 0.5).

pub mod adapt;
pub mod bcd;
pub mod block_tridiagonal;
pub mod coefficients;
pub mod em;
pub mod estep;
pub mod init;
pub mod normalise;
pub mod perspective;
pub mod rotations;

use nalgebra::{Matrix3, Vector2};
use serde::{Deserialize, Serialize};

use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use posestream_base::{OutOfDomain, check_range, check_real};

/// How each frame is initialised before the joint optimisation.
///
/// Named as in the reference (`convex+refine`, `convex+robust+refine`, `altern`; the
/// kebab-case spellings are accepted too) by one parser, serde's: the configuration
/// reads it, and [`std::str::FromStr`] (the command line) goes through it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum InitMethod {
    /// Convex relaxation (spectral-norm ADMM), then rotation recovery and refinement
    /// by alternation. The reference's `convex+refine`.
    #[serde(rename = "convex+refine", alias = "convex-refine")]
    ConvexRefine,
    /// Convex relaxation with an L1 outlier term, then refinement. The reference's
    /// default `convex+robust+refine`.
    #[default]
    #[serde(
        rename = "convex+robust+refine",
        alias = "convex-robust-refine",
        alias = "convex"
    )]
    ConvexRobustRefine,
    /// Alternate a greedy rotation (projected least squares) and a coefficient step (the
    /// configured C-step solver, active-set by default).
    /// The reference's `altern`; about 10x faster than the convex initialisation.
    #[serde(rename = "altern")]
    Altern,
}

impl std::str::FromStr for InitMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        from_name(s).map_err(|_| {
            format!(
                "unknown init method `{s}` (expected convex+robust+refine, convex+refine or altern)"
            )
        })
    }
}

impl std::fmt::Display for InitMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&name_of(self))
    }
}

/// A unit enum variant from its name, by the enum's serde `Deserialize` (so the
/// command line and the configuration accept the same names).
pub(crate) fn from_name<T: serde::de::DeserializeOwned>(s: &str) -> Result<T, String> {
    use serde::de::IntoDeserializer;
    T::deserialize(IntoDeserializer::<serde::de::value::Error>::into_deserializer(s))
        .map_err(|e| e.to_string())
}

/// A unit enum variant's serde name.
pub(crate) fn name_of<T: Serialize>(value: &T) -> String {
    match serde_json::to_value(value) {
        Ok(serde_json::Value::String(name)) => name,
        _ => "?".into(),
    }
}

/// Every weight, cap and tolerance of the estimator. Defaults are the reference's, plus
/// posestream's additions to the model ([`adapt`]); [`Params::reference`] is the paper's
/// model alone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Params {
    /// L1 weight on the coefficients (sparsity).
    pub alpha: f64,
    /// Temporal smoothness of the coefficients.
    pub beta: f64,
    /// Temporal smoothness of the rotations.
    pub gamma: f64,
    /// Standard deviation of the Gaussian around the projection in the E-step
    /// (normalised units: a heat map is 6 units high).
    pub sigma: f64,
    /// Weights of the joints in the EM's M-step from their E-step: a joint weighs 1
    /// while the spread of its posterior (trace of its covariance) is at most this
    /// fraction of the E-step Gaussian's own (`2 sigma^2`), and that bound over its
    /// spread beyond: a map that is flat where the projection is, or whose peak is far
    /// from it (an occluder, a swapped joint), pulls less. 0: every joint weighs 1 (the
    /// paper); otherwise at least 1e-3. docs/beyond-the-paper.md.
    pub confidence_spread: f64,
    /// Prior probability that the heat maps of a left/right pair (the dictionary's
    /// joints named `l...`/`r...` or `left...`/`right...`) are swapped in a frame, as
    /// detectors swap them: the E-step weighs that hypothesis against the maps as they
    /// are by how well each explains the pair at its projection, and takes each joint's
    /// expectation under both (a mixture). 0: the paper's E-step, maps as they are;
    /// otherwise in [0.001, 0.5]. docs/beyond-the-paper.md.
    pub swap_prior: f64,
    /// Outlier threshold of the robust convex initialisation (normalised units).
    pub robust_threshold: f64,
    /// Heat-map joints whose peak is not above this are left out of the initialisation.
    pub visibility_threshold: f64,
    /// EM iterations at most.
    pub max_em_iterations: usize,
    /// Block-coordinate rounds (C, R, T) of Algorithm 1 on given 2D joints at most.
    pub max_rounds: usize,
    /// Block-coordinate rounds per M-step of the EM at most. Fewer than the reference's
    /// 10 make a partial M-step (generalised EM: every round still lowers the objective,
    /// and the next E-step moves the data anyway); 2 gives the same accuracy on the
    /// parity fixtures in about 65 % of the time of 10 (docs/architecture.md, "How it
    /// works").
    pub max_em_rounds: usize,
    /// APG steps (or coordinate-descent sweeps) per C-step at most.
    pub max_apg_steps: usize,
    /// Newton steps of the active-set C-step per round over a window at most. One step
    /// already lowers the objective, and the next round continues from there (inexact
    /// block coordinate descent); more steps solve each C-step more exactly for little
    /// gain in accuracy (docs/architecture.md, "How it works").
    pub max_newton_steps: usize,
    /// Coefficients the active-set C-step admits per frame and Newton step at most. Many
    /// make a cold start fast (a frame's active set grows by this much per step); few
    /// spare a warm start the refactorisations that drop admitted coefficients again.
    pub admit_per_frame: usize,
    /// Newton sweeps over the frames per R-step at most.
    pub max_rotation_sweeps: usize,
    /// Iterations of the per-frame initialisation at most.
    pub max_init_iterations: usize,
    /// Relative tolerance of every stopping rule (objective decrease, change of C).
    pub tolerance: f64,
    /// Per-frame initialisation; `None` chooses by input: the convex relaxation for given
    /// 2D joints, alternation for heat maps (the reference's best mode for each).
    pub init: Option<InitMethod>,
    /// Algorithm of the C-step.
    pub coefficient_solver: coefficients::CoefficientSolver,
    /// Coordinate descent also stops when a sweep lowers the C-step objective by less
    /// than this (relative).
    pub cd_objective_tolerance: f64,
    /// The batch EM on heat maps starts from a sliding window's pass over the sequence
    /// (each frame's fit as the default window refined it, with
    /// [`START_LAG`](crate::estimator::START_LAG) frames after it) instead of from each
    /// frame's own initialisation. The window's EMs over few frames, warm-started and
    /// with its left/right reordering of the maps, reach a start the whole sequence's EM
    /// from the arg-maxes does not find: on the training motions the EM's P-MPJPE fell
    /// 53.0 -> 45.6 mm (docs/beyond-the-paper.md). It costs the window's time on top
    /// of the EM's. false: the paper's start. The batch estimator's only (`lift`,
    /// `eval`): the streaming service has no batch EM.
    pub start_from_window: bool,
    /// The person's shape beyond the dictionary ([`adapt`]).
    pub adaptation: adapt::Adaptation,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            alpha: 0.5,
            beta: 20.0,
            gamma: 2.0,
            sigma: 0.5,
            confidence_spread: 0.25,
            swap_prior: 0.05,
            robust_threshold: 1.0,
            visibility_threshold: 0.0,
            max_em_iterations: 10,
            max_rounds: 10,
            max_em_rounds: 2,
            max_apg_steps: 500,
            max_newton_steps: 1,
            admit_per_frame: 8,
            max_rotation_sweeps: 50,
            max_init_iterations: 1000,
            tolerance: 1e-4,
            init: None,
            coefficient_solver: coefficients::CoefficientSolver::default(),
            cd_objective_tolerance: 1e-6,
            start_from_window: true,
            adaptation: adapt::Adaptation::default(),
        }
    }
}

impl Params {
    /// The paper's model as the authors' release runs it (parity mode, `tests/parity.rs`):
    /// the default weights and caps without what posestream adds to the model (the
    /// person's shape beyond the dictionary, [`adapt`]; the joints' weights from their
    /// E-step, [`Params::confidence_spread`]; the left/right swap hypothesis,
    /// [`Params::swap_prior`]; the batch EM's start from a window's pass,
    /// [`Params::start_from_window`]).
    pub fn reference() -> Self {
        Self {
            adaptation: adapt::Adaptation::off(),
            confidence_spread: 0.0,
            swap_prior: 0.0,
            start_from_window: false,
            ..Self::default()
        }
    }

    /// The paper's "no smoothness" ablation: `beta = gamma = 0`, and the EM from each
    /// frame's own start (a window's pass, [`Params::start_from_window`], would bring
    /// the neighbouring frames back in through its warm starts).
    pub fn without_smoothness(mut self) -> Self {
        self.beta = 0.0;
        self.gamma = 0.0;
        self.start_from_window = false;
        self
    }

    /// Checks every value is in its domain.
    pub fn validate(&self) -> Result<(), EstimateError> {
        self.check().map_err(EstimateError::from)
    }

    /// Checks every value is in its domain; the error names the key
    /// (`[estimator.params]` in the service configuration).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        for (key, v) in [
            ("alpha", self.alpha),
            ("beta", self.beta),
            ("gamma", self.gamma),
            ("robust_threshold", self.robust_threshold),
        ] {
            check_real(key, v, 0.0, 1e6, false)?;
        }
        check_real("sigma", self.sigma, 0.0, 1e3, true)?;
        // 0 (off), or large enough that no weight underflows.
        check_off_or_in("confidence_spread", self.confidence_spread, 1e-3, 1.0)?;
        check_off_or_in("swap_prior", self.swap_prior, 1e-3, 0.5)?;
        check_real(
            "visibility_threshold",
            self.visibility_threshold,
            -1e6,
            1e6,
            false,
        )?;
        check_real("tolerance", self.tolerance, 0.0, 1.0, true)?;
        check_real(
            "cd_objective_tolerance",
            self.cd_objective_tolerance,
            0.0,
            1.0,
            false,
        )?;
        check_range("max_em_iterations", self.max_em_iterations, 1, 10_000)?;
        check_range("max_rounds", self.max_rounds, 1, 10_000)?;
        check_range("max_em_rounds", self.max_em_rounds, 1, 1_000)?;
        check_range("max_apg_steps", self.max_apg_steps, 1, 100_000)?;
        check_range("max_newton_steps", self.max_newton_steps, 0, 1_000)?;
        check_range("admit_per_frame", self.admit_per_frame, 1, 10_000)?;
        check_range("max_rotation_sweeps", self.max_rotation_sweeps, 0, 100_000)?;
        check_range("max_init_iterations", self.max_init_iterations, 0, 100_000)?;
        self.adaptation.check()?;
        Ok(())
    }
}

/// The model parameters of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFit {
    /// Coefficients `c_t` of the bases (k).
    pub coefficients: Vec<f64>,
    /// Camera rotation `R_t` (a proper rotation; its first two rows project).
    pub rotation: Matrix3<f64>,
    /// Image translation `T_t` (normalised units).
    pub translation: Vector2<f64>,
}

impl FrameFit {
    /// A frame at rest: zero coefficients, identity rotation, zero translation.
    pub fn zero(k: usize) -> Self {
        Self {
            coefficients: vec![0.0; k],
            rotation: Matrix3::identity(),
            translation: Vector2::zeros(),
        }
    }

    /// The frame's joints in the image, `[x, y]` per joint (normalised units), into
    /// `xy`; `shape` is a buffer for the pose (3 x p).
    pub fn project_into(&self, dict: &Dictionary, shape: &mut [f64], xy: &mut [f64]) {
        let p = dict.num_joints();
        dict.compose_into(&self.coefficients, shape);
        let r = &self.rotation;
        for (j, out) in xy.chunks_exact_mut(2).enumerate().take(p) {
            let (x, y, z) = (shape[j], shape[p + j], shape[2 * p + j]);
            out[0] = r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z + self.translation.x;
            out[1] = r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z + self.translation.y;
        }
    }
}

/// Frozen frames around the frames being solved: their fits stay fixed, and the
/// smoothness terms pull the first frame towards `before` (`beta/2 |c_0 - c_b|^2 +
/// gamma/2 ||R_0 - R_b||_F^2`) and the last towards `after`. A sliding window has a
/// `before` (the frame that left it); a part of a window solved on its own has both.
#[derive(Debug, Clone, Copy, Default)]
pub struct Anchors<'a> {
    /// The frame just before the first.
    pub before: Option<&'a FrameFit>,
    /// The frame just after the last.
    pub after: Option<&'a FrameFit>,
}

impl<'a> Anchors<'a> {
    /// Only a frame before (or none).
    pub fn before(before: Option<&'a FrameFit>) -> Self {
        Self {
            before,
            after: None,
        }
    }

    /// How many anchors there are (0, 1 or 2).
    pub fn count(&self) -> usize {
        usize::from(self.before.is_some()) + usize::from(self.after.is_some())
    }
}

/// 2D joints of F frames (normalised units) with a weight per joint: the data of
/// Algorithm 1, and the expected joints the E-step hands to it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Observations {
    /// Joints per frame.
    pub joints: usize,
    /// `[x, y]` per joint, frame-major: `xy[2*(t*p + j) + d]`.
    pub xy: Vec<f64>,
    /// Weight per joint, `weights[t*p + j]`, >= 0; 0 means "not observed".
    pub weights: Vec<f64>,
}

impl Observations {
    /// Observations with unit weights.
    pub fn new(joints: usize, xy: Vec<f64>) -> Self {
        let n = xy.len() / 2;
        Self {
            joints,
            xy,
            weights: vec![1.0; n],
        }
    }

    /// Number of frames.
    pub fn frames(&self) -> usize {
        if self.joints == 0 {
            0
        } else {
            self.xy.len() / (2 * self.joints)
        }
    }

    /// The `[x, y]` values of frame `t` (2p values).
    pub fn frame(&self, t: usize) -> &[f64] {
        let n = 2 * self.joints;
        &self.xy[n * t..n * (t + 1)]
    }

    /// The weights of frame `t` (p values).
    pub fn frame_weights(&self, t: usize) -> &[f64] {
        &self.weights[self.joints * t..self.joints * (t + 1)]
    }

    /// True when every weight is one (the reference's unweighted model).
    pub fn unweighted(&self) -> bool {
        self.weights.iter().all(|&w| w == 1.0)
    }
}

/// The frames solved together and their current fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Window {
    /// One fit per frame, oldest first.
    pub fits: Vec<FrameFit>,
}

/// Clears `v` and makes it `n` zeros, with capacity for at least `worst` (the largest
/// `n` possible with the largest sizes seen so far, `worst >= n`), and when it must grow,
/// twice that. Buffers sized by the active set, which varies from round to round, then
/// stop allocating once the sizes they depend on stop setting records by more than 2x.
pub(crate) fn zeroed_with_room(v: &mut Vec<f64>, n: usize, worst: usize) {
    v.clear();
    let worst = worst.max(n);
    if v.capacity() < worst {
        v.reserve_exact(2 * worst);
    }
    v.resize(n, 0.0);
}

/// Sum of squares.
pub(crate) fn sq_norm(v: &[f64]) -> f64 {
    dot(v, v)
}

/// Dot product with four independent partial sums, so that the compiler can vectorise
/// it (a single running sum fixes the order of the additions and forbids that).
#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// `y += a x`.
#[inline]
pub(crate) fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

/// Soft threshold `sign(x) max(|x| - tau, 0)`.
#[inline]
pub(crate) fn soft(x: f64, tau: f64) -> f64 {
    if x > tau {
        x - tau
    } else if x < -tau {
        x + tau
    } else {
        0.0
    }
}

/// A switch with a value: 0 (off), or finite in `[lo, hi]` (the error prints the value in
/// exponent form: a tiny one shows as what it is).
fn check_off_or_in(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), OutOfDomain> {
    if v != 0.0 && !(v.is_finite() && (lo..=hi).contains(&v)) {
        return Err(OutOfDomain::new(
            key,
            format!("0 (off), or finite in [{lo}, {hi}]"),
            format!("{v:e}"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::coefficients::CoefficientSolver;
    use super::*;

    #[test]
    fn the_command_line_and_the_configuration_take_the_same_names() {
        for m in [
            InitMethod::ConvexRefine,
            InitMethod::ConvexRobustRefine,
            InitMethod::Altern,
        ] {
            let name = m.to_string();
            assert_eq!(name.parse::<InitMethod>(), Ok(m));
            assert_eq!(serde_json::to_value(m).ok(), Some(name.clone().into()));
            let json: InitMethod = serde_json::from_value(name.into()).expect("serde");
            assert_eq!(json, m);
        }
        assert_eq!("convex+refine".parse(), Ok(InitMethod::ConvexRefine));
        assert_eq!("convex".parse(), Ok(InitMethod::ConvexRobustRefine));
        for s in [
            CoefficientSolver::ActiveSet,
            CoefficientSolver::CoordinateDescent,
            CoefficientSolver::Apg,
        ] {
            let name = s.to_string();
            assert_eq!(name.parse::<CoefficientSolver>(), Ok(s));
            let json: CoefficientSolver = serde_json::from_value(name.into()).expect("serde");
            assert_eq!(json, s);
        }
        let cd: CoefficientSolver = serde_json::from_value("cd".into()).expect("serde");
        assert_eq!(cd, CoefficientSolver::CoordinateDescent);
        let unknown = "newton".parse::<CoefficientSolver>().expect_err("unknown");
        assert!(unknown.contains("active-set"), "{unknown}");
    }
}
