//! The image detector: a camera frame in, the dictionary's heat maps with their crop
//! box and track id (a [`Detection`]; the node makes the `HeatMaps` message) out,
//! through a BlazePose landmark model.
//!
//! Where it looks, per frame (MediaPipe's tracking, without the rotation):
//! 1. the box that followed the previous frame's landmarks, while a person is tracked;
//! 2. otherwise (first frame, or after a loss) BlazePose's person detector searches the
//!    configured `person_box`, else the whole image letterboxed to a square, and its
//!    best detection's alignment keypoints place the box; if it finds nobody (or is
//!    switched off), the search region itself is the box. The landmarks found there
//!    give a tighter box and the model runs once more on it.
//!
//! The model's pose flag says whether a person is in the box; below
//! `presence_threshold` the track is lost, the frame yields no heat maps (the
//! estimator sees a gap) and the next frame starts over at step 2. Each acquisition
//! starts a new track id.

use std::path::PathBuf;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::crop::{box_from_alignment, crop_input, squared, whole_image_box};
use super::mapping::{ChannelMapping, ChannelMappingError};
use crate::images::ImageFrame;
use crate::models::landmarks::{HEATMAP_SIZE, INPUT_SIZE, LandmarkNetwork, NetworkError};
use crate::models::person::{INPUT_SIZE as PERSON_INPUT, PersonNetwork};
use crate::models::{LandmarkModel, ModelFile};
use posestream_math::camera::CropBox;
use posestream_math::error::{OutOfDomain, check_real};
use posestream_msgs::HeatMapEncoding;
use posestream_transport::ros2::check_topic_name;
use posestream_transport::shm::FRAME_ID_BYTES;

/// BlazePose's alignment landmarks: the hips' midpoint and the body circle's scale point.
const ALIGNMENT: [usize; 2] = [33, 34];
/// Values per landmark in the model's output (x, y, z, visibility, presence).
const LANDMARK_VALUES: usize = 5;

/// The image detector's settings (`[detector.images]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImageSettings {
    /// The images: a folder (source `images`), a video file (`video`) or a recording
    /// (`image-recording`).
    pub path: PathBuf,
    /// The camera topic (sources `ros2` and `image-recording`): `sensor_msgs/Image`, or
    /// `sensor_msgs/CompressedImage` when the name ends in `/compressed`
    /// (`image_transport`'s convention).
    pub topic: String,
    /// Frames per second of a folder of images (their capture times).
    pub fps: f64,
    /// Camera frame id of images from files.
    pub frame_id: String,
    /// The landmark model (`posestream models fetch` downloads it).
    pub model: LandmarkModel,
    /// Where the models are; empty: the cache (`posestream models fetch --help`).
    pub models_dir: PathBuf,
    /// From the model's channels to the dictionary's joints.
    pub mapping: PathBuf,
    /// Where to look for a person first, image pixels `[x, y, width, height]`; empty:
    /// the whole image.
    pub person_box: Vec<f64>,
    /// The model's pose flag below this: no person in the box.
    pub presence_threshold: f32,
    /// Search for people with BlazePose's person detector (else: look at the search
    /// region as a whole).
    pub person_detector: bool,
    /// The person detector's score below this: not a person.
    pub detection_threshold: f32,
    /// How the heat maps are sent: `float32`, or `uint8` (4 x smaller).
    pub encoding: MapEncoding,
    /// The horizontal field of view, degrees, assumed for images from files (folders,
    /// videos), which carry no calibration: their `sensor_msgs/CameraInfo` is that of a
    /// pinhole camera centred on the image; 0: none (skeletons in dictionary units).
    pub field_of_view: f64,
}

/// [`HeatMapEncoding`] as configured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MapEncoding {
    /// One f32 per score.
    Float32,
    /// One u8 per score.
    Uint8,
}

