//! The estimator node: heat-map messages in, skeleton messages out, one window per person
//! ([`EstimatorNode`]); its metres ([`metres`]: the camera's calibration, the floor); its
//! tracks ([`track`]: what is remembered of each frame, the messages written); and its
//! decision core ([`core`]: every input a driver moves, with a clock passed in, and the
//! plan of what to publish).

pub mod core;
pub mod metres;
pub mod track;

pub use self::core::{Clock, EstimatorCore, EstimatorReport, Flow, Input};
pub use metres::{FloorReport, MetricTiming, calibration};

use std::collections::VecDeque;
use std::panic::AssertUnwindSafe;

use crate::estimator::Estimator;
use crate::floor::BodyScale;
use crate::limits::Limits;
use crate::metres::MetricSettings;
use crate::msgs::{self, Skeleton3D};
use crate::nodes::config::{self, DEFAULT_MAX_TRACKS, ServiceConfig};
use crate::nodes::errors::{NodeError, Refusals, SetupError};
use crate::nodes::publish::outputs::SkeletonLayout;
use crate::nodes::unknown_ids;
use crate::skeleton::same_layout;
use crate::streaming::{Estimates, FrameMaps, StreamCounters, WindowEstimator};
use crate::transport::TransportError;
use metres::{FloorFromTf, Metric};
use posestream_base::CropBox;
use track::{FrameInfo, Track, frames_kept, release};

/// The sizes of people whose tracks ended kept at most ([`EstimatorNode`]'s: the newest).
const KEPT_SIZES: usize = 64;

/// Heat-map messages in, skeleton messages out, through one [`WindowEstimator`] per
/// track.
///
/// Each heat-map message names its person (`track_id`); each track has a window of its
/// own, so people in one image never reset each other's windows. At most `max_tracks`
/// run at once: a new person's frame ends the track seen least recently if that one is
/// not in the same image (frame number), else it is refused and counted
/// (`too-many-tracks`). A track also ends, its owed estimates published with state
/// `lost`, when another track takes a frame more than the window's `max_gap_seconds`
/// (in capture time) from its newest one, when its own frames jump (the window's
/// rules), or at the end of the stream ([`EstimatorNode::finish`]). An ended track's window is reset and kept for the next
/// track (one at most; the others are freed).
///
/// Every message is handled behind a boundary: a bad one is refused and counted by kind
/// ([`Refusals`]); should handling it panic (a bug), the panic is caught, the track reset
/// and the node goes on.
pub struct EstimatorNode {
    /// Checks frames before a track takes them, and makes new tracks' windows; it never
    /// holds a track itself.
    template: WindowEstimator,
    joint_names: Vec<String>,
    limits: Limits,
    max_tracks: usize,
    tracks: Vec<Track>,
    /// Metres, when the camera is known (`[estimator.metric] intrinsics`, or a
    /// `CameraInfo`).
    metric: Option<Metric>,
    metric_settings: MetricSettings,
    /// An ended track's window, reset, for the next track.
    spare_window: Option<WindowEstimator>,
    /// The counters of the ended tracks' windows, and of frames no track took.
    ended: StreamCounters,
    /// The sizes of people whose tracks ended (their contacts with the floor), by id, the
    /// newest last, at most [`KEPT_SIZES`]: a person back under their id (re-identified
    /// by the detector) keeps theirs.
    kept_sizes: VecDeque<(u32, BodyScale)>,
    /// The track being handled (for the boundary: the one a panic resets).
    current: Option<usize>,
    /// Frames the tracks took, in all (orders them by recency).
    taken: u64,
    /// The window's estimates of the frame in hand (reused from frame to frame).
    estimates: Estimates,
    /// Skeleton messages handed back ([`EstimatorNode::recycle`]), written over by the
    /// next ones.
    spare: Vec<Skeleton3D>,
    refused: Refusals,
    /// People without ids: their messages of the image in hand, and their tracker
    /// (taken out while their messages are handled).
    unknown: Option<unknown_ids::UnknownIds>,
    /// The floor from TF (`[estimator.metric.floor] source = "tf"`).
    tf: Option<FloorFromTf>,
    /// Test builds (`--features fault-injection`): the sequence number whose handling
    /// panics, from `POSESTREAM_INJECT_PANIC_AT`.
    #[cfg(feature = "fault-injection")]
    panic_at: Option<u64>,
}

