//! Writing a recording: [`Recorder`], into a `.partial` file renamed into place when done.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;
use mcap::{Compression, WriteOptions, Writer};

use super::{RecordingError, RecordingSummary};
use crate::RosMessage;

/// Messages of the complete chunks of a file being written, read back (a recording that
/// could not be finished says what of it can be used, not what should).
fn readable(partial: &Path) -> u64 {
    let Ok(mut file) = File::open(partial) else {
        return 0;
    };
    let limit = crate::limits::Limits::default().max_record_bytes;
    let Ok(mut salvager) = crate::salvage::Salvager::new(&mut file, limit) else {
        return 0;
    };
    std::iter::from_fn(|| salvager.next_message(&mut file)).count() as u64
}

/// Writes messages of any [`RosMessage`] type to an MCAP file.
///
/// The file is written under a temporary name beside the output
/// ([`crate::files::create_partial`]) and renamed into place by [`Recorder::finish`], so
/// an existing output is replaced only by a complete recording. A recorder that is
/// killed, or whose writes fail (a full disk), leaves its messages in that `.partial`
/// file, readable up to its last complete chunk, and the output as it was.
pub struct Recorder {
    path: PathBuf,
    partial: PathBuf,
    writer: Writer<BufWriter<File>>,
    channels: BTreeMap<String, u16>,
    /// Channels of [`Recorder::write_raw`]: by topic and schema name.
    raw_channels: BTreeMap<(String, String), u16>,
    counts: BTreeMap<String, (String, u64)>,
    sequence: u32,
    first_ns: Option<u64>,
    last_ns: u64,
    flush_every: Option<Duration>,
    last_flush: Instant,
    /// The first write that failed: nothing more is written.
    failed: Option<String>,
}

impl Recorder {
    /// Starts a recording that [`Recorder::finish`] puts at `path` (replacing a file
    /// there).
    pub fn create(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let asked = path.as_ref();
        let io = |source| RecordingError::Io {
            path: asked.to_path_buf(),
            source,
        };
        if asked.is_dir() {
            return Err(io(std::io::Error::other("is a directory")));
        }
        // An output that is a symbolic link is written where the link points.
        let path = if asked.is_symlink() {
            std::fs::canonicalize(asked).map_err(io)?
        } else {
            asked.to_path_buf()
        };
        // The finished file replaces what is there: only a file (not a device or a pipe,
        // which the rename would destroy).
        if std::fs::metadata(&path).is_ok_and(|m| !m.is_file()) {
            return Err(io(std::io::Error::other(
                "is not a regular file (a device or a pipe): give a file's path",
            )));
        }
        // Never onto a file this process read (a configuration, a take, a mapping).
        crate::files::check_output(&path, &[])?;
        let (partial, file) = crate::files::create_partial(&path).map_err(io)?;
        let writer = WriteOptions::new()
            .profile("ros2")
            .library(concat!("posestream ", env!("CARGO_PKG_VERSION")))
            .compression(Some(Compression::Zstd))
            .chunk_size(Some(1 << 20))
            .create(BufWriter::new(file))
            .map_err(|source| RecordingError::Mcap {
                path: partial.clone(),
                source,
            })?;
        Ok(Self {
            path,
            partial,
            writer,
            channels: BTreeMap::new(),
            raw_channels: BTreeMap::new(),
            counts: BTreeMap::new(),
            sequence: 0,
            first_ns: None,
            last_ns: 0,
            flush_every: Some(Duration::from_secs(1)),
            last_flush: Instant::now(),
            failed: None,
        })
    }

    /// True after a write failed: nothing more is written.
    pub fn failed(&self) -> bool {
        self.failed.is_some()
    }

    /// Messages written so far, over every topic.
    pub fn messages(&self) -> u64 {
        self.counts.values().map(|(_, n)| n).sum()
    }

