//! The image detector's settings (`[detector.images]`: [`ImageSettings`], [`Runtime`],
//! [`MapEncoding`]), its errors ([`DetectorError`]) and its counts ([`DetectorStats`]).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::mapping::ChannelMappingError;
use crate::models::LandmarkModel;
use crate::models::landmarks::NetworkError;
use crate::tracker::{TrackerStats, TrackingSettings};
use posestream_base::CropBox;
use posestream_base::{OutOfDomain, check_real};
use posestream_msgs::HeatMapEncoding;
use posestream_msgs::names::{FRAME_ID_BYTES, check_topic_name};

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
    /// What runs it: `auto` (LiteRT when set up, else tract), `tract` (pure Rust, built
    /// in) or `litert` (Google's LiteRT, loaded at run time: 2-3 x faster on CPU).
    pub runtime: Runtime,
    /// LiteRT's `libLiteRt.so` (`site-packages/ai_edge_litert/libLiteRt.so` of
    /// `pip install 'ai-edge-litert==2.3.*'`); empty: `$POSESTREAM_LITERT`, else the one
    /// `posestream models fetch` put in the model cache.
    pub litert_library: PathBuf,
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
    /// The person detector also searches tiles of the image, this many along its
    /// longer side (overlapping, as many as cover the shorter), where people far from
    /// the camera look bigger: all on a scene's first frame, else one per search in
    /// turn beside the whole image (while nobody is followed, in one search of three);
    /// 1: the whole image only.
    pub search_tiles: u32,
    /// Propose where to look from what moves (a fixed camera's frame differences;
    /// `crate::motion`): people the person detector misses, seen from behind or far
    /// away. Off by itself while the camera moves.
    pub motion: bool,
    /// Moving blobs shorter than this (image pixels) are not proposed.
    pub motion_min_height: f64,
    /// Search for people with a whole-body detector too (`body_detector`, fetched by
    /// `posestream models fetch`): whole bodies at any distance, seen from any side,
    /// where BlazePose's face-anchored detector finds people near the camera. Skipped,
    /// with a warning, when it is not fetched.
    pub pedestrians: bool,
    /// The pedestrian detector's score below this: not a person.
    pub pedestrian_threshold: f32,
    /// The pedestrian detector also searches this many tiles along the image's longer
    /// side (each its full other side, overlapping), where people far away look
    /// bigger, beside the whole image; 1: the whole image only.
    pub pedestrian_tiles: u32,
    /// Which whole-body detector `pedestrians` searches with: `nanodet` (NanoDet-g, a
    /// COCO detector, `crate::models::nanodet`: one run on the whole image) or
    /// `ssdlite` (the SSDLite pedestrian detector, on the image and
    /// `pedestrian_tiles` tiles).
    pub body_detector: BodyDetector,
    /// NanoDet's person score below this: not a person.
    pub nanodet_threshold: f32,
    /// NanoDet's input size, `WIDTHxHEIGHT` (one of those `models fetch` converts:
    /// 416x416, 416x320, 320x416, 416x256, 256x416), or `auto`: the one nearest the
    /// search region's aspect (the image's, or `person_box`'s).
    pub nanodet_input: String,
    /// Run the searches on a thread of their own, all the time: a frame where someone is
    /// followed takes the newest sightings ready and never waits; one where nobody is
    /// (and a scene's first) waits for its own search. False: on the frame's thread,
    /// when the tracker wants boxes (every `detect_every` frames while people are
    /// followed), the frame waiting for them.
    pub search_thread: bool,
    /// How people are followed from frame to frame (`[detector.images.tracking]`).
    pub tracking: TrackingSettings,
}

/// The whole-body person detector ([`ImageSettings::body_detector`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BodyDetector {
    /// NanoDet-g (COCO), `crate::models::nanodet`.
    #[default]
    Nanodet,
    /// The SSDLite pedestrian detector, `crate::models::pedestrians`.
    Ssdlite,
}

/// The landmark model's runtime.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Runtime {
    /// LiteRT when it is set up (`posestream models fetch` fetches it, or
    /// `litert_library`, or `$POSESTREAM_LITERT`), else tract.
    #[default]
    Auto,
    /// tract, pure Rust (the rewritten models).
    Tract,
    /// Google's LiteRT with XNNPACK, loaded at run time (the original models).
    Litert,
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
            runtime: Runtime::Auto,
            litert_library: PathBuf::new(),
            models_dir: PathBuf::new(),
            mapping: PathBuf::from("builtin:detectors/blazepose.toml"),
            person_box: Vec::new(),
            presence_threshold: 0.5,
            person_detector: true,
            detection_threshold: 0.5,
            encoding: MapEncoding::Float32,
            field_of_view: 60.0,
            search_tiles: 4,
            motion: true,
            motion_min_height: 40.0,
            pedestrians: true,
            pedestrian_threshold: 0.3,
            pedestrian_tiles: 2,
            body_detector: BodyDetector::Nanodet,
            nanodet_threshold: 0.45,
            nanodet_input: "auto".into(),
            search_thread: true,
            tracking: TrackingSettings::default(),
        }
    }
}

