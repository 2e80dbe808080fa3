//! The streaming estimator: EM over a sliding [`Window`](crate::solver::Window) of the
//! most recent frames, one frame in, estimates out with bounded lag.
//!
//! For each new frame of heat maps, [`WindowEstimator::push`]:
//! 1. checks where it falls: the next frame, a short gap (frames dropped: carry on), a
//!    long gap or a restart of the detector's numbering (end the track: emit the
//!    estimates still owed, start again), or late / out of order (drop it and count it);
//! 2. initialises it from its maps' arg-max, as the batch EM initialises every frame
//!    ([`StreamSettings::warm_start`] copies the previous frame's fit instead: measured
//!    worse, because a track then keeps its first frame's depth ambiguity); with the
//!    swap model on ([`Params::swap_prior`](crate::solver::Params::swap_prior)), a
//!    left/right pair whose peaks lie [`SWAP_MARGIN`](crate::estimator::SWAP_MARGIN)
//!    times nearer the previous frame's peaks (as put back) swapped than as they are is
//!    swapped back first (a detector's swap; for at most
//!    [`MAX_SWAP_FRAMES`](crate::estimator::MAX_SWAP_FRAMES) frames running, and not
//!    when most pairs are: a whole-body flip of the detector's, the maps stand);
//! 3. if the window is full, freezes its oldest frame: that frame leaves the window and
//!    becomes the *anchor*, a fixed neighbour whose coefficients and rotation keep
//!    pulling the first frame of the window through the smoothness terms
//!    ([`em::run_anchored`]);
//! 4. runs [`StreamSettings::local_iterations`] EM iterations over the newest
//!    [`StreamSettings::local_frames`] frames (anchored on the frame before them), which
//!    is what makes the lag-0 estimate good, then (when configured; off by default)
//!    [`StreamSettings::lag_iterations`] over the newest `lag + 1` frames, so that the
//!    lagged estimate has been refined together with every frame after it, and, every
//!    [`StreamSettings::window_every`] frames,
//!    [`StreamSettings::em_iterations`] over the whole window, in
//!    [`StreamSettings::window_parts`] parts on consecutive frames;
//! 5. emits the estimate of the newest frame (lag 0) and/or of the frame `lag` frames
//!    back, which has seen `lag` more frames of evidence ([`StreamSettings::outputs`]).
//!
//! The math is the batch EM's ([`crate::solver::em`]); nothing here knows about
//! transports. Once the window has filled, the solver's buffers are reused, and
//! [`WindowEstimator::push_into`] writes the estimates over those of the previous frame:
//! a warm update allocates nothing (`tests/allocations.rs` counts).

use nalgebra::Vector3;

use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::estimator::Estimator;
use crate::solver::adapt::ShapeStats;
use crate::solver::em::{self, EmWorkspace, MapSource};
use crate::solver::init::InitWorkspace;
use crate::solver::normalise::heatmap_scale;
use crate::solver::{Anchors, FrameFit, Observations, Params};
pub use posestream_base::Scores;

mod frames;
mod ring;
mod settings;
#[cfg(test)]
mod tests;

pub use frames::{CheckedFrame, Estimates, FrameEstimate, FrameMaps, StreamCounters, TrackState};
use ring::{MapRing, Slot, Sweep, Tail, Which};
pub use settings::{Emitted, StreamSettings};

/// EM over a sliding window of heat-map frames: the core of the estimator node.
#[derive(Debug, Clone)]
pub struct WindowEstimator {
    estimator: Estimator,
    settings: StreamSettings,
    /// The estimator's parameters with the EM capped for the newest frames, and for the
    /// whole window.
    local_params: Params,
    lag_params: Params,
    window_params: Params,
    /// The estimator's parameters with the initialisation capped.
    init_params: Params,
    /// Frames since the last EM over the whole window began.
    since_window: usize,
    /// The window EM under way in parts, if any.
    sweep: Option<Sweep>,
    /// Frames that have left the window at its front since the track began.
    dropped: usize,
    /// The window's frames, oldest first, and their fits (same order).
    slots: Vec<Slot>,
    fits: Vec<FrameFit>,
    /// The frozen frame just before the window, if the track has one.
    anchor: Option<FrameFit>,
    maps: MapRing,
    last: Option<(u64, i64)>,
    /// Frames without evidence since the last frame taken (not counted as missing).
    empty_since_last: u64,
    counters: StreamCounters,
    // Buffers.
    obs: Observations,
    one: Observations,
    variance: Vec<f64>,
    shape: Vec<f64>,
    em: EmWorkspace,
    init: InitWorkspace,
    argmax: Vec<f64>,
    /// The track's arg-maxes (normalised units, as put back; each joint where it was
    /// last seen, NaN before), for the initialisation, and per left/right pair the
    /// frames its maps have run swapped against them.
    previous: Vec<f64>,
    swap_runs: Vec<u32>,
    visible: Vec<bool>,
    spare: Vec<FrameFit>,
    /// The evidence of the track's shape beyond the dictionary (frames that left the
    /// window), and the offset it gives ([`crate::solver::adapt`]).
    shape_stats: ShapeStats,
    offset: Vec<f64>,
    /// The estimates of the allocating API ([`WindowEstimator::push`]), cloned out.
    released: Estimates,
}

