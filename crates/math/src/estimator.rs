//! [`Estimator`]: a [`Dictionary`] plus [`Params`], lifting 2D joints or heat maps of a
//! sequence to 3D poses. The entry point of the library; the batch `lift` command and the
//! streaming nodes are thin adapters over it.

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::Vector3;
use serde::Serialize;

use crate::camera::{Intrinsics, PixelMap};
use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::heatmaps::HeatMapSequence;
use crate::solver::adapt::{self, ShapeStats};
use crate::solver::bcd::{self, BcdWorkspace};
use crate::solver::coefficients::basis_gram_max;
use crate::solver::em::{self, EmWorkspace, PreparedMaps};
use crate::solver::init::{InitCache, InitWorkspace, initialise_frame, initialise_frame_into};
use crate::solver::normalise::{heatmap_scale, keypoint_scale};
use crate::solver::perspective::{
    self, PerspectiveFit, PerspectiveParams, PerspectiveWorkspace, start_from_weak_fit,
};
use crate::solver::{FrameFit, InitMethod, Observations, Params};
use crate::streaming::{Estimates, FrameMaps, Outputs, StreamSettings, WindowEstimator};

/// Frames running that the sliding window's initialisation swaps a left/right pair's
/// maps back at most (a third of a second at 30 frames/s): a detector's swap is an
/// episode, a "swap" that lasts is the person's own (the maps then stand).
pub const MAX_SWAP_FRAMES: u32 = 10;

/// Frames after it a frame's fit has seen when the batch EM starts from it
/// ([`Params::start_from_window`]): the window's estimate that many frames back. On the
/// training files (`posestream eval --train --max-files-per-action 1 --no-scenes`, our
/// K128, EM P-MPJPE / 90th-percentile frame, mm) lag 0: 46.4 / 82.0, 2: 45.5 / 77.2,
/// 3: 45.6 / 76.8, 5: 45.5 / 77.3, 10 (the window's default): 46.3 / 77.5, 20: 46.9 /
/// 81.3; the authors' K128 66.8-66.9 for all. A fit refined further is not a better
/// start: the batch EM refines it with every frame after it anyway.
pub const START_LAG: usize = 3;

/// How much nearer (summed squared distance) a left/right pair's peaks must lie to the
/// track's previous peaks (each joint's last seen, as put back) swapped than as they are
/// for the sliding window's initialisation to put them back: at 1, two limbs crossing
/// in the image (a kick seen from the side) were put back on noise and held the fit on
/// the mirrored side (the held-out kick, docs/beyond-the-paper.md); on the training
/// files 2 leaves the window's errors as they were (`posestream eval --train
/// --max-files-per-action 1`). A joint unseen for a while keeps its last peak as the
/// reference (no expiry yet).
pub const SWAP_MARGIN: f64 = 2.0;

/// 2D joints of a sequence in pixels, with optional per-joint confidence in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Keypoints {
    /// Joints per frame.
    pub joints: usize,
    /// `[x, y]` per joint, frame-major (x right, y down).
    pub xy: Vec<f64>,
    /// Confidence per joint (`t*p + j`); `None` means all 1. A joint with confidence 0 is
    /// not observed.
    pub confidence: Option<Vec<f64>>,
}

impl Keypoints {
    /// Number of frames.
    pub fn frames(&self) -> usize {
        if self.joints == 0 {
            0
        } else {
            self.xy.len() / (2 * self.joints)
        }
    }
}

/// How the estimate was reached.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Report {
    /// Frames.
    pub frames: usize,
    /// Initialisation method.
    pub init: String,
    /// EM iterations (1 for given 2D joints).
    pub em_iterations: usize,
    /// Block-coordinate rounds per EM iteration.
    pub rounds: Vec<usize>,
    /// Objective after initialisation.
    pub objective_init: f64,
    /// Objective at the end.
    pub objective: f64,
    /// Objective history: for given 2D joints, before Algorithm 1 and after each of its
    /// rounds (never increasing); for heat maps, after each EM iteration's M-step (each
    /// E-step changes the data, so this sequence may rise slightly).
    pub objective_rounds: Vec<f64>,
    /// Seconds spent initialising.
    pub seconds_init: f64,
    /// Seconds in total.
    pub seconds: f64,
}

