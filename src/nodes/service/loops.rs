//! The loops of the services: one per node ([`run_estimator`], [`run_detector`],
//! [`run_recorder`]), both nodes in one process ([`run_pipeline`]), and the one pacing
//! function they share ([`pace`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::ServiceError;
use super::runtime::{DetectorSide, run_estimator_on_runtime_with};
use super::side_inputs::SideInputs;
use super::wiring::{
    DetectorInput, EstimatorOutputs, Publishers, Recorded, Wiring, detector_transport,
};
use crate::detector::DetectorStats;
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::nodes::camera::CameraTap;
use crate::nodes::config::{ReplayRate, ServiceConfig};
use crate::nodes::latency::{FrameClock, LatencyHistogram, LatencySummary};
use crate::nodes::{EstimatorNode, MetricTiming, Refusals};
use crate::recording::RecordingSummary;
use crate::streaming::StreamCounters;
use crate::transport::{FrameSource, Message, Received, Sink, Source, TransportError};

/// How long a source is asked to wait before the loop checks for a stop.
pub(super) const POLL: Duration = Duration::from_millis(100);

/// Waits until `due` after `start` (the pace of recorded stamps), waking at least every
/// [`POLL`] to look at `stop`; false if stopped while waiting.
pub fn pace(start: Instant, due: Duration, stop: &AtomicBool) -> bool {
    while let Some(wait) = due_wait(start, due, stop) {
        std::thread::sleep(wait);
    }
    !stop.load(Ordering::Relaxed)
}

/// How long to sleep next when waiting until `due` after `start` (at most [`POLL`], so
/// that `stop` is looked at); `None` once due or stopped.
pub(super) fn due_wait(start: Instant, due: Duration, stop: &AtomicBool) -> Option<Duration> {
    let wait = due.checked_sub(start.elapsed())?;
    (!stop.load(Ordering::Relaxed)).then(|| wait.min(POLL))
}

/// What the estimator service did.
#[derive(Debug, Clone, Serialize)]
pub struct EstimatorReport {
    /// Heat-map messages received.
    pub frames: u64,
    /// Messages refused (undecodable, inconsistent, beyond the limits, unknown joints).
    pub malformed: u64,
    /// The refusals by kind.
    pub refused: Refusals,
    /// Skeleton messages published.
    pub skeletons: u64,
    /// Sends that failed.
    pub failed_sends: u64,
    /// The window's counters.
    pub counters: StreamCounters,
    /// Estimates the metric step failed on (published in dictionary units).
    pub metric_failures: u64,
    /// What the metric step cost.
    pub metric: MetricTiming,
    /// Time per heat-map message in the estimator node.
    pub update: LatencySummary,
    /// Why the input ended early, if it did.
    pub input_error: Option<String>,
    /// Tracks the node made for people whose heat maps came without an id.
    pub unknown_id_tracks: u64,
    /// Where learning the floor stood at the end (`[estimator.metric.floor] source =
    /// "learnt"`).
    pub learnt_floor: Option<crate::nodes::FloorReport>,
}

