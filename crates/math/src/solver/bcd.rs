//! Algorithm 1: block coordinate descent over (C, R, T) given 2D joints.
//!
//! Each round runs the C-step ([`super::coefficients`]), the R-step
//! ([`super::rotations`]) and the closed-form T-step (weighted mean of
//! `W_t - Pi R_t S_t`); each step does not increase the objective `J`
//! ([`super`] documents it), so neither does the round. Rounds stop when the relative
//! decrease of `J` falls below the tolerance, as in the reference.

use nalgebra::{Matrix3, Vector2};

use super::coefficients::{
    CoefficientProblem, CoefficientSolver, CoefficientWorkspace, lipschitz_bound,
};
use super::rotations::{self, FrameTerms};
use super::{Anchors, FrameFit, Observations, Params};
use crate::dictionary::Dictionary;

/// What one run of Algorithm 1 did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BcdInfo {
    /// Objective before the first round, then after each round.
    pub objective: Vec<f64>,
    /// Rounds run.
    pub rounds: usize,
    /// APG steps, summed over rounds.
    pub apg_steps: usize,
    /// Rotation sweeps, summed over rounds.
    pub rotation_sweeps: usize,
}

/// Reusable buffers of [`solve`]: allocate once, reuse for every window.
#[derive(Debug, Clone, Default)]
pub struct BcdWorkspace {
    problem: CoefficientProblem,
    apg: CoefficientWorkspace,
    c: Vec<f64>,
    shapes: Vec<f64>,
    terms: Vec<FrameTerms>,
    rotations: Vec<Matrix3<f64>>,
    translations: Vec<Vector2<f64>>,
    scratch: Vec<f64>,
    /// What the last run did (its objective history reuses this vector).
    info: BcdInfo,
}

/// The full objective `J` of `fits` on `obs`.
pub fn objective(dict: &Dictionary, obs: &Observations, fits: &[FrameFit], params: &Params) -> f64 {
    objective_anchored(dict, obs, fits, None, params)
}

/// The full objective `J` of `fits` on `obs`, with the smoothness term to a frozen frame
/// `anchor` before the first.
pub fn objective_anchored(
    dict: &Dictionary,
    obs: &Observations,
    fits: &[FrameFit],
    anchor: Option<&FrameFit>,
    params: &Params,
) -> f64 {
    objective_between(dict, obs, fits, Anchors::before(anchor), params)
}

/// The full objective `J` of `fits` on `obs`, with the smoothness terms to the frozen
/// frames around them.
pub fn objective_between(
    dict: &Dictionary,
    obs: &Observations,
    fits: &[FrameFit],
    anchors: Anchors<'_>,
    params: &Params,
) -> f64 {
    let mut s = vec![0.0; 3 * dict.num_joints()];
    objective_with(dict, obs, fits, anchors, params, &mut s)
}

/// [`objective_between`] with a buffer of 3 x p values for the shapes.
fn objective_with(
    dict: &Dictionary,
    obs: &Observations,
    fits: &[FrameFit],
    anchors: Anchors<'_>,
    params: &Params,
    s: &mut [f64],
) -> f64 {
    let mut j_total = 0.0;
    for (t, fit) in fits.iter().enumerate() {
        dict.compose_into(&fit.coefficients, s);
        j_total += frame_data_cost(
            s,
            obs.frame(t),
            obs.frame_weights(t),
            &fit.rotation,
            &fit.translation,
        );
        j_total += params.alpha * fit.coefficients.iter().map(|c| c.abs()).sum::<f64>();
    }
    let before = anchors.before.zip(fits.first()).map(|(a, f)| [a, f]);
    let after = anchors.after.zip(fits.last()).map(|(b, l)| [l, b]);
    for w in before
        .into_iter()
        .chain(fits.windows(2).map(|w| [&w[0], &w[1]]))
        .chain(after)
    {
        let dc: f64 = w[0]
            .coefficients
            .iter()
            .zip(&w[1].coefficients)
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        j_total += 0.5 * params.beta * dc;
        j_total += 0.5 * params.gamma * (w[0].rotation - w[1].rotation).norm_squared();
    }
    j_total
}

