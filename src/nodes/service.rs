//! The nodes as services: the loops that move messages between [`Source`]s, the
//! [`EstimatorNode`] and [`Sink`]s. What backend each end is comes from the
//! configuration; the loops do not know.
//!
//! - [`run_detector`]: heat maps from a source (a recording replayed, or camera images
//!   through the image detector: [`detector_input`]) to publishers, at the recorded pace
//!   or as fast as they take them;
//! - [`run_estimator`]: heat maps in, skeletons (and markers) out;
//! - [`run_pipeline`]: both in one process over a bounded in-memory channel;
//! - [`run_recorder`]: ROS 2 topics into a recording.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::config::{DetectorSource, ReplayRate, ServiceConfig, Transport};
use super::images::{ImageHeatMaps, SharedStats, image_frames};
use super::latency::{LatencyHistogram, LatencySummary};
use super::markers::skeleton_markers;
use super::{EstimatorNode, Refusals, SetupError};
use crate::detector::{DetectorStats, ImageDetector};
use crate::msgs::{HeatMaps, MarkerArray, Skeleton3D};
use crate::recording::{RecordingError, RecordingSummary};
use crate::streaming::StreamCounters;
use crate::transport::mcap::{McapSource, SharedRecorder};
use crate::transport::memory;
use crate::transport::ros2::Ros2;
use crate::transport::shm::Shm;
use crate::transport::{FrameSource, Lend, Message, Received, Sink, Source, TransportError};

/// How long a source is asked to wait before the loop checks for a stop.
const POLL: Duration = Duration::from_millis(100);

/// Waits until `due` after `start` (the pace of recorded stamps), waking at least every
/// [`POLL`] to look at `stop`; false if stopped while waiting.
pub fn pace(start: Instant, due: Duration, stop: &AtomicBool) -> bool {
    while let Some(wait) = due.checked_sub(start.elapsed()) {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        std::thread::sleep(wait.min(POLL));
    }
    !stop.load(Ordering::Relaxed)
}

