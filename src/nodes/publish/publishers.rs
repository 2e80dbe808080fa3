//! Publishers of one message type on every configured output ([`Publishers`]): a ROS 2
//! publisher (kept apart: awaited on a runtime while its reliable history is full) and
//! any other sinks (iceoryx2, the output recording, the live view). A failed send is
//! counted and the first failure of each sink logged; the other sinks go on.

use crate::transport::ros2::Ros2Sink;
use crate::transport::{Message, Sink, TransportError};

/// Publishers of one message type on every configured output. A failed send is counted;
/// the first failure of each sink is logged (a full disk under a recording fails every
/// later write too), and the other sinks go on.
pub struct Publishers<M: Message> {
    /// Each sink with its name and whether a failure of it was logged.
    sinks: Vec<(String, Output<M>, bool)>,
    /// Messages handed to every sink.
    pub sent: u64,
    /// Sends that failed (per sink).
    pub failed: u64,
}

/// One sink of [`Publishers`]: ROS 2 apart, for its async publishing.
enum Output<M: Message> {
    Ros2(Box<Ros2Sink<M>>),
    Other(Box<dyn Sink<M>>),
}

impl<M: Message> Output<M> {
    fn sink(&mut self) -> &mut dyn Sink<M> {
        match self {
            Output::Ros2(s) => s.as_mut(),
            Output::Other(s) => s.as_mut(),
        }
    }
}

impl<M: Message> Default for Publishers<M> {
    fn default() -> Self {
        Self {
            sinks: Vec::new(),
            sent: 0,
            failed: 0,
        }
    }
}

impl<M: Message> Publishers<M> {
    /// Adds a sink, named for the logs.
    pub fn add(&mut self, name: impl Into<String>, sink: Box<dyn Sink<M>>) {
        self.sinks.push((name.into(), Output::Other(sink), false));
    }

    /// Adds a ROS 2 publisher, named for the logs ([`Publishers::publish_async`] awaits
    /// room in its history instead of blocking).
    pub fn add_ros2(&mut self, name: impl Into<String>, sink: Ros2Sink<M>) {
        self.sinks
            .push((name.into(), Output::Ros2(Box::new(sink)), false));
    }

    /// Sinks configured.
    pub fn len(&self) -> usize {
        self.sinks.len()
    }

    /// True without sinks.
    pub fn is_empty(&self) -> bool {
        self.sinks.is_empty()
    }

    /// Sends to every sink.
    pub fn publish(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.sink().send(message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    /// Sends to every sink on a runtime: as [`Publishers::publish`], a ROS 2 publisher
    /// awaited instead of blocking while its reliable history is full.
    pub async fn publish_async(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for (name, sink, logged) in &mut self.sinks {
            let sent = match sink {
                Output::Ros2(s) => s.send_async(message).await,
                Output::Other(s) => s.send(message, stamp_ns),
            };
            if let Err(e) = sent {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    /// Sends to every sink, the message given up to the last one (added last: the
    /// in-memory channel moves it instead of copying it).
    pub fn publish_owned(&mut self, message: M, stamp_ns: u64) {
        self.sent += 1;
        let Some(((last_name, last, last_logged), others)) = self.sinks.split_last_mut() else {
            return;
        };
        for (name, sink, logged) in others {
            if let Err(e) = sink.sink().send(&message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
        if let Err(e) = last.sink().send_owned(message, stamp_ns) {
            self.failed += 1;
            Self::failure(last_name, last_logged, &e);
        }
    }

    /// Flushes every sink.
    pub fn flush(&mut self) {
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.sink().flush() {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    fn failure(name: &str, logged: &mut bool, e: &TransportError) {
        // A sink closed by an earlier failure (reported then) is only counted.
        if !*logged && !matches!(e, TransportError::Closed { .. }) {
            *logged = true;
            tracing::warn!("{name}: {e} (further failures of this output are counted, not logged)");
        } else {
            tracing::debug!("{name}: {e}");
        }
    }
}
