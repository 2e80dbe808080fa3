//! The searches for people ([`Searcher::search`]): BlazePose's person detector (faces)
//! and a whole-body detector (NanoDet on the search region, or the SSDLite pedestrian
//! detector on it and its tiles), their sightings merged into one per person. A
//! [`Searcher`] holds the detectors and what the searches remember; it runs on the
//! frame's thread (its runs spread over the cores) or on a stage of its own
//! (`super::stage`, its runs one after another).

use std::time::Instant;

use rayon::prelude::*;

use super::bodies::{self, letterboxed};
use super::looks::{HEAD_PER_HEIGHT, Sighting, box_iou, same_sighting};
use super::{DetectorError, DetectorStats};
use crate::crop::{
    box_from_alignment, crop_input_signed, crop_input_sized, squared, tiles, whole_image_box,
};
use crate::images::ImageFrame;
use crate::models::nanodet::{NanoDetNetwork, normalise};
use crate::models::pedestrians::{INPUT_SIZE as PEDESTRIAN_INPUT, Pedestrian, PedestrianNetwork};
use crate::models::person::{INPUT_SIZE as PERSON_INPUT, PersonDetection, PersonNetwork};
use crate::tracker::Observation;
use posestream_base::CropBox;

/// Two pedestrian boxes (of overlapping tiles) overlapping more than this: one person.
const BODY_NMS_IOU: f64 = 0.5;
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
/// NanoDet's boxes down to this share of `nanodet_threshold` are kept, scored under the
/// detection threshold: the tracker re-acquires lost people with them (ByteTrack's
/// low-score pass), never starts a track on one without a face confirmed. Footage bench,
/// two interleaved rounds each against none: `sample.mp4` recall 0.55 -> 0.58 (both
/// rounds), `vtest.avi` 0.88 -> 0.88-0.89, precision alike.
const NANODET_LOW_SHARE: f32 = 0.55;
/// Pedestrian boxes shorter than this (image pixels) are not looked at.
const MIN_BODY_HEIGHT: f64 = 20.0;

/// A pedestrian detector's box: its score and `[x0, y0, x1, y1]`, image pixels.
type ScoredBox = (f32, [f64; 4]);

/// One detector run of a search: the detector and the region it looks at.
#[derive(Clone, Copy)]
enum Run<'a> {
    Faces(&'a PersonNetwork, CropBox),
    Bodies(&'a PedestrianNetwork, CropBox),
    People(&'a NanoDetNetwork, CropBox),
}

/// What one run of a search found.
enum Seen {
    Faces(Vec<Sighting>),
    Bodies(Vec<ScoredBox>),
}

/// What a search is for: the frame's number (from 1), whether it is a scene's first,
/// whether someone is followed in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct SearchRequest {
    /// The frame's number in the run, from 1.
    pub frame: u64,
    /// The first frame of a scene (an image size): every tile is searched.
    pub scene_first: bool,
    /// Someone is followed in the frame.
    pub followed: bool,
    /// Someone followed waits for a look this frame (the schedule's): the search
    /// stage, on a core the looks need, searches every other such frame only (but
    /// when the tracker wants boxes).
    pub crowded: bool,
}

/// What searches cost and found, added to [`DetectorStats`] when their sightings are
/// taken.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct SearchStats {
    detector_runs: u64,
    detector_seconds: f64,
    pedestrian_runs: u64,
    pedestrian_seconds: f64,
    searches: u64,
    detector_hits: u64,
}

impl SearchStats {
    /// Adds these to `stats`.
    pub(super) fn add_to(&self, stats: &mut DetectorStats) {
        stats.detector_runs += self.detector_runs;
        stats.detector_seconds += self.detector_seconds;
        stats.pedestrian_runs += self.pedestrian_runs;
        stats.pedestrian_seconds += self.pedestrian_seconds;
        stats.searches += self.searches;
        stats.detector_hits += self.detector_hits;
    }

    /// These and `other`'s.
    pub(super) fn merged(mut self, other: &Self) -> Self {
        self.detector_runs += other.detector_runs;
        self.detector_seconds += other.detector_seconds;
        self.pedestrian_runs += other.pedestrian_runs;
        self.pedestrian_seconds += other.pedestrian_seconds;
        self.searches += other.searches;
        self.detector_hits += other.detector_hits;
        self
    }
}

