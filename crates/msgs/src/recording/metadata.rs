//! The rosbag2 `metadata.yaml` beside a recording ([`write_rosbag2_metadata`]).

use std::path::{Path, PathBuf};

use super::{RecordingError, RecordingSummary};

/// Writes `metadata.yaml` next to the recording, making its folder a rosbag2 bag
/// (storage `mcap`, format version 5).
pub fn write_rosbag2_metadata(summary: &RecordingSummary) -> Result<PathBuf, RecordingError> {
    let file = summary
        .path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let total: u64 = summary.topics.values().map(|(_, n)| n).sum();
    let duration = summary.end_ns.saturating_sub(summary.start_ns);
    let mut yaml = String::from("rosbag2_bagfile_information:\n  version: 5\n");
    yaml.push_str("  storage_identifier: mcap\n");
    yaml.push_str(&format!(
        "  duration:\n    nanoseconds: {duration}\n  starting_time:\n    nanoseconds_since_epoch: {}\n",
        summary.start_ns
    ));
    yaml.push_str(&format!(
        "  message_count: {total}\n  topics_with_message_count:\n"
    ));
    for (topic, (ty, n)) in &summary.topics {
        yaml.push_str(&format!(
            "    - topic_metadata:\n        name: {topic}\n        type: {ty}\n        serialization_format: cdr\n        offered_qos_profiles: \"\"\n      message_count: {n}\n"
        ));
    }
    yaml.push_str(&format!(
        "  compression_format: \"\"\n  compression_mode: \"\"\n  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n      starting_time:\n        nanoseconds_since_epoch: {}\n      duration:\n        nanoseconds: {duration}\n      message_count: {total}\n",
        summary.start_ns
    ));
    let path = rosbag2_metadata_path(&summary.path);
    crate::files::write_output(&path, &[], yaml.as_bytes()).map_err(metadata_error)?;
    Ok(path)
}

/// Where [`write_rosbag2_metadata`] writes the `metadata.yaml` of `recording`: beside it.
pub fn rosbag2_metadata_path(recording: &Path) -> PathBuf {
    recording
        .parent()
        .unwrap_or(Path::new("."))
        .join("metadata.yaml")
}

/// Checks, before any work, that the `metadata.yaml` of `recording` can be written
/// ([`crate::files::check_target`]: not an input, not a directory or a device), none of
/// `inputs`.
pub fn check_rosbag2_metadata(recording: &Path, inputs: &[&Path]) -> Result<(), RecordingError> {
    crate::files::check_target(&rosbag2_metadata_path(recording), inputs).map_err(metadata_error)
}

fn metadata_error(e: crate::files::OutputError) -> RecordingError {
    match e {
        crate::files::OutputError::Io { path, source } => RecordingError::Io { path, source },
        crate::files::OutputError::IsInput(e) => RecordingError::from(e),
    }
}
