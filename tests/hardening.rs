//! Hostile inputs: each defect of the hardening issue, reproduced against the library and
//! the release binary. Files give one clear error (exit 1); bad frames in a stream are
//! refused and counted while the stream goes on; nothing panics, aborts or allocates
//! without bound, and nothing already recorded is lost.

mod common;

use posestream::LoadDictionary;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::{peak_memory_run, python_client, recording, root};
use posestream::msgs::{self, HeatMaps, Skeleton3D};
use posestream::nodes::{EstimatorNode, ServiceConfig};
use posestream::recording::{Recorder, RecordingError, RecordingReader, read_topic};

const HEATMAPS: &str = "/posestream/heatmaps";
const SKELETONS: &str = "/posestream/skeletons";
/// Peak resident memory any hostile input may cost the process (kB).
const MEMORY_BUDGET_KB: u64 = 200 * 1024;

fn config() -> ServiceConfig {
    let mut c = ServiceConfig::load(root().join("config/default.toml")).expect("config");
    c.outputs.ros2 = false;
    c
}

fn frames(name: &str) -> Vec<(u64, HeatMaps)> {
    read_topic(&recording(name), HEATMAPS).expect("reads")
}

/// The binary under test: this build's, or `POSESTREAM_BIN` (to run these cases against
/// another build, e.g. the one before a fix).
fn binary() -> PathBuf {
    std::env::var_os("POSESTREAM_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_posestream")))
}

fn posestream() -> Command {
    let mut c = Command::new(binary());
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

/// What a run of the binary did.
struct Run {
    code: Option<i32>,
    stdout: String,
    stderr: String,
    peak_kb: u64,
}

impl Run {
    fn report(&self) -> serde_json::Value {
        serde_json::from_str(&self.stdout)
            .unwrap_or_else(|e| panic!("report: {e}\n{}\n{}", self.stdout, self.stderr))
    }

    /// Exit status 1 with exactly one line on stderr, an error containing `needle`.
    fn assert_one_error(&self, needle: &str) {
        assert_eq!(self.code, Some(1), "{}", self.stderr);
        let lines: Vec<&str> = self.stderr.lines().collect();
        assert_eq!(lines.len(), 1, "{}", self.stderr);
        assert!(
            lines[0].starts_with("posestream: error: ") && lines[0].contains(needle),
            "expected an error about {needle:?}: {}",
            self.stderr
        );
        self.assert_bounded();
    }

    fn assert_bounded(&self) {
        assert!(!self.stderr.contains("panicked"), "{}", self.stderr);
        assert!(
            self.peak_kb < MEMORY_BUDGET_KB,
            "peak memory {} MB",
            self.peak_kb / 1024
        );
    }
}

/// Runs the binary; every run, whatever its input, must end without a panic or an abort
/// and stay within the memory budget.
fn run(args: &[&str]) -> Run {
    let (code, out, peak_kb) = peak_memory_run(&binary(), args, &[]);
    let run = Run {
        code,
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        peak_kb,
    };
    assert!(
        matches!(run.code, Some(0 | 1)),
        "exit status {:?}: {}",
        run.code,
        run.stderr
    );
    run.assert_bounded();
    run
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A recording of `messages` (raw CDR) on the heat-map topic, a chunk every `per_chunk`.
fn write_raw(path: &Path, messages: &[(u64, Vec<u8>)], per_chunk: usize) {
    let mut rec = Recorder::create(path).expect("create");
    rec.set_flush_interval(None);
    for (i, (t, bytes)) in messages.iter().enumerate() {
        rec.write_encoded::<HeatMaps>(HEATMAPS, *t, bytes)
            .expect("write");
        if (i + 1) % per_chunk == 0 {
            rec.flush().expect("flush");
        }
    }
    rec.finish().expect("finish");
}

fn encoded(frames: &[(u64, HeatMaps)]) -> Vec<(u64, Vec<u8>)> {
    frames
        .iter()
        .map(|(t, m)| (*t, msgs::encode(m).expect("encodes")))
        .collect()
}

/// byebye.mcap with `bad` in place of frame `at`.
fn with_frame(at: usize, bad: Vec<u8>) -> Vec<(u64, Vec<u8>)> {
    let mut all = encoded(&frames("byebye.mcap"));
    all[at].1 = bad;
    all
}

fn replay_json(input: &Path) -> Run {
    run(&["replay", "--json", s(input)])
}

// Defect 1: 17 x h x w wraps around to the number of values sent.

fn overflowing_frame() -> HeatMaps {
    let mut m = frames("byebye.mcap").remove(40).1;
    m.height = 3_537_046_315;
    m.width = 4_294_949_781;
    // 17 * h * w = 96631 (mod 2^64): as many values as the wrapped product.
    m.encoding = 0;
    m.values = vec![0.5; 96_631];
    m.quantized_values.clear();
    m
}

#[test]
fn a_map_size_that_overflows_is_refused_and_the_stream_goes_on() {
    let mut node = EstimatorNode::from_config(&config().estimator).expect("node");
    let mut out = Vec::new();
    let all = frames("byebye.mcap");
    for (i, (_, m)) in all.iter().enumerate() {
        if i == 40 {
            assert!(node.handle(&overflowing_frame(), &mut out).is_err());
        } else {
            node.handle(m, &mut out).expect("good frame");
        }
    }
    node.finish(&mut out);
    assert_eq!(node.malformed(), 1);
    assert_eq!(out.len(), 2 * (all.len() - 1));

    // Through the binary, in the middle of a track and as the first frame of one.
    let dir = tempfile::tempdir().expect("tempdir");
    for at in [40, 0] {
        let input = dir.path().join(format!("overflow-{at}.mcap"));
        write_raw(
            &input,
            &with_frame(at, msgs::encode(&overflowing_frame()).expect("encodes")),
            1000,
        );
        let r = replay_json(&input);
        assert_eq!(r.code, Some(0), "{}", r.stderr);
        r.assert_bounded();
        let report = r.report();
        assert_eq!(report["malformed"], 1);
        assert_eq!(report["skeletons"], 2 * 120);
    }
}

// Defect 3: memory grows with the claimed map size.

fn huge_frame(side: u32) -> HeatMaps {
    let mut m = frames("byebye.mcap").remove(0).1;
    m.height = side;
    m.width = side;
    m.encoding = 1;
    m.quantization_scale = 1.0 / 255.0;
    m.quantized_values = vec![0; 17 * side as usize * side as usize];
    m.values.clear();
    m
}

#[test]
fn frames_beyond_the_limits_are_refused_within_the_memory_budget() {
    let dir = tempfile::tempdir().expect("tempdir");
    let recording_with = |side: u32| {
        let input = dir.path().join(format!("huge-{side}.mcap"));
        let mut all = encoded(&frames("byebye.mcap")[..30]);
        all[10].1 = msgs::encode(&huge_frame(side)).expect("encodes");
        write_raw(&input, &all, 1000);
        input
    };
    // 17 x 1024 x 1024 (a 17 MiB message): read, refused as a frame, the stream goes on.
    let r = replay_json(&recording_with(1024));
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    r.assert_bounded();
    let report = r.report();
    assert_eq!(report["malformed"], 1, "{report}");
    assert_eq!(report["refused"]["beyond-limits"], 1, "{report}");
    assert_eq!(report["skeletons"], 2 * 29);
    assert!(
        r.stderr.contains("beyond the limit"),
        "the refusal says why: {}",
        r.stderr
    );
    // 17 x 2048 x 2048 (a 68 MiB message): its chunk is beyond `limits.max_record_bytes`,
    // so it is skipped, nothing of that size allocated, and the frames after it (their
    // own chunk) replayed, with a warning; strict, reading ends there with one error.
    let huge = recording_with(2048);
    let r = run(&["replay", "--json", s(&huge)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let report = r.report();
    assert_eq!(report["frames"], 19, "{report}");
    assert_eq!(report["skipped"]["counts"]["over-limit"], 1, "{report}");
    assert!(
        r.stderr.contains("damaged parts skipped") && r.stderr.contains("1 over the limit"),
        "{}",
        r.stderr
    );
    let r = run(&["replay", "--strict", s(&huge)]);
    r.assert_one_error("limits.max_record_bytes");
    // `recover` copies the frames after it, and the copy reads whole.
    let copy = dir.path().join("huge-recovered.mcap");
    let r = run(&["recover", s(&huge), s(&copy), "--json"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(r.report()["skipped"]["counts"]["over-limit"], 1);
    let kept: Vec<(u64, HeatMaps)> = read_topic(&copy, HEATMAPS).expect("clean");
    assert_eq!(kept.len(), 19);
    let indexed = python_client("read_indexed.py", &[s(&copy)]);
    assert_eq!(indexed["topics"][HEATMAPS], 19, "{indexed}");
    // The limits are configuration: 64 x 64 maps are refused under a 32 limit.
    let mut node_config = config();
    node_config.limits.max_map_size = 32;
    let mut node = EstimatorNode::from_service_config(&node_config).expect("node");
    let err = node
        .handle(&frames("byebye.mcap")[0].1, &mut Vec::new())
        .expect_err("64 x 64 maps beyond a 32 limit");
    assert!(err.to_string().contains("beyond the limit"), "{err}");
}

// Defect 4: record lengths are trusted.

/// The offsets of the records of an MCAP file: (offset of the opcode, opcode).
fn records(bytes: &[u8]) -> Vec<(usize, u8)> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().expect("8 bytes"));
        out.push((at, op));
        if op == 0x02 {
            break; // footer
        }
        at += 9 + len as usize;
    }
    out
}

const CHUNK: u8 = 0x06;

/// Heat-map messages per chunk of [`chunked`] (10 of 70 kB: under the recorder's 1 MiB
/// chunk size, so every chunk holds exactly this many).
const PER_CHUNK: usize = 10;

/// byebye.mcap's heat maps in chunks of [`PER_CHUNK`] messages (13 chunks).
fn chunked(dir: &Path) -> (PathBuf, Vec<u8>) {
    let path = dir.join("chunked.mcap");
    write_raw(&path, &encoded(&frames("byebye.mcap")), PER_CHUNK);
    let bytes = std::fs::read(&path).expect("read");
    (path, bytes)
}

/// The frames estimated at once (lag 0), not counting the owed estimates of a track's end.
fn newest_estimates(skeletons: &[(u64, Skeleton3D)]) -> usize {
    skeletons
        .iter()
        .filter(|(_, s)| s.lag == 0 && s.state != msgs::SkeletonState::Lost as u8)
        .count()
}

/// The `.partial` file a failed run left beside `output`, if any.
fn partial_of(output: &Path) -> Option<PathBuf> {
    let name = output.file_name()?.to_str()?.to_string();
    std::fs::read_dir(output.parent()?)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(&format!("{name}.")) && n.ends_with(".partial"))
        })
}

