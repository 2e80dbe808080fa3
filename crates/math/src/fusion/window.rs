//! [`FusedWindow`]: one person seen by several cameras, one pose per frame, streamed.

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::deviation::{DeviationBuffers, deviate, views_offset};
use super::estep::{EStepBuffers, e_step};
use super::extrinsics::ViewResidual;
use super::frame::{Frame, ViewData};
use super::mstep::{self, MStepBuffers};
use super::start::{StartBuffers, start};
use super::{FusedEstimate, FusionSettings, ViewCamera, ViewMaps};
use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::estimator::Estimator;
use crate::heatmaps::{argmax, refined_argmax};
use crate::solver::Params;
use crate::solver::estep::MapMoments;
use crate::solver::init::InitCache;
use posestream_base::Scores;

/// The multi-view EM over a sliding window of one person's frames (module docs of
/// [`super`]).
#[derive(Debug, Clone)]
pub struct FusedWindow {
    dict: Dictionary,
    params: Params,
    gram_max: f64,
    cache: InitCache,
    cameras: Vec<ViewCamera>,
    settings: FusionSettings,
    frames: VecDeque<Frame>,
    spare: Vec<Frame>,
    /// Metres per normalised unit: the person's size.
    metres_per_unit: f64,
    /// The poses' mean bone length, normalised units.
    limb0: f64,
    /// Frames pushed since the whole window's EM last ran.
    since_window: usize,
    estep: EStepBuffers,
    mstep: MStepBuffers,
    /// Each frame's size evidence in the M-step round.
    evidence: Vec<Option<mstep::SizeEvidence>>,
    /// Each camera's residuals against the fused poses ([`super::extrinsics`]).
    residuals: Vec<ViewResidual>,
    scratch: Vec<f64>,
    start: StartBuffers,
    shape: Vec<f64>,
    deviation: DeviationBuffers,
    /// The model's joints of the frames around one put out (the deviations' median).
    around: Vec<Vec<f64>>,
    /// Per joint, the per-axis variance the deviations gave the frame put out.
    variance: Vec<f64>,
}

impl FusedWindow {
    /// A window over `cameras` (a view's index is its place here) with the estimator's
    /// dictionary and E-step parameters.
    pub fn new(
        estimator: &Estimator,
        cameras: Vec<ViewCamera>,
        settings: FusionSettings,
    ) -> Result<Self, EstimateError> {
        settings
            .check()
            .map_err(|e| EstimateError::Parameter(e.to_string()))?;
        for (v, camera) in cameras.iter().enumerate() {
            camera
                .check()
                .map_err(|e| EstimateError::Parameter(format!("camera {v}: {e}")))?;
        }
        let mut dict = estimator.dictionary().clone();
        // The paper's model: the pose linear in the coefficients (the start's and the
        // C-step's rescaling assume it), without a track's shape beyond the bases.
        if dict.has_offset() {
            dict.set_offset(&vec![0.0; 3 * dict.num_joints()]);
        }
        let residuals = vec![ViewResidual::default(); cameras.len()];
        Ok(Self {
            dict,
            params: estimator.params().clone(),
            gram_max: estimator.basis_gram_max(),
            cache: estimator.init_cache().clone(),
            cameras,
            settings,
            frames: VecDeque::new(),
            spare: Vec::new(),
            metres_per_unit: 0.0,
            limb0: 0.0,
            since_window: 0,
            estep: EStepBuffers::default(),
            mstep: MStepBuffers::default(),
            evidence: Vec::new(),
            residuals,
            scratch: Vec::new(),
            start: StartBuffers::default(),
            shape: Vec::new(),
            deviation: DeviationBuffers::default(),
            around: Vec::new(),
            variance: Vec::new(),
        })
    }

    /// The cameras.
    pub fn cameras(&self) -> &[ViewCamera] {
        &self.cameras
    }

