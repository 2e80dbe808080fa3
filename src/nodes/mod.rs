//! The nodes of the service: thin adapters between messages ([`crate::msgs`]) and the
//! math ([`crate::streaming`]). Nothing here solves anything.
//!
//! - [`EstimatorNode`]: heat-map messages in, [`Skeleton3D`] messages out;
//! - [`replay`]: a recording's heat maps through the estimator loop, skeletons to a
//!   recording;
//! - [`service`]: the detector, estimator, pipeline and recorder loops over any
//!   transport ([`crate::transport`]), and their wiring from the configuration;
//! - [`markers`]: skeletons as `visualization_msgs/MarkerArray`, and over each image;
//! - [`arrays`]: the skeletons of one image together (`Skeleton3DArray`);
//! - [`camera`]: the calibration assumed for images without one (`CameraInfo`);
//! - [`frames`]: each person's body and joint frames for `/tf`;
//! - [`hri`]: skeletons as REP-155 (ROS4HRI) bodies: ids, regions, 2D skeletons;
//! - [`shown_images`]: the camera images as the Foxglove live view shows them;
//! - [`unknown_ids`]: ids for people whose heat maps came without one;
//! - [`fusion`]: several calibrated cameras' heat maps in, one skeleton per person out.

pub mod arrays;
pub mod camera;
pub mod config;
pub mod frames;
pub mod fusion;
pub mod hri;
pub mod images;
pub mod latency;
pub mod markers;
pub mod priority;
pub mod replay;
pub mod service;
pub mod shown_images;
pub mod tf_buffer;
pub mod unknown_ids;

use std::collections::{BTreeMap, VecDeque};
use std::panic::AssertUnwindSafe;

use self::tf_buffer::TfBuffer;
use crate::camera::Intrinsics;
use crate::error::EstimateError;
use crate::estimator::Estimator;
use crate::floor::{BodyScale, FloorModel, FloorSource};
use crate::learnt_floor::{FloorLearner, LearningSettings, LearningState, LearntFloor};
use crate::limits::{LimitError, Limits};
use crate::metric::{MetricPose, MetricSettings, MetricStep};
use crate::msgs::tf::TFMessage;
use crate::msgs::{self, DecodeError, Skeleton3D, Time, Units};
use crate::skeleton::same_layout;
use crate::streaming::{
    Estimates, FrameEstimate, FrameMaps, StreamCounters, TrackState, WindowEstimator,
};
use crate::transport::TransportError;
use posestream_base::{CropBox, PixelMap};

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
    /// A `sensor_msgs/CameraInfo` the metric step cannot use (zero, negative or
    /// non-finite focal lengths, no image size, an image beyond the limits): refused;
    /// the camera known before stays.
    #[error("camera info: {reason}; refused")]
    CameraInfo {
        /// What is wrong with it.
        reason: String,
    },
    /// A transform the TF buffer cannot hold (`tf_buffer`): refused.
    #[error("transform: {reason}; refused")]
    Transform {
        /// What is wrong with it.
        reason: String,
    },
    /// A frame of a new track while `max_tracks` tracks run, each with a frame of the
    /// same image: refused.
    #[error(
        "frame {sequence}: track {track_id} would be track {} of at most {max_tracks} (estimator.max_tracks); refused",
        max_tracks + 1
    )]
    TooManyTracks {
        /// The frame.
        sequence: u64,
        /// Its track.
        track_id: u32,
        /// The bound.
        max_tracks: usize,
    },
    /// A second message of one image (the same capture time and frame number) with the
    /// same track id: refused, not taken for a later frame.
    #[error(
        "frame {sequence}: track {track_id} came twice in one image (duplicate id in one image); the second is refused"
    )]
    DuplicateId {
        /// The frame.
        sequence: u64,
        /// The id given twice.
        track_id: u32,
    },
    /// The fusion node: a frame of a fused frame already made (its camera is behind the
    /// others by more than `[fusion] wait`): refused.
    #[error(
        "frame {sequence} of camera {camera}: {behind_ms:.0} ms behind the fused frames made; refused"
    )]
    Late {
        /// The frame.
        sequence: u64,
        /// Its camera.
        camera: String,
        /// How far behind.
        behind_ms: f64,
    },
    /// The fusion node: a frame whose capture time is far from the other cameras' (its
    /// camera's clock is off).
    #[error(
        "frame {sequence} of camera {camera}: its capture time is {seconds:+.1} s from the other cameras' fused frames (is its clock off?); refused"
    )]
    Clock {
        /// The frame.
        sequence: u64,
        /// Its camera.
        camera: String,
        /// How far, seconds (positive: ahead).
        seconds: f64,
    },
    /// The fusion node: a frame of a camera whose intrinsics or pose are not known yet.
    #[error(
        "frame {sequence} of camera {camera}: not calibrated yet (waiting for {what}); refused"
    )]
    Uncalibrated {
        /// The frame.
        sequence: u64,
        /// Its camera.
        camera: String,
        /// What is missing.
        what: String,
    },
    /// The fusion node: a frame that does not fit its camera (another frame id, no frame
    /// id, too many tracks).
    #[error("frame {sequence}: {reason}; refused")]
    Camera {
        /// The frame.
        sequence: u64,
        /// What is wrong.
        reason: String,
    },
    /// A person without an id whom the tracker gave none: a box on a person already in
    /// the image, or no room.
    #[error(
        "frame {sequence}: a person without an id got none from the tracker (a box on someone already in the image, or estimator.max_tracks people already)"
    )]
    NoTrack {
        /// The frame.
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
            Self::TooManyTracks { .. } => "too-many-tracks",
            Self::DuplicateId { .. } => "duplicate-id",
            Self::NoTrack { .. } => "no-track",
            Self::CameraInfo { .. } => "camera-info",
            Self::Transform { .. } => "tf",
            Self::Late { .. } => "late",
            Self::Clock { .. } => "clock",
            Self::Uncalibrated { .. } => "uncalibrated",
            Self::Camera { .. } => "camera",
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
    /// The heat maps' size (columns, rows).
    map_size: (f64, f64),
    frame_id: String,
}

