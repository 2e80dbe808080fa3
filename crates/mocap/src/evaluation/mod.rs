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

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Instant;

use crate::MappedSequence;
use crate::synth::{self, CameraSpec, ErrorModel, Projection, RenderedMaps, View, heatmaps};
use posestream_math::dictionary::Dictionary;
use posestream_math::error::EstimateError;
use posestream_math::estimator::{Estimate, Estimator, Keypoints};
use posestream_math::heatmaps::HeatMapSequence;
use posestream_math::metrics;
use posestream_math::skeleton::Skeleton;
use posestream_math::solver::Params;
use posestream_math::streaming::{
    FrameEstimate, FrameMaps, Outputs, StreamSettings, WindowEstimator,
};

/// What the evaluation runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Frames per sequence at most (from the start).
    pub max_frames: usize,
    /// Orbit speed of the moving camera of Table 1, deg/s.
    pub orbit_deg_per_s: f64,
    /// The heat-map camera (azimuth is set per sequence).
    pub camera: CameraSpec,
    /// The synthetic detector's error model (seeded per sequence from its `seed`).
    pub errors: ErrorModel,
    /// PCK threshold, pixels of a 256-pixel crop.
    pub pck_threshold: f64,
    /// Crop box side, times the joints' extent.
    pub margin: f64,
    /// Mean bone length (metres, over the layout's tree) every held-out subject is scaled
    /// to, so that millimetres refer to a body of known size.
    pub limb_length: f64,
    /// Actions of the per-action table (the held-out contents); empty = every action.
    pub actions: Vec<String>,
    /// The sequences are the split's training files, not its held-out ones (`eval
    /// --train`, to calibrate without looking at the held-out motion).
    pub training: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            max_frames: 150,
            orbit_deg_per_s: 15.0,
            camera: CameraSpec::default(),
            errors: ErrorModel::default(),
            pck_threshold: 10.0,
            margin: 1.25,
            limb_length: posestream_math::solver::perspective::PerspectiveParams::default()
                .mean_limb_length,
            actions: Vec::new(),
            training: false,
        }
    }
}

/// One held-out sequence, prepared.
#[derive(Debug, Clone)]
pub struct Case {
    /// File stem.
    pub name: String,
    /// Action (content) of the file.
    pub action: String,
    /// Orthographic static view (Table 1).
    pub still: View,
    /// Orthographic orbiting view (Table 1).
    pub orbit: View,
    /// Pinhole view the heat maps were rendered from (Table 3).
    pub pinhole: View,
    /// Heat maps of the pinhole view.
    pub maps: RenderedMaps,
}

impl Case {
    /// Prepares the views and heat maps of a mapped sequence; `index` picks its azimuth
    /// and the error model's seed.
    pub fn new(
        name: String,
        action: String,
        seq: &MappedSequence,
        skeleton: &Skeleton,
        settings: &Settings,
        index: usize,
    ) -> Result<Self, String> {
        let mut seq = seq
            .frames_from(0, settings.max_frames)
            .ok_or("the sequence has no frames")?;
        let scale = settings.limb_length / mean_bone_length(&seq, skeleton);
        if !scale.is_finite() {
            return Err("the subject's bones have no length".into());
        }
        seq.positions.iter_mut().for_each(|v| *v *= scale);
        let azimuth = (47.0 * index as f64) % 360.0;
        let ortho = CameraSpec {
            azimuth_deg: azimuth,
            projection: Projection::Orthographic,
            orbit_deg_per_s: 0.0,
            ..settings.camera.clone()
        };
        let still = synth::view(&seq, skeleton, &ortho)?;
        let orbit = synth::view(
            &seq,
            skeleton,
            &CameraSpec {
                orbit_deg_per_s: settings.orbit_deg_per_s,
                ..ortho
            },
        )?;
        let pin = CameraSpec {
            azimuth_deg: azimuth,
            ..settings.camera.clone()
        };
        let pinhole = synth::view(&seq, skeleton, &pin)?;
        let boxes = synth::crop_boxes(&pinhole.image_2d, pinhole.joints, settings.margin);
        let errors = ErrorModel {
            seed: settings.errors.seed.wrapping_add(index as u64),
            ..settings.errors.clone()
        };
        let maps = heatmaps::render(&pinhole.image_2d, &boxes, skeleton, &errors)
            .map_err(|e| e.to_string())?;
        Ok(Self {
            name,
            action,
            still,
            orbit,
            pinhole,
            maps,
        })
    }
}