/// Why a service could not start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The estimator could not be set up.
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// A transport could not be set up, or broke.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The output recording could not be written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// A thread of the pipeline panicked.
    #[error("the {0} thread stopped unexpectedly")]
    Thread(&'static str),
    /// An output is one of the inputs.
    #[error(transparent)]
    OutputIsInput(#[from] crate::files::OutputIsInput),
    /// The input broke part way (a corrupt recording): the outputs are left as they
    /// were; what was recorded before is kept in the recording's `.partial` file.
    #[error("{reason}{}", kept.as_ref().map(|k| format!("; what was recorded before is in {}", k.display())).unwrap_or_default())]
    Input {
        /// What was wrong with the input.
        reason: String,
        /// The output recording's temporary file, if recording.
        kept: Option<std::path::PathBuf>,
    },
}

/// The middleware of a process: a ROS 2 node and an iceoryx2 node, each only if used.
#[derive(Default)]
pub struct Middleware {
    /// The ROS 2 participant and node.
    pub ros: Option<Ros2>,
    /// The iceoryx2 node.
    pub shm: Option<Shm>,
}

impl Middleware {
    /// Opens what `config` (plus `extra`, a transport a node reads from) needs.
    pub fn open(config: &ServiceConfig, extra: Option<Transport>) -> Result<Self, ServiceError> {
        let ros = config.outputs.ros2 || extra == Some(Transport::Ros2);
        let shm = config.outputs.iceoryx2 || extra == Some(Transport::Iceoryx2);
        Ok(Self {
            ros: ros.then(|| Ros2::new(&config.ros)).transpose()?,
            shm: shm.then(Shm::new).transpose()?,
        })
    }

    fn ros(&mut self) -> Result<&mut Ros2, TransportError> {
        self.ros.as_mut().ok_or_else(|| missing("ros2"))
    }

    fn shm(&self) -> Result<&Shm, TransportError> {
        self.shm.as_ref().ok_or_else(|| missing("iceoryx2"))
    }

    /// The heat-map source of `transport` (iceoryx2 lends its samples' scores where
    /// they are; ROS 2 decodes each message and lends it).
    pub fn heatmaps_source(
        &mut self,
        config: &ServiceConfig,
        transport: Transport,
    ) -> Result<Box<dyn FrameSource>, TransportError> {
        Ok(match transport {
            Transport::Ros2 => Box::new(Lend(
                self.ros()?.source::<HeatMaps>(&config.topics.heatmaps)?,
            )),
            Transport::Iceoryx2 => Box::new(
                self.shm()?
                    .heatmaps_source(&config.iceoryx2.heatmaps, &config.limits)?,
            ),
        })
    }
}

fn missing(transport: &'static str) -> TransportError {
    TransportError::Setup {
        transport,
        what: "the node".into(),
        reason: "not opened (enable it in [outputs] or as the input)".into(),
    }
}

/// Publishers of one message type on every configured output. A failed send is counted;
/// the first failure of each sink is logged (a full disk under a recording fails every
/// later write too), and the other sinks go on.
pub struct Publishers<M> {
    /// Each sink with its name and whether a failure of it was logged.
    sinks: Vec<(String, Box<dyn Sink<M>>, bool)>,
    /// Messages handed to every sink.
    pub sent: u64,
    /// Sends that failed (per sink).
    pub failed: u64,
}

impl<M> Default for Publishers<M> {
    fn default() -> Self {
        Self {
            sinks: Vec::new(),
            sent: 0,
            failed: 0,
        }
    }
}

impl<M> Publishers<M> {
    /// Adds a sink, named for the logs.
    pub fn add(&mut self, name: impl Into<String>, sink: Box<dyn Sink<M>>) {
        self.sinks.push((name.into(), sink, false));
    }

    /// Sinks configured.
    pub fn len(&self) -> usize {
        self.sinks.len()
    }

    /// True without sinks.
    pub fn is_empty(&self) -> bool {
        self.sinks.is_empty()
    }

    /// Sends to every sink.
    pub fn publish(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.send(message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    /// Sends to every sink, the message given up to the last one (added last: the
    /// in-memory channel moves it instead of copying it).
    pub fn publish_owned(&mut self, message: M, stamp_ns: u64) {
        self.sent += 1;
        let Some(((last_name, last, last_logged), others)) = self.sinks.split_last_mut() else {
            return;
        };
        for (name, sink, logged) in others {
            if let Err(e) = sink.send(&message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
        if let Err(e) = last.send_owned(message, stamp_ns) {
            self.failed += 1;
            Self::failure(last_name, last_logged, &e);
        }
    }

    /// Flushes every sink.
    pub fn flush(&mut self) {
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.flush() {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    fn failure(name: &str, logged: &mut bool, e: &TransportError) {
        // A sink closed by an earlier failure (reported then) is only counted.
        if !*logged && !matches!(e, TransportError::Closed { .. }) {
            *logged = true;
            tracing::warn!("{name}: {e} (further failures of this output are counted, not logged)");
        } else {
            tracing::debug!("{name}: {e}");
        }
    }
}

/// The recording of `[outputs] record`, if configured (refused if it is one of the
/// detector's inputs).
pub fn output_recording(config: &ServiceConfig) -> Result<Option<SharedRecorder>, ServiceError> {
    let path = &config.outputs.record;
    if path.as_os_str().is_empty() {
        return Ok(None);
    }
    crate::files::check_output(
        path,
        &[&config.detector.recording, &config.detector.images.path],
    )?;
    Ok(Some(SharedRecorder::create(path)?))
}

/// Publishers of `M` on `topic` / `service` for every configured output.
fn publishers<M: Message>(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    recorder: Option<&SharedRecorder>,
    topic: &str,
    shm: Option<Result<Box<dyn Sink<M>>, TransportError>>,
) -> Result<Publishers<M>, ServiceError> {
    let mut out = Publishers::default();
    if config.outputs.ros2 {
        let ros = middleware.ros()?;
        out.add(format!("ros2 {topic}"), Box::new(ros.sink::<M>(topic)?));
    }
    if let Some(sink) = shm {
        out.add(format!("iceoryx2 {topic}"), sink?);
    }
    if let Some(r) = recorder {
        out.add(format!("mcap {topic}"), Box::new(r.sink::<M>(topic)));
    }
    Ok(out)
}

/// Where the estimator's results go.
pub struct EstimatorOutputs {
    /// Skeletons.
    pub skeletons: Publishers<Skeleton3D>,
    /// Markers (empty when `[outputs] markers` is off).
    pub markers: Publishers<MarkerArray>,
    bones: Vec<(usize, usize)>,
}

impl EstimatorOutputs {
    /// The configured outputs of the estimator node (skeletons of a dictionary whose
    /// bones are `bones`).
    pub fn open(
        config: &ServiceConfig,
        middleware: &mut Middleware,
        recorder: Option<&SharedRecorder>,
        bones: Vec<(usize, usize)>,
    ) -> Result<Self, ServiceError> {
        let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
            (Some(shm), true) => Some(
                shm.skeleton_sink(&config.iceoryx2.skeletons)
                    .map(|s| Box::new(s) as Box<dyn Sink<Skeleton3D>>),
            ),
            _ => None,
        };
        let skeletons = publishers(
            config,
            middleware,
            recorder,
            &config.topics.skeletons,
            shm_sink,
        )?;
        let markers = if config.outputs.markers {
            publishers(config, middleware, recorder, &config.topics.markers, None)?
        } else {
            Publishers::default()
        };
        Ok(Self {
            skeletons,
            markers,
            bones,
        })
    }

    /// Publishes the node's skeletons and hands them back to it to be reused.
    fn publish(&mut self, skeletons: &mut Vec<Skeleton3D>, node: &mut EstimatorNode) {
        for s in skeletons.iter() {
            let stamp = u64::try_from(s.header.stamp.nanos()).unwrap_or(0);
            self.skeletons.publish(s, stamp);
            if !self.markers.is_empty() {
                self.markers
                    .publish(&skeleton_markers(s, &self.bones), stamp);
            }
        }
        node.recycle(skeletons);
    }
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
    /// Time per heat-map message in the estimator node.
    pub update: LatencySummary,
    /// Why the input ended early, if it did.
    pub input_error: Option<String>,
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
    let idle_limit = Duration::from_secs_f64(node.settings().max_gap_seconds);
    let (mut frames, mut latency, mut out) = (0, LatencyHistogram::default(), Vec::new());
    let mut last_frame = Instant::now();
    let mut open_track = false;
    let mut input_error = None;
    while !stop.load(Ordering::Relaxed) {
        let accepted = node.frames_accepted();
        let mut handle = |frame: &crate::msgs::HeatMapsView<'_>, _stamp: u64| {
            let began = Instant::now();
            // A refused message is counted and logged by the node.
            let _ = node.handle_view(frame, &mut out);
            latency.record(began.elapsed());
        };
        match source.recv_frame(POLL, &mut handle) {
            Ok(Received::Message((), _)) => {
                frames += 1;
                outputs.publish(&mut out, node);
                // Only frames the window took keep a track alive: a stream of refused
                // frames does not hold an idle track open.
                if node.frames_accepted() > accepted {
                    last_frame = Instant::now();
                    open_track = true;
                }
                if open_track && last_frame.elapsed() > idle_limit {
                    node.finish(&mut out);
                    outputs.publish(&mut out, node);
                    open_track = false;
                }
            }
            Ok(Received::Idle) => {
                if open_track && last_frame.elapsed() > idle_limit {
                    node.finish(&mut out);
                    outputs.publish(&mut out, node);
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
    outputs.publish(&mut out, node);
    outputs.skeletons.flush();
    outputs.markers.flush();
    EstimatorReport {
        frames,
        malformed: node.malformed(),
        refused: node.refused().clone(),
        skeletons: outputs.skeletons.sent,
        failed_sends: outputs.skeletons.failed + outputs.markers.failed,
        counters: node.counters(),
        update: latency.summary(),
        input_error,
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

/// The detector's configured heat-map publishers (`[outputs]`).
pub fn detector_outputs(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    recorder: Option<&SharedRecorder>,
) -> Result<Publishers<HeatMaps>, ServiceError> {
    let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
        (Some(shm), true) => Some(
            shm.heatmaps_sink(&config.iceoryx2.heatmaps)
                .map(|s| Box::new(s) as Box<dyn Sink<HeatMaps>>),
        ),
        _ => None,
    };
    publishers(
        config,
        middleware,
        recorder,
        &config.topics.heatmaps,
        shm_sink,
    )
}

/// The replay source of the detector: the heat maps of a recording, played
/// `detector.repeat` times.
pub fn recording_source(
    config: &ServiceConfig,
    path: &Path,
) -> Result<RecordedHeatMaps, TransportError> {
    Ok(RecordedHeatMaps(
        McapSource::open_with_limit(
            path,
            &config.topics.heatmaps,
            config.limits.max_record_bytes,
        )?
        .repeat(config.detector.repeat),
    ))
}

/// The heat maps of a recording, each pass of a repeated one a track of its own (its
/// track ids offset by the pass), as a detector seeing the scene again would number it.
pub struct RecordedHeatMaps(McapSource<HeatMaps>);

impl Source<HeatMaps> for RecordedHeatMaps {
    fn recv(&mut self, timeout: Duration) -> Result<Received<HeatMaps>, TransportError> {
        Ok(match self.0.recv(timeout)? {
            Received::Message(mut m, stamp) => {
                m.track_id = m.track_id.wrapping_add(self.0.pass() as u32);
                Received::Message(m, stamp)
            }
            other => other,
        })
    }
}

/// The detector node's input: heat maps from the configured source.
pub struct DetectorInput {
    /// The heat maps.
    pub source: Box<dyn Source<HeatMaps>>,
    /// The image detector's counters (image sources).
    pub stats: Option<SharedStats>,
    /// The pace: `detector.rate` for a recording of heat maps; image sources go as fast
    /// as the model (a camera paces itself).
    pub rate: ReplayRate,
}

impl DetectorInput {
    /// The image detector's counters now.
    pub fn stats_now(stats: &Option<SharedStats>) -> Option<DetectorStats> {
        stats.as_ref().and_then(|s| s.lock().ok().map(|s| *s))
    }
}

/// The detector's configured source (`detector.source`): the heat maps of
/// `detector.recording`, or the image detector on the configured images (its model
/// and mapping loaded, for the joints of `estimator.dictionary`).
pub fn detector_input(
    config: &ServiceConfig,
    middleware: &mut Middleware,
) -> Result<DetectorInput, ServiceError> {
    if config.detector.source == DetectorSource::Recording {
        return Ok(DetectorInput {
            source: Box::new(recording_source(config, &config.detector.recording)?),
            stats: None,
            rate: config.detector.rate,
        });
    }
    let dictionary =
        crate::Dictionary::load(&config.estimator.dictionary).map_err(SetupError::Dictionary)?;
    let detector = ImageDetector::load(&config.detector.images, &dictionary.skeleton().joints)
        .map_err(SetupError::Detector)?;
    let frames = image_frames(config, middleware.ros.as_mut())?;
    let encoding = config.detector.images.encoding.message_encoding();
    let source = ImageHeatMaps::new(frames, detector, encoding);
    Ok(DetectorInput {
        stats: Some(source.stats()),
        source: Box::new(source),
        rate: ReplayRate::Fast,
    })
}

/// The transport the detector's source needs opened, beyond the outputs.
pub fn detector_transport(config: &ServiceConfig) -> Option<Transport> {
    (config.detector.source == DetectorSource::Ros2).then_some(Transport::Ros2)
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
    /// The output recording, if any.
    pub recording: Option<RecordingSummary>,
    /// Why the output recording could not be finished, if it could not (the service
    /// went on; what was written is in its `.partial` file).
    pub recording_error: Option<String>,
}

/// Detector and estimator in one process: the detector (the configured source,
/// [`detector_input`]) on its own thread feeds the estimator through a bounded channel
/// (a slow estimator slows the detector down); results go to the configured outputs.
/// When recording, the heat maps are recorded too, so that the recording holds the
/// whole run (`posestream render` draws them).
pub fn run_pipeline(
    config: &ServiceConfig,
    stop: &AtomicBool,
) -> Result<PipelineReport, ServiceError> {
    let start = Instant::now();
    let mut node = EstimatorNode::from_service_config(config)?;
    let mut middleware = Middleware::open(config, detector_transport(config))?;
    let input = detector_input(config, &mut middleware)?;
    let recorder = output_recording(config)?;
    let mut outputs =
        EstimatorOutputs::open(config, &mut middleware, recorder.as_ref(), node.bones())?;
    let DetectorInput {
        mut source,
        stats,
        rate,
    } = input;
    let (sink, channel) = memory::channel::<HeatMaps>(4);
    let heatmaps_record = recorder
        .as_ref()
        .map(|r| r.sink::<HeatMaps>(&config.topics.heatmaps));
    let (detector, estimator) = std::thread::scope(|scope| {
        let detector = std::thread::Builder::new()
            .name("detector".into())
            .spawn_scoped(scope, move || {
                let mut sinks = Publishers::default();
                if let Some(r) = heatmaps_record {
                    sinks.add("mcap heat maps", Box::new(r));
                }
                // Last: the channel takes each frame by move.
                sinks.add("memory", Box::new(sink));
                // Dropping the sinks at the end closes the channel: the estimator ends.
                run_detector(&mut source, &mut sinks, rate, stop)
            });
        let mut channel = Lend(channel);
        let estimator = run_estimator(&mut node, &mut channel, &mut outputs, stop);
        // The estimator stops only when the channel closes or on `stop`; a detector
        // still blocked on a full channel then sees the receiver gone.
        drop(channel);
        let detector = detector.map(|h| h.join());
        (detector, estimator)
    });
    let mut detector = match detector {
        Ok(Ok(report)) => report,
        _ => return Err(ServiceError::Thread("detector")),
    };
    detector.images = DetectorInput::stats_now(&stats);
    drop(outputs);
    if let Some(reason) = detector.input_error.clone() {
        let kept = recorder.map(|r| r.finish_partial()).transpose()?;
        return Err(ServiceError::Input { reason, kept });
    }
    let (recording, recording_error) = match recorder.map(|r| r.finish()) {
        Some(Ok(summary)) => (Some(summary), None),
        Some(Err(e)) => (None, Some(e.to_string())),
        None => (None, None),
    };
    Ok(PipelineReport {
        detector,
        estimator,
        seconds: start.elapsed().as_secs_f64(),
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
