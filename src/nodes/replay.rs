//! Replay: a recording's heat maps through the estimator node, as fast as possible or at
//! the recorded pace; skeletons (and any ground truth in the input) to a new recording.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::config::{ReplayRate, ServiceConfig};
use super::latency::{LatencyHistogram, LatencySummary};
use super::{EstimatorNode, SetupError};
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
    /// Heat-map messages refused (undecodable, inconsistent, unknown joints).
    pub malformed: u64,
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
    /// The input could not be read, or the output written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
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
    let mut node = EstimatorNode::from_config(&config.estimator)?;
    let mut reader = RecordingReader::open(input)?;
    let mut recorder = options.record.as_ref().map(Recorder::create).transpose()?;
    let topics = &config.topics;
    let start = Instant::now();
    let mut first_log: Option<u64> = None;
    let mut skeletons = Vec::new();
    let (mut frames, mut produced, mut truncated) = (0_u64, 0_u64, None);
    let write = |recorder: &mut Option<Recorder>,
                 skeletons: &mut Vec<Skeleton3D>,
                 log_time: u64|
     -> Result<u64, RecordingError> {
        let n = skeletons.len() as u64;
        if let Some(r) = recorder.as_mut() {
            for s in skeletons.iter() {
                r.write(&topics.skeletons, log_time, s)?;
            }
        }
        skeletons.clear();
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
                tracing::warn!("{e}");
                truncated = Some(e.to_string());
                break;
            }
            Err(e) => return Err(e.into()),
        };
        last_log = msg.log_time_ns;
        if options.rate == ReplayRate::Recorded {
            let first = *first_log.get_or_insert(msg.log_time_ns);
            let due = Duration::from_nanos(msg.log_time_ns.saturating_sub(first));
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        if msg.topic == topics.heatmaps {
            frames += 1;
            let began = Instant::now();
            let handled = node.handle_encoded(&msg.data, &mut skeletons);
            latency.record(began.elapsed());
            if let Err(e) = handled {
                tracing::warn!("skipped a heat-map message: {e}");
            }
            produced += write(&mut recorder, &mut skeletons, msg.log_time_ns)?;
        } else if msg.topic == topics.ground_truth && msg.schema == Skeleton3D::NAME {
            if let Some(r) = recorder.as_mut() {
                r.write_encoded::<Skeleton3D>(&topics.ground_truth, msg.log_time_ns, &msg.data)?;
            }
        }
    }
    node.finish(&mut skeletons);
    produced += write(&mut recorder, &mut skeletons, last_log)?;
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
        counters: node.counters(),
        truncated,
        seconds,
        frames_per_second: frames as f64 / seconds.max(1e-9),
        update: latency.summary(),
        output,
    })
}
