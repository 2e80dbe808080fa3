//! Who is who from frame to frame: tracks of people as boxes in the image, ByteTrack /
//! OC-SORT style, independent of any model so it can be tested on boxes alone.
//!
//! A frame's work, in order:
//! 1. [`Tracker::begin`]; the boxes of tracks being followed
//!    ([`Tracker::predictions`]: each track's box moved by its velocity);
//! 2. what was seen there, per track ([`Tracker::seen`]); the image detector looks with
//!    its landmark model, whose landmarks give the next box;
//! 3. when new boxes are needed ([`Tracker::wants_detections`]: nobody followed, a track
//!    just lost, or every `detect_every` frames), unlabelled boxes from a person detector
//!    are matched to tracks not seen this frame (nor waiting for a look: a box on
//!    someone who waits is theirs) by a minimum-cost assignment
//!    (Hungarian, `pathfinding`'s Kuhn-Munkres) on 1 - IoU with the tracks' predicted
//!    boxes, in two passes: confident boxes first, then the low-scoring ones against
//!    the tracks still unmatched ([`Tracker::associate`]); confident boxes left over
//!    start tracks, while there is room for `max_people`, and low-scoring ones on
//!    nobody are candidates: they start a track only if the caller's second opinion
//!    (the image detector's landmark model) finds a person there;
//! 4. [`Tracker::end`]: a track unseen (and not waiting for a look:
//!    [`Tracker::scheduled`]) misses a frame (as one the caller found on a
//!    person another track has: [`Tracker::duplicate`]), and ends after
//!    `lost_frames` misses in a row (until then, a box near where its velocity has
//!    taken it re-acquires it with its id); a new track is confirmed after
//!    `birth_frames` frames in a row (at once on a scene's first frame), and only
//!    confirmed tracks are reported.
//!
//! A person who comes back ([`Tracker::born_like`]): a newcomer whose look (an
//! [`Appearance`], given with [`Tracker::looked_like`] while each person is seen clear of
//! the others, frozen while they are not) is near a lost track's, or an ended one's
//! remembered up to `reid_seconds` after they were last seen, and who is where that
//! person could have gone, gets their id back (`tracker/reid.rs`).
//!
//! Boxes are square crop boxes in image pixels ([`CropBox`]); ids are `u32` from 1,
//! counted up (past `u32::MAX` they wrap around, skipping 0 and those live or
//! remembered): no id is given to a second person while the first may still come back.

use pathfinding::kuhn_munkres::kuhn_munkres_min;
use pathfinding::matrix::Matrix;
use serde::Serialize;

use crate::appearance::Appearance;
use posestream_base::CropBox;

mod reid;
pub mod schedule;
mod settings;

pub use settings::TrackingSettings;

/// An unlabelled box: where a person detector saw someone, and how sure it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// The box, image pixels.
    pub region: CropBox,
    /// The detector's score, 0 to 1.
    pub score: f32,
}

/// What an observation is, as [`Tracker::associate`] decides.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Assignment {
    /// Track `id` (unseen this frame), re-acquired or caught up.
    Track(u32),
    /// A new person: [`Tracker::born`] starts the track once it is confirmed there.
    Birth,
    /// A low score on nobody: a new person only if a second opinion finds one there
    /// (the image detector's landmark model: a face where the person detector saw one,
    /// on nobody's body); then [`Tracker::born`] starts the track.
    /// ByteTrack never starts a track from a low score, having no second opinion
    /// ([`Tracker::frame_of_boxes`] does not either): here the track must still be
    /// followed by its landmarks for `birth_frames` frames before it is reported.
    Candidate,
    /// A person already seen this frame, a low score on someone seen this frame, or no
    /// room.
    Ignored,
}

/// What the tracker did so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct TrackerStats {
    /// Tracks started.
    pub births: u64,
    /// Of these, confirmed (reported).
    pub confirmed: u64,
    /// Tracks ended: unseen longer than `lost_frames`, or never confirmed.
    pub deaths: u64,
    /// Lost tracks found again with their id.
    pub reacquisitions: u64,
    /// Tracks dropped as a second track on a person already tracked.
    pub duplicates: u64,
    /// Confident boxes of new people ignored for want of room (`max_people`).
    pub no_room: u64,
    /// Newcomers given a lost or remembered person's id by their look.
    pub reidentified: u64,
    /// Ended tracks forgotten for want of room (`reid_capacity`).
    pub forgotten: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Tentative,
    Confirmed,
}