impl WindowEstimator {
    /// A window over `estimator`'s dictionary and parameters.
    pub fn new(mut estimator: Estimator, settings: StreamSettings) -> Result<Self, EstimateError> {
        settings.validate()?;
        let p = estimator.dictionary().num_joints();
        // A track's shape beyond the dictionary is its own: every window starts without.
        if estimator.dictionary().has_offset() {
            estimator.dictionary_mut().set_offset(&vec![0.0; 3 * p]);
        }
        let capped = |iterations| Params {
            max_em_iterations: iterations,
            admit_per_frame: settings.admit_per_frame,
            ..estimator.params().clone()
        };
        Ok(Self {
            local_params: capped(settings.local_iterations.max(1)),
            lag_params: Params {
                max_em_rounds: settings.lag_rounds,
                ..capped(settings.lag_iterations.max(1))
            },
            window_params: capped(settings.em_iterations),
            init_params: Params {
                max_init_iterations: settings
                    .init_iterations
                    .min(estimator.params().max_init_iterations),
                ..estimator.params().clone()
            },
            since_window: 0,
            sweep: None,
            dropped: 0,
            slots: Vec::with_capacity(settings.size),
            fits: Vec::with_capacity(settings.size),
            anchor: None,
            maps: MapRing::default(),
            last: None,
            empty_since_last: 0,
            counters: StreamCounters::default(),
            obs: Observations::default(),
            one: Observations::new(p, vec![0.0; 2 * p]),
            variance: vec![0.0; p],
            shape: vec![0.0; 3 * p],
            em: EmWorkspace::default(),
            init: InitWorkspace::default(),
            argmax: vec![0.0; 2 * p],
            previous: vec![f64::NAN; 2 * p],
            swap_runs: vec![0; estimator.dictionary().left_right_pairs().len()],
            visible: vec![false; p],
            spare: Vec::new(),
            shape_stats: ShapeStats::new(p),
            offset: vec![0.0; 3 * p],
            released: Estimates::default(),
            estimator,
            settings,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &StreamSettings {
        &self.settings
    }

    /// The dictionary.
    pub fn dictionary(&self) -> &Dictionary {
        self.estimator.dictionary()
    }

    /// The estimator (dictionary and parameters) the window runs.
    pub fn estimator(&self) -> &Estimator {
        &self.estimator
    }

    /// What the window has done so far.
    pub fn counters(&self) -> StreamCounters {
        self.counters
    }

    /// What the window has done so far, after which its counters start again from
    /// zero (a window reused for another track reports only what it did for that one).
    pub fn take_counters(&mut self) -> StreamCounters {
        std::mem::take(&mut self.counters)
    }

    /// Frames in the window now.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// True when no track is running.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Takes one frame; appends the estimates it releases to `out` (oldest first).
    ///
    /// A malformed frame (wrong size, non-finite values) is counted and returned as an
    /// error; the window is unchanged and the stream can go on. Late and out-of-order
    /// frames, and frames without evidence (every map zero), are counted and ignored. A
    /// frame whose maps have another size than the track's ends the track and starts a
    /// new one.
    ///
    /// Each estimate is a new allocation; a service emitting for every frame uses
    /// [`WindowEstimator::push_into`], which reuses them.
    pub fn push(
        &mut self,
        frame: &FrameMaps<'_>,
        out: &mut Vec<FrameEstimate>,
    ) -> Result<(), EstimateError> {
        let checked = self.check_frame(frame)?;
        self.push_checked(frame, checked, out);
        Ok(())
    }

    /// [`WindowEstimator::push`] into reused estimates: appends the estimates the frame
    /// releases to `out` (call [`Estimates::clear`] first to keep only this frame's).
    /// Once the window is full and `out` has held as many estimates, nothing allocates.
    ///
    /// ```
    /// use posestream_math::streaming::{Estimates, FrameMaps, StreamSettings, WindowEstimator};
    /// use posestream_math::skeleton::default_layout;
    /// use posestream_math::{Dictionary, Estimator, Params};
    ///
    /// // A dictionary of 8 bases over the default 17 joints (a real one is loaded from a
    /// // file: `posestream_msgs::formats::LoadDictionary`).
    /// let bases = (0..8 * 3 * 17).map(|i| ((i * 37 % 101) as f64 / 101.0 - 0.5)).collect();
    /// let dict = Dictionary::new(default_layout(), bases, vec![0.0; 3 * 17])?;
    /// let estimator = Estimator::new(dict, Params::default())?;
    /// let mut window = WindowEstimator::new(estimator, StreamSettings::default())?;
    /// let mut out = Estimates::default();
    /// // One frame: 17 maps of 16 x 16, a peak in each.
    /// let mut values = vec![0.0f32; 17 * 256];
    /// for j in 0..17 {
    ///     values[j * 256 + 16 * (4 + j % 8) + 5 + j % 6] = 1.0;
    /// }
    /// let frame = FrameMaps {
    ///     sequence: 0,
    ///     stamp_ns: 0,
    ///     height: 16,
    ///     width: 16,
    ///     values: (&values).into(),
    /// };
    /// out.clear();
    /// window.push_into(&frame, &mut out)?;
    /// assert_eq!(out.len(), 1); // the newest frame at lag 0; lagged ones come later
    /// assert_eq!(out[0].pose.len(), 3 * 17);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn push_into(
        &mut self,
        frame: &FrameMaps<'_>,
        out: &mut Estimates,
    ) -> Result<(), EstimateError> {
        let checked = self.check_frame(frame)?;
        self.push_checked_into(frame, checked, out);
        Ok(())
    }

    /// Checks a frame's sizes and values, as [`WindowEstimator::push`] does first: a
    /// malformed frame is counted and returned as an error, nothing else changes. For a
    /// caller that must know a frame is good before acting on it (the node ends a track
    /// only for a good frame of another track).
    pub fn check_frame(&mut self, frame: &FrameMaps<'_>) -> Result<CheckedFrame, EstimateError> {
        match self.check(frame) {
            Ok(evidence) => Ok(CheckedFrame { evidence }),
            Err(e) => {
                self.counters.malformed += 1;
                Err(e)
            }
        }
    }

    /// [`WindowEstimator::push`] of a frame [`WindowEstimator::check_frame`] passed.
    pub fn push_checked(
        &mut self,
        frame: &FrameMaps<'_>,
        checked: CheckedFrame,
        out: &mut Vec<FrameEstimate>,
    ) {
        self.cloned_out(out, |window, released| {
            window.push_checked_into(frame, checked, released);
        });
    }

    /// Runs `f` into the window's own reused estimates and appends clones of them to
    /// `out`: the allocating API over the reusing one.
    fn cloned_out(
        &mut self,
        out: &mut Vec<FrameEstimate>,
        f: impl FnOnce(&mut Self, &mut Estimates),
    ) {
        let mut released = std::mem::take(&mut self.released);
        released.clear();
        f(self, &mut released);
        out.extend(released.iter().cloned());
        self.released = released;
    }

    /// [`WindowEstimator::push_into`] of a frame [`WindowEstimator::check_frame`] passed.
    pub fn push_checked_into(
        &mut self,
        frame: &FrameMaps<'_>,
        checked: CheckedFrame,
        out: &mut Estimates,
    ) {
        if !checked.evidence {
            // Nothing seen: no estimate, and the frame counts as dropped (a long run of
            // them ends the track as a gap does), though not as missing.
            self.counters.empty += 1;
            self.empty_since_last += 1;
            return;
        }
        if let Some((seq, stamp)) = self.last {
            let late =
                frame.sequence <= seq && seq - frame.sequence <= self.settings.max_gap_frames;
            if late {
                self.counters.late += 1;
                return;
            }
            let gap_seconds = frame.stamp_ns.abs_diff(stamp) as f64 * 1e-9;
            let restart = frame.sequence < seq
                || frame.sequence - seq > self.settings.max_gap_frames
                || gap_seconds > self.settings.max_gap_seconds;
            if restart {
                self.counters.resets += 1;
                self.finish_into(out);
            } else {
                self.counters.missing +=
                    (frame.sequence - seq - 1).saturating_sub(self.empty_since_last);
            }
        }
        self.empty_since_last = 0;
        let geometry = (frame.height, frame.width);
        if (self.maps.height, self.maps.width) != geometry {
            // Maps of another size: the detector changed; the track ends here.
            if !self.slots.is_empty() {
                self.counters.resets += 1;
                self.finish_into(out);
            }
            let p = self.dictionary().num_joints();
            self.maps
                .configure(self.settings.size, p, frame.height, frame.width);
        }
        self.counters.frames += 1;
        self.last = Some((frame.sequence, frame.stamp_ns));
        self.admit(frame);
        self.solve();
        let newest = self.slots.len() - 1;
        let state = if self.slots[newest].age < self.settings.lag as u64 {
            TrackState::Initialising
        } else {
            TrackState::Tracking
        };
        if self.settings.outputs != Emitted::Newest && newest >= self.settings.lag {
            let t = newest - self.settings.lag;
            self.estimate(t, TrackState::Tracking, out.next_slot());
        }
        if self.settings.outputs != Emitted::Lagged {
            self.estimate(newest, state, out.next_slot());
        }
    }

    /// Ends the track: appends the lagged estimates still owed (state
    /// [`TrackState::Lost`], lag smaller than configured) and empties the window.
    pub fn finish(&mut self, out: &mut Vec<FrameEstimate>) {
        self.cloned_out(out, Self::finish_into);
    }

    /// [`WindowEstimator::finish`] into reused estimates.
    pub fn finish_into(&mut self, out: &mut Estimates) {
        if self.settings.outputs != Emitted::Newest {
            let n = self.slots.len();
            let first_owed = n.saturating_sub(self.settings.lag);
            for t in first_owed..n {
                self.estimate(t, TrackState::Lost, out.next_slot());
            }
        }
        self.reset();
    }

    /// Forgets the track without emitting anything.
    pub fn reset(&mut self) {
        self.shape_stats.clear();
        if self.estimator.dictionary().has_offset() {
            self.offset.iter_mut().for_each(|v| *v = 0.0);
            let offset = &self.offset;
            self.estimator.dictionary_mut().set_offset(offset);
        }
        self.slots.clear();
        self.swap_runs.fill(0);
        self.previous.fill(f64::NAN);
        self.spare.append(&mut self.fits);
        if let Some(a) = self.anchor.take() {
            self.spare.push(a);
        }
        self.maps.clear();
        self.since_window = 0;
        self.sweep = None;
        self.dropped = 0;
        self.last = None;
        self.empty_since_last = 0;
    }

    /// A new window over the same estimator and settings, keeping only the counters: for
    /// starting again after a failure left this one's state in doubt.
    pub fn fresh(&self) -> Result<Self, EstimateError> {
        let mut window = Self::new(self.estimator.clone(), self.settings.clone())?;
        window.counters = self.counters;
        Ok(window)
    }

    /// Checks a frame's sizes and values; true if any score is positive (the frame has
    /// evidence of someone).
    fn check(&self, frame: &FrameMaps<'_>) -> Result<bool, EstimateError> {
        let p = self.dictionary().num_joints();
        let n = frame.height.checked_mul(frame.width).unwrap_or(0);
        if n == 0 || p.checked_mul(n) != Some(frame.values.len()) {
            return Err(EstimateError::Parameter(format!(
                "frame {} holds {} values, expected {p} joints x {} x {}",
                frame.sequence,
                frame.values.len(),
                frame.height,
                frame.width
            )));
        }
        let mut evidence = false;
        let non_finite = |i: usize| EstimateError::NonFinite {
            frame: usize::try_from(frame.sequence).unwrap_or(usize::MAX),
            joint: i / n,
        };
        match frame.values {
            Scores::F32(values) => {
                for (i, v) in values.iter().enumerate() {
                    if !v.is_finite() {
                        return Err(non_finite(i));
                    }
                    evidence |= *v > 0.0;
                }
            }
            Scores::U8 { values, scale } => {
                if !(scale.is_finite() && scale > 0.0) {
                    return Err(EstimateError::Parameter(format!(
                        "frame {}: quantization scale {scale}",
                        frame.sequence
                    )));
                }
                evidence = values.iter().any(|&q| q > 0);
            }
        }
        Ok(evidence)
    }

    /// Adds the frame to the window (freezing the oldest if full) and initialises it.
    fn admit(&mut self, frame: &FrameMaps<'_>) {
        let k = self.dictionary().num_bases();
        if self.slots.len() == self.settings.size {
            self.learn_shape_from_oldest();
            self.slots.remove(0);
            let frozen = self.fits.remove(0);
            if let Some(old) = self.anchor.replace(frozen) {
                self.spare.push(old);
            }
            self.maps.pop_front();
            self.dropped += 1;
        }
        self.maps.push_back(&frame.values);
        let age = self.slots.last().map_or(0, |s| s.age + 1);
        if age == 0 {
            self.counters.tracks += 1;
        }
        self.slots.push(Slot {
            sequence: frame.sequence,
            stamp_ns: frame.stamp_ns,
            age,
        });
        let mut fit = self.spare.pop().unwrap_or_else(|| FrameFit::zero(k));
        match self.fits.last().filter(|_| self.settings.warm_start) {
            Some(prev) => {
                fit.coefficients.copy_from_slice(&prev.coefficients);
                fit.rotation = prev.rotation;
                fit.translation = prev.translation;
            }
            None => self.initialise(&mut fit),
        }
        self.fits.push(fit);
    }

    /// Adds the evidence of the window's oldest frame (about to freeze) about the
    /// track's shape beyond the dictionary: its E-step's expected joints under its fit.
    fn learn_shape_from_oldest(&mut self) {
        let adaptation = &self.estimator.params().adaptation;
        if !adaptation.enabled || self.fits.is_empty() {
            return;
        }
        let keep = 1.0 - 1.0 / adaptation.memory_frames;
        let dict = self.estimator.dictionary();
        let fit = std::slice::from_ref(&self.fits[0]);
        let view = Tail {
            inner: &self.maps,
            from: 0,
        };
        let scale = heatmap_scale(self.maps.height);
        em::e_step(
            dict,
            &view,
            fit,
            scale,
            self.estimator.params(),
            &mut self.one,
            None,
            &mut self.em,
        );
        self.shape_stats.decay(keep);
        self.shape_stats.add_frame(dict, &self.one, 0, &fit[0]);
    }

    /// Sets the track's offset from the evidence so far (at the start of a window EM,
    /// which then fits the window to it).
    fn adapt_offset(&mut self) {
        let adaptation = &self.estimator.params().adaptation;
        if !adaptation.enabled || self.shape_stats.is_empty() {
            return;
        }
        self.shape_stats.solve(adaptation, &mut self.offset);
        let offset = &self.offset;
        self.estimator.dictionary_mut().set_offset(offset);
    }

    /// The batch EM's per-frame initialisation of the newest frame, from its arg-max (its
    /// left/right pairs put back in the order of the track's previous arg-maxes when the
    /// swap model is on).
    fn initialise(&mut self, fit: &mut FrameFit) {
        let t = self.maps.len - 1;
        // The track's arg-maxes, each joint where it was last seen (none at its start).
        let swaps = self.estimator.params().swap_prior > 0.0;
        if self.fits.is_empty() {
            self.previous.fill(f64::NAN);
        }
        let previous = swaps.then_some((&mut self.previous[..], &mut self.swap_runs[..]));
        let maps = &self.maps;
        self.estimator.initialise_from_argmax(
            |j| maps.map(t, j),
            maps.width,
            heatmap_scale(maps.height),
            &mut self.argmax,
            &mut self.visible,
            &self.init_params,
            previous,
            &mut self.init,
            fit,
        );
    }

    /// EM iterations: first over the newest frames (anchored on the frame before them),
    /// then over the newest `lag + 1` (the same), then, every
    /// [`StreamSettings::window_every`] frames, over the whole window
    /// (anchored on the frozen frame), in [`StreamSettings::window_parts`] parts on
    /// consecutive frames.
    fn solve(&mut self) {
        let n = self.fits.len();
        let local = self.settings.local_frames.min(n);
        let has_local = local < n && self.settings.local_iterations > 0;
        if !has_local {
            // Too few frames for a local EM (or none configured): the whole window, now.
            self.sweep = None;
            self.since_window = 0;
            self.adapt_offset();
            self.solve_part(0, n, Which::Window);
            return;
        }
        // The newest `lag + 1` frames, unless the local EM already covers them.
        let lagged = self.settings.lag + 1;
        let has_lagged = self.settings.lag_iterations > 0 && lagged > local && lagged <= n;
        self.since_window += 1;
        if self.sweep.is_none() && self.since_window >= self.settings.window_every {
            // A window EM begins: the offset first, so that every pass of this frame
            // fits the same one.
            self.since_window = 0;
            self.adapt_offset();
            self.sweep = Some(Sweep {
                part: 0,
                parts: self.settings.window_parts.min(n),
                frames: n,
                dropped: self.dropped,
            });
        }
        self.solve_newest(local, Which::Local);
        if has_lagged {
            self.solve_newest(lagged, Which::Lagged);
        }
        let Some(sweep) = self.sweep.as_mut() else {
            return;
        };
        let part = sweep.next_part(n, self.dropped);
        if sweep.part == sweep.parts {
            self.sweep = None;
        }
        if !part.is_empty() {
            self.solve_part(part.start, part.end, Which::Window);
        }
    }

    /// EM over the newest `frames` frames of the window, anchored on the frame before
    /// (the frozen frame when they are the whole window).
    fn solve_newest(&mut self, frames: usize, which: Which) {
        let n = self.fits.len();
        self.solve_part(n - frames, n, which);
    }

    /// The window's EM over its frames `[from, to)`, between the frames on both sides
    /// (the frozen frame before the window when `from` is 0; nothing after the newest),
    /// with `which` EM's parameters.
    fn solve_part(&mut self, from: usize, to: usize, which: Which) {
        let scale = heatmap_scale(self.maps.height);
        let (before, rest) = self.fits.split_at_mut(from);
        let (part, after) = rest.split_at_mut(to - from);
        let anchors = Anchors {
            before: if from == 0 {
                self.anchor.as_ref()
            } else {
                before.last()
            },
            after: after.first(),
        };
        let view = Tail {
            inner: &self.maps,
            from,
        };
        em::run_between_in(
            self.estimator.dictionary(),
            self.estimator.basis_gram_max(),
            &view,
            part,
            anchors,
            scale,
            match which {
                Which::Local => &self.local_params,
                Which::Lagged => &self.lag_params,
                Which::Window => &self.window_params,
            },
            &mut self.obs,
            &mut self.em,
        );
    }

    /// The estimate of window frame `t`, written over `e`.
    fn estimate(&mut self, t: usize, state: TrackState, e: &mut FrameEstimate) {
        let dict = self.estimator.dictionary();
        let p = dict.num_joints();
        let scale = heatmap_scale(self.maps.height);
        let fit = &self.fits[t];
        let view = Tail {
            inner: &self.maps,
            from: t,
        };
        em::e_step(
            dict,
            &view,
            std::slice::from_ref(fit),
            scale,
            self.estimator.params(),
            &mut self.one,
            Some(&mut self.variance),
            &mut self.em,
        );
        dict.compose_into(&fit.coefficients, &mut self.shape);
        let s = &self.shape;
        e.pose.clear();
        e.projected.clear();
        for j in 0..p {
            let q = fit.rotation * Vector3::new(s[j], s[p + j], s[2 * p + j]);
            e.pose.extend_from_slice(q.as_slice());
            e.projected.push((q.x + fit.translation.x) * scale);
            e.projected.push((q.y + fit.translation.y) * scale);
        }
        // The variance is the trace of the 2D covariance: per axis, half of it.
        e.keypoint_std.clear();
        e.pose_std.clear();
        let later = self.slots.len() - 1 - t;
        let newest = self.settings.newest_std_factor(later);
        let (lateral, depth) = (
            newest * self.settings.std_scale,
            newest * self.settings.depth_std_scale,
        );
        for v in &self.variance {
            let std = (0.5 * v).sqrt();
            e.keypoint_std.push(std);
            let model = std / scale;
            e.pose_std
                .extend([model * lateral, model * lateral, model * depth]);
        }
        e.keypoints.clear();
        e.keypoints.extend(self.one.xy.iter().map(|v| v * scale));
        e.fit.coefficients.clone_from(&fit.coefficients);
        e.fit.rotation = fit.rotation;
        e.fit.translation = fit.translation;
        e.pixels_per_unit = scale;
        e.offset.clear();
        e.offset.extend_from_slice(dict.offset());
        let slot = &self.slots[t];
        e.sequence = slot.sequence;
        e.stamp_ns = slot.stamp_ns;
        e.lag = later;
        e.state = state;
    }
}