/// The mean bone length of a sequence over the skeleton's tree (its units).
pub fn mean_bone_length(seq: &MappedSequence, skeleton: &Skeleton) -> f64 {
    let mut total = Mean::default();
    for frame in seq.positions.chunks_exact(3 * seq.joints) {
        for (a, b) in skeleton.bones() {
            let d: f64 = (0..3)
                .map(|i| (frame[3 * a + i] - frame[3 * b + i]).powi(2))
                .sum();
            total.add(d.sqrt(), 1.0);
        }
    }
    total.get()
}

/// A running, frame-weighted mean.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mean {
    sum: f64,
    weight: f64,
}

impl Mean {
    /// Adds `value` with weight `weight`.
    pub fn add(&mut self, value: f64, weight: f64) {
        self.sum += value * weight;
        self.weight += weight;
    }

    /// Adds another mean's sums.
    pub fn merge(&mut self, other: &Self) {
        self.sum += other.sum;
        self.weight += other.weight;
    }

    /// The mean (NaN when empty).
    pub fn get(&self) -> f64 {
        if self.weight > 0.0 {
            self.sum / self.weight
        } else {
            f64::NAN
        }
    }
}

/// Scores of one method over the cases.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Score {
    /// P-MPJPE, mm.
    pub p_mpjpe_mm: Mean,
    /// 2D error, pixels of a 256-pixel crop (heat maps only).
    pub error_2d: Mean,
    /// PCK, percent (heat maps only).
    pub pck: Mean,
    /// Seconds per frame.
    pub seconds_per_frame: Mean,
    /// P-MPJPE per action, mm.
    pub per_action: BTreeMap<String, Mean>,
    /// P-MPJPE of every frame, mm (for percentiles).
    pub frames_mm: Vec<f64>,
    /// Calibration of the per-joint standard deviations: how many pose coordinates
    /// (after the similarity alignment, the deviation scaled with the pose) have
    /// `|error| / std` in each bin of [`RatioHistogram`].
    pub ratios: RatioHistogram,
    /// The same for the lateral coordinates (x, y) alone.
    pub lateral_ratios: RatioHistogram,
    /// The same for the depth coordinate (z) alone.
    pub depth_ratios: RatioHistogram,
}

/// A histogram of `|error| / std` over log-spaced bins (1e-3 to 1e3, 100 per decade),
/// for the fraction within any number of deviations and the scale that calibrates.
#[derive(Debug, Clone, PartialEq)]
pub struct RatioHistogram {
    bins: Vec<f64>,
    total: f64,
}

impl Default for RatioHistogram {
    fn default() -> Self {
        Self {
            bins: vec![0.0; Self::BINS + 2],
            total: 0.0,
        }
    }
}

impl RatioHistogram {
    const BINS: usize = 600;
    const LOG_MIN: f64 = -3.0;
    const PER_DECADE: f64 = 100.0;

    fn bin(ratio: f64) -> usize {
        if ratio.is_nan() {
            return Self::BINS + 1;
        }
        let x = (ratio.log10() - Self::LOG_MIN) * Self::PER_DECADE;
        if x < 0.0 {
            0
        } else if x < Self::BINS as f64 {
            x.floor() as usize + 1
        } else {
            // Beyond the last bin, +inf (a zero deviation) included.
            Self::BINS + 1
        }
    }

    /// Adds one `|error| / std`.
    pub fn add(&mut self, ratio: f64) {
        self.bins[Self::bin(ratio)] += 1.0;
        self.total += 1.0;
    }

    /// True when nothing was added.
    pub fn is_empty(&self) -> bool {
        self.total == 0.0
    }

    /// The fraction within `z` deviations (to the bins' resolution, 2.3 %).
    pub fn within(&self, z: f64) -> f64 {
        let last = Self::bin(z);
        self.bins[..last].iter().sum::<f64>() / self.total
    }