#[derive(Debug, Clone)]
struct Track {
    id: u32,
    state: State,
    /// The newest box seen.
    region: CropBox,
    /// Pixels per frame of the box's centre.
    velocity: [f64; 2],
    /// Frames seen in a row.
    hits: u32,
    /// Frames unseen in a row (0 while followed).
    misses: u32,
    /// Its place in the order of births (older tracks win duplicates).
    born: u64,
    /// Seen this frame: where.
    seen: Option<CropBox>,
    /// When it was last seen (the tracker's clock, ns).
    seen_ns: u64,
    /// How they look, from the looks clear of other people.
    look: Option<Appearance>,
    /// Followed but not looked at this frame ([`Tracker::wait`]).
    waiting: bool,
    /// Frames in a row followed without a look.
    waited: u32,
}

impl Track {
    /// Seen this frame, or waiting for a look (there, as far as boxes go: a box on
    /// them is them, not a newcomer, and not worth a look).
    fn present(&self) -> bool {
        self.seen.is_some() || self.waiting
    }

    /// Frames from its newest box (the last seen) to this one: those missed or waited
    /// since, and this.
    fn ahead(&self) -> u32 {
        self.misses.saturating_add(self.waited).saturating_add(1)
    }

    /// Where the track is expected `frames` after its newest box: moved by its velocity,
    /// grown by 10 % a frame unseen (the longer it is gone, the less sure where). The
    /// side is not extrapolated: a box that follows its own landmarks would feed its
    /// growth back into itself.
    fn predicted(&self, frames: u32) -> CropBox {
        let f = f64::from(frames);
        let (cx, cy, side) = centre_side(&self.region);
        let grown = side * (1.0 + 0.1 * f64::from(self.misses));
        let centre = [cx + self.velocity[0] * f, cy + self.velocity[1] * f];
        CropBox {
            x0: centre[0] - 0.5 * grown,
            y0: centre[1] - 0.5 * grown,
            width: grown,
            height: grown,
        }
    }
}

/// The clock's step for a frame without a stamp ([`Tracker::begin`]).
const FRAME_NS: u64 = 33_333_333;
/// How far a track's look moves towards each clear look of it.
const LOOK_RATE: f32 = 0.1;

/// Remembers an ended track `t` in `memory` (a confirmed one with a look; at most
/// `capacity`); returns how many were forgotten for want of room.
fn remember(memory: &mut reid::Memory, t: &Track, capacity: usize) -> u64 {
    match (&t.look, t.state) {
        (Some(look), State::Confirmed) => memory.remember(
            reid::Remembered {
                id: t.id,
                born: t.born,
                region: t.region,
                seen_ns: t.seen_ns,
                look: *look,
            },
            capacity,
        ),
        _ => 0,
    }
}

fn centre_side(b: &CropBox) -> (f64, f64, f64) {
    (
        b.x0 + 0.5 * b.width,
        b.y0 + 0.5 * b.height,
        0.5 * (b.width + b.height),
    )
}