impl Default for ImageSettings {
    fn default() -> Self {
        Self {
            path: PathBuf::new(),
            topic: "/camera/image_raw".into(),
            fps: 30.0,
            frame_id: "camera".into(),
            model: LandmarkModel::Full,
            models_dir: PathBuf::new(),
            mapping: PathBuf::from("config/detectors/blazepose.toml"),
            person_box: Vec::new(),
            presence_threshold: 0.5,
            person_detector: true,
            detection_threshold: 0.5,
            encoding: MapEncoding::Float32,
            field_of_view: 60.0,
        }
    }
}

impl ImageSettings {
    /// The folder holding the models.
    pub fn models_dir(&self) -> PathBuf {
        if self.models_dir.as_os_str().is_empty() {
            crate::models::cache_dir()
        } else {
            self.models_dir.clone()
        }
    }

    /// Checks every value is in its domain; the error names the key
    /// (`[detector.images]` in the service configuration).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        if self.field_of_view != 0.0 {
            check_real("field_of_view", self.field_of_view, 1.0, 170.0, false)?;
        }
        check_real("fps", self.fps, 0.0, 1000.0, true)?;
        check_real(
            "presence_threshold",
            f64::from(self.presence_threshold),
            0.0,
            1.0,
            false,
        )?;
        check_real(
            "detection_threshold",
            f64::from(self.detection_threshold),
            0.0,
            1.0,
            false,
        )?;
        check_topic_name("topic", &self.topic)?;
        if self.frame_id.len() > FRAME_ID_BYTES {
            return Err(OutOfDomain::new(
                "frame_id",
                format!("at most {FRAME_ID_BYTES} bytes"),
                format!("{:?}", self.frame_id),
            ));
        }
        self.person_box().map_err(|_| {
            OutOfDomain::new(
                "person_box",
                "[] or [x, y, width, height] (finite pixels, width and height > 0)",
                format!("{:?}", self.person_box),
            )
        })?;
        Ok(())
    }

    /// The configured person box, checked.
    pub fn person_box(&self) -> Result<Option<CropBox>, DetectorError> {
        match self.person_box.as_slice() {
            [] => Ok(None),
            &[x, y, w, h] => CropBox::new(x, y, w, h)
                .map(Some)
                .map_err(|e| DetectorError::Settings(format!("person_box: {e}"))),
            other => Err(DetectorError::Settings(format!(
                "person_box needs 4 values [x, y, width, height], got {}",
                other.len()
            ))),
        }
    }
}

/// Why the image detector could not start or run.
#[derive(Debug, thiserror::Error)]
pub enum DetectorError {
    /// A setting is invalid.
    #[error("detector settings: {0}")]
    Settings(String),
    /// The model file is absent.
    #[error("{0} not found: run `posestream models fetch` first")]
    MissingModel(PathBuf),
    /// The network failed.
    #[error(transparent)]
    Network(#[from] NetworkError),
    /// The network's maps do not fit the mapping.
    #[error("heat maps: {0}")]
    Maps(Box<ChannelMappingError>),
    /// The channel mapping is unusable.
    #[error("{path}: {source}")]
    Mapping {
        /// The mapping file.
        path: PathBuf,
        /// The cause.
        source: Box<ChannelMappingError>,
    },
}

/// What the detector did so far.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct DetectorStats {
    /// Frames seen.
    pub frames: u64,
    /// Frames with a person (heat maps sent).
    pub detected: u64,
    /// Frames without one.
    pub no_person: u64,
    /// Tracks started (first frame, and after each loss).
    pub acquisitions: u64,
    /// Landmark model runs.
    pub network_runs: u64,
    /// Seconds in the landmark model.
    pub network_seconds: f64,
    /// Person detector runs.
    pub detector_runs: u64,
    /// Person detector runs that found someone.
    pub detector_hits: u64,
    /// Seconds in the person detector.
    pub detector_seconds: f64,
}

impl DetectorStats {
    /// Mean milliseconds per landmark-model run.
    pub fn mean_network_ms(&self) -> f64 {
        if self.network_runs == 0 {
            0.0
        } else {
            1e3 * self.network_seconds / self.network_runs as f64
        }
    }
}

