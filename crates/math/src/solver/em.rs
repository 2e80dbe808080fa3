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
    /// One frame's projections (pixels) and expectations.
    projected: Vec<[f64; 2]>,
    expected: Vec<estep::Expectation>,
    /// Each left/right pair's probability of swapped maps.
    swapped: Vec<f64>,
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
/// joints (normalised units) into `obs`, their weights too when
/// [`Params::confidence_spread`] is positive (0 leaves them), and, if given, the variance
/// (pixels^2) into `var`. `scale` is pixels per unit; [`Params::sigma`] is in normalised
/// units. With [`Params::swap_prior`] positive, each left/right pair's expectations are
/// a mixture of the maps as they are and swapped (module [`super::estep`]).
pub fn e_step(
    dict: &Dictionary,
    maps: &impl MapSource,
    fits: &[FrameFit],
    scale: f64,
    params: &Params,
    obs: &mut Observations,
    mut var: Option<&mut [f64]>,
    ws: &mut EmWorkspace,
) {
    let p = dict.num_joints();
    let (h, w) = (maps.height(), maps.width());
    let sigma = params.sigma * scale;
    ws.shape.resize(3 * p, 0.0);
    ws.projected.resize(p, [0.0; 2]);
    ws.expected.resize(p, estep::Expectation::default());
    // The spread (pixels^2) up to which a joint weighs 1.
    let bound = params.confidence_spread * 2.0 * sigma.powi(2);
    if bound > 0.0 {
        obs.weights.resize(p * fits.len(), 1.0);
    }
    let swap_prior = params.swap_prior;
    for (t, fit) in fits.iter().enumerate() {
        dict.compose_into(&fit.coefficients, &mut ws.shape);
        let s = &ws.shape;
        let r = &fit.rotation;
        for j in 0..p {
            let (x, y, z) = (s[j], s[p + j], s[2 * p + j]);
            let u = r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z + fit.translation.x;
            let v = r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z + fit.translation.y;
            let [u, v] = [u * scale, v * scale];
            ws.projected[j] = [u, v];
        }
        estep::expect_joints(
            |j| (maps.map(t, j), maps.moments(t, j)),
            h,
            w,
            &ws.projected,
            sigma,
            swap_prior,
            dict.left_right_pairs(),
            &mut ws.estep,
            &mut ws.swapped,
            &mut ws.expected,
        );
        for (j, e) in ws.expected.iter().enumerate() {
            obs.xy[2 * (t * p + j)] = e.x / scale;
            obs.xy[2 * (t * p + j) + 1] = e.y / scale;
            if bound > 0.0 {
                obs.weights[t * p + j] = if e.variance > bound {
                    bound / e.variance
                } else {
                    1.0
                };
            }
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
        e_step(dict, maps, fits, scale, params, obs, None, ws);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::normalise::heatmap_scale;

    /// A dictionary of one basis (joint `j` at `(6 (j / p - 0.5), (j % 3) / 3, 0)`,
    /// normalised units) and a frame of it: the fit, and each joint's projection in map
    /// pixels (2 to 62 across).
    fn one_frame() -> (Dictionary, FrameFit, Vec<[f64; 2]>) {
        let skeleton = crate::skeleton::default_layout();
        let p = skeleton.len();
        let mut basis = vec![0.0; 3 * p];
        for j in 0..p {
            basis[j] = 6.0 * (j as f64 / p as f64 - 0.5);
            basis[p + j] = (j % 3) as f64 / 3.0;
        }
        let dict = Dictionary::new(skeleton, basis, vec![0.0; 3 * p]).expect("dictionary");
        let scale = heatmap_scale(64);
        let mut fit = FrameFit::zero(1);
        fit.coefficients[0] = 1.0;
        fit.translation = nalgebra::Vector2::new(3.2, 3.0);
        let shape = dict.compose(&fit.coefficients);
        let pixels = (0..p)
            .map(|j| {
                [
                    (shape[j] + fit.translation.x) * scale,
                    (shape[p + j] + fit.translation.y) * scale,
                ]
            })
            .collect();
        (dict, fit, pixels)
    }

    /// 64 x 64 maps of one frame: map `j` peaks at `peaks[j]` (a blob of 1.5 pixels on
    /// a floor of 0.01, as a CNN's maps are not exactly 0 away from their peak), or is
    /// flat (0.5) when `None`.
    fn maps_peaking_at(peaks: &[Option<[f64; 2]>]) -> HeatMapSequence {
        let (h, w) = (64, 64);
        let mut values = vec![0.5_f32; peaks.len() * h * w];
        for (map, peak) in values.chunks_exact_mut(h * w).zip(peaks) {
            let Some([cx, cy]) = *peak else { continue };
            for (i, v) in map.iter_mut().enumerate() {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                let blob = (-((c - cx).powi(2) + (r - cy).powi(2)) / (2.0 * 1.5 * 1.5)).exp();
                *v = (0.01 + blob) as f32;
            }
        }
        HeatMapSequence {
            frames: 1,
            joints: peaks.len(),
            height: h,
            width: w,
            values,
        }
    }

    /// The E-step's expected joints (map pixels) under `params`.
    fn expected(
        dict: &Dictionary,
        fit: &FrameFit,
        maps: &HeatMapSequence,
        params: &Params,
    ) -> Observations {
        let p = dict.num_joints();
        let mut obs = Observations::new(p, vec![0.0; 2 * p]);
        let scale = heatmap_scale(maps.height);
        let mut ws = EmWorkspace::default();
        let prepared = PreparedMaps::new(maps);
        e_step(
            dict,
            &prepared,
            std::slice::from_ref(fit),
            scale,
            params,
            &mut obs,
            None,
            &mut ws,
        );
        obs.xy.iter_mut().for_each(|v| *v *= scale);
        obs
    }

    /// A joint whose map peaks where it is projected weighs 1; one whose only peak is far
    /// from its projection (an occluder: the posterior is then the map's faint floor
    /// under the Gaussian) or whose map is flat weighs less; with `confidence_spread = 0`
    /// (the paper) every joint weighs 1.
    #[test]
    fn joints_weigh_by_how_sure_their_e_step_is() {
        let (dict, fit, pixels) = one_frame();
        let peaks: Vec<_> = pixels
            .iter()
            .enumerate()
            .map(|(j, &[x, y])| match j {
                // An occluder's peak 20 pixels away.
                1 => Some([x + 20.0, y]),
                // Flat: says nothing.
                2 => None,
                _ => Some([x, y]),
            })
            .collect();
        let maps = maps_peaking_at(&peaks);
        for confidence in [0.25, 0.0] {
            let params = Params {
                sigma: 0.5,
                confidence_spread: confidence,
                swap_prior: 0.0,
                ..Params::default()
            };
            let obs = expected(&dict, &fit, &maps, &params);
            let weights = obs.frame_weights(0);
            if confidence == 0.0 {
                assert!(weights.iter().all(|&v| v == 1.0), "{weights:?}");
                continue;
            }
            assert_eq!(weights[0], 1.0, "{weights:?}");
            assert!(weights[3..].iter().all(|&v| v == 1.0), "{weights:?}");
            assert!(weights[1] < 0.5, "occluded: {weights:?}");
            assert!((weights[2] - confidence).abs() < 0.05, "flat: {weights:?}");
        }
    }

    /// Maps of a left/right pair swapped (each peaks at the other joint's projection):
    /// the paper's E-step follows the maps; with the swap hypothesis the pair's joints
    /// stay near where they are projected (a mixture: the maps as they are keep some
    /// weight), and maps as they are stay as they are.
    #[test]
    fn a_swapped_pair_of_maps_is_read_as_swapped() {
        let (dict, fit, pixels) = one_frame();
        let &[(l, r), ..] = dict.left_right_pairs() else {
            panic!("the layout has left/right pairs");
        };
        let gap =
            ((pixels[l][0] - pixels[r][0]).powi(2) + (pixels[l][1] - pixels[r][1]).powi(2)).sqrt();
        // Twice the E-step Gaussian's spread (sigma 0.5 units, 5.3 pixels): a swap over
        // less is hard to tell from the maps, and costs less.
        assert!(gap > 10.0, "the pair's joints {gap} pixels apart");
        let as_is: Vec<_> = pixels.iter().map(|&x| Some(x)).collect();
        let mut swapped = as_is.clone();
        swapped.swap(l, r);
        let error = |obs: &Observations, j: usize| {
            (obs.xy[2 * j] - pixels[j][0]).hypot(obs.xy[2 * j + 1] - pixels[j][1])
        };
        for (prior, maps, within) in [
            (0.0, &swapped, None),
            (0.05, &swapped, Some(gap / 4.0)),
            (0.05, &as_is, Some(0.1)),
        ] {
            let params = Params {
                swap_prior: prior,
                ..Params::default()
            };
            let maps = maps_peaking_at(maps);
            let obs = expected(&dict, &fit, &maps, &params);
            let paper = expected(&dict, &fit, &maps, &Params::reference());
            for j in [l, r] {
                let e = error(&obs, j);
                match within {
                    None => assert!(e > gap / 3.0, "prior {prior}: joint {j} {e} px off"),
                    Some(px) => assert!(e < px, "prior {prior}: joint {j} {e} px off"),
                }
            }
            // Every other joint as in the paper's E-step (the other pairs' maps, as they
            // are, keep all but a trace of their weight).
            for j in (0..dict.num_joints()).filter(|&j| j != l && j != r) {
                let d = (obs.xy[2 * j] - paper.xy[2 * j])
                    .hypot(obs.xy[2 * j + 1] - paper.xy[2 * j + 1]);
                assert!(d < 0.05, "prior {prior}: joint {j} {d} px from the paper's");
            }
        }
    }
}
