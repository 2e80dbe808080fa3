//! The image detector: a camera frame in, the dictionary's heat maps of every person
//! in it, each with its crop box and track id (a [`Detection`]; the node makes the
//! `HeatMaps` messages) out, through a BlazePose landmark model.
//!
//! Per frame (MediaPipe's tracking, without the rotation, for several people):
//! 1. each person followed looks at the box their previous landmarks gave, moved by
//!    their velocity; the landmark runs of different people go in parallel across
//!    cores (`rayon`);
//! 2. when the [`Tracker`] wants new boxes (nobody followed, someone just lost, every
//!    `detect_every` frames), BlazePose's person detector searches the configured
//!    `person_box`, else the whole image letterboxed to a square; its boxes (placed by
//!    each detection's alignment keypoints) are matched to lost tracks or start new
//!    ones, and the landmark model looks at each (then at the box its landmarks give,
//!    until that settles: at most three looks). Without the person detector the search region itself is
//!    the one box;
//! 3. a look whose pose flag is below `presence_threshold`, or whose landmarks
//!    collapse to a point (a box drifted off its person), is a miss: that person gets
//!    no heat maps in this frame (the estimator sees a gap); the tracker ends tracks
//!    after `lost_frames` misses and reports only confirmed ones.
//!
//! People side by side: every look has the other people's heads blacked out (a box
//! that follows a person cut off at the waist holds their neighbour too), a look whose
//! head jumped onto another person's is a miss, and a low-scoring detection on nobody
//! starts a track only when the landmark model confirms a face there (`confirms`).
//!
//! A change of image size is a new scene: every track ends (a folder of unrelated
//! photos).

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::crop::{
    box_from_alignment, crop_input, crop_input_signed, mask_input, squared, tiles, whole_image_box,
};
use super::mapping::{ChannelMapping, ChannelMappingError};
use crate::images::ImageFrame;
use crate::models::landmarks::{HEATMAP_SIZE, INPUT_SIZE, LandmarkNetwork, NetworkError};
use crate::models::litert::{Landmarks, LiteRt};
use crate::models::pedestrians::{INPUT_SIZE as PEDESTRIAN_INPUT, Pedestrian, PedestrianNetwork};
use crate::models::person::{
    Detection as PersonDetection, INPUT_SIZE as PERSON_INPUT, PersonNetwork,
};
use crate::models::{LandmarkModel, ModelFile};
use crate::motion::Motion;
use crate::tracker::{Assignment, Observation, Tracker, TrackerStats, TrackingSettings, iou};
use posestream_base::CropBox;
use posestream_base::{OutOfDomain, check_real};
use posestream_msgs::HeatMapEncoding;
use posestream_msgs::names::{FRAME_ID_BYTES, check_topic_name};

/// BlazePose's alignment landmarks: the hips' midpoint and the body circle's scale point.
const ALIGNMENT: [usize; 2] = [33, 34];
/// Values per landmark in the model's output (x, y, z, visibility, presence).
const LANDMARK_VALUES: usize = 5;
/// BlazePose's body landmarks (the rest are auxiliary).
const BODY_LANDMARKS: usize = 33;
/// Landmarks spread over less than this fraction of the crop's side: collapsed to a
/// point, the box has drifted off its person.
const COLLAPSED_SPREAD: f64 = 0.05;
/// Person-detector boxes from different search regions overlapping more than this
/// (IoU) are one person.
const SAME_PERSON_IOU: f64 = 0.4;
/// Landmarks closer than this fraction of the body's extent, on average: one person.
const SAME_PERSON_DISTANCE: f64 = 0.15;
/// Faces closer than this fraction of the body's extent, on average: one person.
const SAME_FACE_DISTANCE: f64 = 0.3;
/// BlazePose's face landmarks (nose, eyes, ears, mouth) come first.
const FACE_LANDMARKS: usize = 11;
/// Moving blobs nobody followed explains, looked at per frame at most.
const MOTION_LOOKS: usize = 4;
/// A moving blob where the landmark model found nobody is not looked at again for this
/// many frames.
const REFUSED_FRAMES: u64 = 15;
/// Motion's looks are judged over this many frames...
const MOTION_WINDOW: u64 = 60;
/// ... once there are this many looks in them...
const MOTION_TRIAL: usize = 20;
/// ... and found someone in fewer than this share of them, motion is not looked at until
/// they age out of the window.
const MOTION_YIELD: f64 = 0.1;
/// A proposal overlapping a refused place by more than this (IoU) is that place (a
/// neighbour's crop overlaps by about 0.5).
const REFUSED_IOU: f64 = 0.7;
/// A head's side over the person's height.
const HEAD_PER_HEIGHT: f64 = 0.15;
/// Two pedestrian boxes (of overlapping tiles) overlapping more than this: one person.
const BODY_NMS_IOU: f64 = 0.5;
/// The margin around a pedestrian box kept visible to the landmark model (the rest of
/// its crop blacked out), as a share of the box's height: across, and half that
/// above and below.
const BODY_MARGIN: f64 = 0.1;
/// A newcomer's look whose body landmarks lie within someone's (this share of them)...
const PART_INSIDE: f64 = 0.9;
/// ... and span at most this share of their height is a part of them (`part_of`).
const PART_HEIGHT: f64 = 0.75;
/// While nobody is followed (a search every frame) the pedestrian detector runs every
/// this many times `detect_every` frames (BlazePose's, 4 x cheaper, searches every
/// frame): bikes.mp4, a cyclist in 80 of 250 frames, lost 15 % of its frames per
/// second to it at 1 x; at 4 x, 24 pedestrian runs instead of 42 and 3-8 % more frames
/// per second, but sample.mp4's recall went from 0.55 to 0.50.
const EMPTY_SCENE_SEARCHES: u64 = 2;
/// While nobody is followed (a search every frame) BlazePose's detector searches a tile
/// besides the whole image in one search of this many (the first of a scene, and while
/// someone is followed, every one): bikes.mp4 (scenes of nobody, cut after cut) 383 ->
/// 258 detector runs, 225 -> 169 landmark runs, 37.3 -> 43.8-50.0 frames/s; the footage
/// bench: vtest.avi unchanged, sample.mp4 recall 0.55 = 0.55, precision 0.97 -> 0.95,
/// IDF1 0.47 -> 0.49.
const EMPTY_SCENE_TILE_EVERY: u64 = 3;
/// Pedestrian boxes shorter than this (image pixels) are not looked at.
const MIN_BODY_HEIGHT: f64 = 20.0;
/// Looks at most at a newly found person: the detector's box, then the landmarks' box
/// until it settles.
const ACQUISITION_LOOKS: usize = 3;
/// A landmark box overlapping the box looked at by more than this (IoU) has settled.
const SETTLED_IOU: f64 = 0.7;
/// The head's side over the face landmarks' extent (nose, eyes, ears, mouth: the ears
/// span about two thirds of a head).
const HEAD_PER_FACE: f64 = 2.0;
/// A face the landmark model finds and the person detector's head box differ in size by
/// at most this factor when they are the same head.
const HEAD_SIZE_RATIO: f64 = 3.0;
/// A lost person's head is blacked out in the others' looks for this many frames after
/// they were last seen (then it may be where someone else is now).
const MASKED_HEAD_FRAMES: u64 = 2;

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
    /// Search for people with the pedestrian detector too (`crate::models::pedestrians`,
    /// fetched by `posestream models fetch`): whole bodies at any distance, seen from
    /// any side, where BlazePose's face-anchored detector finds people near the camera.
    /// Skipped, with a warning, when it is not fetched.
    pub pedestrians: bool,
    /// The pedestrian detector's score below this: not a person.
    pub pedestrian_threshold: f32,
    /// The pedestrian detector also searches this many tiles along the image's longer
    /// side (each its full other side, overlapping), where people far away look
    /// bigger, beside the whole image; 1: the whole image only.
    pub pedestrian_tiles: u32,
    /// How people are followed from frame to frame (`[detector.images.tracking]`).
    pub tracking: TrackingSettings,
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
            tracking: TrackingSettings::default(),
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