/// `1/2 sum_j d_j |w_j - Pi R s_j - T|^2` for one frame.
pub fn frame_data_cost(
    s: &[f64],
    w: &[f64],
    d: &[f64],
    r: &Matrix3<f64>,
    tr: &Vector2<f64>,
) -> f64 {
    let p = d.len();
    let mut cost = 0.0;
    for j in 0..p {
        let (x, y, z) = (s[j], s[p + j], s[2 * p + j]);
        let u = r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z + tr.x;
        let v = r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z + tr.y;
        cost += d[j] * ((w[2 * j] - u).powi(2) + (w[2 * j + 1] - v).powi(2));
    }
    0.5 * cost
}

/// The closed-form T-step for one frame: weighted mean of `w - Pi R s`.
pub fn best_translation(s: &[f64], w: &[f64], d: &[f64], r: &Matrix3<f64>) -> Vector2<f64> {
    let p = d.len();
    let (mut tx, mut ty, mut sum) = (0.0, 0.0, 0.0);
    for j in 0..p {
        let (x, y, z) = (s[j], s[p + j], s[2 * p + j]);
        tx += d[j] * (w[2 * j] - (r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z));
        ty += d[j] * (w[2 * j + 1] - (r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z));
        sum += d[j];
    }
    if sum > 0.0 {
        Vector2::new(tx / sum, ty / sum)
    } else {
        Vector2::zeros()
    }
}

/// Runs Algorithm 1 on `obs` from `fits` (warm start), in place.
///
/// `basis_gram_max` is [`super::coefficients::basis_gram_max`] of `dict`.
pub fn solve(
    dict: &Dictionary,
    basis_gram_max: f64,
    obs: &Observations,
    fits: &mut [FrameFit],
    params: &Params,
    ws: &mut BcdWorkspace,
) -> BcdInfo {
    solve_anchored(dict, basis_gram_max, obs, fits, None, params, ws)
}

/// [`solve`] with a frozen frame `anchor` just before the first: it stays fixed and
/// pulls the first frame through the smoothness terms (`beta/2 |c_0 - c_a|^2 +
/// gamma/2 ||R_0 - R_a||_F^2`). This is how a sliding window keeps continuity with the
/// frames that left it.
pub fn solve_anchored(
    dict: &Dictionary,
    basis_gram_max: f64,
    obs: &Observations,
    fits: &mut [FrameFit],
    anchor: Option<&FrameFit>,
    params: &Params,
    ws: &mut BcdWorkspace,
) -> BcdInfo {
    solve_between(
        dict,
        basis_gram_max,
        obs,
        fits,
        Anchors::before(anchor),
        params,
        ws,
    )
}

/// [`solve`] between frozen frames before the first and after the last (see
/// [`Anchors`]): a part of a window solved on its own.
pub fn solve_between(
    dict: &Dictionary,
    basis_gram_max: f64,
    obs: &Observations,
    fits: &mut [FrameFit],
    anchors: Anchors<'_>,
    params: &Params,
    ws: &mut BcdWorkspace,
) -> BcdInfo {
    solve_in(dict, basis_gram_max, obs, fits, anchors, params, ws).clone()
}

