//! The batch EM: a whole sequence lifted at once (2D joints, [`Estimator::lift_keypoints`],
//! or heat maps, [`Estimator::lift_heatmaps`]), optionally started from the sliding
//! window's fits ([`Params::start_from_window`]), and the perspective adjustment of its
//! result ([`Estimator::adjust_perspective`]).

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::Vector3;

use crate::camera::Intrinsics;
use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::estimator::*;
use crate::heatmaps::HeatMapSequence;
use crate::solver::adapt::{self, ShapeStats};
use crate::solver::bcd::{self, BcdWorkspace};
use crate::solver::em::{self, EmWorkspace, PreparedMaps};
use crate::solver::init::{InitWorkspace, initialise_frame};
use crate::solver::normalise::{heatmap_scale, keypoint_scale};
use crate::solver::perspective::{
    self, PerspectiveParams, PerspectiveWorkspace, start_from_weak_fit,
};
use crate::solver::{FrameFit, InitMethod, Observations};
use crate::streaming::{Emitted, Estimates, FrameMaps, StreamSettings, WindowEstimator};
use posestream_base::PixelMap;

impl Estimator {
    /// Algorithm 1 on given 2D joints.
    pub fn lift_keypoints(&self, kp: &Keypoints) -> Result<Estimate, EstimateError> {
        self.keypoints_inner(kp, true)
    }

    /// The single-frame baseline on given 2D joints: each frame's initialisation alone,
    /// without Algorithm 1's joint optimisation over the sequence.
    pub fn initialise_keypoints(&self, kp: &Keypoints) -> Result<Estimate, EstimateError> {
        self.keypoints_inner(kp, false)
    }

