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
//! - a message on a channel never declared;
//! - a chunk that repeats, byte for byte, one read before (the first
//!   [`MAX_SEEN_CHUNKS`] chunks are remembered);
//! - a schema or channel declared again as another (the first declaration stands);
//! - a message that repeats one read before: channel, sequence number, times and payload
//!   (the first [`MAX_SEEN_MESSAGES`] messages are remembered).
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
    /// A chunk that repeats one read before, byte for byte (a copy's blocks written
    /// twice): its messages were already given out once.
    Duplicate,
    /// A schema or channel declared again as another (its id is the first's: the first
    /// declaration stands).
    Conflict,
    /// A message that repeats one read before: its channel, sequence number, times and
    /// payload (a chunk copied with other bytes around the same messages).
    Repeated,
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
            Damage::Duplicate => "duplicate chunk",
            Damage::Conflict => "conflicting declaration",
            Damage::Repeated => "repeated message",
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
        let mut text = format!("{} skipped ({}", self.total(), kinds.join(", "));
        // Messages on undeclared channels are counted without bytes of their own.
        if self.bytes > 0 {
            let unit = if self.bytes == 1 { "byte" } else { "bytes" };
            text.push_str(&format!("; {} {unit}", self.bytes));
        }
        text.push(')');
        if !self.ranges.is_empty() {
            let mut ranges: Vec<String> = self
                .ranges
                .iter()
                .take(8)
                .map(|r| format!("{}-{}", r.from, r.to))
                .collect();
            if self.ranges.len() > ranges.len() {
                ranges.push("...".into());
            }
            text.push_str(": bytes ");
            text.push_str(&ranges.join(", "));
        }
        text
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

impl From<mcap::records::Channel> for ChannelInfo {
    fn from(c: mcap::records::Channel) -> Self {
        Self {
            topic: c.topic,
            schema_id: c.schema_id,
            message_encoding: c.message_encoding,
            metadata: c.metadata,
        }
    }
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
    /// The data section's CRC so far, over every record read whole
    /// ([`Salvager::checking_data_crc`]), and the data-end record's, once read.
    data_crc: Option<(crc32fast::Hasher, Option<u32>)>,
    /// Where the summary's chunk indexes place chunks (sorted, at most
    /// [`MAX_INDEXED_CHUNKS`]): a record there that is not a chunk took one's place.
    indexed_chunks: Vec<u64>,
    /// Declarations found anywhere in the file by [`Salvager::scan_declarations`], once a
    /// message's channel was declared nowhere else.
    scanned: Option<(BTreeMap<u16, SchemaInfo>, BTreeMap<u16, ChannelInfo>)>,
    /// Bytes of chunk records decompressed so far from chunks of more than [`INFLATION`]
    /// times their size (at most [`INFLATION_ALLOWANCE`]).
    inflated: u64,
    /// Reading ends at the first skip ([`Salvager::stopping_at_damage`]).
    stop_at_damage: bool,
    /// The file's length, where bytes follow its closing magic (they are skipped at the
    /// end, the file read as if it ended at the magic: `len`).
    trailing: Option<u64>,
    /// Where the data section's end record is, once read.
    data_end: Option<u64>,
    /// A hash of each chunk read that held messages (its times, sizes, compression and
    /// both CRCs), for [`Damage::Duplicate`]: at most [`MAX_SEEN_CHUNKS`].
    seen_chunks: std::collections::HashSet<u64>,
    /// A hash of each message given out (channel, sequence, times, payload's CRC), for
    /// [`Damage::Repeated`]: at most [`MAX_SEEN_MESSAGES`].
    seen_messages: std::collections::HashSet<u64>,
}

/// Messages remembered to find repeats, at most (about 16 MiB of hashes).
pub const MAX_SEEN_MESSAGES: usize = 1 << 20;

/// Chunks remembered to find repeats, at most (about 16 MiB of hashes; a recording of
/// 1 MiB chunks has that many in a terabyte).
pub const MAX_SEEN_CHUNKS: usize = 1 << 20;

/// Bytes of chunk records per byte of a chunk beyond which the chunk counts against
/// [`INFLATION_ALLOWANCE`] (recordings compress 10 to 100 times; a compression bomb, a
/// 2 kB chunk of 64 MiB of zeros, 32,000).
const INFLATION: u64 = 1000;

/// Bytes of chunk records decompressed from chunks of more than [`INFLATION`] times
/// their size, in all, at most (1 GiB): beyond, such chunks are skipped as over the
/// limit, and the chunks of real recordings around them still read.
const INFLATION_ALLOWANCE: u64 = 1 << 30;

/// The longest schema or channel record [`Salvager::scan_declarations`] takes.
const MAX_SCANNED_DECLARATION: usize = 64 << 10;