/// The person detectors and what the searches remember.
#[derive(Default)]
pub(super) struct Searcher {
    /// BlazePose's person detector (`None`: the search region as a whole is the box).
    pub person: Option<PersonNetwork>,
    /// The pedestrian detector (`None`: off, not fetched, or NanoDet instead).
    pub pedestrians: Option<PedestrianNetwork>,
    /// NanoDet, the whole-body detector (`None`: off, not fetched, or SSDLite instead).
    pub bodies: Option<bodies::Bodies>,
    /// The pedestrian detector's score below this: not a person.
    pub pedestrian_threshold: f32,
    /// NanoDet's score below this: not a person.
    pub nanodet_threshold: f32,
    /// The person detector's score below this: not a person.
    pub detection_threshold: f32,
    /// The tracker's low-score pass's threshold.
    pub low_threshold: f32,
    /// Tiles of the pedestrian detector.
    pub pedestrian_tiles: u32,
    /// Tiles of the person detector.
    pub search_tiles: u32,
    /// Where to search (`None`: the whole image).
    pub person_box: Option<CropBox>,
    /// `detect_every`, frames.
    pub candidate_every: u64,
    /// Runs spread over the cores (else one after another, on the caller's thread).
    pub parallel: bool,
    /// The frame the whole-body detector last ran (see `EMPTY_SCENE_SEARCHES`).
    pub last_pedestrians: Option<u64>,
    /// The tile the next search looks at besides the whole image.
    pub next_tile: usize,
    /// Searches in a row while nobody is followed (0 while someone is).
    pub empty_searches: u64,
    /// One model input per run.
    pub inputs: Vec<Vec<f32>>,
    /// Tests: a search of a frame this wide panics (a stage's thread dying).
    #[cfg(test)]
    pub panic_at_width: Option<u32>,
}