/// Heat maps from `source` through `node` to `outputs`, until the source closes or
/// `stop` is set. A track with no frame for the window's `max_gap_seconds` is finished
/// (its owed estimates are published). Each frame is handled where the source lends it
/// (an iceoryx2 sample is not copied before the window).
pub fn run_estimator(
    node: &mut EstimatorNode,
    source: &mut dyn FrameSource,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> EstimatorReport {
    run_estimator_with(node, source, &mut SideInputs::default(), outputs, stop)
}

/// [`run_estimator`], the node also taking what waits in `side` before each frame (the
/// camera's calibration and transforms beside a source that does not carry them).
pub fn run_estimator_with(
    node: &mut EstimatorNode,
    source: &mut dyn FrameSource,
    side: &mut SideInputs,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> EstimatorReport {
    // A live source's idle track ends after the window's gap in wall time; a replayed
    // recording's gaps are in its stamps, which the window checks itself.
    let idle_limit = Duration::from_secs_f64(node.settings().max_gap_seconds);
    let live = source.live();
    let (mut frames, mut latency, mut out) = (0, LatencyHistogram::default(), Vec::new());
    let mut last_frame = Instant::now();
    let mut open_track = false;
    let mut input_error = None;
    while !stop.load(Ordering::Relaxed) {
        side.take(node);
        let accepted = node.frames_accepted();
        let mut image = None;
        let mut handle = |frame: &crate::msgs::HeatMapsView<'_>, _stamp: u64| {
            image = Some((frame.stamp_ns, frame.sequence));
            let began = Instant::now();
            // A refused message is counted and logged by the node.
            let _ = node.handle_view(frame, &mut out);
            latency.record(began.elapsed());
        };
        match source.recv_frame(POLL, &mut handle) {
            Ok(Received::Message((), stamp)) => {
                frames += 1;
                outputs.frame_stamp(stamp);
                outputs.publish(image, &mut out, node);
                // Only frames the window took keep a track alive: a stream of refused
                // frames does not hold an idle track open.
                if node.frames_accepted() > accepted {
                    last_frame = Instant::now();
                    open_track = true;
                }
                if live && open_track && last_frame.elapsed() > idle_limit {
                    node.finish(&mut out);
                    outputs.publish(None, &mut out, node);
                    open_track = false;
                }
            }
            Ok(Received::Idle) => {
                if let Some(info) = source.camera_info() {
                    // Counted and logged by the node if refused.
                    let _ = node.camera_info(&info);
                    continue;
                }
                if let Some(tf) = source.transforms() {
                    // Refusals counted by the node.
                    node.transforms(&tf);
                    continue;
                }
                // A quiet input: the image handled last is complete (its people without
                // ids are given theirs and estimated).
                node.complete_image(&mut out);
                if !out.is_empty() {
                    outputs.publish(None, &mut out, node);
                }
                outputs.flush_arrays();
                if live && open_track && last_frame.elapsed() > idle_limit {
                    node.finish(&mut out);
                    outputs.publish(None, &mut out, node);
                    open_track = false;
                }
            }
            Ok(Received::Closed) => break,
            Err(e @ (TransportError::Malformed { .. } | TransportError::BeyondLimits { .. })) => {
                node.count_refused(&e)
            }
            Err(e) => {
                // Reported by the caller, from the report.
                input_error = Some(e.to_string());
                break;
            }
        }
    }
    node.finish(&mut out);
    outputs.flush_arrays();
    outputs.publish(None, &mut out, node);
    outputs.flush();
    EstimatorReport {
        frames,
        malformed: node.malformed(),
        refused: node.refused().clone(),
        skeletons: outputs.skeletons.sent,
        failed_sends: outputs.failed_sends(),
        counters: node.counters(),
        metric_failures: node.metric_failures(),
        metric: node.metric_timing(),
        update: latency.summary(),
        input_error,
        unknown_id_tracks: node.tracks_from_unknown_ids(),
        learnt_floor: node.learnt_floor(),
    }
}

/// What the detector service did.
#[derive(Debug, Clone, Serialize)]
pub struct DetectorReport {
    /// Heat-map messages published.
    pub published: u64,
    /// Messages of the source that could not be read (skipped).
    pub malformed: u64,
    /// Sends that failed.
    pub failed_sends: u64,
    /// Why the source ended early, if it did.
    pub input_error: Option<String>,
    /// The image detector's counters (image sources only).
    pub images: Option<DetectorStats>,
}

/// Heat maps from `source` to `sinks`, at the pace of their stamps
/// ([`ReplayRate::Recorded`]) or as fast as the sinks take them, until the source
/// closes or `stop` is set.
pub fn run_detector(
    source: &mut dyn Source<HeatMaps>,
    sinks: &mut Publishers<HeatMaps>,
    rate: ReplayRate,
    stop: &AtomicBool,
) -> DetectorReport {
    let start = Instant::now();
    let (mut first, mut refused, mut input_error) = (None, Refusals::default(), None);
    while !stop.load(Ordering::Relaxed) {
        match source.recv(POLL) {
            Ok(Received::Message(maps, stamp)) => {
                if rate == ReplayRate::Recorded {
                    let first = *first.get_or_insert(stamp);
                    if !pace(
                        start,
                        Duration::from_nanos(stamp.saturating_sub(first)),
                        stop,
                    ) {
                        break;
                    }
                }
                sinks.publish_owned(maps, stamp);
            }
            Ok(Received::Idle) => {}
            Ok(Received::Closed) => break,
            Err(e @ TransportError::Malformed { .. }) => refused.note("undecodable", &e),
            Err(e @ TransportError::BeyondLimits { .. }) => refused.note("beyond-limits", &e),
            Err(e) => {
                // Reported by the caller, from the report.
                input_error = Some(e.to_string());
                break;
            }
        }
    }
    sinks.flush();
    DetectorReport {
        published: sinks.sent,
        malformed: refused.total(),
        failed_sends: sinks.failed,
        input_error,
        images: None,
    }
}

/// What the pipeline did.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineReport {
    /// The detector's side.
    pub detector: DetectorReport,
    /// The estimator's side.
    pub estimator: EstimatorReport,
    /// Seconds of wall time.
    pub seconds: f64,
    /// Frames the detector took per second of wall time.
    pub frames_per_second: f64,
    /// Image sources: frames per second from the first image in to the run's end
    /// (closing the recording included; model loading and start-up left out, as
    /// `benches/against_mediapipe.py` times MediaPipe).
    pub streaming_frames_per_second: Option<f64>,
    /// Image sources: from a decoded image to each of its newest (lag 0) skeletons
    /// published, one per person.
    pub latency: Option<LatencySummary>,
    /// Image sources: milliseconds per stage.
    pub stages: Option<Stages>,
    /// The output recording, if any.
    pub recording: Option<RecordingSummary>,
    /// Why the output recording could not be finished, if it could not (the service
    /// went on; what was written is in its `.partial` file).
    pub recording_error: Option<String>,
}