    /// The factor on the deviations that puts a fraction `q` within one deviation: the
    /// `q`-quantile of `|error| / std`.
    pub fn scale_for(&self, q: f64) -> f64 {
        let mut sum = 0.0;
        for (i, n) in self.bins.iter().enumerate() {
            sum += n;
            if sum >= q * self.total {
                return 10f64.powf(Self::LOG_MIN + i as f64 / Self::PER_DECADE);
            }
        }
        f64::INFINITY
    }

    fn merge(&mut self, other: &Self) {
        self.bins
            .iter_mut()
            .zip(&other.bins)
            .for_each(|(a, b)| *a += b);
        self.total += other.total;
    }
}

/// The deviations of the calibration table and the fraction of a normal distribution
/// within each: 50 %, 68.3 %, 90 %, 95.4 %.
pub const CALIBRATION_Z: [(f64, f64); 4] = [
    (0.674_49, 50.0),
    (1.0, 68.27),
    (1.644_85, 90.0),
    (2.0, 95.45),
];

impl Score {
    /// The `q`-quantile (0..=1) of the per-frame P-MPJPE, mm (NaN without frames): the
    /// nearest rank.
    pub fn frame_quantile(&self, q: f64) -> f64 {
        let mut v: Vec<f64> = self
            .frames_mm
            .iter()
            .copied()
            .filter(|e| e.is_finite())
            .collect();
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
        v[i]
    }

    /// Adds another score's sums (the same method on other cases).
    pub fn merge(&mut self, other: &Self) {
        self.p_mpjpe_mm.merge(&other.p_mpjpe_mm);
        self.error_2d.merge(&other.error_2d);
        self.pck.merge(&other.pck);
        self.seconds_per_frame.merge(&other.seconds_per_frame);
        for (a, m) in &other.per_action {
            self.per_action.entry(a.clone()).or_default().merge(m);
        }
        self.frames_mm.extend_from_slice(&other.frames_mm);
        self.ratios.merge(&other.ratios);
        self.depth_ratios.merge(&other.depth_ratios);
        self.lateral_ratios.merge(&other.lateral_ratios);
    }

    /// Adds `|error| / std` of every coordinate of `poses` (`std`: per frame, joint and
    /// axis) against the truth, after each frame's similarity alignment (which scales
    /// the deviations too).
    fn add_calibration(&mut self, poses: &[f64], std: &[f64], truth: &[f64], joints: usize) {
        let n = 3 * joints;
        for ((pred, truth), std) in poses
            .chunks_exact(n)
            .zip(truth.chunks_exact(n))
            .zip(std.chunks_exact(n))
        {
            let aligned = metrics::procrustes_align(pred, truth, false);
            let spread = |v: &[f64]| {
                let mut c = [0.0; 3];
                for q in v.chunks_exact(3) {
                    (0..3).for_each(|i| c[i] += q[i] / joints as f64);
                }
                v.chunks_exact(3)
                    .map(|q| (0..3).map(|i| (q[i] - c[i]).powi(2)).sum::<f64>())
                    .sum::<f64>()
                    .sqrt()
            };
            let scale = spread(&aligned) / spread(pred);
            if !scale.is_finite() {
                continue;
            }
            for i in 0..n {
                let e = (aligned[i] - truth[i]).abs();
                self.ratios.add(e / (std[i] * scale));
                if i % 3 == 2 {
                    self.depth_ratios.add(e / (std[i] * scale));
                } else {
                    self.lateral_ratios.add(e / (std[i] * scale));
                }
            }
        }
    }

    /// Scores poses of `frames` frames against the truth: the mean and every frame's
    /// P-MPJPE, weighted by frame.
    fn add_poses(&mut self, poses: &[f64], truth: &[f64], joints: usize, action: &str) -> f64 {
        let n = 3 * joints;
        let start = self.frames_mm.len();
        for (pred, truth) in poses.chunks_exact(n).zip(truth.chunks_exact(n)) {
            self.frames_mm
                .push(1000.0 * metrics::p_mpjpe(pred, truth, joints));
        }
        let frames = self.frames_mm.len() - start;
        let e = self.frames_mm[start..].iter().sum::<f64>() / frames.max(1) as f64;
        self.p_mpjpe_mm.add(e, frames as f64);
        self.per_action
            .entry(action.to_string())
            .or_default()
            .add(e, frames as f64);
        e
    }
}