/// Whether a search (not a scene's first) looks at a tile beside the whole image: every
/// one while someone is `followed`, else the first of every `EMPTY_SCENE_TILE_EVERY`
/// (`empty`: searches in a row while nobody is followed, this one included).
pub(super) fn a_tile_too(followed: bool, empty: u64) -> bool {
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

impl Searcher {
    /// A new scene: the searches start over.
    fn begin_scene(&mut self) {
        self.last_pedestrians = None;
        self.next_tile = 0;
        self.empty_searches = 0;
    }

    /// Where the people are, as the person detectors see the search region (the
    /// person box, else the whole image), each with their head's box; without a
    /// detector, the region. With what the search cost.
    pub(super) fn search(
        &mut self,
        frame: &ImageFrame,
        request: SearchRequest,
    ) -> Result<(Vec<Sighting>, SearchStats), DetectorError> {
        if request.scene_first {
            self.begin_scene();
        }
        #[cfg(test)]
        if self.panic_at_width == Some(frame.rgb.width()) {
            panic!("a search that dies");
        }
        let mut stats = SearchStats::default();
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
        let face_regions = self.face_regions(region, &area, request);
        // The whole-body detector's turn is decided once a search.
        let bodies_now =
            (self.pedestrians.is_some() || self.bodies.is_some()) && self.bodies_now(request);
        let body_regions = if bodies_now && self.pedestrians.is_some() {
            self.body_regions(&area)
        } else {
            Vec::new()
        };
        if let Some(bodies) = &mut self.bodies {
            // The input size nearest the search region's aspect.
            let side = |v: f64| v.round().clamp(1.0, f64::from(u32::MAX)) as u32;
            bodies.prepare(side(area.width), side(area.height))?;
        }
        let people = if bodies_now {
            self.bodies.as_ref().and_then(bodies::Bodies::loaded)
        } else {
            None
        };
        let mut runs: Vec<Run<'_>> = Vec::new();
        if let Some(network) = people {
            runs.push(Run::People(network, letterboxed(&area, network.size())));
        }
        if let Some(person) = &self.person {
            runs.extend(face_regions.iter().map(|r| Run::Faces(person, *r)));
        }
        if let Some(network) = &self.pedestrians {
            runs.extend(body_regions.iter().map(|r| Run::Bodies(network, *r)));
        }
        // Both detectors' runs at once, spread over the cores: a search with the
        // pedestrian detector is 2 + 3 runs, not one detector's runs after the other's.
        let low = self.low_threshold;
        let pedestrian_threshold = self.pedestrian_threshold;
        // NanoDet's boxes under its threshold too, down to the low-score pass's share
        // of it: the tracker re-acquires lost people with them, never starts one.
        let nanodet_threshold = self.nanodet_low();
        let rgb = &frame.rgb;
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
                Run::People(network, region) => {
                    let size = network.size();
                    crop_input_sized(rgb, &region, [size.width, size.height], input);
                    normalise(input);
                    let people = network.detect(input, nanodet_threshold)?;
                    Seen::Bodies(bodies_in(&region, &people))
                }
            };
            Ok::<_, DetectorError>((found, began.elapsed().as_secs_f64()))
        };
        let done: Vec<Result<(Seen, f64), DetectorError>> = match runs.as_slice() {
            // On a stage of its own, one run after another (beside the frames' looks),
            // but while nobody is followed: the frame waits for this search.
            _ if !self.parallel && request.followed => runs
                .iter()
                .zip(inputs.iter_mut())
                .map(|(run, input)| one(run, Some(0), input))
                .collect(),
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
                    stats.detector_runs += 1;
                    stats.detector_seconds += seconds;
                }
                (Seen::Bodies(b), seconds) => {
                    bodies.extend(b);
                    stats.pedestrian_runs += 1;
                    stats.pedestrian_seconds += seconds;
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
        stats.searches += 1;
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
            stats.detector_hits += 1;
        }
        Ok((placed, stats))
    }

    /// Where BlazePose's person detector looks: `region`, and one tile of `area` in
    /// turn (all of them on a scene's first frame), where people far away look bigger;
    /// none without the detector.
    fn face_regions(
        &mut self,
        region: CropBox,
        area: &CropBox,
        request: SearchRequest,
    ) -> Vec<CropBox> {
        let followed = request.followed;
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
        if request.scene_first || all.is_empty() {
            regions.extend(all);
        } else if a_tile_too(followed, self.empty_searches) {
            regions.push(all[self.next_tile % all.len()]);
            self.next_tile = self.next_tile.wrapping_add(1);
        }
        regions
    }

    /// NanoDet's boxes scoring at least this are kept ([`NANODET_LOW_SHARE`] of its
    /// threshold): those under the threshold only for the tracker's low-score pass.
    fn nanodet_low(&self) -> f32 {
        self.nanodet_threshold * NANODET_LOW_SHARE
    }

    /// Whether the whole-body detector runs in this search: always while someone is
    /// followed, else every `EMPTY_SCENE_SEARCHES x detect_every` frames (and on a
    /// scene's first).
    fn bodies_now(&mut self, request: SearchRequest) -> bool {
        let now = request.frame;
        if !request.followed
            && !request.scene_first
            && self.last_pedestrians.is_some_and(|at| {
                now.saturating_sub(at) < EMPTY_SCENE_SEARCHES * self.candidate_every
            })
        {
            return false;
        }
        self.last_pedestrians = Some(now);
        true
    }

    /// Where the pedestrian detector looks: `area` and `pedestrian_tiles` tiles across
    /// it (each its full height, overlapping by a fifth of a tile), where people far
    /// away look bigger; all of them each time: one in turn (a third of the cost)
    /// found 0.34 of sample.mp4's people against 0.55 (README). While nobody is
    /// `followed` (a search every frame), every `EMPTY_SCENE_SEARCHES x detect_every`
    /// frames; none without the detector.
    fn body_regions(&self, area: &CropBox) -> Vec<CropBox> {
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
        let threshold = if self.bodies.is_some() {
            self.nanodet_threshold
        } else {
            self.pedestrian_threshold
        };
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
                let score = if score >= threshold {
                    t + (1.0 - t) * ((score - threshold) / span).clamp(0.0, 1.0)
                } else {
                    // A low-score box: into [low_threshold, detection_threshold).
                    let low = self.nanodet_low();
                    let below =
                        ((score - low) / (threshold - low).max(f32::EPSILON)).clamp(0.0, 1.0);
                    (self.low_threshold + (t - self.low_threshold) * below).min(t - f32::EPSILON)
                };
                Some(Sighting {
                    observation: Observation { region, score },
                    head,
                    body: CropBox::new(x0, y0, w, h).ok(),
                })
            })
            .collect()
    }
}
