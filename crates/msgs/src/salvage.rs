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
}

/// A record's opcode and length are those of some MCAP record.
fn known(op: u8) -> bool {
    (op::HEADER..=op::DATA_END).contains(&op)
}

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

    /// A declared schema.
    pub fn schema(&self, id: u16) -> Option<&SchemaInfo> {
        self.schemas.get(&id)
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
        (known(op) && len <= self.limit && end <= self.len).then_some(end)
    }

    /// A record starts at `at`, or the file (or its closing magic) ends there.
    fn boundary<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        at == self.len
            || self.len.checked_sub(at) == Some(MAGIC.len() as u64)
            || self.plausible(file, at).is_some()
    }

    /// Reads and handles the record at `self.at`, or skips.
    fn step<R: Read + Seek>(&mut self, file: &mut R) {
        let at = self.at;
        let Some((op, len)) = Self::head(file, at) else {
            if at < self.len {
                self.skips.add(Damage::CutShort, at, self.len);
            }
            self.done = true;
            return;
        };
        if op == op::FOOTER || op == op::DATA_END {
            // The data section is over: the summary is not read (see the module docs).
            self.done = true;
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
            self.skips.add(Damage::LyingLength, at, at);
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
            _ => self.record(opcode, &body).and_then(|declared| {
                if declared {
                    Ok(())
                } else {
                    Err(Damage::UnknownChannel)
                }
            }),
        };
        self.body = body;
        result
    }

    /// Handles one record outside a chunk or inside one; a message on an undeclared
    /// channel is counted (`Ok(false)`).
    fn record(&mut self, opcode: u8, body: &[u8]) -> Result<bool, Damage> {
        let record = posestream_math::error::contain_panics(|| {
            mcap::parse_record(opcode, body).map(Record::into_owned)
        });
        let Ok(Ok(record)) = record else {
            return Err(Damage::Unparsable);
        };
        match record {
            Record::Schema { header, data } => {
                self.schemas.insert(
                    header.id,
                    SchemaInfo {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
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
                self.pending.push_back(Salvaged {
                    channel: header.channel_id,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data: data.into_owned(),
                });
            }
            _ => {}
        }
        Ok(true)
    }

    /// A chunk: decompressed within the limit, its CRC checked, then its records; the
    /// messages before a record that does not parse are kept.
    fn chunk(&mut self, body: &[u8]) -> Result<(), Damage> {
        let parsed = posestream_math::error::contain_panics(|| {
            mcap::parse_record(op::CHUNK, body).map(Record::into_owned)
        });
        let Ok(Ok(Record::Chunk { header, data })) = parsed else {
            return Err(Damage::Unparsable);
        };
        if header.uncompressed_size > self.limit {
            return Err(Damage::OverLimit);
        }
        let size = header.uncompressed_size as usize;
        let records: Vec<u8> = match header.compression.as_str() {
            "" => data.into_owned(),
            "zstd" => zstd::bulk::decompress(&data, size).map_err(|_| Damage::NotDecompressed)?,
            "lz4" => {
                let mut out = Vec::with_capacity(size);
                lz4::Decoder::new(std::io::Cursor::new(&data[..]))
                    .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                    .map_err(|_| Damage::NotDecompressed)?;
                out
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
        let mut unknown = false;
        while at < records.len() {
            let head = records.get(at..at + 9).ok_or(Damage::Unparsable)?;
            let opcode = head[0];
            let len = u64::from_le_bytes(head[1..9].try_into().map_err(|_| Damage::Unparsable)?);
            let body = usize::try_from(len)
                .ok()
                .and_then(|l| records.get(at + 9..(at + 9).checked_add(l)?))
                .ok_or(Damage::Unparsable)?;
            unknown |= !self.record(opcode, body)?;
            at += 9 + body.len();
        }
        if unknown {
            return Err(Damage::UnknownChannel);
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

    /// Whether a record that holds together starts at `at`: a chunk that decompresses
    /// and passes its CRC (declared, or not decompressed here), or another record
    /// followed by a record or the end.
    fn holds_together<R: Read + Seek>(&mut self, file: &mut R, at: u64) -> bool {
        let Some(end) = self.plausible(file, at) else {
            return false;
        };
        let Some((opcode, len)) = Self::head(file, at) else {
            return false;
        };
        if opcode == op::CHUNK {
            if self.read_record(file, at, len).is_none() {
                return false;
            }
            // A trial: what it declares and holds is read again when reading goes on.
            let (schemas, channels, pending) = (
                self.schemas.clone(),
                self.channels.clone(),
                self.pending.len(),
            );
            let body = std::mem::take(&mut self.body);
            let ok = self.chunk(&body).is_ok();
            self.body = body;
            self.schemas = schemas;
            self.channels = channels;
            self.pending.truncate(pending);
            return ok;
        }
        self.boundary(file, end)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::{Recorder, RecordingReader};
    use crate::sensor::CompressedImage;

    /// Messages per chunk of [`recording`].
    const PER_CHUNK: u32 = 5;

    /// A recording of `chunks` chunks of [`PER_CHUNK`] images each (`data` of 1000 bytes,
    /// 3000 in the first chunk, holding the message's number), and its bytes.
    fn recording(dir: &std::path::Path, chunks: u32) -> (std::path::PathBuf, Vec<u8>) {
        let path = dir.join("r.mcap");
        let mut r = Recorder::create(&path).expect("create");
        r.set_flush_interval(None);
        for i in 0..chunks * PER_CHUNK {
            let m = CompressedImage {
                format: "jpeg".into(),
                // The first chunk's three times the others' (the limit's test).
                data: vec![i as u8; if i < PER_CHUNK { 3000 } else { 1000 }],
                ..CompressedImage::default()
            };
            r.write("/images", u64::from(i) * 1000, &m).expect("write");
            if (i + 1) % PER_CHUNK == 0 {
                r.flush().expect("flush");
            }
        }
        r.finish().expect("finish");
        let bytes = std::fs::read(&path).expect("read");
        (path, bytes)
    }

    /// Offsets of the top-level records of `bytes` with `opcode`.
    fn offsets(bytes: &[u8], opcode: u8) -> Vec<usize> {
        let mut out = Vec::new();
        let mut at = 8;
        while at + 9 <= bytes.len() {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().expect("8")) as usize;
            if bytes[at] == opcode {
                out.push(at);
            }
            if bytes[at] == op::FOOTER {
                break;
            }
            at += 9 + len;
        }
        out
    }

    /// The numbers of the messages salvaged from `bytes`, and the skips.
    fn salvage(bytes: &[u8], limit: usize) -> (Vec<u8>, Skips) {
        let mut file = std::io::Cursor::new(bytes.to_vec());
        let mut s = Salvager::new(&mut file, limit).expect("new");
        let mut got = Vec::new();
        while let Some(m) = s.next_message(&mut file) {
            // CDR: header, stamp, frame id, format, then the data's length and bytes.
            got.push(*m.data.last().expect("data"));
        }
        (got, s.skips().clone())
    }

    fn all_but(chunks: u32, lost: &[u32]) -> Vec<u8> {
        (0..chunks * PER_CHUNK)
            .filter(|i| !lost.contains(&(i / PER_CHUNK)))
            .map(|i| i as u8)
            .collect()
    }

    #[test]
    fn an_undamaged_recording_is_read_whole_with_nothing_skipped() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (_, bytes) = recording(dir.path(), 6);
        let (got, skips) = salvage(&bytes, 1 << 20);
        assert_eq!(got, all_but(6, &[]));
        assert!(skips.is_empty(), "{skips:?}");
    }

    #[test]
    fn each_kind_of_damage_costs_only_its_part() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (path, bytes) = recording(dir.path(), 6);
        let chunks = offsets(&bytes, op::CHUNK);
        assert_eq!(chunks.len(), 6);
        let patch = |at: usize, with: &[u8]| {
            let mut b = bytes.clone();
            b[at..at + with.len()].copy_from_slice(with);
            b
        };
        let c = chunks[2];
        // The CRC: after the opcode and length, start, end and uncompressed size.
        let crc = patch(c + 9 + 24, &[0xde, 0xad]);
        let flipped = patch((c + chunks[3]) / 2, &[bytes[(c + chunks[3]) / 2] ^ 0x10]);
        let tib = patch(c + 1, &(1_u64 << 40).to_le_bytes());
        let max = patch(c + 1, &u64::MAX.to_le_bytes());
        let garbage = patch(c, &[0xee; 16]);
        let longer = {
            let len = u64::from_le_bytes(bytes[c + 1..c + 9].try_into().expect("8"));
            patch(c + 1, &(len + 100).to_le_bytes())
        };
        let shorter = {
            let len = u64::from_le_bytes(bytes[c + 1..c + 9].try_into().expect("8"));
            patch(c + 1, &(len - 100).to_le_bytes())
        };
        // A chunk's length that lies is corrected from the chunk's own sizes: nothing lost.
        for (name, damaged) in [
            ("1 TiB", tib),
            ("u64::MAX", max),
            ("longer", longer),
            ("shorter", shorter),
        ] {
            let (got, skips) = salvage(&damaged, 1 << 20);
            assert_eq!(got, all_but(6, &[]), "{name}: {skips:?}");
            assert_eq!(skips.counts.get(&Damage::LyingLength), Some(&1), "{name}");
            assert_eq!(skips.total(), 1, "{name}: {skips:?}");
        }
        // Lengths that lie where nothing says better: scanned past.
        let both = {
            let mut b = bytes.clone();
            b[c + 1..c + 9].copy_from_slice(&u64::MAX.to_le_bytes());
            // The compressed size too.
            let name = u32::from_le_bytes(b[c + 37..c + 41].try_into().expect("4")) as usize;
            let sizes = c + 41 + name;
            b[sizes..sizes + 8].copy_from_slice(&(1_u64 << 40).to_le_bytes());
            b
        };
        for (name, damaged, kind) in [
            ("crc", crc, Damage::BadCrc),
            ("flipped", flipped, Damage::NotDecompressed),
            ("garbage", garbage, Damage::Unparsable),
            ("both lengths", both, Damage::LyingLength),
        ] {
            let (got, skips) = salvage(&damaged, 1 << 20);
            assert_eq!(got, all_but(6, &[2]), "{name}: {skips:?}");
            assert_eq!(skips.total(), 1, "{name}: {skips:?}");
            assert!(
                skips.counts.contains_key(&kind)
                    || (name == "flipped" && skips.counts.contains_key(&Damage::BadCrc)),
                "{name}: {skips:?}"
            );
            let r = skips.ranges[0];
            assert_eq!(r.from, c as u64, "{name}");
            assert!(
                r.to >= chunks[3] as u64 - 100 && r.to <= chunks[3] as u64,
                "{name}: {r:?}"
            );
        }
        // Cut short inside the fourth chunk: the three before.
        let cut = &bytes[..chunks[3] + 50];
        let (got, skips) = salvage(cut, 1 << 20);
        assert_eq!(got, all_but(3, &[]));
        assert_eq!(skips.counts.get(&Damage::CutShort), Some(&1), "{skips:?}");
        // A chunk over the limit (here, its records decompressed) is not read: the others
        // are.
        let (got, skips) = salvage(&bytes, 10_000);
        assert_eq!(got, all_but(6, &[0]), "{skips:?}");
        assert_eq!(skips.counts.get(&Damage::OverLimit), Some(&1), "{skips:?}");
        // The reader's salvaging mode gives the same, and never fails.
        std::fs::write(&path, crc_of(&bytes, c)).expect("write");
        let mut reader = RecordingReader::open(&path)
            .expect("opens")
            .salvaging()
            .expect("salvaging");
        let read: Vec<_> = reader.by_ref().collect();
        assert!(read.iter().all(Result::is_ok));
        assert_eq!(read.len(), 25);
        assert_eq!(reader.skips().map(Skips::total), Some(1));
    }

    fn crc_of(bytes: &[u8], chunk: usize) -> Vec<u8> {
        let mut b = bytes.to_vec();
        b[chunk + 9 + 24] ^= 0xff;
        b
    }

    #[test]
    fn random_bytes_after_the_magic_are_skipped_without_reading_beyond_the_limit() {
        let mut bytes = MAGIC.to_vec();
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            bytes.push(x as u8);
        }
        let (got, skips) = salvage(&bytes, 1 << 20);
        assert!(got.is_empty());
        assert!(!skips.is_empty());
        assert_eq!(skips.bytes, bytes.len() as u64 - 8, "{skips:?}");
    }

    #[test]
    fn a_summary_names_kinds_counts_and_ranges() {
        let mut s = Skips::default();
        assert!(s.is_empty());
        s.add(Damage::BadCrc, 10, 20);
        s.add(Damage::BadCrc, 30, 45);
        s.add(Damage::OverLimit, 100, 1_000);
        assert_eq!(s.total(), 3);
        assert_eq!(s.bytes, 10 + 15 + 900);
        let text = s.summary();
        assert!(
            text.contains("2 CRC mismatch") && text.contains("1 over the limit"),
            "{text}"
        );
        assert!(text.contains("10-20, 30-45, 100-1000"), "{text}");
        for i in 0..100 {
            s.add(Damage::CutShort, 2000 + i, 2001 + i);
        }
        assert_eq!(s.ranges.len(), MAX_RANGES);
        assert_eq!(s.total(), 103);
    }
}
