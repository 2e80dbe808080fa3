//! Running the methods on the cases: the [`Evaluator`] of one dictionary, case by case,
//! and [`evaluate`] over them all.

use std::time::Instant;

use super::{Case, DictionaryResults, Score, Settings};
use posestream_math::accuracy;
use posestream_math::dictionary::Dictionary;
use posestream_math::error::EstimateError;
use posestream_math::estimator::{Estimate, Estimator, Keypoints};
use posestream_math::heatmaps::HeatMapSequence;
use posestream_math::solver::Params;
use posestream_math::streaming::{
    Emitted, FrameEstimate, FrameMaps, StreamSettings, WindowEstimator,
};

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
            outputs: Emitted::Both,
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
                .add(to_256 * accuracy::mean_error_2d(xy, &case.maps.truth), f);
            let pck = accuracy::pck(xy, &case.maps.truth, self.pck_threshold / to_256);
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