/// The intrinsics and the image size (columns, rows) of a camera's calibration
/// (`sensor_msgs/CameraInfo`'s `k`, `width`, `height`); why it cannot be used otherwise
/// (focal lengths, no image size, an image beyond the limits).
pub fn calibration(
    info: &msgs::sensor::CameraInfo,
    limits: &Limits,
) -> Result<(Intrinsics, (f64, f64)), String> {
    let k = &info.k;
    let camera = Intrinsics::new(k[0], k[4], k[2], k[5])?;
    if info.width == 0 || info.height == 0 {
        return Err(format!("image size {} x {}", info.width, info.height));
    }
    limits
        .image(u64::from(info.width), u64::from(info.height))
        .map_err(|e| e.to_string())?;
    Ok((camera, (f64::from(info.width), f64::from(info.height))))
}

/// The kind of refusal of a message its transport refused (`beyond-limits`, else
/// `undecodable`).
pub fn transport_refusal(error: &TransportError) -> &'static str {
    match error {
        TransportError::BeyondLimits { .. } => "beyond-limits",
        _ => "undecodable",
    }
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

/// One person's track in the estimator node: its window and what the node remembers of
/// its frames until their last estimates are out.
struct Track {
    id: u32,
    window: WindowEstimator,
    frames: VecDeque<FrameInfo>,
    /// Capture time of the newest frame the window took.
    last_stamp_ns: i64,
    /// Its frame number.
    last_sequence: u64,
    /// When it took it, in frames the node took (the least recent one makes room).
    last_taken: u64,
    /// A duplicate of its id in one image was warned about.
    duplicate_warned: bool,
    /// The person's size from their feet on the floor (with a floor).
    scale: BodyScale,
}

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

/// The floor from TF: the transforms taken, the floor frame, and what the floor in hand
/// was looked up for (the buffer's version and the camera frame).
struct FloorFromTf {
    buffer: TfBuffer,
    frame: String,
    looked_up: Option<(u64, String)>,
    /// The floor was missing once (logged once).
    missing_said: bool,
}