impl ImageSettings {
    /// NanoDet's input size as configured; `None`: `auto`. `Err`: why it is none.
    pub fn nanodet_input(&self) -> Result<Option<crate::models::nanodet::InputSize>, String> {
        match self.nanodet_input.as_str() {
            "auto" => Ok(None),
            s => s.parse().map(Some),
        }
    }

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
        check_real(
            "motion_min_height",
            self.motion_min_height,
            8.0,
            100_000.0,
            false,
        )?;
        check_real(
            "pedestrian_threshold",
            f64::from(self.pedestrian_threshold),
            0.0,
            1.0,
            true,
        )?;
        check_real(
            "nanodet_threshold",
            f64::from(self.nanodet_threshold),
            0.0,
            1.0,
            true,
        )?;
        self.nanodet_input().map_err(|why| {
            OutOfDomain::new("nanodet_input", "auto or one of the converted sizes", why)
        })?;
        if !(1..=4).contains(&self.pedestrian_tiles) {
            return Err(OutOfDomain::new(
                "pedestrian_tiles",
                "an integer in 1..=4",
                self.pedestrian_tiles.to_string(),
            ));
        }
        self.tracking.check()?;
        if !(1..=8).contains(&self.search_tiles) {
            return Err(OutOfDomain::new(
                "search_tiles",
                "an integer in 1..=8",
                self.search_tiles.to_string(),
            ));
        }
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
    /// The model's path names something other than a file (a directory, a FIFO, a
    /// device).
    #[error("{}: {what}, not a regular file: a model is a file (`posestream models fetch` writes them)", path.display())]
    NotAModel {
        /// The model's path.
        path: PathBuf,
        /// What it names, in words.
        what: &'static str,
    },
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
    /// The search stage stopped (a detector failed, or its thread panicked): the run
    /// ends, never silently without searches.
    #[error("the search stage failed: {0}")]
    SearchStage(String),
}

/// What the detector did so far.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct DetectorStats {
    /// What runs the models: `tract` or `litert`.
    pub runtime: Runtime,
    /// Frames seen.
    pub frames: u64,
    /// Frames with at least one person (heat maps sent).
    pub detected: u64,
    /// Frames without anyone.
    pub no_person: u64,
    /// Heat maps sent: one per person and frame.
    pub people: u64,
    /// Landmark model runs.
    pub network_runs: u64,
    /// Seconds in the landmark runs, the crop included (summed over the runs, parallel
    /// ones too).
    pub network_seconds: f64,
    /// Person detector runs (one per region searched).
    pub detector_runs: u64,
    /// Searches for people (BlazePose's person detector and the pedestrian detector,
    /// each on the whole image and tiles).
    pub searches: u64,
    /// Searches that found someone (either detector, a confident box).
    pub detector_hits: u64,
    /// Seconds in the person detector's runs, summed over the runs (parallel ones
    /// too: two side by side take longer each than one alone).
    pub detector_seconds: f64,
    /// Pedestrian detector runs (one per region searched).
    pub pedestrian_runs: u64,
    /// Seconds in the pedestrian detector's runs, summed over the runs (parallel ones
    /// too).
    pub pedestrian_seconds: f64,
    /// Frames a person followed went without a look, by the schedule
    /// (`tracking.looks_per_frame`): their newest look's heat maps sent again, moved.
    pub waits: u64,
    /// Looks whose landmarks had collapsed to a point (a box drifted off its person).
    pub collapsed: u64,
    /// Looks at a person followed whose head jumped onto another person's: the model had
    /// taken to someone else in the box (a miss).
    pub jumps: u64,
    /// Moving blobs that nobody followed explained, looked at by the landmark model
    /// (`motion`).
    pub motion_proposals: u64,
    /// Of those, where no one new or lost was found.
    pub motion_refused: u64,
    /// Of the detectors' boxes looked at, where the landmark model found nobody (not
    /// looked at again for a while).
    pub refused_sightings: u64,
    /// Frames the search stage dropped unsearched (a newer frame came before it was
    /// free).
    pub searches_dropped: u64,
    /// Frames between a search's frame and the frame that took its sightings, summed
    /// (0 for searches on the frame's thread).
    pub search_lag_frames: u64,
    /// Seconds spent getting the images from their source, counted by the node: the
    /// wait for the next image (files are decoded ahead on another thread; a topic's
    /// images are decoded here).
    pub source_seconds: f64,
    /// The tracker's births, deaths, re-acquisitions.
    pub tracks: TrackerStats,
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

impl MapEncoding {
    /// The message encoding of this setting.
    pub fn message_encoding(self) -> HeatMapEncoding {
        match self {
            Self::Float32 => HeatMapEncoding::Float32,
            Self::Uint8 => HeatMapEncoding::Uint8,
        }
    }
}
