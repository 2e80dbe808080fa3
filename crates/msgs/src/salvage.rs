//! Everything readable of a damaged recording: [`Salvager`] reads an MCAP file record by
//! record and skips what it cannot or must not read, as the `mcap` CLI's `recover` and
//! rosbag2's `reindex` do, counting each skip by kind with its byte range ([`Skips`]).
//!
//! What is skipped, and where reading goes on:
//!
//! - a record longer than the limit ([`crate::limits::Limits::max_record_bytes`]): never
//!   read (nothing of its size is allocated); reading goes on after it when a record
//!   starts there, else as for a lying length;
//! - a chunk whose data does not decompress, or decompresses to another size than its
//!   header says, or whose CRC does not match, or whose records do not parse: its
//!   messages (the ones before a record that does not parse are kept); reading goes on
//!   after it;
//! - a length that lies (a record running past the end of the file, or followed by no
//!   record), an opcode that is none of MCAP's: the reader scans forward for the next
//!   record that holds together (a known opcode, a length within the limit and the file,
//!   and a chunk that decompresses and passes its CRC, or a record followed by another);
//! - the end of a file cut short (a recorder killed mid-chunk);
//! - a message on a channel never declared.
//!
//! The summary section and the index are not read: everything comes from the data, which
//! is what holds the messages (a summary that disagrees with it cannot mislead). Memory
//! is bounded by the limit: one record's body and one chunk's decompressed records at a
//! time, and the scan reads the file in blocks of [`SCAN_BLOCK`] bytes.
//!
//! Written by hand on the `mcap` crate's record parser (`mcap::parse_record`): the crate's
//! readers stop at the first bad record (their design: an index is trusted or the file
//! is read front to back), and none of them resumes.

use std::collections::{BTreeMap, VecDeque};
use std::io::{Read, Seek, SeekFrom};

use mcap::records::{Record, op};
use serde::Serialize;

/// Bytes the scan for the next record reads at once.
pub const SCAN_BLOCK: usize = 64 << 10;

/// Ranges of skipped bytes kept for the report, at most (every skip is counted).
pub const MAX_RANGES: usize = 64;

/// The MCAP magic at the start (and end) of a recording.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Why a part of a recording was skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Damage {
    /// A record (or a chunk's decompressed records) longer than the limit.
    OverLimit,
    /// A chunk whose CRC does not match its records.
    BadCrc,
    /// A chunk whose data does not decompress to the size its header says.
    NotDecompressed,
    /// A record that does not parse, or an opcode that is none of MCAP's.
    Unparsable,
    /// A length that runs past its record's end, or is followed by no record.
    LyingLength,
    /// The file ends inside a record.
    CutShort,
    /// A message on a channel never declared.
    UnknownChannel,
}

impl Damage {
    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Damage::OverLimit => "over the limit",
            Damage::BadCrc => "CRC mismatch",
            Damage::NotDecompressed => "not decompressed",
            Damage::Unparsable => "unparsable",
            Damage::LyingLength => "lying length",
            Damage::CutShort => "cut short",
            Damage::UnknownChannel => "unknown channel",
        }
    }
}

/// One skipped part: its kind and the bytes of the file it spans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Skipped {
    /// Why.
    pub kind: Damage,
    /// Its first byte in the file.
    pub from: u64,
    /// One past its last byte.
    pub to: u64,
}

/// What a [`Salvager`] skipped.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Skips {
    /// Skips by kind.
    pub counts: BTreeMap<Damage, u64>,
    /// The first [`MAX_RANGES`] skipped parts, in file order.
    pub ranges: Vec<Skipped>,
    /// Bytes skipped in all.
    pub bytes: u64,
}

impl Skips {
    /// Nothing was skipped.
    pub fn is_empty(&self) -> bool {
        self.counts.is_empty()
    }

    /// Skips in all.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }

