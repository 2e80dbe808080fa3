//! A [`Source`] read ahead on its own thread: a file's next frames are read and decoded
//! while the caller works on the current one (a folder of PNGs costs ~25 ms a
//! 2000 x 720 image to decode, as much as a landmark run). At most `depth` results wait
//! (and one more in the thread's hands), so a slow caller bounds the work done ahead;
//! the thread ends with the source (closed, or an error it cannot go on from) or when
//! the reader is dropped. Dropping the reader waits for the thread a moment (its
//! source's current call) and then leaves it: a source stuck in a read (a stalled
//! `ffmpeg` pipe) must not hang the service's shutdown.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

use super::{Received, Source, TransportError};

/// How long the reading thread waits on its source per call (it only matters to how
/// soon it notices a dropped reader while its source is idle).
const POLL: Duration = Duration::from_millis(100);

/// A source's messages, read ahead on a thread.
pub struct ReadAhead<M> {
    results: Option<Receiver<Result<Received<M>, TransportError>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// Disconnected when the thread ends.
    ended: Receiver<()>,
}

/// How long dropping the reader waits for its thread.
const JOIN_WAIT: Duration = Duration::from_secs(2);

impl<M: Send + 'static> ReadAhead<M> {
    /// Reads `source` on a thread named `name`, keeping up to `depth` (at least 1)
    /// results ready.
    pub fn new(
        mut source: Box<dyn Source<M>>,
        depth: usize,
        name: &str,
    ) -> Result<Self, TransportError> {
        let (tx, rx) = sync_channel(depth.max(1));
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let (ending, ended) = std::sync::mpsc::channel::<()>();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                read(&mut *source, &tx, &stopped);
                drop(source);
                drop(ending);
            })
            .map_err(|e| TransportError::Setup {
                transport: "read-ahead",
                what: name.into(),
                reason: e.to_string(),
            })?;
        Ok(Self {
            results: Some(rx),
            stop,
            thread: Some(thread),
            ended,
        })
    }
}

/// The reading thread: every message and error handed on, in order, until the source
/// ends (closed, or an error it cannot go on from) or the reader is gone.
fn read<M>(
    source: &mut dyn Source<M>,
    tx: &SyncSender<Result<Received<M>, TransportError>>,
    stop: &AtomicBool,
) {
    while !stop.load(Ordering::Relaxed) {
        let result = source.recv(POLL);
        if matches!(result, Ok(Received::Idle)) {
            continue;
        }
        let last = is_last(&result);
        if tx.send(result).is_err() || last {
            return;
        }
    }
}

/// Whether nothing comes after `result`: the source closed, or failed in a way it
/// cannot go on from (a malformed or oversized message is skipped, and reading goes on).
fn is_last<M>(result: &Result<Received<M>, TransportError>) -> bool {
    match result {
        Ok(Received::Closed) => true,
        Ok(_) => false,
        Err(TransportError::Malformed { .. } | TransportError::BeyondLimits { .. }) => false,
        Err(_) => true,
    }
}

impl<M: Send + 'static> Source<M> for ReadAhead<M> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        let Some(results) = &self.results else {
            return Ok(Received::Closed);
        };
        match results.recv_timeout(timeout) {
            Ok(result) => {
                if is_last(&result) {
                    self.results = None;
                }
                result
            }
            Err(RecvTimeoutError::Timeout) => Ok(Received::Idle),
            Err(RecvTimeoutError::Disconnected) => {
                self.results = None;
                Ok(Received::Closed)
            }
        }
    }
}

impl<M> Drop for ReadAhead<M> {
    fn drop(&mut self) {
        // The reader gone, the thread ends after its source's current call.
        self.stop.store(true, Ordering::Relaxed);
        self.results = None;
        let Some(thread) = self.thread.take() else {
            return;
        };
        match self.ended.recv_timeout(JOIN_WAIT) {
            Err(RecvTimeoutError::Timeout) => tracing::warn!(
                "a read-ahead thread is still in its source's read after {JOIN_WAIT:?}: left"
            ),
            _ => {
                if thread.join().is_err() {
                    tracing::warn!("a read-ahead thread panicked");
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers 0..n, a malformed one at 2, then closed (or broken).
    struct Counting {
        next: u32,
        n: u32,
        broken: bool,
    }

    impl Source<u32> for Counting {
        fn recv(&mut self, _: Duration) -> Result<Received<u32>, TransportError> {
            let i = self.next;
            self.next += 1;
            if i == 2 {
                return Err(TransportError::Malformed {
                    transport: "test",
                    topic: "t".into(),
                    reason: "two".into(),
                });
            }
            if i < self.n {
                Ok(Received::Message(i, u64::from(i)))
            } else if self.broken {
                Err(TransportError::Broken {
                    transport: "test",
                    topic: "t".into(),
                    reason: "gone".into(),
                })
            } else {
                Ok(Received::Closed)
            }
        }
    }

    fn drain(source: &mut ReadAhead<u32>) -> Vec<String> {
        let mut out = Vec::new();
        loop {
            match source.recv(Duration::from_secs(10)) {
                Ok(Received::Message(i, _)) => out.push(i.to_string()),
                Ok(Received::Idle) => out.push("idle".into()),
                Ok(Received::Closed) => return out,
                Err(e @ TransportError::Malformed { .. }) => out.push(format!("{e}")),
                Err(e) => {
                    out.push(format!("{e}"));
                    return out;
                }
            }
        }
    }

    #[test]
    fn everything_comes_in_order_errors_included_then_the_end() {
        let source = Counting {
            next: 0,
            n: 5,
            broken: false,
        };
        let mut ahead = ReadAhead::new(Box::new(source), 2, "test").expect("thread");
        let got = drain(&mut ahead);
        assert_eq!(got.len(), 5);
        assert_eq!(got[..2], ["0", "1"]);
        assert!(got[2].contains("malformed"), "{got:?}");
        assert_eq!(got[3..], ["3", "4"]);
        // Closed stays closed.
        assert!(matches!(ahead.recv(Duration::ZERO), Ok(Received::Closed)));
        let source = Counting {
            next: 0,
            n: 4,
            broken: true,
        };
        let mut ahead = ReadAhead::new(Box::new(source), 1, "test").expect("thread");
        let got = drain(&mut ahead);
        assert!(got.last().is_some_and(|e| e.contains("gone")), "{got:?}");
    }

    /// A source whose read never returns (a stalled pipe).
    struct Stuck;

    impl Source<u32> for Stuck {
        fn recv(&mut self, _: Duration) -> Result<Received<u32>, TransportError> {
            std::thread::sleep(Duration::from_secs(3600));
            Ok(Received::Idle)
        }
    }

    #[test]
    fn dropping_the_reader_of_a_stuck_source_does_not_hang() {
        let ahead = ReadAhead::new(Box::new(Stuck), 1, "stuck").expect("thread");
        let began = std::time::Instant::now();
        drop(ahead);
        assert!(began.elapsed() < JOIN_WAIT + Duration::from_secs(2));
    }

    #[test]
    fn a_reader_dropped_early_ends_the_thread() {
        // An endless source: dropping the reader must not hang.
        let source = Counting {
            next: 3,
            n: u32::MAX,
            broken: false,
        };
        let mut ahead = ReadAhead::new(Box::new(source), 2, "test").expect("thread");
        assert!(matches!(
            ahead.recv(Duration::from_secs(10)),
            Ok(Received::Message(3, 3))
        ));
        drop(ahead);
    }
}