    fn keypoints_inner(&self, kp: &Keypoints, solve: bool) -> Result<Estimate, EstimateError> {
        let start = Instant::now();
        let p = self.dict.num_joints();
        if kp.joints != p {
            return Err(EstimateError::JointCount {
                expected: p,
                found: kp.joints,
            });
        }
        let f = kp.frames();
        if f == 0 {
            return Err(EstimateError::NoFrames);
        }
        let weights = match &kp.confidence {
            Some(c) => {
                if c.len() != f * p {
                    return Err(EstimateError::Parameter(format!(
                        "confidence holds {} values, expected {f} x {p}",
                        c.len()
                    )));
                }
                if let Some(i) = c
                    .iter()
                    .position(|v| !v.is_finite() || *v < 0.0 || *v > 1.0)
                {
                    return Err(EstimateError::Parameter(format!(
                        "confidence of frame {}, joint {} is {}, expected a value in [0, 1]",
                        i / p,
                        i % p,
                        c[i]
                    )));
                }
                c.clone()
            }
            None => vec![1.0; f * p],
        };
        for (i, v) in kp.xy.iter().enumerate() {
            if !v.is_finite() {
                return Err(EstimateError::NonFinite {
                    frame: i / (2 * p),
                    joint: (i / 2) % p,
                });
            }
        }
        for t in 0..f {
            let observed = weights[t * p..(t + 1) * p]
                .iter()
                .filter(|&&w| w > 0.0)
                .count();
            if observed < 2 {
                return Err(EstimateError::TooFewJoints { frame: t, observed });
            }
        }
        let scale = keypoint_scale(&kp.xy, &weights, p);
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(EstimateError::Degenerate);
        }
        let obs = Observations {
            joints: p,
            xy: kp.xy.iter().map(|v| v / scale).collect(),
            weights,
        };
        let mut fits = Vec::with_capacity(f);
        let mut init_ws = InitWorkspace::default();
        for t in 0..f {
            let visible: Vec<bool> = obs.frame_weights(t).iter().map(|&w| w > 0.0).collect();
            fits.push(
                initialise_frame(
                    &self.dict,
                    &self.cache,
                    obs.frame(t),
                    &visible,
                    self.keypoint_init(),
                    &self.params,
                    &mut init_ws,
                )
                .0,
            );
        }
        let seconds_init = start.elapsed().as_secs_f64();
        if !solve {
            return Ok(self.initial_estimate(
                fits,
                obs,
                scale,
                start,
                seconds_init,
                self.keypoint_init(),
            ));
        }
        let mut ws = BcdWorkspace::default();
        let mut info = bcd::solve(
            &self.dict,
            self.gram_max,
            &obs,
            &mut fits,
            &self.params,
            &mut ws,
        );
        let mut passes = vec![info.rounds];
        let mut obs = obs;
        let dict = self.fit_person(&mut obs, &mut fits, |dict, obs, fits| {
            let more = bcd::solve(dict, self.gram_max, obs, fits, &self.params, &mut ws);
            // The report counts every pass (one entry of `rounds` each).
            passes.push(more.rounds);
            info.objective.extend(&more.objective[1..]);
        });
        let mut est = self.finish(&dict, fits, obs, scale, None);
        est.report = Report {
            frames: f,
            init: self.keypoint_init().to_string(),
            em_iterations: 1,
            rounds: passes,
            objective_init: info.objective[0],
            objective: info.objective.last().copied().unwrap_or(f64::NAN),
            objective_rounds: info.objective,
            seconds_init,
            seconds: start.elapsed().as_secs_f64(),
        };
        Ok(est)
    }

    /// Algorithm 2 (EM) on heat maps. Output 2D values are in heat-map pixels.
    pub fn lift_heatmaps(&self, maps: &HeatMapSequence) -> Result<Estimate, EstimateError> {
        self.heatmaps_inner(maps, true)
    }

    /// The single-frame baseline on heat maps: each frame initialised from its maps'
    /// arg-max, without the EM. `keypoints` are the arg-max joints (heat-map pixels);
    /// joints whose peak is not above the visibility threshold have weight 0.
    pub fn initialise_heatmaps(&self, maps: &HeatMapSequence) -> Result<Estimate, EstimateError> {
        self.heatmaps_inner(maps, false)
    }

    fn heatmaps_inner(
        &self,
        maps: &HeatMapSequence,
        solve: bool,
    ) -> Result<Estimate, EstimateError> {
        let start = Instant::now();
        let p = self.dict.num_joints();
        if maps.joints != p {
            return Err(EstimateError::JointCount {
                expected: p,
                found: maps.joints,
            });
        }
        if maps.frames == 0 {
            return Err(EstimateError::NoFrames);
        }
        let f = maps.frames;
        let scale = heatmap_scale(maps.height);
        let prepared = PreparedMaps::new(maps);
        let mut fits = vec![FrameFit::zero(self.dict.num_bases()); f];
        // The window's pass first, if the EM starts from it: each frame it fits needs no
        // initialisation of its own.
        let mut started = vec![false; f];
        if solve && self.params.start_from_window {
            self.start_from_window(maps, &mut fits, &mut started)?;
        }
        // Initialise every other frame from the arg-max of each map.
        let mut init_ws = InitWorkspace::default();
        let mut argmax = Observations::new(p, vec![0.0; 2 * p * f]);
        let (mut w, mut visible) = (vec![0.0; 2 * p], vec![false; p]);
        for (t, fit) in fits.iter_mut().enumerate() {
            if started[t] {
                continue;
            }
            self.initialise_from_argmax(
                |j| maps.map(t, j),
                maps.width,
                scale,
                &mut w,
                &mut visible,
                &self.params,
                None,
                &mut init_ws,
                fit,
            );
            argmax.xy[2 * p * t..2 * p * (t + 1)].copy_from_slice(&w);
            for (j, &v) in visible.iter().enumerate() {
                argmax.weights[t * p + j] = if v { 1.0 } else { 0.0 };
            }
        }
        let seconds_init = start.elapsed().as_secs_f64();
        if !solve {
            return Ok(self.initial_estimate(
                fits,
                argmax,
                scale,
                start,
                seconds_init,
                self.heatmap_init(),
            ));
        }
        let mut ws = EmWorkspace::default();
        let mut scratch = Observations::new(p, vec![0.0; 2 * p * f]);
        let (mut obs, mut info) = em::run(
            &self.dict,
            self.gram_max,
            &prepared,
            &mut fits,
            scale,
            &self.params,
            &mut ws,
        );
        let dict = self.fit_person(&mut obs, &mut fits, |dict, obs, fits| {
            let (o, more) = em::run(
                dict,
                self.gram_max,
                &prepared,
                fits,
                scale,
                &self.params,
                &mut ws,
            );
            // The report counts every pass's iterations; its objectives are the adapted
            // model's (with the offset of the last pass).
            *obs = o;
            info.iterations += more.iterations;
            info.rounds.extend(&more.rounds);
            info.objective.extend(&more.objective);
            info.relative_change.extend(&more.relative_change);
        });
        let mut variance = vec![0.0; f * p];
        em::e_step(
            &dict,
            &prepared,
            &fits,
            scale,
            &self.params,
            &mut scratch,
            Some(&mut variance),
            &mut ws,
        );
        let mut est = self.finish(&dict, fits, obs, scale, Some(variance));
        est.report = Report {
            frames: f,
            init: if self.params.start_from_window {
                format!("{}, then the window", self.heatmap_init())
            } else {
                self.heatmap_init().to_string()
            },
            em_iterations: info.iterations,
            rounds: info.rounds,
            objective_init: info.objective_start,
            objective: info.objective.last().copied().unwrap_or(f64::NAN),
            objective_rounds: info.objective,
            seconds_init,
            seconds: start.elapsed().as_secs_f64(),
        };
        Ok(est)
    }

    /// The batch EM's start with [`Params::start_from_window`]: each frame's fit as a
    /// sliding window (the default [`StreamSettings`] at lag [`START_LAG`]) refined it,
    /// into `fits`, with `started` set for each frame the window fitted (a frame whose
    /// maps hold no evidence gets no estimate: it keeps its own initialisation). The
    /// window's estimates are reused from frame to frame: memory stays that of one
    /// window (at most the sequence's own frames) whatever the sequence's length.
    fn start_from_window(
        &self,
        maps: &HeatMapSequence,
        fits: &mut [FrameFit],
        started: &mut [bool],
    ) -> Result<(), EstimateError> {
        let settings = StreamSettings {
            outputs: Emitted::Lagged,
            lag: START_LAG,
            ..StreamSettings::default()
        };
        let mut window = WindowEstimator::new(self.clone(), settings)?;
        let mut out = Estimates::default();
        // Frames 1/30 s apart: the window's gap rules see consecutive frames.
        const FRAME_NS: i64 = 33_333_333;
        let mut take = |out: &Estimates| {
            for e in out.iter() {
                if let Some(t) = usize::try_from(e.sequence).ok().filter(|&t| t < fits.len()) {
                    fits[t].clone_from(&e.fit);
                    started[t] = true;
                }
            }
        };
        for t in 0..maps.frames {
            out.clear();
            let stamp = i64::try_from(t).map_or(i64::MAX, |t| t.saturating_mul(FRAME_NS));
            window.push_into(&FrameMaps::of(maps, t, t as u64, stamp), &mut out)?;
            take(&out);
        }
        out.clear();
        window.finish_into(&mut out);
        take(&out);
        Ok(())
    }

    /// The estimate of the initialisation alone.
    fn initial_estimate(
        &self,
        fits: Vec<FrameFit>,
        obs: Observations,
        scale: f64,
        start: Instant,
        seconds_init: f64,
        init: InitMethod,
    ) -> Estimate {
        let mut est = self.finish(&self.dict, fits, obs, scale, None);
        est.report = Report {
            frames: est.fits.len(),
            init: init.to_string(),
            em_iterations: 0,
            seconds_init,
            seconds: start.elapsed().as_secs_f64(),
            ..Report::default()
        };
        est
    }

    /// The batch's passes fitting the person ([`adapt`], when enabled): each an offset
    /// step from the current fits, then `solve` again under the new offset (warm
    /// started; it may renew the evidence, as the EM's E-step does), until the offset
    /// settles or `passes` have run. The dictionary with the offset (borrowed without).
    fn fit_person(
        &self,
        obs: &mut Observations,
        fits: &mut Vec<FrameFit>,
        mut solve: impl FnMut(&Dictionary, &mut Observations, &mut Vec<FrameFit>),
    ) -> Cow<'_, Dictionary> {
        let mut dict = Cow::Borrowed(&self.dict);
        let adaptation = &self.params.adaptation;
        if !adaptation.enabled {
            return dict;
        }
        let (mut stats, mut offset) = (ShapeStats::default(), Vec::new());
        for _ in 0..adaptation.passes {
            let settled = adapt::offset_step(
                dict.to_mut(),
                obs,
                fits,
                adaptation,
                &mut stats,
                &mut offset,
            );
            solve(&dict, obs, fits);
            if settled {
                break;
            }
        }
        dict
    }

    /// Poses and 2D outputs from the fits and the observations they were fitted to.
    fn finish(
        &self,
        dict: &Dictionary,
        fits: Vec<FrameFit>,
        obs: Observations,
        scale: f64,
        variance: Option<Vec<f64>>,
    ) -> Estimate {
        let p = dict.num_joints();
        let f = fits.len();
        let mut poses = vec![0.0; 3 * p * f];
        let mut projected = vec![0.0; 2 * p * f];
        let mut s = vec![0.0; 3 * p];
        for (t, fit) in fits.iter().enumerate() {
            dict.compose_into(&fit.coefficients, &mut s);
            for j in 0..p {
                let q = fit.rotation * Vector3::new(s[j], s[p + j], s[2 * p + j]);
                poses[3 * (t * p + j)..3 * (t * p + j) + 3].copy_from_slice(q.as_slice());
                projected[2 * (t * p + j)] = (q.x + fit.translation.x) * scale;
                projected[2 * (t * p + j) + 1] = (q.y + fit.translation.y) * scale;
            }
        }
        Estimate {
            joints: p,
            poses,
            keypoints: obs.xy.iter().map(|v| v * scale).collect(),
            projected,
            variance,
            fits,
            pixels_per_unit: scale,
            weights: obs.weights,
            offset: dict.offset().to_vec(),
            report: Report::default(),
        }
    }

    /// The perspective adjustment (see [`perspective`]): metric poses in the camera frame
    /// under the pinhole `camera`. `to_image` maps the estimate's input pixels to image
    /// pixels, one map per frame or one for all (keypoints in image pixels:
    /// [`PixelMap::IDENTITY`]; heat maps: [`CropBox::pixel_map`](crate::CropBox::pixel_map)).
    pub fn adjust_perspective(
        &self,
        est: &Estimate,
        camera: &Intrinsics,
        to_image: &[PixelMap],
        params: &PerspectiveParams,
    ) -> Result<MetricEstimate, EstimateError> {
        let start = Instant::now();
        params.validate()?;
        let p = self.dict.num_joints();
        let f = est.fits.len();
        if to_image.len() != f && to_image.len() != 1 {
            return Err(EstimateError::Parameter(format!(
                "{} crop boxes for {f} frames",
                to_image.len()
            )));
        }
        let mut dict = Cow::Borrowed(&self.dict);
        // The offset the fits were composed with (zero for the paper's model, or an
        // estimate from elsewhere).
        let zero = vec![0.0; 3 * p];
        let offset = if est.offset.len() == 3 * p {
            &est.offset
        } else {
            &zero
        };
        if offset.as_slice() != dict.offset() {
            dict.to_mut().set_offset(offset);
        }
        let dict = dict.as_ref();
        let mut poses = Vec::with_capacity(3 * p * f);
        let mut keypoints = Vec::with_capacity(2 * p * f);
        let mut projected = Vec::with_capacity(2 * p * f);
        let mut fits = Vec::with_capacity(f);
        let mut ws = PerspectiveWorkspace::default();
        for (t, fit) in est.fits.iter().enumerate() {
            let map = to_image[t.min(to_image.len() - 1)];
            let uv: Vec<f64> = est.keypoints[2 * p * t..2 * p * (t + 1)]
                .chunks_exact(2)
                .flat_map(|xy| map.apply(xy[0], xy[1]))
                .collect();
            let units_to_image = PixelMap {
                scale: map.scale.map(|s| s * est.pixels_per_unit),
                offset: map.offset,
            };
            let mut pf = start_from_weak_fit(dict, fit, &units_to_image, camera, params)
                .ok_or(EstimateError::ZeroSize { frame: t })?;
            perspective::adjust_frame(
                dict,
                self.gram_max,
                camera,
                &uv,
                &est.weights[p * t..p * (t + 1)],
                &mut pf,
                params,
                &mut ws,
            );
            let joints = pf.joints(dict);
            for q in joints.chunks_exact(3) {
                projected.extend(camera.project(&Vector3::new(q[0], q[1], q[2])));
            }
            poses.extend(joints);
            keypoints.extend(uv);
            fits.push(pf);
        }
        Ok(MetricEstimate {
            joints: p,
            poses,
            keypoints,
            projected,
            fits,
            seconds: start.elapsed().as_secs_f64(),
        })
    }
}
