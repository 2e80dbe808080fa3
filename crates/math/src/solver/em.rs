//! Algorithm 2: EM over heat maps. The E-step ([`super::estep`]) replaces the 2D joints
//! by their expectation under heat map x Gaussian around the current projection; the
//! M-step is Algorithm 1 ([`super::bcd`]) warm-started from the current fit. Stops when
//! the relative change of C falls below the tolerance, or at the iteration cap.

use std::borrow::Cow;

use super::bcd::{self, BcdWorkspace};
use super::estep::{self, EStepWorkspace, MapMoments};
use super::{Anchors, FrameFit, Observations, Params};

use crate::dictionary::Dictionary;
use crate::heatmaps::HeatMapSequence;

/// What the EM did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EmInfo {
    /// EM iterations run.
    pub iterations: usize,
    /// Block-coordinate rounds of each M-step.
    pub rounds: Vec<usize>,
    /// Objective after the first E-step (at the initialisation).
    pub objective_start: f64,
    /// Objective after each M-step.
    pub objective: Vec<f64>,
    /// Relative change of C of each iteration.
    pub relative_change: Vec<f64>,
}

/// Reusable buffers of [`run`].
#[derive(Debug, Clone, Default)]
pub struct EmWorkspace {
    /// Buffers of the M-step.
    pub bcd: BcdWorkspace,
    estep: EStepWorkspace,
    shape: Vec<f64>,
    c_prev: Vec<f64>,
    /// What the last run did (its vectors reused).
    info: EmInfo,
}

/// Heat maps prepared for the E-step: clipped at 0, with their moments.
#[derive(Debug, Clone)]
pub struct PreparedMaps<'a> {
    /// The maps, negatives clipped to 0 (borrowed when there is nothing to clip).
    pub maps: Cow<'a, HeatMapSequence>,
    /// Moments per (frame, joint).
    pub moments: Vec<MapMoments>,
}

impl<'a> PreparedMaps<'a> {
    /// Clips (in a copy, only if a value is negative) and computes moments.
    pub fn new(maps: &'a HeatMapSequence) -> Self {
        let mut maps = Cow::Borrowed(maps);
        if maps.values.iter().any(|&v| v < 0.0) {
            maps.to_mut()
                .values
                .iter_mut()
                .for_each(|v| *v = v.max(0.0));
        }
        let moments = maps
            .values
            .chunks_exact(maps.height * maps.width)
            .map(|m| MapMoments::new(m, maps.width))
            .collect();
        Self { maps, moments }
    }
}

/// Heat maps the E-step reads, one per (frame, joint), with their moments: a whole
/// sequence ([`PreparedMaps`]) or a sliding window's ring of frames.
pub trait MapSource {
    /// Rows of each map.
    fn height(&self) -> usize;
    /// Columns of each map.
    fn width(&self) -> usize;
    /// The map of joint `j` in frame `t` (row-major, values >= 0).
    fn map(&self, t: usize, j: usize) -> &[f32];
    /// The moments of that map.
    fn moments(&self, t: usize, j: usize) -> &MapMoments;
}

impl MapSource for PreparedMaps<'_> {
    fn height(&self) -> usize {
        self.maps.height
    }
    fn width(&self) -> usize {
        self.maps.width
    }
    fn map(&self, t: usize, j: usize) -> &[f32] {
        self.maps.map(t, j)
    }
    fn moments(&self, t: usize, j: usize) -> &MapMoments {
        &self.moments[t * self.maps.joints + j]
    }
}

/// The E-step for frames `fits` (frame `t` of `maps` is fit `t`): writes the expected
/// joints (normalised units) into `obs` and, if given, the variance (pixels^2) into `var`.
/// `scale` is pixels per unit; `sigma` in normalised units.
pub fn e_step(
    dict: &Dictionary,
    maps: &impl MapSource,
    fits: &[FrameFit],
    scale: f64,
    sigma: f64,
    obs: &mut Observations,
    mut var: Option<&mut [f64]>,
    ws: &mut EmWorkspace,
) {
    let p = dict.num_joints();
    let (h, w) = (maps.height(), maps.width());
    ws.shape.resize(3 * p, 0.0);
    for (t, fit) in fits.iter().enumerate() {
        dict.compose_into(&fit.coefficients, &mut ws.shape);
        let s = &ws.shape;
        let r = &fit.rotation;
        for j in 0..p {
            let (x, y, z) = (s[j], s[p + j], s[2 * p + j]);
            let u = r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z + fit.translation.x;
            let v = r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z + fit.translation.y;
            let e = estep::expectation(
                maps.map(t, j),
                h,
                w,
                maps.moments(t, j),
                u * scale,
                v * scale,
                sigma * scale,
                &mut ws.estep,
            );
            obs.xy[2 * (t * p + j)] = e.x / scale;
            obs.xy[2 * (t * p + j) + 1] = e.y / scale;
            if let Some(var) = var.as_deref_mut() {
                var[t * p + j] = e.variance;
            }
        }
    }
}