    /// Counts a skip that spans no bytes of its own (a message, a corrected length).
    fn note(&mut self, kind: Damage) {
        *self.counts.entry(kind).or_default() += 1;
    }

    fn add(&mut self, kind: Damage, from: u64, to: u64) {
        *self.counts.entry(kind).or_default() += 1;
        self.bytes = self.bytes.saturating_add(to.saturating_sub(from));
        if self.ranges.len() < MAX_RANGES {
            self.ranges.push(Skipped { kind, from, to });
        }
    }

    /// One line for people: `3 skipped (2 CRC mismatch, 1 lying length; 71.0 MB):
    /// bytes 1234-71000000, ...`.
    pub fn summary(&self) -> String {
        let kinds: Vec<String> = self
            .counts
            .iter()
            .map(|(k, n)| format!("{n} {}", k.name()))
            .collect();
        let mut ranges: Vec<String> = self
            .ranges
            .iter()
            .take(8)
            .map(|r| format!("{}-{}", r.from, r.to))
            .collect();
        if self.total() > ranges.len() as u64 {
            ranges.push("...".into());
        }
        format!(
            "{} skipped ({}; {} bytes): bytes {}",
            self.total(),
            kinds.join(", "),
            self.bytes,
            ranges.join(", ")
        )
    }
}

/// A schema as the recording declares it.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemaInfo {
    /// Its name (`pkg/msg/Type`).
    pub name: String,
    /// Its encoding (`ros2msg`).
    pub encoding: String,
    /// Its text.
    pub data: Vec<u8>,
}

/// A channel as the recording declares it.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// Its topic.
    pub topic: String,
    /// Its schema's id (0: none).
    pub schema_id: u16,
    /// Its messages' encoding (`cdr`).
    pub message_encoding: String,
    /// Its metadata (rosbag2's QoS profiles).
    pub metadata: BTreeMap<String, String>,
}

/// A message read by a [`Salvager`].
#[derive(Debug, Clone, PartialEq)]
pub struct Salvaged {
    /// Its channel (declared: [`Salvager::channel`]).
    pub channel: u16,
    /// Its sequence number.
    pub sequence: u32,
    /// Log time, nanoseconds.
    pub log_time: u64,
    /// Publish time, nanoseconds.
    pub publish_time: u64,
    /// Its payload.
    pub data: Vec<u8>,
}

/// Reads every message of a recording that can be read; see the module docs. It holds
/// what it has learnt of the file; the file itself is lent to each call.
#[derive(Debug)]
pub struct Salvager {
    len: u64,
    at: u64,
    limit: u64,
    schemas: BTreeMap<u16, SchemaInfo>,
    channels: BTreeMap<u16, ChannelInfo>,
    pending: VecDeque<Salvaged>,
    skips: Skips,
    done: bool,
    body: Vec<u8>,
    /// The schemas and channels of the summary section, for messages whose declarations
    /// in the data were lost (the data's own win where both declare an id).
    summary: (BTreeMap<u16, SchemaInfo>, BTreeMap<u16, ChannelInfo>),
    /// Bytes of schema text kept (at most the limit).
    declared: u64,
    /// Payload buffers handed back ([`Salvager::recycle`]), written over by the next
    /// messages (at most [`SPARE_PAYLOADS`]).
    spare: Vec<Vec<u8>>,
}

/// Payload buffers a [`Salvager`] keeps to write messages over, at most.
const SPARE_PAYLOADS: usize = 64;

/// A record's opcode and length are those of some MCAP record.
fn known(op: u8) -> bool {
    (op::HEADER..=op::DATA_END).contains(&op)
}

/// The first of MCAP's opcodes for an application's private records (0x80 to 0xff).
const PRIVATE: u8 = 0x80;

/// A footer's record: opcode, length, summary start, summary offset start, CRC.
const FOOTER_BYTES: u64 = 9 + 20;

