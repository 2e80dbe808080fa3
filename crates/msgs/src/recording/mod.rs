//! MCAP recordings, rosbag2-compatible: profile `ros2`, schemas `pkg/msg/Type` in the
//! `ros2msg` encoding (the full definition text with nested `MSG:` blocks), messages in
//! `cdr` with the encapsulation header; zstd-compressed chunks.
//!
//! [`Recorder`] writes one; [`RecordingReader`] reads one front to back with the `mcap`
//! crate's sans-io reader, one record at a time, so a recording cut short (a recorder
//! killed mid-run) still yields every message of its complete chunks before it reports
//! [`RecordingError::Truncated`]. [`write_rosbag2_metadata`] adds the `metadata.yaml`
//! that makes a folder a rosbag2 bag.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Compression, McapError, WriteOptions, Writer};

use crate::RosMessage;

/// Errors of reading or writing a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be opened, created or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP library refused the data.
    #[error("{path}: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: mcap::McapError,
    },
    /// The file does not start with the MCAP magic (or is empty).
    #[error("{path}: not an MCAP recording ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What it starts with instead.
        reason: String,
    },
    /// The file ends inside a record: every message before that point was read.
    #[error("{path}: the recording is cut short after {messages} messages ({reason})")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Messages read before the cut.
        messages: u64,
        /// What the reader found.
        reason: String,
    },
    /// A record is corrupt (a chunk whose CRC does not match, a length beyond
    /// `limits.max_record_bytes` or beyond its container, a record that does not parse):
    /// reading ends there; every message before it was read, nothing of it is used.
    #[error("{path}: corrupt recording after {messages} messages: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Messages read before the corrupt record.
        messages: u64,
        /// What the reader found.
        reason: String,
    },
    /// The output would overwrite one of the inputs.
    #[error(transparent)]
    OutputIsInput(#[from] crate::files::OutputIsInput),
    /// The recording could not be finished (a write failed, e.g. the disk is full): the
    /// messages written before are in `partial`, readable up to its last complete chunk.
    #[error(
        "{path}: the recording could not be finished ({reason}); what was written is in {partial} (readable up to its last complete chunk)"
    )]
    Unfinished {
        /// The output asked for (left as it was).
        path: PathBuf,
        /// The file written until the failure.
        partial: PathBuf,
        /// The first failure.
        reason: String,
    },
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] crate::EncodeError),
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
            return Err(self.failure(e.to_string()));
        }
        let failure = |reason: String| RecordingError::Unfinished {
            path: self.path.clone(),
            partial: self.partial.clone(),
            reason,
        };
        let file = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| failure(e.error().to_string()))?;
        file.sync_all().map_err(|e| failure(e.to_string()))
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
        }
    }

    fn mcap_error(&self, source: mcap::McapError) -> RecordingError {
        RecordingError::Mcap {
            path: self.partial.clone(),
            source,
        }
    }
}

/// What a finished recording holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub path: PathBuf,
    /// Per topic: message type and count.
    pub topics: BTreeMap<String, (String, u64)>,
    /// Earliest log time, nanoseconds.
    pub start_ns: u64,
    /// Latest log time, nanoseconds.
    pub end_ns: u64,
}

/// Writes `metadata.yaml` next to the recording, making its folder a rosbag2 bag
/// (storage `mcap`, format version 5).
pub fn write_rosbag2_metadata(summary: &RecordingSummary) -> Result<PathBuf, RecordingError> {
    let dir = summary.path.parent().unwrap_or(Path::new("."));
    let file = summary
        .path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let total: u64 = summary.topics.values().map(|(_, n)| n).sum();
    let duration = summary.end_ns.saturating_sub(summary.start_ns);
    let mut yaml = String::from("rosbag2_bagfile_information:\n  version: 5\n");
    yaml.push_str("  storage_identifier: mcap\n");
    yaml.push_str(&format!(
        "  duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {}\n",
        summary.start_ns
    ));
    yaml.push_str(&format!(
        "  message_count: {total}\n  topics_with_message_count:\n"
    ));
    for (topic, (ty, n)) in &summary.topics {
        yaml.push_str(&format!(
            "    - topic_metadata:\n        name: {topic}\n        type: {ty}\n        serialization_format: cdr\n        offered_qos_profiles: \"\"\n      message_count: {n}\n"
        ));
    }
    yaml.push_str(&format!(
        "  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n      starting_time:\n        nanoseconds_since_epoch: {}\n      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n",
        summary.start_ns
    ));
    let path = dir.join("metadata.yaml");
    std::fs::write(&path, yaml).map_err(|source| RecordingError::Io {
        path: path.clone(),
        source,
    })?;
    Ok(path)
}