fn patched(dir: &Path, name: &str, bytes: &[u8], at: usize, with: &[u8]) -> PathBuf {
    let mut b = bytes.to_vec();
    b[at..at + with.len()].copy_from_slice(with);
    let path = dir.join(name);
    std::fs::write(&path, b).expect("write");
    path
}

#[test]
fn hostile_record_lengths_end_reading_with_one_error_and_keep_what_came_before() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, bytes) = chunked(dir.path());
    let recs = records(&bytes);
    assert_eq!(recs[0].1, 0x01, "a header first");
    let chunks: Vec<usize> = recs
        .iter()
        .filter(|(_, op)| *op == CHUNK)
        .map(|(at, _)| *at)
        .collect();
    assert!(chunks.len() >= 6, "{} chunks", chunks.len());
    let tib = (1_u64 << 40).to_le_bytes();
    let cases = [
        ("header-1tib.mcap", recs[0].0 + 1, tib.to_vec(), 0),
        (
            "header-max.mcap",
            recs[0].0 + 1,
            u64::MAX.to_le_bytes().to_vec(),
            0,
        ),
        (
            "chunk5-1tib.mcap",
            chunks[4] + 1,
            tib.to_vec(),
            4 * PER_CHUNK,
        ),
        (
            "chunk5-max.mcap",
            chunks[4] + 1,
            u64::MAX.to_le_bytes().to_vec(),
            4 * PER_CHUNK,
        ),
    ];
    for (name, at, with, frames_before) in cases {
        let input = patched(dir.path(), name, &bytes, at, &with);
        let out = dir.path().join(format!("{name}.out.mcap"));
        let r = run(&["replay", "--strict", s(&input), "--record", s(&out)]);
        r.assert_one_error(name);
        // The output is not written (the run failed); everything before the bad record
        // was replayed and its skeletons kept in the output's `.partial` file, which the
        // error names.
        assert!(!out.exists(), "{name}");
        match partial_of(&out) {
            Some(kept) => {
                assert!(r.stderr.contains(s(&kept)), "{}", r.stderr);
                let kept: Vec<(u64, Skeleton3D)> = read_topic(&kept, SKELETONS).expect("complete");
                let newest = newest_estimates(&kept);
                assert_eq!(newest, frames_before, "{name}");
            }
            None => assert_eq!(frames_before, 0, "{name}: nothing kept"),
        }
    }
    // The magic, then random bytes.
    let mut random = b"\x89MCAP0\r\n".to_vec();
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for _ in 0..4096 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        random.push(x as u8);
    }
    let input = dir.path().join("random.mcap");
    std::fs::write(&input, random).expect("write");
    run(&["replay", s(&input)]).assert_one_error("random.mcap");
}

// Defect 5: chunk CRCs.

#[test]
fn a_corrupt_chunk_is_reported_and_never_used() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, bytes) = chunked(dir.path());
    let third = records(&bytes)
        .into_iter()
        .filter(|(_, op)| *op == CHUNK)
        .nth(2)
        .expect("a third chunk")
        .0;
    // Chunk body: start, end, uncompressed size (u64 each), uncompressed CRC (u32), ...
    let crc_at = third + 9 + 24;
    let wrong_crc = patched(dir.path(), "wrong-crc.mcap", &bytes, crc_at, &[0xde, 0xad]);
    // A byte in the middle of the chunk's compressed records.
    let next = records(&bytes)
        .into_iter()
        .filter(|(_, op)| *op == CHUNK)
        .nth(3)
        .expect("a fourth chunk")
        .0;
    let middle = (third + next) / 2;
    let flipped = patched(
        dir.path(),
        "flipped.mcap",
        &bytes,
        middle,
        &[bytes[middle] ^ 0x10],
    );
    for input in [wrong_crc, flipped] {
        let name = input.file_name().and_then(|n| n.to_str()).expect("name");
        let out = dir.path().join(format!("{name}.out.mcap"));
        let r = run(&["replay", "--strict", s(&input), "--record", s(&out)]);
        r.assert_one_error(name);
        assert!(!out.exists());
        let kept = partial_of(&out).expect("the skeletons before are kept");
        let kept: Vec<(u64, Skeleton3D)> = read_topic(&kept, SKELETONS).expect("complete");
        let newest = newest_estimates(&kept);
        assert_eq!(
            newest,
            2 * PER_CHUNK,
            "only the two chunks before the corrupt one"
        );
        // The library says which kind of failure it was.
        let mut reader = RecordingReader::open(&input).expect("opens");
        let err = reader.by_ref().find_map(|m| m.err()).expect("an error");
        assert!(
            matches!(err, RecordingError::Corrupt { messages: 20, .. }),
            "{err:?}"
        );
    }
}

// Strict reading: it fails wherever reading on past damage warns, under the same limits.

/// Every message of `path` read on past damage, and what was skipped.
fn read_on(path: &Path) -> (u64, msgs::salvage::Skips) {
    let mut reader = RecordingReader::open(path)
        .and_then(RecordingReader::salvaging)
        .expect("opens");
    let mut read = 0;
    for m in reader.by_ref() {
        m.expect("never fails");
        read += 1;
    }
    (read, reader.skips().cloned().expect("salvaging"))
}

/// What a strict reader of `path` read before it ended, and how it ended.
fn read_strictly(path: &Path) -> (u64, Option<RecordingError>) {
    let mut reader = RecordingReader::open(path).expect("opens");
    let mut read = 0;
    for m in reader.by_ref() {
        match m {
            Ok(_) => read += 1,
            Err(e) => return (read, Some(e)),
        }
    }
    (read, None)
}

#[test]
fn strict_reading_fails_wherever_reading_on_past_damage_warns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (clean, bytes) = chunked(dir.path());
    let (all, skips) = read_on(&clean);
    assert!(skips.is_empty(), "{skips:?}");
    let (strict, ended) = read_strictly(&clean);
    assert_eq!(strict, all);
    assert!(ended.is_none(), "{ended:?}");
    let chunks: Vec<usize> = records(&bytes)
        .into_iter()
        .filter(|(_, op)| *op == CHUNK)
        .map(|(at, _)| at)
        .collect();
    let c = chunks[3];
    let footer = bytes[bytes.len() - 37..bytes.len() - 8].to_vec();
    let inserted = |what: &[u8]| [&bytes[..c], what, &bytes[c..]].concat();
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    // The fourth chunk's opcode flipped: to a message index, an application's private
    // record, a summary offset (records that hold no messages: the index has a chunk
    // there), and to no opcode at all.
    for op in [0x07_u8, 0x86, 0x0e, 0x16] {
        cases.push((format!("opcode-{op:02x}"), patch(&bytes, c, &[op])));
    }
    cases.push(("footer-mid-file".into(), inserted(&footer)));
    cases.push(("inserted-byte".into(), inserted(&[0])));
    // A chunk claiming 2^62 bytes of records, and a compression bomb's 8 GiB: beyond the
    // limit, never decompressed.
    for (name, size) in [("claims-2^62", 1_u64 << 62), ("claims-8gib", 8 << 30)] {
        cases.push((name.into(), patch(&bytes, c + 9 + 16, &size.to_le_bytes())));
    }
    for (name, damaged) in cases {
        let path = dir.path().join(format!("{name}.mcap"));
        std::fs::write(&path, &damaged).expect("write");
        let (read, skips) = read_on(&path);
        assert!(!skips.is_empty(), "{name}: reading on warns");
        assert!(read >= all - PER_CHUNK as u64, "{name}: {read} of {all}");
        let (strict, ended) = read_strictly(&path);
        let Some(RecordingError::Corrupt {
            messages, reason, ..
        }) = ended
        else {
            panic!("{name}: strict reading ends in an error: {ended:?}");
        };
        assert_eq!(messages, strict, "{name}");
        // Nothing of the damaged chunk: the three chunks before it and the other topics.
        assert!(strict < all - PER_CHUNK as u64, "{name}: {strict}");
        assert!(reason.contains(" at bytes "), "{name}: {reason}");
    }
    // A stray byte after the end: every message, and the end said as cut short.
    let path = dir.path().join("stray-byte.mcap");
    std::fs::write(&path, [&bytes[..], &[0]].concat()).expect("write");
    assert_eq!(read_on(&path).0, all);
    let (strict, ended) = read_strictly(&path);
    assert_eq!(strict, all);
    assert!(
        matches!(
            ended,
            Some(RecordingError::Corrupt { .. } | RecordingError::Truncated { .. })
        ),
        "{ended:?}"
    );
    // The command: exit 1, one error naming the damage and its bytes.
    let path = dir.path().join("opcode-86.mcap");
    let r = run(&["replay", "--strict", s(&path)]);
    r.assert_one_error("corrupt recording");
    assert!(r.stderr.contains("at bytes"), "{}", r.stderr);
}

