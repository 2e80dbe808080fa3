//! The detector node's image side: camera frames from the configured source (a folder,
//! a video, a recording's or a ROS 2 topic's `sensor_msgs` images) through the
//! [`ImageDetector`], as a [`Source`] of heat maps, so the detector loop and the
//! pipeline run it exactly as they run a replayed recording.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::camera::{CameraTap, assumed_camera_info};
use super::config::{DetectorSource, ServiceConfig};
use super::latency::FrameClock;
use super::shown_images::ShownImages;
use crate::detector::{DetectorStats, ImageDetector};
use crate::images::{DecodedImages, FolderSource, ImageFrame, VideoSource};
use crate::msgs::sensor::CameraInfo;
use crate::msgs::{CompressedImage, Header, HeatMapEncoding, HeatMaps, Image, Time};
use crate::transport::foxglove::LiveSink;
use crate::transport::mcap::McapSource;
use crate::transport::read_ahead::ReadAhead;
use crate::transport::ros2::Ros2;
use crate::transport::{Received, Source, TransportError};

/// How long a live camera may send nothing before the detector says so.
pub const QUIET_CAMERA: Duration = Duration::from_secs(5);

/// A live camera's images, saying once (a warning naming the commands that find out why)
/// when none has come for [`QUIET_CAMERA`]: a camera driver not running, another topic
/// name or domain; again after images came and stopped.
struct QuietCamera {
    images: Box<dyn Source<ImageFrame>>,
    topic: String,
    since: std::time::Instant,
    warned: bool,
}

impl QuietCamera {
    fn new(images: Box<dyn Source<ImageFrame>>, topic: &str) -> Self {
        Self {
            images,
            topic: topic.to_string(),
            since: std::time::Instant::now(),
            warned: false,
        }
    }
}

impl Source<ImageFrame> for QuietCamera {
    fn recv(&mut self, timeout: Duration) -> Result<Received<ImageFrame>, TransportError> {
        let received = self.images.recv(timeout)?;
        match &received {
            Received::Message(..) => {
                self.since = std::time::Instant::now();
                self.warned = false;
            }
            Received::Idle if !self.warned && self.since.elapsed() >= QUIET_CAMERA => {
                self.warned = true;
                tracing::warn!(
                    "no camera images on {topic} for {s} s: is the camera driver running? \
                     `ros2 topic list` and `ros2 topic hz {topic}` (same ROS_DOMAIN_ID) tell; \
                     another topic goes in [detector.images] topic (--config FILE)",
                    topic = self.topic,
                    s = QUIET_CAMERA.as_secs()
                );
            }
            _ => {}
        }
        Ok(received)
    }
}

/// The detector's counters, readable while it runs on another thread.
pub type SharedStats = Arc<Mutex<DetectorStats>>;

/// Heat maps computed from the frames of an image source: one message per person and
/// frame, the people of a frame in a row.
pub struct ImageHeatMaps {
    frames: Box<dyn Source<ImageFrame>>,
    /// The people of the current frame not yet handed on (at most `max_people`).
    pending: VecDeque<(HeatMaps, u64)>,
    /// The field of view assumed for the images, and where their calibration goes.
    camera: Option<(f64, CameraTap)>,
    /// A recording's own calibration of its images (`image-recording`).
    recorded: Option<RecordedCamera>,
    /// Notes when each image came in (latency to its skeletons).
    clock: Option<FrameClock>,
    detector: ImageDetector,
    joint_names: Vec<String>,
    encoding: HeatMapEncoding,
    stats: SharedStats,
    /// The live view's images, if one is served.
    shown: Option<ShownImages>,
    /// How nice the thread reading this source is made on its first read (`[detector]
    /// nice`); 0 once done.
    nice: u8,
}

impl ImageHeatMaps {
    /// `detector` on the frames of `frames`, its maps sent as `encoding`.
    pub fn new(
        frames: Box<dyn Source<ImageFrame>>,
        detector: ImageDetector,
        encoding: HeatMapEncoding,
    ) -> Self {
        Self {
            frames,
            pending: VecDeque::new(),
            camera: None,
            recorded: None,
            clock: None,
            joint_names: detector.joint_names().to_vec(),
            detector,
            encoding,
            stats: SharedStats::default(),
            shown: None,
            nice: 0,
        }
    }

    /// The same source, making the thread that reads it at least `nice` nice on its
    /// first read ([`crate::nodes::priority`]).
    pub fn with_nice(mut self, nice: u8) -> Self {
        self.nice = nice;
        self
    }

