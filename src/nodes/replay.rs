//! Replay: a recording's heat maps through the estimator node, as fast as possible or at
//! the recorded pace; skeletons (and any ground truth in the input) to a new recording.
//!
//! What a replay does with a bad input: by default it reads on past every damaged part
//! (`posestream_msgs::salvage`), replays every readable message and reports what it
//! skipped in [`ReplayReport::skipped`]; nothing readable is [`ReplayError::Unreadable`].
//! Strict (`[replay] strict`, `--strict`): a recording cut short (a recorder killed) is
//! replayed up to its last complete message and reported in
//! [`ReplayReport::truncated`]; a corrupt record ends the replay with
//! [`ReplayError::Input`], the skeletons of everything before it kept in the output's
//! `.partial` file and the output left as it was. Either way, a file that is not a
//! recording, or holds no heat maps, is one error and nothing is written.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::config::{ReplayRate, ServiceConfig};
use super::drivers::{pace, run_estimator};
use super::frames::is_body_transform;
use super::latency::LatencySummary;
use super::publish::{EstimatorOutputs, Publishers};
use super::publish::{Taps, live_view};
use super::{EstimatorNode, Refusals, SetupError};
use crate::files::{OutputIsInput, check_output};
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::msgs::{self, HeatMaps, HeatMapsView, RosMessage, Skeleton3D};
use crate::recording::{RecordedMessage, RecordingError, RecordingReader, write_rosbag2_metadata};
use crate::streaming::StreamCounters;
use crate::transport::foxglove::LiveView;
use crate::transport::mcap::SharedRecorder;
use crate::transport::{FrameSource, Lent, Received, TransportError};

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
    /// Estimates the metric step failed on (published in dictionary units).
    pub metric_failures: u64,
    /// Where the input was cut short, if it was (every message before was replayed).
    pub truncated: Option<String>,
    /// Seconds of wall time.
    pub seconds: f64,
    /// Heat-map frames per second of wall time.
    pub frames_per_second: f64,
    /// Time the estimator node took per heat-map frame (checks, window update,
    /// skeleton messages).
    pub update: LatencySummary,
    /// The output recording, if any.
    pub output: Option<PathBuf>,
    /// The damaged parts of the input skipped (reading on past damage), if any.
    pub skipped: Option<crate::msgs::salvage::Skips>,
    /// Tracks made for people whose heat maps came without an id.
    pub unknown_id_tracks: u64,
    /// Where learning the floor stood at the end (`[estimator.metric.floor] source =
    /// "learnt"`).
    pub learnt_floor: Option<super::FloorReport>,
    /// With the floor from TF: frames the transform buffer dropped to make room.
    pub tf_evicted: u64,
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
    /// The live view could not start.
    #[error(transparent)]
    Live(#[from] TransportError),
    /// The live view's outputs could not be set up.
    #[error(transparent)]
    Service(#[from] super::errors::ServiceError),
    /// Nothing of the input could be read (reading on past damage).
    #[error("{path}: nothing could be read: {skipped}")]
    Unreadable {
        /// The input.
        path: PathBuf,
        /// What was skipped.
        skipped: String,
    },
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
    /// The pace is the recorded one because a live view is served (said when it starts).
    pub paced_for_live: bool,
}

/// Replays `input` through an estimator node set up from `config`: the estimator
/// service's loop ([`run_estimator`]) over the recording's heat maps
/// ([`RecordingFrames`]), the skeletons to the output recording. Stops early (and still
/// finalises the output) when `stop` becomes true.
pub fn replay(
    config: &ServiceConfig,
    input: &Path,
    options: &ReplayOptions,
    stop: &AtomicBool,
) -> Result<ReplayReport, ReplayError> {
    if let Some(out) = &options.record {
        check_output(out, &[input])?;
        if options.rosbag2 {
            crate::recording::check_rosbag2_metadata(out, &[input])?;
        }
    }
    let mut node = EstimatorNode::from_service_config(config)?;
    let reader = RecordingReader::open_with_limit(input, config.limits.max_record_bytes)?;
    // Past damage unless strict: what cannot be read is skipped, and said.
    let reader = if config.replay.strict {
        reader
    } else {
        reader.salvaging()?
    };
    // The recording takes the skeletons, and each image's together (`[outputs] arrays`);
    // the live view everything the estimator node publishes (markers, /tf, REP-155 as
    // configured) and the input's heat maps, truth and calibration. The live view first,
    // and a recording that was started is removed when what follows cannot start.
    let live = live_view(config)?;
    if live.is_some() && options.paced_for_live {
        tracing::info!(
            target: "posestream::live",
            "replaying at the recorded pace for the live view (--rate fast: as fast as it goes)"
        );
    }
    let recorder = options
        .record
        .as_ref()
        .map(SharedRecorder::create)
        .transpose()?;
    let mut outputs = match replay_outputs(config, &node, recorder.as_ref(), live.as_ref()) {
        Ok(o) => o,
        Err(e) => {
            if let Some(r) = recorder {
                r.abandon();
            }
            return Err(e);
        }
    };
    let topics = &config.topics;
    let passed_on = Taps {
        recorder: recorder.clone(),
        live: live.clone(),
    };
    let mut source = RecordingFrames {
        reader,
        heatmaps_topic: &topics.heatmaps,
        ground_truth: (passed_on.recorder.is_some() || passed_on.live.is_some())
            .then_some((&passed_on, topics.ground_truth.as_str())),
        truth: Vec::new(),
        shown: Vec::new(),
        live: live.as_ref(),
        camera_topic: &topics.camera_info,
        tf_topics: [&topics.tf_static, &topics.tf],
        pace: (options.rate == ReplayRate::Recorded).then(|| (Instant::now(), None)),
        stop,
        heatmaps: 0,
        frame: HeatMaps::default(),
        message: RecordedMessage::default(),
        truncated: None,
        error: None,
    };
    let start = Instant::now();
    let report = run_estimator(&mut node, &mut source, &mut outputs, stop);
    drop(outputs);
    if let Some(live) = &live {
        live.stop();
    }
    let RecordingFrames {
        reader,
        heatmaps: frames,
        truncated,
        error,
        ..
    } = source;
    if let Some(source) = error {
        if reader.messages_read() == 0 {
            // Nothing came before: there is nothing to keep.
            if let Some(r) = recorder {
                r.abandon();
            }
            return Err(source.into());
        }
        let kept = recorder.map(|r| r.finish_partial()).transpose()?;
        return Err(ReplayError::Input { source, kept });
    }
    let skipped = reader.skips().filter(|s| !s.is_empty()).cloned();
    if frames == 0 && !stop.load(Ordering::Relaxed) {
        if let Some(r) = recorder {
            r.abandon();
        }
        if let Some(skips) = skipped.filter(|_| reader.messages_read() == 0) {
            return Err(ReplayError::Unreadable {
                path: input.to_path_buf(),
                skipped: skips.summary(),
            });
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
        skeletons: report.skeletons,
        malformed: report.malformed,
        refused: report.refused,
        counters: report.counters,
        metric_failures: report.metric_failures,
        truncated,
        seconds,
        frames_per_second: frames as f64 / seconds.max(1e-9),
        update: report.update,
        output,
        skipped,
        unknown_id_tracks: report.unknown_id_tracks,
        learnt_floor: report.learnt_floor,
        tf_evicted: report.tf_evicted,
    })
}

/// A replay's outputs: the skeletons (and each image's together) to the recording, and
/// everything the estimator node publishes to the live view.
fn replay_outputs(
    config: &ServiceConfig,
    node: &EstimatorNode,
    recorder: Option<&SharedRecorder>,
    live: Option<&LiveView>,
) -> Result<EstimatorOutputs, ReplayError> {
    let topics = &config.topics;
    let recorded = Taps {
        recorder: recorder.cloned(),
        live: None,
    };
    let shown = Taps {
        recorder: None,
        live: live.cloned(),
    };
    let mut skeletons = recorded.publishers::<Skeleton3D>(&topics.skeletons)?;
    shown.add_to(&mut skeletons, &topics.skeletons)?;
    let mut arrays = Publishers::default();
    if config.outputs.arrays {
        recorded.add_to(&mut arrays, &topics.skeleton_arrays)?;
        shown.add_to(&mut arrays, &topics.skeleton_arrays)?;
    }
    let outputs = if live.is_some() {
        let mut shown_only = config.clone();
        shown_only.outputs.ros2 = false;
        shown_only.outputs.iceoryx2 = false;
        let mut none = super::middleware::Middleware::default();
        let mut o = EstimatorOutputs::open(&shown_only, &mut none, &shown, node)?;
        o.sinks.skeletons = skeletons;
        o.planner = o.planner.with_arrays(!arrays.is_empty());
        o.sinks.arrays = arrays;
        o
    } else {
        EstimatorOutputs::new(skeletons, Publishers::default(), node.bones()).with_arrays(arrays)
    };
    Ok(outputs.stamped_at_release())
}

/// A replay's input as a [`FrameSource`]: the heat maps of a recording, decoded and
/// lent one by one, at the recorded pace or as fast as they are taken; the ground
/// truth on the way is copied to the output. Where the file is cut short or corrupt is
/// kept for the report.
struct RecordingFrames<'a> {
    reader: RecordingReader,
    heatmaps_topic: &'a str,
    /// The output recording and live view, and the ground-truth topic, when recording
    /// or showing.
    ground_truth: Option<(&'a Taps, &'a str)>,
    /// A truth message encoded again (reused).
    truth: Vec<u8>,
    /// A heat-map message encoded again for the live view (reused).
    shown: Vec<u8>,
    /// The live view, which is shown the heat maps as they are read.
    live: Option<&'a LiveView>,
    /// The camera-info topic.
    camera_topic: &'a str,
    /// The transform topics (`/tf_static`, `/tf`).
    tf_topics: [&'a str; 2],
    /// When pacing: the start, and the first log time.
    pace: Option<(Instant, Option<u64>)>,
    stop: &'a AtomicBool,
    /// Heat-map messages read (decodable or not).
    heatmaps: u64,
    /// The heat-map message in hand, decoded over the one before (its buffers reused).
    frame: HeatMaps,
    /// The record in hand, read over the one before.
    message: RecordedMessage,
    truncated: Option<String>,
    error: Option<RecordingError>,
}

impl RecordingFrames<'_> {
    /// Records transforms read beside the heat maps (people's frames left out of the
    /// copy: an output recording's own body frames, replayed, are not this run's), then
    /// lends them to the estimator, before the frames after them; ones that do not decode
    /// are refused and counted.
    fn lend_transforms(
        &mut self,
        topic: &str,
        stamp_ns: u64,
        data: &[u8],
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        let tf = msgs::decode::<TFMessage>(data).map_err(|e| malformed(topic, e))?;
        if let Some((taps, _)) = self.ground_truth {
            let mut kept = tf.clone();
            kept.transforms
                .retain(|t| !is_body_transform(&t.header.frame_id, &t.child_frame_id));
            self.truth.clear();
            if !kept.transforms.is_empty() && msgs::encode_into(&kept, &mut self.truth).is_ok() {
                let _ = taps.send_encoded::<TFMessage>(topic, stamp_ns, &self.truth);
            }
        }
        let kind = if topic == self.tf_topics[0] {
            TfTopic::Static
        } else {
            TfTopic::Dynamic
        };
        take(Lent::Transforms(&tf, kind), stamp_ns);
        Ok(Received::Message((), stamp_ns))
    }

    /// Records a calibration read beside the heat maps (`data`, as it came: the output
    /// holds the calibration it was made with), then lends it to the estimator, before
    /// the frames after it; one that does not decode is refused and counted.
    fn lend_calibration(
        &mut self,
        topic: &str,
        stamp_ns: u64,
        data: &[u8],
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        if let Some((taps, _)) = self.ground_truth {
            let _ = taps.send_encoded::<CameraInfo>(topic, stamp_ns, data);
        }
        let info = msgs::decode::<CameraInfo>(data).map_err(|e| malformed(topic, e))?;
        take(Lent::Calibration(&info), stamp_ns);
        Ok(Received::Message((), stamp_ns))
    }
}

