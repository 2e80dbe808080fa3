//! Where records start and end: the heads, lengths and shapes that say whether a record
//! holds together where it is, and the scan for the next one that does.

use std::io::{Read, Seek, SeekFrom};

use mcap::records::op;

use super::*;

impl Salvager {
    /// Where bytes follow the file's closing magic (a footer and the magic, then more):
    /// the file is read as ending at the magic, and the rest skipped at the end. Looks
    /// at the last 64 kB only.
    pub(super) fn find_end<R: Read + Seek>(&mut self, file: &mut R) {
        let mut last = [0_u8; 8];
        let ends_in_magic = self.len >= 16
            && file.seek(SeekFrom::Start(self.len - 8)).is_ok()
            && file.read_exact(&mut last).is_ok()
            && last == *MAGIC;
        if ends_in_magic {
            return;
        }
        let from = self
            .len
            .saturating_sub(SCAN_BLOCK as u64)
            .max(MAGIC.len() as u64);
        let mut tail = Vec::new();
        if file.seek(SeekFrom::Start(from)).is_err()
            || file
                .by_ref()
                .take(SCAN_BLOCK as u64)
                .read_to_end(&mut tail)
                .is_err()
        {
            return;
        }
        let footer_head = [op::FOOTER, 20, 0, 0, 0, 0, 0, 0, 0];
        let closing = (0..tail
            .len()
            .saturating_sub(FOOTER_BYTES as usize + MAGIC.len()))
            .rev()
            .find(|&i| {
                tail[i..i + 9] == footer_head
                    && tail[i + FOOTER_BYTES as usize..i + FOOTER_BYTES as usize + 8] == *MAGIC
            });
        if let Some(i) = closing {
            self.trailing = Some(self.len);
            self.len = from + (i as u64) + FOOTER_BYTES + MAGIC.len() as u64;
        }
    }

    /// The opcode and length of the record at `at`, if 9 bytes are there.
    pub(super) fn head<R: Read + Seek>(file: &mut R, at: u64) -> Option<(u8, u64)> {
        let mut h = [0_u8; 9];
        file.seek(SeekFrom::Start(at)).ok()?;
        file.read_exact(&mut h).ok()?;
        let len = u64::from_le_bytes(h[1..9].try_into().ok()?);
        Some((h[0], len))
    }

    /// Where the record at `at` ends, if it is a known record that fits the file and
    /// the limit.
    pub(super) fn plausible<R: Read + Seek>(&self, file: &mut R, at: u64) -> Option<u64> {
        let (op, len) = Self::head(file, at)?;
        let end = at.checked_add(9)?.checked_add(len)?;
        // An application's private record counts as a record here (never as a place the
        // scan resumes: that takes a known opcode).
        ((known(op) || op >= PRIVATE) && len <= self.limit && end <= self.len).then_some(end)
    }

