//! Transports: one [`Sink`] and one [`Source`] trait, several backends.
//!
//! A node talks to the world only through these two traits (the foundation's ports,
//! [`posestream_base::ports`], re-exported here), so the same estimator runs
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

pub use posestream_base::ports::{Received, Sink, Source, TransportError};
use posestream_msgs::{HeatMaps, HeatMapsView, RosMessage};

/// A message any transport can carry.
pub trait Message: RosMessage + Serialize + DeserializeOwned + Clone + Send + 'static {}

impl<M: RosMessage + Serialize + DeserializeOwned + Clone + Send + 'static> Message for M {}

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
