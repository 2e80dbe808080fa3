//! What a strict reader checks besides the skips: the data section's CRC, the summary's
//! CRC and the closing magic.

use std::io::{Read, Seek, SeekFrom};

use mcap::records::op;

use super::*;

impl Salvager {
    /// Also computes the data section's CRC (from the magic to the data-end record) as
    /// records are read, for [`Salvager::data_crc_mismatch`]: what a strict reader checks
    /// that a skip does not already say. Call before the first message.
    pub fn checking_data_crc(&mut self) {
        let mut hasher = crc32fast::Hasher::new();
        hasher.update(MAGIC);
        self.data_crc = Some((hasher, None));
    }

    /// At the end of a file read without a skip: the data-end record's CRC and the one
    /// computed, where they differ (a CRC of 0: none recorded).
    pub fn data_crc_mismatch(&self) -> Option<(u32, u32)> {
        let (hasher, Some(recorded)) = self.data_crc.as_ref()? else {
            return None;
        };
        let computed = hasher.clone().finalize();
        (*recorded != 0 && *recorded != computed).then_some((*recorded, computed))
    }

    /// What is wrong after the data section (the summary is not read for messages): the
    /// footer's summary CRC, and the closing magic. `None` when all holds (or the file
    /// has no footer: reading then ended in a skip).
    pub fn end_mismatch<R: Read + Seek>(&self, file: &mut R) -> Option<String> {
        let footer = self.len.checked_sub(FOOTER_BYTES + MAGIC.len() as u64)?;
        let Some((op::FOOTER, 20)) = Self::head(file, footer) else {
            return None;
        };
        let mut body = [0_u8; 20];
        let mut magic = [0_u8; 8];
        if file.read_exact(&mut body).is_err() || file.read_exact(&mut magic).is_err() {
            return Some("the footer cannot be read".into());
        }
        if magic != *MAGIC {
            return Some("the file does not end with the MCAP magic".into());
        }
        let start = u64::from_le_bytes(body[..8].try_into().unwrap_or_default());
        let recorded = u32::from_le_bytes(body[16..20].try_into().unwrap_or_default());
        // The summary starts right after the data section's end record (0: none).
        if let Some(data_end) = self.data_end {
            let after = data_end + 9 + 4;
            let expected = if after == footer { 0 } else { after };
            if start != expected {
                return Some(if expected == 0 {
                    format!("the footer places a summary at byte {start}, and there is none")
                } else {
                    format!(
                        "the footer places the summary at byte {start}, where it starts at \
                         byte {expected}"
                    )
                });
            }
        }
        if start == 0 || recorded == 0 {
            return None;
        }
        if start < MAGIC.len() as u64 || start > footer {
            return Some(format!("the footer places the summary at byte {start}"));
        }
        // The summary's records, then the footer's opcode, length and offsets.
        let mut hasher = crc32fast::Hasher::new();
        if Self::hash_range(file, start, footer + 9 + 16, &mut hasher).is_none() {
            return Some("the summary cannot be read".into());
        }
        let computed = hasher.finalize();
        (computed != recorded).then(|| {
            format!("the summary's CRC does not match (recorded {recorded:#010x}, computed {computed:#010x})")
        })
    }

    /// Feeds bytes `from..to` of `file` to `hasher`, a block at a time.
    pub(super) fn hash_range<R: Read + Seek>(
        file: &mut R,
        from: u64,
        to: u64,
        hasher: &mut crc32fast::Hasher,
    ) -> Option<()> {
        file.seek(SeekFrom::Start(from)).ok()?;
        let mut block = [0_u8; 4096];
        let mut left = to.checked_sub(from)?;
        while left > 0 {
            let n = (left as usize).min(block.len());
            file.read_exact(&mut block[..n]).ok()?;
            hasher.update(&block[..n]);
            left -= n as u64;
        }
        Some(())
    }

    /// Counts the record at `at`, read whole (its body in `self.body`, or passed over
    /// unread: `unread`), into the data section's CRC, if one is computed.
    pub(super) fn hash_record<R: Read + Seek>(
        &mut self,
        file: &mut R,
        at: u64,
        opcode: u8,
        len: u64,
        unread: bool,
    ) {
        let Some((hasher, _)) = self.data_crc.as_mut() else {
            return;
        };
        hasher.update(&[opcode]);
        hasher.update(&len.to_le_bytes());
        if unread {
            if Self::hash_range(file, at + 9, at + 9 + len, hasher).is_none() {
                // Unreadable now: the CRC cannot match (said at the end).
                hasher.update(&[0xff]);
            }
        } else {
            hasher.update(&self.body);
        }
    }
}
