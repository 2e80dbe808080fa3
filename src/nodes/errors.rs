//! Why a node did not use a message ([`NodeError`], counted by kind: [`Refusals`]), why
//! a node could not be set up ([`SetupError`]), and why a service could not start or had
//! to stop ([`ServiceError`]).

use std::collections::BTreeMap;

use crate::error::EstimateError;
use crate::limits::LimitError;
use crate::msgs::DecodeError;
use crate::recording::RecordingError;
use crate::transport::TransportError;

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

/// Why a service could not start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The estimator could not be set up.
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// A transport could not be set up, or broke.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The output recording could not be written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The node's I/O runtime could not start.
    #[error("cannot start the I/O runtime: {0}")]
    Runtime(std::io::Error),
    /// A thread of the pipeline panicked.
    #[error("the {0} thread stopped unexpectedly")]
    Thread(&'static str),
    /// An output is one of the inputs.
    #[error(transparent)]
    OutputIsInput(#[from] crate::files::OutputIsInput),
    /// The input broke part way (a corrupt recording): the outputs are left as they
    /// were; what was recorded before is kept in the recording's `.partial` file.
    #[error("{reason}{}", kept.as_ref().map(|k| format!("; what was recorded before is in {}", k.display())).unwrap_or_default())]
    Input {
        /// What was wrong with the input.
        reason: String,
        /// The output recording's temporary file, if recording.
        kept: Option<std::path::PathBuf>,
    },
}
