//! Per-frame initialisation (paper §3.3): a single-frame pose from 2D joints, before the
//! joint optimisation over the window.
//!
//! - [`altern`]: alternate a greedy rotation and a coefficient step;
//! - [`convex`]: the convex relaxation of Zhou et al. (CVPR 2015), ADMM on the
//!   spectral-norm penalty, optionally with an L1 outlier term (robust), then rotation
//!   recovery ([`convex::synchronise_rotation`]) and refinement by alternation.

pub mod altern;
pub mod convex;

use nalgebra::{Matrix2x3, Matrix3, Vector3};

use super::coefficients::{CoefficientProblem, CoefficientWorkspace};
use super::rotations::{self, FrameTerms};
use super::{FrameFit, InitMethod, Observations, Params};
use crate::dictionary::Dictionary;

/// What the initialisation of one frame did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct InitInfo {
    /// Iterations of the ADMM (0 for alternation).
    pub admm_iterations: usize,
    /// Iterations of the alternation (refinement).
    pub alternations: usize,
}

/// Quantities of a dictionary that every initialisation reuses.
#[derive(Debug, Clone)]
pub struct InitCache {
    /// `lambda_max(Bvec' Bvec)`: Lipschitz bound of a single-frame C-step.
    pub basis_gram_max: f64,
    /// Thin SVD of the (3k x p) basis matrix for the ADMM with all joints visible.
    pub all_visible: convex::BasisFactor,
    /// The average of the bases (row-major 3 x p): the alternation's starting shape.
    pub average_basis: Vec<f64>,
}

impl InitCache {
    /// Precomputes for `dict`.
    pub fn new(dict: &Dictionary, basis_gram_max: f64) -> Self {
        let all: Vec<usize> = (0..dict.num_joints()).collect();
        Self {
            basis_gram_max,
            all_visible: convex::BasisFactor::new(dict, &all),
            average_basis: dict.average_basis(),
        }
    }
}

/// Buffers of the initialisation, reused from frame to frame; the convex ADMM also
/// starts from the previous frame's solution ([`convex::AdmmState`]).
#[derive(Debug, Clone, Default)]
pub struct InitWorkspace {
    /// The ADMM's iterates.
    pub admm: convex::AdmmState,
    problem: CoefficientProblem,
    coefficients: CoefficientWorkspace,
    obs: Observations,
    /// The alternation's buffers: joint weights, shape, centred joints, zeros.
    altern: altern::AlternBuffers,
}

/// Initialises one frame from its 2D joints `w` (`[x, y]` per joint, normalised units);
/// joints with `visible[j] == false` are left out.
pub fn initialise_frame(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    method: InitMethod,
    params: &Params,
    ws: &mut InitWorkspace,
) -> (FrameFit, InitInfo) {
    let mut fit = FrameFit::zero(dict.num_bases());
    let info = initialise_frame_into(dict, cache, w, visible, method, params, ws, &mut fit);
    (fit, info)
}

/// [`initialise_frame`] written over `fit` (its coefficient vector reused): with the
/// alternation (the default for heat maps) nothing allocates once `ws` is warm; the
/// convex initialisation allocates its result.
pub fn initialise_frame_into(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    method: InitMethod,
    params: &Params,
    ws: &mut InitWorkspace,
    fit: &mut FrameFit,
) -> InitInfo {
    let robust = match method {
        InitMethod::Altern => {
            return altern::initialise_into(dict, cache, w, visible, params, ws, fit);
        }
        InitMethod::ConvexRefine => false,
        InitMethod::ConvexRobustRefine => true,
    };
    let (result, info) = convex::initialise(dict, cache, w, visible, params, robust, ws);
    *fit = result;
    info
}

/// Completes a 2 x 3 matrix with orthonormal rows to a rotation (third row = cross).
pub fn complete_rotation(r2: &Matrix2x3<f64>) -> Matrix3<f64> {
    let r1 = Vector3::new(r2[(0, 0)], r2[(0, 1)], r2[(0, 2)]);
    let r2v = Vector3::new(r2[(1, 0)], r2[(1, 1)], r2[(1, 2)]);
    let r3 = r1.cross(&r2v);
    Matrix3::from_rows(&[r1.transpose(), r2v.transpose(), r3.transpose()])
}

/// The nearest 2 x 3 matrix with orthonormal rows (polar factor, via SVD).
pub fn nearest_orthonormal_rows(m: &Matrix2x3<f64>) -> Option<Matrix2x3<f64>> {
    let svd = m.svd(true, true);
    Some(svd.u? * svd.v_t?)
}

/// Single-frame C-step on `w` (already minus translation and outliers) under rotation `r`,
/// warm-started from `c`. Uses `weights` (0 leaves a joint out).
pub(crate) fn single_frame_coefficients(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    weights: &[f64],
    r: &Matrix3<f64>,
    c: &mut [f64],
    params: &Params,
    ws: &mut InitWorkspace,
) {
    let InitWorkspace {
        problem,
        coefficients,
        obs,
        ..
    } = ws;
    obs.joints = dict.num_joints();
    obs.xy.clear();
    obs.xy.extend_from_slice(w);
    obs.weights.clear();
    obs.weights.extend_from_slice(weights);
    problem.build(
        dict,
        obs,
        std::iter::once(*r),
        &[nalgebra::Vector2::zeros()],
    );
    let lipschitz = cache.basis_gram_max * weights.iter().cloned().fold(0.0, f64::max);
    problem.solve_with(
        params.coefficient_solver,
        c,
        params.alpha,
        0.0,
        lipschitz,
        params.tolerance,
        params.cd_objective_tolerance,
        params.max_apg_steps.max(1000),
        params.admit_per_frame,
        coefficients,
    );
}

/// Local rotation fit `min_R |w - Pi R s|^2` (weights `d`) from `r`, by Riemannian Newton.
pub(crate) fn fit_rotation(s: &[f64], w: &[f64], d: &[f64], r: &mut Matrix3<f64>) {
    let term = FrameTerms::new(s, w, nalgebra::Vector2::zeros(), d);
    let mut rs = [*r];
    rotations::solve(&[term], &mut rs, 0.0, 1e-6, 100);
    *r = rs[0];
}