/// One message read from a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    /// The topic.
    pub topic: String,
    /// The schema name (`pkg/msg/Type`), empty if the channel has none.
    pub schema: String,
    /// Log time, nanoseconds.
    pub log_time_ns: u64,
    /// The payload (CDR with its encapsulation header).
    pub data: Vec<u8>,
}

/// Reads a recording front to back, one message at a time.
///
/// Every record length and every chunk's compressed and decompressed size is checked
/// against a limit before anything of that size is allocated
/// ([`crate::limits::Limits::max_record_bytes`]), and every chunk's CRC is checked before
/// any message of it is yielded: a corrupt chunk ends reading with
/// [`RecordingError::Corrupt`], never yields its messages.
pub struct RecordingReader<R = RecordingInput> {
    path: PathBuf,
    file: R,
    reader: LinearReader,
    channels: BTreeMap<u16, (String, u16)>,
    schemas: BTreeMap<u16, String>,
    messages: u64,
    /// Whether the first record (an MCAP header) has been read.
    seen_header: bool,
    /// Bytes handed to the MCAP reader so far (it asks for what it needs, no more).
    fed: u64,
    max_record_bytes: usize,
    done: bool,
    /// Reading on past damage ([`RecordingReader::salvaging`]).
    salvage: Option<crate::salvage::Salvager>,
}

/// The MCAP magic every recording starts with.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Where [`RecordingReader::open`] reads: a file, or a recording shipped in the binary
/// (`builtin:recordings/NAME.mcap`, [`crate::shipped`]).
#[derive(Debug)]
pub enum RecordingInput {
    /// A file.
    File(File),
    /// A shipped recording.
    Shipped(std::io::Cursor<&'static [u8]>),
}

impl RecordingInput {
    /// Opens `path`: a file, or a shipped recording (`builtin:recordings/NAME.mcap`).
    pub fn open(path: &Path) -> std::io::Result<Self> {
        Ok(match crate::shipped::find(path) {
            Some(shipped) => RecordingInput::Shipped(std::io::Cursor::new(shipped?.bytes)),
            None => RecordingInput::File(File::open(path)?),
        })
    }
}

impl Read for RecordingInput {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            RecordingInput::File(f) => f.read(buf),
            RecordingInput::Shipped(c) => c.read(buf),
        }
    }
}

impl Seek for RecordingInput {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        match self {
            RecordingInput::File(f) => f.seek(pos),
            RecordingInput::Shipped(c) => c.seek(pos),
        }
    }
}

impl RecordingReader {
    /// Opens `path` with the default record limit.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        Self::open_with_limit(path, crate::limits::Limits::default().max_record_bytes)
    }

    /// Opens `path` (a file, or a shipped recording: `builtin:recordings/NAME.mcap`);
    /// records (and chunks, compressed or decompressed) longer than
    /// `max_record_bytes` end reading with [`RecordingError::Corrupt`].
    pub fn open_with_limit(
        path: impl AsRef<Path>,
        max_record_bytes: usize,
    ) -> Result<Self, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let io = |source| RecordingError::Io {
            path: path.clone(),
            source,
        };
        let file = RecordingInput::open(&path).map_err(io)?;
        Self::from_reader(file, path, max_record_bytes)
    }
}

impl<R: Read + Seek> RecordingReader<R> {
    /// Reads a recording from `file` (named `path` in errors), with the record limit
    /// `max_record_bytes`.
    pub fn from_reader(
        mut file: R,
        path: PathBuf,
        max_record_bytes: usize,
    ) -> Result<Self, RecordingError> {
        let io = |source| RecordingError::Io {
            path: path.clone(),
            source,
        };
        let mut magic = [0_u8; 8];
        let mut got = 0;
        while got < magic.len() {
            match file.read(&mut magic[got..]).map_err(io)? {
                0 => break,
                n => got += n,
            }
        }
        if got == 0 {
            return Err(RecordingError::NotMcap {
                path,
                reason: "the file is empty".into(),
            });
        }
        if magic[..got] != MAGIC[..got] {
            return Err(RecordingError::NotMcap {
                path,
                reason: "it does not start with the MCAP magic".into(),
            });
        }
        if got < MAGIC.len() {
            return Err(RecordingError::Truncated {
                path,
                messages: 0,
                reason: "the file ends inside the MCAP magic".into(),
            });
        }
        // The reader checks the magic again and counts it into the data section's CRC.
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        let options = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_validate_data_section_crc(true)
            .with_validate_summary_section_crc(true)
            .with_record_length_limit(max_record_bytes);
        Ok(Self {
            path,
            file,
            reader: LinearReader::new_with_options(options),
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            messages: 0,
            seen_header: false,
            fed: 0,
            max_record_bytes,
            done: false,
            salvage: None,
        })
    }