/// A record of the recording's `topic` that does not decode: refused and counted.
fn malformed(topic: &str, e: impl std::fmt::Display) -> TransportError {
    TransportError::Malformed {
        transport: "mcap",
        topic: topic.to_owned(),
        reason: e.to_string(),
    }
}

impl FrameSource for RecordingFrames<'_> {
    /// A recording's time is in its stamps.
    fn live(&self) -> bool {
        false
    }

    /// The next frame; the calibrations and transforms on the way are recorded and
    /// passed over.
    fn recv_frame(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        loop {
            let mut lent_frame = false;
            let got = self.recv_input(timeout, &mut |lent, stamp| {
                if let Lent::Frame(frame) = lent {
                    lent_frame = true;
                    take(frame, stamp);
                }
            })?;
            if lent_frame || !matches!(got, Received::Message(..)) {
                return Ok(got);
            }
        }
    }

    /// Never waits, but for the pace: the next heat-map frame, or a calibration or
    /// transforms in their place among the frames.
    fn recv_input(
        &mut self,
        _timeout: Duration,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        // The record in hand, read over the one before (its buffers reused).
        let mut msg = std::mem::take(&mut self.message);
        let got = self.next_input(&mut msg, take);
        self.message = msg;
        got
    }
}

impl RecordingFrames<'_> {
    /// [`FrameSource::recv_input`] with the record in hand `msg`.
    fn next_input(
        &mut self,
        msg: &mut RecordedMessage,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        while let Some(next) = self.reader.next_message_into(msg) {
            // A failed write (a full disk) ends the replay: its only output is the
            // recording, whose finishing then reports it.
            let failed = self
                .ground_truth
                .and_then(|(taps, _)| taps.recorder.as_ref())
                .is_some_and(SharedRecorder::failed);
            if failed || self.stop.load(Ordering::Relaxed) {
                break;
            }
            match next {
                Ok(()) => {}
                Err(e @ RecordingError::Truncated { .. }) => {
                    self.truncated = Some(e.to_string());
                    break;
                }
                Err(e) => {
                    let broken = TransportError::Broken {
                        transport: "mcap",
                        topic: self.heatmaps_topic.to_string(),
                        reason: e.to_string(),
                    };
                    self.error = Some(e);
                    return Err(broken);
                }
            }
            if let Some((start, first)) = &mut self.pace {
                let first = *first.get_or_insert(msg.log_time_ns);
                let due = Duration::from_nanos(msg.log_time_ns.saturating_sub(first));
                if !pace(*start, due, self.stop) {
                    break;
                }
            }
            if msg.topic == self.heatmaps_topic {
                self.heatmaps += 1;
                return match msgs::decode_into::<HeatMaps>(&msg.data, &mut self.frame) {
                    Ok(()) => {
                        // Encoded again for the live view: heat maps recorded before a
                        // field was added go out in the layout of the schema it
                        // announces (a viewer decoding the old bytes by the new schema
                        // fails).
                        if let Some(live) = self.live
                            && msg.schema == HeatMaps::NAME
                        {
                            self.shown.clear();
                            if msgs::encode_into(&self.frame, &mut self.shown).is_ok() {
                                let _ = live.send_encoded::<HeatMaps>(
                                    self.heatmaps_topic,
                                    msg.log_time_ns,
                                    &self.shown,
                                );
                            }
                        }
                        take(Lent::Frame(&self.frame.view()), msg.log_time_ns);
                        Ok(Received::Message((), msg.log_time_ns))
                    }
                    Err(e) => Err(malformed(&msg.topic, e)),
                };
            }
            if msg.topic == self.camera_topic && msg.schema != CameraInfo::NAME {
                // Not a calibration where one is expected: refused and counted.
                return Err(malformed(
                    &msg.topic,
                    format!("schema {:?}, expected {}", msg.schema, CameraInfo::NAME),
                ));
            }
            if msg.topic == self.camera_topic {
                // Recorded as it came (the output holds the calibration it was made
                // with), then handed to the estimator before the frames after it.
                return self.lend_calibration(&msg.topic, msg.log_time_ns, &msg.data, take);
            }
            if self.tf_topics.contains(&msg.topic.as_str()) && msg.schema == TFMessage::NAME {
                // The same (the floor), people's frames of an earlier run left out of the
                // copy.
                return self.lend_transforms(&msg.topic, msg.log_time_ns, &msg.data, take);
            }
            if let Some((taps, topic)) = self.ground_truth
                && msg.topic == topic
                && msg.schema == Skeleton3D::NAME
            {
                // Decoded and encoded again: a truth recorded before a field was
                // added to Skeleton3D goes out in the layout of the output's schema
                // (one that does not decode is left out). A failed write marks the
                // recording failed: the next message ends the replay, and finishing
                // the recording reports it.
                let truth = &mut self.truth;
                let again = msgs::decode::<Skeleton3D>(&msg.data).ok().filter(|s| {
                    truth.clear();
                    msgs::encode_into(s, truth).is_ok()
                });
                if again.is_some() {
                    let _ = taps.send_encoded::<Skeleton3D>(topic, msg.log_time_ns, truth);
                }
            }
        }
        Ok(Received::Closed)
    }
}
