//! The ports every transport implements and every node talks through: a [`Source`] of
//! messages and a [`Sink`] for them, what a source [`Received`], and the one
//! [`TransportError`], whose [`TransportError::refusal`] says whether a message was
//! refused (the source goes on) or the transport broke.

use std::time::Duration;

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

impl<M> Received<M> {
    /// The same with the message, if any, turned into `f(message, stamp)`.
    pub fn map<N>(self, f: impl FnOnce(M, u64) -> N) -> Received<N> {
        match self {
            Self::Message(m, stamp) => Received::Message(f(m, stamp), stamp),
            Self::Idle => Received::Idle,
            Self::Closed => Received::Closed,
        }
    }
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

/// Whether a source that gave `got` has ended: it closed, or broke (a refused message,
/// [`TransportError::refusal`], is no end).
pub fn ended<M>(got: &Result<Received<M>, TransportError>) -> bool {
    match got {
        Ok(Received::Closed) => true,
        Ok(_) => false,
        Err(e) => e.refusal().is_none(),
    }
}

impl TransportError {
    /// The kind of refusal of a message its transport refused before it reached a node,
    /// as nodes count them (`undecodable`, `beyond-limits`): `Some` for
    /// [`TransportError::Malformed`] and [`TransportError::BeyondLimits`], whose source
    /// goes on; `None` for the errors that end a source or a sink.
    pub fn refusal(&self) -> Option<&'static str> {
        match self {
            Self::Malformed { .. } => Some("undecodable"),
            Self::BeyondLimits { .. } => Some("beyond-limits"),
            _ => None,
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_messages_refused_are_refusals() {
        let malformed = TransportError::Malformed {
            transport: "t",
            topic: "a".into(),
            reason: "r".into(),
        };
        let beyond = TransportError::BeyondLimits {
            transport: "t",
            topic: "a".into(),
            reason: "r".into(),
        };
        let broken = TransportError::Broken {
            transport: "t",
            topic: "a".into(),
            reason: "r".into(),
        };
        assert_eq!(malformed.refusal(), Some("undecodable"));
        assert_eq!(beyond.refusal(), Some("beyond-limits"));
        assert_eq!(broken.refusal(), None);
    }
}