    /// The same reader, reading on past what it cannot or must not read
    /// ([`crate::salvage`]): a damaged chunk, a record over the limit, a lying length, an
    /// end cut short are skipped and counted ([`RecordingReader::skips`]), and
    /// [`RecordingReader::next_message`] never fails. Without it (strict), reading ends
    /// at the first damage with its error.
    pub fn salvaging(mut self) -> Result<Self, RecordingError> {
        let salvager = crate::salvage::Salvager::new(&mut self.file, self.max_record_bytes)
            .map_err(|source| RecordingError::Io {
                path: self.path.clone(),
                source,
            })?;
        self.salvage = Some(salvager);
        Ok(self)
    }

    /// What reading on past damage skipped so far (`None`: a strict reader).
    pub fn skips(&self) -> Option<&crate::salvage::Skips> {
        self.salvage.as_ref().map(crate::salvage::Salvager::skips)
    }

    /// Messages read so far.
    pub fn messages_read(&self) -> u64 {
        self.messages
    }

    /// The topics of the channels seen so far, with their schema names.
    pub fn topics(&self) -> Vec<(String, String)> {
        self.channels
            .values()
            .map(|(topic, schema)| {
                (
                    topic.clone(),
                    self.schemas.get(schema).cloned().unwrap_or_default(),
                )
            })
            .collect()
    }

    /// [`RecordingReader::topics`] for a message: `"/a (pkg/msg/A), /b (pkg/msg/B)"`, or
    /// `"no topics"`.
    pub fn topics_text(&self) -> String {
        let found: Vec<String> = self
            .topics()
            .into_iter()
            .map(|(t, ty)| format!("{t} ({ty})"))
            .collect();
        if found.is_empty() {
            "no topics".into()
        } else {
            found.join(", ")
        }
    }

    /// The next message; `None` at the end. After an error the reader is done.
    pub fn next_message(&mut self) -> Option<Result<RecordedMessage, RecordingError>> {
        if self.done {
            return None;
        }
        if let Some(salvage) = &mut self.salvage {
            let Some(m) = salvage.next_message(&mut self.file) else {
                self.done = true;
                return None;
            };
            let channel = salvage.channel(m.channel).cloned().unwrap_or_else(|| {
                crate::salvage::ChannelInfo {
                    topic: String::new(),
                    schema_id: 0,
                    message_encoding: String::new(),
                    metadata: BTreeMap::new(),
                }
            });
            let schema = salvage
                .schema(channel.schema_id)
                .map(|s| s.name.clone())
                .unwrap_or_default();
            if let std::collections::btree_map::Entry::Vacant(e) = self.channels.entry(m.channel) {
                e.insert((channel.topic.clone(), channel.schema_id));
                self.schemas.insert(channel.schema_id, schema.clone());
            }
            self.messages += 1;
            return Some(Ok(RecordedMessage {
                topic: channel.topic,
                schema,
                log_time_ns: m.log_time,
                data: m.data,
            }));
        }
        // The mcap crate's calls are contained (`reader_failed`): a panic there is a
        // corrupt file, not the end of the process.
        let result = self.advance();
        if !matches!(result, Some(Ok(_))) {
            self.done = true;
        }
        result
    }

