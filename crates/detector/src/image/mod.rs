//! The image detector: a camera frame in, the dictionary's heat maps of every person
//! in it, each with its crop box and track id (a [`Detection`]; the node makes the
//! `HeatMaps` messages) out, through a BlazePose landmark model.
//!
//! Per frame (MediaPipe's tracking, without the rotation, for several people):
//! 1. each person followed looks at the box their previous landmarks gave, moved by
//!    their velocity; the landmark runs of different people go in parallel across
//!    cores (`rayon`); with `tracking.looks_per_frame` set, the people a frame has no
//!    time for wait a frame or so, the most urgent looked at first
//!    (`crate::tracker::schedule`): their boxes move on, their newest look's heat maps
//!    are sent again, moved with them (`frames_since_look`);
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
//!
//! The submodules (the stages of `detect` each an `impl ImageDetector` block of its own
//! file; they use `looks` and this module, never each other):
//! - `settings`: [`ImageSettings`] (with [`Runtime`], [`MapEncoding`]), [`DetectorError`],
//!   [`DetectorStats`];
//! - `looks`: one look of the landmark model at a box, and the geometry of boxes, heads
//!   and bodies the stages judge looks by (shared by them);
//! - `search`: the person detector's and the pedestrian detector's searches;
//! - `track`: step 1, following the people tracked;
//! - `landmarks`: step 2, motion's proposals, the tracker's verdicts, the looks at the
//!   boxes found and the people admitted;
//! - `decode`: step 3, the heads kept and the heat maps of the people reported.

mod bodies;
mod decode;
mod landmarks;
mod looks;
mod search;
mod settings;
mod stage;
#[cfg(test)]
mod tests;
mod track;

use std::path::Path;
use std::sync::Arc;

pub use settings::{
    BodyDetector, DetectorError, DetectorStats, ImageSettings, MapEncoding, Runtime,
};

use self::looks::{BODY_LANDMARKS, Found, Head};
use crate::images::ImageFrame;
use crate::mapping::ChannelMapping;
use crate::models::ModelFile;
use crate::models::landmarks::{LandmarkNetwork, NetworkError};
use crate::models::litert::{Landmarks, LiteRt};
use crate::models::pedestrians::PedestrianNetwork;
use crate::models::person::PersonNetwork;
use crate::motion::Motion;
use crate::tracker::Tracker;
use posestream_base::CropBox;

/// The detector: the landmark model, the mapping, and the people tracked.
pub struct ImageDetector {
    network: Landmarks,
    /// The person detectors, where they run.
    searches: stage::Searches,
    detection_threshold: f32,
    mapping: ChannelMapping,
    joint_names: Vec<String>,
    threshold: f32,
    tracker: Tracker,
    /// The image size of the scene, and the frame it began.
    scene: Option<(u32, u32)>,
    scene_start: u64,
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
    /// The people followed who wait for a look this frame (the schedule's): id and
    /// box expected.
    waiting: Vec<(u32, CropBox)>,
    /// The people of the current frame (their maps buffers reused).
    found: Vec<Found>,
    /// The slots of `found` shown this frame, in order.
    shown: Vec<usize>,
    stats: DetectorStats,
}

