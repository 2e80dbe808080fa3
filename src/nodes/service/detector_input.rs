//! The detector node's input as configured ([`DetectorInput`]: a recording's heat maps,
//! or the image detector on images, a video or a camera) and its heat-map publishers.

use std::path::Path;
use std::time::Duration;

use crate::detector::{DetectorStats, ImageDetector};
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::nodes::camera::CameraTap;
use crate::nodes::config::{DetectorSource, ReplayRate, ServiceConfig, Transport};
use crate::nodes::errors::ServiceError;
use crate::nodes::errors::SetupError;
use crate::nodes::images::{ImageHeatMaps, SharedStats, image_frames};
use crate::nodes::latency::FrameClock;
use crate::nodes::middleware::Middleware;
use crate::nodes::publish::configured::publishers;
use crate::nodes::publish::publishers::Publishers;
use crate::nodes::publish::taps::Taps;
use crate::nodes::shown_images::shown_images_topic;
use crate::transport::foxglove::LiveView;
use crate::transport::mcap::McapSource;
use crate::transport::{Received, Sink, Source, TransportError};

/// The detector's configured heat-map publishers (`[outputs]`).
pub fn detector_outputs(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
) -> Result<Publishers<HeatMaps>, ServiceError> {
    let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
        (Some(shm), true) => Some(
            shm.heatmaps_sink(&config.iceoryx2.heatmaps)
                .map(|s| Box::new(s) as Box<dyn Sink<HeatMaps>>),
        ),
        _ => None,
    };
    publishers(config, middleware, taps, &config.topics.heatmaps, shm_sink)
}

/// The replay source of the detector: the heat maps of a recording, played
/// `detector.repeat` times.
pub fn recording_source(
    config: &ServiceConfig,
    path: &Path,
) -> Result<RecordedHeatMaps, TransportError> {
    Ok(RecordedHeatMaps(
        config
            .replay
            .source(McapSource::open_with_limit(
                path,
                &config.topics.heatmaps,
                config.limits.max_record_bytes,
            )?)?
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
    /// The calibration assumed for images from files (`detector.images.field_of_view`),
    /// for the outputs ([`Wiring::camera_outputs`]) and an estimator in the process.
    pub camera: Option<CameraTap>,
    /// When each image came in (image sources), for the latency to its skeletons.
    pub clock: Option<FrameClock>,
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
    live: Option<&LiveView>,
    nice: u8,
) -> Result<DetectorInput, ServiceError> {
    if config.detector.source == DetectorSource::Recording {
        return Ok(DetectorInput {
            source: Box::new(recording_source(config, &config.detector.recording)?),
            stats: None,
            rate: config.detector.rate,
            camera: None,
            clock: None,
        });
    }
    let dictionary = crate::msgs::shipped::load_dictionary(&config.estimator.dictionary)
        .map_err(SetupError::Dictionary)?;
    // Loaded on a thread made `nice` first: the threads its models start (LiteRT's)
    // inherit it; rayon's workers, which run the models in parallel, are made so too.
    // The main thread's stack size: compiling the models may want more than a spawned
    // thread's 2 MiB.
    let joints = &dictionary.skeleton().joints;
    let detector = std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("detector-load".into())
            .stack_size(8 << 20)
            .spawn_scoped(scope, || {
                crate::nodes::priority::detector_threads_at_least(nice);
                ImageDetector::load(&config.detector.images, joints)
            })
            .map_err(|_| ServiceError::Thread("detector-load"))?
            .join()
            .map_err(|_| ServiceError::Thread("detector-load"))
    })?
    .map_err(SetupError::Detector)?;
    let frames = image_frames(config, middleware.ros.as_mut())?;
    let encoding = config.detector.images.encoding.message_encoding();
    let mut source = ImageHeatMaps::new(frames, detector, encoding).with_nice(nice);
    if let Some(live) = live {
        source = source.with_shown_images(live.sink(&shown_images_topic(config))?);
    }
    // Files carry no calibration: a camera is assumed (a real one has its own).
    let fov = config.detector.images.field_of_view;
    let from_files = matches!(
        config.detector.source,
        DetectorSource::Images | DetectorSource::Video
    );
    let mut camera = (from_files && fov > 0.0).then(CameraTap::default);
    if let Some(tap) = &camera {
        source = source.with_assumed_camera(fov, tap.clone());
    }
    // A recording of a camera: its own calibration channel, read beside the images.
    if config.detector.source == DetectorSource::ImageRecording {
        let tap = CameraTap::default();
        let recorded = config
            .replay
            .source(McapSource::<CameraInfo>::open_with_limit(
                &config.detector.images.path,
                &config.topics.camera_info,
                config.limits.max_record_bytes,
            )?)?;
        source = source.with_recorded_camera(Box::new(recorded), tap.clone());
        camera = Some(tap);
    }
    let clock = FrameClock::default();
    let source = source.with_clock(clock.clone());
    Ok(DetectorInput {
        stats: Some(source.stats()),
        source: Box::new(source),
        rate: ReplayRate::Fast,
        camera,
        clock: Some(clock),
    })
}

/// The transport the detector's source needs opened, beyond the outputs.
pub fn detector_transport(config: &ServiceConfig) -> Option<Transport> {
    (config.detector.source == DetectorSource::Ros2).then_some(Transport::Ros2)
}