/// Where the time of an image source's frames goes, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Stages {
    /// Getting each image from its source, per image: reading and decoding a file
    /// (a video: reading ffmpeg's decoded frames); for a topic, mostly the wait for
    /// the next image.
    pub image_ms: f64,
    /// One landmark run (crop and model), per run.
    pub landmark_ms: f64,
    /// Landmark runs per image.
    pub landmark_runs_per_image: f64,
    /// One person-detector run (one region searched), per run.
    pub person_detector_ms: f64,
    /// Person-detector runs per image.
    pub person_detector_runs_per_image: f64,
    /// One pedestrian-detector run (one region searched), per run: the wall time of a
    /// search over its runs (they run in parallel).
    pub pedestrian_detector_ms: f64,
    /// Pedestrian-detector runs per image.
    pub pedestrian_detector_runs_per_image: f64,
    /// The estimator's update, per heat-map message: median (the window, its lag pass
    /// and the metric step of what it publishes).
    pub estimator_update_median_ms: f64,
    /// Of that, the metric step, per heat-map message: mean.
    pub metric_ms: f64,
    /// The metric step's iterations per estimate it adjusted: mean.
    pub metric_iterations: f64,
}

impl Stages {
    /// The stages of a run whose detector did `images` and estimator `update` (its
    /// `messages`, the metric step `metric`).
    pub fn of(
        images: &DetectorStats,
        update: &LatencySummary,
        messages: u64,
        metric: &MetricTiming,
    ) -> Self {
        let per = |total: f64, n: u64| if n == 0 { 0.0 } else { total / n as f64 };
        let frames = images.frames;
        Self {
            image_ms: 1e3 * per(images.source_seconds, frames),
            landmark_ms: 1e3 * per(images.network_seconds, images.network_runs),
            landmark_runs_per_image: per(images.network_runs as f64, frames),
            person_detector_ms: 1e3 * per(images.detector_seconds, images.detector_runs),
            person_detector_runs_per_image: per(images.detector_runs as f64, frames),
            pedestrian_detector_ms: 1e3 * per(images.pedestrian_seconds, images.pedestrian_runs),
            pedestrian_detector_runs_per_image: per(images.pedestrian_runs as f64, frames),
            estimator_update_median_ms: update.median_ms,
            metric_ms: 1e3 * per(metric.seconds, messages),
            metric_iterations: per(metric.iterations as f64, metric.adjusted),
        }
    }
}