    /// The same source, showing each image on `sink` (a live view) as it comes in.
    pub fn with_shown_images(mut self, sink: LiveSink<CompressedImage>) -> Self {
        self.shown = ShownImages::start(sink)
            .map_err(|e| tracing::warn!("live view: the images cannot be shown: {e}"))
            .ok();
        self
    }

    /// The same source, giving each image the calibration of a camera with horizontal
    /// field of view `fov_deg` (degrees): written to `tap` before its heat maps.
    pub fn with_assumed_camera(mut self, fov_deg: f64, tap: CameraTap) -> Self {
        self.camera = Some((fov_deg, tap));
        self
    }

    /// The same source, giving each image the calibration `calibration` (a recording's
    /// channel) logged up to its time: written to `tap` before its heat maps.
    pub fn with_recorded_camera(
        mut self,
        calibration: Box<dyn Source<CameraInfo>>,
        tap: CameraTap,
    ) -> Self {
        self.recorded = Some(RecordedCamera {
            source: calibration,
            next: None,
            tap,
            done: false,
            handed: false,
            mismatched: 0,
        });
        self
    }

    /// The same source, noting on `clock` when each decoded image comes in.
    pub fn with_clock(mut self, clock: FrameClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// A handle on the detector's counters.
    pub fn stats(&self) -> SharedStats {
        self.stats.clone()
    }
}

impl Source<HeatMaps> for ImageHeatMaps {
    fn recv(&mut self, timeout: Duration) -> Result<Received<HeatMaps>, TransportError> {
        if let Some((maps, stamp)) = self.pending.pop_front() {
            return Ok(Received::Message(maps, stamp));
        }
        if self.nice > 0 {
            crate::nodes::priority::at_least(std::mem::take(&mut self.nice));
        }
        let began = std::time::Instant::now();
        let (frame, stamp) = match self.frames.recv(timeout)? {
            Received::Message(frame, stamp) => (frame, stamp),
            Received::Idle => return Ok(Received::Idle),
            Received::Closed => return Ok(Received::Closed),
        };
        self.detector
            .add_source_seconds(began.elapsed().as_secs_f64());
        if let Some(clock) = &self.clock {
            clock.image_in(i64::try_from(frame.stamp_ns).unwrap_or(i64::MAX));
        }
        if let Some((fov, tap)) = &self.camera {
            tap.image(assumed_camera_info(&frame, *fov), stamp);
        }
        if let Some(recorded) = &mut self.recorded {
            recorded.up_to(stamp, frame.rgb.dimensions());
        }
        if let Some(shown) = &self.shown {
            shown.show(&frame, stamp);
        }
        let header = Header {
            stamp: Time::from_nanos(i64::try_from(frame.stamp_ns).unwrap_or(i64::MAX)),
            frame_id: frame.frame_id.clone(),
        };
        // Shared with the search stage, not copied.
        let frame = std::sync::Arc::new(frame);
        let result = self.detector.detect(&frame).map(|found| {
            for d in found {
                let size = d.size as u32;
                let mut msg = HeatMaps::from_values(
                    header.clone(),
                    frame.sequence,
                    self.joint_names.clone(),
                    size,
                    size,
                    d.crop,
                    d.maps,
                    self.encoding,
                );
                msg.track_id = d.track_id;
                msg.frames_since_look = d.frames_since_look;
                self.pending.push_back((msg, stamp));
            }
        });
        if let Ok(mut stats) = self.stats.lock() {
            *stats = self.detector.stats();
        }
        if let Err(e) = result {
            return Err(TransportError::Broken {
                transport: "image detector",
                topic: frame.name.clone(),
                reason: e.to_string(),
            });
        }
        match self.pending.pop_front() {
            Some((maps, stamp)) => Ok(Received::Message(maps, stamp)),
            None => {
                tracing::debug!("{}: nobody", frame.name);
                Ok(Received::Idle)
            }
        }
    }
}

/// A recording's calibration channel, read beside its images: each `CameraInfo` goes to
/// the tap once the images reach its log time (the next one held back), so a
/// calibration that changes applies from its own time on; one for another image size
/// than the image's is skipped with a warning (a calibration of other images would put
/// every skeleton at a wrong distance). A recording without that channel is read to
/// its end once, on the first image, to find that out, and says so (dictionary units
/// then).
struct RecordedCamera {
    source: Box<dyn Source<CameraInfo>>,
    next: Option<(CameraInfo, u64)>,
    tap: CameraTap,
    done: bool,
    /// Whether a calibration went to the tap.
    handed: bool,
    /// Calibrations skipped for their image size.
    mismatched: u64,
}

impl RecordedCamera {
    /// A warning when the recording ended without a usable calibration.
    fn say_if_none(&self) {
        if !self.handed {
            tracing::warn!(
                "no usable camera calibration in the recording (topics.camera_info): \
                 skeletons in dictionary units"
            );
        }
    }

