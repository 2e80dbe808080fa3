//! Sources awaited on a tokio runtime: a node's I/O (its inputs, its timers, its
//! outputs) waits in one place, on one thread, while its math runs on a thread of its
//! own.
//!
//! - A ROS 2 subscription is awaited natively (`ros2-client`'s async API:
//!   [`Ros2Source`](crate::ros2::Ros2Source) is an [`AsyncSource`]).
//! - Any blocking [`Source`] (an MCAP recording, the in-memory channel, iceoryx2,
//!   whose waits are blocking calls) becomes one through [`Blocking`]: it runs on a
//!   named thread of its own and hands its messages over a bounded channel.
//!
//! Of the sinks only the ROS 2 one has an async side
//! ([`Ros2Sink::send_async`](crate::ros2::Ros2Sink::send_async): while a reliable
//! history is full it waits for room without blocking the runtime, as long as the
//! blocking send would, then fails). The others are called as they are: the in-memory
//! channel and iceoryx2 write to memory, an MCAP recording writes its file (a chunk at
//! a time) on the runtime's thread.
//!
//! ```
//! use posestream_msgs::Skeleton3D;
//! use posestream_transport::runtime::{AsyncSource, Blocking};
//! use posestream_transport::{Received, Sink, memory};
//!
//! let (mut sink, source) = memory::channel::<Skeleton3D>(4);
//! let mut source = Blocking::spawn("example", source, 4)?;
//! sink.send(&Skeleton3D { sequence: 7, ..Skeleton3D::default() }, 1_000)?;
//! drop(sink);
//! let runtime = tokio::runtime::Builder::new_current_thread().build().expect("runtime");
//! runtime.block_on(async {
//!     match source.next().await? {
//!         Received::Message(m, stamp) => assert_eq!((m.sequence, stamp), (7, 1_000)),
//!         other => panic!("expected the skeleton, got {other:?}"),
//!     }
//!     assert!(matches!(source.next().await?, Received::Closed));
//!     Ok::<(), posestream_transport::TransportError>(())
//! })?;
//! # Ok::<(), posestream_transport::TransportError>(())
//! ```

use std::future::Future;
use std::time::Duration;

use tokio::sync::mpsc;

use crate::recycle::Recycler;
use crate::{Received, Source, TransportError};

/// How long the thread of a [`Blocking`] source waits in one call before it looks
/// whether its receiver is still there.
const POLL: Duration = Duration::from_millis(100);

/// Where messages of type `M` come from, awaited on a runtime.
pub trait AsyncSource<M>: Send {
    /// The next message, or [`Received::Closed`] once nothing more will come (never
    /// [`Received::Idle`]). Errors as [`Source::recv`]: after a
    /// [`TransportError::Malformed`] or [`TransportError::BeyondLimits`] one, the next
    /// call goes on.
    ///
    /// Not every source's `next` is cancel-safe: [`Blocking`]'s and the ROS 2 one's
    /// are (a message is either returned or still there for the next call), but an
    /// implementation may do work after taking a message (a detector paces and
    /// publishes it), and dropping its future then loses that message. Race it with a
    /// timer only where losing one is acceptable (at a stop).
    fn next(&mut self) -> impl Future<Output = Result<Received<M>, TransportError>> + Send;

    /// Where messages are handed back once used, if the source decodes its next ones over
    /// them ([`Recycler`]); none by default.
    fn recycler(&self) -> Option<Recycler<M>> {
        None
    }
}

impl<M, S: AsyncSource<M> + ?Sized> AsyncSource<M> for &mut S {
    fn next(&mut self) -> impl Future<Output = Result<Received<M>, TransportError>> + Send {
        (**self).next()
    }
    fn recycler(&self) -> Option<Recycler<M>> {
        (**self).recycler()
    }
}

/// A blocking [`Source`] as an [`AsyncSource`]: the source runs on a thread of its
/// own, which sends what it receives over a bounded channel (at most `capacity`
/// messages wait; then the thread waits, as the source's own sender would). The thread
/// ends when the source closes or breaks, or when this is dropped: the drop waits for
/// it (at most one wait of the source, 100 ms, and the message it is taking), so that
/// the source is gone before what it was opened from. A panic on that thread is a
/// [`TransportError::Broken`] source, never a clean end.
#[derive(Debug)]
pub struct Blocking<M> {
    receiver: mpsc::Receiver<Result<Received<M>, TransportError>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl<M> Drop for Blocking<M> {
    fn drop(&mut self) {
        self.receiver.close();
        if let Some(thread) = self.thread.take() {
            // A panic of the source's thread was printed by the panic hook already.
            let _ = thread.join();
        }
    }
}

impl<M: Send + 'static> Blocking<M> {
    /// Starts a thread named `posestream-<name>` receiving from `source`.
    pub fn spawn(
        name: &str,
        mut source: impl Source<M> + 'static,
        capacity: usize,
    ) -> Result<Self, TransportError> {
        let (sender, receiver) = mpsc::channel(capacity.max(1));
        let thread = std::thread::Builder::new()
            .name(format!("posestream-{name}"))
            .spawn(move || {
                while !sender.is_closed() {
                    let got = source.recv(POLL);
                    let end = match &got {
                        Ok(Received::Idle) => continue,
                        Ok(Received::Message(..))
                        | Err(
                            TransportError::Malformed { .. } | TransportError::BeyondLimits { .. },
                        ) => false,
                        Ok(Received::Closed) | Err(_) => true,
                    };
                    if sender.blocking_send(got).is_err() || end {
                        return;
                    }
                }
            })
            .map_err(|e| TransportError::Setup {
                transport: "runtime",
                what: format!("the thread of {name}"),
                reason: e.to_string(),
            })?;
        Ok(Self {
            receiver,
            thread: Some(thread),
        })
    }
}

impl<M: Send> AsyncSource<M> for Blocking<M> {
    async fn next(&mut self) -> Result<Received<M>, TransportError> {
        if let Some(got) = self.receiver.recv().await {
            return got;
        }
        // The thread is gone: after Closed or a broken source (whose word came
        // first), or in a panic, which is said once; then the source is closed. The
        // sender is dropped as the thread leaves its loop, so the join waits only for
        // the rest of its end: the source's own drop (a camera's, a detector's).
        let Some(thread) = self.thread.take() else {
            return Ok(Received::Closed);
        };
        let name = thread
            .thread()
            .name()
            .unwrap_or("posestream-source")
            .to_string();
        match thread.join() {
            Err(payload) => Err(TransportError::Broken {
                transport: "runtime",
                topic: name,
                reason: format!(
                    "the source's thread panicked: {}",
                    posestream_base::panic_text(payload.as_ref())
                ),
            }),
            Ok(()) => Ok(Received::Closed),
        }
    }
}
