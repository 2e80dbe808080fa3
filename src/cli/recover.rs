//! `posestream recover IN OUT`: a clean, indexed copy of everything readable in a damaged
//! recording, as the `mcap` CLI's `recover` makes one: every message that can be read
//! (`posestream::msgs::salvage`), on its channel with its schema, in a new MCAP file with
//! a summary and an index.

use std::path::PathBuf;

use clap::Args;
use posestream::files::check_output;
use posestream::msgs::salvage::{Salvager, Skips};
use posestream::recording::{
    Recorder, RecordingError, RecordingInput, RecordingReader, write_rosbag2_metadata,
};
use serde::Serialize;

use super::{CliError, progress_bar};

/// Options of `recover`.
#[derive(Debug, Args)]
pub struct RecoverArgs {
    /// The damaged recording (MCAP).
    pub input: PathBuf,
    /// The clean copy to write (MCAP).
    pub output: PathBuf,
    /// The service configuration (`--config FILE`): its `[limits] max_record_bytes`.
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// Also write a rosbag2 `metadata.yaml` next to the copy (its folder a bag).
    #[arg(long)]
    pub rosbag2: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `recover` did.
#[derive(Debug, Serialize)]
pub struct RecoverReport {
    /// Messages copied.
    pub messages: u64,
    /// Messages per topic.
    pub topics: std::collections::BTreeMap<String, u64>,
    /// What was skipped.
    pub skipped: Skips,
    /// The clean copy.
    pub output: PathBuf,
}

/// Runs `recover`.
pub fn run(args: &RecoverArgs) -> Result<(), CliError> {
    let config = args.config.load()?;
    check_output(&args.output, &[&args.input]).map_err(RecordingError::from)?;
    if args.rosbag2 {
        posestream::recording::check_rosbag2_metadata(&args.output, &[&args.input])?;
    }
    let limit = config.limits.max_record_bytes;
    // Opened as a recording first: a file that is no MCAP at all is one error.
    drop(RecordingReader::open_with_limit(&args.input, limit)?);
    let io = |source| RecordingError::Io {
        path: args.input.clone(),
        source,
    };
    let mut file = RecordingInput::open(&args.input).map_err(io)?;
    let mut salvager = Salvager::new(&mut file, limit).map_err(io)?;
    let mut recorder = Recorder::create(&args.output)?;
    recorder.set_flush_interval(None);
    let bar = progress_bar(
        usize::try_from(salvager.progress().1).unwrap_or(usize::MAX),
        "recovering",
    );
    let mut messages = 0_u64;
    while let Some(m) = salvager.next_message(&mut file) {
        let Some(channel) = salvager.channel(m.channel) else {
            continue;
        };
        let schema = salvager.schema(channel.schema_id);
        if let Err(e) = recorder.write_raw(schema, channel, &m) {
            // A clean copy half written is of no use: it goes, and the error names the
            // output, not the removed temporary file.
            recorder.abandon();
            return Err(match e {
                RecordingError::Io { source, .. } => CliError::Io {
                    action: "write",
                    path: args.output.clone(),
                    source,
                },
                RecordingError::Unfinished { reason, .. } => CliError::Failed(format!(
                    "cannot write {}: {reason} (nothing was written)",
                    args.output.display()
                )),
                other => other.into(),
            });
        }
        messages += 1;
        if messages.is_multiple_of(1024) {
            bar.set_position(salvager.progress().0);
        }
    }
    bar.finish_and_clear();
    let skipped = salvager.skips().clone();
    if messages == 0 {
        recorder.abandon();
        return Err(CliError::Nothing(format!(
            "{}: nothing could be read{}",
            args.input.display(),
            if skipped.is_empty() {
                String::new()
            } else {
                format!(": {}", skipped.summary())
            }
        )));
    }
    let summary = recorder.finish()?;
    if args.rosbag2 {
        write_rosbag2_metadata(&summary)?;
    }
    let report = RecoverReport {
        messages,
        topics: summary
            .topics
            .iter()
            .map(|(topic, (_, n))| (topic.clone(), *n))
            .collect(),
        skipped,
        output: summary.path,
    };
    if args.json {
        let text = serde_json::to_string_pretty(&report).map_err(|source| CliError::Json {
            path: args.output.clone(),
            source,
        })?;
        println!("{text}");
    } else {
        println!(
            "{} messages on {} topics -> {}",
            report.messages,
            report.topics.len(),
            report.output.display()
        );
    }
    if !report.skipped.is_empty() {
        eprintln!(
            "posestream: warning: {}: damaged parts skipped: {}",
            args.input.display(),
            report.skipped.summary()
        );
    }
    Ok(())
}