#[test]
fn damage_a_summary_cannot_reveal_and_bombs_are_said_too() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, bytes) = chunked(dir.path());
    let recs = records(&bytes);
    // The recording without its summary (a footer that points at none): a chunk whose
    // opcode became a message index, a summary offset or an application's record is
    // found out by its own shape.
    let data_end = recs.iter().find(|(_, op)| *op == 0x0f).expect("data end").0;
    let footer = raw_record(0x02, &[0_u8; 20]);
    let bare = [&bytes[..data_end + 13], &footer, b"\x89MCAP0\r\n"].concat();
    let path = dir.path().join("bare.mcap");
    std::fs::write(&path, &bare).expect("write");
    let (all, skips) = read_on(&path);
    assert!(skips.is_empty(), "{skips:?}");
    let c = recs
        .iter()
        .filter(|(_, op)| *op == CHUNK)
        .nth(3)
        .expect("chunk")
        .0;
    for op in [0x07_u8, 0x0e, 0x86] {
        let path = dir.path().join(format!("bare-{op:02x}.mcap"));
        std::fs::write(&path, patch(&bare, c, &[op])).expect("write");
        let (read, skips) = read_on(&path);
        assert_eq!(read, all - PER_CHUNK as u64, "{op:#x}");
        assert_eq!(
            skips.counts.get(&msgs::salvage::Damage::Unparsable),
            Some(&1)
        );
        assert!(
            matches!(read_strictly(&path).1, Some(RecordingError::Corrupt { .. })),
            "{op:#x}"
        );
    }
    // Bytes after the closing magic: skipped and said (strictly, an error).
    let path = dir.path().join("trailing.mcap");
    std::fs::write(&path, [&bytes[..], &[0; 5]].concat()).expect("write");
    let (read, skips) = read_on(&path);
    assert_eq!(read, all);
    assert_eq!(skips.bytes, 5, "{skips:?}");
    // Cut inside the data-end record: cut short, every message read.
    let path = dir.path().join("cut-data-end.mcap");
    std::fs::write(&path, &bytes[..data_end + 11]).expect("write");
    let (strict, ended) = read_strictly(&path);
    assert_eq!(strict, all);
    assert!(
        matches!(ended, Some(RecordingError::Truncated { .. })),
        "{ended:?}"
    );
    // A compression bomb: chunks of 2 kB that each decompress to 64 MiB (of records
    // that are none of MCAP's). Such chunks (over 1000 times their size) are decompressed
    // up to 1 GiB in all, the rest skipped as over the limit; the real chunks after them
    // are read.
    let zeros = vec![0_u8; (64 << 20) / 9 * 9];
    let packed = zstd::bulk::compress(&zeros, 19).expect("compresses");
    let crc = crc32fast::hash(&zeros);
    let bomb_chunk = raw_record(
        CHUNK,
        &[
            &0_u64.to_le_bytes()[..],
            &0_u64.to_le_bytes(),
            &(zeros.len() as u64).to_le_bytes(),
            &crc.to_le_bytes(),
            &raw_bytes(b"zstd"),
            &(packed.len() as u64).to_le_bytes(),
            &packed,
        ]
        .concat(),
    );
    let header_end = recs[1].0;
    let bomb: Vec<u8> = [
        &bytes[..header_end],
        &bomb_chunk.repeat(40),
        &bytes[header_end..],
    ]
    .concat();
    let path = dir.path().join("bomb.mcap");
    std::fs::write(&path, &bomb).expect("write");
    let (read, skips) = read_on(&path);
    assert_eq!(read, all);
    let over = skips
        .counts
        .get(&msgs::salvage::Damage::OverLimit)
        .copied()
        .unwrap_or(0);
    let inflated = (40 - over) * zeros.len() as u64;
    assert!(inflated <= 1 << 30 && over >= 20, "{skips:?}");
    // Strictly, the first bomb chunk ends reading.
    assert!(matches!(
        read_strictly(&path),
        (0, Some(RecordingError::Corrupt { .. }))
    ));
}

#[test]
fn a_record_over_the_limit_costs_only_itself_not_the_one_before() {
    // An unchunked recording with a 2 MiB attachment (over a 1 MiB limit) after its
    // 100th message.
    let dir = tempfile::tempdir().expect("tempdir");
    let all = frames("byebye.mcap");
    let attachment = raw_record(
        0x09,
        &[
            &0_u64.to_le_bytes()[..],
            &0_u64.to_le_bytes(),
            &raw_bytes(b"big.bin"),
            &raw_bytes(b"application/octet-stream"),
            &(2_u64 << 20).to_le_bytes(),
            &vec![7; 2 << 20],
            &0_u32.to_le_bytes(),
        ]
        .concat(),
    );
    let mut bytes = [&b"\x89MCAP0\r\n"[..], &heat_map_declarations().concat()].concat();
    for (i, (t, m)) in all.iter().enumerate() {
        bytes.extend(raw_message(i, *t, m));
        if i == 100 {
            bytes.extend(&attachment);
        }
    }
    let path = dir.path().join("attachment.mcap");
    std::fs::write(&path, &bytes).expect("write");
    let mut reader = RecordingReader::open_with_limit(&path, 1 << 20)
        .and_then(RecordingReader::salvaging)
        .expect("opens");
    let read = reader.by_ref().filter(|m| m.is_ok()).count();
    assert_eq!(read, all.len());
    let skips = reader.skips().expect("salvaging");
    assert_eq!(
        skips.counts.get(&msgs::salvage::Damage::OverLimit),
        Some(&1),
        "{skips:?}"
    );
    assert!(
        !skips
            .counts
            .contains_key(&msgs::salvage::Damage::LyingLength),
        "{skips:?}"
    );
}

/// A header, a schema and a channel (id 1) for heat maps on [`HEATMAPS`], as records.
fn heat_map_declarations() -> [Vec<u8>; 3] {
    let header = raw_record(0x01, &[raw_bytes(b"ros2"), raw_bytes(b"test")].concat());
    let schema = raw_record(
        0x03,
        &[
            &1_u16.to_le_bytes()[..],
            &raw_bytes(<HeatMaps as msgs::RosMessage>::NAME.as_bytes()),
            &raw_bytes(b"ros2msg"),
            &raw_bytes(<HeatMaps as msgs::RosMessage>::DEFINITION.as_bytes()),
        ]
        .concat(),
    );
    let channel = raw_record(
        0x04,
        &[
            &1_u16.to_le_bytes()[..],
            &1_u16.to_le_bytes(),
            &raw_bytes(HEATMAPS.as_bytes()),
            &raw_bytes(b"cdr"),
            &0_u32.to_le_bytes(),
        ]
        .concat(),
    );
    [header, schema, channel]
}

/// A message record of frame `i` (log and publish time `t`) on channel 1.
fn raw_message(i: usize, t: u64, m: &HeatMaps) -> Vec<u8> {
    raw_record(
        0x05,
        &[
            &1_u16.to_le_bytes()[..],
            &(i as u32).to_le_bytes(),
            &t.to_le_bytes(),
            &t.to_le_bytes(),
            &msgs::encode(m).expect("encodes"),
        ]
        .concat(),
    )
}

/// An MCAP record: opcode, length, body.
fn raw_record(op: u8, body: &[u8]) -> Vec<u8> {
    [&[op][..], &(body.len() as u64).to_le_bytes(), body].concat()
}

/// An MCAP string or byte array: its length (u32), then its bytes.
fn raw_bytes(b: &[u8]) -> Vec<u8> {
    [&(b.len() as u32).to_le_bytes()[..], b].concat()
}

