//! Publishers of one message type on every configured output ([`Publishers`]): ROS 2
//! publishers (kept apart: awaited on a runtime while a reliable history is full), sinks
//! that take the message itself (iceoryx2's fixed layouts, the in-memory channel), and
//! sinks that take its bytes (the output recording, the live view), which share one
//! encoding of each message. A failed send is counted and the first failure of each sink
//! logged; the other sinks go on. Each message goes to the ROS 2 publishers first, then
//! to the others, each kind in the order added. A message kept in an `Arc`
//! ([`Publishers::publish_shared`]) goes to ROS 2 without a copy.

use std::sync::Arc;

use crate::transport::ros2::Ros2Sink;
use crate::transport::{EncodedSink, Message, Sink, TransportError};

/// One sink with its name (for the logs) and whether a failure of it was logged.
struct Named<S: ?Sized> {
    name: String,
    logged: bool,
    sink: Box<S>,
}

/// Publishers of one message type on every configured output; see the module docs.
pub struct Publishers<M: Message> {
    ros2: Vec<Named<Ros2Sink<M>>>,
    typed: Vec<Named<dyn Sink<M>>>,
    encoded: Vec<Named<dyn EncodedSink<M>>>,
    /// The message in hand, encoded once for every sink of bytes (reused).
    buffer: Vec<u8>,
    /// Messages handed to every sink.
    pub sent: u64,
    /// Sends that failed (per sink).
    pub failed: u64,
}

impl<M: Message> Default for Publishers<M> {
    fn default() -> Self {
        Self {
            ros2: Vec::new(),
            typed: Vec::new(),
            encoded: Vec::new(),
            buffer: Vec::new(),
            sent: 0,
            failed: 0,
        }
    }
}

impl<M: Message> Publishers<M> {
    /// Adds a sink of the message itself, named for the logs.
    pub fn add(&mut self, name: impl Into<String>, sink: Box<dyn Sink<M>>) {
        self.typed.push(named(name, sink));
    }

    /// Adds a sink of the message's bytes (a recording, the live view), named for the
    /// logs: every such sink is sent one encoding of each message.
    pub fn add_encoded(&mut self, name: impl Into<String>, sink: Box<dyn EncodedSink<M>>) {
        self.encoded.push(named(name, sink));
    }

    /// Adds a ROS 2 publisher, named for the logs ([`Publishers::publish_async`] awaits
    /// room in its history instead of blocking).
    pub fn add_ros2(&mut self, name: impl Into<String>, sink: Ros2Sink<M>) {
        self.ros2.push(named(name, Box::new(sink)));
    }

    /// Sinks configured.
    pub fn len(&self) -> usize {
        self.ros2.len() + self.typed.len() + self.encoded.len()
    }

    /// True without sinks.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sends to every sink.
    pub fn publish(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for s in &mut self.ros2 {
            let sent = s.sink.send(message, stamp_ns);
            note(&mut self.failed, s, sent);
        }
        self.send_others(message, stamp_ns, self.typed.len());
    }

    /// Sends to every sink on a runtime: as [`Publishers::publish`], a ROS 2 publisher
    /// awaited instead of blocking while its reliable history is full.
    pub async fn publish_async(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for s in &mut self.ros2 {
            let sent = s.sink.send_async(message).await;
            note(&mut self.failed, s, sent);
        }
        self.send_others(message, stamp_ns, self.typed.len());
    }

    /// [`Publishers::publish`] of a message kept shared: ROS 2 takes it without a copy.
    pub fn publish_shared(&mut self, message: &Arc<M>, stamp_ns: u64) {
        self.sent += 1;
        for s in &mut self.ros2 {
            let sent = s.sink.send_shared(message);
            note(&mut self.failed, s, sent);
        }
        self.send_others(message, stamp_ns, self.typed.len());
    }

    /// [`Publishers::publish_async`] of a message kept shared: ROS 2 takes it without a
    /// copy.
    pub async fn publish_shared_async(&mut self, message: &Arc<M>, stamp_ns: u64) {
        self.sent += 1;
        for s in &mut self.ros2 {
            let sent = s.sink.send_shared_async(message).await;
            note(&mut self.failed, s, sent);
        }
        self.send_others(message, stamp_ns, self.typed.len());
    }

    /// Sends to every sink, the message given up to the last sink of the message itself
    /// (the in-memory channel, added last, moves it instead of copying it).
    pub fn publish_owned(&mut self, message: M, stamp_ns: u64) {
        self.sent += 1;
        for s in &mut self.ros2 {
            let sent = s.sink.send(&message, stamp_ns);
            note(&mut self.failed, s, sent);
        }
        let last = self.typed.len().saturating_sub(1);
        self.send_others(&message, stamp_ns, last);
        if let Some(s) = self.typed.get_mut(last) {
            let sent = s.sink.send_owned(message, stamp_ns);
            note(&mut self.failed, s, sent);
        }
    }

    /// Sends to the first `typed` sinks of the message itself, and to every sink of bytes
    /// (the message encoded once, when one wants it).
    fn send_others(&mut self, message: &M, stamp_ns: u64, typed: usize) {
        for s in self.typed.iter_mut().take(typed) {
            let sent = s.sink.send(message, stamp_ns);
            note(&mut self.failed, s, sent);
        }
        let mut encoding = None;
        for s in &mut self.encoded {
            if !s.sink.wanted() {
                continue;
            }
            let encoded = encoding.get_or_insert_with(|| {
                self.buffer.clear();
                crate::msgs::encode_into(message, &mut self.buffer).map_err(|e| e.to_string())
            });
            let sent = match encoded {
                Ok(()) => s.sink.send_encoded(&self.buffer, stamp_ns),
                Err(reason) => Err(TransportError::Send {
                    transport: "cdr",
                    topic: M::NAME.into(),
                    reason: reason.clone(),
                }),
            };
            note(&mut self.failed, s, sent);
        }
    }

    /// Flushes every sink.
    pub fn flush(&mut self) {
        for s in &mut self.ros2 {
            let flushed = s.sink.flush();
            note(&mut self.failed, s, flushed);
        }
        for s in &mut self.typed {
            let flushed = s.sink.flush();
            note(&mut self.failed, s, flushed);
        }
        for s in &mut self.encoded {
            let flushed = s.sink.flush();
            note(&mut self.failed, s, flushed);
        }
    }
}

fn named<S: ?Sized>(name: impl Into<String>, sink: Box<S>) -> Named<S> {
    Named {
        name: name.into(),
        logged: false,
        sink,
    }
}

/// Counts a failed send of sink `s` (its first failure logged: a full disk under a
/// recording fails every later write too; a sink closed by an earlier failure, reported
/// then, is only counted).
fn note<S: ?Sized>(failed: &mut u64, s: &mut Named<S>, sent: Result<(), TransportError>) {
    let Err(e) = sent else {
        return;
    };
    *failed += 1;
    if !s.logged && !matches!(e, TransportError::Closed { .. }) {
        s.logged = true;
        tracing::warn!(
            "{}: {e} (further failures of this output are counted, not logged)",
            s.name
        );
    } else {
        tracing::debug!("{}: {e}", s.name);
    }
}