/// One model run on one box.
struct Look {
    crop: CropBox,
    pose_flag: f32,
    /// The box the landmarks give for the next frame.
    next_box: Option<CropBox>,
    /// The body landmarks' extent over the crop's side.
    spread: f64,
    /// The body landmarks, image pixels.
    points: Vec<[f64; 2]>,
    /// Where the head is: a square around the face landmarks, image pixels.
    face: Option<CropBox>,
    logits: Vec<f32>,
    seconds: f64,
}

impl Look {
    /// Where the person is, if there is one: the pose flag at least `threshold`, a box
    /// from the landmarks, the landmarks not collapsed.
    fn person(&self, threshold: f32) -> Option<CropBox> {
        if self.pose_flag >= threshold && self.spread >= COLLAPSED_SPREAD {
            self.next_box
        } else {
            None
        }
    }
}

/// Runs `network` (its `worker`; `None`: the lone run's model, on every core with
/// LiteRT) on `crop` of `frame` with the other people's heads `masks` blacked out,
/// `input` its scratch.
fn look(
    network: &Landmarks,
    worker: Option<usize>,
    frame: &ImageFrame,
    crop: CropBox,
    masks: &[CropBox],
    input: &mut Vec<f32>,
) -> Result<Look, DetectorError> {
    let began = Instant::now();
    crop_input(&frame.rgb, &crop, INPUT_SIZE, input);
    for m in masks {
        mask_input(input, &crop, INPUT_SIZE, m);
    }
    let out = network.run(worker, input)?;
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
    let points: Vec<[f64; 2]> = (0..BODY_LANDMARKS).map(point).collect();
    let (lo, hi) = extent(&points);
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let face = head_box(&points[..FACE_LANDMARKS]);
    Ok(Look {
        crop,
        pose_flag: out.pose_flag,
        next_box,
        spread: if extent.is_finite() {
            extent / crop.width
        } else {
            0.0
        },
        points,
        face,
        logits: out.heatmap_logits,
        seconds: began.elapsed().as_secs_f64(),
    })
}

/// The head around face landmarks `face`: a square twice their extent, centred on them.
fn head_box(face: &[[f64; 2]]) -> Option<CropBox> {
    let (lo, hi) = extent(face);
    let side = HEAD_PER_FACE * (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    CropBox::new(centre[0] - 0.5 * side, centre[1] - 0.5 * side, side, side).ok()
}

/// The heads of other people to black out in a look at a person whose head is `own`:
/// every one of `heads` that does not overlap it (a head that does may be the person's
/// own, seen by another track); none when `own` is unknown (any might be theirs).
fn masks_for(own: Option<&CropBox>, heads: impl Iterator<Item = CropBox>) -> Vec<CropBox> {
    match own {
        Some(own) => heads.filter(|h| iou(own, h) <= 0.0).collect(),
        None => Vec::new(),
    }
}

/// A head seen at `after` is not the one seen at `before` the frame before but one of
/// the `others` (people followed): their centres are more than `before`'s side apart (a
/// head moves far less between frames) and `after`'s lies in another's head box. The
/// landmark model looking at a box that holds two people can jump to the other one (a
/// person cut off at the waist has a body circle, and so a box, several times their
/// width).
fn head_jump<'a>(
    before: &CropBox,
    after: &CropBox,
    mut others: impl Iterator<Item = &'a CropBox>,
) -> bool {
    let (a, b) = (centre(before), centre(after));
    (a[0] - b[0]).hypot(a[1] - b[1]) > before.width && others.any(|h| contains(h, b))
}

/// Two sightings of one search are one person: two bodies never (the pedestrian
/// detector's boxes are thinned already, and the crops of people side by side overlap
/// much), a body and a face when the face's head lies in the body's upper half, two
/// faces' crops when they overlap more than `SAME_PERSON_IOU`.
fn same_sighting(a: &Sighting, b: &Sighting) -> bool {
    match (a.body, b.body) {
        (Some(_), Some(_)) => false,
        (Some(body), None) | (None, Some(body)) => {
            let other = if a.body.is_some() { b } else { a };
            let upper = CropBox {
                height: 0.5 * body.height,
                ..body
            };
            other.head.is_some_and(|h| contains(&upper, centre(&h)))
        }
        (None, None) => iou(&a.observation.region, &b.observation.region) > SAME_PERSON_IOU,
    }
}

/// `part`'s body landmarks lie within `whole`'s body (their extent grown by a tenth of
/// its height), nearly all of them, and span at most `PART_HEIGHT` of its height: a
/// look at a part of someone already found (their legs), not a person.
fn part_of(whole: &Look, part: &Look) -> bool {
    let n = BODY_LANDMARKS
        .min(whole.points.len())
        .min(part.points.len());
    if n == 0 {
        return false;
    }
    let (lo, hi) = extent(&whole.points[..n]);
    let height = hi[1] - lo[1];
    let margin = 0.1 * height;
    let (plo, phi) = extent(&part.points[..n]);
    let inside = part.points[..n]
        .iter()
        .filter(|p| {
            (lo[0] - margin..=hi[0] + margin).contains(&p[0])
                && (lo[1] - margin..=hi[1] + margin).contains(&p[1])
        })
        .count();
    height > 0.0
        && phi[1] - plo[1] <= PART_HEIGHT * height
        && inside as f64 >= PART_INSIDE * n as f64
}

/// The parts of `crop` outside `body` grown by a margin (a person's limbs reach out of
/// the detector's box): at most four strips, image pixels.
fn around(body: &CropBox, crop: &CropBox) -> Vec<CropBox> {
    let (mx, my) = (BODY_MARGIN * body.height, 0.5 * BODY_MARGIN * body.height);
    let (x0, x1) = (body.x0 - mx, body.x0 + body.width + mx);
    let (y0, y1) = (body.y0 - my, body.y0 + body.height + my);
    let (cx1, cy1) = (crop.x0 + crop.width, crop.y0 + crop.height);
    [
        (crop.x0, crop.y0, x0 - crop.x0, crop.height),
        (x1, crop.y0, cx1 - x1, crop.height),
        (crop.x0, crop.y0, crop.width, y0 - crop.y0),
        (crop.x0, y1, crop.width, cy1 - y1),
    ]
    .into_iter()
    .filter_map(|(x, y, w, h)| CropBox::new(x, y, w, h).ok())
    .collect()
}

/// Overlap of two boxes given as `[x0, y0, x1, y1]`.
fn box_iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let w = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let h = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = w * h;
    let union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// The centre of `b`.
fn centre(b: &CropBox) -> [f64; 2] {
    [b.x0 + 0.5 * b.width, b.y0 + 0.5 * b.height]
}

/// Whether `p` lies in `b`.
fn contains(b: &CropBox, p: [f64; 2]) -> bool {
    (b.x0..=b.x0 + b.width).contains(&p[0]) && (b.y0..=b.y0 + b.height).contains(&p[1])
}

/// Whether `p` lies within the extent of `look`'s body landmarks.
fn within_body(look: &Look, p: [f64; 2]) -> bool {
    let (lo, hi) = extent(&look.points);
    (lo[0]..=hi[0]).contains(&p[0]) && (lo[1]..=hi[1]).contains(&p[1])
}