#[test]
fn a_channel_declared_anywhere_is_found_before_its_messages_are_given_up() {
    // A recording without a summary (a recorder cut off): its heat-map channel declared
    // after its messages, ending in one stray byte; then with an application's record
    // beyond the limit right after the declarations.
    let dir = tempfile::tempdir().expect("tempdir");
    let all = frames("byebye.mcap");
    let [header, schema, channel] = heat_map_declarations();
    let messages: Vec<u8> = all
        .iter()
        .enumerate()
        .flat_map(|(i, (t, m))| raw_message(i, *t, m))
        .collect();
    let magic = b"\x89MCAP0\r\n".to_vec();
    let declared_last = [&magic[..], &header, &schema, &messages, &channel, &[0]].concat();
    let private = raw_record(0x80, &vec![7; 2 << 20]);
    let private_first = [&magic[..], &header, &schema, &channel, &private, &messages].concat();
    for (name, bytes) in [("declared-last", declared_last), ("private", private_first)] {
        let path = dir.path().join(format!("{name}.mcap"));
        std::fs::write(&path, bytes).expect("write");
        let mut reader = RecordingReader::open_with_limit(&path, 1 << 20)
            .and_then(RecordingReader::salvaging)
            .expect("opens");
        let read = reader
            .by_ref()
            .map(|m| m.expect("never fails"))
            .filter(|m| m.topic == HEATMAPS)
            .count();
        assert_eq!(read, all.len(), "{name}: {:?}", reader.skips());
        let skips = reader.skips().expect("salvaging");
        assert!(
            !skips
                .counts
                .contains_key(&msgs::salvage::Damage::UnknownChannel),
            "{name}: {skips:?}"
        );
    }
    // And the command replays every frame of the first, saying the stray byte.
    let path = dir.path().join("declared-last.mcap");
    let r = run(&["replay", "--json", s(&path)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(r.report()["frames"], all.len(), "{}", r.stdout);
    assert!(r.stderr.contains("1 cut short; 1 byte)"), "{}", r.stderr);
}

// Issue 41: a damaged part of a recording costs only that part.

/// `replay --json` of `input` (reading on past damage): its report, checked to be a
/// success with one warning line naming what was skipped.
fn salvaged(input: &Path, out: &Path) -> serde_json::Value {
    let r = run(&["replay", "--json", s(input), "--record", s(out)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let warnings: Vec<&str> = r.stderr.lines().collect();
    assert_eq!(warnings.len(), 1, "{}", r.stderr);
    assert!(
        warnings[0].starts_with("posestream: warning: ")
            && warnings[0].contains("damaged parts skipped")
            && warnings[0].contains(" skipped ("),
        "{}",
        r.stderr
    );
    r.report()
}

#[test]
fn each_kind_of_damage_costs_only_its_part_and_the_good_frames_around_it_are_replayed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, bytes) = chunked(dir.path());
    let recs = records(&bytes);
    let chunks: Vec<usize> = recs
        .iter()
        .filter(|(_, op)| *op == CHUNK)
        .map(|(at, _)| *at)
        .collect();
    let all = frames("byebye.mcap").len();
    let tib = (1_u64 << 40).to_le_bytes();
    let third = chunks[2];
    let middle = (chunks[2] + chunks[3]) / 2;
    // (name, bytes, frames replayed, kind of skip)
    let cases: Vec<(&str, Vec<u8>, usize, &str)> = vec![
        // A header whose length lies: scanned past, every chunk read.
        (
            "header-1tib",
            patch(&bytes, recs[0].0 + 1, &tib),
            all,
            "lying-length",
        ),
        (
            "header-max",
            patch(&bytes, recs[0].0 + 1, &u64::MAX.to_le_bytes()),
            all,
            "lying-length",
        ),
        // A chunk's lengths that lie: corrected from the chunk's own sizes.
        (
            "chunk5-1tib",
            patch(&bytes, chunks[4] + 1, &tib),
            all,
            "lying-length",
        ),
        (
            "chunk5-max",
            patch(&bytes, chunks[4] + 1, &u64::MAX.to_le_bytes()),
            all,
            "lying-length",
        ),
        // A chunk whose CRC fails, one with a byte flipped (zstd keeps no checksum of its
        // own here, so the CRC finds it, unless the flip breaks the zstd frame itself,
        // which depends on where the byte falls): that chunk's 10 frames.
        (
            "wrong-crc",
            patch(&bytes, third + 9 + 24, &[0xde, 0xad]),
            all - PER_CHUNK,
            "bad-crc",
        ),
        (
            "flipped",
            patch(&bytes, middle, &[bytes[middle] ^ 0x10]),
            all - PER_CHUNK,
            "bad-crc|not-decompressed",
        ),
        // A chunk whose zstd frame is broken: it does not decompress.
        (
            "bad-zstd",
            patch(&bytes, third + 53, &[0, 0, 0, 0]),
            all - PER_CHUNK,
            "not-decompressed",
        ),
        // Garbage over a chunk's start: scanned past (the record before it, whose length
        // now leads nowhere, is where the skip starts: a lying length).
        (
            "garbage",
            patch(&bytes, third, &[0xee; 64]),
            all - PER_CHUNK,
            "lying-length",
        ),
        // A file cut short in its fourth chunk: the three before.
        (
            "cut",
            bytes[..chunks[3] + 100].to_vec(),
            3 * PER_CHUNK,
            "cut-short",
        ),
    ];
    for (name, damaged, frames, kind) in cases {
        let input = dir.path().join(format!("{name}.mcap"));
        std::fs::write(&input, &damaged).expect("write");
        let out = dir.path().join(format!("{name}.out.mcap"));
        let report = salvaged(&input, &out);
        assert_eq!(report["frames"], frames, "{name}: {report}");
        let skips: u64 = kind
            .split('|')
            .filter_map(|k| report["skipped"]["counts"][k].as_u64())
            .sum();
        assert_eq!(skips, 1, "{name}: {report}");
        // The output is in place, and holds the skeletons of every frame replayed.
        let kept: Vec<(u64, Skeleton3D)> = read_topic(&out, SKELETONS).expect("complete");
        assert_eq!(newest_estimates(&kept), frames, "{name}");
        // `recover` writes a clean, indexed copy of the same frames, which Python `mcap`
        // reads through its index and `rosbags` as a rosbag2 bag.
        let bag = dir.path().join(format!("{name}-bag"));
        std::fs::create_dir_all(&bag).expect("bag");
        let copy = bag.join("recovered.mcap");
        let r = run(&["recover", s(&input), s(&copy), "--rosbag2", "--json"]);
        assert_eq!(r.code, Some(0), "{name}: {}", r.stderr);
        assert_eq!(r.report()["messages"], frames, "{name}");
        assert!(
            r.stderr.contains("damaged parts skipped"),
            "{name}: {}",
            r.stderr
        );
        let indexed = python_client("read_indexed.py", &[s(&copy)]);
        assert_eq!(indexed["topics"][HEATMAPS], frames, "{name}: {indexed}");
        assert_eq!(indexed["decoded"], frames, "{name}: {indexed}");
        assert!(
            indexed["chunk_indexes"].as_u64() > Some(0),
            "{name}: {indexed}"
        );
        let bag_read = python_client("read_recording.py", &["--rosbag2", s(&bag)]);
        assert_eq!(bag_read["topics"][HEATMAPS], frames, "{name}: {bag_read}");
        // And the copy reads strictly, whole.
        let strict: Vec<(u64, HeatMaps)> = read_topic(&copy, HEATMAPS).expect("clean");
        assert_eq!(strict.len(), frames, "{name}");
    }
    // The service reads on past damage too: `run --recording` publishes every readable
    // frame and warns; strict, the input ends at the damage with one error.
    let input = dir.path().join("wrong-crc.mcap");
    let r = run(&["run", "--recording", s(&input), "--ros2", "false", "--json"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(
        r.report()["detector"]["published"],
        all - PER_CHUNK,
        "{}",
        r.stdout
    );
    assert!(
        r.stderr.contains("damaged parts skipped") && r.stderr.contains("1 CRC mismatch"),
        "{}",
        r.stderr
    );
    let r = run(&[
        "run",
        "--recording",
        s(&input),
        "--ros2",
        "false",
        "--strict",
    ]);
    assert_eq!(r.code, Some(1), "{}", r.stderr);
    assert!(r.stderr.contains("corrupt recording"), "{}", r.stderr);
    // Nothing readable at all: one error.
    let mut random = b"\x89MCAP0\r\n".to_vec();
    random.extend((0..4096_u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
    let input = dir.path().join("random.mcap");
    std::fs::write(&input, random).expect("write");
    run(&["replay", s(&input)]).assert_one_error("nothing could be read");
    let copy = dir.path().join("random-copy.mcap");
    run(&["recover", s(&input), s(&copy)]).assert_one_error("nothing could be read");
    assert!(!copy.exists());
}

fn patch(bytes: &[u8], at: usize, with: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[at..at + with.len()].copy_from_slice(with);
    b
}

// Defect 6: a frame with another map size wedged the track.

/// The first frame of kick.mcap with 32 x 32 maps (every other row and column).
fn downsampled(m: &HeatMaps) -> HeatMaps {
    let mut small = m.clone();
    let (h, w) = (m.height as usize, m.width as usize);
    small.height = (h / 2) as u32;
    small.width = (w / 2) as u32;
    small.quantized_values = (0..17)
        .flat_map(|j| (0..h / 2).flat_map(move |r| (0..w / 2).map(move |c| (j, 2 * r, 2 * c))))
        .map(|(j, r, c)| m.quantized_values[j * h * w + r * w + c])
        .collect();
    small
}

#[test]
fn a_map_size_change_starts_a_new_track_instead_of_wedging_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut all = frames("kick.mcap");
    let n = all.len();
    all[0].1 = downsampled(&all[0].1);
    let input = dir.path().join("resized.mcap");
    write_raw(&input, &encoded(&all), 1000);
    let r = replay_json(&input);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let report = r.report();
    assert_eq!(report["malformed"], 0, "{report}");
    assert_eq!(report["skeletons"], 2 * n);
    assert_eq!(report["counters"]["tracks"], 2);
}

#[test]
fn refused_frames_do_not_keep_an_idle_track_alive() {
    refused_frames_and_an_idle_track(false);
}

#[test]
fn refused_frames_do_not_keep_an_idle_track_alive_on_the_runtime() {
    refused_frames_and_an_idle_track(true);
}

/// Frames of one person, then refused frames for longer than the idle time, then the
/// same person again: two tracks, in the blocking loop or on the runtime.
fn refused_frames_and_an_idle_track(on_runtime: bool) {
    use std::sync::atomic::AtomicBool;
    use std::time::Duration;

    use posestream::nodes::service::{
        EstimatorOutputs, Middleware, Taps, run_estimator, run_estimator_on_runtime,
    };
    use posestream::transport::memory;
    use posestream::transport::runtime::Blocking;
    use posestream::transport::{Lend, Sink};

    let dir = tempfile::tempdir().expect("tempdir");
    let mut c = config();
    c.outputs.markers = false;
    c.outputs.record = dir.path().join("idle.mcap");
    c.estimator.window.max_gap_seconds = 0.5;
    let mut node = EstimatorNode::from_config(&c.estimator).expect("node");
    let mut middleware = Middleware::open(&c, None).expect("middleware");
    let recorder = posestream::nodes::service::output_recording(&c)
        .expect("recording")
        .expect("configured");
    let mut outputs = EstimatorOutputs::open(
        &c,
        &mut middleware,
        &Taps {
            recorder: Some(recorder.clone()),
            live: None,
        },
        &node,
    )
    .expect("outputs");
    let (mut sink, source) = memory::channel::<HeatMaps>(256);
    let all = frames("kick.mcap");
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            for (t, m) in &all[..20] {
                sink.send(m, *t).expect("send");
            }
            // Frames the node refuses (another joint layout), for longer than the gap.
            let mut wrong = all[20].1.clone();
            wrong.joint_names.reverse();
            for _ in 0..30 {
                std::thread::sleep(Duration::from_millis(60));
                sink.send(&wrong, 0).expect("send");
            }
            // The same person goes on: a track that was not ended by the idle time would
            // simply continue.
            for (t, m) in &all[20..40] {
                sink.send(m, *t).expect("send");
            }
            drop(sink);
        });
        let report = if on_runtime {
            let source = Blocking::spawn("test", source, 4).expect("thread");
            run_estimator_on_runtime(&mut node, source, &mut outputs, &stop).expect("runs")
        } else {
            run_estimator(&mut node, &mut Lend(source), &mut outputs, &stop)
        };
        assert_eq!(report.malformed, 30);
        assert_eq!(
            report.counters.tracks, 2,
            "the idle track ended while only refused frames arrived"
        );
        assert_eq!(report.frames, 70);
        assert_eq!(
            report.skeletons, 80,
            "both tracks' skeletons, newest and lagged"
        );
    });
    drop(outputs);
    recorder.finish().expect("finish");
}

// Defect 7: configuration values without bounds.

#[test]
fn configuration_values_outside_their_domain_are_one_error_naming_the_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = [
        (
            "[estimator.window]\nsize = 1000000000\n",
            "estimator.window.size",
        ),
        (
            "[estimator.window]\nsize = 9223372036854775807\n",
            "estimator.window.size",
        ),
        (
            "[estimator.window]\nlocal_frames = 0\n",
            "estimator.window.local_frames",
        ),
        ("[estimator.window]\nlag = 30\n", "estimator.window.lag"),
        (
            "[estimator.window]\nwindow_parts = 0\n",
            "estimator.window.window_parts",
        ),
        (
            "[estimator.window]\nwindow_parts = 18446744073709551615\n",
            "estimator.window.window_parts",
        ),
        (
            "[estimator.window]\nem_iterations = 100000\n",
            "estimator.window.em_iterations",
        ),
        (
            "[estimator.window]\nmax_gap_seconds = -1.0\n",
            "estimator.window.max_gap_seconds",
        ),
        (
            "[estimator.window]\nmax_gap_frames = 0\n",
            "estimator.window.max_gap_frames",
        ),
        (
            "[estimator.params]\nalpha = -1.0\n",
            "estimator.params.alpha",
        ),
        (
            "[estimator.params]\nsigma = nan\n",
            "estimator.params.sigma",
        ),
        (
            "[estimator.params]\nconfidence_spread = 1.5\n",
            "estimator.params.confidence_spread",
        ),
        (
            "[estimator.params]\nswap_prior = 0.9\n",
            "estimator.params.swap_prior",
        ),
        (
            "[estimator.params]\nswap_prior = -inf\n",
            "estimator.params.swap_prior",
        ),
        (
            "[estimator.window]\nlag_rounds = 0\n",
            "estimator.window.lag_rounds",
        ),
        (
            "[estimator.params]\nmax_apg_steps = 100000000000\n",
            "estimator.params.max_apg_steps",
        ),
        ("[estimator]\nmax_tracks = 0\n", "estimator.max_tracks"),
        (
            "[estimator]\nmax_tracks = 1000000000\n",
            "estimator.max_tracks",
        ),
        (
            "[estimator.metric]\nintrinsics = [1000.0, 1000.0, inf, 500.0]\n",
            "estimator.metric.intrinsics",
        ),
        (
            "[estimator.metric]\nintrinsics = [1e300, 1e300, 500.0, 500.0]\n",
            "estimator.metric.intrinsics",
        ),
        (
            "[estimator.metric]\nintrinsics = [1000.0, 1000.0, 1e300, 500.0]\n",
            "estimator.metric.intrinsics",
        ),
        (
            "[topics]\nskeleton_arrays = \"/posestream/skeletons\"\n",
            "topics.skeleton_arrays",
        ),
        (
            "[topics]\ncamera_info = \"/posestream/heatmaps\"\n",
            "topics.camera_info",
        ),
        (
            "[estimator.metric]\nmean_limb_length = nan\n",
            "estimator.metric.mean_limb_length",
        ),
        (
            "[estimator.metric]\nmean_limb_length = 1e300\n",
            "estimator.metric.mean_limb_length",
        ),
        (
            "[estimator.metric]\nscale_std = 2.0\n",
            "estimator.metric.scale_std",
        ),
        (
            "[estimator.metric]\nalpha = inf\n",
            "estimator.metric.alpha",
        ),
        (
            "[estimator.metric]\nmax_iterations = 0\n",
            "estimator.metric.max_iterations",
        ),
        (
            "[estimator.metric]\napg_steps = 18446744073709551615\n",
            "estimator.metric.apg_steps",
        ),
        (
            "[estimator.metric]\ntolerance = 0.0\n",
            "estimator.metric.tolerance",
        ),
        (
            "[detector.images]\nfield_of_view = nan\n",
            "detector.images.field_of_view",
        ),
        (
            "[detector.images]\nfield_of_view = 180.0\n",
            "detector.images.field_of_view",
        ),
        (
            "[detector.images]\nfield_of_view = -60.0\n",
            "detector.images.field_of_view",
        ),
        (
            "[topics]\nskeleton_arrays = \"\"\n",
            "topics.skeleton_arrays",
        ),
        (
            "[topics]\ncamera_info = \"camera info\"\n",
            "topics.camera_info",
        ),
        ("[ros]\ndomain_id = 500\n", "ros.domain_id"),
        (
            "[estimator.metric]\nstd_factor = nan\n",
            "estimator.metric.std_factor",
        ),
        (
            "[estimator.metric]\nstd_factor = -1.0\n",
            "estimator.metric.std_factor",
        ),
        (
            "[estimator.metric]\nstd_factor = 1e300\n",
            "estimator.metric.std_factor",
        ),
        ("[topics]\nfloor = \"floor\"\n", "topics.floor"),
        (
            "[topics]\nfloor = \"/posestream/skeletons\"\n",
            "topics.floor",
        ),
        ("[ros.qos]\ndepth = 0\n", "ros.qos.depth"),
        ("[ros.qos]\ndepth = 100000000\n", "ros.qos.depth"),
        ("[topics]\nheatmaps = \"\"\n", "topics.heatmaps"),
        (
            "[topics]\nskeletons = \"no/leading/slash\"\n",
            "topics.skeletons",
        ),
        ("[iceoryx2]\nheatmaps = \"\"\n", "iceoryx2.heatmaps"),
        ("[detector.images]\nfps = 0.0\n", "detector.images.fps"),
        (
            "[detector.images]\npresence_threshold = 2.0\n",
            "detector.images.presence_threshold",
        ),
        (
            "[detector.images]\nperson_box = [0.0, 0.0, -5.0, 10.0]\n",
            "detector.images.person_box",
        ),
        (
            "[detector.images.tracking]\nmax_people = 0\n",
            "detector.images.tracking.max_people",
        ),
        (
            "[detector.images.tracking]\nmax_people = 18446744073709551615\n",
            "detector.images.tracking.max_people",
        ),
        (
            "[detector.images.tracking]\nbirth_frames = 0\n",
            "detector.images.tracking.birth_frames",
        ),
        (
            "[detector.images.tracking]\ndetect_every = 4294967295\n",
            "detector.images.tracking.detect_every",
        ),
        (
            "[detector.images.tracking]\nlow_threshold = nan\n",
            "detector.images.tracking.low_threshold",
        ),
        (
            "[detector.images.tracking]\nmatch_iou = inf\n",
            "detector.images.tracking.match_iou",
        ),
        (
            "[detector.images.tracking]\nduplicate_iou = -1.0\n",
            "detector.images.tracking.duplicate_iou",
        ),
        (
            "[detector.images.tracking]\nreid_seconds = nan\n",
            "detector.images.tracking.reid_seconds",
        ),
        (
            "[detector.images.tracking]\nreid_seconds = 1e308\n",
            "detector.images.tracking.reid_seconds",
        ),
        (
            "[detector.images.tracking]\nreid_capacity = 4097\n",
            "detector.images.tracking.reid_capacity",
        ),
        (
            "[detector.images.tracking]\nreid_distance = -inf\n",
            "detector.images.tracking.reid_distance",
        ),
        (
            "[detector.images.tracking]\nlooks_per_frame = 65\n",
            "detector.images.tracking.looks_per_frame",
        ),
        (
            "[detector.images.tracking]\nlooks_per_frame = 18446744073709551615\n",
            "detector.images.tracking.looks_per_frame",
        ),
        (
            "[detector.images.tracking]\nmax_wait_frames = 31\n",
            "detector.images.tracking.max_wait_frames",
        ),
        (
            "[detector.images.tracking]\nmax_wait_frames = 4294967295\n",
            "detector.images.tracking.max_wait_frames",
        ),
        ("[detector]\nnice = 20\n", "detector.nice"),
        (
            "[detector.images]\nsearch_tiles = 0\n",
            "detector.images.search_tiles",
        ),
        (
            "[detector.images]\nsearch_tiles = 1000000\n",
            "detector.images.search_tiles",
        ),
        (
            "[detector.images]\npedestrian_tiles = 0\n",
            "detector.images.pedestrian_tiles",
        ),
        (
            "[detector.images]\npedestrian_tiles = 5\n",
            "detector.images.pedestrian_tiles",
        ),
        (
            "[detector.images]\npedestrian_threshold = 0.0\n",
            "detector.images.pedestrian_threshold",
        ),
        (
            "[detector.images]\npedestrian_threshold = nan\n",
            "detector.images.pedestrian_threshold",
        ),
        (
            "[detector.images]\npedestrian_threshold = 1.5\n",
            "detector.images.pedestrian_threshold",
        ),
        (
            "[detector.images]\nnanodet_threshold = nan\n",
            "detector.images.nanodet_threshold",
        ),
        (
            "[detector.images]\nnanodet_threshold = 1.5\n",
            "detector.images.nanodet_threshold",
        ),
        (
            "[detector.images]\nnanodet_input = \"400x300\"\n",
            "detector.images.nanodet_input",
        ),
        (
            "[detector.images]\nnanodet_input = \"\"\n",
            "detector.images.nanodet_input",
        ),
        (
            "[detector.images]\nnanodet_input = \"4294967296x4294967296\"\n",
            "detector.images.nanodet_input",
        ),
        (
            "[ros]\nwait_for_subscribers = -1.0\n",
            "ros.wait_for_subscribers",
        ),
        (
            "[ros]\nwait_for_subscribers = nan\n",
            "ros.wait_for_subscribers",
        ),
        ("[topics]\nhri_bodies = \"/tf\"\n", "topics.hri_bodies"),
        (
            "[topics]\nhri_bodies = \"/posestream\"\n",
            "topics.hri_bodies",
        ),
        ("[ros]\nnamespace = \"robot1\"\n", "ros.namespace"),
        ("[ros]\nnode_name = \"1node\"\n", "ros.node_name"),
        ("[limits]\nmax_map_size = 0\n", "limits.max_map_size"),
        ("[limits]\nmax_joints = 100000\n", "limits.max_joints"),
        (
            "[limits]\nmax_record_bytes = 10\n",
            "limits.max_record_bytes",
        ),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad-{i}.toml"));
        std::fs::write(&path, text).expect("write");
        let r = run(&["replay", "recordings/byebye.mcap", "--config", s(&path)]);
        r.assert_one_error(key);
        assert!(
            r.stderr.contains(" must be ") || r.stderr.contains("expected"),
            "the domain is named: {}",
            r.stderr
        );
    }
    // The shipped configuration is inside every domain.
    config().validate().expect("valid");
}