/// One model run on one box.
struct Look {
    crop: CropBox,
    pose_flag: f32,
    next_box: Option<CropBox>,
    logits: Vec<f32>,
}

/// The detector: the landmark model, the mapping, and the tracked box.
pub struct ImageDetector {
    network: LandmarkNetwork,
    person: Option<PersonNetwork>,
    detection_threshold: f32,
    mapping: ChannelMapping,
    joint_names: Vec<String>,
    person_box: Option<CropBox>,
    threshold: f32,
    tracked: Option<CropBox>,
    track_id: u32,
    input: Vec<f32>,
    maps: Vec<f32>,
    stats: DetectorStats,
}

impl ImageDetector {
    /// Loads the configured model and mapping for a dictionary with `joint_names`.
    pub fn load(settings: &ImageSettings, joint_names: &[String]) -> Result<Self, DetectorError> {
        let path = settings.model.for_tract(&settings.models_dir());
        if !path.is_file() {
            return Err(DetectorError::MissingModel(path));
        }
        let network = LandmarkNetwork::load(&path)?;
        let person = if settings.person_detector {
            let path = ModelFile::PersonDetector.for_tract(&settings.models_dir());
            if !path.is_file() {
                return Err(DetectorError::MissingModel(path));
            }
            Some(PersonNetwork::load(&path)?)
        } else {
            None
        };
        let mapping = ChannelMapping::load(&settings.mapping, joint_names).map_err(|source| {
            DetectorError::Mapping {
                path: settings.mapping.clone(),
                source: Box::new(source),
            }
        })?;
        let mut detector = Self::new(network, mapping, joint_names, settings)?;
        detector.person = person;
        Ok(detector)
    }

    /// A detector from parts.
    pub fn new(
        network: LandmarkNetwork,
        mapping: ChannelMapping,
        joint_names: &[String],
        settings: &ImageSettings,
    ) -> Result<Self, DetectorError> {
        if mapping.joints() != joint_names.len() {
            return Err(DetectorError::Settings(format!(
                "the mapping has {} joints, the dictionary {}",
                mapping.joints(),
                joint_names.len()
            )));
        }
        if !(0.0..=1.0).contains(&settings.presence_threshold) {
            return Err(DetectorError::Settings(format!(
                "presence_threshold {} is not in [0, 1]",
                settings.presence_threshold
            )));
        }
        if !(0.0..=1.0).contains(&settings.detection_threshold) {
            return Err(DetectorError::Settings(format!(
                "detection_threshold {} is not in [0, 1]",
                settings.detection_threshold
            )));
        }
        Ok(Self {
            network,
            person: None,
            detection_threshold: settings.detection_threshold,
            mapping,
            joint_names: joint_names.to_vec(),
            person_box: settings.person_box()?,
            threshold: settings.presence_threshold,
            tracked: None,
            track_id: 0,
            input: Vec::new(),
            maps: Vec::new(),
            stats: DetectorStats::default(),
        })
    }

    /// What it did so far.
    pub fn stats(&self) -> DetectorStats {
        self.stats
    }

    /// Runs the model on `crop` of `frame`; keeps the logits.
    fn look(&mut self, frame: &ImageFrame, crop: CropBox) -> Result<Look, DetectorError> {
        let began = Instant::now();
        crop_input(&frame.rgb, &crop, INPUT_SIZE, &mut self.input);
        let out = self.network.run(&self.input)?;
        self.stats.network_runs += 1;
        self.stats.network_seconds += began.elapsed().as_secs_f64();
        // Landmarks are in input pixels: map them into the image.
        let scale = crop.width / INPUT_SIZE as f64;
        let point = |i: usize| {
            let at = i * LANDMARK_VALUES;
            let (x, y) = (out.landmarks[at], out.landmarks[at + 1]);
            [
                crop.x0 + f64::from(x) * scale,
                crop.y0 + f64::from(y) * scale,
            ]
        };
        let next_box = box_from_alignment(point(ALIGNMENT[0]), point(ALIGNMENT[1]), 16.0);
        Ok(Look {
            crop,
            pose_flag: out.pose_flag,
            next_box,
            logits: out.heatmap_logits,
        })
    }

