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
pub mod recycle;
pub mod ros2;
pub mod runtime;
pub mod shm;

use std::time::Duration;

use serde::Serialize;
use serde::de::DeserializeOwned;

pub use posestream_base::ports::{Received, Sink, Source, TransportError};
use posestream_msgs::sensor::CameraInfo;
use posestream_msgs::tf::{TFMessage, TfTopic};
use posestream_msgs::{HeatMaps, HeatMapsView, RosMessage};

/// A message any transport can carry.
pub trait Message:
    RosMessage + Serialize + DeserializeOwned + Clone + Default + Send + Sync + 'static
{
}

impl<M> Message for M where
    M: RosMessage + Serialize + DeserializeOwned + Clone + Default + Send + Sync + 'static
{
}

/// Where encoded messages of type `M` go (CDR with its encapsulation header, as a
/// recording holds them): the output recording and the live view take a message's bytes,
/// so that one encoding serves every such sink of a publisher.
pub trait EncodedSink<M>: Send {
    /// Whether a message sent now would go anywhere (the live view: while a viewer
    /// subscribes); one nobody wants is not encoded. True by default.
    fn wanted(&self) -> bool {
        true
    }

    /// Sends one encoded message, stamped `stamp_ns` (the log time in a recording).
    fn send_encoded(&mut self, data: &[u8], stamp_ns: u64) -> Result<(), TransportError>;

    /// As [`Sink::flush`].
    fn flush(&mut self) -> Result<(), TransportError> {
        Ok(())
    }
}

impl<M, S: EncodedSink<M> + ?Sized> EncodedSink<M> for Box<S> {
    fn wanted(&self) -> bool {
        (**self).wanted()
    }
    fn send_encoded(&mut self, data: &[u8], stamp_ns: u64) -> Result<(), TransportError> {
        (**self).send_encoded(data, stamp_ns)
    }
    fn flush(&mut self) -> Result<(), TransportError> {
        (**self).flush()
    }
}

/// What a [`FrameSource`] lends: a heat-map frame, or what comes in the same stream
/// beside the frames (a recording's camera calibration and transforms), in stream order.
#[derive(Debug, Clone, Copy)]
pub enum Lent<'a> {
    /// A heat-map frame.
    Frame(&'a HeatMapsView<'a>),
    /// The camera's calibration.
    Calibration(&'a CameraInfo),
    /// Transforms, and the topic they came on (`/tf_static`, `/tf`).
    Transforms(&'a TFMessage, TfTopic),
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

    /// Waits up to `timeout` for the next thing the stream carries and lends it to `take`
    /// with its stamp: a frame, as [`FrameSource::recv_frame`] does, or, from a source
    /// that carries them in the same stream (a recording), the camera's calibration or
    /// transforms in their place among the frames. A source of frames only lends them
    /// ([`frames_only`]); required, so that no wrapper loses what a source carries.
    fn recv_input(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError>;

    /// Whether the frames arrive live, so that a pause in wall time is a pause of the
    /// camera (true by default). A replayed recording's time is in its stamps.
    fn live(&self) -> bool {
        true
    }
}

/// [`FrameSource::recv_input`] of a source of frames only: its frames lent as such.
pub fn frames_only<S: FrameSource + ?Sized>(
    source: &mut S,
    timeout: Duration,
    take: &mut dyn FnMut(Lent<'_>, u64),
) -> Result<Received<()>, TransportError> {
    source.recv_frame(timeout, &mut |frame, stamp| take(Lent::Frame(frame), stamp))
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

    fn recv_input(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        frames_only(self, timeout, take)
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
    fn recv_input(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        (**self).recv_input(timeout, take)
    }
    fn live(&self) -> bool {
        (**self).live()
    }
}