/// A look confirms a low-scoring detection (a candidate newcomer): the landmark model
/// found a face where the person detector saw one (its centre inside the detector's
/// head box), of a like size (within a factor `HEAD_SIZE_RATIO`), and not within the
/// body of anyone in `present` (their landmarks' extent). The lite model, shown a
/// hand held out that the detector took for a face at a low score, finds a whole
/// small person there, face on the hand, with a confident pose flag.
fn confirms<'a>(
    head: Option<&CropBox>,
    look: &Look,
    mut present: impl Iterator<Item = &'a Look>,
) -> bool {
    let (Some(head), Some(face)) = (head, look.face.as_ref()) else {
        return false;
    };
    let at = centre(face);
    let ratio = face.width / head.width;
    contains(head, at)
        && (1.0 / HEAD_SIZE_RATIO..=HEAD_SIZE_RATIO).contains(&ratio)
        && !present.any(|p| within_body(p, at))
}

/// The corners of the box around `points`.
fn extent(points: &[[f64; 2]]) -> ([f64; 2], [f64; 2]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Two looks found the same person: their faces (BlazePose's landmarks 0-10) within
/// `SAME_FACE_DISTANCE` (about half a metre for a standing body), or all their body
/// landmarks within `SAME_PERSON_DISTANCE`, of the smaller body's extent of each other
/// on average. The face is the test that holds for a body seen in part (a portrait):
/// two looks at it guess the unseen rest of it differently. Two people whose faces
/// come that close in the image (one passing behind the other) are one track until
/// they part; the other is then re-acquired.
fn same_person(a: &Look, b: &Look) -> bool {
    let extent = (a.spread * a.crop.width).min(b.spread * b.crop.width);
    let n = a.points.len().min(b.points.len());
    if n <= FACE_LANDMARKS || extent.is_nan() || extent <= 0.0 {
        return false;
    }
    let distance =
        |k: usize| (a.points[k][0] - b.points[k][0]).hypot(a.points[k][1] - b.points[k][1]);
    let face = (0..FACE_LANDMARKS).map(distance).sum::<f64>() / FACE_LANDMARKS as f64;
    let body = (0..n).map(distance).sum::<f64>() / n as f64;
    tracing::trace!("same person? face {face:.1} px, body {body:.1} px, extent {extent:.1} px");
    face < SAME_FACE_DISTANCE * extent || body < SAME_PERSON_DISTANCE * extent
}

/// A person a detector saw: their box for the landmark model, their head's box, and
/// (the pedestrian detector's) their body's.
#[derive(Debug, Clone, Copy)]
struct Sighting {
    observation: Observation,
    head: Option<CropBox>,
    body: Option<CropBox>,
}

/// A pedestrian detector's box: its score and `[x0, y0, x1, y1]`, image pixels.
type ScoredBox = (f32, [f64; 4]);

/// One detector run of a search: the detector and the region it looks at.
#[derive(Clone, Copy)]
enum Run<'a> {
    Faces(&'a PersonNetwork, CropBox),
    Bodies(&'a PedestrianNetwork, CropBox),
}

/// What one run of a search found.
enum Seen {
    Faces(Vec<Sighting>),
    Bodies(Vec<ScoredBox>),
}

/// Whether a search (not a scene's first) looks at a tile beside the whole image: every
/// one while someone is `followed`, else the first of every `EMPTY_SCENE_TILE_EVERY`
/// (`empty`: searches in a row while nobody is followed, this one included).
fn a_tile_too(followed: bool, empty: u64) -> bool {
    followed || empty % EMPTY_SCENE_TILE_EVERY == 1
}

/// The person detector's people in `region` (found by their face), each with the
/// landmark model's box from the detection's alignment points and their head, image
/// pixels.
fn faces_in(region: &CropBox, found: &[PersonDetection]) -> Vec<Sighting> {
    let to_image = |p: [f32; 2]| {
        [
            region.x0 + f64::from(p[0]) * region.width,
            region.y0 + f64::from(p[1]) * region.height,
        ]
    };
    found
        .iter()
        .filter_map(|d| {
            let [x, y] = to_image([d.centre[0] - 0.5 * d.size[0], d.centre[1] - 0.5 * d.size[1]]);
            let head = CropBox::new(
                x,
                y,
                f64::from(d.size[0]) * region.width,
                f64::from(d.size[1]) * region.height,
            )
            .ok();
            box_from_alignment(to_image(d.keypoints[0]), to_image(d.keypoints[1]), 16.0).map(
                |region| Sighting {
                    observation: Observation {
                        region,
                        score: d.score,
                    },
                    head,
                    body: None,
                },
            )
        })
        .collect()
}

/// The pedestrian detector's boxes in `region`, image pixels.
fn bodies_in(region: &CropBox, people: &[Pedestrian]) -> Vec<ScoredBox> {
    let x = |v: f32| region.x0 + f64::from(v) * region.width;
    let y = |v: f32| region.y0 + f64::from(v) * region.height;
    people
        .iter()
        .map(|p| {
            (
                p.score,
                [x(p.min[0]), y(p.min[1]), x(p.max[0]), y(p.max[1])],
            )
        })
        .collect()
}

/// Where a person's head was last seen, and the frame.
struct Head {
    id: u32,
    region: CropBox,
    seen: u64,
}

/// One person's heat maps in the current frame.
struct Found {
    crop: CropBox,
    track_id: u32,
    maps: Vec<f32>,
}

/// The detector: the landmark model, the mapping, and the people tracked.
pub struct ImageDetector {
    network: Landmarks,
    person: Option<PersonNetwork>,
    /// The pedestrian detector (`None`: off, or not fetched).
    pedestrians: Option<PedestrianNetwork>,
    pedestrian_threshold: f32,
    pedestrian_tiles: u32,
    /// The frame the pedestrian detector last ran (see `EMPTY_SCENE_SEARCHES`).
    last_pedestrians: Option<u64>,
    detection_threshold: f32,
    mapping: ChannelMapping,
    joint_names: Vec<String>,
    person_box: Option<CropBox>,
    threshold: f32,
    search_tiles: u32,
    tracker: Tracker,
    /// The image size of the scene, and the frame it began.
    scene: Option<(u32, u32)>,
    scene_start: u64,
    /// The tile the next search looks at besides the whole image.
    next_tile: usize,
    /// Searches in a row while nobody is followed (0 while someone is).
    empty_searches: u64,
    /// Each person's head where it was last seen: blacked out in the other people's
    /// looks (a box that holds two people is looked at for the one it was given).
    heads: Vec<Head>,
    /// The frame a candidate (a low-scoring box) was last looked at: one is looked at
    /// every `detect_every` frames at most (low scores on a background would otherwise
    /// cost a look a search, and a search runs every frame while nobody is followed).
    last_candidate: Option<u64>,
    candidate_every: u64,
    /// What moves (`None`: `motion` off).
    motion: Option<Motion>,
    motion_min_height: f64,
    /// Moving blobs looked at where nobody was, and when.
    refused: Vec<(CropBox, u64)>,
    /// Motion's looks in the last `MOTION_WINDOW` frames: when, and whether someone was
    /// there.
    motion_looks: Vec<(u64, bool)>,
    /// One model input per run in parallel (landmark looks, a search's detector runs).
    inputs: Vec<Vec<f32>>,
    /// The people of the current frame (their maps buffers reused).
    found: Vec<Found>,
    found_len: usize,
    stats: DetectorStats,
}

impl ImageDetector {
    /// Loads the configured model and mapping for a dictionary with `joint_names`.
    pub fn load(settings: &ImageSettings, joint_names: &[String]) -> Result<Self, DetectorError> {
        let dir = settings.models_dir();
        let existing = |path: std::path::PathBuf| {
            if path.is_file() {
                Ok(path)
            } else {
                Err(DetectorError::MissingModel(path))
            }
        };
        // LiteRT's models: present, and the package's bytes (LiteRT does not verify them).
        let checked = |file: ModelFile| {
            let path = existing(file.original(&dir))?;
            file.checked_original(&dir).map_err(|reason| {
                DetectorError::Network(NetworkError::LiteRt {
                    context: format!("loading {}", path.display()),
                    reason,
                })
            })
        };
        let litert = match settings.runtime {
            Runtime::Tract => None,
            Runtime::Litert => Some(Self::litert(settings, &dir)?),
            Runtime::Auto => match Self::litert(settings, &dir) {
                Ok(runtime) => Some(runtime),
                Err(DetectorError::Settings(_)) => None,
                Err(e) => {
                    tracing::warn!("LiteRT cannot run the models ({e}): tract runs them");
                    None
                }
            },
        };
        // The pedestrian detector: one converted file for both runtimes, checked as
        // fetched before LiteRT parses it.
        let pedestrians_path = crate::models::fetch::cached_pedestrians(&dir);
        let pedestrians = settings.pedestrians
            && {
                let present = pedestrians_path.is_file();
                if !present {
                    tracing::warn!(
                        "the pedestrian detector is not fetched ({} is missing: `posestream models fetch` \
                     fetches it): people far away or seen from behind are found where they move only",
                        pedestrians_path.display()
                    );
                }
                present
            };
        let checked_pedestrians = || {
            crate::models::fetch::checked_pedestrians(&dir).map_err(|reason| {
                DetectorError::Network(NetworkError::LiteRt {
                    context: format!("loading {}", pedestrians_path.display()),
                    reason,
                })
            })
        };
        let (network, person, pedestrians) = match litert {
            None => {
                let landmarks = LandmarkNetwork::load(&existing(settings.model.for_tract(&dir))?)?;
                let person = if settings.person_detector {
                    let path = existing(ModelFile::PersonDetector.for_tract(&dir))?;
                    Some(PersonNetwork::load(&path)?)
                } else {
                    None
                };
                let pedestrians = if pedestrians {
                    // The same file as LiteRT's, checked as fetched: tract's TFLite
                    // reader trusts the indices in a file.
                    Some(PedestrianNetwork::load(&checked_pedestrians()?)?)
                } else {
                    None
                };
                (Landmarks::Tract(landmarks), person, pedestrians)
            }
            Some(runtime) => {
                // One compiled model per worker of the parallel runs.
                let workers = rayon::current_num_threads().clamp(1, 8);
                let path = checked(ModelFile::Landmark(settings.model))?;
                let landmarks = Landmarks::litert(&runtime, &path, workers)?;
                let person = if settings.person_detector {
                    let path = checked(ModelFile::PersonDetector)?;
                    Some(PersonNetwork::load_litert(&runtime, &path, workers)?)
                } else {
                    None
                };
                let pedestrians = if pedestrians {
                    Some(PedestrianNetwork::load_litert(
                        &runtime,
                        &checked_pedestrians()?,
                        workers,
                    )?)
                } else {
                    None
                };
                (landmarks, person, pedestrians)
            }
        };
        let mapping = ChannelMapping::load(&settings.mapping, joint_names).map_err(|source| {
            DetectorError::Mapping {
                path: settings.mapping.clone(),
                source: Box::new(source),
            }
        })?;
        let mut detector = Self::new(network, mapping, joint_names, settings)?;
        detector.person = person;
        detector.pedestrians = pedestrians;
        Ok(detector)
    }

    /// LiteRT's library as configured (`litert_library`, else `$POSESTREAM_LITERT`, else
    /// the model cache's), loaded. `Settings` error: none is set up.
    fn litert(settings: &ImageSettings, dir: &Path) -> Result<LiteRt, DetectorError> {
        let library = match LiteRt::library_path(&settings.litert_library) {
            Some(path) => path,
            None => {
                let cached = crate::models::fetch::cached_litert(dir);
                if !cached.exists() {
                    return Err(DetectorError::Settings(format!(
                        "runtime \"litert\" needs LiteRT: `posestream models fetch` sets it up in {}, \
                         or name a libLiteRt.so of pip install 'ai-edge-litert==2.3.*' in litert_library \
                         (or $POSESTREAM_LITERT)",
                        dir.display()
                    )));
                }
                crate::models::fetch::checked_litert(dir).map_err(|reason| {
                    DetectorError::Network(NetworkError::LiteRt {
                        context: format!("loading {}", cached.display()),
                        reason,
                    })
                })?
            }
        };
        Ok(LiteRt::load(&library)?)
    }

    /// A detector from parts.
    pub fn new(
        network: Landmarks,
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
        settings
            .check()
            .map_err(|e| DetectorError::Settings(e.to_string()))?;
        let runtime = match &network {
            Landmarks::Tract(_) => Runtime::Tract,
            Landmarks::LiteRt { .. } => Runtime::Litert,
        };
        Ok(Self {
            network,
            person: None,
            pedestrians: None,
            pedestrian_threshold: settings.pedestrian_threshold,
            pedestrian_tiles: settings.pedestrian_tiles,
            last_pedestrians: None,
            detection_threshold: settings.detection_threshold,
            mapping,
            joint_names: joint_names.to_vec(),
            person_box: settings.person_box()?,
            threshold: settings.presence_threshold,
            search_tiles: settings.search_tiles,
            tracker: Tracker::new(settings.tracking.clone(), settings.detection_threshold),
            scene: None,
            scene_start: 0,
            next_tile: 0,
            empty_searches: 0,
            heads: Vec::new(),
            last_candidate: None,
            candidate_every: u64::from(settings.tracking.detect_every),
            motion: settings.motion.then(Motion::new),
            motion_min_height: settings.motion_min_height,
            refused: Vec::new(),
            motion_looks: Vec::new(),
            inputs: Vec::new(),
            found: Vec::new(),
            found_len: 0,
            stats: DetectorStats {
                runtime,
                ..DetectorStats::default()
            },
        })
    }

    /// What it did so far.
    pub fn stats(&self) -> DetectorStats {
        DetectorStats {
            tracks: self.tracker.stats(),
            ..self.stats
        }
    }

    /// Adds `seconds` to the time spent getting images (the node measures it).
    pub fn add_source_seconds(&mut self, seconds: f64) {
        self.stats.source_seconds += seconds;
    }

    /// The landmark model on each of `boxes` of `frame`, in parallel, each with its
    /// `masks` (other people's heads) blacked out.
    fn look_all(
        &mut self,
        frame: &ImageFrame,
        boxes: &[CropBox],
        masks: &[Vec<CropBox>],
    ) -> Result<Vec<Look>, DetectorError> {
        if self.inputs.len() < boxes.len() {
            self.inputs.resize_with(boxes.len(), Vec::new);
        }
        let network = &self.network;
        let looks: Vec<Result<Look, DetectorError>> = if boxes.len() == 1 {
            // One run (one person followed): on every core with LiteRT, XNNPACK's
            // threads (bikes.mp4: 26.2-29.0 -> 30.4-32.5 frames/s in interleaved
            // rounds, p50 latency 29.4-33.4 -> 24.4-29.4 ms).
            vec![look(
                network,
                None,
                frame,
                boxes[0],
                &masks[0],
                &mut self.inputs[0],
            )]
        } else {
            self.inputs[..boxes.len()]
                .par_iter_mut()
                .zip(boxes.par_iter().zip(masks.par_iter()))
                .map(|(input, (crop, masks))| {
                    let worker = rayon::current_thread_index().unwrap_or(0);
                    look(network, Some(worker), frame, *crop, masks, input)
                })
                .collect()
        };
        let looks = looks.into_iter().collect::<Result<Vec<Look>, _>>()?;
        for l in &looks {
            self.stats.network_runs += 1;
            self.stats.network_seconds += l.seconds;
            if l.pose_flag >= self.threshold && l.spread < COLLAPSED_SPREAD {
                self.stats.collapsed += 1;
            }
        }
        Ok(looks)
    }

    /// Where the people are, as the person detectors see the search region (the
    /// person box, else the whole image), each with their head's box; without a
    /// detector, the region. `followed`: someone is followed this frame.
    fn search(
        &mut self,
        frame: &ImageFrame,
        followed: bool,
    ) -> Result<Vec<Sighting>, DetectorError> {
        let (width, height) = frame.rgb.dimensions();
        let (region, area) = match &self.person_box {
            Some(b) => (squared(b), *b),
            None => (
                whole_image_box(width, height),
                CropBox {
                    x0: 0.0,
                    y0: 0.0,
                    width: f64::from(width.max(1)),
                    height: f64::from(height.max(1)),
                },
            ),
        };
        let face_regions = self.face_regions(region, &area, followed);
        let body_regions = self.body_regions(&area, followed);
        let mut runs: Vec<Run<'_>> = Vec::new();
        if let Some(person) = &self.person {
            runs.extend(face_regions.iter().map(|r| Run::Faces(person, *r)));
        }
        if let Some(network) = &self.pedestrians {
            runs.extend(body_regions.iter().map(|r| Run::Bodies(network, *r)));
        }
        // Both detectors' runs at once, spread over the cores: a search with the
        // pedestrian detector is 2 + 3 runs, not one detector's runs after the other's.
        let low = self.tracker_low_threshold();
        let pedestrian_threshold = self.pedestrian_threshold;
        let rgb = &frame.rgb;
        // The model inputs: the landmark looks' buffers (not in use during a search).
        if self.inputs.len() < runs.len() {
            self.inputs.resize_with(runs.len(), Vec::new);
        }
        let inputs = &mut self.inputs[..runs.len()];
        let one = |run: &Run<'_>, worker: Option<usize>, input: &mut Vec<f32>| {
            let began = Instant::now();
            let found = match *run {
                Run::Faces(person, region) => {
                    crop_input_signed(rgb, &region, PERSON_INPUT, input);
                    Seen::Faces(faces_in(&region, &person.detect(worker, input, low)?))
                }
                Run::Bodies(network, region) => {
                    crop_input_signed(rgb, &region, PEDESTRIAN_INPUT, input);
                    let people = network.detect(worker, input, pedestrian_threshold)?;
                    Seen::Bodies(bodies_in(&region, &people))
                }
            };
            Ok::<_, DetectorError>((found, began.elapsed().as_secs_f64()))
        };
        let done: Vec<Result<(Seen, f64), DetectorError>> = match runs.as_slice() {
            // A lone run (the whole image while nobody is followed, in two searches of
            // three) here, on every core with LiteRT (XNNPACK's threads; the person
            // detector's lone model: the pedestrian detector, never alone beside it,
            // has none).
            [run] => vec![one(run, None, &mut inputs[0])],
            _ => runs
                .par_iter()
                .zip(inputs.par_iter_mut())
                .map(|(run, input)| {
                    one(run, Some(rayon::current_thread_index().unwrap_or(0)), input)
                })
                .collect(),
        };
        // Without BlazePose's detector, the region as a whole (and the bodies found).
        let mut all = if self.person.is_none() {
            vec![Sighting {
                observation: Observation { region, score: 1.0 },
                head: None,
                body: None,
            }]
        } else {
            Vec::new()
        };
        let mut bodies = Vec::new();
        for d in done {
            match d? {
                (Seen::Faces(f), seconds) => {
                    all.extend(f);
                    self.stats.detector_runs += 1;
                    self.stats.detector_seconds += seconds;
                }
                (Seen::Bodies(b), seconds) => {
                    bodies.extend(b);
                    self.stats.pedestrian_runs += 1;
                    self.stats.pedestrian_seconds += seconds;
                }
            }
        }
        all.extend(self.body_sightings(bodies));
        // One person seen in several regions, or by both detectors: the best-scoring
        // sighting.
        all.sort_by(|a, b| b.observation.score.total_cmp(&a.observation.score));
        let mut placed: Vec<Sighting> = Vec::new();
        for s in all {
            if !placed.iter().any(|p| same_sighting(p, &s)) {
                placed.push(s);
            }
        }
        self.stats.searches += 1;
        tracing::debug!(
            "person detectors: {} boxes {:?}",
            placed.len(),
            placed
                .iter()
                .map(|s| {
                    let o = &s.observation;
                    (o.score, o.region.x0, o.region.y0, o.region.width)
                })
                .collect::<Vec<_>>()
        );
        if placed
            .iter()
            .any(|s| s.observation.score >= self.detection_threshold)
        {
            self.stats.detector_hits += 1;
        }
        Ok(placed)
    }

    /// Where BlazePose's person detector looks: `region`, and one tile of `area` in
    /// turn (all of them on a scene's first frame), where people far away look bigger;
    /// none without the detector.
    fn face_regions(&mut self, region: CropBox, area: &CropBox, followed: bool) -> Vec<CropBox> {
        if self.person.is_none() {
            return Vec::new();
        }
        let mut regions = vec![region];
        let all = tiles(area, self.search_tiles);
        self.empty_searches = if followed {
            0
        } else {
            self.empty_searches.wrapping_add(1)
        };
        if self.stats.frames == self.scene_start || all.is_empty() {
            regions.extend(all);
        } else if a_tile_too(followed, self.empty_searches) {
            regions.push(all[self.next_tile % all.len()]);
            self.next_tile = self.next_tile.wrapping_add(1);
        }
        regions
    }

    /// Where the pedestrian detector looks: `area` and `pedestrian_tiles` tiles across
    /// it (each its full height, overlapping by a fifth of a tile), where people far
    /// away look bigger; all of them each time: one in turn (a third of the cost)
    /// found 0.34 of sample.mp4's people against 0.55 (README). While nobody is
    /// `followed` (a search every frame), every `EMPTY_SCENE_SEARCHES x detect_every`
    /// frames; none without the detector.
    fn body_regions(&mut self, area: &CropBox, followed: bool) -> Vec<CropBox> {
        if self.pedestrians.is_none() {
            return Vec::new();
        }
        let now = self.stats.frames;
        if !followed
            && self.last_pedestrians.is_some_and(|at| {
                now.saturating_sub(at) < EMPTY_SCENE_SEARCHES * self.candidate_every
            })
        {
            return Vec::new();
        }
        self.last_pedestrians = Some(now);
        let mut regions = vec![*area];
        if self.pedestrian_tiles > 1 {
            // Along the longer side (a portrait image: down it).
            let n = f64::from(self.pedestrian_tiles);
            let across = area.width >= area.height;
            let long = if across { area.width } else { area.height };
            let side = long / (0.8 * n + 0.2);
            regions.extend((0..self.pedestrian_tiles).map(|k| {
                let at = 0.8 * side * f64::from(k);
                if across {
                    CropBox {
                        x0: area.x0 + at,
                        width: side,
                        ..*area
                    }
                } else {
                    CropBox {
                        y0: area.y0 + at,
                        height: side,
                        ..*area
                    }
                }
            }));
        }
        regions
    }

    /// The pedestrian detector's boxes (of all regions searched) as sightings: one
    /// person in several regions is the best box; each as the landmark model's box
    /// around it (as for a moving blob) with where their head is. Their scores are
    /// mapped onto the person detector's: the pedestrian threshold to the detection
    /// threshold (a pedestrian found is a confident box).
    fn body_sightings(&self, mut bodies: Vec<ScoredBox>) -> Vec<Sighting> {
        bodies.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut kept: Vec<ScoredBox> = Vec::new();
        for b in bodies {
            if kept.iter().all(|k| box_iou(&k.1, &b.1) <= BODY_NMS_IOU) {
                kept.push(b);
            }
        }
        let threshold = self.pedestrian_threshold;
        let span = (1.0 - threshold).max(f32::EPSILON);
        kept.into_iter()
            .filter_map(|(score, [x0, y0, x1, y1])| {
                let (w, h) = (x1 - x0, y1 - y0);
                if !(h >= MIN_BODY_HEIGHT && w > 0.0) {
                    return None;
                }
                let side = crate::motion::CROP_PER_HEIGHT * h.max(w);
                let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
                let region = CropBox::new(cx - 0.5 * side, cy - 0.5 * side, side, side).ok()?;
                let head_side = HEAD_PER_HEIGHT * h;
                let head = CropBox::new(cx - 0.5 * head_side, y0, head_side, head_side).ok();
                let t = self.detection_threshold;
                let score = t + (1.0 - t) * ((score - threshold) / span).clamp(0.0, 1.0);
                Some(Sighting {
                    observation: Observation { region, score },
                    head,
                    body: CropBox::new(x0, y0, w, h).ok(),
                })
            })
            .collect()
    }

    /// The low-score pass's threshold (the tracker keeps it under the confident one).
    fn tracker_low_threshold(&self) -> f32 {
        self.tracker.low_threshold()
    }

    /// The people the detector found in `frame`, one [`Detection`] each (the heat maps
    /// lent until the next frame); empty when it finds nobody. The node makes the
    /// messages.
    pub fn detect(&mut self, frame: &ImageFrame) -> Result<Vec<Detection<'_>>, DetectorError> {
        self.stats.frames += 1;
        let size = frame.rgb.dimensions();
        if self.scene != Some(size) {
            if self.scene.is_some() {
                self.tracker.reset();
                self.heads.clear();
                self.refused.clear();
                self.motion_looks.clear();
                self.last_candidate = None;
                self.last_pedestrians = None;
            }
            self.scene = Some(size);
            self.scene_start = self.stats.frames;
            self.next_tile = 0;
            self.empty_searches = 0;
        }
        self.tracker.begin();
        let now = self.stats.frames;
        // 1. Follow.
        let (ids, boxes): (Vec<u32>, Vec<CropBox>) = self.tracker.predictions().unzip();
        let heads = &self.heads;
        // Not tried again: all around a person's body as last seen blacked out when
        // their box overlaps someone else's (as a new body's look is): it lost people
        // followed by their face (vtest.avi's first 91 frames, faces only: recall 0.45
        // -> 0.27) and found no one more with the pedestrian detector on.
        let masks: Vec<Vec<CropBox>> = ids
            .iter()
            .map(|&id| {
                let own = heads.iter().find(|h| h.id == id).map(|h| &h.region);
                masks_for(
                    own,
                    heads
                        .iter()
                        .filter(|h| h.id != id && now - h.seen <= MASKED_HEAD_FRAMES)
                        .map(|h| h.region),
                )
            })
            .collect();
        let looks = self.look_all(frame, &boxes, &masks)?;
        let mut kept: Vec<(u32, Look)> = Vec::with_capacity(looks.len());
        for (id, l) in ids.into_iter().zip(looks) {
            tracing::trace!(
                "follow {id}: box ({:.0}, {:.0}, {:.0}), pose flag {:.2}, face {:?}",
                l.crop.x0,
                l.crop.y0,
                l.crop.width,
                l.pose_flag,
                l.face.map(|f| (f.x0 as i64, f.y0 as i64, f.width as i64))
            );
            let before = self.heads.iter().find(|h| h.id == id).map(|h| &h.region);
            let others = self.heads.iter().filter(|h| h.id != id).map(|h| &h.region);
            let jumped = before
                .zip(l.face.as_ref())
                .is_some_and(|(a, b)| head_jump(a, b, others));
            if jumped {
                self.stats.jumps += 1;
            }
            match l.person(self.threshold) {
                Some(next) if !jumped => {
                    self.tracker.seen(id, next);
                    kept.push((id, l));
                }
                _ => self.tracker.missed(id),
            }
        }
        // Two followed boxes on one person (their landmarks coincide): the older track
        // (first) keeps them.
        let mut k = 0;
        while k < kept.len() {
            if kept[..k].iter().any(|(_, o)| same_person(o, &kept[k].1)) {
                let (id, _) = kept.remove(k);
                self.tracker.duplicate(id);
            } else {
                k += 1;
            }
        }
        // 2. Search, when wanted; and look where something moves that nobody followed
        // is (at most MOTION_LOOKS a frame, the tallest first).
        let moving = match &mut self.motion {
            Some(m) => m.update(&frame.rgb, self.motion_min_height),
            None => Vec::new(),
        };
        // Refused places are not looked at again for a while (a shadow, a car, where
        // someone stood).
        self.refused
            .retain(|(_, at)| now.saturating_sub(*at) < REFUSED_FRAMES);
        // Motion that keeps turning out to be nobody (a camera moving too slowly to be
        // told from people moving) is not looked at while that lasts.
        self.motion_looks
            .retain(|(at, _)| now.saturating_sub(*at) < MOTION_WINDOW);
        let looks = self.motion_looks.len();
        let people = self.motion_looks.iter().filter(|(_, p)| *p).count();
        let fruitless = looks >= MOTION_TRIAL && (people as f64) < MOTION_YIELD * looks as f64;
        let unexplained: Vec<CropBox> = moving
            .into_iter()
            .filter(|_| !fruitless)
            .filter(|b| {
                !kept.iter().any(|(_, k)| within_body(k, centre(b)))
                    && !self.refused.iter().any(|(r, _)| iou(r, b) > REFUSED_IOU)
            })
            .take(MOTION_LOOKS)
            .collect();
        let searching = self.tracker.wants_detections();
        if searching || !unexplained.is_empty() {
            let sightings = if searching {
                self.search(frame, !kept.is_empty())?
            } else {
                Vec::new()
            };
            let mut observations: Vec<Observation> =
                sightings.iter().map(|s| s.observation).collect();
            let mut heads: Vec<Option<CropBox>> = sightings.iter().map(|s| s.head).collect();
            let bodies: Vec<Option<CropBox>> = sightings.iter().map(|s| s.body).collect();
            // Proposals the person detector's boxes do not already hold (not against
            // each other: the crops of people side by side overlap).
            let proposed_from = observations.len();
            for b in unexplained {
                if !observations[..proposed_from]
                    .iter()
                    .any(|o| iou(&o.region, &b) > SAME_PERSON_IOU)
                {
                    observations.push(Observation {
                        region: b,
                        score: self.detection_threshold,
                    });
                    // Where the head of a person filling the blob is: the others'
                    // heads are blacked out, never this one.
                    let height = b.height / crate::motion::CROP_PER_HEIGHT;
                    let side = HEAD_PER_HEIGHT * height;
                    heads.push(
                        CropBox::new(
                            b.x0 + 0.5 * (b.width - side),
                            b.y0 + 0.5 * (b.height - height),
                            side,
                            side,
                        )
                        .ok(),
                    );
                }
            }
            let mut verdicts = if searching {
                self.tracker.associate(&observations)
            } else {
                self.tracker.associate_proposals(&observations)
            };
            // Nor the detectors' boxes at a refused place, those matched to a lost track
            // too (looking there for them anyway found the cyclist of bikes.mp4 in 68
            // frames instead of 77: the box is not them, and their track lives on).
            for (v, o) in verdicts.iter_mut().zip(&observations[..proposed_from]) {
                if *v != Assignment::Ignored
                    && self
                        .refused
                        .iter()
                        .any(|(r, _)| iou(r, &o.region) > REFUSED_IOU)
                {
                    *v = Assignment::Ignored;
                }
            }
            // One candidate (the best whose face the detector saw off everyone followed)
            // every `detect_every` frames at most.
            let mut allowed = self
                .last_candidate
                .is_none_or(|at| now.saturating_sub(at) >= self.candidate_every);
            for (v, head) in verdicts.iter_mut().zip(&heads) {
                if *v != Assignment::Candidate {
                    continue;
                }
                let on_someone = head
                    .as_ref()
                    .is_none_or(|h| kept.iter().any(|(_, k)| within_body(k, centre(h))));
                if allowed && !on_someone {
                    self.last_candidate = Some(now);
                    allowed = false;
                } else {
                    *v = Assignment::Ignored;
                }
            }
            let looked: Vec<usize> = (0..verdicts.len())
                .filter(|&i| verdicts[i] != Assignment::Ignored)
                .collect();
            // Each box to look at, the other people blacked out (those followed this
            // frame, and the heads the detector saw of the others looked at now) but
            // for a head overlapping this one's (as the detector saw it; unknown: none).
            // Not for a candidate: with the heads near it blacked out, a part of
            // someone (a hand held out) can pass for a whole person.
            let others: Vec<CropBox> = kept
                .iter()
                .filter_map(|(_, l)| l.face)
                .chain(looked.iter().filter_map(|&i| heads[i]))
                .collect();
            let head_masks: Vec<Vec<CropBox>> = looked
                .iter()
                .map(|&i| match (&verdicts[i], heads[i].as_ref()) {
                    (Assignment::Candidate, _) | (_, None) => Vec::new(),
                    (_, Some(own)) => {
                        masks_for(Some(own), others.iter().copied().filter(|h| h != own))
                    }
                })
                .collect();
            // A body the pedestrian detector saw: all around it blacked out too (the
            // people beside it, whose heads may not be known), in every look at it.
            let looked_bodies: Vec<Option<CropBox>> = looked
                .iter()
                .map(|&i| match verdicts[i] {
                    Assignment::Candidate => None,
                    _ => bodies.get(i).copied().flatten(),
                })
                .collect();
            let masks_at = |n: usize, crop: &CropBox| {
                let mut masks = head_masks[n].clone();
                if let Some(body) = &looked_bodies[n] {
                    masks.extend(around(body, crop));
                }
                masks
            };
            let boxes: Vec<CropBox> = looked.iter().map(|&i| observations[i].region).collect();
            let masks: Vec<Vec<CropBox>> = boxes
                .iter()
                .enumerate()
                .map(|(n, b)| masks_at(n, b))
                .collect();
            // Look at each box; while the landmarks found give a box unlike the one
            // looked at (a detector box is a rough guess), look again there (a
            // candidate is looked at once).
            let mut current: Vec<Option<Look>> = self
                .look_all(frame, &boxes, &masks)?
                .into_iter()
                .map(|l| l.person(self.threshold).is_some().then_some(l))
                .collect();
            for _ in 1..ACQUISITION_LOOKS {
                let again: Vec<(usize, CropBox)> = current
                    .iter()
                    .enumerate()
                    .filter(|(n, _)| verdicts[looked[*n]] != Assignment::Candidate)
                    .filter_map(|(n, l)| {
                        let l = l.as_ref()?;
                        let next = l.person(self.threshold)?;
                        (iou(&next, &l.crop) < SETTLED_IOU).then_some((n, next))
                    })
                    .collect();
                if again.is_empty() {
                    break;
                }
                let (index, next): (Vec<usize>, Vec<CropBox>) = again.into_iter().unzip();
                let again_masks: Vec<Vec<CropBox>> = index
                    .iter()
                    .zip(&next)
                    .map(|(&n, b)| masks_at(n, b))
                    .collect();
                for (n, l) in index
                    .into_iter()
                    .zip(self.look_all(frame, &next, &again_masks)?)
                {
                    if l.person(self.threshold).is_some() {
                        current[n] = Some(l);
                    }
                }
            }
            // A box where the landmark model found nobody is a refused place, as a
            // moving blob's is (a poster, a shadow the detector scores as a person):
            // not looked at again for `REFUSED_FRAMES`.
            for (n, l) in current.iter().enumerate() {
                if l.is_none() && looked[n] < proposed_from {
                    self.refused.push((observations[looked[n]].region, now));
                    self.stats.refused_sightings += 1;
                }
            }
            let proposals: Vec<usize> = looked
                .iter()
                .copied()
                .filter(|&i| i >= proposed_from)
                .collect();
            self.stats.motion_proposals += proposals.len() as u64;
            let mut taken: Vec<usize> = Vec::new();
            // People found again first (they keep their places), then newcomers, then
            // candidates.
            let mut found: Vec<(usize, Look)> = looked
                .iter()
                .zip(current)
                .filter_map(|(&i, l)| Some((i, l?)))
                .collect();
            // Among newcomers of a kind, the taller first: a look at a part of someone
            // (their legs) comes after them and is dropped as theirs.
            let height = |l: &Look| {
                let n = BODY_LANDMARKS.min(l.points.len());
                let (lo, hi) = extent(&l.points[..n]);
                hi[1] - lo[1]
            };
            found.sort_by(|(i, a), (j, b)| {
                let kind = |k: usize| match verdicts[k] {
                    Assignment::Track(_) => 0,
                    Assignment::Candidate => 2,
                    _ => 1,
                };
                kind(*i)
                    .cmp(&kind(*j))
                    .then(height(b).total_cmp(&height(a)))
            });
            for (i, l) in found {
                // A candidate is confirmed against everyone now present, those just
                // found included.
                // Someone already present, or a part of them (a box on a person's legs
                // gives a small skeleton there).
                let newcomer = !matches!(verdicts[i], Assignment::Track(_));
                if kept
                    .iter()
                    .any(|(_, o)| same_person(o, &l) || (newcomer && part_of(o, &l)))
                    || (verdicts[i] == Assignment::Candidate
                        && !confirms(heads[i].as_ref(), &l, kept.iter().map(|(_, k)| k)))
                {
                    continue;
                }
                let Some(next) = l.person(self.threshold) else {
                    continue;
                };
                let id = match verdicts[i] {
                    Assignment::Track(id) => {
                        self.tracker.seen(id, next);
                        id
                    }
                    _ => match self.tracker.born(next) {
                        Some(id) => id,
                        None => continue,
                    },
                };
                taken.push(i);
                kept.push((id, l));
            }
            // A proposal counts as someone only where a person was found and taken
            // (one found who was already followed, or without room, is refused too).
            for i in proposals {
                let someone = taken.contains(&i);
                self.motion_looks.push((now, someone));
                if !someone {
                    self.refused.push((observations[i].region, now));
                    self.stats.motion_refused += 1;
                }
            }
        }
        let reported = self.tracker.end();
        // Heads where they were seen this frame; a person lost keeps theirs until their
        // track ends (a head jumping there is theirs; blacked out for a few frames).
        for (id, l) in &kept {
            if let Some(face) = l.face {
                match self.heads.iter_mut().find(|h| h.id == *id) {
                    Some(h) => {
                        h.region = face;
                        h.seen = now;
                    }
                    None => self.heads.push(Head {
                        id: *id,
                        region: face,
                        seen: now,
                    }),
                }
            }
        }
        let tracker = &self.tracker;
        self.heads.retain(|h| tracker.is_live(h.id));
        // 3. The heat maps of the people reported.
        self.found_len = 0;
        for (id, _) in &reported {
            let Some((_, l)) = kept.iter().find(|(k, _)| k == id) else {
                continue;
            };
            if self.found.len() == self.found_len {
                self.found.push(Found {
                    crop: l.crop,
                    track_id: *id,
                    maps: Vec::new(),
                });
            }
            let slot = &mut self.found[self.found_len];
            slot.crop = l.crop;
            slot.track_id = *id;
            self.mapping
                .apply(&l.logits, HEATMAP_SIZE, HEATMAP_SIZE, &mut slot.maps)
                .map_err(|source| DetectorError::Maps(Box::new(source)))?;
            self.found_len += 1;
        }
        if self.found_len == 0 {
            self.stats.no_person += 1;
        } else {
            self.stats.detected += 1;
            self.stats.people += self.found_len as u64;
        }
        Ok(self.found[..self.found_len]
            .iter()
            .map(|f| Detection {
                crop: f.crop,
                maps: &f.maps,
                size: HEATMAP_SIZE,
                track_id: f.track_id,
            })
            .collect())
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
    /// The person: their track's id, kept while they are followed or re-acquired.
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

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f64, y: f64, side: f64) -> CropBox {
        CropBox::new(x, y, side, side).expect("box")
    }

    /// A look whose face landmarks lie in `face` (corners and centre).
    fn look_with_face(face: CropBox) -> Look {
        let (x, y, w) = (face.x0, face.y0, face.width);
        let mut points = vec![[x + 0.5 * w, y + 0.5 * w]; BODY_LANDMARKS];
        points[1] = [x, y];
        points[2] = [x + w, y + w];
        Look {
            crop: square(0.0, 0.0, 1000.0),
            pose_flag: 1.0,
            next_box: None,
            spread: 0.5,
            face: head_box(&points[..FACE_LANDMARKS]),
            points,
            logits: Vec::new(),
            seconds: 0.0,
        }
    }

    /// A look whose body landmarks run down a vertical line from `top` to `bottom` at `x`.
    fn look_along(x: f64, top: f64, bottom: f64) -> Look {
        let mut l = look_with_face(square(x, top, 1.0));
        let n = l.points.len();
        for (k, p) in l.points.iter_mut().enumerate() {
            *p = [x, top + (bottom - top) * k as f64 / (n - 1) as f64];
        }
        l
    }

    #[test]
    fn while_nobody_is_followed_a_tile_is_searched_in_one_search_of_three() {
        // Searches in a row while nobody is followed: a tile on the 1st, 4th, 7th...
        let tiles: Vec<bool> = (1..=7).map(|n| a_tile_too(false, n)).collect();
        assert_eq!(tiles, [true, false, false, true, false, false, true]);
        // While someone is followed: every search.
        assert!((0..5).all(|n| a_tile_too(true, n)));
    }

    #[test]
    fn a_small_skeleton_on_someones_legs_is_a_part_of_them_not_a_person() {
        let whole = look_along(100.0, 0.0, 300.0);
        // Legs: the lower half, inside the body.
        assert!(part_of(&whole, &look_along(105.0, 150.0, 300.0)));
        // Not a part: as tall as the person, beside them, or bigger.
        assert!(!part_of(&whole, &look_along(100.0, 20.0, 300.0)));
        assert!(!part_of(&whole, &look_along(200.0, 150.0, 300.0)));
        assert!(!part_of(&look_along(105.0, 150.0, 300.0), &whole));
    }

    #[test]
    fn around_a_body_is_what_of_the_crop_lies_outside_it_grown_by_a_margin() {
        let crop = square(0.0, 0.0, 200.0);
        let body = CropBox::new(80.0, 20.0, 40.0, 160.0).expect("box");
        let strips = around(&body, &crop);
        // Margin 16 px across, 8 above and below: left, right, top, bottom strips.
        assert_eq!(strips.len(), 4, "{strips:?}");
        assert!((strips[0].width - 64.0).abs() < 1e-9);
        assert!((strips[1].x0 - 136.0).abs() < 1e-9 && (strips[1].width - 64.0).abs() < 1e-9);
        assert!((strips[2].height - 12.0).abs() < 1e-9);
        assert!((strips[3].y0 - 188.0).abs() < 1e-9);
        // A body filling the crop leaves nothing to black out.
        let full = CropBox::new(-50.0, -50.0, 300.0, 300.0).expect("box");
        assert!(around(&full, &crop).is_empty());
    }

    #[test]
    fn pedestrian_settings_outside_their_domain_are_refused_by_name() {
        for (threshold, tiles) in [(0.0, 2), (f32::NAN, 2), (1.5, 2), (0.3, 0), (0.3, 9)] {
            let settings = ImageSettings {
                pedestrian_threshold: threshold,
                pedestrian_tiles: tiles,
                ..ImageSettings::default()
            };
            let err = settings.check().expect_err("refused");
            assert!(err.to_string().contains("pedestrian_"), "{err}");
        }
        assert!(ImageSettings::default().check().is_ok());
    }

    #[test]
    fn motion_settings_outside_their_domain_are_refused_by_name() {
        for bad in [f64::NAN, f64::INFINITY, -1.0, 0.0, 1e300] {
            let settings = ImageSettings {
                motion_min_height: bad,
                ..ImageSettings::default()
            };
            let err = settings.check().expect_err("refused");
            assert!(
                err.to_string().contains("motion_min_height"),
                "{bad}: {err}"
            );
        }
        assert!(ImageSettings::default().check().is_ok());
    }

    #[test]
    fn a_head_is_twice_the_face_landmarks_extent_around_their_centre() {
        let h = head_box(&[[100.0, 200.0], [140.0, 220.0], [120.0, 210.0]]).expect("head");
        assert_eq!((h.x0, h.y0, h.width, h.height), (80.0, 170.0, 80.0, 80.0));
        assert!(head_box(&[[f64::NAN, 0.0]]).is_none());
    }

    #[test]
    fn other_heads_are_masked_but_one_overlapping_the_persons_own() {
        let own = square(100.0, 100.0, 50.0);
        let near = square(130.0, 120.0, 50.0);
        let far = square(500.0, 100.0, 50.0);
        assert_eq!(masks_for(Some(&own), [near, far].into_iter()), vec![far]);
        assert!(masks_for(None, [near, far].into_iter()).is_empty());
    }

    #[test]
    fn a_head_jumps_only_far_and_onto_someone_elses() {
        let before = square(100.0, 100.0, 50.0);
        let other = square(400.0, 100.0, 60.0);
        let moved = square(130.0, 110.0, 50.0);
        let onto_other = square(405.0, 105.0, 50.0);
        let far_away = square(900.0, 100.0, 50.0);
        assert!(!head_jump(&before, &moved, [&other].into_iter()));
        assert!(head_jump(&before, &onto_other, [&other].into_iter()));
        // Far, but onto nobody followed: small faces jitter that much.
        assert!(!head_jump(&before, &far_away, [&other].into_iter()));
        assert!(!head_jump(&before, &onto_other, std::iter::empty()));
    }

    #[test]
    fn a_low_score_box_is_confirmed_only_by_a_face_of_like_size_inside_its_head() {
        let head = square(100.0, 100.0, 60.0);
        // The look's head is twice the landmarks' extent: a 30 px face gives 60 px.
        let same = look_with_face(square(115.0, 115.0, 30.0));
        let none = std::iter::empty;
        assert!(confirms(Some(&head), &same, none()));
        let elsewhere = look_with_face(square(300.0, 115.0, 30.0));
        assert!(!confirms(Some(&head), &elsewhere, none()));
        // On someone's body (a hand held out): a part of them.
        let someone = look_with_face(square(50.0, 50.0, 200.0));
        assert!(!confirms(Some(&head), &same, [&someone].into_iter()));
        let huge = look_with_face(square(30.0, 30.0, 200.0));
        assert!(
            !confirms(Some(&head), &huge, none()),
            "centre inside, 6.7 x the size"
        );
        assert!(!confirms(None, &same, none()));
    }
}
