//! Detector and estimator in one process (`posestream run`): the detector's source on a
//! thread of its own, paced on a runtime ([`DetectorSide`]), feeds the estimator's core
//! through the tokio driver; results go to the configured outputs.

use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::Serialize;

use super::detector_input::{DetectorInput, detector_transport};
use super::wiring::{Recorded, Wiring};
use crate::detector::DetectorStats;
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::nodes::camera::CameraTap;
use crate::nodes::config::{DetectorSource, ServiceConfig};
use crate::nodes::drivers::side_inputs::SideInputs;
use crate::nodes::drivers::{DetectorReport, DetectorSide, run_estimator_on_runtime_with};
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::{EstimatorNode, EstimatorReport, MetricTiming};
use crate::nodes::latency::{FrameClock, LatencySummary};
use crate::recording::RecordingSummary;
use crate::transport::Source;

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
    // A replayed recording's time is in its stamps; images and cameras are live.
    let live = config.detector.source != DetectorSource::Recording;
    let estimator =
        run_estimator_on_runtime_with(&mut node, &mut detector, side, live, &mut outputs, stop)?;
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