/// Detector and estimator in one process, on a tokio runtime: the detector's source
/// (the configured one, [`detector_input`]) on a thread of its own, paced on the
/// runtime, feeds the estimator's solver thread through a bounded channel (a slow
/// estimator slows the detector down: [`DetectorSide`], [`run_estimator_on_runtime_with`]);
/// results go to the configured outputs. When recording, the heat maps are recorded
/// too, so that the recording holds the whole run (`posestream render` draws them).
pub fn run_pipeline(
    config: &ServiceConfig,
    stop: &AtomicBool,
) -> Result<PipelineReport, ServiceError> {
    let start = Instant::now();
    let mut node = EstimatorNode::from_service_config(config)?;
    let mut wiring = Wiring::open(config, detector_transport(config))?;
    // The estimator shares the cores: the detector's threads yield to it.
    let input = wiring.detector_input(config, config.detector.nice)?;
    wiring.start_recording(config)?;
    let outputs = wiring.estimator_outputs(config, &node)?;
    let DetectorInput {
        source,
        stats,
        rate,
        camera,
        clock,
    } = input;
    let mut outputs = outputs.with_clock(clock.clone());
    // The calibration assumed for images from files: published and recorded, and read
    // by the estimator before the heat maps of its first image.
    if let Some(tap) = &camera {
        tap.publish_to(wiring.camera_outputs(config)?);
    }
    // The heat maps stay in the process: recorded and shown live, not published.
    let heatmaps = wiring
        .taps
        .publishers::<HeatMaps>(&config.topics.heatmaps)?;
    // No lost beginning: the first skeletons wait (a while) for a subscriber, as the
    // detector node's heat maps do.
    wiring.wait_for_subscribers(config, &config.topics.skeletons, false);
    let mut detector = DetectorSide::spawn(source, heatmaps, rate, stop)?;
    // The estimator reads the calibration of the images (assumed, or a recording's), or
    // a live camera's own topic (recorded as it is read, so that a replay of the
    // recording is in metres too).
    let calibration = match wiring.camera_calibration(config)? {
        Some(source) => {
            let sink = wiring
                .taps
                .publishers::<CameraInfo>(&config.topics.camera_info)?;
            Some(Box::new(Recorded { source, sink }) as Box<dyn Source<CameraInfo>>)
        }
        None => None,
    };
    let mut side = SideInputs::camera(camera.as_ref().map(CameraTap::reader).or(calibration));
    side.transforms = wiring.transform_sources(config)?;
    let estimator =
        run_estimator_on_runtime_with(&mut node, &mut detector, side, &mut outputs, stop)?;
    if let Some(tap) = &camera {
        tap.close();
    }
    let mut detector = detector.conclude();
    detector.images = DetectorInput::stats_now(&stats);
    drop(outputs);
    // A recording that cannot be finished after a good run is reported, not an error:
    // the service ran (what was written is in its `.partial` file).
    let (recording, recording_error) = match wiring.conclude(detector.input_error.as_deref()) {
        Ok(summary) => (summary, None),
        Err(ServiceError::Recording(e)) if detector.input_error.is_none() => {
            (None, Some(e.to_string()))
        }
        Err(e) => return Err(e),
    };
    let seconds = start.elapsed().as_secs_f64();
    let frames = detector.images.map_or(estimator.frames, |s| s.frames);
    let stages = detector
        .images
        .as_ref()
        .map(|s| Stages::of(s, &estimator.update, estimator.frames, &estimator.metric));
    Ok(PipelineReport {
        detector,
        estimator,
        seconds,
        frames_per_second: frames as f64 / seconds.max(f64::MIN_POSITIVE),
        streaming_frames_per_second: clock
            .as_ref()
            .and_then(FrameClock::first_in)
            .map(|first| frames as f64 / first.elapsed().as_secs_f64().max(f64::MIN_POSITIVE)),
        latency: clock.map(|c| c.summary()),
        stages,
        recording,
        recording_error,
    })
}

/// One topic of a recorder: takes a message (waiting up to the given time) and writes
/// it; true if one was recorded ([`record_step`]).
pub type RecordStep = Box<dyn FnMut(Duration) -> Result<bool, TransportError> + Send>;

/// Runs the recorder `steps` (topic name, step) round-robin until `stop`, `duration` or
/// `max_messages`; returns the messages recorded per topic.
pub fn run_recorder(
    sources: &mut [(String, RecordStep)],
    stop: &AtomicBool,
    duration: Option<Duration>,
    max_messages: Option<u64>,
) -> Vec<(String, u64)> {
    let start = Instant::now();
    let mut counts = vec![0_u64; sources.len()];
    let step = Duration::from_millis(10);
    'outer: while !stop.load(Ordering::Relaxed) {
        if duration.is_some_and(|d| start.elapsed() >= d) {
            break;
        }
        for (i, (name, take)) in sources.iter_mut().enumerate() {
            match take(step) {
                Ok(true) => counts[i] += 1,
                Ok(false) => {}
                Err(e) => tracing::warn!("{name}: {e}"),
            }
            if max_messages.is_some_and(|m| counts.iter().sum::<u64>() >= m) {
                break 'outer;
            }
        }
    }
    sources.iter().map(|(n, _)| n.clone()).zip(counts).collect()
}

/// A recorder step for one topic: takes a message of `source` (waiting up to the given
/// time) and writes it to `sink`; true if one was recorded.
pub fn record_step<M: Message>(
    mut source: impl Source<M> + 'static,
    mut sink: impl Sink<M> + 'static,
) -> RecordStep {
    Box::new(move |wait| match source.recv(wait)? {
        Received::Message(m, stamp) => {
            // DDS gives no log time of its own: use the reception time, as rosbag2 does.
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(stamp, |d| u64::try_from(d.as_nanos()).unwrap_or(stamp));
            sink.send(&m, now)?;
            Ok(true)
        }
        Received::Idle | Received::Closed => Ok(false),
    })
}
