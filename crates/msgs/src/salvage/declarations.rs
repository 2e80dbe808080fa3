//! Schemas and channels declared outside the data being read: the summary's, and any
//! found by one scan of the file for a message whose channel is declared nowhere else.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};

use mcap::records::{Record, op};

use super::*;

impl Salvager {
    /// Reads the schemas and channels of the summary section, when the footer says where
    /// it is and its records hold together; anything else leaves them empty.
    pub(super) fn read_summary<R: Read + Seek>(&mut self, file: &mut R) {
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
        let start = u64::from_le_bytes(start);
        let mut at = start;
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
            if opcode == op::CHUNK_INDEX && self.indexed_chunks.len() < MAX_INDEXED_CHUNKS {
                // Message start and end times, then the chunk's offset.
                let mut fields = [0_u8; 24];
                if len >= 24
                    && file.seek(SeekFrom::Start(at + 9)).is_ok()
                    && file.read_exact(&mut fields).is_ok()
                {
                    let chunk = u64::from_le_bytes(fields[16..].try_into().unwrap_or_default());
                    if (MAGIC.len() as u64..start).contains(&chunk) {
                        self.indexed_chunks.push(chunk);
                    }
                }
            } else if (opcode == op::SCHEMA || opcode == op::CHANNEL)
                && self.read_record(file, at, len).is_some()
            {
                let body = std::mem::take(&mut self.body);
                let _ = self.record(file, opcode, &body);
                self.body = body;
            }
            at = end;
        }
        self.indexed_chunks.sort_unstable();
        self.indexed_chunks.dedup();
        self.summary = (
            std::mem::replace(&mut self.schemas, schemas),
            std::mem::replace(&mut self.channels, channels),
        );
    }

    /// Takes the summary's declaration of channel `id` (and its schema) where the data's
    /// was lost; true if there was one.
    pub(super) fn declared_in_summary(&mut self, id: u16) -> bool {
        let Some(channel) = self.summary.1.get(&id).cloned() else {
            return false;
        };
        if let Some(schema) = self.summary.0.get(&channel.schema_id).cloned() {
            self.schemas.entry(channel.schema_id).or_insert(schema);
        }
        self.channels.insert(id, channel);
        true
    }

    /// Takes a declaration of channel `id` (and its schema) found anywhere in the file,
    /// outside compressed chunks (a channel declared after its messages, or in a part of
    /// the file skipped, or in a summary the footer no longer leads to): scanned for once,
    /// when a message's channel is first declared nowhere else. True if there was one.
    pub(super) fn declared_elsewhere<R: Read + Seek>(&mut self, file: &mut R, id: u16) -> bool {
        if self.scanned.is_none() {
            let found = self.scan_declarations(file);
            self.scanned = Some(found);
        }
        let Some((schemas, channels)) = self.scanned.as_ref() else {
            return false;
        };
        let Some(channel) = channels.get(&id).cloned() else {
            return false;
        };
        if let Some(schema) = schemas.get(&channel.schema_id).cloned() {
            self.schemas.entry(channel.schema_id).or_insert(schema);
        }
        self.channels.insert(id, channel);
        true
    }

    /// Every schema and channel record in the file outside compressed chunks (at most
    /// [`MAX_SCANNED_DECLARATION`] bytes each, the limit's worth in all), the first
    /// declaration of an id kept: one pass over the file in overlapping windows, each
    /// candidate parsed where it lies.
    pub(super) fn scan_declarations<R: Read + Seek>(
        &mut self,
        file: &mut R,
    ) -> (BTreeMap<u16, SchemaInfo>, BTreeMap<u16, ChannelInfo>) {
        let (mut schemas, mut channels) = (BTreeMap::new(), BTreeMap::new());
        let mut kept = 0_u64;
        // Bytes handed to the parser, at most: a file of candidates that each parse far
        // before failing (a crafted one) costs a bounded multiple of one pass.
        let mut budget = self.len.saturating_mul(16).saturating_add(64 << 20);
        let mut window = vec![0_u8; SCAN_BLOCK + 9 + MAX_SCANNED_DECLARATION];
        let mut base = MAGIC.len() as u64;
        while base < self.len {
            if posestream_base::files::stop::requested() {
                break;
            }
            if file.seek(SeekFrom::Start(base)).is_err() {
                break;
            }
            let mut n = 0;
            while n < window.len() {
                match file.read(&mut window[n..]) {
                    Ok(0) | Err(_) => break,
                    Ok(got) => n += got,
                }
            }
            for i in 0..n.min(SCAN_BLOCK) {
                let opcode = window[i];
                if opcode != op::SCHEMA && opcode != op::CHANNEL {
                    continue;
                }
                let Some(len) = window.get(i + 1..i + 9) else {
                    break;
                };
                let len = u64::from_le_bytes(len.try_into().unwrap_or([0xff; 8]));
                let Some(body) = usize::try_from(len)
                    .ok()
                    .filter(|&l| (4..=MAX_SCANNED_DECLARATION).contains(&l))
                    .and_then(|l| window.get(i + 9..i + 9 + l))
                else {
                    continue;
                };
                let id = u16::from_le_bytes([body[0], body[1]]);
                let known = if opcode == op::SCHEMA {
                    schemas.contains_key(&id)
                } else {
                    channels.contains_key(&id)
                };
                if known || kept.saturating_add(len) > self.limit {
                    continue;
                }
                let Some(left) = budget.checked_sub(len) else {
                    return (schemas, channels);
                };
                budget = left;
                let parsed = posestream_base::contain_panics(|| mcap::parse_record(opcode, body));
                match parsed {
                    Ok(Ok(Record::Schema { header, data })) => {
                        kept += len;
                        schemas.insert(
                            header.id,
                            SchemaInfo {
                                name: header.name,
                                encoding: header.encoding,
                                data: data.into_owned(),
                            },
                        );
                    }
                    Ok(Ok(Record::Channel(c))) => {
                        kept += len;
                        channels.insert(c.id, ChannelInfo::from(c));
                    }
                    _ => {}
                }
            }
            base += SCAN_BLOCK as u64;
        }
        (schemas, channels)
    }
}