/// The metric step of a node whose camera is known.
struct Metric {
    step: MetricStep,
    camera: Intrinsics,
    /// The images' size (columns, rows), when a `CameraInfo` gave it: a crop box whose
    /// centre is outside is not of these images.
    size: Option<(f64, f64)>,
    /// The floor under the camera, when known (`[estimator.metric.floor]`).
    floor: Option<FloorModel>,
    /// With the floor learnt: the learner, and the lag of the estimates it learns from
    /// (the refined ones when the window publishes them).
    learner: Option<(FloorLearner, usize)>,
    /// The frame in hand, in metres (reused).
    pose: MetricPose,
    /// Estimates the step failed on (published in dictionary units).
    failures: u64,
    /// What the step cost so far.
    timing: MetricTiming,
}

/// Where learning the floor stands, for the reports: the state, and the floor trusted
/// (else the newest fit, not trusted) with its uncertainty.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FloorReport {
    /// `learning`, `accepted`, or `rejected: <why>`.
    pub state: String,
    /// Person-frames kept.
    pub points: usize,
    /// The camera's height above the floor, metres.
    pub height: Option<f64>,
    /// Its standard deviation, metres.
    pub height_std: Option<f64>,
    /// Pitch, degrees, positive looking down.
    pub pitch: Option<f64>,
    /// Its standard deviation, degrees.
    pub pitch_std: Option<f64>,
    /// Roll, degrees.
    pub roll: Option<f64>,
    /// Its standard deviation, degrees.
    pub roll_std: Option<f64>,
    /// Of the roots, those on their plane, as a fraction.
    pub inliers: Option<f64>,
}

impl FloorReport {
    fn of(learner: &FloorLearner) -> Self {
        let newest = learner.floor().or(learner.newest());
        let angles = newest.map(|f| f.model.pitch_roll());
        Self {
            state: match learner.state() {
                LearningState::Learning => "learning".into(),
                LearningState::Accepted => "accepted".into(),
                LearningState::Rejected(why) => format!("rejected: {why}"),
            },
            points: learner.points(),
            height: newest.map(|f| f.model.height()),
            height_std: newest.map(|f| f.height_std),
            pitch: angles.map(|a| a.0),
            pitch_std: newest.map(|f| f.pitch_std),
            roll: angles.map(|a| a.1),
            roll_std: newest.map(|f| f.roll_std),
            inliers: newest.map(|f| f.inliers),
        }
    }
}

/// What the metric step cost so far (`EstimatorNode::metric_timing`).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct MetricTiming {
    /// Estimates adjusted (each published estimate of each person: the newest and, with
    /// a lag, its refinement).
    pub estimates: u64,
    /// Seconds in the step, summed.
    pub seconds: f64,
    /// Of those, the ones adjusted (a metric pose made).
    pub adjusted: u64,
    /// The perspective adjustment's iterations on those adjusted, summed.
    pub iterations: u64,
}