impl Salvager {
    /// Reads `file` (its first 8 bytes the MCAP magic, which the caller checked), records
    /// of at most `max_record_bytes`.
    pub fn new<R: Read + Seek>(file: &mut R, max_record_bytes: usize) -> std::io::Result<Self> {
        let len = file.seek(SeekFrom::End(0))?;
        let mut salvager = Self {
            len,
            at: MAGIC.len() as u64,
            limit: max_record_bytes as u64,
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            pending: VecDeque::new(),
            skips: Skips::default(),
            done: false,
            body: Vec::new(),
            summary: (BTreeMap::new(), BTreeMap::new()),
            declared: 0,
            spare: Vec::new(),
        };
        salvager.read_summary(file);
        Ok(salvager)
    }

    /// Reads the schemas and channels of the summary section, when the footer says where
    /// it is and its records hold together; anything else leaves them empty.
    fn read_summary<R: Read + Seek>(&mut self, file: &mut R) {
        // The footer: opcode, length 20, summary start, summary offset start, CRC; magic.
        let Some(footer) = self.len.checked_sub(9 + 20 + MAGIC.len() as u64) else {
            return;
        };
        let Some((op::FOOTER, 20)) = Self::head(file, footer) else {
            return;
        };
        let mut start = [0_u8; 8];
        if file.read_exact(&mut start).is_err() {
            return;
        }
        let mut at = u64::from_le_bytes(start);
        if at == 0 || at >= footer {
            return;
        }
        let (schemas, channels) = (
            std::mem::take(&mut self.schemas),
            std::mem::take(&mut self.channels),
        );
        while at < footer {
            let Some(end) = self.plausible(file, at).filter(|&e| e <= footer) else {
                break;
            };
            let Some((opcode, len)) = Self::head(file, at) else {
                break;
            };
            if (opcode == op::SCHEMA || opcode == op::CHANNEL)
                && self.read_record(file, at, len).is_some()
            {
                let body = std::mem::take(&mut self.body);
                let _ = self.record(opcode, &body);
                self.body = body;
            }
            at = end;
        }
        self.summary = (
            std::mem::replace(&mut self.schemas, schemas),
            std::mem::replace(&mut self.channels, channels),
        );
    }

    /// Takes the summary's declaration of channel `id` (and its schema) where the data's
    /// was lost; true if there was one.
    fn declared_in_summary(&mut self, id: u16) -> bool {
        let Some(channel) = self.summary.1.get(&id).cloned() else {
            return false;
        };
        if let Some(schema) = self.summary.0.get(&channel.schema_id).cloned() {
            self.schemas.entry(channel.schema_id).or_insert(schema);
        }
        self.channels.insert(id, channel);
        true
    }

    /// Where reading is in the file (bytes), and the file's length.
    pub fn progress(&self) -> (u64, u64) {
        (self.at.min(self.len), self.len)
    }

    /// What was skipped so far.
    pub fn skips(&self) -> &Skips {
        &self.skips
    }

    /// A declared channel.
    pub fn channel(&self, id: u16) -> Option<&ChannelInfo> {
        self.channels.get(&id)
    }

    /// A declared schema (the summary's where the data's was lost).
    pub fn schema(&self, id: u16) -> Option<&SchemaInfo> {
        self.schemas.get(&id).or_else(|| self.summary.0.get(&id))
    }

    /// The channels declared so far.
    pub fn channels(&self) -> &BTreeMap<u16, ChannelInfo> {
        &self.channels
    }

    /// The next message that can be read; `None` at the end. Reading errors of the file
    /// itself (a disk error) end it as a part cut short.
    pub fn next_message<R: Read + Seek>(&mut self, file: &mut R) -> Option<Salvaged> {
        loop {
            if let Some(m) = self.pending.pop_front() {
                return Some(m);
            }
            if self.done {
                return None;
            }
            self.step(file);
        }
    }

