//! An in-process transport: a bounded channel. A full channel makes the sender wait
//! (backpressure), as a reliable ROS 2 topic with a full history does. A message sent
//! with [`Sink::send_owned`] moves through it (no copy); [`Sink::send`] clones it.
//!
//! ```
//! use std::time::Duration;
//! use posestream_msgs::Skeleton3D;
//! use posestream_transport::{Received, Sink, Source, memory};
//!
//! let (mut sink, mut source) = memory::channel::<Skeleton3D>(4);
//! let skeleton = Skeleton3D { sequence: 7, ..Skeleton3D::default() };
//! sink.send(&skeleton, 1_000)?;
//! match source.recv(Duration::from_millis(10))? {
//!     Received::Message(m, stamp) => assert_eq!((m.sequence, stamp), (7, 1_000)),
//!     other => panic!("expected the skeleton, got {other:?}"),
//! }
//! // Given up, a message moves through the channel without a copy.
//! sink.send_owned(Skeleton3D { sequence: 8, ..Skeleton3D::default() }, 2_000)?;
//! match source.recv(Duration::from_millis(10))? {
//!     Received::Message(m, stamp) => assert_eq!((m.sequence, stamp), (8, 2_000)),
//!     other => panic!("expected the skeleton, got {other:?}"),
//! }
//! drop(sink);
//! assert!(matches!(source.recv(Duration::from_millis(10))?, Received::Closed));
//! # Ok::<(), posestream_transport::TransportError>(())
//! ```

use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::time::Duration;

use super::{Received, Sink, Source, TransportError};

/// The sending end.
#[derive(Debug)]
pub struct MemorySink<M> {
    sender: SyncSender<(M, u64)>,
}

/// The receiving end.
#[derive(Debug)]
pub struct MemorySource<M> {
    receiver: Receiver<(M, u64)>,
}

impl<M> Clone for MemorySink<M> {
    fn clone(&self) -> Self {
        Self {
            sender: self.sender.clone(),
        }
    }
}

/// A channel holding at most `capacity` messages in flight (at least 1).
pub fn channel<M>(capacity: usize) -> (MemorySink<M>, MemorySource<M>) {
    let (sender, receiver) = sync_channel(capacity.max(1));
    (MemorySink { sender }, MemorySource { receiver })
}

impl<M: Clone + Send> Sink<M> for MemorySink<M> {
    fn send(&mut self, message: &M, stamp_ns: u64) -> Result<(), TransportError> {
        self.send_owned(message.clone(), stamp_ns)
    }

    fn send_owned(&mut self, message: M, stamp_ns: u64) -> Result<(), TransportError> {
        self.sender
            .send((message, stamp_ns))
            .map_err(|_| TransportError::Send {
                transport: "memory",
                topic: "channel".into(),
                reason: "the receiver is gone".into(),
            })
    }
}

impl<M: Send> Source<M> for MemorySource<M> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        match self.receiver.recv_timeout(timeout) {
            Ok((m, stamp)) => Ok(Received::Message(m, stamp)),
            Err(RecvTimeoutError::Timeout) => Ok(Received::Idle),
            Err(RecvTimeoutError::Disconnected) => Ok(Received::Closed),
        }
    }
}