/// Tracks an estimator node runs at once unless configured otherwise
/// (`[estimator] max_tracks`).
pub const DEFAULT_MAX_TRACKS: usize = 12;

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

    /// The same node, publishing metres in the camera frame when `settings` name the
    /// camera's intrinsics (dictionary units otherwise).
    pub fn with_metric(mut self, settings: &MetricSettings) -> Result<Self, SetupError> {
        // Checked here, so that a camera given later cannot fail on them.
        MetricStep::new(self.template.estimator(), settings.clone())?;
        self.metric_settings = settings.clone();
        self.metric = None;
        self.tf = (settings.floor.source == FloorSource::Tf).then(|| FloorFromTf {
            buffer: TfBuffer::new(),
            frame: settings.floor.frame.clone(),
            looked_up: None,
            missing_said: false,
        });
        if let Some(camera) = settings.camera() {
            self.set_camera(camera, None)?;
        }
        Ok(self)
    }

    fn set_camera(
        &mut self,
        camera: Intrinsics,
        size: Option<(f64, f64)>,
    ) -> Result<(), EstimateError> {
        let learner = (self.metric_settings.floor.source == FloorSource::Learnt).then(|| {
            let s = &self.metric_settings;
            let settings = LearningSettings {
                root_height_m: s.floor.root_height * s.mean_limb_length,
                ..LearningSettings::default()
            };
            let window = self.template.settings();
            let lag = match window.outputs {
                crate::streaming::Outputs::Newest => 0,
                _ => window.lag,
            };
            (FloorLearner::new(settings), lag)
        });
        match &mut self.metric {
            Some(m) => {
                if m.camera != camera && learner.is_some() {
                    // Another camera: what was learnt was of the other's floor.
                    m.learner = learner;
                    m.floor = None;
                }
                m.camera = camera;
                m.size = size;
            }
            None => {
                self.metric = Some(Metric {
                    step: MetricStep::new(self.template.estimator(), self.metric_settings.clone())?,
                    camera,
                    size,
                    floor: self.metric_settings.floor.configured(),
                    learner,
                    pose: MetricPose::default(),
                    failures: 0,
                    timing: MetricTiming::default(),
                })
            }
        }
        Ok(())
    }

    /// Takes the camera's calibration (`sensor_msgs/CameraInfo`, the intrinsics `k` of
    /// the images the crop boxes are in): from now on skeletons are in metres, with
    /// these intrinsics in place of any configured ones. A calibration the step cannot
    /// use is refused and counted (`camera-info`); the camera known before stays.
    pub fn camera_info(&mut self, info: &msgs::sensor::CameraInfo) -> Result<(), NodeError> {
        let result = self.camera_info_inner(info);
        if let Err(e) = &result {
            self.refused.note(e.kind(), e);
        }
        result
    }

    fn camera_info_inner(&mut self, info: &msgs::sensor::CameraInfo) -> Result<(), NodeError> {
        let refuse = |reason: String| NodeError::CameraInfo { reason };
        let (camera, size) = calibration(info, &self.limits).map_err(refuse)?;
        let size = Some(size);
        if let Some(m) = &self.metric
            && m.camera == camera
            && m.size == size
        {
            return Ok(());
        }
        self.set_camera(camera, size)
            .map_err(|e| refuse(e.to_string()))
    }

    /// Takes transforms (`/tf_static`, `/tf`): with the floor from TF, the camera's place
    /// over the floor frame comes from them (the newest of each frame). Transforms the
    /// buffer cannot hold are refused and counted (`tf`); without a floor from TF they
    /// are not looked at. People's frames (posestream's own body and joint frames, heard
    /// back on `/tf`: [`frames::is_body_transform`]) are passed over.
    pub fn transforms(&mut self, message: &TFMessage) {
        let Some(tf) = &mut self.tf else {
            return;
        };
        let wanted = |t: &msgs::tf::TransformStamped| {
            !frames::is_body_transform(&t.header.frame_id, &t.child_frame_id)
        };
        for reason in tf.buffer.take_where(message, wanted) {
            let e = NodeError::Transform { reason };
            self.refused.note(e.kind(), &e);
        }
    }

    /// The floor the metric step uses now (from the configuration, TF, or learnt and
    /// trusted).
    pub fn floor(&self) -> Option<FloorModel> {
        self.metric.as_ref().and_then(|m| m.floor)
    }

    /// Where learning the floor stands (`None` unless it is learnt and the camera known).
    pub fn learnt_floor(&self) -> Option<FloorReport> {
        let (learner, _) = self.metric.as_ref()?.learner.as_ref()?;
        Some(FloorReport::of(learner))
    }

    /// With the floor from TF: looks it up again for `camera_frame` when a transform
    /// came since, or the camera frame changed.
    fn update_floor(&mut self, camera_frame: &str) {
        let (Some(tf), Some(m)) = (&mut self.tf, &mut self.metric) else {
            return;
        };
        let version = tf.buffer.version();
        if tf
            .looked_up
            .as_ref()
            .is_some_and(|(v, f)| *v == version && f == camera_frame)
        {
            return;
        }
        // The frame id's buffer kept (no allocation while a robot's /tf streams).
        match &mut tf.looked_up {
            Some((v, f)) => {
                *v = version;
                f.clear();
                f.push_str(camera_frame);
            }
            None => tf.looked_up = Some((version, camera_frame.to_owned())),
        }
        let pose = tf.buffer.lookup(&tf.frame, camera_frame);
        m.floor = pose.and_then(|p| FloorModel::new(p.rotation, p.translation.vector).ok());
        if m.floor.is_none() && !tf.missing_said {
            tf.missing_said = true;
            tracing::warn!(
                "no floor yet: no transform from {} to the camera frame {camera_frame:?} on \
                 /tf_static or /tf (or the camera is not above it); metres from the assumed size",
                tf.frame
            );
        }
    }

    /// Estimates the metric step failed on (a pose without size, a non-finite result):
    /// published in dictionary units.
    pub fn metric_failures(&self) -> u64 {
        self.metric.as_ref().map_or(0, |m| m.failures)
    }

    /// What the metric step cost so far (zero without a camera).
    pub fn metric_timing(&self) -> MetricTiming {
        self.metric
            .as_ref()
            .map_or_else(MetricTiming::default, |m| m.timing)
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
        self.refused.note(transport_refusal(error), error);
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
            });
            info.sequence = msg.sequence;
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
            scale: BodyScale::new(self.metric_settings.floor.contact_frames),
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