/// The result of lifting a sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Joints per frame.
    pub joints: usize,
    /// 3D poses `R_t S_t`, camera frame (x right, y down, z forward), dictionary units,
    /// centred: `[x, y, z]` per joint, frame-major.
    pub poses: Vec<f64>,
    /// The 2D joints the model was fitted to, in input pixels: the given keypoints, or the
    /// EM's expected joints.
    pub keypoints: Vec<f64>,
    /// The model's reprojection `Pi R_t S_t + T_t`, in input pixels.
    pub projected: Vec<f64>,
    /// Per-joint 2D variance (trace of the covariance, pixels^2) from the E-step; heat-map
    /// input only.
    pub variance: Option<Vec<f64>>,
    /// The model parameters per frame (normalised units).
    pub fits: Vec<FrameFit>,
    /// Input pixels per normalised unit (the fits' units).
    pub pixels_per_unit: f64,
    /// Weight of each joint in the fit (`t*p + j`): the keypoints' confidence, the last
    /// EM iteration's E-step weights on heat maps ([`Params::confidence_spread`]), or 1.
    pub weights: Vec<f64>,
    /// The person's shape beyond the dictionary the fits were composed with (row-major
    /// 3 x p, [`crate::solver::adapt`]; zero for the paper's model).
    pub offset: Vec<f64>,
    /// How it was reached.
    pub report: Report,
}

/// The result of the perspective adjustment of an [`Estimate`]
/// ([`Estimator::adjust_perspective`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MetricEstimate {
    /// Joints per frame.
    pub joints: usize,
    /// 3D poses, metres, camera frame (x right, y down, z forward), absolute position:
    /// `[x, y, z]` per joint, frame-major.
    pub poses: Vec<f64>,
    /// The 2D joints the model was fitted to, image pixels.
    pub keypoints: Vec<f64>,
    /// The perspective projection of the poses, image pixels.
    pub projected: Vec<f64>,
    /// The model per frame.
    pub fits: Vec<PerspectiveFit>,
    /// Seconds spent.
    pub seconds: f64,
}

/// Lifts 2D joints or heat maps to 3D with one dictionary and one parameter set.
///
/// ```
/// use posestream_math::{Dictionary, Estimator, Keypoints, Params};
///
/// let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
/// let dict = Dictionary::load(format!("{root}/config/dictionaries/default-k128.json"))?;
/// let estimator = Estimator::new(dict, Params::default())?;
/// // Two frames of 17 joints, pixels (x right, y down): a standing figure, 100 px tall.
/// let standing: [f64; 34] = [
///     50., 50., 58., 50., 58., 75., 58., 100., 42., 50., 42., 75., 42., 100., 50., 35.,
///     50., 20., 50., 12., 50., 0., 60., 22., 68., 38., 70., 52., 40., 22., 32., 38.,
///     30., 52.,
/// ];
/// let xy: Vec<f64> = standing.iter().chain(&standing).copied().collect();
/// let estimate = estimator.lift_keypoints(&Keypoints { joints: 17, xy, confidence: None })?;
/// assert_eq!(estimate.poses.len(), 2 * 17 * 3); // (F, p, 3), dictionary units
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone)]
pub struct Estimator {
    dict: Dictionary,
    params: Params,
    cache: InitCache,
    gram_max: f64,
}

impl Estimator {
    /// Prepares an estimator (precomputes the dictionary's factorisations).
    pub fn new(dict: Dictionary, params: Params) -> Result<Self, EstimateError> {
        params.validate()?;
        let gram_max = basis_gram_max(&dict);
        let cache = InitCache::new(&dict, gram_max);
        Ok(Self {
            dict,
            params,
            cache,
            gram_max,
        })
    }