impl EstimatorNode {
    /// A node whose tracks run `window`'s estimator and settings, with the default
    /// [`Limits`] and at most [`DEFAULT_MAX_TRACKS`] tracks.
    pub fn new(window: WindowEstimator) -> Self {
        let joint_names = window.dictionary().skeleton().joints.clone();
        Self {
            template: window,
            joint_names,
            limits: Limits::default(),
            max_tracks: DEFAULT_MAX_TRACKS,
            tracks: Vec::new(),
            metric: None,
            metric_settings: MetricSettings::default(),
            spare_window: None,
            ended: StreamCounters::default(),
            kept_sizes: VecDeque::new(),
            current: None,
            taken: 0,
            estimates: Estimates::default(),
            spare: Vec::new(),
            refused: Refusals::default(),
            unknown: Some(unknown_ids::UnknownIds::new(DEFAULT_MAX_TRACKS)),
            tf: None,
            #[cfg(feature = "fault-injection")]
            panic_at: std::env::var("POSESTREAM_INJECT_PANIC_AT")
                .ok()
                .and_then(|v| v.parse().ok()),
        }
    }

    /// A node from the configuration's estimator section.
    pub fn from_config(config: &config::EstimatorConfig) -> Result<Self, SetupError> {
        let dict = crate::msgs::shipped::load_dictionary(&config.dictionary)?;
        let estimator = Estimator::new(dict, config.params.clone())?;
        let window = WindowEstimator::new(estimator, config.window.clone())?;
        Self::new(window)
            .with_max_tracks(config.max_tracks)
            .with_metric(&config.metric)
    }

    /// The node of a service configuration: `[estimator]` under `[limits]`.
    pub fn from_service_config(config: &ServiceConfig) -> Result<Self, SetupError> {
        Ok(Self::from_config(&config.estimator)?.with_limits(&config.limits))
    }

    /// The same node, refusing frames beyond `limits`.
    pub fn with_limits(mut self, limits: &Limits) -> Self {
        self.limits = limits.clone();
        self
    }

    /// The same node, running at most `max_tracks` tracks at once (at least one).
    pub fn with_max_tracks(mut self, max_tracks: usize) -> Self {
        self.max_tracks = max_tracks.max(1);
        self.unknown = Some(unknown_ids::UnknownIds::new(self.max_tracks));
        self
    }

    /// Tracks the node started for people whose heat maps came without an id.
    pub fn tracks_from_unknown_ids(&self) -> u64 {
        self.unknown
            .as_ref()
            .map_or(0, unknown_ids::UnknownIds::tracks_made)
    }

    /// The windows' counters, summed over every track so far.
    pub fn counters(&self) -> StreamCounters {
        let mut sum = self.ended;
        sum += self.template.counters();
        for track in &self.tracks {
            sum += track.window.counters();
        }
        sum
    }

    /// Tracks running now.
    pub fn tracks(&self) -> usize {
        self.tracks.len()
    }

    /// Messages refused (undecodable, inconsistent, beyond the limits, with unknown
    /// joints, or whose handling failed).
    pub fn malformed(&self) -> u64 {
        self.refused.total()
    }

    /// Refusals by kind.
    pub fn refused(&self) -> &Refusals {
        &self.refused
    }

    /// Counts a message the transport refused before it reached the node: one it could
    /// not decode, or one beyond the limits (an iceoryx2 sample).
    pub fn count_refused(&mut self, error: &TransportError) {
        self.refused
            .note(error.refusal().unwrap_or("undecodable"), error);
    }

    /// The limits it refuses frames beyond.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The window's settings.
    pub fn settings(&self) -> &crate::streaming::StreamSettings {
        self.template.settings()
    }

    /// The bones of the skeletons (joint index pairs), for drawing.
    pub fn bones(&self) -> Vec<(usize, usize)> {
        self.template.dictionary().skeleton().bones().collect()
    }

    /// Handles one encoded heat-map message; a bad one is counted and returned as an
    /// error, and the node goes on.
    pub fn handle_encoded(
        &mut self,
        data: &[u8],
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        match msgs::decode::<msgs::HeatMaps>(data) {
            Ok(msg) => self.handle(&msg, out),
            Err(e) => {
                let e = NodeError::from(e);
                self.refused.note(e.kind(), &e);
                Err(e)
            }
        }
    }

    /// Handles one heat-map message; appends the skeletons it releases to `out`. A bad
    /// message is refused, counted and logged once per kind; the node goes on.
    pub fn handle(
        &mut self,
        msg: &msgs::HeatMaps,
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        self.handle_view(&msg.view(), out)
    }