    fn advance(&mut self) -> Option<Result<RecordedMessage, RecordingError>> {
        loop {
            let reader = &mut self.reader;
            let event = match posestream_base::contain_panics(move || reader.next_event()) {
                Ok(next) => match next? {
                    Ok(e) => e,
                    Err(e) => return Some(Err(self.classify(e))),
                },
                Err(panic) => return Some(Err(self.reader_failed(panic))),
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    match self.file.read(buf) {
                        Ok(n) => {
                            self.reader.notify_read(n);
                            self.fed += n as u64;
                        }
                        Err(source) => {
                            return Some(Err(RecordingError::Io {
                                path: self.path.clone(),
                                source,
                            }));
                        }
                    }
                }
                LinearReadEvent::Record { opcode, data } => {
                    let record = match posestream_base::contain_panics(|| {
                        mcap::parse_record(opcode, data)
                    }) {
                        Ok(Ok(r)) => r,
                        Ok(Err(e)) => return Some(Err(self.corrupt(e.to_string()))),
                        Err(panic) => return Some(Err(self.reader_failed(panic))),
                    };
                    if !self.seen_header {
                        if !matches!(record, Record::Header(_)) {
                            return Some(Err(RecordingError::NotMcap {
                                path: self.path.clone(),
                                reason: "its first record is not an MCAP header".into(),
                            }));
                        }
                        self.seen_header = true;
                    }
                    match record {
                        Record::Schema { header, .. } => {
                            self.schemas.insert(header.id, header.name);
                        }
                        Record::Channel(c) => {
                            self.channels.insert(c.id, (c.topic, c.schema_id));
                        }
                        Record::Message { header, data } => {
                            let (topic, schema) = match self.channels.get(&header.channel_id) {
                                Some((t, s)) => {
                                    (t.clone(), self.schemas.get(s).cloned().unwrap_or_default())
                                }
                                None => {
                                    return Some(Err(self.corrupt(format!(
                                        "message on unknown channel {}",
                                        header.channel_id
                                    ))));
                                }
                            };
                            self.messages += 1;
                            return Some(Ok(RecordedMessage {
                                topic,
                                schema,
                                log_time_ns: header.log_time,
                                data: data.into_owned(),
                            }));
                        }
                        _ => {}
                    }
                }
            }
        }
    }

    /// The `mcap` crate panicked on this record (its arithmetic overflows on some
    /// malformed chunks: found by fuzzing, `linear_reader.rs:745`; release builds wrap and
    /// then fail further on): a corrupt file.
    fn reader_failed(&self, panic: String) -> RecordingError {
        self.corrupt(format!("the MCAP reader failed on this record ({panic})"))
    }

    /// What a failure of the MCAP reader means: the file cut short, or corrupt.
    fn classify(&mut self, e: McapError) -> RecordingError {
        match e {
            McapError::UnexpectedEof => self.truncated("the file ends inside a record".into()),
            _ if self.ends_in_unfinished_chunk() => {
                self.truncated("the file ends in a chunk its recorder never finished".into())
            }
            McapError::RecordTooLarge { .. } | McapError::ChunkTooLarge(_) => {
                self.corrupt(format!(
                    "{e}: beyond limits.max_record_bytes = {}",
                    self.max_record_bytes
                ))
            }
            e => self.corrupt(e.to_string()),
        }
    }

    /// True if the file's last top-level record is a chunk still holding the
    /// placeholder header the MCAP writer puts down when it starts one (length, sizes and
    /// CRC all ones), and the reader failed inside it: a recorder killed mid-chunk left
    /// it, which is a file cut short, not a corrupt one. Reads only record headers.
    fn ends_in_unfinished_chunk(&mut self) -> bool {
        const CHUNK: u8 = 0x06;
        const FOOTER: u8 = 0x02;
        let mut at = MAGIC.len() as u64;
        loop {
            let mut head = [0_u8; 9 + 24];
            if self.file.seek(SeekFrom::Start(at)).is_err()
                || self.file.read_exact(&mut head[..9]).is_err()
            {
                return false;
            }
            let len = u64::from_le_bytes(head[1..9].try_into().unwrap_or_default());
            if head[0] == CHUNK && len == u64::MAX {
                // start time, end time, uncompressed size: the last one is all ones.
                let placeholder =
                    self.file.read_exact(&mut head[9..]).is_ok() && head[25..33] == [0xff; 8];
                return placeholder && self.fed > at;
            }
            match at.checked_add(9).and_then(|a| a.checked_add(len)) {
                Some(next) if head[0] != FOOTER => at = next,
                _ => return false,
            }
        }
    }

    fn truncated(&self, reason: String) -> RecordingError {
        RecordingError::Truncated {
            path: self.path.clone(),
            messages: self.messages,
            reason,
        }
    }

    fn corrupt(&self, reason: String) -> RecordingError {
        RecordingError::Corrupt {
            path: self.path.clone(),
            messages: self.messages,
            reason,
        }
    }
}

impl<R: Read + Seek> Iterator for RecordingReader<R> {
    type Item = Result<RecordedMessage, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_message()
    }
}

/// [`read_topic`] reading on past damage ([`RecordingReader::salvaging`]): every
/// readable message of `topic`, and what was skipped.
pub fn salvage_topic<M: RosMessage>(
    path: &Path,
    topic: &str,
    max_record_bytes: usize,
) -> Result<(Vec<(u64, M)>, crate::salvage::Skips), RecordingError> {
    let mut reader = RecordingReader::open_with_limit(path, max_record_bytes)?.salvaging()?;
    let mut out = Vec::new();
    for msg in reader.by_ref() {
        let msg = msg?;
        if msg.topic == topic {
            match crate::decode::<M>(&msg.data) {
                Ok(m) => out.push((msg.log_time_ns, m)),
                Err(e) => tracing::warn!("{}: {e}", path.display()),
            }
        }
    }
    let skipped = reader.skips().cloned().unwrap_or_default();
    Ok((out, skipped))
}

/// Decodes every message of `topic` in a recording as `M` (for tests and tools).
pub fn read_topic<M: RosMessage>(
    path: &Path,
    topic: &str,
) -> Result<Vec<(u64, M)>, RecordingError> {
    let mut out = Vec::new();
    for msg in RecordingReader::open(path)? {
        let msg = msg?;
        if msg.topic == topic {
            match crate::decode::<M>(&msg.data) {
                Ok(m) => out.push((msg.log_time_ns, m)),
                Err(e) => tracing::warn!("{}: {e}", path.display()),
            }
        }
    }
    Ok(out)
}
