//! Reading a recording: [`RecordingReader`] (strict, or reading on past damage), its
//! input ([`RecordingInput`]), and the whole-topic readers [`read_topic`] and
//! [`salvage_topic`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use mcap::McapError;
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::RecordingError;
use crate::RosMessage;

/// One message read from a recording.
#[derive(Debug, Clone, PartialEq, Default)]
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
        let mut message = RecordedMessage::default();
        Some(self.next_message_into(&mut message)?.map(|()| message))
    }

    /// [`RecordingReader::next_message`] written over `out` (its topic, schema and data
    /// buffers reused): reading a recording strictly allocates nothing per message once
    /// warm; reading on past damage, one buffer (the message's bytes as the salvage reader
    /// copied them out of their chunk).
    pub fn next_message_into(
        &mut self,
        out: &mut RecordedMessage,
    ) -> Option<Result<(), RecordingError>> {
        if self.done {
            return None;
        }
        if let Some(salvage) = &mut self.salvage {
            let Some(m) = salvage.next_message(&mut self.file) else {
                self.done = true;
                return None;
            };
            let channel = salvage.channel(m.channel);
            let schema_id = channel.map_or(0, |c| c.schema_id);
            let schema = salvage.schema(schema_id).map_or("", |s| s.name.as_str());
            if let std::collections::btree_map::Entry::Vacant(e) = self.channels.entry(m.channel) {
                e.insert((
                    channel.map_or_else(String::new, |c| c.topic.clone()),
                    schema_id,
                ));
                self.schemas.insert(schema_id, schema.to_owned());
            }
            self.messages += 1;
            out.topic.clear();
            out.topic.push_str(channel.map_or("", |c| c.topic.as_str()));
            out.schema.clear();
            out.schema.push_str(schema);
            out.log_time_ns = m.log_time;
            // The payload read before goes back to be written over.
            let before = std::mem::replace(&mut out.data, m.data);
            salvage.recycle(before);
            return Some(Ok(()));
        }
        // The mcap crate's calls are contained (`reader_failed`): a panic there is a
        // corrupt file, not the end of the process.
        let result = self.advance(out);
        if !matches!(result, Some(Ok(()))) {
            self.done = true;
        }
        result
    }

    fn advance(&mut self, out: &mut RecordedMessage) -> Option<Result<(), RecordingError>> {
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
                            let Some((topic, schema)) = self.channels.get(&header.channel_id)
                            else {
                                return Some(Err(self.corrupt(format!(
                                    "message on unknown channel {}",
                                    header.channel_id
                                ))));
                            };
                            out.topic.clear();
                            out.topic.push_str(topic);
                            out.schema.clear();
                            out.schema
                                .push_str(self.schemas.get(schema).map_or("", String::as_str));
                            out.log_time_ns = header.log_time;
                            out.data.clear();
                            out.data.extend_from_slice(&data);
                            self.messages += 1;
                            return Some(Ok(()));
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
