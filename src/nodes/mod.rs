//! The nodes of the service: thin adapters between messages ([`crate::msgs`]) and the
//! math ([`crate::streaming`]). Nothing here solves anything.
//!
//! - [`EstimatorNode`]: heat-map messages in, [`Skeleton3D`] messages out;
//! - [`replay`]: a recording's heat maps through the estimator loop, skeletons to a
//!   recording;
//! - [`service`]: the detector, estimator, pipeline and recorder loops over any
//!   transport ([`crate::transport`]), and their wiring from the configuration;
//! - [`markers`]: skeletons as `visualization_msgs/MarkerArray`.

pub mod config;
pub mod images;
pub mod latency;
pub mod markers;
pub mod replay;
pub mod service;

use std::collections::{BTreeMap, VecDeque};
use std::panic::AssertUnwindSafe;

use crate::camera::{CropBox, PixelMap};
use crate::error::EstimateError;
use crate::estimator::Estimator;
use crate::limits::{LimitError, Limits};
use crate::msgs::{self, DecodeError, Skeleton3D, Time, Units};
use crate::skeleton::same_layout;
use crate::streaming::{
    Estimates, FrameEstimate, FrameMaps, StreamCounters, TrackState, WindowEstimator,
};
use crate::transport::TransportError;

pub use config::ServiceConfig;

/// Why a message was not used.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// The message could not be decoded or is inconsistent.
    #[error(transparent)]
    Decode(#[from] DecodeError),
    /// The message names joints the dictionary does not have (or in another order).
    #[error("frame {sequence}: joints {found:?} do not match the dictionary's {expected:?}")]
    Joints {
        /// The frame.
        sequence: u64,
        /// The message's joints.
        found: Vec<String>,
        /// The dictionary's joints.
        expected: Vec<String>,
    },
    /// The message declares sizes beyond the configured limits.
    #[error("frame {sequence}: {source}")]
    Limit {
        /// The frame.
        sequence: u64,
        /// What is beyond which limit.
        source: LimitError,
    },
    /// The estimator refused the frame.
    #[error("frame {sequence}: {source}")]
    Estimate {
        /// The frame.
        sequence: u64,
        /// The cause.
        source: EstimateError,
    },
    /// Handling a frame, or ending a track, panicked (a bug): the frame is dropped and
    /// the track reset, since its state may be inconsistent.
    #[error("{during}: internal error ({message}); the track was reset")]
    Panic {
        /// What was being done (`frame 12`, `ending a track`).
        during: String,
        /// The panic's message.
        message: String,
    },
    /// An estimate had non-finite values (it is not published).
    #[error("frame {sequence}: the estimate has non-finite values; not published")]
    NonFiniteOutput {
        /// The frame the estimate describes.
        sequence: u64,
    },
}

impl NodeError {
    /// The kind of refusal, as counted in reports (`refused`).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Decode(DecodeError::Invalid { .. }) => "invalid",
            Self::Decode(_) => "undecodable",
            Self::Joints { .. } => "joints",
            Self::Limit { .. } => "beyond-limits",
            Self::Estimate {
                source: EstimateError::NonFinite { .. },
                ..
            } => "non-finite",
            Self::Estimate { .. } => "inconsistent",
            Self::Panic { .. } => "panic",
            Self::NonFiniteOutput { .. } => "non-finite-output",
        }
    }
}