    /// Hands back a message's payload once used: the next messages are copied over it
    /// (kept up to a few; a warm reader allocates no payload).
    pub fn recycle(&mut self, payload: Vec<u8>) {
        if self.spare.len() < SPARE_PAYLOADS && payload.capacity() > 0 {
            self.spare.push(payload);
        }
    }

    /// The opcode and length of the record at `at`, if 9 bytes are there.
    fn head<R: Read + Seek>(file: &mut R, at: u64) -> Option<(u8, u64)> {
        let mut h = [0_u8; 9];
        file.seek(SeekFrom::Start(at)).ok()?;
        file.read_exact(&mut h).ok()?;
        let len = u64::from_le_bytes(h[1..9].try_into().ok()?);
        Some((h[0], len))
    }

    /// Where the record at `at` ends, if it is a known record that fits the file and
    /// the limit.
    fn plausible<R: Read + Seek>(&self, file: &mut R, at: u64) -> Option<u64> {
        let (op, len) = Self::head(file, at)?;
        let end = at.checked_add(9)?.checked_add(len)?;
        // An application's private record counts as a record here (never as a place the
        // scan resumes: that takes a known opcode).
        ((known(op) || op >= PRIVATE) && len <= self.limit && end <= self.len).then_some(end)
    }

    /// A record starts at `at`, or the file (or its closing magic) ends there.
    fn boundary<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        let private = matches!(Self::head(file, at), Some((opcode, _)) if opcode >= PRIVATE);
        let record = match self.plausible(file, at) {
            // An application's record only when a known one (or the end) follows it: a
            // byte inside a record is too often 0x80 or more to take it on its own.
            Some(end) if private => {
                self.ends(end)
                    || matches!(Self::head(file, end), Some((opcode, _)) if known(opcode))
                        && self.plausible(file, end).is_some()
            }
            Some(_) => true,
            None => false,
        };
        self.ends(at) || record || self.cut_at(file, at) || {
            // A chunk whose own length field lies is still a record there when its own
            // sizes lead to the next one.
            matches!(Self::head(file, at), Some((op::CHUNK, _)))
                && self.chunk_end(file, at).is_some_and(|own| {
                    own - at - 9 <= self.limit
                        && (self.ends(own) || self.plausible(file, own).is_some())
                })
        }
    }

    /// A record starts at `at` that the end of the file cuts short: a known opcode and a
    /// length within the limit that runs past the end.
    fn cut_at<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        Self::head(file, at).is_some_and(|(opcode, len)| {
            known(opcode) && len <= self.limit && at.saturating_add(9 + len) > self.len
        })
    }

    /// The file ends at `at` (or its closing magic starts there).
    fn ends(&self, at: u64) -> bool {
        at == self.len || self.len.checked_sub(at) == Some(MAGIC.len() as u64)
    }

    /// Reads and handles the record at `self.at`, or skips.
    fn step<R: Read + Seek>(&mut self, file: &mut R) {
        let at = self.at;
        let Some((op, len)) = Self::head(file, at) else {
            // The end without a data-end record or footer: a file cut short (at a record
            // boundary, a recorder killed between chunks, nothing is lost).
            self.skips.add(Damage::CutShort, at.min(self.len), self.len);
            self.done = true;
            return;
        };
        if (op == op::FOOTER && self.footer_at(at))
            || (op == op::DATA_END && self.data_end_at(file, at))
        {
            // The data section is over: the summary is not read (see the module docs).
            self.done = true;
            return;
        }
        if op == op::FOOTER || op == op::DATA_END {
            // Where the data goes on: not the end.
            self.resync(file, at, Damage::Unparsable);
            return;
        }
        if op >= PRIVATE {
            // A record of an application's own (MCAP's private opcodes): passed over
            // where its length leads to a record, else as any opcode unknown.
            match at.checked_add(9).and_then(|a| a.checked_add(len)) {
                Some(end) if end <= self.len && self.boundary(file, end) => self.at = end,
                _ => self.resync(file, at, Damage::Unparsable),
            }
            return;
        }
        let mut len = len;
        let mut end = at.checked_add(9).and_then(|a| a.checked_add(len));
        // A chunk says its own size: where its length disagrees and the chunk's own end
        // is followed by a record, the length lied and the chunk is read as it says.
        if op == op::CHUNK
            && let Some(own) = self.chunk_end(file, at)
            && Some(own) != end
            && own - at - 9 <= self.limit
            && self.boundary(file, own)
        {
            self.skips.note(Damage::LyingLength);
            len = own - at - 9;
            end = Some(own);
        }
        let Some(end) = end.filter(|&e| known(op) && e <= self.len) else {
            let kind = if known(op) {
                Damage::LyingLength
            } else {
                Damage::Unparsable
            };
            self.resync(file, at, kind);
            return;
        };
        if len > self.limit {
            if self.boundary(file, end) {
                self.skips.add(Damage::OverLimit, at, end);
                self.at = end;
            } else {
                self.resync(file, at, Damage::LyingLength);
            }
            return;
        }
        if op != op::CHUNK && !self.boundary(file, end) {
            // A record whose length does not lead to the next one: not read (a message
            // would take the next record's bytes for its own), the next one looked for.
            self.resync(file, at, Damage::LyingLength);
            return;
        }
        match self.read_record(file, at, len).map(|()| self.handle(op)) {
            Some(Ok(())) => self.at = end,
            Some(Err(kind)) if self.boundary(file, end) => {
                self.skips.add(kind, at, end);
                self.at = end;
            }
            // Not a record, or not this long: look for the next one.
            Some(Err(_)) => self.resync(file, at, Damage::LyingLength),
            None => {
                self.skips.add(Damage::CutShort, at, self.len);
                self.done = true;
            }
        }
    }

    /// Where the chunk at `at` ends by its own sizes (its compression's name and its
    /// compressed size), if those fit the file.
    fn chunk_end<R: Read + Seek>(&self, file: &mut R, at: u64) -> Option<u64> {
        // Opcode, length, start and end times, uncompressed size, CRC, compression's length.
        let mut fixed = [0_u8; 9 + 8 + 8 + 8 + 4 + 4];
        file.seek(SeekFrom::Start(at)).ok()?;
        file.read_exact(&mut fixed).ok()?;
        let name = u64::from(u32::from_le_bytes(fixed[37..41].try_into().ok()?));
        let sizes = at.checked_add(fixed.len() as u64)?.checked_add(name)?;
        let mut compressed = [0_u8; 8];
        file.seek(SeekFrom::Start(sizes)).ok()?;
        file.read_exact(&mut compressed).ok()?;
        let end = sizes
            .checked_add(8)?
            .checked_add(u64::from_le_bytes(compressed))?;
        (end <= self.len).then_some(end)
    }

    /// Whether a footer at `at` is the file's: just before the closing magic.
    fn footer_at(&self, at: u64) -> bool {
        self.len.checked_sub(FOOTER_BYTES + MAGIC.len() as u64) == Some(at)
    }

    /// Whether a data-end record at `at` ends the data section: the file's footer
    /// follows it, or its summary, as the footer says.
    fn data_end_at<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        let Some(footer) = self.len.checked_sub(FOOTER_BYTES + MAGIC.len() as u64) else {
            return false;
        };
        let Some((op::DATA_END, 4)) = Self::head(file, at) else {
            return false;
        };
        let next = at + 9 + 4;
        if !matches!(Self::head(file, footer), Some((op::FOOTER, 20))) {
            return false;
        }
        let mut start = [0_u8; 8];
        if file.read_exact(&mut start).is_err() {
            return false;
        }
        let summary = u64::from_le_bytes(start);
        next == footer || summary == next
    }

    /// Reads the body of the record at `at` into `self.body`.
    fn read_record<R: Read + Seek>(&mut self, file: &mut R, at: u64, len: u64) -> Option<()> {
        self.body.clear();
        file.seek(SeekFrom::Start(at + 9)).ok()?;
        file.by_ref()
            .take(len)
            .read_to_end(&mut self.body)
            .ok()
            .filter(|&n| n as u64 == len)
            .map(|_| ())
    }

    /// Handles the record in `self.body`: declarations kept, messages queued.
    fn handle(&mut self, opcode: u8) -> Result<(), Damage> {
        let body = std::mem::take(&mut self.body);
        let result = match opcode {
            op::CHUNK => self.chunk(&body),
            _ => self.record(opcode, &body).map(|declared| {
                if !declared {
                    self.skips.note(Damage::UnknownChannel);
                }
            }),
        };
        self.body = body;
        result
    }

    /// Handles one record outside a chunk or inside one; a message on an undeclared
    /// channel is counted (`Ok(false)`).
    fn record(&mut self, opcode: u8, body: &[u8]) -> Result<bool, Damage> {
        // Parsed where it lies (nothing copied but what is kept).
        let record = posestream_base::contain_panics(|| mcap::parse_record(opcode, body));
        let Ok(Ok(record)) = record else {
            return Err(Damage::Unparsable);
        };
        match record {
            Record::Schema { header, data } => {
                // Schema texts kept at most the limit's worth in all: a file of huge
                // schemas keeps their names only (a copy of it has them empty).
                let fits = self.declared.saturating_add(data.len() as u64) <= self.limit;
                let data = if fits {
                    self.declared += data.len() as u64;
                    data.into_owned()
                } else {
                    self.skips.note(Damage::OverLimit);
                    Vec::new()
                };
                self.schemas.insert(
                    header.id,
                    SchemaInfo {
                        name: header.name,
                        encoding: header.encoding,
                        data,
                    },
                );
            }
            Record::Channel(c) => {
                self.channels.insert(
                    c.id,
                    ChannelInfo {
                        topic: c.topic,
                        schema_id: c.schema_id,
                        message_encoding: c.message_encoding,
                        metadata: c.metadata,
                    },
                );
            }
            Record::Message { header, data } => {
                if !self.channels.contains_key(&header.channel_id)
                    && !self.declared_in_summary(header.channel_id)
                {
                    return Ok(false);
                }
                // Copied over a payload handed back, if there is one.
                let mut payload = self.spare.pop().unwrap_or_default();
                payload.clear();
                payload.extend_from_slice(&data);
                self.pending.push_back(Salvaged {
                    channel: header.channel_id,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data: payload,
                });
            }
            _ => {}
        }
        Ok(true)
    }

    /// A chunk: decompressed within the limit, its CRC checked, then its records; the
    /// messages before a record that does not parse are kept.
    fn chunk(&mut self, body: &[u8]) -> Result<(), Damage> {
        // Parsed where it lies; an uncompressed chunk's records are read there too.
        let parsed = posestream_base::contain_panics(|| mcap::parse_record(op::CHUNK, body));
        let Ok(Ok(Record::Chunk { header, data })) = parsed else {
            return Err(Damage::Unparsable);
        };
        if header.uncompressed_size > self.limit {
            return Err(Damage::OverLimit);
        }
        let size = header.uncompressed_size as usize;
        let records: std::borrow::Cow<'_, [u8]> = match header.compression.as_str() {
            "" => data,
            "zstd" => zstd::bulk::decompress(&data, size)
                .map_err(|_| Damage::NotDecompressed)?
                .into(),
            "lz4" => {
                let mut out = Vec::with_capacity(size);
                lz4::Decoder::new(std::io::Cursor::new(&data[..]))
                    .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                    .map_err(|_| Damage::NotDecompressed)?;
                out.into()
            }
            _ => return Err(Damage::NotDecompressed),
        };
        if records.len() != size {
            return Err(Damage::NotDecompressed);
        }
        if header.uncompressed_crc != 0 && crc32fast::hash(&records) != header.uncompressed_crc {
            return Err(Damage::BadCrc);
        }
        let mut at = 0_usize;
        while at < records.len() {
            let head = records.get(at..at + 9).ok_or(Damage::Unparsable)?;
            let opcode = head[0];
            let len = u64::from_le_bytes(head[1..9].try_into().map_err(|_| Damage::Unparsable)?);
            let body = usize::try_from(len)
                .ok()
                .and_then(|l| records.get(at + 9..(at + 9).checked_add(l)?))
                .ok_or(Damage::Unparsable)?;
            if opcode < PRIVATE && !self.record(opcode, body)? {
                // Each message on no declared channel counted; the chunk's others kept.
                self.skips.note(Damage::UnknownChannel);
            }
            at += 9 + body.len();
        }
        Ok(())
    }

    /// Scans from `from + 1` for the next record that holds together (see the module
    /// docs), skipping what lies between as `kind`; to the end if none does.
    fn resync<R: Read + Seek>(&mut self, file: &mut R, from: u64, kind: Damage) {
        let mut block = vec![0_u8; SCAN_BLOCK];
        let mut base = from + 1;
        while base < self.len {
            if file.seek(SeekFrom::Start(base)).is_err() {
                break;
            }
            let n = match file.by_ref().take(SCAN_BLOCK as u64).read(&mut block) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            for i in 0..n {
                // What the block already shows rules out most positions without a read.
                let at = base + i as u64;
                let fits = block.get(i + 1..i + 9).is_none_or(|len| {
                    let len = u64::from_le_bytes(len.try_into().unwrap_or([0xff; 8]));
                    len <= self.limit && at.saturating_add(9).saturating_add(len) <= self.len
                });
                if known(block[i]) && fits && self.holds_together(file, at) {
                    self.skips.add(kind, from, at);
                    self.at = at;
                    return;
                }
            }
            base += n as u64;
        }
        // Nothing after it: a record running past the end is a file cut short there.
        let runs_past_end = Self::head(file, from).is_some_and(|(opcode, len)| {
            known(opcode) && from.saturating_add(9).saturating_add(len) > self.len
        });
        let kind = if kind == Damage::LyingLength && runs_past_end {
            Damage::CutShort
        } else {
            kind
        };
        self.skips.add(kind, from, self.len);
        self.done = true;
    }

    /// Whether a record that holds together starts at `at`: a chunk whose own sizes
    /// give its length, whose compression is one MCAP names and whose records fit the
    /// limit, followed by a record or the end; or another record followed by a record
    /// or the end. Only its head is read: a candidate that then fails is skipped whole,
    /// so the scan stays linear in the file.
    fn holds_together<R: Read + Seek>(&mut self, file: &mut R, at: u64) -> bool {
        let Some(end) = self.plausible(file, at) else {
            return false;
        };
        let Some((opcode, _)) = Self::head(file, at) else {
            return false;
        };
        if opcode == op::CHUNK {
            if self.chunk_end(file, at) != Some(end) {
                return false;
            }
            // Start and end times, uncompressed size, CRC, the compression's name.
            let mut fields = [0_u8; 8 + 8 + 8 + 4 + 4 + 4];
            if file.seek(SeekFrom::Start(at + 9)).is_err() || file.read_exact(&mut fields).is_err()
            {
                return false;
            }
            let uncompressed = u64::from_le_bytes(fields[16..24].try_into().unwrap_or([0xff; 8]));
            let name_len = u32::from_le_bytes(fields[28..32].try_into().unwrap_or([0xff; 4]));
            let name = &fields[32..32 + (name_len as usize).min(4)];
            let compression = match name_len {
                0 => true,
                3 => name[..3] == *b"lz4",
                4 => name == b"zstd",
                _ => false,
            };
            if !compression || uncompressed > self.limit {
                return false;
            }
        }
        self.boundary(file, end)
    }
}

#[cfg(test)]
mod tests;