    /// [`EstimatorNode::handle`] of a frame borrowed from where it arrived (a message, an
    /// iceoryx2 sample): its scores are read there and copied once, into the window.
    ///
    /// A message without an id ([`unknown_ids::UNKNOWN_TRACK`]) is held until its image
    /// is complete, then given an id by the node's tracker ([`unknown_ids`]); its
    /// skeletons come then.
    pub fn handle_view(
        &mut self,
        msg: &msgs::HeatMapsView<'_>,
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        if self.unknown.as_ref().is_some_and(|u| u.held_before(msg)) {
            self.complete_image(out);
        }
        if msg.track_id == unknown_ids::UNKNOWN_TRACK {
            let held = self.hold_unknown(msg);
            if let Err(e) = &held {
                self.refused.note(e.kind(), e);
            }
            return held;
        }
        self.handle_known(msg, out)
    }

    /// The image in hand is complete (the input went quiet): the messages without an
    /// id held for it are given ids and handled, their skeletons appended to `out`.
    pub fn complete_image(&mut self, out: &mut Vec<Skeleton3D>) {
        let Some(mut unknown) = self.unknown.take() else {
            return;
        };
        unknown.release(|m, id| match id {
            Some(_) => {
                // Counted and logged by the node if refused.
                let _ = self.handle_known(&m.view(), out);
            }
            None => {
                let e = NodeError::NoTrack {
                    sequence: m.sequence,
                };
                self.refused.note(e.kind(), &e);
            }
        });
        self.unknown = Some(unknown);
    }

    /// The message's maps within the configured limits.
    fn check_map_size(&self, msg: &msgs::HeatMapsView<'_>) -> Result<(), NodeError> {
        self.limits
            .heatmap_values(
                msg.joint_names.len() as u64,
                u64::from(msg.height),
                u64::from(msg.width),
            )
            .map(|_| ())
            .map_err(|source| NodeError::Limit {
                sequence: msg.sequence,
                source,
            })
    }

    /// Checks a message without an id as far as it can be without its track, and holds
    /// a copy of it for its image's end.
    fn hold_unknown(&mut self, msg: &msgs::HeatMapsView<'_>) -> Result<(), NodeError> {
        self.check_map_size(msg)?;
        msg.crop()?;
        let max_tracks = self.max_tracks;
        let held = self
            .unknown
            .as_mut()
            .is_some_and(|u| u.hold(msg, max_tracks));
        match held {
            true => Ok(()),
            false => Err(NodeError::TooManyTracks {
                sequence: msg.sequence,
                track_id: msg.track_id,
                max_tracks,
            }),
        }
    }

    /// [`EstimatorNode::handle_view`] of a message with its id.
    fn handle_known(
        &mut self,
        msg: &msgs::HeatMapsView<'_>,
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        let result = self
            .isolated(out, |node, out| node.handle_inner(msg, out))
            .unwrap_or_else(|message| {
                Err(NodeError::Panic {
                    during: format!("frame {}", msg.sequence),
                    message,
                })
            });
        if let Err(e) = &result {
            self.refused.note(e.kind(), e);
        }
        result
    }

    /// Runs `f` behind the node's boundary: should it panic (a bug), the messages it
    /// added to `out` are dropped, the track it was handling (every track, if it was not
    /// handling one) is dropped, since its state may be inconsistent, and the panic's
    /// message is returned.
    fn isolated<T>(
        &mut self,
        out: &mut Vec<Skeleton3D>,
        f: impl FnOnce(&mut Self, &mut Vec<Skeleton3D>) -> T,
    ) -> Result<T, String> {
        let before = out.len();
        self.current = None;
        let caught = std::panic::catch_unwind(AssertUnwindSafe(|| f(self, out)));
        let current = self.current.take();
        caught.map_err(|payload| {
            out.truncate(before);
            let dropped: Vec<Track> = match current {
                Some(i) if i < self.tracks.len() => vec![self.tracks.swap_remove(i)],
                _ => self.tracks.drain(..).collect(),
            };
            for mut track in dropped {
                self.ended += track.window.take_counters();
            }
            // The spare window may be the one that failed; a new one is made when needed.
            self.spare_window = None;
            crate::error::panic_text(payload.as_ref())
        })
    }