    /// Replaces camera `view`'s calibration (new extrinsics from TF, say); the frames
    /// already in the window keep the rays they had.
    pub fn set_camera(&mut self, view: usize, camera: ViewCamera) -> Result<(), EstimateError> {
        camera
            .check()
            .map_err(|e| EstimateError::Parameter(format!("camera {view}: {e}")))?;
        let cameras = self.cameras.len();
        let slot = self.cameras.get_mut(view).ok_or_else(|| {
            EstimateError::Parameter(format!("no camera {view} (the rig has {cameras})"))
        })?;
        *slot = camera;
        // Its residuals were against the calibration it had.
        self.residuals[view] = ViewResidual::default();
        Ok(())
    }

    /// Each camera's residuals against this person's refined fused poses (the model's
    /// joints, before the views' deviations move them), for the check of their extrinsics ([`super::extrinsics::suspects`]; merge several people's).
    pub fn residuals(&self) -> &[ViewResidual] {
        &self.residuals
    }

    /// The person's mean bone length as fitted, metres (0 before the first frame).
    pub fn mean_limb_length(&self) -> f64 {
        self.metres_per_unit * self.limb0
    }

    /// Frames in the window.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True before the first frame and after a reset.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Ends the track: the next frame starts a new one.
    pub fn reset(&mut self) {
        while let Some(f) = self.frames.pop_back() {
            self.spare.push(f);
        }
        self.since_window = 0;
    }