/// The results of one dictionary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DictionaryResults {
    /// Label of the dictionary.
    pub label: String,
    /// Table 1: (camera, method) -> score; camera "static" or "orbit", method "init" or
    /// "algorithm 1".
    pub given_2d: BTreeMap<(String, String), Score>,
    /// Table 3: method ("init (arg-max)", "EM", "EM, no smoothness") -> score.
    pub heatmaps: Vec<(String, Score)>,
    /// Frames evaluated.
    pub frames: usize,
    /// Sequences evaluated.
    pub cases: usize,
}

impl DictionaryResults {
    /// Adds the results of the same dictionary and model on other cases.
    pub fn merge(&mut self, other: &Self) {
        for (key, sc) in &other.given_2d {
            self.given_2d.entry(key.clone()).or_default().merge(sc);
        }
        for (m, sc) in &other.heatmaps {
            match self.heatmaps.iter_mut().find(|(n, _)| n == m) {
                Some((_, mine)) => mine.merge(sc),
                None => self.heatmaps.push((m.clone(), sc.clone())),
            }
        }
        self.frames += other.frames;
        self.cases += other.cases;
    }
}

fn timed(
    f: impl FnOnce() -> Result<Estimate, EstimateError>,
) -> Result<(Estimate, f64), EstimateError> {
    let start = Instant::now();
    let e = f()?;
    Ok((e, start.elapsed().as_secs_f64()))
}

/// What a method gives for a case's frames: poses, the 2D joints it fitted and its
/// reprojection.
#[derive(Debug, Clone, Default)]
struct Output {
    poses: Vec<f64>,
    keypoints: Vec<f64>,
    projected: Vec<f64>,
    /// Standard deviation of each pose coordinate (the poses' units, `[x, y, z]` per
    /// joint, frame-major); empty when the method gives none (the batch methods).
    std: Vec<f64>,
    /// Frames the method gave nothing for (the sliding window skips frames without
    /// evidence).
    filled: Vec<bool>,
}

impl From<Estimate> for Output {
    fn from(e: Estimate) -> Self {
        let f = e.fits.len();
        Self {
            poses: e.poses,
            keypoints: e.keypoints,
            projected: e.projected,
            std: Vec::new(),
            filled: vec![true; f],
        }
    }
}

impl Output {
    fn empty(p: usize, f: usize) -> Self {
        Self {
            poses: vec![0.0; 3 * p * f],
            keypoints: vec![0.0; 2 * p * f],
            projected: vec![0.0; 2 * p * f],
            std: vec![0.0; 3 * p * f],
            filled: vec![false; f],
        }
    }

    fn set_frame(&mut self, t: usize, pose: &[f64], projected: &[f64], std: &[f64]) {
        let (n3, n2) = (pose.len(), projected.len());
        self.std[t * n3..(t + 1) * n3].copy_from_slice(std);
        self.poses[t * n3..(t + 1) * n3].copy_from_slice(pose);
        self.projected[t * n2..(t + 1) * n2].copy_from_slice(projected);
        self.keypoints[t * n2..(t + 1) * n2].copy_from_slice(projected);
        self.filled[t] = true;
    }

    /// Gives each frame without an estimate the nearest earlier one's (or later, at the
    /// start).
    fn fill_forward(&mut self) {
        let f = self.filled.len();
        let Some(first) = self.filled.iter().position(|&x| x) else {
            return;
        };
        let (n3, n2) = (self.poses.len() / f, self.projected.len() / f);
        let mut last = first;
        for t in 0..f {
            if self.filled[t] {
                last = t;
                continue;
            }
            self.poses.copy_within(last * n3..(last + 1) * n3, t * n3);
            self.projected
                .copy_within(last * n2..(last + 1) * n2, t * n2);
            self.keypoints
                .copy_within(last * n2..(last + 1) * n2, t * n2);
            self.std.copy_within(last * n3..(last + 1) * n3, t * n3);
        }
    }
}

/// Scores one dictionary case by case (so that cases need not be held in memory).
#[derive(Debug, Clone)]
pub struct Evaluator {
    estimator: Estimator,
    flat: Estimator,
    window: WindowEstimator,
    pck_threshold: f64,
    results: DictionaryResults,
    estimates: Vec<FrameEstimate>,
}

/// The batch heat-map methods of Table 3, in order; the sliding window's rows
/// ([`window_methods`]) follow them.
pub const HEATMAP_METHODS: [&str; 3] = ["init (arg-max)", "EM", "EM, no smoothness"];