    fn handle_inner(
        &mut self,
        msg: &msgs::HeatMapsView<'_>,
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        #[cfg(feature = "fault-injection")]
        if self.panic_at == Some(msg.sequence) {
            panic!(
                "injected panic (POSESTREAM_INJECT_PANIC_AT={})",
                msg.sequence
            );
        }
        self.check_map_size(msg)?;
        if !same_layout(msg.joint_names, &self.joint_names) {
            return Err(NodeError::Joints {
                sequence: msg.sequence,
                found: msg.joint_names.to_vec(),
                expected: self.joint_names.clone(),
            });
        }
        let crop: CropBox = msg.crop()?;
        // The message's scores, borrowed: the window's ring is their one copy.
        let frame = FrameMaps {
            sequence: msg.sequence,
            stamp_ns: msg.stamp_ns,
            height: msg.height as usize,
            width: msg.width as usize,
            values: msg.scores()?,
        };
        let checked = self
            .template
            .check_frame(&frame)
            .map_err(|source| NodeError::Estimate {
                sequence: msg.sequence,
                source,
            })?;
        // Only a well-formed frame with evidence starts a track (or, once taken, ends
        // others: below).
        let index = match self.tracks.iter().position(|t| t.id == msg.track_id) {
            Some(i)
                if self.tracks[i].last_taken > 0
                    && self.tracks[i].last_sequence == msg.sequence
                    && self.tracks[i].last_stamp_ns == msg.stamp_ns =>
            {
                // Said once per track: the node's refusals log the first of the kind.
                let track = &mut self.tracks[i];
                if !track.duplicate_warned && self.refused.of("duplicate-id") > 0 {
                    tracing::warn!(
                        "frame {}: track {} came twice in one image (duplicate id in one image); \
                         its second messages are refused",
                        msg.sequence,
                        msg.track_id
                    );
                }
                track.duplicate_warned = true;
                return Err(NodeError::DuplicateId {
                    sequence: msg.sequence,
                    track_id: msg.track_id,
                });
            }
            Some(i) => i,
            None if !checked.has_evidence() => {
                // Nothing seen of a person not tracked: counted as the window would.
                self.ended.empty += 1;
                return Ok(());
            }
            None => {
                if self.tracks.len() >= self.max_tracks {
                    // Room is made by the track seen least recently, if it is not in
                    // this image (a single-person detector's earlier ids, a person
                    // who left); people of this image are never pushed out.
                    let oldest = (0..self.tracks.len())
                        .filter(|&i| self.tracks[i].last_sequence != msg.sequence)
                        .min_by_key(|&i| self.tracks[i].last_taken);
                    match oldest {
                        Some(i) => self.end_track(i, out),
                        None => {
                            return Err(NodeError::TooManyTracks {
                                sequence: msg.sequence,
                                track_id: msg.track_id,
                                max_tracks: self.max_tracks,
                            });
                        }
                    }
                }
                self.start_track(msg.track_id)?
            }
        };
        self.current = Some(index);
        let track = &mut self.tracks[index];
        self.estimates.clear();
        let accepted_before = track.window.counters().frames;
        track
            .window
            .push_checked_into(&frame, checked, &mut self.estimates);
        // Only frames the window accepted are remembered (not late ones); the oldest
        // one no estimate can need any more is written over.
        let taken = track.window.counters().frames > accepted_before;
        if taken {
            self.taken += 1;
            track.last_stamp_ns = msg.stamp_ns;
            track.last_sequence = msg.sequence;
            track.last_taken = self.taken;
            let to_image = crop.pixel_map(msg.width as usize, msg.height as usize);
            let oldest = if track.frames.len() >= frames_kept(&track.window) {
                track.frames.pop_front()
            } else {
                None
            };
            let map_size = (f64::from(msg.width), f64::from(msg.height));
            let mut info = oldest.unwrap_or(FrameInfo {
                sequence: msg.sequence,
                to_image,
                map_size,
                frame_id: String::new(),
                frames_since_look: 0,
            });
            info.sequence = msg.sequence;
            info.frames_since_look = msg.frames_since_look;
            info.to_image = to_image;
            info.map_size = map_size;
            info.frame_id.clear();
            info.frame_id.push_str(msg.frame_id);
            track.frames.push_back(info);
        }
        self.release(index, out);
        // A frame its track took ends the tracks left behind in time (a late one, or
        // one refused, ends none).
        if taken {
            self.current = None;
            self.end_stale(msg.track_id, msg.stamp_ns, out);
        }
        Ok(())
    }

    /// A new track for `id`, on the spare window or a new one; its index.
    fn start_track(&mut self, id: u32) -> Result<usize, NodeError> {
        let window = match self.spare_window.take() {
            Some(window) => window,
            None => {
                let mut window = self
                    .template
                    .fresh()
                    .map_err(|source| NodeError::Estimate {
                        sequence: 0,
                        source,
                    })?;
                // The template's counts stay the template's.
                window.take_counters();
                window
            }
        };
        self.tracks.push(Track {
            id,
            window,
            frames: VecDeque::new(),
            last_stamp_ns: 0,
            last_sequence: 0,
            last_taken: 0,
            duplicate_warned: false,
            scale: match self.kept_sizes.iter().position(|(kept, _)| *kept == id) {
                Some(k) => self.kept_sizes.remove(k).map(|(_, scale)| scale),
                None => None,
            }
            .unwrap_or_else(|| BodyScale::new(self.metric_settings.floor.contact_frames)),
        });
        Ok(self.tracks.len() - 1)
    }