/// The search's detector and thread switches: a value of the wrong kind is one error
/// (TOML's, with the line it is on) naming the key and what it takes, nothing run.
#[test]
fn a_detector_choice_or_switch_of_the_wrong_kind_is_refused_with_what_it_takes() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, (text, key, takes)) in [
        (
            "body_detector = \"yolo\"",
            "body_detector",
            "`nanodet` or `ssdlite`",
        ),
        ("body_detector = 1e308", "body_detector", "string"),
        ("search_thread = \"yes\"", "search_thread", "bool"),
        ("search_thread = nan", "search_thread", "bool"),
    ]
    .iter()
    .enumerate()
    {
        let path = dir.path().join(format!("kind-{i}.toml"));
        std::fs::write(&path, format!("[detector.images]\n{text}\n")).expect("write");
        let r = run(&["replay", "recordings/byebye.mcap", "--config", s(&path)]);
        assert_eq!(r.code, Some(1), "{}", r.stderr);
        assert!(r.stderr.starts_with("posestream: error: "), "{}", r.stderr);
        assert!(
            r.stderr.contains(key) && r.stderr.contains(takes),
            "names {key} and {takes}: {}",
            r.stderr
        );
        r.assert_bounded();
    }
}

// Found while giving each enum one parser: `config/default.toml` documents
// `init = "convex+refine"`, which the configuration refused (its serde names were
// `convex-refine`, the command line's `convex+refine`).

