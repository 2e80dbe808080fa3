//! Replay: a recording's heat maps through the estimator node, as fast as possible or at
//! the recorded pace; skeletons (and any ground truth in the input) to a new recording.
//!
//! What a replay does with a bad input: a recording cut short (a recorder killed) is
//! replayed up to its last complete message and reported in
//! [`ReplayReport::truncated`]; a corrupt record ends the replay with
//! [`ReplayError::Input`], the skeletons of everything before it kept in the output's
//! `.partial` file and the output left as it was; a file that is not a recording, or
//! holds no heat maps, is one error and nothing is written.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::config::{ReplayRate, ServiceConfig};
use super::latency::{LatencyHistogram, LatencySummary};
use super::service::pace;
use super::{EstimatorNode, Refusals, SetupError};
use crate::files::{OutputIsInput, check_output};
use crate::msgs::{RosMessage, Skeleton3D};
use crate::recording::{Recorder, RecordingError, RecordingReader, write_rosbag2_metadata};
use crate::streaming::StreamCounters;

/// What a replay did.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    /// Messages read from the input.
    pub messages: u64,
    /// Heat-map frames handed to the estimator.
    pub frames: u64,
    /// Skeleton messages produced.
    pub skeletons: u64,
    /// Heat-map messages refused (undecodable, inconsistent, beyond the limits, unknown
    /// joints).
    pub malformed: u64,
    /// The refusals by kind.
    pub refused: Refusals,
    /// The window's counters (late, missing, resets, tracks).
    pub counters: StreamCounters,
    /// Where the input was cut short, if it was (every message before was replayed).
    pub truncated: Option<String>,
    /// Seconds of wall time.
    pub seconds: f64,
    /// Heat-map frames per second of wall time.
    pub frames_per_second: f64,
    /// Time the estimator node took per heat-map message (decode, window update,
    /// skeleton messages).
    pub update: LatencySummary,
    /// The output recording, if any.
    pub output: Option<PathBuf>,
}

/// Why a replay failed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The estimator could not be set up.
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// The input could not be opened, or the output written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The output is the input.
    #[error(transparent)]
    OutputIsInput(#[from] OutputIsInput),
    /// The input holds no heat maps.
    #[error("{path}: no messages on {topic} (the recording has {found})")]
    NoHeatMaps {
        /// The input.
        path: PathBuf,
        /// The heat-map topic looked for (`topics.heatmaps`).
        topic: String,
        /// The topics it has, with their types.
        found: String,
    },
    /// The input turned out corrupt part way: everything before was replayed.
    #[error("{source}{}", kept.as_ref().map(|k| format!("; the skeletons of the messages before are in {}", k.display())).unwrap_or_default())]
    Input {
        /// What was wrong with the input.
        source: RecordingError,
        /// The output's temporary file holding the skeletons of what came before (the
        /// output itself is left as it was).
        kept: Option<PathBuf>,
    },
}

/// Options of [`replay`].
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Output recording of the skeletons (and the input's ground truth).
    pub record: Option<PathBuf>,
    /// Also write a rosbag2 `metadata.yaml` next to the output.
    pub rosbag2: bool,
    /// Pace.
    pub rate: ReplayRate,
}

/// Replays `input` through an estimator node set up from `config`. Stops early (and
/// still finalises the output) when `stop` becomes true.
pub fn replay(
    config: &ServiceConfig,
    input: &Path,
    options: &ReplayOptions,
    stop: &AtomicBool,
) -> Result<ReplayReport, ReplayError> {
    if let Some(out) = &options.record {
        check_output(out, &[input])?;
    }
    let mut node = EstimatorNode::from_service_config(config)?;
    let mut reader = RecordingReader::open_with_limit(input, config.limits.max_record_bytes)?;
    let mut recorder = options.record.as_ref().map(Recorder::create).transpose()?;
    let topics = &config.topics;
    let start = Instant::now();
    let mut first_log: Option<u64> = None;
    let mut skeletons = Vec::new();
    let (mut frames, mut produced, mut truncated, mut input_error) = (0_u64, 0_u64, None, None);
    // Records the node's skeletons and hands them back to it to be reused.
    let write = |recorder: &mut Option<Recorder>,
                 node: &mut EstimatorNode,
                 skeletons: &mut Vec<Skeleton3D>,
                 log_time: u64|
     -> Result<u64, RecordingError> {
        let n = skeletons.len() as u64;
        if let Some(r) = recorder.as_mut() {
            for s in skeletons.iter() {
                r.write(&topics.skeletons, log_time, s)?;
            }
        }
        node.recycle(skeletons);
        Ok(n)
    };
    let mut last_log = 0;
    let mut latency = LatencyHistogram::default();
    while let Some(next) = reader.next_message() {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let msg = match next {
            Ok(m) => m,
            Err(e @ RecordingError::Truncated { .. }) => {
                truncated = Some(e.to_string());
                break;
            }
            Err(e) => {
                input_error = Some(e);
                break;
            }
        };
        last_log = msg.log_time_ns;
        if options.rate == ReplayRate::Recorded {
            let first = *first_log.get_or_insert(msg.log_time_ns);
            if !pace(
                start,
                Duration::from_nanos(msg.log_time_ns.saturating_sub(first)),
                stop,
            ) {
                break;
            }
        }
        if msg.topic == topics.heatmaps {
            frames += 1;
            let began = Instant::now();
            // A refused message is counted and logged by the node.
            let _ = node.handle_encoded(&msg.data, &mut skeletons);
            latency.record(began.elapsed());
            produced += write(&mut recorder, &mut node, &mut skeletons, msg.log_time_ns)?;
        } else if msg.topic == topics.ground_truth && msg.schema == Skeleton3D::NAME {
            if let Some(r) = recorder.as_mut() {
                r.write_encoded::<Skeleton3D>(&topics.ground_truth, msg.log_time_ns, &msg.data)?;
            }
        }
    }
    node.finish(&mut skeletons);
    produced += write(&mut recorder, &mut node, &mut skeletons, last_log)?;
    if let Some(source) = input_error {
        if reader.messages_read() == 0 {
            // Nothing came before: there is nothing to keep.
            if let Some(r) = recorder {
                r.abandon();
            }
            return Err(source.into());
        }
        let kept = recorder.map(Recorder::finish_partial).transpose()?;
        return Err(ReplayError::Input { source, kept });
    }
    if frames == 0 && !stop.load(Ordering::Relaxed) {
        if let Some(r) = recorder {
            r.abandon();
        }
        return Err(ReplayError::NoHeatMaps {
            path: input.to_path_buf(),
            topic: topics.heatmaps.clone(),
            found: reader.topics_text(),
        });
    }
    let output = match recorder {
        Some(r) => {
            let summary = r.finish()?;
            if options.rosbag2 {
                write_rosbag2_metadata(&summary)?;
            }
            Some(summary.path)
        }
        None => None,
    };
    let seconds = start.elapsed().as_secs_f64();
    Ok(ReplayReport {
        messages: reader.messages_read(),
        frames,
        skeletons: produced,
        malformed: node.malformed(),
        refused: node.refused().clone(),
        counters: node.counters(),
        truncated,
        seconds,
        frames_per_second: frames as f64 / seconds.max(1e-9),
        update: latency.summary(),
        output,
    })
}