/// The names of the sliding window's rows: its refined (lag L) and newest (lag 0)
/// estimates.
pub fn window_methods(settings: &StreamSettings) -> [String; 2] {
    [
        format!("window, lag {}", settings.lag),
        "window, lag 0".to_string(),
    ]
}

impl Evaluator {
    /// An evaluator of `dict` under `params` (and the same without smoothness, and the
    /// sliding window with its default settings).
    pub fn new(
        label: &str,
        dict: &Dictionary,
        params: &Params,
        settings: &Settings,
    ) -> Result<Self, EstimateError> {
        let estimator = Estimator::new(dict.clone(), params.clone())?;
        let stream = StreamSettings {
            outputs: Outputs::Both,
            ..StreamSettings::default()
        };
        let names = HEATMAP_METHODS
            .iter()
            .map(|m| m.to_string())
            .chain(window_methods(&stream));
        Ok(Self {
            window: WindowEstimator::new(estimator.clone(), stream)?,
            estimator,
            flat: Estimator::new(dict.clone(), params.clone().without_smoothness())?,
            pck_threshold: settings.pck_threshold,
            results: DictionaryResults {
                label: label.to_string(),
                heatmaps: names.map(|m| (m, Score::default())).collect(),
                ..Default::default()
            },
            estimates: Vec::new(),
        })
    }

    /// Runs every method on one case and adds its scores.
    pub fn add(&mut self, case: &Case) -> Result<(), EstimateError> {
        let p = case.pinhole.joints;
        let f = case.pinhole.frames as f64;
        for (camera, view) in [("static", &case.still), ("orbit", &case.orbit)] {
            let kp = Keypoints {
                joints: p,
                xy: view.image_2d.clone(),
                confidence: None,
            };
            for (method, run) in [
                ("init", timed(|| self.estimator.initialise_keypoints(&kp))?),
                ("algorithm 1", timed(|| self.estimator.lift_keypoints(&kp))?),
            ] {
                let s = self
                    .results
                    .given_2d
                    .entry((camera.to_string(), method.to_string()))
                    .or_default();
                s.add_poses(&run.0.poses, &view.camera_3d, p, &case.action);
                s.seconds_per_frame.add(run.1 / f, f);
            }
        }
        let maps = &case.maps.maps;
        let mut runs: Vec<(Output, f64)> = [
            timed(|| self.estimator.initialise_heatmaps(maps))?,
            timed(|| self.estimator.lift_heatmaps(maps))?,
            timed(|| self.flat.lift_heatmaps(maps))?,
        ]
        .into_iter()
        .map(|(e, s)| (Output::from(e), s))
        .collect();
        runs.extend(self.stream(maps)?);
        let to_256 = 256.0 / maps.height as f64;
        for (i, (est, seconds)) in runs.iter().enumerate() {
            let s = &mut self.results.heatmaps[i].1;
            s.add_poses(&est.poses, &case.pinhole.camera_3d, p, &case.action);
            if !est.std.is_empty() {
                s.add_calibration(&est.poses, &est.std, &case.pinhole.camera_3d, p);
            }
            // The baseline's 2D answer is the arg-max itself; the others' is the model's
            // reprojection.
            let xy = if i == 0 {
                &est.keypoints
            } else {
                &est.projected
            };
            s.error_2d
                .add(to_256 * metrics::mean_error_2d(xy, &case.maps.truth), f);
            let pck = metrics::pck(xy, &case.maps.truth, self.pck_threshold / to_256);
            s.pck.add(100.0 * pck, f);
            s.seconds_per_frame.add(seconds / f, f);
        }
        self.results.frames += case.pinhole.frames;
        self.results.cases += 1;
        Ok(())
    }