/// Intersection over union of two boxes (0 for disjoint or empty ones).
pub fn iou(a: &CropBox, b: &CropBox) -> f64 {
    let w = (a.x0 + a.width).min(b.x0 + b.width) - a.x0.max(b.x0);
    let h = (a.y0 + a.height).min(b.y0 + b.height) - a.y0.max(b.y0);
    if w.is_nan() || h.is_nan() || w <= 0.0 || h <= 0.0 {
        return 0.0;
    }
    let inter = w * h;
    let union = a.width * a.height + b.width * b.height - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// The tracks of the people in view.
#[derive(Debug, Clone)]
pub struct Tracker {
    settings: TrackingSettings,
    /// The person detector's confident score.
    detection_threshold: f32,
    tracks: Vec<Track>,
    /// Ended tracks that may come back.
    memory: reid::Memory,
    next_id: u32,
    frame: u64,
    /// The current frame's stamp (ns; never runs backwards).
    now_ns: u64,
    /// The frame the scene began (its tracks are confirmed at once).
    scene_start: u64,
    frames_since_detection: u32,
    lost_this_frame: bool,
    /// Tracks [`Tracker::associate`] gave boxes this frame (not evicted for newcomers).
    claimed: Vec<u32>,
    stats: TrackerStats,
}

impl Tracker {
    /// A tracker with no tracks; `detection_threshold` is the person detector's
    /// confident score (boxes below it are the low-score pass).
    pub fn new(mut settings: TrackingSettings, detection_threshold: f32) -> Self {
        // The low-score pass lies below the confident one.
        settings.low_threshold = settings.low_threshold.min(detection_threshold);
        Self {
            settings,
            detection_threshold,
            tracks: Vec::new(),
            memory: reid::Memory::default(),
            next_id: 1,
            frame: 0,
            now_ns: 0,
            scene_start: 1,
            frames_since_detection: u32::MAX,
            lost_this_frame: false,
            claimed: Vec::new(),
            stats: TrackerStats::default(),
        }
    }

    /// The low-score pass's threshold.
    pub fn low_threshold(&self) -> f32 {
        self.settings.low_threshold
    }

    /// What it did so far.
    pub fn stats(&self) -> TrackerStats {
        self.stats
    }

    /// Ends every track (counted) and forgets them; the next frame is a new scene's
    /// first.
    pub fn reset(&mut self) {
        self.stats.deaths += self.tracks.len() as u64;
        self.tracks.clear();
        self.memory.clear();
        self.scene_start = self.frame + 1;
        self.frames_since_detection = u32::MAX;
    }

    /// Starts a frame without a stamp: 1/30 s after the one before.
    pub fn begin(&mut self) {
        self.begin_at(self.now_ns.saturating_add(FRAME_NS));
    }

    /// Starts a frame stamped `stamp_ns`; a stamp not after the newest (unset, or a
    /// replay starting over) is taken as 1/30 s after it: the clock never stops or runs
    /// backwards. Ended tracks last seen more than `reid_seconds` ago are forgotten.
    pub fn begin_at(&mut self, stamp_ns: u64) {
        self.now_ns = if stamp_ns > self.now_ns {
            stamp_ns
        } else {
            self.now_ns.saturating_add(FRAME_NS)
        };
        self.memory
            .forget_before(self.now_ns, self.settings.reid_seconds);
        self.frame += 1;
        self.lost_this_frame = false;
        self.claimed.clear();
        for t in &mut self.tracks {
            t.seen = None;
            t.waiting = false;
        }
    }

    /// The tracks to follow this frame (those seen in the previous one): id and box
    /// expected now.
    pub fn predictions(&self) -> impl Iterator<Item = (u32, CropBox)> + '_ {
        self.tracks
            .iter()
            .filter(|t| t.misses == 0)
            .map(|t| (t.id, t.predicted(t.ahead())))
    }

    /// Track `id` was seen this frame at `region` (the box its person fills).
    pub fn seen(&mut self, id: u32, region: CropBox) {
        if let Some(t) = self.tracks.iter_mut().find(|t| t.id == id) {
            t.seen = Some(region);
        }
    }

    /// Track `id`, followed, was not found where expected.
    pub fn missed(&mut self, id: u32) {
        if let Some(t) = self.tracks.iter_mut().find(|t| t.id == id) {
            t.seen = None;
            self.lost_this_frame |= t.misses == 0;
        }
    }

    /// Track `id`, followed, was found on a person another track has: a miss, counted
    /// as a duplicate.
    pub fn duplicate(&mut self, id: u32) {
        self.missed(id);
        self.stats.duplicates += 1;
    }

    /// Whether boxes from the person detector are wanted this frame (after the
    /// followed tracks are [`seen`](Self::seen) or [`missed`](Self::missed)).
    pub fn wants_detections(&self) -> bool {
        let followed = self.tracks.iter().filter(|t| t.present()).count();
        followed == 0
            || self.lost_this_frame
            || self.frames_since_detection >= self.settings.detect_every
    }

    /// The room left for new tracks, besides those seen this frame, those followed in
    /// the previous one and `coming_back` more: lost ones give theirs up to a newcomer.
    fn room(&self, coming_back: usize) -> usize {
        let present = self
            .tracks
            .iter()
            .filter(|t| t.misses == 0 || t.seen.is_some())
            .count();
        self.settings
            .max_people
            .saturating_sub(present + coming_back)
    }

    /// [`associate`](Self::associate) for boxes that did not come from a search of the
    /// person detector (motion's proposals): the detector's schedule (`detect_every`)
    /// goes on as if they were not there.
    pub fn associate_proposals(&mut self, observations: &[Observation]) -> Vec<Assignment> {
        let since = self.frames_since_detection;
        let out = self.associate(observations);
        self.frames_since_detection = since;
        out
    }

    /// What each of `observations` is: a track not yet seen nor waiting this frame (matched by
    /// minimum total 1 - IoU with its predicted box, confident boxes first, then the
    /// low-score ones), a new person, or nothing. Changes no track: the caller checks
    /// each and reports with [`seen`](Self::seen) or [`born`](Self::born).
    pub fn associate(&mut self, observations: &[Observation]) -> Vec<Assignment> {
        self.frames_since_detection = 0;
        let mut out = vec![Assignment::Ignored; observations.len()];
        // The best-scoring boxes only (bounds the assignment's cost on a cluttered
        // image): four per person tracked at most.
        let mut usable: Vec<usize> = (0..observations.len())
            .filter(|&i| observations[i].score >= self.settings.low_threshold)
            .collect();
        usable.sort_by(|&a, &b| observations[b].score.total_cmp(&observations[a].score));
        usable.truncate(4 * self.settings.max_people);
        let confident = |i: &usize| observations[*i].score >= self.detection_threshold;
        let (high, low): (Vec<usize>, Vec<usize>) = usable.into_iter().partition(confident);
        // Confident boxes against every track (one on a person seen this frame is that
        // person), then the low-score ones against the tracks still unseen.
        let all: Vec<usize> = (0..self.tracks.len()).collect();
        let mut taken = vec![false; self.tracks.len()];
        // Boxes matched to a person seen this frame: that person, never a newcomer.
        let mut absorbed = vec![false; observations.len()];
        for (i, k) in self.assign(observations, &high, &all) {
            taken[k] = true;
            if !self.tracks[k].present() {
                out[i] = Assignment::Track(self.tracks[k].id);
            } else {
                absorbed[i] = true;
            }
        }
        // Low-scoring boxes against the tracks still unseen, then those left against
        // the people seen this frame: on one of them, that person again (not a
        // candidate newcomer).
        let open: Vec<usize> = all
            .iter()
            .copied()
            .filter(|&k| !taken[k] && !self.tracks[k].present())
            .collect();
        for (i, k) in self.assign(observations, &low, &open) {
            out[i] = Assignment::Track(self.tracks[k].id);
            taken[k] = true;
        }
        let left: Vec<usize> = low
            .iter()
            .copied()
            .filter(|&i| out[i] == Assignment::Ignored)
            .collect();
        let seen: Vec<usize> = all
            .iter()
            .copied()
            .filter(|&k| !taken[k] && self.tracks[k].present())
            .collect();
        for (i, _) in self.assign(observations, &left, &seen) {
            absorbed[i] = true;
        }
        // Confident boxes left, not on a person seen this frame: new people, best
        // first, while there is room.
        let matched: Vec<bool> = (0..observations.len())
            .map(|i| out[i] != Assignment::Ignored || absorbed[i])
            .collect();
        for a in &out {
            if let Assignment::Track(id) = a {
                self.claimed.push(*id);
            }
        }
        let coming_back = self
            .tracks
            .iter()
            .filter(|t| t.misses > 0 && self.claimed.contains(&t.id))
            .count();
        let on_nobody = |&i: &usize| {
            !matched[i]
                && !self.tracks.iter().enumerate().any(|(k, t)| {
                    let on = t.seen.unwrap_or_else(|| t.predicted(t.ahead()));
                    (taken[k] || t.present())
                        && iou(&on, &observations[i].region) > self.settings.duplicate_iou
                })
        };
        // Confident boxes first, then the low-scoring candidates, each best first (the
        // passes are sorted by score already).
        let births: Vec<usize> = high.iter().copied().filter(on_nobody).collect();
        let candidates: Vec<usize> = low.iter().copied().filter(on_nobody).collect();
        let room = self.room(coming_back);
        tracing::debug!(
            "associate: boxes {:?} tracks {:?} -> {out:?}, births {births:?}, candidates \
             {candidates:?}, room {room}",
            observations
                .iter()
                .map(|o| (
                    o.score,
                    o.region.x0 as i64,
                    o.region.y0 as i64,
                    o.region.width as i64
                ))
                .collect::<Vec<_>>(),
            self.tracks
                .iter()
                .map(|t| (
                    t.id,
                    t.misses,
                    t.seen.is_some(),
                    t.region.x0 as i64,
                    t.region.width as i64
                ))
                .collect::<Vec<_>>()
        );
        let newcomers = births
            .into_iter()
            .map(|i| (i, Assignment::Birth))
            .chain(candidates.into_iter().map(|i| (i, Assignment::Candidate)));
        for (n, (i, what)) in newcomers.enumerate() {
            if n < room {
                out[i] = what;
            } else if what == Assignment::Birth {
                self.stats.no_room += 1;
            }
        }
        out
    }

    /// The minimum-cost matching of observations `obs` to tracks `open` (indices into
    /// both), each pair overlapping by at least `match_iou`: a track seen this frame by
    /// where it was seen, others by where they are expected.
    fn assign(
        &self,
        observations: &[Observation],
        obs: &[usize],
        open: &[usize],
    ) -> Vec<(usize, usize)> {
        if obs.is_empty() || open.is_empty() {
            return Vec::new();
        }
        // Square: rows observations, columns tracks, padding costs more than any pair.
        const SCALE: f64 = 1e6;
        let n = obs.len().max(open.len());
        let gate = self.settings.match_iou;
        let expected: Vec<CropBox> = open
            .iter()
            .map(|&k| {
                let t = &self.tracks[k];
                t.seen.unwrap_or_else(|| t.predicted(t.ahead()))
            })
            .collect();
        let overlap = |i: usize, k: usize| iou(&observations[obs[i]].region, &expected[k]);
        let cost = Matrix::from_fn(n, n, |(i, k)| {
            if i < obs.len() && k < open.len() && overlap(i, k) >= gate {
                ((1.0 - overlap(i, k)) * SCALE).round() as i64
            } else {
                SCALE as i64 + 1
            }
        });
        let (_, columns) = kuhn_munkres_min(&cost);
        columns
            .into_iter()
            .enumerate()
            .filter(|&(i, k)| i < obs.len() && k < open.len() && overlap(i, k) >= gate)
            .map(|(i, k)| (obs[i], open[k]))
            .collect()
    }

    /// A new person seen at `region` this frame: their track's id; `None` (counted as
    /// `no_room`) when `max_people` tracks are seen this frame, were followed in the
    /// previous one or were given a box by [`associate`](Self::associate). Room is made
    /// by ending the track lost longest.
    pub fn born(&mut self, region: CropBox) -> Option<u32> {
        self.born_like(region, None)
    }

    /// [`born`](Self::born) for a newcomer who looks like `look`: a confirmed track lost
    /// (not given a box this frame) or an ended one remembered, whose look is within
    /// `reid_distance` of it and who could have gone to `region` since last seen, is
    /// found again with its id: the least look distance plus a tenth of the way moved
    /// over the reach (a lost track before a remembered one at equal cost), counted as
    /// `reidentified` (a lost track's also as a `reacquisition`). They were confirmed
    /// before: their track is reported at once.
    pub fn born_like(&mut self, region: CropBox, look: Option<&Appearance>) -> Option<u32> {
        // Room first: a lost track ended for it is remembered, and may be this person.
        if !self.make_room() {
            return None;
        }
        if let Some(look) = look
            && let Some(id) = self.reidentify(region, look)
        {
            return Some(id);
        }
        // Never 0 (no id, in HeatMaps), nor an id live or remembered.
        let mut id = self.next_id;
        while id == 0 || self.tracks.iter().any(|t| t.id == id) || self.memory.holds(id) {
            id = id.wrapping_add(1);
        }
        self.next_id = id.wrapping_add(1);
        self.stats.births += 1;
        self.tracks.push(Track {
            id,
            state: State::Tentative,
            region,
            velocity: [0.0; 2],
            hits: 0,
            misses: 0,
            born: self.stats.births,
            seen: Some(region),
            seen_ns: self.now_ns,
            look: None,
            waiting: false,
            waited: 0,
        });
        Some(id)
    }

    /// Ends the track lost longest (remembered) while `max_people` tracks live; `false`
    /// (counted as `no_room`) when none can end.
    fn make_room(&mut self) -> bool {
        while self.tracks.len() >= self.settings.max_people {
            let Some(k) = (0..self.tracks.len())
                .filter(|&k| {
                    let t = &self.tracks[k];
                    t.seen.is_none() && t.misses > 0 && !self.claimed.contains(&t.id)
                })
                .max_by_key(|&k| self.tracks[k].misses)
            else {
                self.stats.no_room += 1;
                return false;
            };
            let t = self.tracks.swap_remove(k);
            self.stats.deaths += 1;
            self.stats.forgotten += remember(&mut self.memory, &t, self.settings.reid_capacity);
        }
        true
    }

    /// The lost or remembered person a newcomer at `region` looking like `look` is, if
    /// anyone: their track seen there, its id.
    fn reidentify(&mut self, region: CropBox, look: &Appearance) -> Option<u32> {
        let (now, gate) = (self.now_ns, self.settings.reid_distance);
        if gate <= 0.0 {
            return None;
        }
        let lost = self
            .tracks
            .iter()
            .enumerate()
            .filter(|(_, t)| {
                t.state == State::Confirmed
                    && t.seen.is_none()
                    && t.misses > 0
                    && !self.claimed.contains(&t.id)
            })
            .filter_map(|(k, t)| {
                let c = reid::cost(
                    t.look.as_ref()?,
                    &t.region,
                    t.seen_ns,
                    look,
                    &region,
                    now,
                    gate,
                )?;
                Some((k, c))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let remembered = self.memory.best(look, &region, now, gate);
        let id = match (lost, remembered) {
            (Some((k, c)), r) if r.is_none_or(|(_, rc)| c <= rc) => {
                let t = &mut self.tracks[k];
                t.seen = Some(region);
                t.id
            }
            (_, Some((i, _))) => {
                // Room was made by `born_like`.
                let person = self.memory.take(i)?;
                self.tracks.push(Track {
                    id: person.id,
                    state: State::Confirmed,
                    region,
                    velocity: [0.0; 2],
                    hits: 0,
                    misses: 0,
                    born: person.born,
                    seen: Some(region),
                    seen_ns: now,
                    look: Some(person.look),
                    waiting: false,
                    waited: 0,
                });
                person.id
            }
            _ => return None,
        };
        tracing::debug!("reid: a newcomer at {region:?} is {id}");
        self.claimed.push(id);
        self.stats.reidentified += 1;
        Some(id)
    }

    /// Track `id` looked like `look` this frame, clear of other people (the caller
    /// gives only such looks: a look beside someone is not taken, the track's kept as it
    /// was): its look moves towards this one (the first one taken whole).
    pub fn looked_like(&mut self, id: u32, look: &Appearance) {
        if let Some(t) = self.tracks.iter_mut().find(|t| t.id == id) {
            match &mut t.look {
                Some(mine) => mine.blend(look, LOOK_RATE),
                None => t.look = Some(*look),
            }
        }
    }

    /// Ended tracks remembered now.
    pub fn remembered(&self) -> usize {
        self.memory.len()
    }

    /// A whole frame of unlabelled boxes, nothing followed (the boxes are all there
    /// is): [`begin`](Self::begin), [`associate`](Self::associate), the tracks found
    /// again, the newcomers, [`end`](Self::end). Returns each box's reported track id
    /// (`None`: not reported: ignored, refused, or a track not yet confirmed).
    pub fn frame_of_boxes(&mut self, observations: &[Observation]) -> Vec<Option<u32>> {
        self.begin();
        self.boxes_seen(observations)
    }

    /// The boxes of a frame begun: [`associate`](Self::associate), the tracks found
    /// again, the newcomers, [`end`](Self::end); each box's reported track id.
    fn boxes_seen(&mut self, observations: &[Observation]) -> Vec<Option<u32>> {
        let what = self.associate(observations);
        let mut ids = vec![None; observations.len()];
        for (i, (o, a)) in observations.iter().zip(&what).enumerate() {
            if let Assignment::Track(id) = a {
                self.seen(*id, o.region);
                ids[i] = Some(*id);
            }
        }
        for (i, (o, a)) in observations.iter().zip(&what).enumerate() {
            if *a == Assignment::Birth {
                ids[i] = self.born(o.region);
            }
        }
        let reported: Vec<u32> = self.end().into_iter().map(|(id, _)| id).collect();
        for id in &mut ids {
            if id.is_some_and(|i| !reported.contains(&i)) {
                *id = None;
            }
        }
        ids
    }

    /// Ends the frame: misses counted, lost tracks ended, confirmations. Returns the
    /// confirmed tracks seen this frame (id, box), oldest
    /// first.
    pub fn end(&mut self) -> Vec<(u32, CropBox)> {
        self.frames_since_detection = self.frames_since_detection.saturating_add(1);
        self.tracks.sort_by_key(|t| t.born);
        let first_of_scene = self.frame == self.scene_start;
        let (birth, lost) = (self.settings.birth_frames, self.settings.lost_frames);
        let mut out = Vec::new();
        let stats = &mut self.stats;
        let (memory, now_ns, capacity) =
            (&mut self.memory, self.now_ns, self.settings.reid_capacity);
        self.tracks.retain_mut(|t| match t.seen {
            Some(now) => {
                t.seen_ns = now_ns;
                // From the last box seen, over the frames missed or waited since.
                let gap = f64::from(t.ahead());
                let (a, b) = (centre_side(&t.region), centre_side(&now));
                let step = [(b.0 - a.0) / gap, (b.1 - a.1) / gap];
                if t.hits > 0 || t.misses > 0 {
                    for (v, s) in t.velocity.iter_mut().zip(step) {
                        *v = 0.5 * *v + 0.5 * s;
                    }
                }
                if t.misses > 0 {
                    stats.reacquisitions += 1;
                }
                t.region = now;
                t.hits = t.hits.saturating_add(1);
                t.misses = 0;
                t.waited = 0;
                if t.state == State::Tentative && (t.hits >= birth || first_of_scene) {
                    t.state = State::Confirmed;
                    stats.confirmed += 1;
                }
                if t.state == State::Confirmed {
                    out.push((t.id, now));
                }
                true
            }
            // Not looked at (the schedule's): neither seen nor missed; expected where
            // its velocity takes it from the box last seen.
            None if t.waiting => {
                t.waited = t.waited.saturating_add(1);
                true
            }
            None => {
                t.hits = 0;
                t.misses = t.misses.saturating_add(1);
                let keep = t.state == State::Confirmed && t.misses <= lost;
                if !keep {
                    stats.deaths += 1;
                    stats.forgotten += remember(memory, t, capacity);
                }
                keep
            }
        });
        out
    }

    /// Whether track `id` is live (followed, tentative, or lost but not yet ended).
    pub fn is_live(&self, id: u32) -> bool {
        self.tracks.iter().any(|t| t.id == id)
    }

    /// Live tracks (followed, tentative or lost but not yet ended).
    pub fn len(&self) -> usize {
        self.tracks.len()
    }

    /// No live track.
    pub fn is_empty(&self) -> bool {
        self.tracks.is_empty()
    }
}

#[cfg(test)]
mod tests;
