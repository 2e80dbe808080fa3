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
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
use mcap::{Compression, WriteOptions, Writer};

use crate::msgs::{self, RosMessage};

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
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] msgs::EncodeError),
}

/// Writes messages of any [`RosMessage`] type to an MCAP file.
pub struct Recorder {
    path: PathBuf,
    writer: Writer<BufWriter<File>>,
    channels: BTreeMap<String, u16>,
    counts: BTreeMap<String, (String, u64)>,
    sequence: u32,
    first_ns: Option<u64>,
    last_ns: u64,
    flush_every: Option<Duration>,
    last_flush: Instant,
}

impl Recorder {
    /// Creates (or truncates) `path`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|source| RecordingError::Io {
            path: path.clone(),
            source,
        })?;
        let writer = WriteOptions::new()
            .profile("ros2")
            .library(concat!("posestream ", env!("CARGO_PKG_VERSION")))
            .compression(Some(Compression::Zstd))
            .chunk_size(Some(1 << 20))
            .create(BufWriter::new(file))
            .map_err(|source| RecordingError::Mcap {
                path: path.clone(),
                source,
            })?;
        Ok(Self {
            path,
            writer,
            channels: BTreeMap::new(),
            counts: BTreeMap::new(),
            sequence: 0,
            first_ns: None,
            last_ns: 0,
            flush_every: Some(Duration::from_secs(1)),
            last_flush: Instant::now(),
        })
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
        let data = msgs::encode(msg)?;
        self.write_encoded::<M>(topic, log_time_ns, &data)
    }

    /// Appends an already encoded message (CDR with its encapsulation header).
    pub fn write_encoded<M: RosMessage>(
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

    /// Closes the current chunk and flushes it to the file: whatever happens to the
    /// process afterwards, the messages so far can be read.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        self.last_flush = Instant::now();
        self.writer
            .flush()
            .map_err(|source| self.mcap_error(source))
    }

    /// Writes the summary and footer; returns what was recorded.
    pub fn finish(mut self) -> Result<RecordingSummary, RecordingError> {
        self.writer
            .finish()
            .map_err(|source| self.mcap_error(source))?;
        Ok(RecordingSummary {
            path: self.path.clone(),
            topics: self.counts.clone(),
            start_ns: self.first_ns.unwrap_or(0),
            end_ns: self.last_ns,
        })
    }

    fn mcap_error(&self, source: mcap::McapError) -> RecordingError {
        RecordingError::Mcap {
            path: self.path.clone(),
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
pub struct RecordingReader {
    path: PathBuf,
    file: File,
    reader: LinearReader,
    channels: BTreeMap<u16, (String, u16)>,
    schemas: BTreeMap<u16, String>,
    messages: u64,
    done: bool,
}

impl RecordingReader {
    /// Opens `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref().to_path_buf();
        let file = File::open(&path).map_err(|source| RecordingError::Io {
            path: path.clone(),
            source,
        })?;
        Ok(Self {
            path,
            file,
            reader: LinearReader::new(),
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            messages: 0,
            done: false,
        })
    }

    /// Messages read so far.
    pub fn messages_read(&self) -> u64 {
        self.messages
    }

    /// The next message; `None` at the end. After an error the reader is done.
    pub fn next_message(&mut self) -> Option<Result<RecordedMessage, RecordingError>> {
        if self.done {
            return None;
        }
        let result = self.advance();
        if !matches!(result, Some(Ok(_))) {
            self.done = true;
        }
        result
    }

    fn advance(&mut self) -> Option<Result<RecordedMessage, RecordingError>> {
        loop {
            let event = match self.reader.next_event()? {
                Ok(e) => e,
                Err(e) => return Some(Err(self.truncated(e.to_string()))),
            };
            match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    match self.file.read(buf) {
                        Ok(n) => self.reader.notify_read(n),
                        Err(source) => {
                            return Some(Err(RecordingError::Io {
                                path: self.path.clone(),
                                source,
                            }));
                        }
                    }
                }
                LinearReadEvent::Record { opcode, data } => {
                    let record = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => return Some(Err(self.truncated(e.to_string()))),
                    };
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
                                    return Some(Err(self.truncated(format!(
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

    fn truncated(&self, reason: String) -> RecordingError {
        RecordingError::Truncated {
            path: self.path.clone(),
            messages: self.messages,
            reason,
        }
    }
}

impl Iterator for RecordingReader {
    type Item = Result<RecordedMessage, RecordingError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_message()
    }
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
            match msgs::decode::<M>(&msg.data) {
                Ok(m) => out.push((msg.log_time_ns, m)),
                Err(e) => tracing::warn!("{}: {e}", path.display()),
            }
        }
    }
    Ok(out)
}