    /// The sliding window over a case's heat maps, frame by frame at 30 frames/s: its
    /// refined and its newest estimates, each as an [`Estimate`] of every frame (poses
    /// and reprojections), and the time of the whole run.
    fn stream(&mut self, maps: &HeatMapSequence) -> Result<[(Output, f64); 2], EstimateError> {
        let (p, f) = (maps.joints, maps.frames);
        let mut refined = Output::empty(p, f);
        let mut newest = Output::empty(p, f);
        self.window.reset();
        self.estimates.clear();
        let start = Instant::now();
        for t in 0..f {
            let frame = FrameMaps::of(maps, t, t as u64, t as i64 * 33_333_333);
            self.window.push(&frame, &mut self.estimates)?;
        }
        self.window.finish(&mut self.estimates);
        let seconds = start.elapsed().as_secs_f64();
        // Each frame's refined estimate is the one made latest (the lag L one, or the
        // last owed when the track ended); a frame without evidence keeps no pose and
        // is scored by the nearest earlier one.
        let mut best_lag = vec![None; f];
        for e in &self.estimates {
            let t = usize::try_from(e.sequence).unwrap_or(usize::MAX);
            if t >= f {
                continue;
            }
            if e.lag == 0 {
                newest.set_frame(t, &e.pose, &e.projected, &e.pose_std);
            }
            if best_lag[t].is_none_or(|l| e.lag >= l) {
                best_lag[t] = Some(e.lag);
                refined.set_frame(t, &e.pose, &e.projected, &e.pose_std);
            }
        }
        for est in [&mut refined, &mut newest] {
            est.fill_forward();
        }
        Ok([(refined, seconds), (newest, seconds)])
    }

    /// The scores so far.
    pub fn results(&self) -> &DictionaryResults {
        &self.results
    }
}

/// Runs every method of the tables with one dictionary over the cases.
pub fn evaluate(
    label: &str,
    dict: &Dictionary,
    params: &Params,
    cases: &[Case],
    settings: &Settings,
) -> Result<DictionaryResults, EstimateError> {
    let mut ev = Evaluator::new(label, dict, params, settings)?;
    for case in cases {
        ev.add(case)?;
    }
    Ok(ev.results)
}