    /// Where to look when no person is tracked: the person detector's best detection
    /// in the search region (the person box, else the whole image), else the region.
    fn search_box(&mut self, frame: &ImageFrame) -> Result<CropBox, DetectorError> {
        let region = match &self.person_box {
            Some(b) => squared(b),
            None => whole_image_box(frame.rgb.width(), frame.rgb.height()),
        };
        let Some(person) = &self.person else {
            return Ok(region);
        };
        let began = Instant::now();
        crop_input(&frame.rgb, &region, PERSON_INPUT, &mut self.input);
        for v in &mut self.input {
            *v = 2.0 * *v - 1.0;
        }
        let found = person.detect(&self.input, self.detection_threshold)?;
        self.stats.detector_runs += 1;
        self.stats.detector_seconds += began.elapsed().as_secs_f64();
        let to_image = |p: [f32; 2]| {
            [
                region.x0 + f64::from(p[0]) * region.width,
                region.y0 + f64::from(p[1]) * region.height,
            ]
        };
        let placed = found.first().and_then(|d| {
            box_from_alignment(to_image(d.keypoints[0]), to_image(d.keypoints[1]), 16.0)
        });
        if placed.is_some() {
            self.stats.detector_hits += 1;
        }
        Ok(placed.unwrap_or(region))
    }

    /// What the detector found in `frame` (the heat maps, lent until the next frame),
    /// or `None` when no person is found in it. The node makes the message.
    pub fn detect(&mut self, frame: &ImageFrame) -> Result<Option<Detection<'_>>, DetectorError> {
        self.stats.frames += 1;
        let mut look = match self.tracked {
            Some(b) => Some(self.look(frame, b)?),
            None => None,
        };
        if look.as_ref().is_none_or(|l| l.pose_flag < self.threshold) {
            // (Re)acquire: search, then refine on the box the landmarks give.
            let search = self.search_box(frame)?;
            let first = self.look(frame, search)?;
            let refined = match first.next_box {
                Some(b) if first.pose_flag >= self.threshold => Some(self.look(frame, b)?),
                _ => None,
            };
            look = Some(match refined {
                Some(second) if second.pose_flag >= self.threshold => second,
                _ => first,
            });
            if look.as_ref().is_some_and(|l| l.pose_flag >= self.threshold) {
                self.stats.acquisitions += 1;
                self.track_id = self.track_id.wrapping_add(1);
            }
        }
        let Some(look) = look.filter(|l| l.pose_flag >= self.threshold) else {
            self.tracked = None;
            self.stats.no_person += 1;
            return Ok(None);
        };
        self.tracked = look.next_box;
        self.mapping
            .apply(&look.logits, HEATMAP_SIZE, HEATMAP_SIZE, &mut self.maps)
            .map_err(|source| DetectorError::Maps(Box::new(source)))?;
        self.stats.detected += 1;
        Ok(Some(Detection {
            crop: look.crop,
            maps: &self.maps,
            size: HEATMAP_SIZE,
            track_id: self.track_id,
        }))
    }

    /// The joints of the maps (the dictionary's), in order.
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }
}

/// What the detector found in one frame.
#[derive(Debug, Clone, Copy)]
pub struct Detection<'a> {
    /// Where it looked: the crop box the maps cover, in image pixels.
    pub crop: CropBox,
    /// The heat maps, one per joint ([`ImageDetector::joint_names`]), each `size x size`,
    /// row-major, joint-major.
    pub maps: &'a [f32],
    /// Rows (and columns) of each map.
    pub size: usize,
    /// The person: a new id each time the detector (re)acquires someone.
    pub track_id: u32,
}

impl MapEncoding {
    /// The message encoding of this setting.
    pub fn message_encoding(self) -> HeatMapEncoding {
        match self {
            Self::Float32 => HeatMapEncoding::Float32,
            Self::Uint8 => HeatMapEncoding::Uint8,
        }
    }
}