    /// One frame of the person, at `stamp_ns`: the heat maps of every camera that saw
    /// them (any subset of the rig, in any order). A frame no view has evidence in (none
    /// given, or every map zero) is passed over, as a dropped frame. Appends the newest frame's estimate (lag 0) and the estimate of
    /// the frame [`FusionSettings::lag`] back to `out`. A frame not after the last one
    /// is refused; one more than [`FusionSettings::max_gap_seconds`] after it starts a
    /// new track.
    pub fn push(
        &mut self,
        stamp_ns: i64,
        views: &[ViewMaps<'_>],
        out: &mut Vec<FusedEstimate>,
    ) -> Result<(), EstimateError> {
        let p = self.dict.num_joints();
        for (i, v) in views.iter().enumerate() {
            if v.view >= self.cameras.len() {
                return Err(EstimateError::Parameter(format!(
                    "view {} is not a camera of the rig ({} cameras)",
                    v.view,
                    self.cameras.len()
                )));
            }
            if views[..i].iter().any(|o| o.view == v.view) {
                return Err(EstimateError::Parameter(format!(
                    "view {} appears twice in one frame",
                    v.view
                )));
            }
            let cells = v.height.checked_mul(v.width).and_then(|n| n.checked_mul(p));
            if v.height < 2 || v.width < 2 || cells != Some(v.values.len()) {
                return Err(EstimateError::Parameter(format!(
                    "view {}: {} scores for {p} maps of {} x {}",
                    v.view,
                    v.values.len(),
                    v.height,
                    v.width
                )));
            }
            let map = &v.to_image;
            let finite = map.scale.iter().chain(&map.offset).all(|x| x.is_finite());
            if !(finite && map.scale.iter().all(|&x| x > 0.0)) {
                return Err(EstimateError::Parameter(format!(
                    "view {}: the maps' crop must have finite values and a positive size \
                     (scale {:?}, offset {:?})",
                    v.view, map.scale, map.offset
                )));
            }
            if !(v.dt.is_finite() && v.dt.abs() <= 1.0) {
                return Err(EstimateError::Parameter(format!(
                    "view {}: time offset {} s (at most 1 s)",
                    v.view, v.dt
                )));
            }
        }
        if let Some(last) = self.frames.back()
            && stamp_ns <= last.stamp_ns
        {
            return Err(EstimateError::Parameter(format!(
                "frame at {stamp_ns} ns is not after the last one ({} ns)",
                last.stamp_ns
            )));
        }
        let mut frame = self
            .spare
            .pop()
            .unwrap_or_else(|| Frame::new(self.dict.num_bases()));
        frame.stamp_ns = stamp_ns;
        frame.n_views = 0;
        for v in views {
            if frame.views.len() <= frame.n_views {
                frame.views.push(ViewData::new());
            }
            let vd = &mut frame.views[frame.n_views];
            let filled = fill(vd, v, p);
            frame.n_views += 1;
            if let Err(e) = filled {
                self.spare.push(frame);
                return Err(e);
            }
        }
        // The frame is well formed: a long gap before it ends the track.
        if let Some(last) = self.frames.back()
            && seconds_between(last.stamp_ns, stamp_ns) > self.settings.max_gap_seconds
        {
            self.reset();
        }
        if !frame.views().iter().any(|v| v.evidence) {
            // Nobody saw the person: nothing to estimate (a gap, as a dropped frame).
            self.spare.push(frame);
            return Ok(());
        }
        self.bridge(&mut frame);
        if self.frames.is_empty() {
            let s = &self.settings;
            let started = start(
                &self.dict,
                &self.cache,
                &self.params,
                &self.cameras,
                (s.mean_limb_length, s.size_range, s.peak_threshold),
                &mut frame,
                &mut self.start,
            );
            let Some(started) = started else {
                self.spare.push(frame);
                return Ok(());
            };
            self.metres_per_unit = started.metres_per_unit;
            self.limb0 = started.limb0;
            self.frames.push_back(frame);
            for _ in 0..self.settings.start_rounds {
                self.m_step(0, 1, 1);
            }
        } else {
            // From the frame before. (Not moved on at its velocity: seen by one view,
            // the velocity along that view's rays is the estimates' own drift, and
            // extrapolating it ran away: 0.5 m off within 2 s on `scenes --rooms`.)
            let last = self.frames.back().expect("not empty");
            frame
                .pose
                .coefficients
                .copy_from_slice(&last.pose.coefficients);
            frame.pose.rotation = last.pose.rotation;
            frame.pose.translation = last.pose.translation;
            // Where two or more views triangulate the body, from there (its shape and
            // turn the frame before's): a body moving fast (a dash, 0.2 m a frame) is
            // not where it was, and the E-step's pull towards the projection would keep
            // it back (this is the views' evidence, not an extrapolation).
            frame.pose.joints_into(
                &self.dict,
                self.metres_per_unit,
                &mut self.shape,
                &mut self.scratch,
            );
            if let Some(shift) = views_offset(
                &self.settings.deviation,
                &self.cameras,
                frame.views(),
                &self.scratch,
                &mut self.deviation,
            ) {
                frame.pose.translation += shift;
            }
            self.frames.push_back(frame);
        }
        while self.frames.len() > self.settings.size {
            let f = self.frames.pop_front().expect("not empty");
            self.spare.push(f);
        }
        let n = self.frames.len();
        let s = &self.settings;
        let (local, local_iterations) = (s.local_frames.min(n), s.local_iterations);
        self.em(n - local, n, local_iterations);
        self.since_window += 1;
        if self.since_window >= self.settings.window_every && n > local {
            self.since_window = 0;
            // The oldest frame stays fixed: the anchor of the frames after it.
            self.em(1.min(n - 1), n, self.settings.em_iterations);
        }
        if !self.frames.iter().all(|f| f.pose.is_finite()) {
            // Nothing should get here (every input is checked); if something does, the
            // track starts again rather than carry it on.
            self.reset();
            return Err(EstimateError::Parameter(
                "the fused pose is not finite: the track starts again".into(),
            ));
        }
        self.emit(n - 1, out);
        let lag = self.settings.lag;
        if lag > 0 && n > lag {
            self.emit(n - 1 - lag, out);
        }
        Ok(())
    }

    /// Adds to `frame` the views of the frame before (sent, not bridged themselves) of
    /// the cameras `frame` has none of, at their time offsets from it, when the frames
    /// are at most [`FusionSettings::bridge_seconds`] apart: a camera at half the rate,
    /// or one that dropped a frame, still constrains the depth (the E-step moves the body
    /// by its velocity over the offset).
    fn bridge(&mut self, frame: &mut Frame) {
        let Some(last) = self.frames.back() else {
            return;
        };
        let gap = seconds_between(last.stamp_ns, frame.stamp_ns);
        if gap > self.settings.bridge_seconds {
            return;
        }
        for old in last.views() {
            let dt = old.dt - gap;
            let present = frame.views().iter().any(|v| v.view == old.view);
            if old.bridged || present || !old.evidence || dt.abs() > 1.0 {
                continue;
            }
            if frame.views.len() <= frame.n_views {
                frame.views.push(ViewData::new());
            }
            let vd = &mut frame.views[frame.n_views];
            vd.view = old.view;
            vd.dt = dt;
            vd.to_image = old.to_image;
            vd.height = old.height;
            vd.width = old.width;
            vd.maps.clone_from(&old.maps);
            vd.moments.clone_from(&old.moments);
            vd.peaks.clone_from(&old.peaks);
            vd.evidence = old.evidence;
            vd.bridged = true;
            frame.n_views += 1;
        }
    }

    /// The body's velocity at frame `t` (metres per second): the central difference of
    /// its neighbours; near the newest frame, the difference of the frames before.
    fn velocity(&self, t: usize) -> Vector3<f64> {
        let n = self.frames.len();
        // The newest frame's position is the frame before's until its first M-step: the
        // two frames before the newest are the last ones to difference.
        let (a, b) = if t + 2 < n && t > 0 {
            (t - 1, t + 1)
        } else if t + 1 == n && t >= 2 {
            (t.saturating_sub(3), t - 1)
        } else if t + 2 == n && t >= 1 {
            (t.saturating_sub(2), t)
        } else {
            return Vector3::zeros();
        };
        let (fa, fb) = (&self.frames[a], &self.frames[b]);
        let dt = seconds_between(fa.stamp_ns, fb.stamp_ns);
        if dt > 0.0 {
            (fb.pose.translation - fa.pose.translation) / dt
        } else {
            Vector3::zeros()
        }
    }

    /// `iterations` EM iterations over frames `a..b`.
    fn em(&mut self, a: usize, b: usize, iterations: usize) {
        for _ in 0..iterations {
            for t in a..b {
                let v = self.velocity(t);
                e_step(
                    &self.dict,
                    &self.params,
                    &self.cameras,
                    self.metres_per_unit,
                    &v,
                    &mut self.frames[t],
                    &mut self.estep,
                );
            }
            self.m_step(a, b, self.settings.rounds);
        }
    }

    /// `rounds` M-step rounds over frames `a..b` (rays as the last E-step left them).
    fn m_step(&mut self, a: usize, b: usize, rounds: usize) {
        let s = &self.settings;
        let weights = (s.alpha, s.beta, s.apg_steps, self.limb0);
        let prior = s.mean_limb_length / self.limb0;
        let range = s.size_range;
        for _ in 0..rounds {
            let (mut scale, mut weight) = (0.0, 0.0);
            self.evidence.clear();
            for t in a..b {
                let e = mstep::rigid(
                    &self.dict,
                    self.metres_per_unit,
                    &mut self.frames[t],
                    &mut self.mstep,
                );
                if let Some(e) = e {
                    scale += e.scale * e.weight;
                    weight += e.weight;
                }
                self.evidence.push(e);
            }
            let before = self.metres_per_unit;
            if weight > 0.0 && prior.is_finite() && prior > 0.0 {
                let m = before * scale / weight;
                self.metres_per_unit = m.clamp(prior / range, prior * range);
            }
            // Each frame two views saw placed with the size now applied.
            let applied = self.metres_per_unit / before;
            for (t, e) in (a..b).zip(&self.evidence) {
                if let Some(e) = e {
                    let f = &mut self.frames[t];
                    f.pose.translation = e.translation(&f.pose.rotation, applied);
                }
            }
            for t in a..b {
                self.smooth_depth(t);
            }
            mstep::c_step(
                &self.dict,
                self.gram_max,
                self.metres_per_unit,
                weights,
                &mut self.frames,
                a,
                b,
                &mut self.mstep,
            );
        }
    }

    /// A frame one view saw: its depth along that view (what one view sees least) moved
    /// towards its neighbours' ([`FusionSettings::depth_smoothing`]).
    fn smooth_depth(&mut self, t: usize) {
        let lambda = self.settings.depth_smoothing;
        let f = &self.frames[t];
        if lambda <= 0.0 || f.usable_views() != 1 {
            return;
        }
        let Some(origin) = f.views().iter().find(|v| v.usable()).map(|v| v.origin) else {
            return;
        };
        let (mut sum, mut n) = (Vector3::zeros(), 0.0);
        for nb in [t.wrapping_sub(1), t + 1] {
            if let Some(o) = self.frames.get(nb) {
                sum += o.pose.translation;
                n += 1.0;
            }
        }
        if n == 0.0 {
            return;
        }
        let here = f.pose.translation;
        let Some(u) = (here - origin).try_normalize(1e-9) else {
            return;
        };
        let towards = u.dot(&(sum / n - here)) * lambda / (1.0 + lambda);
        self.frames[t].pose.translation = here + u * towards;
    }

    /// Moves the joints put out for frame `t` (its model's, `joints`) off the
    /// dictionary's shape where its views agree ([`super::deviation`]), the median over
    /// the frames within `deviation.frames / 2` of it that the window holds.
    fn deviate(&mut self, t: usize, joints: &mut [f64]) {
        self.variance.clear();
        self.variance.resize(joints.len() / 3, f64::NAN);
        if self.settings.deviation.joint_std <= 0.0 {
            return;
        }
        let m = self.metres_per_unit;
        let half = self.settings.deviation.frames / 2;
        let first = t.saturating_sub(half);
        let last = (t + half).min(self.frames.len() - 1);
        if self.around.len() < last + 1 - first {
            self.around.resize_with(last + 1 - first, Vec::new);
        }
        for (k, frame) in (first..=last).zip(self.around.iter_mut()) {
            self.frames[k]
                .pose
                .joints_into(&self.dict, m, &mut self.shape, frame);
        }
        let frames = &self.frames;
        let around = &self.around;
        deviate(
            &self.settings.deviation,
            &self.cameras,
            last + 1 - first,
            |k| (&around[k][..], frames[first + k].views()),
            t - first,
            joints,
            &mut self.variance,
            &mut self.deviation,
        );
    }

    /// The estimate of frame `t`.
    fn emit(&mut self, t: usize, out: &mut Vec<FusedEstimate>) {
        let m = self.metres_per_unit;
        let lag = self.frames.len() - 1 - t;
        let f = &self.frames[t];
        let mut e = FusedEstimate {
            stamp_ns: f.stamp_ns,
            lag,
            joints: Vec::with_capacity(3 * self.dict.num_joints()),
            joint_std: Vec::with_capacity(self.dict.num_joints()),
            views: Vec::new(),
            monocular: f.usable_views() < 2,
            mean_limb_length: m * self.limb0,
        };
        f.pose
            .joints_into(&self.dict, m, &mut self.shape, &mut e.joints);
        // The cameras' own views (not those bridged from the frame before).
        let sent = |v: &&ViewData| v.usable() && !v.bridged;
        if lag == self.settings.lag && f.views().iter().filter(sent).count() >= 3 {
            for vd in f.views().iter().filter(sent) {
                let r = residual(&self.cameras[vd.view], vd, &e.joints, &mut self.scratch);
                self.residuals[vd.view].add(r);
            }
        }
        e.views
            .extend(f.views().iter().filter(|v| v.usable()).map(|v| v.view));
        // Where the views agree, they win over the dictionary's shape.
        self.deviate(t, &mut e.joints);
        let f = &self.frames[t];
        let scale_std = self.settings.scale_std;
        for j in 0..self.dict.num_joints() {
            // Each view's 2D spread at the joint's depth (metres per axis), combined;
            // seen by one view, depth as unknown as the size.
            let mut information = 0.0;
            let mut depth: f64 = 0.0;
            for vd in f.views() {
                let w = vd.weights.get(j).copied().unwrap_or(0.0);
                if w <= 0.0 {
                    continue;
                }
                let cam = &self.cameras[vd.view];
                let z = vd.depth[j].max(1e-3);
                // At least a hundredth of a pixel's spread.
                let s = (0.5 * vd.variance[j]).sqrt().max(0.01) * z / cam.intrinsics.focal();
                information += 1.0 / (s * s);
                depth = depth.max(z);
            }
            let mut var = if information > 0.0 {
                1.0 / information
            } else {
                f64::INFINITY
            };
            if e.monocular {
                var += (depth * scale_std).powi(2);
            }
            // Seen by views and deviated: the deviations' variance (the views' spreads,
            // their disagreement, the prior).
            let deviated = self.variance.get(j).copied().unwrap_or(f64::NAN);
            if deviated.is_finite() && !e.monocular {
                var = deviated;
            }
            e.joint_std.push(var.sqrt());
        }
        out.push(e);
    }
}

/// Copies one view's maps into `vd` (clipped at 0) with their moments and each map's
/// refined peak (a new frame's start and the deviations' evidence).
fn fill(vd: &mut ViewData, v: &ViewMaps<'_>, p: usize) -> Result<(), EstimateError> {
    vd.view = v.view;
    vd.dt = v.dt;
    vd.bridged = false;
    vd.to_image = v.to_image;
    vd.height = v.height;
    vd.width = v.width;
    let n = v.height * v.width;
    let bad = match v.values {
        Scores::F32(values) => values.iter().position(|x| !x.is_finite()),
        Scores::U8 { scale, .. } => (!(scale.is_finite() && scale > 0.0)).then_some(0),
    };
    if let Some(at) = bad {
        return Err(EstimateError::Parameter(format!(
            "view {}: the map of joint {} holds a value that is not finite",
            v.view,
            at / n
        )));
    }
    vd.maps.resize(v.values.len(), 0.0);
    v.values.clipped_into(&mut vd.maps);
    // u8 scores times a huge scale overflow f32.
    if let Some(at) = vd.maps.iter().position(|x| !x.is_finite()) {
        return Err(EstimateError::Parameter(format!(
            "view {}: the map of joint {} overflows (scale too large)",
            v.view,
            at / n
        )));
    }
    vd.moments.clear();
    vd.moments
        .extend((0..p).map(|j| MapMoments::new(&vd.maps[j * n..(j + 1) * n], v.width)));
    vd.evidence = vd.moments.iter().any(|m| m.h > 0.0);
    // Each map's peak, to a fraction of a cell (the deviations' evidence).
    vd.peaks.clear();
    if n > 0 {
        vd.peaks.extend(vd.maps.chunks_exact(n).map(|map| {
            let (x, y, score) = refined_argmax(map, v.width);
            let [u, w] = v.to_image.apply(x, y);
            [u, w, f64::from(score)]
        }));
    }
    Ok(())
}

/// A view's residual against fused joints (`[x, y, z]` per joint, world): the median
/// distance of their projections from its heat maps' peaks (the raw evidence, not the
/// E-step's, which leans towards the projection), over its box's size.
fn residual(camera: &ViewCamera, vd: &ViewData, joints: &[f64], scratch: &mut Vec<f64>) -> f64 {
    let box_pixels = vd.to_image.mean_scale() * vd.height.max(vd.width) as f64;
    let n = vd.height * vd.width;
    scratch.clear();
    for (j, q) in joints.chunks_exact(3).enumerate() {
        if vd.weights.get(j).is_none_or(|&w| w <= 0.0) {
            continue;
        }
        let Some(([u, v], _)) = camera.project(&Vector3::new(q[0], q[1], q[2])) else {
            continue;
        };
        let (x, y, peak) = argmax(&vd.maps[j * n..(j + 1) * n], vd.width);
        if peak <= 0.0 {
            continue;
        }
        let [ku, kv] = vd.to_image.apply(x, y);
        scratch.push((u - ku).hypot(v - kv));
    }
    if scratch.len() < 3 || box_pixels <= 0.0 {
        return f64::NAN;
    }
    let mid = scratch.len() / 2;
    let (_, median, _) = scratch.select_nth_unstable_by(mid, f64::total_cmp);
    *median / box_pixels
}

/// Seconds from `a` to `b` (nanoseconds), without overflow.
fn seconds_between(a: i64, b: i64) -> f64 {
    (i128::from(b) - i128::from(a)) as f64 * 1e-9
}