    /// Ends every track other than `id` whose newest frame is more than the window's
    /// `max_gap_seconds` from `stamp_ns` (either way: a person who left, or a track from
    /// a clock that jumped).
    fn end_stale(&mut self, id: u32, stamp_ns: i64, out: &mut Vec<Skeleton3D>) {
        let gap = self.template.settings().max_gap_seconds;
        let mut i = 0;
        while i < self.tracks.len() {
            let t = &self.tracks[i];
            if t.id != id && t.last_stamp_ns.abs_diff(stamp_ns) as f64 * 1e-9 > gap {
                self.end_track(i, out);
            } else {
                i += 1;
            }
        }
    }

    /// Turns the estimates in hand of track `i` into messages ([`release`]).
    fn release(&mut self, i: usize, out: &mut Vec<Skeleton3D>) {
        if self.tf.is_some()
            && let Some(info) = self.tracks[i].frames.back_mut()
        {
            // The camera frame's floor (its id lent out and back: no allocation).
            let frame = std::mem::take(&mut info.frame_id);
            self.update_floor(&frame);
            if let Some(info) = self.tracks[i].frames.back_mut() {
                info.frame_id = frame;
            }
        }
        let Self {
            tracks,
            estimates,
            joint_names,
            metric,
            spare,
            refused,
            ..
        } = self;
        release(
            &mut tracks[i],
            estimates,
            joint_names,
            metric.as_mut(),
            spare,
            refused,
            out,
        );
    }

    /// Ends track `i`: its owed estimates to `out`, its window kept as the spare.
    fn end_track(&mut self, i: usize, out: &mut Vec<Skeleton3D>) {
        self.current = Some(i);
        let track = &mut self.tracks[i];
        self.estimates.clear();
        track.window.finish_into(&mut self.estimates);
        self.release(i, out);
        let mut track = self.tracks.remove(i);
        self.current = None;
        // Their size stays, their feet (frames of the track that ended) do not.
        track.scale.suspend();
        self.kept_sizes.retain(|(kept, _)| *kept != track.id);
        if self.kept_sizes.len() == KEPT_SIZES {
            self.kept_sizes.pop_front();
        }
        self.kept_sizes
            .push_back((track.id, std::mem::take(&mut track.scale)));
        self.ended += track.window.take_counters();
        if self.spare_window.is_none() {
            self.spare_window = Some(track.window);
        }
    }

    /// Takes back skeleton messages the node handed out (after they were published):
    /// the next ones are written over them, so that a warm node allocates no message.
    pub fn recycle(&mut self, skeletons: &mut Vec<Skeleton3D>) {
        self.spare.append(skeletons);
    }

    /// The dictionary's joint names (those of every skeleton published).
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    /// The images' size (columns, rows), when a camera calibration gave it.
    pub fn image_size(&self) -> Option<(f64, f64)> {
        self.metric.as_ref().and_then(|m| m.size)
    }

    /// Frames the windows have taken so far (not refused, late or without evidence).
    pub fn frames_accepted(&self) -> u64 {
        self.counters().frames
    }

    /// Ends the stream: every track ends, with the estimates still owed. Behind the same
    /// boundary as [`EstimatorNode::handle`]: a panic is counted and logged, and the
    /// track dropped.
    pub fn finish(&mut self, out: &mut Vec<Skeleton3D>) {
        self.complete_image(out);
        while !self.tracks.is_empty() {
            let finished = self.isolated(out, |node, out| node.end_track(0, out));
            if let Err(message) = finished {
                let e = NodeError::Panic {
                    during: "ending a track".into(),
                    message,
                };
                self.refused.note(e.kind(), &e);
            }
        }
    }
}

impl SkeletonLayout for EstimatorNode {
    fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    fn bones(&self) -> Vec<(usize, usize)> {
        EstimatorNode::bones(self)
    }

    fn body_lag(&self) -> u32 {
        // The newest estimates when the window publishes them, else the refined ones.
        let settings = self.settings();
        match settings.outputs {
            crate::streaming::Emitted::Lagged => settings.lag as u32,
            _ => 0,
        }
    }
}