/// Frames a track remembers at most: those an estimate can still come for (the window
/// and the lag), and one more.
fn frames_kept(window: &WindowEstimator) -> usize {
    let settings = window.settings();
    settings.size + settings.lag + 1
}

/// Turns a track's estimates into messages (written over `spare` ones); forgets frames
/// no estimate can need any more. An estimate with non-finite values is counted, not
/// published.
#[allow(
    clippy::too_many_arguments,
    reason = "disjoint borrows of the node's fields, so that a track is borrowed beside them"
)]
fn release(
    track: &mut Track,
    estimates: &Estimates,
    joint_names: &[String],
    mut metric: Option<&mut Metric>,
    spare: &mut Vec<Skeleton3D>,
    refused: &mut Refusals,
    out: &mut Vec<Skeleton3D>,
) {
    let keep = frames_kept(&track.window);
    for e in estimates.iter() {
        let Some(info) = track.frames.iter().rev().find(|f| f.sequence == e.sequence) else {
            continue;
        };
        let metres = match metric.as_deref_mut() {
            Some(m) => match metric_pose(m, e, info, &mut track.scale) {
                Ok(()) => Some(&m.pose),
                Err(error) => {
                    m.failures += 1;
                    tracing::debug!(
                        "frame {}: no metric pose ({error}); published in dictionary units",
                        e.sequence
                    );
                    None
                }
            },
            None => None,
        };
        let mut message = spare.pop().unwrap_or_default();
        write_skeleton(&mut message, e, info, joint_names, track.id, metres);
        let placed = metres.is_some();
        if placed && let Some(m) = metric.as_deref_mut() {
            learn_floor(m, track.id, e.lag);
        }
        if message.is_finite() {
            out.push(message);
        } else {
            spare.push(message);
            let e = NodeError::NonFiniteOutput {
                sequence: e.sequence,
            };
            refused.note(e.kind(), &e);
        }
    }
    while track.frames.len() > keep {
        track.frames.pop_front();
    }
}

/// With the floor learnt: the root of the pose in hand (of track `id`, estimate lag
/// `lag`) to the learner; the floor the metric step uses follows what the learner
/// trusts (the change logged).
fn learn_floor(m: &mut Metric, id: u32, lag: usize) {
    let Some((learner, learn_lag)) = &mut m.learner else {
        return;
    };
    if lag != *learn_lag {
        return;
    }
    let before = learner.state();
    if learner.note(id, m.pose.root_at_size) {
        m.floor = learner.floor().map(|f| f.model);
    }
    let after = learner.state();
    if std::mem::discriminant(&before) != std::mem::discriminant(&after) {
        match (after, learner.newest()) {
            (LearningState::Accepted, Some(f)) => {
                tracing::info!("floor learnt: {}", describe(f));
            }
            (LearningState::Rejected(why), Some(f)) => {
                tracing::warn!(
                    "the learnt floor is not trusted: {why} ({}); metres from the assumed size",
                    describe(f)
                );
            }
            _ => tracing::info!("the learnt floor is uncertain again: learning on"),
        }
    }
}