/// [`solve_between`], leaving what it did in the workspace (nothing allocates once the
/// workspace is warm).
pub(crate) fn solve_in<'w>(
    dict: &Dictionary,
    basis_gram_max: f64,
    obs: &Observations,
    fits: &mut [FrameFit],
    anchors: Anchors<'_>,
    params: &Params,
    ws: &'w mut BcdWorkspace,
) -> &'w BcdInfo {
    let (k, p, f) = (dict.num_bases(), dict.num_joints(), fits.len());
    debug_assert_eq!(obs.frames(), f);
    let max_weight = obs.weights.iter().cloned().fold(0.0, f64::max);
    let lipschitz = lipschitz_bound(basis_gram_max, max_weight, params.beta, f + anchors.count());
    ws.problem.set_anchors(
        anchors.before.map(|a| a.coefficients.as_slice()),
        anchors.after.map(|a| a.coefficients.as_slice()),
    );
    ws.c.resize(f * k, 0.0);
    ws.shapes.resize(f * 3 * p, 0.0);
    ws.rotations.clear();
    ws.translations.clear();
    for (t, fit) in fits.iter().enumerate() {
        ws.c[t * k..(t + 1) * k].copy_from_slice(&fit.coefficients);
        ws.rotations.push(fit.rotation);
        ws.translations.push(fit.translation);
    }
    // A T-step first (for uniform weights: the mean of the joints, as the reference).
    {
        let s = &mut ws.scratch;
        s.resize(3 * p, 0.0);
        for (t, fit) in fits.iter_mut().enumerate() {
            dict.compose_into(&fit.coefficients, s);
            fit.translation =
                best_translation(s, obs.frame(t), obs.frame_weights(t), &fit.rotation);
            ws.translations[t] = fit.translation;
        }
    }
    let start = objective_with(dict, obs, fits, anchors, params, &mut ws.scratch);
    let mut info = std::mem::take(&mut ws.info);
    info.objective.clear();
    info.objective.reserve(params.max_rounds + 1);
    info.objective.push(start);
    info.rounds = 0;
    info.apg_steps = 0;
    info.rotation_sweeps = 0;
    let mut prev = start;
    for _ in 0..params.max_rounds {
        info.rounds += 1;
        // C-step.
        ws.problem
            .build(dict, obs, ws.rotations.iter().copied(), &ws.translations);
        let cinfo = ws.problem.solve_with(
            params.coefficient_solver,
            &mut ws.c,
            params.alpha,
            params.beta,
            lipschitz,
            params.tolerance,
            params.cd_objective_tolerance,
            match params.coefficient_solver {
                CoefficientSolver::ActiveSet => params.max_newton_steps,
                _ => params.max_apg_steps,
            },
            params.admit_per_frame,
            &mut ws.apg,
        );
        info.apg_steps += cinfo.steps;
        // R-step.
        ws.terms.clear();
        for t in 0..f {
            let s = &mut ws.shapes[t * 3 * p..(t + 1) * 3 * p];
            dict.compose_into(&ws.c[t * k..(t + 1) * k], s);
            ws.terms.push(FrameTerms::new(
                s,
                obs.frame(t),
                ws.translations[t],
                obs.frame_weights(t),
            ));
        }
        let rinfo = rotations::solve_between(
            &ws.terms,
            &mut ws.rotations,
            anchors.before.map(|a| &a.rotation),
            anchors.after.map(|a| &a.rotation),
            params.gamma,
            params.tolerance,
            params.max_rotation_sweeps,
        );
        info.rotation_sweeps += rinfo.sweeps;
        // T-step and objective.
        let mut data = 0.0;
        for t in 0..f {
            let s = &ws.shapes[t * 3 * p..(t + 1) * 3 * p];
            let (w, d) = (obs.frame(t), obs.frame_weights(t));
            ws.translations[t] = best_translation(s, w, d, &ws.rotations[t]);
            data += frame_data_cost(s, w, d, &ws.rotations[t], &ws.translations[t]);
        }
        let smooth_r: f64 = ws
            .rotations
            .windows(2)
            .map(|w| 0.5 * params.gamma * (w[0] - w[1]).norm_squared())
            .sum::<f64>()
            + anchors.before.map_or(0.0, |a| {
                rotations::anchor_cost(&a.rotation, &ws.rotations[0], params.gamma)
            })
            + anchors.after.map_or(0.0, |b| {
                rotations::anchor_cost(&b.rotation, &ws.rotations[f - 1], params.gamma)
            });
        let obj = data + smooth_r + cinfo.penalty;
        info.objective.push(obj);
        let done = prev / obj - 1.0 < params.tolerance;
        prev = obj;
        if done {
            break;
        }
    }
    for (t, fit) in fits.iter_mut().enumerate() {
        fit.coefficients.copy_from_slice(&ws.c[t * k..(t + 1) * k]);
        fit.rotation = ws.rotations[t];
        fit.translation = ws.translations[t];
    }
    ws.info = info;
    &ws.info
}