/// The markdown tables of the results.
pub fn markdown(results: &[DictionaryResults], settings: &Settings) -> String {
    let mut s = String::new();
    let (cases, frames) = results.first().map_or((0, 0), |r| (r.cases, r.frames));
    let _ = writeln!(
        s,
        "{} sequences: {cases}, {frames} frames (first {} frames of each file at most), \
each subject scaled to a mean bone length of {} m.\n",
        if settings.training {
            "Training"
        } else {
            "Held-out"
        },
        settings.max_frames,
        settings.limb_length
    );
    let _ = writeln!(
        s,
        "## Table 1: given 2D joints, P-MPJPE (mm)\n\nOrthographic projection; a static camera and one orbiting at {} deg/s.\n",
        settings.orbit_deg_per_s
    );
    let _ = writeln!(
        s,
        "| dictionary | static: single frame | static: Algorithm 1 | orbit: single frame | orbit: Algorithm 1 |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|");
    for r in results {
        let g = |c: &str, m: &str| {
            r.given_2d
                .get(&(c.to_string(), m.to_string()))
                .map_or(f64::NAN, |s| s.p_mpjpe_mm.get())
        };
        let _ = writeln!(
            s,
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} |",
            r.label,
            g("static", "init"),
            g("static", "algorithm 1"),
            g("orbit", "init"),
            g("orbit", "algorithm 1")
        );
    }
    let e = &settings.errors;
    let _ = writeln!(
        s,
        "\n## Table 3: heat maps\n\nPinhole camera at {} m, focal {} px; {}x{} heat maps in a square crop ({}x the body's extent). \
Error model: localisation noise {} cells, blob {} cells, swaps {}/frame/pair, occlusions {}/frame/joint, missing {}/frame/joint, \
episodes of {} frames, background {}. 2D error and PCK@{} px are in pixels of a 256-pixel crop; the single-frame row scores \
the arg-max itself, the others the model's reprojection.\n",
        settings.camera.distance,
        settings.camera.focal,
        e.size[0],
        e.size[1],
        settings.margin,
        e.noise,
        e.blob,
        e.swap_rate,
        e.occlusion_rate,
        e.missing_rate,
        e.episode_frames,
        e.background,
        settings.pck_threshold
    );
    let _ = writeln!(
        s,
        "| dictionary | method | 3D P-MPJPE (mm) | median / 90th percentile frame (mm) | 2D error (px) | PCK@{} (%) | ms/frame |",
        settings.pck_threshold
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|");
    for r in results {
        for (m, sc) in &r.heatmaps {
            let _ = writeln!(
                s,
                "| {} | {} | {:.1} | {:.1} / {:.1} | {:.2} | {:.1} | {:.2} |",
                r.label,
                m,
                sc.p_mpjpe_mm.get(),
                sc.frame_quantile(0.5),
                sc.frame_quantile(0.9),
                sc.error_2d.get(),
                sc.pck.get(),
                1000.0 * sc.seconds_per_frame.get()
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Uncertainty: reliability of the per-joint standard deviations\n\nThe fraction of pose \
coordinates (x, y, z of every joint, after the similarity alignment of P-MPJPE, which scales the \
deviations too) whose error lies within z standard deviations, against a normal distribution's. \
Methods without deviations are left out.\n"
    );
    let mut heads: Vec<String> = CALIBRATION_Z
        .iter()
        .map(|(z, nominal)| format!("within {z:.2} std (normal: {nominal:.1} %)"))
        .collect();
    heads.push("x, y: within 1 / 2 std".into());
    heads.push("z: within 1 / 2 std".into());
    heads.push("factor on x, y / z std for 68.3 % within 1 std".into());
    heads.push("the same for 95.45 % within 2 std".into());
    let _ = writeln!(s, "| dictionary | method | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---|{}", "---:|".repeat(heads.len()));
    for r in results {
        for (m, sc) in &r.heatmaps {
            if sc.ratios.is_empty() {
                continue;
            }
            let mut cells: Vec<String> = CALIBRATION_Z
                .iter()
                .map(|(z, _)| format!("{:.1} %", 100.0 * sc.ratios.within(*z)))
                .collect();
            for h in [&sc.lateral_ratios, &sc.depth_ratios] {
                cells.push(format!(
                    "{:.1} % / {:.1} %",
                    100.0 * h.within(1.0),
                    100.0 * h.within(2.0)
                ));
            }
            for (q, z) in [(0.6827, 1.0), (0.9545, 2.0)] {
                cells.push(format!(
                    "{:.2} / {:.2}",
                    sc.lateral_ratios.scale_for(q) / z,
                    sc.depth_ratios.scale_for(q) / z
                ));
            }
            let _ = writeln!(s, "| {} | {} | {} |", r.label, m, cells.join(" | "));
        }
    }
    let _ = writeln!(
        s,
        "\n## Table 2 style: heat maps, P-MPJPE (mm) per action\n"
    );
    let actions: Vec<String> = results
        .first()
        .and_then(|r| r.heatmaps.first())
        .map(|(_, sc)| {
            sc.per_action
                .keys()
                .filter(|a| settings.actions.is_empty() || settings.actions.contains(a))
                .cloned()
                .collect()
        })
        .unwrap_or_default();
    let _ = writeln!(s, "| dictionary | method | {} |", actions.join(" | "));
    let _ = writeln!(s, "|---|---|{}", "---:|".repeat(actions.len()));
    for r in results {
        for (m, sc) in &r.heatmaps {
            let cells: Vec<String> = actions
                .iter()
                .map(|a| format!("{:.1}", sc.per_action.get(a).map_or(f64::NAN, Mean::get)))
                .collect();
            let _ = writeln!(s, "| {} | {} | {} |", r.label, m, cells.join(" | "));
        }
    }
    let _ = writeln!(
        s,
        "\n## Table 4 style: PCK and time per frame\n\nPCK@{} px (256-pixel crop) on the heat-map sequences; wall time per frame of each stage on one core \
(single frame = the per-frame initialisation alone; EM includes its initialisation).\n",
        settings.pck_threshold
    );
    let _ = writeln!(s, "| dictionary | stage | PCK (%) | ms/frame |");
    let _ = writeln!(s, "|---|---|---:|---:|");
    for r in results {
        for ((camera, method), sc) in &r.given_2d {
            let _ = writeln!(
                s,
                "| {} | given 2D, {camera} camera: {method} | | {:.2} |",
                r.label,
                1000.0 * sc.seconds_per_frame.get()
            );
        }
        for (m, sc) in &r.heatmaps {
            let _ = writeln!(
                s,
                "| {} | heat maps: {m} | {:.1} | {:.2} |",
                r.label,
                sc.pck.get(),
                1000.0 * sc.seconds_per_frame.get()
            );
        }
    }
    s
}