    /// The dictionary, to set a track's offset ([`crate::solver::adapt`]).
    pub(crate) fn dictionary_mut(&mut self) -> &mut Dictionary {
        &mut self.dict
    }

    /// The dictionary.
    pub fn dictionary(&self) -> &Dictionary {
        &self.dict
    }

    /// The parameters.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Precomputed quantities of the initialisation.
    pub fn init_cache(&self) -> &InitCache {
        &self.cache
    }

    /// `lambda_max` of the vectorised bases' Gram matrix (Lipschitz bound of the C-step).
    pub fn basis_gram_max(&self) -> f64 {
        self.gram_max
    }

    /// The initialisation used for given 2D joints (default: convex+robust+refine).
    pub fn keypoint_init(&self) -> InitMethod {
        self.params.init.unwrap_or(InitMethod::ConvexRobustRefine)
    }

    /// The initialisation used for heat maps (default: altern, the reference's most
    /// accurate heat-map mode: P-MPJPE 0.123 against 0.163 for its convex default).
    pub fn heatmap_init(&self) -> InitMethod {
        self.params.init.unwrap_or(InitMethod::Altern)
    }

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
            outputs: Outputs::Lagged,
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

    /// The per-frame initialisation from heat maps (`map(j)`: joint j's map, `width`
    /// columns; `scale` pixels per unit): each joint at its map's arg-max, visible if its
    /// peak is above the visibility threshold (all, if fewer than two are). Leaves the
    /// arg-max (normalised units) in `xy` and the visibility in `visible`, and the fit
    /// in `fit` (its buffers reused). Shared by the batch EM and the sliding window
    /// (which caps the iterations in `params`, and gives the track's `previous`
    /// arg-maxes, normalised units, each joint where it was last seen, NaN where never,
    /// and per left/right pair the frames its maps have run swapped against them: with
    /// [`Params::swap_prior`] positive, a pair whose arg-maxes lie [`SWAP_MARGIN`] times
    /// nearer those swapped than as they are is swapped back, for a while; `previous`
    /// is then moved to this frame's arg-maxes, as put back).
    pub(crate) fn initialise_from_argmax<'m>(
        &self,
        map: impl Fn(usize) -> &'m [f32],
        width: usize,
        scale: f64,
        xy: &mut [f64],
        visible: &mut [bool],
        params: &Params,
        previous: Option<(&mut [f64], &mut [u32])>,
        ws: &mut InitWorkspace,
        fit: &mut FrameFit,
    ) {
        for (j, v) in visible.iter_mut().enumerate() {
            let (x, y, peak) = crate::heatmaps::argmax(map(j), width);
            xy[2 * j] = x / scale;
            xy[2 * j + 1] = y / scale;
            *v = f64::from(peak) > self.params.visibility_threshold;
        }
        // A detector's left/right swap (the swap model on): a pair whose peaks (both
        // seen) lie clearly nearer the track's previous peaks (each joint's last seen,
        // as put back) swapped than as they are is swapped back, for at most
        // `MAX_SWAP_FRAMES` frames running (a swap that lasts is the person's own, not
        // the detector's: the maps then stand), and not when most pairs are (a
        // whole-body flip of the detector's: the maps stand). Against the maps' own past,
        // not the fit's projection: a fit on a wrong branch would otherwise reorder
        // every new frame to its side, and stay there.
        if let Some((prev, runs)) = previous.filter(|_| self.params.swap_prior > 0.0) {
            let d2 = |xy: &[f64], a: usize, b: usize| {
                (xy[2 * a] - prev[2 * b]).powi(2) + (xy[2 * a + 1] - prev[2 * b + 1]).powi(2)
            };
            let pairs = self.dict.left_right_pairs();
            // Pairs with both joints seen (an empty map's arg-max says nothing).
            let mirrored = |xy: &[f64], seen: &[bool], (l, r): (usize, usize)| {
                seen[l]
                    && seen[r]
                    && SWAP_MARGIN * (d2(xy, l, r) + d2(xy, r, l)) < d2(xy, l, l) + d2(xy, r, r)
            };
            let most = 2 * pairs
                .iter()
                .filter(|&&pair| mirrored(xy, visible, pair))
                .count()
                > pairs.len();
            for (&(l, r), run) in pairs.iter().zip(runs.iter_mut()) {
                if !mirrored(xy, visible, (l, r)) {
                    *run = 0;
                    continue;
                }
                *run = run.saturating_add(1);
                if !most && *run <= MAX_SWAP_FRAMES {
                    xy.swap(2 * l, 2 * r);
                    xy.swap(2 * l + 1, 2 * r + 1);
                    visible.swap(l, r);
                }
            }
            // Where the track's joints were last seen.
            for (j, _) in visible.iter().enumerate().filter(|(_, v)| **v) {
                prev[2 * j..2 * j + 2].copy_from_slice(&xy[2 * j..2 * j + 2]);
            }
        }
        if visible.iter().filter(|&&v| v).count() < 2 {
            visible.iter_mut().for_each(|v| *v = true);
        }
        initialise_frame_into(
            &self.dict,
            &self.cache,
            xy,
            visible,
            self.heatmap_init(),
            params,
            ws,
            fit,
        );
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The window's initialisation puts a left/right pair back in the track's order
    /// when its peaks jumped to each other's places (a detector's swap), not when two
    /// limbs merely cross in the image (the pair's peaks near each other, a little
    /// nearer each other's previous place): that put a kick on the mirrored side.
    #[test]
    fn a_swap_is_put_back_and_two_limbs_crossing_are_not() {
        let skeleton = crate::skeleton::default_layout();
        let p = skeleton.len();
        let basis: Vec<f64> = (0..3 * p).map(|i| ((i * 7) % 11) as f64 / 11.0).collect();
        let dict = Dictionary::new(skeleton, basis, vec![0.0; 3 * p]).expect("dictionary");
        let &(l, r) = dict.left_right_pairs().first().expect("a left/right pair");
        let est = Estimator::new(dict, Params::default()).expect("estimator");
        let (h, w) = (64, 64);
        let scale = heatmap_scale(h);
        // Every joint in its own column of row 40, the pair at columns 10 and 20.
        let home = |j: usize| -> usize {
            if j == l {
                10
            } else if j == r {
                20
            } else {
                24 + j
            }
        };
        let previous: Vec<f64> = (0..p)
            .flat_map(|j| [home(j) as f64 / scale, 40.0 / scale])
            .collect();
        // (left's column, right's column, put back?), summed squared distances swapped
        // against as they are: a clean swap 0 against 200; a swap with noise 25 against
        // 85 (put back under a margin up to 3.4); crossing 41 against 61 (put back under
        // a margin of 1).
        for (cl, cr, back) in [(20, 10, true), (17, 14, true), (16, 15, false)] {
            let mut maps = vec![0.0_f32; p * h * w];
            for j in 0..p {
                let c = if j == l {
                    cl
                } else if j == r {
                    cr
                } else {
                    home(j)
                };
                maps[j * h * w + 40 * w + c] = 1.0;
            }
            let (mut xy, mut visible) = (vec![0.0; 2 * p], vec![false; p]);
            let pairs = est.dictionary().left_right_pairs().len();
            let (mut reference, mut runs) = (previous.clone(), vec![0; pairs]);
            let mut fit = FrameFit::zero(est.dictionary().num_bases());
            est.initialise_from_argmax(
                |j| &maps[j * h * w..(j + 1) * h * w],
                w,
                scale,
                &mut xy,
                &mut visible,
                est.params(),
                Some((&mut reference, &mut runs)),
                &mut InitWorkspace::default(),
                &mut fit,
            );
            let left = (xy[2 * l] * scale).round() as usize;
            assert_eq!(left, if back { cr } else { cl }, "{cl}, {cr}");
            // The track's reference follows the frame, as put back.
            assert_eq!(reference, xy, "{cl}, {cr}");
        }
    }
}
