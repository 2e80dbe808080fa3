//! MCAP recordings, rosbag2-compatible: profile `ros2`, schemas `pkg/msg/Type` in the
//! `ros2msg` encoding (the full definition text with nested `MSG:` blocks), messages in
//! `cdr` with the encapsulation header; zstd-compressed chunks.
//!
//! [`Recorder`] writes one; [`RecordingReader`] reads one front to back with the `mcap`
//! crate's sans-io reader, one record at a time, so a recording cut short (a recorder
//! killed mid-run) still yields every message of its complete chunks before it reports
//! [`RecordingError::Truncated`]. [`write_rosbag2_metadata`] adds the `metadata.yaml`
//! that makes a folder a rosbag2 bag.

use std::collections::BTreeMap;
use std::path::PathBuf;

mod metadata;
mod reader;
mod writer;

pub use metadata::{check_rosbag2_metadata, rosbag2_metadata_path, write_rosbag2_metadata};
pub use reader::{RecordedMessage, RecordingInput, RecordingReader, read_topic, salvage_topic};
pub use writer::Recorder;

/// Errors of reading or writing a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The file could not be opened, created or written (a full disk named as such).
    #[error("{path}: {}", crate::files::io_text(source))]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP library refused the data.
    #[error("{path}: {source}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: mcap::McapError,
    },
    /// The file does not start with the MCAP magic (or is empty).
    #[error("{path}: not an MCAP recording ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What it starts with instead.
        reason: String,
    },
    /// The file ends inside a record: every message before that point was read.
    #[error("{path}: the recording is cut short after {messages} messages ({reason})")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Messages read before the cut.
        messages: u64,
        /// What the reader found.
        reason: String,
    },
    /// A record is corrupt (a chunk whose CRC does not match, a length beyond
    /// `limits.max_record_bytes` or beyond its container, a record that does not parse):
    /// reading ends there; every message before it was read, nothing of it is used.
    #[error("{path}: corrupt recording after {messages} messages: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Messages read before the corrupt record.
        messages: u64,
        /// What the reader found.
        reason: String,
    },
    /// The output would overwrite one of the inputs.
    #[error(transparent)]
    OutputIsInput(#[from] crate::files::OutputIsInput),
    /// The recording could not be finished (a write failed, e.g. the disk is full): the
    /// messages written before are in `partial`, up to its last complete chunk (counted
    /// by reading it back: `readable`).
    #[error(
        "{path}: the recording could not be finished ({reason}); {}",
        kept(partial, *readable)
    )]
    Unfinished {
        /// The output asked for (left as it was).
        path: PathBuf,
        /// The file written until the failure.
        partial: PathBuf,
        /// The first failure.
        reason: String,
        /// Messages `partial` holds that can be read (in its complete chunks).
        readable: u64,
    },
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] crate::EncodeError),
}

/// What a finished recording holds.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub path: PathBuf,
    /// Per topic: message type and count.
    pub topics: BTreeMap<String, (String, u64)>,
    /// Earliest log time, nanoseconds.
    pub start_ns: u64,
    /// Latest log time, nanoseconds.
    pub end_ns: u64,
}

/// What a recording that could not be finished left, as read back.
fn kept(partial: &std::path::Path, readable: u64) -> String {
    if readable == 0 {
        format!(
            "{} holds no readable message (no chunk was complete)",
            partial.display()
        )
    } else {
        format!(
            "what was written is in {}: {readable} messages, readable by `posestream replay` \
             or `recover`",
            partial.display()
        )
    }
}