/// Runs EM from `fits` (initialised), in place; returns the last E-step's expected joints
/// (normalised units) and what it did.
pub fn run(
    dict: &Dictionary,
    basis_gram_max: f64,
    maps: &impl MapSource,
    fits: &mut [FrameFit],
    scale: f64,
    params: &Params,
    ws: &mut EmWorkspace,
) -> (Observations, EmInfo) {
    let p = dict.num_joints();
    let mut obs = Observations::new(p, vec![0.0; 2 * p * fits.len()]);
    let info = run_anchored(
        dict,
        basis_gram_max,
        maps,
        fits,
        None,
        scale,
        params,
        &mut obs,
        ws,
    );
    (obs, info)
}

/// [`run`] with a frozen frame `anchor` before the first (see
/// [`bcd::solve_anchored`]), writing the last E-step's expected joints into `obs`
/// (resized to the frames): the sliding window's EM.
pub fn run_anchored(
    dict: &Dictionary,
    basis_gram_max: f64,
    maps: &impl MapSource,
    fits: &mut [FrameFit],
    anchor: Option<&FrameFit>,
    scale: f64,
    params: &Params,
    obs: &mut Observations,
    ws: &mut EmWorkspace,
) -> EmInfo {
    run_anchored_in(
        dict,
        basis_gram_max,
        maps,
        fits,
        anchor,
        scale,
        params,
        obs,
        ws,
    )
    .clone()
}

/// [`run_anchored`], leaving what it did in the workspace: once the workspace and `obs`
/// are warm, nothing allocates (the sliding window's update).
pub fn run_anchored_in<'w>(
    dict: &Dictionary,
    basis_gram_max: f64,
    maps: &impl MapSource,
    fits: &mut [FrameFit],
    anchor: Option<&FrameFit>,
    scale: f64,
    params: &Params,
    obs: &mut Observations,
    ws: &'w mut EmWorkspace,
) -> &'w EmInfo {
    run_between_in(
        dict,
        basis_gram_max,
        maps,
        fits,
        Anchors::before(anchor),
        scale,
        params,
        obs,
        ws,
    )
}

/// [`run_anchored_in`] between frozen frames before the first and after the last (see
/// [`Anchors`]): the EM over a part of a sliding window.
pub fn run_between_in<'w>(
    dict: &Dictionary,
    basis_gram_max: f64,
    maps: &impl MapSource,
    fits: &mut [FrameFit],
    anchors: Anchors<'_>,
    scale: f64,
    params: &Params,
    obs: &mut Observations,
    ws: &'w mut EmWorkspace,
) -> &'w EmInfo {
    let (p, k) = (dict.num_joints(), dict.num_bases());
    obs.joints = p;
    obs.xy.resize(2 * p * fits.len(), 0.0);
    obs.weights.clear();
    obs.weights.resize(p * fits.len(), 1.0);
    let mut info = std::mem::take(&mut ws.info);
    info.iterations = 0;
    info.objective_start = f64::NAN;
    for v in [&mut info.objective, &mut info.relative_change] {
        v.clear();
        v.reserve(params.max_em_iterations);
    }
    info.rounds.clear();
    info.rounds.reserve(params.max_em_iterations);
    let m_step = Params {
        max_rounds: params.max_em_rounds,
        ..params.clone()
    };
    for _ in 0..params.max_em_iterations {
        info.iterations += 1;
        e_step(dict, maps, fits, scale, params.sigma, obs, None, ws);
        ws.c_prev.clear();
        for fit in fits.iter() {
            ws.c_prev.extend_from_slice(&fit.coefficients);
        }
        let m = bcd::solve_in(
            dict,
            basis_gram_max,
            obs,
            fits,
            anchors,
            &m_step,
            &mut ws.bcd,
        );
        if info.iterations == 1 {
            info.objective_start = m.objective[0];
        }
        info.rounds.push(m.rounds);
        info.objective
            .push(m.objective.last().copied().unwrap_or(f64::NAN));
        let (mut diff, mut norm) = (0.0, 0.0);
        for (t, fit) in fits.iter().enumerate() {
            for (a, b) in fit.coefficients.iter().zip(&ws.c_prev[t * k..(t + 1) * k]) {
                diff += (a - b) * (a - b);
                norm += b * b;
            }
        }
        let rel = diff.sqrt() / norm.sqrt().max(f64::MIN_POSITIVE);
        info.relative_change.push(rel);
        if rel < params.tolerance {
            break;
        }
    }
    ws.info = info;
    &ws.info
}