#[test]
fn every_initialisation_the_configuration_documents_is_accepted() {
    let dir = tempfile::tempdir().expect("tempdir");
    for init in ["altern", "convex+refine", "convex+robust+refine"] {
        let path = dir.path().join("init.toml");
        std::fs::write(&path, format!("[estimator.params]\ninit = \"{init}\"\n")).expect("write");
        let r = run(&["replay", "recordings/byebye.mcap", "--config", s(&path)]);
        assert_eq!(r.code, Some(0), "init = {init}: {}", r.stderr);
    }
}

// Defect 8: an output that is an input.

#[test]
fn an_output_that_is_an_input_is_refused_and_a_failed_run_keeps_the_old_output() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = dir.path().join("same.mcap");
    std::fs::copy(recording("byebye.mcap"), &input).expect("copy");
    let before = std::fs::read(&input).expect("read");
    run(&["replay", s(&input), "--record", s(&input)]).assert_one_error("same.mcap");
    let link = dir.path().join("link.mcap");
    std::os::unix::fs::symlink(&input, &link).expect("symlink");
    run(&["replay", s(&input), "--record", s(&link)]).assert_one_error("link.mcap");
    let hard = dir.path().join("hard.mcap");
    std::fs::hard_link(&input, &hard).expect("hard link");
    run(&["replay", s(&input), "--record", s(&hard)]).assert_one_error("hard.mcap");
    assert_eq!(std::fs::read(&input).expect("read"), before, "input intact");
    // `run` too.
    let r = run(&[
        "run",
        "--recording",
        s(&input),
        "--record",
        s(&input),
        "--ros2",
        "false",
    ]);
    r.assert_one_error("same.mcap");
    assert_eq!(std::fs::read(&input).expect("read"), before, "input intact");

    // A run that fails leaves an existing output as it was.
    let old = dir.path().join("old.mcap");
    std::fs::write(&old, b"precious").expect("write");
    let not_mcap = dir.path().join("text.mcap");
    std::fs::write(&not_mcap, "hello\n").expect("write");
    run(&["replay", s(&not_mcap), "--record", s(&old)]).assert_one_error("text.mcap");
    assert_eq!(std::fs::read(&old).expect("read"), b"precious");
    // A successful run replaces it, and leaves no temporary file behind.
    let r = run(&["replay", s(&input), "--record", s(&old)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(
        !read_topic::<Skeleton3D>(&old, SKELETONS)
            .expect("reads")
            .is_empty()
    );
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.contains("partial")), "{names:?}");
}

// Defect 9: files that are not recordings, or hold no heat maps.