    /// Hands the calibrations logged up to `stamp` for images of `size` to the tap.
    fn up_to(&mut self, stamp: u64, size: (u32, u32)) {
        loop {
            if self.next.is_none() && !self.done {
                match self.source.recv(Duration::ZERO) {
                    Ok(Received::Message(info, at)) => self.next = Some((info, at)),
                    Ok(Received::Idle) => return,
                    Ok(Received::Closed) => {
                        self.done = true;
                        self.say_if_none();
                    }
                    Err(
                        e
                        @ (TransportError::Malformed { .. } | TransportError::BeyondLimits { .. }),
                    ) => tracing::warn!("camera calibration skipped: {e}"),
                    Err(e) => {
                        tracing::info!("{e}: no (more) calibration from the recording");
                        self.done = true;
                        self.say_if_none();
                    }
                }
                continue;
            }
            match self.next.take() {
                Some((info, at)) if at <= stamp => {
                    if (info.width, info.height) == size {
                        self.tap.image(info, at);
                        self.handed = true;
                    } else {
                        self.mismatched += 1;
                        if self.mismatched == 1 {
                            tracing::warn!(
                                "a camera calibration for {} x {} images, the images are {} x {}: \
                                 skipped (and any more like it)",
                                info.width,
                                info.height,
                                size.0,
                                size.1
                            );
                        }
                    }
                }
                later => {
                    self.next = later;
                    return;
                }
            }
        }
    }
}

/// True for a camera topic carrying `sensor_msgs/CompressedImage`
/// (`image_transport`'s naming).
pub fn is_compressed_topic(topic: &str) -> bool {
    topic.ends_with("/compressed")
}

/// Images of a file source decoded ahead of the detector.
const READ_AHEAD: usize = 2;

/// The frames of the configured image source (`detector.source`, not `recording`);
/// `ros` is needed for the `ros2` source.
pub fn image_frames(
    config: &ServiceConfig,
    ros: Option<&mut Ros2>,
) -> Result<Box<dyn Source<ImageFrame>>, TransportError> {
    let images = &config.detector.images;
    let (path, topic) = (&images.path, images.topic.as_str());
    let (limits, max_record) = (&config.limits, config.limits.max_record_bytes);
    let setup = |reason: &str| TransportError::Setup {
        transport: "images",
        what: format!("the {:?} source", config.detector.source),
        reason: reason.into(),
    };
    let needs_path = !matches!(
        config.detector.source,
        DetectorSource::Ros2 | DetectorSource::Recording
    );
    if needs_path && path.as_os_str().is_empty() {
        return Err(setup("detector.images.path is empty"));
    }
    let files: Box<dyn Source<ImageFrame>> = match config.detector.source {
        DetectorSource::Images => Box::new(FolderSource::open(
            path,
            images.fps,
            &images.frame_id,
            limits,
        )?),
        DetectorSource::Video => Box::new(VideoSource::open(path, &images.frame_id, limits)?),
        DetectorSource::ImageRecording if is_compressed_topic(topic) => {
            Box::new(DecodedImages::new(
                config
                    .replay
                    .source(McapSource::<CompressedImage>::open_with_limit(
                        path, topic, max_record,
                    )?)?,
                topic,
                limits,
            ))
        }
        DetectorSource::ImageRecording => Box::new(DecodedImages::new(
            config.replay.source(McapSource::<Image>::open_with_limit(
                path, topic, max_record,
            )?)?,
            topic,
            limits,
        )),
        DetectorSource::Ros2 => {
            // A live camera: each image as it comes (reading ahead would only queue
            // older ones in front of the newest).
            let ros = ros.ok_or_else(|| setup("ROS 2 is not opened"))?;
            let camera: Box<dyn Source<ImageFrame>> = if is_compressed_topic(topic) {
                Box::new(DecodedImages::new(
                    ros.source::<CompressedImage>(topic)?,
                    topic,
                    limits,
                ))
            } else {
                Box::new(DecodedImages::new(
                    ros.source::<Image>(topic)?,
                    topic,
                    limits,
                ))
            };
            return Ok(Box::new(QuietCamera::new(camera, topic)));
        }
        DetectorSource::Recording => return Err(setup("not an image source")),
    };
    // Files: the next images read and decoded while the detector works on this one.
    Ok(Box::new(ReadAhead::new(files, READ_AHEAD, "image-reader")?))
}
