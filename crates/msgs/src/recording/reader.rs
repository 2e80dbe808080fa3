//! Reading a recording: [`RecordingReader`] (strict, or reading on past damage), its
//! input ([`RecordingInput`]), and the whole-topic readers [`read_topic`] and
//! [`salvage_topic`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

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

/// Reads a recording front to back, one message at a time, through the salvage reader
/// ([`crate::salvage::Salvager`]): strict (the default) or reading on past damage
/// ([`RecordingReader::salvaging`]).
///
/// Both read the same way and under the same limits: every record length and every
/// chunk's compressed and decompressed size is checked against
/// [`crate::limits::Limits::max_record_bytes`] before anything of that size is allocated,
/// and every chunk's CRC before any message of it is yielded. Where reading on past damage
/// would skip something (and say so), a strict reader ends with one error instead:
/// [`RecordingError::Truncated`] for a file cut short (every message before the cut was
/// read), [`RecordingError::Corrupt`] for anything else, naming the damage and its bytes;
/// it never yields a message of a damaged chunk. A strict reader also checks that the
/// first record is an MCAP header, the data section's CRC and the summary's.
pub struct RecordingReader<R = RecordingInput> {
    path: PathBuf,
    file: R,
    salvage: crate::salvage::Salvager,
    strict: bool,
    /// The first record is not an MCAP header (a strict reader's first error).
    no_header: bool,
    channels: BTreeMap<u16, (String, u16)>,
    schemas: BTreeMap<u16, String>,
    messages: u64,
    max_record_bytes: usize,
    done: bool,
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
    /// Opens `path`: a regular file ([`posestream_base::files::open_regular`]: not a
    /// device or a FIFO), or a shipped recording (`builtin:recordings/NAME.mcap`).
    pub fn open(path: &Path) -> std::io::Result<Self> {
        Ok(match crate::shipped::find(path) {
            Some(shipped) => RecordingInput::Shipped(std::io::Cursor::new(shipped?.bytes)),
            None => RecordingInput::File(posestream_base::files::open_regular(path)?),
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
        // An MCAP file's first record is its header.
        let mut first = [0_u8; 1];
        let first = match file.read(&mut first).map_err(io)? {
            0 => None,
            _ => Some(first[0]),
        };
        let mut salvage = crate::salvage::Salvager::new(&mut file, max_record_bytes).map_err(io)?;
        salvage.checking_data_crc();
        salvage.stopping_at_damage();
        Ok(Self {
            path,
            file,
            salvage,
            strict: true,
            no_header: first.is_some_and(|op| op != mcap::records::op::HEADER),
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            messages: 0,
            max_record_bytes,
            done: false,
        })
    }

    /// The same reader, reading on past what it cannot or must not read
    /// ([`crate::salvage`]): a damaged chunk, a record over the limit, a lying length, an
    /// end cut short are skipped and counted ([`RecordingReader::skips`]), and
    /// [`RecordingReader::next_message`] never fails. Without it (strict), reading ends
    /// at the first damage with its error. (It does not fail: a `Result` for the callers
    /// that once opened the file here.)
    pub fn salvaging(mut self) -> Result<Self, RecordingError> {
        self.strict = false;
        self.salvage.reading_on();
        Ok(self)
    }

    /// What reading on past damage skipped so far (`None`: a strict reader).
    pub fn skips(&self) -> Option<&crate::salvage::Skips> {
        (!self.strict).then(|| self.salvage.skips())
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
    /// buffers reused; the payload buffer handed back to the salvage reader, which copies
    /// the next message's bytes over it): once warm, reading allocates a chunk's
    /// decompressed records at most.
    pub fn next_message_into(
        &mut self,
        out: &mut RecordedMessage,
    ) -> Option<Result<(), RecordingError>> {
        if self.done {
            return None;
        }
        if self.strict && self.no_header {
            self.done = true;
            return Some(Err(RecordingError::NotMcap {
                path: self.path.clone(),
                reason: "its first record is not an MCAP header".into(),
            }));
        }
        let skipped = self.salvage.skips().total();
        let next = self.salvage.next_message(&mut self.file);
        if self.strict && self.salvage.skips().total() > skipped {
            // What reading on past damage would skip ends a strict read (nothing of the
            // damaged record is yielded: its messages came in this call).
            self.done = true;
            return Some(Err(self.damaged()));
        }
        let Some(m) = next else {
            self.done = true;
            return self.strict.then(|| self.end_checks()).flatten().map(Err);
        };
        let salvage = &mut self.salvage;
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
        Some(Ok(()))
    }

    /// The error a strict reader ends with where reading on past damage skipped.
    fn damaged(&self) -> RecordingError {
        use crate::salvage::Damage;
        let skips = self.salvage.skips();
        // The first skip: its range, or (a skip without bytes of its own) its kind.
        let range = skips.ranges.first();
        let kind = range
            .map(|r| r.kind)
            .or_else(|| skips.counts.keys().next().copied());
        let kind = kind.unwrap_or(Damage::Unparsable);
        let place = range.map_or_else(String::new, |r| format!(" at bytes {}-{}", r.from, r.to));
        let what = match kind {
            Damage::CutShort => {
                let reason = match range {
                    Some(r) if r.from < r.to && r.to - r.from < 9 => format!(
                        "the file ends in {} after its last record, too few for one",
                        match r.to - r.from {
                            1 => "1 byte".to_string(),
                            n => format!("{n} bytes"),
                        }
                    ),
                    Some(r) if r.from < r.to => {
                        format!(
                            "the file ends inside the record at bytes {}-{}",
                            r.from, r.to
                        )
                    }
                    _ => "the file ends after its last record, without a footer".into(),
                };
                return self.truncated(reason);
            }
            Damage::OverLimit => format!(
                "a record beyond limits.max_record_bytes = {}",
                self.max_record_bytes
            ),
            Damage::BadCrc => "a chunk whose CRC does not match its records".into(),
            Damage::NotDecompressed => {
                "a chunk that does not decompress to the size it says".into()
            }
            Damage::Unparsable => "a record that does not parse, an opcode MCAP does not \
                                   have, or a chunk with another opcode"
                .into(),
            Damage::LyingLength => "a length that does not lead to the next record".into(),
            Damage::UnknownChannel => "a message on a channel never declared".into(),
            Damage::Duplicate => "a chunk that repeats one before it, byte for byte".into(),
            Damage::Repeated => {
                "a message that repeats one before it (channel, sequence, times and payload)".into()
            }
            Damage::Conflict => {
                "a schema or channel declared again as another under the same id".into()
            }
        };
        self.corrupt(format!(
            "{what}{place} (read past it without strict, or copy the rest with `posestream recover`)"
        ))
    }

    /// What a strict reader checks once every message was read: the data section's CRC,
    /// the summary's and the closing magic.
    fn end_checks(&mut self) -> Option<RecordingError> {
        if let Some((recorded, computed)) = self.salvage.data_crc_mismatch() {
            return Some(self.corrupt(format!(
                "the data section's CRC does not match (recorded {recorded:#010x}, computed \
                 {computed:#010x})"
            )));
        }
        let reason = self.salvage.end_mismatch(&mut self.file)?;
        Some(self.corrupt(reason))
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
