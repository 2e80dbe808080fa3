//! Recordings as a transport: a [`McapSink`] writes one topic of a shared
//! [`Recorder`] (several sinks, one file); a [`McapSource`] reads one topic of a
//! recording front to back.

use std::marker::PhantomData;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use super::{EncodedSink, Message, Received, Sink, Source, TransportError};
use posestream_msgs as msgs;
use posestream_msgs::recording::{Recorder, RecordingError, RecordingReader, RecordingSummary};

const TRANSPORT: &str = "mcap";

/// A [`Recorder`] shared by several sinks (one per topic).
#[derive(Clone)]
pub struct SharedRecorder {
    inner: Arc<Mutex<Option<Recorder>>>,
    path: String,
}

impl SharedRecorder {
    /// Creates the recording at `path`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let recorder = Recorder::create(path.as_ref())?;
        Ok(Self {
            inner: Arc::new(Mutex::new(Some(recorder))),
            path: path.as_ref().display().to_string(),
        })
    }

    /// A sink writing messages of type `M` on `topic`.
    pub fn sink<M: Message>(&self, topic: &str) -> McapSink<M> {
        McapSink {
            recorder: self.clone(),
            topic: topic.to_string(),
            _message: PhantomData,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Option<Recorder>> {
        // A sink that panicked mid-write leaves the recorder as it was: go on with it.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn closed(&self, topic: &str) -> TransportError {
        TransportError::Closed {
            transport: TRANSPORT,
            topic: format!("{} ({topic})", self.path),
        }
    }

    fn error(&self, topic: &str, reason: impl ToString) -> TransportError {
        TransportError::Send {
            transport: TRANSPORT,
            topic: format!("{} ({topic})", self.path),
            reason: reason.to_string(),
        }
    }

    /// Finalises the file (summary, footer) and puts it in place; sinks still around can
    /// no longer write.
    pub fn finish(&self) -> Result<RecordingSummary, RecordingError> {
        self.take()?.finish()
    }

    /// Finalises the file but leaves it under its temporary name (the run failed; the
    /// output stays as it was); returns that name.
    pub fn finish_partial(&self) -> Result<std::path::PathBuf, RecordingError> {
        self.take()?.finish_partial()
    }

    /// True once a write failed (a full disk): the recording takes nothing more.
    pub fn failed(&self) -> bool {
        self.lock().as_ref().is_some_and(Recorder::failed)
    }

    /// Messages written so far (0 once finished).
    pub fn messages(&self) -> u64 {
        self.lock().as_ref().map_or(0, Recorder::messages)
    }

    /// Drops the recording and its temporary file (nothing worth keeping was written).
    pub fn abandon(&self) {
        if let Ok(r) = self.take() {
            r.abandon();
        }
    }

    /// Writes an encoded message of type `M` (CDR, as read from another recording) on
    /// `topic`, without decoding it.
    pub fn write_encoded<M: Message>(
        &self,
        topic: &str,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), TransportError> {
        let mut guard = self.lock();
        let recorder = guard
            .as_mut()
            .ok_or_else(|| self.error(topic, "the recording is finished"))?;
        if recorder.failed() {
            return Err(self.closed(topic));
        }
        recorder
            .write_encoded::<M>(topic, log_time_ns, data)
            .map_err(|e| self.error(topic, e))
    }

    fn take(&self) -> Result<Recorder, RecordingError> {
        self.lock().take().ok_or_else(|| RecordingError::Io {
            path: self.path.clone().into(),
            source: std::io::Error::other("the recording was already finished"),
        })
    }
}

/// Writes messages of type `M` on one topic of a recording.
pub struct McapSink<M> {
    recorder: SharedRecorder,
    topic: String,
    _message: PhantomData<fn(M)>,
}

impl<M> McapSink<M> {
    /// Writes with the recorder: the first failed write (a full disk) is an error; after
    /// it, every sink of the recording is [`TransportError::Closed`].
    fn write(
        &mut self,
        write: impl FnOnce(&mut Recorder, &str) -> Result<(), RecordingError>,
    ) -> Result<(), TransportError> {
        let mut guard = self.recorder.lock();
        let recorder = guard.as_mut().ok_or_else(|| {
            self.recorder
                .error(&self.topic, "the recording is finished")
        })?;
        if recorder.failed() {
            return Err(self.recorder.closed(&self.topic));
        }
        write(recorder, &self.topic).map_err(|e| self.recorder.error(&self.topic, e))
    }
}

impl<M: Message> Sink<M> for McapSink<M> {
    /// Writes the message ([`McapSink::write`]'s failures).
    fn send(&mut self, message: &M, stamp_ns: u64) -> Result<(), TransportError> {
        self.write(|r, topic| r.write(topic, stamp_ns, message))
    }

    fn flush(&mut self) -> Result<(), TransportError> {
        match self.recorder.lock().as_mut() {
            Some(r) if r.failed() => Err(self.recorder.closed(&self.topic)),
            Some(r) => r.flush().map_err(|e| self.recorder.error(&self.topic, e)),
            None => Ok(()),
        }
    }
}

impl<M: Message> EncodedSink<M> for McapSink<M> {
    /// Writes the encoded message; failures as [`Sink::send`]'s.
    fn send_encoded(&mut self, data: &[u8], stamp_ns: u64) -> Result<(), TransportError> {
        self.write(|r, topic| r.write_encoded::<M>(topic, stamp_ns, data))
    }

    fn flush(&mut self) -> Result<(), TransportError> {
        Sink::flush(self)
    }
}

/// Reads the messages of one topic of a recording, in order, as fast as asked; once, or
/// several times over ([`McapSource::repeat`]).
pub struct McapSource<M> {
    reader: RecordingReader,
    path: std::path::PathBuf,
    max_record_bytes: usize,
    topic: String,
    closed: bool,
    /// Passes still to play after this one (`None`: forever).
    passes_left: Option<u64>,
    /// Added to log times in this pass, so that time goes on across passes.
    offset_ns: u64,
    /// Log times of this pass: the first and the last.
    span: Option<(u64, u64)>,
    /// Whether this pass has yielded a message of the topic.
    yielded: bool,
    /// Passes started before this one.
    pass: u64,
    /// Read on past damage ([`McapSource::salvaging`]).
    salvage: bool,
    _message: PhantomData<fn() -> M>,
}

impl<M: Message> McapSource<M> {
    /// Opens `path` and reads `topic` (messages of other types on it are skipped), with
    /// the default record limit.
    pub fn open(path: impl AsRef<Path>, topic: &str) -> Result<Self, TransportError> {
        Self::open_with_limit(
            path,
            topic,
            posestream_msgs::limits::Limits::default().max_record_bytes,
        )
    }

    /// Opens `path` and reads `topic`; records longer than `max_record_bytes` end
    /// reading.
    pub fn open_with_limit(
        path: impl AsRef<Path>,
        topic: &str,
        max_record_bytes: usize,
    ) -> Result<Self, TransportError> {
        let reader = Self::reader(path.as_ref(), max_record_bytes, false)?;
        Ok(Self {
            reader,
            path: path.as_ref().to_path_buf(),
            max_record_bytes,
            topic: topic.to_string(),
            closed: false,
            passes_left: Some(0),
            offset_ns: 0,
            span: None,
            yielded: false,
            pass: 0,
            salvage: false,
            _message: PhantomData,
        })
    }

    /// Plays the recording `times` times in all (0: forever), log times going on from
    /// one pass to the next (a pass starts one mean message interval after the last one
    /// ended); the messages themselves are as recorded ([`McapSource::pass`] tells which
    /// pass they belong to).
    pub fn repeat(mut self, times: u64) -> Self {
        self.passes_left = times.checked_sub(1);
        self
    }

    fn reader(
        path: &Path,
        max_record_bytes: usize,
        salvage: bool,
    ) -> Result<RecordingReader, TransportError> {
        let reader = RecordingReader::open_with_limit(path, max_record_bytes);
        let reader = if salvage {
            reader.and_then(RecordingReader::salvaging)
        } else {
            reader
        };
        reader.map_err(|e| TransportError::Setup {
            transport: TRANSPORT,
            what: path.display().to_string(),
            reason: e.to_string(),
        })
    }

    /// The same source, reading on past what it cannot or must not read of the file
    /// (`posestream_msgs::salvage`): each pass's skips are said in one warning at its
    /// end (counts and byte ranges).
    pub fn salvaging(mut self) -> Result<Self, TransportError> {
        self.salvage = true;
        self.reader = Self::reader(&self.path, self.max_record_bytes, true)?;
        Ok(self)
    }

    /// Says what the first pass skipped, if anything (the others skip the same).
    fn report_skips(&self) {
        if self.pass > 0 {
            return;
        }
        if let Some(skips) = self.reader.skips().filter(|s| !s.is_empty()) {
            tracing::warn!(
                "{}: damaged parts skipped, every readable message used: {}",
                self.path.display(),
                skips.summary()
            );
        }
    }

    /// Starts the next pass, if there is one.
    fn next_pass(&mut self) -> Result<bool, TransportError> {
        let Some((first, last)) = self.span.take().filter(|_| self.yielded) else {
            return Ok(false); // nothing of the topic: another pass would yield nothing
        };
        self.yielded = false;
        match self.passes_left {
            Some(0) => return Ok(false),
            Some(n) => self.passes_left = Some(n - 1),
            None => {}
        }
        let messages = self.reader.messages_read().max(2);
        let interval = (last - first) / (messages - 1);
        self.offset_ns = self.offset_ns.saturating_add(last - first + interval);
        self.reader = Self::reader(&self.path, self.max_record_bytes, self.salvage)?;
        self.closed = false;
        self.pass += 1;
        Ok(true)
    }

    /// The pass being played: 0 for the first.
    pub fn pass(&self) -> u64 {
        self.pass
    }

    /// Messages read from the file so far (all topics).
    pub fn messages_read(&self) -> u64 {
        self.reader.messages_read()
    }
}

impl<M: Message> Source<M> for McapSource<M> {
    /// Never waits: the next message of the topic, or [`Received::Closed`] after the
    /// last pass; a recording without any message on the topic is one
    /// [`TransportError::Broken`] naming the topics it has. A file cut short yields every complete message, a warning, then the
    /// next pass (or `Closed`); a corrupt one every message before the bad record, then
    /// one [`TransportError::Broken`].
    fn recv(&mut self, _timeout: Duration) -> Result<Received<M>, TransportError> {
        loop {
            if let Some(got) = self.next_of_pass()? {
                return Ok(got);
            }
            if posestream_base::files::stop::requested() {
                // A signal ended the reading (`posestream_base::files::stop`): the stream
                // ends here, and nothing is said of the file.
                return Ok(Received::Closed);
            }
            if self.pass == 0 && !self.yielded {
                // Nothing of the topic in the whole file: a wrong topic or file, not an
                // empty stream.
                return Err(self.no_messages());
            }
            if !self.next_pass()? {
                return Ok(Received::Closed);
            }
        }
    }
}

impl<M: Message> McapSource<M> {
    /// The error for a recording without any message on the topic, naming what it has.
    fn no_messages(&self) -> TransportError {
        TransportError::Broken {
            transport: TRANSPORT,
            topic: self.topic.clone(),
            reason: format!(
                "{} has no messages on this topic; it has {}",
                self.path.display(),
                self.reader.topics_text()
            ),
        }
    }

    /// The next message of the topic in this pass, `None` at its end.
    fn next_of_pass(&mut self) -> Result<Option<Received<M>>, TransportError> {
        while !self.closed {
            let Some(next) = self.reader.next_message() else {
                self.closed = true;
                self.report_skips();
                break;
            };
            let msg = match next {
                Ok(msg) => msg,
                Err(e @ RecordingError::Truncated { .. }) => {
                    tracing::warn!("{e}");
                    self.closed = true;
                    break;
                }
                Err(e) => {
                    self.closed = true;
                    return Err(TransportError::Broken {
                        transport: TRANSPORT,
                        topic: self.topic.clone(),
                        reason: e.to_string(),
                    });
                }
            };
            let t = msg.log_time_ns;
            self.span = Some(self.span.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
            if msg.topic != self.topic || msg.schema != M::NAME {
                continue;
            }
            let stamp = msg.log_time_ns.saturating_add(self.offset_ns);
            self.yielded = true;
            return match msgs::decode::<M>(&msg.data) {
                Ok(m) => Ok(Some(Received::Message(m, stamp))),
                Err(e) => Err(TransportError::Malformed {
                    transport: TRANSPORT,
                    topic: self.topic.clone(),
                    reason: e.to_string(),
                }),
            };
        }
        Ok(None)
    }
}