/// Chunk offsets taken from a summary's chunk indexes, at most (8 MiB of them).
const MAX_INDEXED_CHUNKS: usize = 1 << 20;

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
            data_crc: None,
            indexed_chunks: Vec::new(),
            scanned: None,
            inflated: 0,
            stop_at_damage: false,
            trailing: None,
            data_end: None,
            seen_chunks: std::collections::HashSet::new(),
            seen_messages: std::collections::HashSet::new(),
        };
        salvager.find_end(file);
        salvager.read_summary(file);
        Ok(salvager)
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
            if self.stop_at_damage && !self.skips.is_empty() {
                // What a damaged record held is not given out.
                self.pending.clear();
                self.done = true;
            }
            if let Some(m) = self.pending.pop_front() {
                return Some(m);
            }
            if self.done {
                return None;
            }
            self.step(file);
        }
    }

    /// Ends reading at the first skip (a strict reader: nothing past damage is read).
    pub fn stopping_at_damage(&mut self) {
        self.stop_at_damage = true;
    }

    /// Reads on past damage after all (undoes [`Salvager::stopping_at_damage`] and
    /// [`Salvager::checking_data_crc`]). Call before the first message.
    pub fn reading_on(&mut self) {
        self.stop_at_damage = false;
        self.data_crc = None;
    }

    /// Hands back a message's payload once used: the next messages are copied over it
    /// (kept up to a few; a warm reader allocates no payload).
    pub fn recycle(&mut self, payload: Vec<u8>) {
        if self.spare.len() < SPARE_PAYLOADS && payload.capacity() > 0 {
            self.spare.push(payload);
        }
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
            if op == op::DATA_END {
                self.data_end = Some(at);
            }
            if let Some(real) = self.trailing {
                self.skips.add(Damage::Unparsable, self.len, real);
            }
            if op == op::DATA_END
                && let Some((_, recorded)) = self.data_crc.as_mut()
            {
                let mut crc = [0_u8; 4];
                let read =
                    file.seek(SeekFrom::Start(at + 9)).is_ok() && file.read_exact(&mut crc).is_ok();
                *recorded = read.then(|| u32::from_le_bytes(crc));
            }
            self.done = true;
            return;
        }
        if op == op::DATA_END
            && let Some(cut) = self.summary_cut_short(file, at)
        {
            // The data section is over and the summary after it cut short.
            self.skips.add(Damage::CutShort, cut, self.len);
            self.done = true;
            return;
        }
        if op == op::FOOTER || op == op::DATA_END {
            // Where the data goes on: not the end.
            self.resync(file, at, Damage::Unparsable);
            return;
        }
        if op != op::CHUNK && self.indexed_chunks.binary_search(&at).is_ok() {
            // The index has a chunk here and this record reads whole as one: a chunk whose
            // opcode was damaged, and its messages are lost. (A record that does not read
            // as a chunk is read as what it is: a summary cannot make the data lie.)
            match at.checked_add(9).and_then(|a| a.checked_add(len)) {
                Some(end)
                    if end <= self.len
                        && len <= self.limit
                        && self.chunk_shaped(file, at, end)
                        && self.boundary(file, end) =>
                {
                    self.skips.add(Damage::Unparsable, at, end);
                    self.at = end;
                    return;
                }
                _ => {}
            }
        }
        if self.not_data(file, at, op, len) {
            // A record that has no place in the data section, or does not hold together
            // as its kind: another one damaged into it (a flipped opcode).
            match at.checked_add(9).and_then(|a| a.checked_add(len)) {
                Some(end) if end <= self.len && self.boundary(file, end) => {
                    self.skips.add(Damage::Unparsable, at, end);
                    self.at = end;
                }
                _ => self.resync(file, at, Damage::Unparsable),
            }
            return;
        }
        if op >= PRIVATE {
            // A record of an application's own (MCAP's private opcodes): passed over
            // where its length leads to a record, else as any opcode unknown.
            match at.checked_add(9).and_then(|a| a.checked_add(len)) {
                Some(end) if end <= self.len && self.boundary(file, end) => {
                    self.hash_record(file, at, op, len, true);
                    self.at = end;
                }
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
        match self
            .read_record(file, at, len)
            .map(|()| self.handle(file, op))
        {
            Some(Ok(())) => {
                self.hash_record(file, at, op, len, false);
                self.at = end;
            }
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
    fn handle<R: Read + Seek>(&mut self, file: &mut R, opcode: u8) -> Result<(), Damage> {
        let body = std::mem::take(&mut self.body);
        let result = match opcode {
            op::CHUNK => self.chunk(file, &body),
            _ => self.record(file, opcode, &body).map(|declared| {
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
    fn record<R: Read + Seek>(
        &mut self,
        file: &mut R,
        opcode: u8,
        body: &[u8],
    ) -> Result<bool, Damage> {
        // Parsed where it lies (nothing copied but what is kept).
        let record = posestream_base::contain_panics(|| mcap::parse_record(opcode, body));
        let Ok(Ok(record)) = record else {
            return Err(Damage::Unparsable);
        };
        match record {
            Record::Schema { header, data } => {
                if let Some(first) = self.schemas.get(&header.id) {
                    let same = first.name == header.name
                        && first.encoding == header.encoding
                        && (first.data.is_empty() || *first.data == *data);
                    if !same {
                        self.skips.note(Damage::Conflict);
                    }
                    return Ok(true);
                }
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
                let id = c.id;
                let channel = ChannelInfo::from(c);
                match self.channels.get(&id) {
                    Some(first) if *first != channel => self.skips.note(Damage::Conflict),
                    Some(_) => {}
                    None => {
                        self.channels.insert(id, channel);
                    }
                }
            }
            Record::Message { header, data } => {
                if !self.channels.contains_key(&header.channel_id)
                    && !self.declared_in_summary(header.channel_id)
                    && !self.declared_elsewhere(file, header.channel_id)
                {
                    return Ok(false);
                }
                if self.repeated(&header, &data) {
                    // Given out once already (a copy of its chunk in other bytes).
                    self.skips.note(Damage::Repeated);
                    return Ok(true);
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

    /// Whether the message of `header` with payload `data` was given out before (the
    /// first [`MAX_SEEN_MESSAGES`] are remembered).
    fn repeated(&mut self, header: &mcap::records::MessageHeader, data: &[u8]) -> bool {
        use std::hash::{Hash, Hasher};
        let mut h = std::hash::DefaultHasher::new();
        (
            header.channel_id,
            header.sequence,
            header.log_time,
            header.publish_time,
            data.len(),
            crc32fast::hash(data),
        )
            .hash(&mut h);
        let key = h.finish();
        if self.seen_messages.contains(&key) {
            return true;
        }
        if self.seen_messages.len() < MAX_SEEN_MESSAGES {
            self.seen_messages.insert(key);
        }
        false
    }

    /// A chunk: decompressed within the limit, its CRC checked, then its records; the
    /// messages before a record that does not parse are kept.
    fn chunk<R: Read + Seek>(&mut self, file: &mut R, body: &[u8]) -> Result<(), Damage> {
        // Parsed where it lies; an uncompressed chunk's records are read there too.
        let parsed = posestream_base::contain_panics(|| mcap::parse_record(op::CHUNK, body));
        let Ok(Ok(Record::Chunk { header, data })) = parsed else {
            return Err(Damage::Unparsable);
        };
        if header.uncompressed_size > self.limit {
            return Err(Damage::OverLimit);
        }
        // A chunk that decompresses to more than INFLATION times its size is decompressed
        // only within the allowance (such chunks in all): a bomb's chunks beyond it are
        // skipped, and reading costs at most the allowance and INFLATION times the file.
        let extreme = header.uncompressed_size > (data.len() as u64).saturating_mul(INFLATION);
        if !header.compression.is_empty() && extreme {
            self.inflated = self.inflated.saturating_add(header.uncompressed_size);
            if self.inflated > INFLATION_ALLOWANCE {
                return Err(Damage::OverLimit);
            }
        }
        let size = header.uncompressed_size as usize;
        let key = {
            use std::hash::{Hash, Hasher};
            // One key for every chunk of this reading (DefaultHasher::new's are alike).
            let mut h = std::hash::DefaultHasher::new();
            (
                header.message_start_time,
                header.message_end_time,
                header.uncompressed_size,
                header.uncompressed_crc,
                header.compression.as_str(),
                crc32fast::hash(&data),
                data.len(),
            )
                .hash(&mut h);
            h.finish()
        };
        if self.seen_chunks.contains(&key) {
            // A chunk whose messages were given out before, byte for byte.
            return Err(Damage::Duplicate);
        }
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
        let queued = self.pending.len();
        let mut at = 0_usize;
        while at < records.len() {
            let head = records.get(at..at + 9).ok_or(Damage::Unparsable)?;
            let opcode = head[0];
            let len = u64::from_le_bytes(head[1..9].try_into().map_err(|_| Damage::Unparsable)?);
            let body = usize::try_from(len)
                .ok()
                .and_then(|l| records.get(at + 9..(at + 9).checked_add(l)?))
                .ok_or(Damage::Unparsable)?;
            // A chunk holds schemas, channels and messages (and an application's records).
            if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) && opcode < PRIVATE {
                return Err(Damage::Unparsable);
            }
            if opcode < PRIVATE && !self.record(file, opcode, body)? {
                // Each message on no declared channel counted; the chunk's others kept.
                self.skips.note(Damage::UnknownChannel);
            }
            at += 9 + body.len();
        }
        // Remembered where it gave messages (a chunk of declarations only may repeat).
        if self.pending.len() > queued && self.seen_chunks.len() < MAX_SEEN_CHUNKS {
            self.seen_chunks.insert(key);
        }
        Ok(())
    }
}

mod checks;
mod declarations;
mod shape;

#[cfg(test)]
mod tests;