/// A learnt floor in words.
fn describe(f: &LearntFloor) -> String {
    let (pitch, roll) = f.model.pitch_roll();
    format!(
        "camera {:.2} +- {:.2} m high, pitch {pitch:.1} +- {:.1}, roll {roll:.1} +- {:.1} degrees, \
         from {} person-frames ({:.0} % on the plane)",
        f.model.height(),
        f.height_std,
        f.pitch_std,
        f.roll_std,
        f.points,
        100.0 * f.inliers
    )
}

/// The metric pose of estimate `e` into `m.pose`: refused when the frame's crop box is
/// not in the camera's images (it does not overlap them; a crop may reach past an
/// image's edge, as BlazePose's body circle does).
fn metric_pose(
    m: &mut Metric,
    e: &FrameEstimate,
    info: &FrameInfo,
    scale: &mut BodyScale,
) -> Result<(), String> {
    if let Some((width, height)) = m.size {
        let [x0, y0] = info.to_image.apply(-0.5, -0.5);
        let [x1, y1] = info
            .to_image
            .apply(info.map_size.0 - 0.5, info.map_size.1 - 0.5);
        let overlaps = |a0: f64, a1: f64, n: f64| a0.min(a1) < n && a0.max(a1) > 0.0;
        if !(overlaps(x0, x1, width) && overlaps(y0, y1, height)) {
            return Err(format!(
                "the crop box ({x0:.0}, {y0:.0}) - ({x1:.0}, {y1:.0}) is outside the camera's {width} x {height} images"
            ));
        }
    }
    let began = std::time::Instant::now();
    let adjusted = m
        .step
        .adjust(
            e,
            &info.to_image,
            &m.camera,
            m.floor.as_ref().map(|f| (f, scale)),
            &mut m.pose,
        )
        .map_err(|e| e.to_string());
    m.timing.estimates += 1;
    m.timing.seconds += began.elapsed().as_secs_f64();
    if adjusted.is_ok() {
        m.timing.adjusted += 1;
        m.timing.iterations += m.step.iterations() as u64;
    }
    adjusted
}

/// The message of one estimate, written over `m` (its buffers reused): in metres when
/// `metres` is the estimate's metric pose, in dictionary units otherwise.
fn write_skeleton(
    m: &mut Skeleton3D,
    e: &FrameEstimate,
    info: &FrameInfo,
    joint_names: &[String],
    track_id: u32,
    metres: Option<&MetricPose>,
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
    if let Some(metres) = metres {
        m.units = Units::Metres as u8;
        m.metric_source = match metres.source {
            crate::metric::MetricSource::Size => msgs::MetricSource::Size,
            crate::metric::MetricSource::Floor => msgs::MetricSource::Floor,
        } as u8;
        m.positions.clone_from(&metres.positions);
        m.position_std.clone_from(&metres.position_std);
        m.keypoints.clone_from(&metres.keypoints);
        m.keypoint_std.clone_from(&metres.keypoint_std);
        m.projected.clone_from(&metres.projected);
    } else {
        m.units = Units::Dictionary as u8;
        m.metric_source = msgs::MetricSource::None as u8;
        m.positions.clone_from(&e.pose);
        m.position_std.clone_from(&e.pose_std);
        to_image(&e.keypoints, &mut m.keypoints);
        m.keypoint_std.clear();
        m.keypoint_std
            .extend(e.keypoint_std.iter().map(|s| s * map.mean_scale()));
        to_image(&e.projected, &mut m.projected);
    }
    m.lag = e.lag as u32;
    m.state = match e.state {
        TrackState::Initialising => msgs::SkeletonState::Initialising,
        TrackState::Tracking => msgs::SkeletonState::Tracking,
        TrackState::Lost => msgs::SkeletonState::Lost,
    } as u8;
}