/// A node could not be set up from its configuration.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The dictionary could not be loaded.
    #[error(transparent)]
    Dictionary(#[from] crate::DictionaryError),
    /// A parameter is out of its domain.
    #[error("configuration: {0}")]
    Parameter(#[from] EstimateError),
    /// The image detector could not be set up.
    #[error(transparent)]
    Detector(#[from] crate::detector::DetectorError),
}

/// What the estimator node needs to remember of a frame until its last estimate is out.
#[derive(Debug, Clone)]
struct FrameInfo {
    sequence: u64,
    to_image: PixelMap,
    frame_id: String,
}

/// Refusals counted by kind; the first of each kind is logged (a warning), the rest only
/// counted, so a hostile stream cannot flood the log.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct Refusals(BTreeMap<&'static str, u64>);

impl Refusals {
    /// Counts `kind`; logs `what` if it is the first of its kind.
    pub fn note(&mut self, kind: &'static str, what: &dyn std::fmt::Display) {
        let n = self.0.entry(kind).or_insert(0);
        *n += 1;
        if *n == 1 {
            tracing::warn!(
                "refused ({kind}): {what} (further ones of this kind are counted, not logged)"
            );
        } else {
            tracing::debug!("refused ({kind}): {what}");
        }
    }

    /// Refusals in all.
    pub fn total(&self) -> u64 {
        self.0.values().sum()
    }

    /// Refusals of `kind`.
    pub fn of(&self, kind: &str) -> u64 {
        self.0.get(kind).copied().unwrap_or(0)
    }
}

/// Heat-map messages in, skeleton messages out, through a [`WindowEstimator`].
///
/// Every message is handled behind a boundary: a bad one is refused and counted by kind
/// ([`Refusals`]); should handling it panic (a bug), the panic is caught, the track reset
/// and the node goes on.
pub struct EstimatorNode {
    window: WindowEstimator,
    joint_names: Vec<String>,
    limits: Limits,
    track_id: u32,
    frames: VecDeque<FrameInfo>,
    /// The window's estimates of the frame in hand (reused from frame to frame).
    estimates: Estimates,
    /// Skeleton messages handed back ([`EstimatorNode::recycle`]), written over by the
    /// next ones.
    spare: Vec<Skeleton3D>,
    refused: Refusals,
    /// Test builds (`--features fault-injection`): the sequence number whose handling
    /// panics, from `POSESTREAM_INJECT_PANIC_AT`.
    #[cfg(feature = "fault-injection")]
    panic_at: Option<u64>,
}

impl EstimatorNode {
    /// A node over `window`, with the default [`Limits`].
    pub fn new(window: WindowEstimator) -> Self {
        let joint_names = window.dictionary().skeleton().joints.clone();
        Self {
            window,
            joint_names,
            limits: Limits::default(),
            track_id: 0,
            frames: VecDeque::new(),
            estimates: Estimates::default(),
            spare: Vec::new(),
            refused: Refusals::default(),
            #[cfg(feature = "fault-injection")]
            panic_at: std::env::var("POSESTREAM_INJECT_PANIC_AT")
                .ok()
                .and_then(|v| v.parse().ok()),
        }
    }

    /// A node from the configuration's estimator section.
    pub fn from_config(config: &config::EstimatorConfig) -> Result<Self, SetupError> {
        let dict = crate::Dictionary::load(&config.dictionary)?;
        let estimator = Estimator::new(dict, config.params.clone())?;
        let window = WindowEstimator::new(estimator, config.window.clone())?;
        Ok(Self::new(window))
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

    /// The window's counters.
    pub fn counters(&self) -> StreamCounters {
        self.window.counters()
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
        let kind = match error {
            TransportError::BeyondLimits { .. } => "beyond-limits",
            _ => "undecodable",
        };
        self.refused.note(kind, error);
    }

    /// The window's settings.
    pub fn settings(&self) -> &crate::streaming::StreamSettings {
        self.window.settings()
    }

    /// The bones of the skeletons (joint index pairs), for drawing.
    pub fn bones(&self) -> Vec<(usize, usize)> {
        self.window.dictionary().skeleton().bones().collect()
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
    pub fn handle_view(
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
    /// added to `out` are dropped, the window is replaced by a fresh one (its state may be
    /// inconsistent) and the panic's message is returned.
    fn isolated<T>(
        &mut self,
        out: &mut Vec<Skeleton3D>,
        f: impl FnOnce(&mut Self, &mut Vec<Skeleton3D>) -> T,
    ) -> Result<T, String> {
        let before = out.len();
        let caught = std::panic::catch_unwind(AssertUnwindSafe(|| f(self, out)));
        caught.map_err(|payload| {
            out.truncate(before);
            self.frames.clear();
            match self.window.fresh() {
                Ok(window) => self.window = window,
                Err(_) => self.window.reset(),
            }
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
        self.limits
            .heatmap_values(
                msg.joint_names.len() as u64,
                u64::from(msg.height),
                u64::from(msg.width),
            )
            .map_err(|source| NodeError::Limit {
                sequence: msg.sequence,
                source,
            })?;
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
            .window
            .check_frame(&frame)
            .map_err(|source| NodeError::Estimate {
                sequence: msg.sequence,
                source,
            })?;
        // Another person (the detector lost its track and found one again): the old
        // track ends here, its owed estimates first. Only a well-formed frame with
        // evidence can end a track.
        if checked.has_evidence() && msg.track_id != self.track_id {
            if !self.window.is_empty() {
                self.estimates.clear();
                self.window.finish_into(&mut self.estimates);
                self.release(out);
                self.frames.clear();
            }
            self.track_id = msg.track_id;
        }
        self.estimates.clear();
        let accepted_before = self.window.counters().frames;
        self.window
            .push_checked_into(&frame, checked, &mut self.estimates);
        // Only frames the window accepted are remembered (not late ones); the oldest
        // one no estimate can need any more is written over.
        if self.window.counters().frames > accepted_before {
            let to_image = crop.pixel_map(msg.width as usize, msg.height as usize);
            let oldest = if self.frames.len() >= self.frames_kept() {
                self.frames.pop_front()
            } else {
                None
            };
            let mut info = oldest.unwrap_or(FrameInfo {
                sequence: msg.sequence,
                to_image,
                frame_id: String::new(),
            });
            info.sequence = msg.sequence;
            info.to_image = to_image;
            info.frame_id.clear();
            info.frame_id.push_str(msg.frame_id);
            self.frames.push_back(info);
        }
        self.release(out);
        Ok(())
    }

    /// Frames remembered at most: those an estimate can still come for (the window and
    /// the lag), and one more.
    fn frames_kept(&self) -> usize {
        let settings = self.window.settings();
        settings.size + settings.lag + 1
    }

    /// Takes back skeleton messages the node handed out (after they were published):
    /// the next ones are written over them, so that a warm node allocates no message.
    pub fn recycle(&mut self, skeletons: &mut Vec<Skeleton3D>) {
        self.spare.append(skeletons);
    }

    /// Frames the window has taken so far (not refused, late or without evidence).
    pub fn frames_accepted(&self) -> u64 {
        self.window.counters().frames
    }

    /// Ends the stream: the estimates still owed. Behind the same boundary as
    /// [`EstimatorNode::handle`]: a panic is counted and logged, and the track dropped.
    pub fn finish(&mut self, out: &mut Vec<Skeleton3D>) {
        let finished = self.isolated(out, |node, out| {
            node.estimates.clear();
            node.window.finish_into(&mut node.estimates);
            node.release(out);
            node.frames.clear();
        });
        if let Err(message) = finished {
            let e = NodeError::Panic {
                during: "ending a track".into(),
                message,
            };
            self.refused.note(e.kind(), &e);
        }
    }

    /// Turns the window's estimates into messages; forgets frames no estimate can
    /// need any more. An estimate with non-finite values is counted, not published.
    fn release(&mut self, out: &mut Vec<Skeleton3D>) {
        let keep = self.frames_kept();
        for e in self.estimates.iter() {
            let Some(info) = self.frames.iter().rev().find(|f| f.sequence == e.sequence) else {
                continue;
            };
            let mut message = self.spare.pop().unwrap_or_default();
            write_skeleton(&mut message, e, info, &self.joint_names, self.track_id);
            if message.is_finite() {
                out.push(message);
            } else {
                self.spare.push(message);
                let e = NodeError::NonFiniteOutput {
                    sequence: e.sequence,
                };
                self.refused.note(e.kind(), &e);
            }
        }
        while self.frames.len() > keep {
            self.frames.pop_front();
        }
    }
}

/// The message of one estimate, written over `m` (its buffers reused).
fn write_skeleton(
    m: &mut Skeleton3D,
    e: &FrameEstimate,
    info: &FrameInfo,
    joint_names: &[String],
    track_id: u32,
) {
    let map = info.to_image;
    let to_image = |xy: &[f64], out: &mut Vec<f64>| {
        out.clear();
        out.extend(xy.chunks_exact(2).flat_map(|p| map.apply(p[0], p[1])));
    };
    m.header.stamp = Time::from_nanos(e.stamp_ns);
    m.header.frame_id.clone_from(&info.frame_id);
    m.sequence = e.sequence;
    m.track_id = track_id;
    // Element by element, so that each name's buffer is reused.
    m.joint_names.truncate(joint_names.len());
    let reused = m.joint_names.len();
    for (d, s) in m.joint_names.iter_mut().zip(joint_names) {
        d.clone_from(s);
    }
    m.joint_names.extend_from_slice(&joint_names[reused..]);
    m.units = Units::Dictionary as u8;
    m.positions.clone_from(&e.pose);
    m.position_std.clone_from(&e.pose_std);
    to_image(&e.keypoints, &mut m.keypoints);
    m.keypoint_std.clear();
    m.keypoint_std
        .extend(e.keypoint_std.iter().map(|s| s * map.mean_scale()));
    to_image(&e.projected, &mut m.projected);
    m.lag = e.lag as u32;
    m.state = match e.state {
        TrackState::Initialising => msgs::SkeletonState::Initialising,
        TrackState::Tracking => msgs::SkeletonState::Tracking,
        TrackState::Lost => msgs::SkeletonState::Lost,
    } as u8;
}