#[test]
fn a_file_that_is_not_a_recording_of_heat_maps_is_one_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a recording\n").expect("write");
    let png = dir.path().join("picture.png");
    image::RgbImage::new(4, 4).save(&png).expect("png");
    let random = dir.path().join("random.bin");
    std::fs::write(
        &random,
        (0..5000_u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect::<Vec<_>>(),
    )
    .expect("write");
    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, b"").expect("write");
    for input in [&text, &png, &random, &empty] {
        run(&["replay", s(input)]).assert_one_error("not an MCAP");
    }
    // A recording without heat maps (skeletons only).
    let skeletons = dir.path().join("skeletons.mcap");
    let mut rec = Recorder::create(&skeletons).expect("create");
    rec.write(SKELETONS, 1, &Skeleton3D::default())
        .expect("write");
    rec.finish().expect("finish");
    run(&["replay", s(&skeletons)]).assert_one_error("no messages on /posestream/heatmaps");
    // The same through the service: `run` and the detector replaying it say so too, not
    // a normal end with nothing published.
    for command in [
        &["run", "--recording"][..],
        &["detector", "--recording"][..],
    ] {
        let mut args = command.to_vec();
        args.push(s(&skeletons));
        let r = run(&args);
        assert_eq!(r.code, Some(1), "{args:?}: {}", r.stderr);
        assert!(
            r.stderr.contains("has no messages on this topic") && r.stderr.contains(SKELETONS),
            "{args:?}: {}",
            r.stderr
        );
    }
    // A cut-short recording: everything complete is replayed, a warning says where it
    // was cut, and the exit status is 0 (docs/limits.md).
    let (_, bytes) = chunked(dir.path());
    let cut = dir.path().join("cut.mcap");
    let third = records(&bytes)
        .into_iter()
        .filter(|(_, op)| *op == CHUNK)
        .nth(2)
        .expect("chunk")
        .0;
    std::fs::write(&cut, &bytes[..third + 100]).expect("write");
    let r = run(&["replay", "--json", s(&cut)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(r.report()["frames"], 2 * PER_CHUNK);
    assert!(r.stderr.starts_with("posestream: warning: ") && r.stderr.contains("cut short"));
    assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
}

// Minor defects.

/// Replays the first 30 frames of byebye.mcap, each changed by `change`, through the
/// binary; returns the skeletons recorded and the run.
fn replay_changed(
    dir: &Path,
    name: &str,
    change: impl Fn(usize, &mut HeatMaps),
) -> (Vec<Skeleton3D>, Run) {
    let input = dir.join(format!("{name}.mcap"));
    let out = dir.join(format!("{name}.out.mcap"));
    let mut all = frames("byebye.mcap");
    all.truncate(30);
    for (i, (_, m)) in all.iter_mut().enumerate() {
        change(i, m);
    }
    write_raw(&input, &encoded(&all), 1000);
    let r = run(&["replay", "--json", s(&input), "--record", s(&out)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let skeletons = read_topic::<Skeleton3D>(&out, SKELETONS)
        .expect("reads")
        .into_iter()
        .map(|(_, s)| s)
        .collect();
    (skeletons, r)
}

#[test]
fn huge_crop_boxes_never_give_non_finite_skeletons() {
    let mut node = EstimatorNode::from_config(&config().estimator).expect("node");
    let mut out = Vec::new();
    for (i, (_, m)) in frames("byebye.mcap").iter().enumerate().take(30) {
        let mut m = m.clone();
        if i >= 10 {
            m.crop_x = 1e308;
            m.crop_width = 1.7e308;
        }
        let _ = node.handle(&m, &mut out);
    }
    node.finish(&mut out);
    assert!(!out.is_empty());
    for s in &out {
        let values = s
            .positions
            .iter()
            .chain(&s.position_std)
            .chain(&s.keypoints)
            .chain(&s.keypoint_std)
            .chain(&s.projected);
        assert!(
            values.clone().all(|v| v.is_finite()),
            "frame {}",
            s.sequence
        );
    }
    assert_eq!(node.malformed(), 20, "the boxes are refused");
    // The binary publishes nothing non-finite either.
    let dir = tempfile::tempdir().expect("tempdir");
    let (skeletons, _) = replay_changed(dir.path(), "crop", |i, m| {
        if i >= 10 {
            m.crop_x = 1e308;
            m.crop_width = 1.7e308;
        }
    });
    assert!(!skeletons.is_empty());
    assert!(skeletons.iter().all(Skeleton3D::is_finite));
}

#[test]
fn frames_without_evidence_are_not_tracking() {
    // Frames 10..15 of 30 have nothing in their maps (a gap the track survives).
    let empty = |i: usize| (10..15).contains(&i);
    let mut node = EstimatorNode::from_config(&config().estimator).expect("node");
    let mut out = Vec::new();
    let all = frames("byebye.mcap");
    for (i, (_, m)) in all.iter().take(30).enumerate() {
        let mut m = m.clone();
        if empty(i) {
            m.quantized_values.iter_mut().for_each(|v| *v = 0);
        }
        node.handle(&m, &mut out).expect("not refused");
    }
    node.finish(&mut out);
    let empty_sequences: Vec<u64> = all[10..15].iter().map(|(_, m)| m.sequence).collect();
    assert!(
        out.iter().all(|s| !empty_sequences.contains(&s.sequence)),
        "an estimate of a frame without evidence"
    );
    assert!(
        out.iter()
            .any(|s| s.state == msgs::SkeletonState::Tracking as u8)
    );
    let c = node.counters();
    assert_eq!(
        (c.empty, c.missing, c.frames, c.tracks),
        (5, 0, 25, 1),
        "{c:?}"
    );
    let dir = tempfile::tempdir().expect("tempdir");
    let (skeletons, r) = replay_changed(dir.path(), "zero", |i, m| {
        if empty(i) {
            m.quantized_values.iter_mut().for_each(|v| *v = 0);
        }
    });
    assert!(!skeletons.is_empty());
    assert!(
        skeletons
            .iter()
            .all(|s| !empty_sequences.contains(&s.sequence)),
        "the binary estimated a frame without evidence"
    );
    assert_eq!(r.report()["counters"]["empty"], 5);
}

#[test]
fn a_refused_frame_of_another_track_does_not_end_the_current_one() {
    let mut node = EstimatorNode::from_config(&config().estimator).expect("node");
    let mut out = Vec::new();
    for (i, (_, m)) in frames("byebye.mcap").iter().take(40).enumerate() {
        let mut m = m.clone();
        if i == 20 {
            // Another track id, and a non-finite score: refused, and nothing else.
            m.track_id = 7;
            let mut values = Vec::new();
            m.values_into(&mut values).expect("values");
            values[3] = f32::NAN;
            m.encoding = 0;
            m.values = values;
            assert!(node.handle(&m, &mut out).is_err());
        } else {
            node.handle(&m, &mut out).expect("good frame");
        }
    }
    assert_eq!(node.counters().tracks, 1);
    assert!(
        out.iter()
            .all(|s| s.state != msgs::SkeletonState::Lost as u8)
    );
}

#[test]
fn the_regression_recordings_of_the_fuzzer_are_one_error() {
    // Where the `mcap` crate's reader once panicked (or wrapped, in release builds),
    // strictly the file ends as a corrupt one; read on past damage, its readable frames
    // are replayed with one warning.
    let dir = common::root().join("fuzz/regressions/mcap");
    let mut n = 0;
    for entry in std::fs::read_dir(dir).expect("regressions") {
        let path = entry.expect("entry").path();
        let r = run(&["replay", "--strict", s(&path)]);
        r.assert_one_error("corrupt recording");
        let r = run(&["replay", s(&path)]);
        r.assert_bounded();
        assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
        n += 1;
    }
    assert!(n > 0);
}

#[test]
fn a_non_finite_value_is_reported_with_its_frame() {
    let mut node = EstimatorNode::from_config(&config().estimator).expect("node");
    let mut m = frames("byebye.mcap").remove(7).1;
    let mut values = Vec::new();
    m.values_into(&mut values).expect("values");
    values[5 * 64 * 64 + 3] = f32::NAN;
    m.encoding = 0;
    m.values = values;
    let err = node.handle(&m, &mut Vec::new()).expect_err("NaN");
    let text = err.to_string();
    assert!(text.contains(&format!("frame {}", m.sequence)), "{text}");
    assert!(!text.contains("frame 0"), "{text}");
    assert!(text.contains("joint 5"), "{text}");
    // The binary's log says which frame.
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, r) = replay_changed(dir.path(), "nan", |i, m| {
        if i == 7 {
            let mut values = Vec::new();
            m.values_into(&mut values).expect("values");
            values[5 * 64 * 64 + 3] = f32::NAN;
            m.encoding = 0;
            m.values = values;
            m.quantized_values.clear();
        }
    });
    let line = r
        .stderr
        .lines()
        .find(|l| l.contains("non-finite"))
        .unwrap_or_else(|| panic!("a refusal is logged: {}", r.stderr));
    assert!(
        line.contains("frame 7") && !line.contains("frame 0"),
        "{line}"
    );
}

#[test]
fn sigterm_finalises_the_recording_as_sigint_does() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("terminated.mcap");
    let mut child = posestream()
        .args([
            "replay",
            "recordings/byebye.mcap",
            "--rate",
            "recorded",
            "--record",
        ])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("starts");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    assert!(child.wait().expect("waits").success());
    let all = RecordingReader::open(&out)
        .expect("open")
        .collect::<Result<Vec<_>, _>>()
        .expect("a complete recording, footer included");
    assert!(all.len() > 20 && all.len() < 363, "{} messages", all.len());
}

#[test]
fn a_signal_ends_the_scan_past_damage_too() {
    // byebye.mcap with 64 GiB of zeros (a sparse hole: no disk) after its magic: reading
    // on scans them for the next record, minutes of reading; SIGTERM ends it at the next
    // block, and the recording made so far is complete.
    use std::io::{Seek, Write};
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = std::fs::read(common::root().join("recordings/byebye.mcap")).expect("read");
    let path = dir.path().join("holed.mcap");
    let mut file = std::fs::File::create(&path).expect("create");
    file.write_all(&bytes[..8]).expect("write");
    file.set_len(8 + (64 << 30)).expect("a sparse hole");
    file.seek(std::io::SeekFrom::End(0)).expect("seek");
    file.write_all(&bytes[8..]).expect("write");
    drop(file);
    for command in ["replay", "run"] {
        let out = dir.path().join(format!("{command}.mcap"));
        let mut child = posestream();
        match command {
            "replay" => child.args(["replay", s(&path)]),
            _ => child.args(["run", "--recording", s(&path), "--ros2", "false"]),
        };
        let mut child = child
            .args(["--record", s(&out)])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("starts");
        std::thread::sleep(std::time::Duration::from_millis(1500));
        assert!(
            child.try_wait().expect("waits").is_none(),
            "{command}: still scanning"
        );
        let sent = std::time::Instant::now();
        let status = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .expect("kill");
        assert!(status.success());
        // Ended within a few blocks' reading (the scan alone would take minutes).
        let ended = (0..300).any(|_| {
            std::thread::sleep(std::time::Duration::from_millis(100));
            child.try_wait().expect("waits").is_some()
        });
        if !ended {
            let _ = child.kill();
        }
        assert!(
            ended,
            "{command}: running {:?} after SIGTERM",
            sent.elapsed()
        );
        let done = child.wait_with_output().expect("waits");
        assert!(
            done.status.success(),
            "{command}: {}",
            String::from_utf8_lossy(&done.stderr)
        );
        RecordingReader::open(&out)
            .expect("open")
            .collect::<Result<Vec<_>, _>>()
            .expect("a complete recording, footer included");
    }
}

#[test]
fn lift_errors_name_the_file_at_fault() {
    use posestream::npy;
    let dir = tempfile::tempdir().expect("tempdir");
    let kp = common::fixture("synthetic-s0").join("keypoints.npy");
    let frames = common::read(kp.clone()).shape[0];
    // Confidences outside [0, 1]: the error names the confidence file, not the keypoints.
    let confidence = dir.path().join("confidence.npy");
    npy::write(&confidence, &[frames, 17], &vec![1.5; frames * 17]).expect("write");
    let out = dir.path().join("S.npy");
    let k128 = common::k128();
    let r = run(&[
        "lift",
        "--dict",
        s(&k128),
        "--keypoints",
        s(&kp),
        "--confidence",
        s(&confidence),
        "--out",
        s(&out),
    ]);
    r.assert_one_error("confidence.npy");
    // An NPY whose shape's product overflows is not "empty".
    let header =
        "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296, 17, 2), }";
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    let padded = format!("{header:<118}\n");
    bytes.extend((padded.len() as u16).to_le_bytes());
    bytes.extend(padded.as_bytes());
    bytes.extend([0_u8; 64]);
    let overflow = dir.path().join("overflow.npy");
    std::fs::write(&overflow, bytes).expect("write");
    let r = run(&[
        "lift",
        "--dict",
        s(&k128),
        "--keypoints",
        s(&overflow),
        "--out",
        s(&out),
    ]);
    r.assert_one_error("overflow.npy");
    assert!(!r.stderr.contains("empty"), "{}", r.stderr);
    assert!(r.stderr.contains("too large"), "{}", r.stderr);
}

#[test]
fn dictionaries_written_by_scipy_savemat_load() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scipy.mat");
    let k128 = posestream::Dictionary::load(common::k128()).expect("dictionary");
    let (p, k) = (k128.num_joints(), k128.num_bases());
    let skel = k128.skeleton();
    // B: 3k x p (rows 3i..3i+2 are basis i); mu: 3 x p; skel.tree(j).name/children and
    // skel.torso, 1-based, as the authors' files hold them.
    let b: Vec<Vec<f64>> = (0..3 * k)
        .map(|r| {
            let (i, d) = (r / 3, r % 3);
            (0..p)
                .map(|j| k128.bases()[i * 3 * p + d * p + j])
                .collect()
        })
        .collect();
    let mu: Vec<Vec<f64>> = (0..3)
        .map(|d| (0..p).map(|j| k128.mean()[d * p + j]).collect())
        .collect();
    let children: Vec<Vec<usize>> = (0..p)
        .map(|j| {
            (0..p)
                .filter(|&c| skel.parents[c] == Some(j))
                .map(|c| c + 1)
                .collect()
        })
        .collect();
    let torso: Vec<usize> = skel.torso.iter().map(|t| t + 1).collect();
    let json = dir.path().join("dict.json");
    let spec = serde_json::json!({
        "B": b, "mu": mu, "names": skel.joints, "children": children, "torso": torso,
    });
    std::fs::write(&json, spec.to_string()).expect("write");
    let code = "import json, sys\n\
        import numpy as np, scipy.io\n\
        d = json.load(open(sys.argv[1]))\n\
        p = len(d['names'])\n\
        tree = np.zeros((1, p), dtype=[('name', 'O'), ('children', 'O')])\n\
        for j in range(p):\n\
        \x20   tree[0, j]['name'] = d['names'][j]\n\
        \x20   tree[0, j]['children'] = np.array(d['children'][j], dtype=float).reshape(1, -1)\n\
        skel = {'tree': tree, 'torso': np.array(d['torso'], dtype=float).reshape(1, -1)}\n\
        scipy.io.savemat(sys.argv[2], {'B': np.array(d['B']), 'mu': np.array(d['mu']), 'skel': skel})\n";
    let status = Command::new(common::python())
        .args(["-c", code, s(&json), s(&path)])
        .status()
        .expect("python runs");
    assert!(
        status.success(),
        "scipy (installed by .ci/run with scikit-image) writes the file"
    );
    let header = std::fs::read(&path).expect("read");
    // scipy's header text has no comma after "MAT-file", unlike MATLAB's and Octave's.
    assert!(
        header.starts_with(b"MATLAB 5.0 MAT-file Platform"),
        "{:?}",
        String::from_utf8_lossy(&header[..40])
    );
    let loaded = posestream::Dictionary::load(&path).expect("a scipy MAT file loads");
    assert_eq!(loaded.bases(), k128.bases());
    assert_eq!(loaded.mean(), k128.mean());
    assert_eq!(loaded.skeleton(), k128.skeleton());
    // And the binary lifts with it.
    let kp = common::fixture("synthetic-s0").join("keypoints.npy");
    let out = dir.path().join("S.npy");
    let r = run(&[
        "lift",
        "--dict",
        s(&path),
        "--keypoints",
        s(&kp),
        "--out",
        s(&out),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
}

#[test]
fn a_short_recording_played_again_is_a_new_track_each_pass() {
    // 5 frames: fewer than max_gap_frames, so without a new track each pass the second
    // pass would look like late frames of the first.
    let dir = tempfile::tempdir().expect("tempdir");
    let input = dir.path().join("short.mcap");
    write_raw(&input, &encoded(&frames("byebye.mcap")[..5]), 1000);
    let r = run(&[
        "run",
        "--recording",
        s(&input),
        "--repeat",
        "3",
        "--rate",
        "fast",
        "--ros2",
        "false",
        "--json",
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let report = r.report();
    let e = &report["estimator"];
    assert_eq!(e["counters"]["frames"], 15, "{report}");
    assert_eq!(e["counters"]["tracks"], 3, "{report}");
    assert_eq!(e["counters"]["late"], 0, "{report}");
    assert_eq!(e["skeletons"], 30, "{report}");
}

#[test]
fn a_summary_or_a_copy_cannot_make_reading_lose_or_repeat_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, bytes) = chunked(dir.path());
    let (all, _) = read_on(&dir.path().join("chunked.mcap"));
    let recs = records(&bytes);
    let footer = bytes.len() - 37;
    let data_end = recs.iter().find(|(_, op)| *op == 0x0f).expect("data end").0;
    // A footer that misplaces the summary (one byte on, at the data-end record, at the
    // header): every message read, nothing said to be cut short; strictly, all of them
    // and then one error naming the footer.
    for (name, start) in [
        ("summary-one-on", data_end as u64 + 14),
        ("summary-at-data-end", data_end as u64),
        ("summary-at-header", 8),
    ] {
        let path = patched(dir.path(), name, &bytes, footer + 9, &start.to_le_bytes());
        let (read, skips) = read_on(&path);
        assert_eq!(read, all, "{name}");
        assert!(skips.is_empty(), "{name}: {skips:?}");
        let (strict, ended) = read_strictly(&path);
        assert_eq!(strict, all, "{name}");
        let Some(RecordingError::Corrupt { reason, .. }) = ended else {
            panic!("{name}: {ended:?}");
        };
        assert!(
            reason.contains("footer places the summary"),
            "{name}: {reason}"
        );
    }
    // A chunk written twice (a copy's blocks repeated): its frames given out once, the
    // repeat skipped and said; strictly, an error at the repeat.
    let chunks: Vec<usize> = recs
        .iter()
        .filter(|(_, op)| *op == CHUNK)
        .map(|(at, _)| *at)
        .collect();
    let (c, next) = (
        chunks[3],
        recs.iter().find(|(at, _)| *at > chunks[3]).expect("next").0,
    );
    let twice = [&bytes[..next], &bytes[c..next], &bytes[next..]].concat();
    let path = dir.path().join("chunk-twice.mcap");
    std::fs::write(&path, &twice).expect("write");
    let (read, skips) = read_on(&path);
    assert_eq!(read, all);
    assert_eq!(
        skips.counts.get(&msgs::salvage::Damage::Duplicate),
        Some(&1),
        "{skips:?}"
    );
    assert_eq!(skips.ranges[0].from, next as u64, "{skips:?}");
    let (strict, ended) = read_strictly(&path);
    assert!(strict < all, "{strict}");
    assert!(
        matches!(&ended, Some(RecordingError::Corrupt { reason, .. }) if reason.contains("repeats")),
        "{ended:?}"
    );
    let r = run(&["replay", "--json", s(&path)]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(r.stderr.contains("1 duplicate chunk"), "{}", r.stderr);
    // The copy in other bytes (its CRC field zeroed): its messages are the first copy's,
    // each given once and the repeats said; strictly, an error.
    let mut copy = bytes[c..next].to_vec();
    copy[9 + 8 + 8 + 8..9 + 8 + 8 + 8 + 4].copy_from_slice(&[0; 4]);
    let again = [&bytes[..next], &copy, &bytes[next..]].concat();
    let path = dir.path().join("chunk-copied.mcap");
    std::fs::write(&path, &again).expect("write");
    let (read, skips) = read_on(&path);
    assert_eq!(read, all);
    assert_eq!(
        skips.counts.get(&msgs::salvage::Damage::Repeated),
        Some(&(PER_CHUNK as u64)),
        "{skips:?}"
    );
    assert!(matches!(
        read_strictly(&path).1,
        Some(RecordingError::Corrupt { .. })
    ));
    // A summary whose chunk index places a chunk on a good message of an unchunked
    // recording (its CRC left out): the message is read as what it is.
    let heat = frames("byebye.mcap");
    let mut raw = [&b"\x89MCAP0\r\n"[..], &heat_map_declarations().concat()].concat();
    let mut target = 0;
    for (i, (t, m)) in heat.iter().enumerate() {
        if i == 50 {
            target = raw.len() as u64;
        }
        raw.extend(raw_message(i, *t, m));
    }
    raw.extend(raw_record(0x0f, &0_u32.to_le_bytes()));
    let summary = raw.len() as u64;
    let index = raw_record(
        0x08,
        &[
            &0_u64.to_le_bytes()[..],
            &u64::MAX.to_le_bytes(),
            &target.to_le_bytes(),
            &100_u64.to_le_bytes(),
            &0_u32.to_le_bytes(),
            &0_u64.to_le_bytes(),
            &raw_bytes(b""),
            &100_u64.to_le_bytes(),
            &100_u64.to_le_bytes(),
        ]
        .concat(),
    );
    raw.extend(index);
    let footer = raw_record(
        0x02,
        &[
            &summary.to_le_bytes()[..],
            &0_u64.to_le_bytes(),
            &0_u32.to_le_bytes(),
        ]
        .concat(),
    );
    raw.extend(footer);
    raw.extend(b"\x89MCAP0\r\n");
    let path = dir.path().join("index-on-a-message.mcap");
    std::fs::write(&path, &raw).expect("write");
    let (read, skips) = read_on(&path);
    assert_eq!(read, heat.len() as u64, "{skips:?}");
    assert!(skips.is_empty(), "{skips:?}");
}

/// Messages of `path` on the heat-map topic, read on past damage, and what was skipped.
fn heat_maps_read_on(path: &Path) -> (usize, msgs::salvage::Skips) {
    let mut reader = RecordingReader::open(path)
        .and_then(RecordingReader::salvaging)
        .expect("opens");
    let n = reader
        .by_ref()
        .filter(|m| m.as_ref().is_ok_and(|m| m.topic == HEATMAPS))
        .count();
    (n, reader.skips().cloned().expect("salvaging"))
}

#[test]
fn data_after_a_summary_or_a_second_copy_is_read_and_a_redeclared_channel_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (a_path, a) = chunked(dir.path());
    let (all_a, _) = heat_maps_read_on(&a_path);
    let b_path = dir.path().join("kick.mcap");
    write_raw(&b_path, &encoded(&frames("kick.mcap")), PER_CHUNK);
    let b = std::fs::read(&b_path).expect("read");
    let (all_b, _) = heat_maps_read_on(&b_path);
    let b_recs = records(&b);
    let b_data_end = b_recs
        .iter()
        .find(|(_, op)| *op == 0x0f)
        .expect("data end")
        .0;
    // Another recording's data between a summary and its footer (the footer's summary
    // start still right): read, and the summary's records among them said.
    let footer = a.len() - 37;
    let hidden = [&a[..footer], &b[b_recs[1].0..b_data_end], &a[footer..]].concat();
    // A file written twice, one copy after the other: the second's frames are the
    // first's, given once; its header and closing magic said.
    let twice = [&a[..], &a[..]].concat();
    for (name, bytes, frames) in [("hidden", hidden, all_a + all_b), ("twice", twice, all_a)] {
        let path = dir.path().join(format!("{name}.mcap"));
        std::fs::write(&path, &bytes).expect("write");
        let (read, skips) = heat_maps_read_on(&path);
        assert_eq!(read, frames, "{name}: {skips:?}");
        assert!(!skips.is_empty(), "{name}: the damage is said");
        let (_, ended) = read_strictly(&path);
        assert!(
            matches!(ended, Some(RecordingError::Corrupt { .. })),
            "{name}: {ended:?}"
        );
    }
    // The heat-map channel declared again under another topic half-way: the first
    // declaration stands, every frame stays on its topic, the conflict is said.
    let heat = frames("byebye.mcap");
    let [header, schema, channel] = heat_map_declarations();
    let mut raw = [&b"\x89MCAP0\r\n"[..], &header, &schema, &channel].concat();
    for (i, (t, m)) in heat.iter().enumerate() {
        if i == 50 {
            raw.extend(raw_record(
                0x04,
                &[
                    &1_u16.to_le_bytes()[..],
                    &1_u16.to_le_bytes(),
                    &raw_bytes(b"/elsewhere"),
                    &raw_bytes(b"cdr"),
                    &0_u32.to_le_bytes(),
                ]
                .concat(),
            ));
        }
        raw.extend(raw_message(i, *t, m));
    }
    let path = dir.path().join("redeclared.mcap");
    std::fs::write(&path, &raw).expect("write");
    let (read, skips) = heat_maps_read_on(&path);
    assert_eq!(read, heat.len(), "{skips:?}");
    assert_eq!(
        skips.counts.get(&msgs::salvage::Damage::Conflict),
        Some(&1),
        "{skips:?}"
    );
    let (strict, ended) = read_strictly(&path);
    assert_eq!(strict, 50);
    assert!(
        matches!(&ended, Some(RecordingError::Corrupt { reason, .. }) if reason.contains("declared again")),
        "{ended:?}"
    );
}