    /// Closes a chunk and flushes it to the file at least this often (default 1 s;
    /// `None`: only when a chunk is full). Bounds what a killed recorder loses.
    pub fn set_flush_interval(&mut self, every: Option<Duration>) {
        self.flush_every = every;
    }

    /// Appends `msg` on `topic`, logged at `log_time_ns` (nanoseconds since the epoch).
    pub fn write<M: RosMessage>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        msg: &M,
    ) -> Result<(), RecordingError> {
        let data = crate::encode(msg)?;
        self.write_encoded::<M>(topic, log_time_ns, &data)
    }

    /// Appends an already encoded message (CDR with its encapsulation header). After a
    /// failed write (the disk full) every later one fails at once with the first error.
    pub fn write_encoded<M: RosMessage>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        if let Some(reason) = &self.failed {
            return Err(self.failure(reason.clone()));
        }
        let result = self.write_unchecked::<M>(topic, log_time_ns, data);
        if let Err(e) = &result {
            self.failed = Some(e.to_string());
        }
        result
    }

    fn write_unchecked<M: RosMessage>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<(), RecordingError> {
        let channel = match self.channels.get(topic) {
            Some(&id) => id,
            None => {
                let schema = self
                    .writer
                    .add_schema(M::NAME, "ros2msg", M::full_definition().as_bytes())
                    .map_err(|source| self.mcap_error(source))?;
                let metadata =
                    BTreeMap::from([("offered_qos_profiles".to_string(), String::new())]);
                let id = self
                    .writer
                    .add_channel(schema, topic, "cdr", &metadata)
                    .map_err(|source| self.mcap_error(source))?;
                self.channels.insert(topic.to_string(), id);
                self.counts
                    .insert(topic.to_string(), (M::NAME.to_string(), 0));
                id
            }
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id: channel,
                    sequence: self.sequence,
                    log_time: log_time_ns,
                    publish_time: log_time_ns,
                },
                data,
            )
            .map_err(|source| self.mcap_error(source))?;
        if let Some(c) = self.counts.get_mut(topic) {
            c.1 += 1;
        }
        self.first_ns = Some(self.first_ns.map_or(log_time_ns, |f| f.min(log_time_ns)));
        self.last_ns = self.last_ns.max(log_time_ns);
        if self
            .flush_every
            .is_some_and(|every| self.last_flush.elapsed() >= every)
        {
            self.flush()?;
        }
        Ok(())
    }

    /// Appends a message of a channel as another recording declared it (its schema, its
    /// topic, encoding and metadata), whatever its type: for copying what was read of a
    /// recording (`posestream recover`). Channels are told apart by topic and schema.
    pub fn write_raw(
        &mut self,
        schema: Option<&crate::salvage::SchemaInfo>,
        channel: &crate::salvage::ChannelInfo,
        message: &crate::salvage::Salvaged,
    ) -> Result<(), RecordingError> {
        if let Some(reason) = &self.failed {
            return Err(self.failure(reason.clone()));
        }
        let name = schema.map(|s| s.name.clone()).unwrap_or_default();
        let key = (channel.topic.clone(), name.clone());
        let id = match self.raw_channels.get(&key) {
            Some(&id) => id,
            None => {
                let schema_id = match schema {
                    Some(s) => self
                        .writer
                        .add_schema(&s.name, &s.encoding, &s.data)
                        .map_err(|source| self.mcap_error(source))?,
                    None => 0,
                };
                let id = self
                    .writer
                    .add_channel(
                        schema_id,
                        &channel.topic,
                        &channel.message_encoding,
                        &channel.metadata,
                    )
                    .map_err(|source| self.mcap_error(source))?;
                self.raw_channels.insert(key, id);
                self.counts
                    .entry(channel.topic.clone())
                    .or_insert((name, 0));
                id
            }
        };
        let written = self.writer.write_to_known_channel(
            &MessageHeader {
                channel_id: id,
                sequence: message.sequence,
                log_time: message.log_time,
                publish_time: message.publish_time,
            },
            &message.data,
        );
        if let Err(source) = written {
            let e = self.mcap_error(source);
            self.failed = Some(e.to_string());
            return Err(e);
        }
        if let Some(c) = self.counts.get_mut(&channel.topic) {
            c.1 += 1;
        }
        self.first_ns = Some(
            self.first_ns
                .map_or(message.log_time, |f| f.min(message.log_time)),
        );
        self.last_ns = self.last_ns.max(message.log_time);
        Ok(())
    }

    /// Closes the current chunk and flushes it to the file: whatever happens to the
    /// process afterwards, the messages so far can be read.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        if let Some(reason) = &self.failed {
            return Err(self.failure(reason.clone()));
        }
        self.last_flush = Instant::now();
        let result = self
            .writer
            .flush()
            .map_err(|source| self.mcap_error(source));
        if let Err(e) = &result {
            self.failed = Some(e.to_string());
        }
        result
    }

    /// Writes the summary and footer, makes the file durable and renames it into place;
    /// returns what was recorded. If a write failed, or fails now, the output is left as
    /// it was and the error names the `.partial` file holding what was written.
    pub fn finish(self) -> Result<RecordingSummary, RecordingError> {
        let summary = RecordingSummary {
            path: self.path.clone(),
            topics: self.counts.clone(),
            start_ns: self.first_ns.unwrap_or(0),
            end_ns: self.last_ns,
        };
        let (path, partial) = (self.path.clone(), self.partial.clone());
        self.complete()?;
        let unfinished = |reason: String| RecordingError::Unfinished {
            path: path.clone(),
            partial: partial.clone(),
            reason,
            readable: readable(&partial),
        };
        std::fs::rename(&partial, &path).map_err(|e| unfinished(e.to_string()))?;
        // The rename itself is durable once the folder is.
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty())
            && let Ok(d) = File::open(dir)
        {
            let _ = d.sync_all();
        }
        Ok(summary)
    }

    /// Writes the summary and footer but leaves the file under its temporary name (the
    /// run failed: the output stays as it was); returns that name.
    pub fn finish_partial(self) -> Result<PathBuf, RecordingError> {
        let partial = self.partial.clone();
        self.complete()?;
        Ok(partial)
    }

    /// Writes the summary and footer and makes the file durable, under its temporary
    /// name.
    fn complete(mut self) -> Result<(), RecordingError> {
        if let Some(reason) = self.failed.take() {
            return Err(self.failure(reason));
        }
        if let Err(e) = self.writer.finish() {
            let reason = self.mcap_error(e).to_string();
            return Err(self.failure(reason));
        }
        let (path, partial) = (self.path.clone(), self.partial.clone());
        let failure = |e: &std::io::Error| RecordingError::Unfinished {
            path: path.clone(),
            partial: partial.clone(),
            reason: crate::files::io_text(e),
            readable: readable(&partial),
        };
        let file = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| failure(e.error()))?;
        file.sync_all().map_err(|e| failure(&e))
    }

    /// Drops the recording: nothing of value was written; the temporary file is removed
    /// and the output stays as it was.
    pub fn abandon(self) {
        let partial = self.partial.clone();
        drop(self);
        let _ = std::fs::remove_file(partial);
    }

    fn failure(&self, reason: String) -> RecordingError {
        RecordingError::Unfinished {
            path: self.path.clone(),
            partial: self.partial.clone(),
            reason,
            readable: readable(&self.partial),
        }
    }

    fn mcap_error(&self, source: mcap::McapError) -> RecordingError {
        match source {
            // A write that failed: said as what it is (a full disk, a quota), not as the
            // library's "I/O error from writing, or reading a compression stream".
            mcap::McapError::Io(source) => RecordingError::Io {
                path: self.partial.clone(),
                source,
            },
            source => RecordingError::Mcap {
                path: self.partial.clone(),
                source,
            },
        }
    }
}