impl ImageDetector {
    /// Loads the configured model and mapping for a dictionary with `joint_names`.
    pub fn load(settings: &ImageSettings, joint_names: &[String]) -> Result<Self, DetectorError> {
        let dir = settings.models_dir();
        let existing = |path: std::path::PathBuf| {
            if path.is_file() {
                Ok(path)
            } else if let Some(what) = posestream_base::files::what_is(&path) {
                Err(DetectorError::NotAModel { path, what })
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
        if settings.pedestrians
            && let Some(what) = posestream_base::files::what_is(&pedestrians_path)
        {
            return Err(DetectorError::NotAModel {
                path: pedestrians_path,
                what,
            });
        }
        let nanodet = settings.pedestrians && settings.body_detector == BodyDetector::Nanodet;
        let pedestrians = settings.pedestrians
            && !nanodet
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
        let workers = rayon::current_num_threads().clamp(1, 8);
        let bodies = if nanodet {
            let fixed = settings.nanodet_input().map_err(DetectorError::Settings)?;
            // On the search stage's one thread, one thread of LiteRT's too.
            let threads = if settings.search_thread { 1 } else { workers };
            bodies::Bodies::new(dir.clone(), litert.clone(), threads, fixed)?
        } else {
            None
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
        // Every model run once now: their first runs are slow (weights packed), and
        // would otherwise fall on the first frames.
        network.warm_up()?;
        if let Some(person) = &person {
            person.warm_up()?;
        }
        if let Some(pedestrians) = &pedestrians {
            pedestrians.warm_up()?;
        }
        let mut detector = Self::new(network, mapping, joint_names, settings)?;
        let stage::Searches::Inline(mut searcher) = std::mem::replace(
            &mut detector.searches,
            stage::Searches::Inline(Box::default()),
        ) else {
            unreachable!("a new detector searches inline")
        };
        searcher.person = person;
        searcher.pedestrians = pedestrians;
        searcher.bodies = bodies;
        detector.searches = if settings.search_thread {
            stage::Searches::Stage(stage::Stage::start(*searcher)?)
        } else {
            stage::Searches::Inline(searcher)
        };
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
        let tracker = Tracker::new(settings.tracking.clone(), settings.detection_threshold);
        Ok(Self {
            network,
            searches: stage::Searches::Inline(Box::new(search::Searcher {
                nanodet_threshold: settings.nanodet_threshold,
                pedestrian_threshold: settings.pedestrian_threshold,
                pedestrian_tiles: settings.pedestrian_tiles,
                detection_threshold: settings.detection_threshold,
                low_threshold: tracker.low_threshold(),
                person_box: settings.person_box()?,
                search_tiles: settings.search_tiles,
                candidate_every: u64::from(settings.tracking.detect_every),
                // Inline: a search's runs spread over the cores (a stage sets false).
                parallel: true,
                ..search::Searcher::default()
            })),
            detection_threshold: settings.detection_threshold,
            mapping,
            joint_names: joint_names.to_vec(),
            threshold: settings.presence_threshold,
            tracker,
            scene: None,
            scene_start: 0,
            heads: Vec::new(),
            last_candidate: None,
            candidate_every: u64::from(settings.tracking.detect_every),
            motion: settings.motion.then(Motion::new),
            motion_min_height: settings.motion_min_height,
            refused: Vec::new(),
            motion_looks: Vec::new(),
            inputs: Vec::new(),
            waiting: Vec::new(),
            found: Vec::new(),
            shown: Vec::new(),
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

    /// A change of image size to `size` is a new scene: every track ends (a folder of
    /// unrelated photos), with the heads, refused places and motion's record; the
    /// searches start over.
    fn begin_scene(&mut self, size: (u32, u32)) {
        if self.scene != Some(size) {
            if self.scene.is_some() {
                self.tracker.reset();
                self.heads.clear();
                self.refused.clear();
                self.motion_looks.clear();
                self.last_candidate = None;
            }
            self.scene = Some(size);
            self.scene_start = self.stats.frames;
        }
    }

    /// The people the detector found in `frame`, one [`Detection`] each (the heat maps
    /// lent until the next frame); empty when it finds nobody. The node makes the
    /// messages.
    pub fn detect(&mut self, frame: &Arc<ImageFrame>) -> Result<Vec<Detection<'_>>, DetectorError> {
        self.stats.frames += 1;
        self.begin_scene(frame.rgb.dimensions());
        self.tracker.begin_at(frame.stamp_ns);
        let now = self.stats.frames;
        // 1. Follow.
        let mut kept = self.follow(frame, now)?;
        // 2. The search's sightings (inline: when the tracker wants them; a stage: the
        // newest ready); and look where something moves that nobody followed is (at
        // most MOTION_LOOKS a frame, the tallest first).
        let unexplained = self.unexplained_motion(frame, now, &kept);
        let request = search::SearchRequest {
            frame: now,
            scene_first: now == self.scene_start,
            followed: !kept.is_empty(),
            crowded: !self.waiting.is_empty(),
        };
        let wanted = self.tracker.wants_detections();
        let sightings = self
            .searches
            .sightings(frame, request, wanted, &mut self.stats)?;
        let searching = sightings.is_some();
        if searching || !unexplained.is_empty() {
            let sightings = sightings.unwrap_or_default();
            self.acquire(frame, now, searching, &sightings, unexplained, &mut kept)?;
        }
        // How each person looks, learnt while they are clear of the others (their look
        // is taken only then).
        for (k, (id, l)) in kept.iter().enumerate() {
            let others = kept.iter().enumerate().filter(|(o, _)| *o != k);
            if looks::clear_of(l, others.map(|(_, (_, o))| o))
                && let Some(look) = looks::appearance(frame, l)
            {
                self.tracker.looked_like(*id, &look);
            }
        }
        let reported = self.tracker.end();
        // Who was kept and reported (`benches/footage/missed.py` reads these lines).
        if tracing::enabled!(tracing::Level::DEBUG) {
            for (id, l) in &kept {
                let (lo, hi) = looks::extent(&l.points[..BODY_LANDMARKS.min(l.points.len())]);
                tracing::debug!(
                    "image {}: kept {id} body {:.0},{:.0},{:.0},{:.0} reported {}",
                    now.saturating_sub(1),
                    lo[0],
                    lo[1],
                    hi[0],
                    hi[1],
                    reported.iter().any(|r| r.0 == *id)
                );
            }
        }
        self.update_heads(&kept, now);
        // 3. The heat maps of the people reported.
        self.decode(&reported, &kept)?;
        Ok(self.detections())
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
    /// 0: the landmark model looked at them in this frame; n: it had no time for them
    /// (`tracking.looks_per_frame`), and these are the maps of its look n frames
    /// before, their box moved as the person is expected to have moved.
    pub frames_since_look: u32,
}