    /// A record starts at `at`, or the file (or its closing magic) ends there.
    pub(super) fn boundary<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
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
        self.ends(at) || record || self.cut_at(file, at) || self.oversized_at(file, at) || {
            // A chunk whose own length field lies is still a record there when its own
            // sizes lead to the next one.
            matches!(Self::head(file, at), Some((op::CHUNK, _)))
                && self.chunk_end(file, at).is_some_and(|own| {
                    own - at - 9 <= self.limit
                        && (self.ends(own) || self.plausible(file, own).is_some())
                })
        }
    }

    /// A record over the limit starts at `at` (a known opcode whose length fits the file
    /// and leads to another record or the end): skipped when it comes, it does not make
    /// the record before it a liar.
    pub(super) fn oversized_at<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        let Some((opcode, len)) = Self::head(file, at) else {
            return false;
        };
        let end = at.checked_add(9).and_then(|a| a.checked_add(len));
        known(opcode)
            && len > self.limit
            && end.is_some_and(|end| {
                end <= self.len && (self.ends(end) || self.plausible(file, end).is_some())
            })
    }

    /// A record starts at `at` that the end of the file cuts short: a known opcode and a
    /// length within the limit that runs past the end, or a chunk never finished.
    pub(super) fn cut_at<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        Self::head(file, at).is_some_and(|(opcode, len)| {
            // The MCAP writer puts a chunk down with a length of all ones until it is
            // finished: a recorder killed there left it so.
            (opcode == op::CHUNK && len == u64::MAX)
                || known(opcode) && len <= self.limit && at.saturating_add(9 + len) > self.len
        })
    }

    /// The file ends at `at`: its closing magic starts there, or fewer bytes follow than
    /// any record's head (a stray byte or a few: skipped as a tail cut short, and the
    /// record before them kept).
    pub(super) fn ends(&self, at: u64) -> bool {
        self.len.checked_sub(at).is_some_and(|left| left < 9)
    }

    /// Whether the record at `at` (opcode `opcode`, length `len`) cannot be what the data
    /// section holds there: a header anywhere but at the start, a record only a summary
    /// has (chunk, attachment and metadata indexes, statistics, summary offsets), a message index whose entries do not fill
    /// it exactly, or an application's record that reads whole as a chunk (a chunk's
    /// opcode damaged).
    pub(super) fn not_data<R: Read + Seek>(
        &self,
        file: &mut R,
        at: u64,
        opcode: u8,
        len: u64,
    ) -> bool {
        match opcode {
            // A header only at the start (a second one: a file's copy after the first).
            op::HEADER => at != MAGIC.len() as u64,
            op::CHUNK_INDEX
            | op::ATTACHMENT_INDEX
            | op::STATISTICS
            | op::METADATA_INDEX
            | op::SUMMARY_OFFSET => true,
            op::MESSAGE_INDEX => {
                // Channel id, then the entries' byte length, then 16 bytes an entry.
                let mut fields = [0_u8; 6];
                let read = file.seek(SeekFrom::Start(at + 9)).is_ok()
                    && file.read_exact(&mut fields).is_ok();
                let entries = u64::from(u32::from_le_bytes([
                    fields[2], fields[3], fields[4], fields[5],
                ]));
                !read || len < 6 || entries != len - 6 || entries % 16 != 0
            }
            PRIVATE.. => at
                .checked_add(9)
                .and_then(|a| a.checked_add(len))
                .is_some_and(|end| self.chunk_shaped(file, at, end)),
            _ => false,
        }
    }

    /// Whether the record at `at`, ending at `end`, reads as a chunk whatever its opcode:
    /// its own sizes lead to `end`, its compression is one MCAP names and its records fit
    /// the limit.
    pub(super) fn chunk_shaped<R: Read + Seek>(&self, file: &mut R, at: u64, end: u64) -> bool {
        if self.chunk_end(file, at) != Some(end) {
            return false;
        }
        // Start and end times, uncompressed size, CRC, the compression's name.
        let mut fields = [0_u8; 8 + 8 + 8 + 4 + 4 + 4];
        if file.seek(SeekFrom::Start(at + 9)).is_err() || file.read_exact(&mut fields).is_err() {
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
        compression && uncompressed <= self.limit
    }

    /// Where the chunk at `at` ends by its own sizes (its compression's name and its
    /// compressed size), if those fit the file.
    pub(super) fn chunk_end<R: Read + Seek>(&self, file: &mut R, at: u64) -> Option<u64> {
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

    /// Where the file is cut short, when a data-end record at `at` is followed only by
    /// records of a summary (declarations, indexes, statistics, a footer) up to a record
    /// the end cuts short, or up to the end: a recorder killed while it wrote its summary.
    pub(super) fn summary_cut_short<R: Read + Seek>(&self, file: &mut R, at: u64) -> Option<u64> {
        let Some((op::DATA_END, 4)) = Self::head(file, at) else {
            return None;
        };
        let mut next = at + 9 + 4;
        if next > self.len {
            // Cut inside the data-end record itself.
            return Some(at);
        }
        loop {
            if self.ends(next) || self.cut_at(file, next) {
                return Some(next);
            }
            let (opcode, _) = Self::head(file, next)?;
            let summary = summary_record(opcode) || opcode == op::FOOTER;
            next = self.plausible(file, next).filter(|_| summary)?;
        }
    }

    /// Whether a footer at `at` is the file's: just before the closing magic.
    pub(super) fn footer_at(&self, at: u64) -> bool {
        self.len.checked_sub(FOOTER_BYTES + MAGIC.len() as u64) == Some(at)
    }

    /// Whether a data-end record at `at` ends the data section: the file's footer
    /// follows it, or records only a summary holds that lead to the footer. The footer's
    /// word on where the summary starts is not taken (data hidden between a summary and
    /// the footer, or a second copy of a file after the first, is read; a footer that
    /// misplaces the summary is said by [`Salvager::end_mismatch`]).
    pub(super) fn data_end_at<R: Read + Seek>(&self, file: &mut R, at: u64) -> bool {
        let Some(footer) = self.len.checked_sub(FOOTER_BYTES + MAGIC.len() as u64) else {
            return false;
        };
        let Some((op::DATA_END, 4)) = Self::head(file, at) else {
            return false;
        };
        if !matches!(Self::head(file, footer), Some((op::FOOTER, 20))) {
            return false;
        }
        let mut record = at + 9 + 4;
        while record < footer {
            let Some((opcode, _)) = Self::head(file, record) else {
                return false;
            };
            match self.plausible(file, record) {
                Some(end) if summary_record(opcode) && end <= footer => record = end,
                _ => return false,
            }
        }
        record == footer
    }

    /// Scans from `from + 1` for the next record that holds together (see the module
    /// docs), skipping what lies between as `kind`; to the end if none does. A stop
    /// ([`posestream_base::files::stop`]) ends the scan and the reading.
    pub(super) fn resync<R: Read + Seek>(&mut self, file: &mut R, from: u64, kind: Damage) {
        let mut block = vec![0_u8; SCAN_BLOCK];
        let mut base = from + 1;
        while base < self.len {
            if posestream_base::files::stop::requested() {
                // A signal: reading ends here, nothing more is claimed of the file.
                self.done = true;
                return;
            }
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
    pub(super) fn holds_together<R: Read + Seek>(&mut self, file: &mut R, at: u64) -> bool {
        let Some(end) = self.plausible(file, at) else {
            return false;
        };
        let Some((opcode, _)) = Self::head(file, at) else {
            return false;
        };
        if opcode == op::CHUNK && !self.chunk_shaped(file, at, end) {
            return false;
        }
        self.boundary(file, end)
    }
}

/// A record a summary section holds (declarations, indexes, statistics, offsets).
fn summary_record(opcode: u8) -> bool {
    matches!(
        opcode,
        op::SCHEMA
            | op::CHANNEL
            | op::CHUNK_INDEX
            | op::ATTACHMENT_INDEX
            | op::STATISTICS
            | op::METADATA_INDEX
            | op::SUMMARY_OFFSET
    )
}
