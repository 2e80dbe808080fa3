//! Transports: one [`Sink`] and one [`Source`] trait, several backends.
//!
//! A node talks to the world only through these two traits, so the same estimator runs
//! over any of them, and one conformance suite (`tests/transport.rs`) runs against
//! every backend:
//!
//! - [`memory`]: a bounded in-process channel (the pipeline mode, `posestream run`);
//! - [`mcap`]: a topic of a recording (write: [`posestream_msgs::recording::Recorder`]; read:
//!   [`posestream_msgs::recording::RecordingReader`]);
//! - [`ros2`]: a ROS 2 topic over DDS (`ros2-client`, no ROS installation needed);
//! - [`shm`]: iceoryx2 shared memory;
//! - [`foxglove`]: a live view in the Foxglove app (the Foxglove WebSocket protocol;
//!   sinks only).
//!
//! [`runtime`] has the same sources awaited on a tokio runtime ([`runtime::AsyncSource`]).
//!
//! Messages are the ROS 2 types of [`posestream_msgs`], whatever the transport.

pub mod foxglove;
pub mod mcap;
pub mod memory;
pub mod read_ahead;
pub mod ros2;
pub mod runtime;
pub mod shm;

use std::time::Duration;

use serde::Serialize;
use serde::de::DeserializeOwned;

use posestream_msgs::{HeatMaps, HeatMapsView, RosMessage};

/// A message any transport can carry.
pub trait Message: RosMessage + Serialize + DeserializeOwned + Clone + Send + 'static {}

impl<M: RosMessage + Serialize + DeserializeOwned + Clone + Send + 'static> Message for M {}

/// What [`Source::recv`] got.
#[derive(Debug, Clone, PartialEq)]
pub enum Received<M> {
    /// A message and its time stamp (nanoseconds: log time in recordings, the sender's
    /// clock otherwise).
    Message(M, u64),
    /// Nothing arrived within the timeout; more may come.
    Idle,
    /// Nothing more will come (end of a recording, every sender gone).
    Closed,
}

/// Why a transport failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// A publisher, subscriber, service or file could not be set up.
    #[error("{transport}: cannot set up {what}: {reason}")]
    Setup {
        /// The backend.
        transport: &'static str,
        /// What was being set up (a topic, a service).
        what: String,
        /// The cause.
        reason: String,
    },
    /// A message could not be sent.
    #[error("{transport}: cannot send on {topic}: {reason}")]
    Send {
        /// The backend.
        transport: &'static str,
        /// The topic or service.
        topic: String,
        /// The cause.
        reason: String,
    },
    /// A message arrived but could not be read; the source can go on.
    #[error("{transport}: malformed message on {topic}: {reason}")]
    Malformed {
        /// The backend.
        transport: &'static str,
        /// The topic or service.
        topic: String,
        /// The cause.
        reason: String,
    },
    /// A message arrived that declares sizes beyond the configured limits; it was not
    /// copied. The source can go on.
    #[error("{transport}: message on {topic} refused: {reason}")]
    BeyondLimits {
        /// The backend.
        transport: &'static str,
        /// The topic or service.
        topic: String,
        /// What is beyond which limit.
        reason: String,
    },
    /// The sink failed earlier (the first failure was reported) and takes nothing more.
    #[error("{transport}: {topic} is closed after an earlier failure")]
    Closed {
        /// The backend.
        transport: &'static str,
        /// The topic or service.
        topic: String,
    },
    /// The source cannot go on (a recording cut short, a broken connection).
    #[error("{transport}: {topic}: {reason}")]
    Broken {
        /// The backend.
        transport: &'static str,
        /// The topic or service.
        topic: String,
        /// The cause.
        reason: String,
    },
}

/// Where messages of type `M` go: a publisher.
pub trait Sink<M>: Send {
    /// Sends one message, stamped `stamp_ns` (the log time in a recording).
    fn send(&mut self, message: &M, stamp_ns: u64) -> Result<(), TransportError>;

    /// Sends one message the caller gives up: a sink that keeps messages (the in-memory
    /// channel) takes it without copying; the others serialise it as [`Sink::send`].
    fn send_owned(&mut self, message: M, stamp_ns: u64) -> Result<(), TransportError> {
        self.send(&message, stamp_ns)
    }
    /// Makes everything sent so far durable or delivered as far as the backend can
    /// (a recording flushes its chunk); sending may go on afterwards.
    fn flush(&mut self) -> Result<(), TransportError> {
        Ok(())
    }
}

/// Where messages of type `M` come from: a subscriber.
pub trait Source<M>: Send {
    /// Waits up to `timeout` for the next message. A [`TransportError::Malformed`] or
    /// [`TransportError::BeyondLimits`] message is skipped: the next call goes on with
    /// the one after it.
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError>;
}

impl<M, S: Sink<M> + ?Sized> Sink<M> for Box<S> {
    fn send(&mut self, message: &M, stamp_ns: u64) -> Result<(), TransportError> {
        (**self).send(message, stamp_ns)
    }
    fn send_owned(&mut self, message: M, stamp_ns: u64) -> Result<(), TransportError> {
        (**self).send_owned(message, stamp_ns)
    }
    fn flush(&mut self) -> Result<(), TransportError> {
        (**self).flush()
    }
}

impl<M, S: Source<M> + ?Sized> Source<M> for Box<S> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        (**self).recv(timeout)
    }
}

/// Heat-map frames lent to the caller one at a time, instead of handed over as
/// messages: a transport whose frames live in its own buffers (an iceoryx2 sample)
/// lends them where they are, without a copy. Any [`Source`] of [`HeatMaps`] is one
/// through [`Lend`] (each message lent as its [`HeatMaps::view`]).
pub trait FrameSource: Send {
    /// Waits up to `timeout` for the next frame and lends it to `take` with its stamp
    /// (and returns `Received::Message((), stamp)`). Errors as [`Source::recv`]: after a
    /// [`TransportError::Malformed`] or [`TransportError::BeyondLimits`] one the next
    /// call goes on.
    fn recv_frame(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError>;

    /// Whether the frames arrive live, so that a pause in wall time is a pause of the
    /// camera (true by default). A replayed recording's time is in its stamps: the
    /// estimator then ends an idle track by those alone.
    fn live(&self) -> bool {
        true
    }

    /// The camera's calibration, if one came since the last call. A source that carries
    /// one beside the frames (a recording's camera-info topic) returns
    /// `Received::Idle` from [`FrameSource::recv_frame`] when it read one, so that the
    /// caller takes it before the frames after it.
    fn camera_info(&mut self) -> Option<posestream_msgs::sensor::CameraInfo> {
        None
    }

    /// Transforms (`/tf_static`, `/tf`), if some came since the last call; returned as
    /// [`FrameSource::camera_info`] is.
    fn transforms(&mut self) -> Option<posestream_msgs::tf::TFMessage> {
        None
    }
}

/// A [`Source`] of [`HeatMaps`] messages as a [`FrameSource`]: each message is lent as
/// its view.
#[derive(Debug)]
pub struct Lend<S>(pub S);

impl<S: Source<HeatMaps>> FrameSource for Lend<S> {
    fn recv_frame(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        Ok(match self.0.recv(timeout)? {
            Received::Message(m, stamp) => {
                take(&m.view(), stamp);
                Received::Message((), stamp)
            }
            Received::Idle => Received::Idle,
            Received::Closed => Received::Closed,
        })
    }
}

impl<S: FrameSource + ?Sized> FrameSource for Box<S> {
    fn recv_frame(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        (**self).recv_frame(timeout, take)
    }
    fn live(&self) -> bool {
        (**self).live()
    }
}
