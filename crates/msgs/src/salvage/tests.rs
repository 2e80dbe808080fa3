//! Unit tests of `salvage`.

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
        // Garbage over a chunk's head also makes the record before it (its message
        // index) end nowhere: the skip starts there, and is a lying length.
        assert!(
            skips.counts.contains_key(&kind)
                || (name == "flipped" && skips.counts.contains_key(&Damage::BadCrc))
                || (name == "garbage" && skips.counts.contains_key(&Damage::LyingLength)),
            "{name}: {skips:?}"
        );
        let r = skips.ranges[0];
        assert!(
            r.from <= c as u64 && r.from > chunks[1] as u64,
            "{name}: {r:?}"
        );
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

/// An unchunked recording written record by record: a header, a schema, a channel,
/// `messages` messages of 100 bytes (each its number), a data end, a footer. Returns
/// the bytes and each message record's offset.
fn unchunked(messages: u8) -> (Vec<u8>, Vec<usize>) {
    fn string(out: &mut Vec<u8>, s: &str) {
        out.extend((s.len() as u32).to_le_bytes());
        out.extend(s.as_bytes());
    }
    fn record(out: &mut Vec<u8>, opcode: u8, body: &[u8]) -> usize {
        let at = out.len();
        out.push(opcode);
        out.extend((body.len() as u64).to_le_bytes());
        out.extend(body);
        at
    }
    let mut out = MAGIC.to_vec();
    let mut b = Vec::new();
    string(&mut b, "ros2");
    string(&mut b, "test");
    record(&mut out, op::HEADER, &b);
    let mut b = 1_u16.to_le_bytes().to_vec();
    string(&mut b, "pkg/msg/T");
    string(&mut b, "ros2msg");
    b.extend(4_u32.to_le_bytes());
    b.extend(b"x y\n");
    record(&mut out, op::SCHEMA, &b);
    let mut b = 1_u16.to_le_bytes().to_vec();
    b.extend(1_u16.to_le_bytes());
    string(&mut b, "/t");
    string(&mut b, "cdr");
    b.extend(0_u32.to_le_bytes());
    record(&mut out, op::CHANNEL, &b);
    let mut at = Vec::new();
    for i in 0..messages {
        let mut b = 1_u16.to_le_bytes().to_vec();
        b.extend(u32::from(i).to_le_bytes());
        b.extend(u64::from(i).to_le_bytes());
        b.extend(u64::from(i).to_le_bytes());
        b.extend([i; 100]);
        at.push(record(&mut out, op::MESSAGE, &b));
    }
    record(&mut out, op::DATA_END, &0_u32.to_le_bytes());
    let mut b = 0_u64.to_le_bytes().to_vec();
    b.extend(0_u64.to_le_bytes());
    b.extend(0_u32.to_le_bytes());
    record(&mut out, op::FOOTER, &b);
    out.extend(MAGIC);
    (out, at)
}

/// The messages salvaged from `bytes`: each one's data, and the skips.
fn salvage_data(bytes: &[u8]) -> (Vec<Vec<u8>>, Skips) {
    let mut file = std::io::Cursor::new(bytes.to_vec());
    let mut s = Salvager::new(&mut file, 1 << 20).expect("new");
    let mut got = Vec::new();
    while let Some(m) = s.next_message(&mut file) {
        got.push(m.data);
    }
    (got, s.skips().clone())
}

#[test]
fn a_message_whose_length_lies_never_takes_the_next_record_s_bytes() {
    let (bytes, at) = unchunked(10);
    let (got, skips) = salvage_data(&bytes);
    assert_eq!(got.len(), 10);
    assert!(skips.is_empty(), "{skips:?}");
    for extra in [1_u64, 9, 500] {
        let mut b = bytes.clone();
        let len = u64::from_le_bytes(b[at[5] + 1..at[5] + 9].try_into().expect("8"));
        b[at[5] + 1..at[5] + 9].copy_from_slice(&(len + extra).to_le_bytes());
        let (got, skips) = salvage_data(&b);
        // Every message yielded is one that was written, whole.
        for data in &got {
            assert_eq!(data.len(), 100, "+{extra}: {skips:?}");
            assert!(data.iter().all(|&x| x == data[0]), "+{extra}");
        }
        let numbers: Vec<u8> = got.iter().map(|d| d[0]).collect();
        assert!(
            !numbers.contains(&5),
            "+{extra}: message 5 taken with other bytes"
        );
        assert!(
            numbers.contains(&4) && numbers.contains(&6),
            "+{extra}: {numbers:?}"
        );
        assert!(!skips.is_empty(), "+{extra}");
    }
}

#[test]
fn an_end_record_in_the_middle_of_the_data_is_damage_not_the_end() {
    let (bytes, at) = unchunked(10);
    for opcode in [op::DATA_END, op::FOOTER] {
        let mut b = bytes.clone();
        b[at[3]] = opcode;
        let (got, skips) = salvage_data(&b);
        let numbers: Vec<u8> = got.iter().map(|d| d[0]).collect();
        assert!(numbers.contains(&9), "{opcode}: {numbers:?}");
        assert!(!skips.is_empty(), "{opcode}: said");
    }
}

#[test]
fn a_file_cut_at_a_record_boundary_is_said_to_be_cut_short() {
    let (bytes, at) = unchunked(10);
    let (got, skips) = salvage_data(&bytes[..at[7]]);
    assert_eq!(got.len(), 7);
    assert_eq!(skips.counts.get(&Damage::CutShort), Some(&1), "{skips:?}");
}

#[test]
fn an_application_s_private_record_is_passed_over() {
    let (bytes, at) = unchunked(4);
    // A private record (opcode 0x80) between messages 1 and 2.
    let mut b = bytes[..at[2]].to_vec();
    b.push(0x80);
    b.extend(3_u64.to_le_bytes());
    b.extend([1, 2, 3]);
    b.extend(&bytes[at[2]..]);
    let (got, skips) = salvage_data(&b);
    assert_eq!(got.len(), 4);
    assert!(skips.is_empty(), "{skips:?}");
}

#[test]
fn chunk_heads_repeated_over_megabytes_are_scanned_past_in_one_pass() {
    // A file of `06` and a length of half the file, over and over (a review's case
    // that took the scan 72 s for 4 MB): each candidate is judged by its head.
    let n = 1_000_000_usize;
    let mut bytes = MAGIC.to_vec();
    bytes.push(0);
    while bytes.len() < n {
        bytes.push(op::CHUNK);
        bytes.extend(((n / 2) as u64).to_le_bytes());
    }
    bytes.extend(MAGIC);
    let (got, skips) = salvage(&bytes, 1 << 20);
    assert!(got.is_empty());
    assert!(!skips.is_empty());
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

#[test]
fn the_summary_says_bytes_only_where_bytes_were_skipped() {
    let mut skips = Skips::default();
    for _ in 0..121 {
        skips.note(Damage::UnknownChannel);
    }
    assert_eq!(skips.summary(), "121 skipped (121 unknown channel)");
    skips.add(Damage::BadCrc, 100, 300);
    assert_eq!(
        skips.summary(),
        "122 skipped (1 CRC mismatch, 121 unknown channel; 200 bytes): bytes 100-300"
    );
}
