//! Scores skeletons found in real footage against boxes annotated by eye
//! (`benches/footage/*.json`, made with `annotate.py`; docs/evaluation.md).
//!
//! - A skeleton is **on** a person when the median of its 2D joints falls inside the
//!   person's box grown by 15 % on each side; in a frame each box takes at most one
//!   skeleton and each skeleton one box (the nearest box centre first).
//! - **Counted** people are at least [`MIN_HEIGHT`] px tall and not `uncertain` (less
//!   than half of the body in view). Recall is over them. A skeleton on someone not
//!   counted (small, mostly hidden) is neither right nor wrong; a skeleton on nobody is
//!   a false one. Precision = skeletons on counted people / skeletons on counted people or
//!   on nobody.
//! - **IDF1** (Ristani et al. 2016) over the counted people and those skeletons: the
//!   one-to-one map from annotated ids to track ids that maximises the frames where a
//!   track's skeleton is on its person (IDTP); IDF1 = 2 IDTP / (annotated + skeletons).
//! - **Id switches**: per person, the times the track on them (frame by frame, the frames
//!   they are counted) changes to another track; reported per person per 200 frames of
//!   the clip they span.
//!
//! Shared by `benches/footage.rs` (the README's table) and `tests/images.rs` (CI).

#![allow(dead_code, reason = "each includer uses a part")]

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use pathfinding::kuhn_munkres::kuhn_munkres;
use pathfinding::matrix::Matrix;
use serde::Deserialize;

/// People shorter than this (px) are not counted: the "at least 60 px tall".
pub const MIN_HEIGHT: f64 = 60.0;
/// Boxes grow by this fraction of their size on each side for the "on" test.
pub const GROW: f64 = 0.15;

/// One annotated clip.
#[derive(Debug, Clone, Deserialize)]
pub struct Clip {
    /// The video's file name.
    pub clip: String,
    /// Where it comes from.
    #[serde(default)]
    pub source: String,
    /// Frame size.
    pub width: u32,
    /// Frame size.
    pub height: u32,
    /// Frame rate (frame `n` is stamped `n / fps` s by a video source).
    pub fps: f64,
    /// The annotated frames.
    pub frames: Vec<Frame>,
}

/// An annotated frame.
#[derive(Debug, Clone, Deserialize)]
pub struct Frame {
    /// Its index in decoding order, from 0.
    pub frame: u64,
    /// Everyone in view.
    pub people: Vec<Person>,
}

/// A person's box.
#[derive(Debug, Clone, Deserialize)]
pub struct Person {
    /// Kept across the clip's frames.
    pub id: u32,
    /// `[x0, y0, x1, y1]`, image pixels.
    #[serde(rename = "box")]
    pub bbox: [f64; 4],
    /// Less than half of the body in view, or not sure it is a person.
    #[serde(default)]
    pub uncertain: bool,
}

impl Person {
    /// Counted for recall.
    pub fn counted(&self) -> bool {
        !self.uncertain && self.bbox[3] - self.bbox[1] >= MIN_HEIGHT
    }

    fn holds(&self, p: (f64, f64)) -> bool {
        let (w, h) = (self.bbox[2] - self.bbox[0], self.bbox[3] - self.bbox[1]);
        p.0 >= self.bbox[0] - GROW * w
            && p.0 <= self.bbox[2] + GROW * w
            && p.1 >= self.bbox[1] - GROW * h
            && p.1 <= self.bbox[3] + GROW * h
    }

    fn centre(&self) -> (f64, f64) {
        (
            (self.bbox[0] + self.bbox[2]) / 2.0,
            (self.bbox[1] + self.bbox[3]) / 2.0,
        )
    }
}

impl Clip {
    /// Reads an annotation file.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// A skeleton as the scorer sees it: its frame, track and the median of its 2D joints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Found {
    /// Frame index.
    pub frame: u64,
    /// Track id.
    pub track: u32,
    /// Median of the 2D joints, image pixels.
    pub at: (f64, f64),
}

/// The scores of one clip.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Scores {
    /// Annotated frames.
    pub frames: usize,
    /// Counted people, summed over the frames.
    pub counted: usize,
    /// Counted people with a skeleton on them.
    pub found: usize,
    /// Skeletons on nobody.
    pub false_skeletons: usize,
    /// Skeletons on people not counted.
    pub ignored: usize,
    /// found / counted.
    pub recall: f64,
    /// found / (found + false).
    pub precision: f64,
    /// IDF1 over the counted people.
    pub idf1: f64,
    /// Id switches, all people.
    pub id_switches: usize,
    /// The most switches of one person per 200 frames.
    pub worst_switches_per_200: f64,
    /// Counted people per annotated frame.
    pub people_per_frame: f64,
    /// Recall by the person's height: found and counted in [60, 80), [80, 100), [100, ...) px.
    pub by_height: [(usize, usize); 3],
}

/// The height band of a box (index into [`Scores::by_height`]).
fn band(p: &Person) -> usize {
    let h = p.bbox[3] - p.bbox[1];
    if h < 80.0 {
        0
    } else if h < 100.0 {
        1
    } else {
        2
    }
}

/// The one-to-one matches of a frame: (person index, skeleton index).
fn matches(people: &[Person], found: &[&Found]) -> Vec<(usize, usize)> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, p) in people.iter().enumerate() {
        for (j, f) in found.iter().enumerate() {
            if p.holds(f.at) {
                let c = p.centre();
                let h = (p.bbox[3] - p.bbox[1]).max(1.0);
                pairs.push((
                    ((c.0 - f.at.0).powi(2) + (c.1 - f.at.1).powi(2)).sqrt() / h,
                    i,
                    j,
                ));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_p, mut used_f) = (BTreeSet::new(), BTreeSet::new());
    let mut out = Vec::new();
    for (_, i, j) in pairs {
        if !used_p.contains(&i) && !used_f.contains(&j) {
            used_p.insert(i);
            used_f.insert(j);
            out.push((i, j));
        }
    }
    out
}

/// Scores `found` (every skeleton of the clip's run) against `clip`.
pub fn score(clip: &Clip, found: &[Found]) -> Scores {
    let mut s = Scores {
        frames: clip.frames.len(),
        ..Scores::default()
    };
    // Per (annotated id, track): frames on them. Per id: the track frame by frame.
    let mut together: BTreeMap<(u32, u32), usize> = BTreeMap::new();
    let mut counted_skeletons = 0usize;
    let mut tracks_on: BTreeMap<u32, Vec<(u64, u32)>> = BTreeMap::new();
    let mut span: BTreeMap<u32, (u64, u64)> = BTreeMap::new();
    for frame in &clip.frames {
        let here: Vec<&Found> = found.iter().filter(|f| f.frame == frame.frame).collect();
        let pairs = matches(&frame.people, &here);
        s.counted += frame.people.iter().filter(|p| p.counted()).count();
        for p in frame.people.iter().filter(|p| p.counted()) {
            s.by_height[band(p)].1 += 1;
        }
        for p in &frame.people {
            let e = span.entry(p.id).or_insert((frame.frame, frame.frame));
            e.0 = e.0.min(frame.frame);
            e.1 = e.1.max(frame.frame);
        }
        for (j, _) in here.iter().enumerate() {
            match pairs.iter().find(|&&(_, k)| k == j) {
                None => s.false_skeletons += 1,
                Some(&(i, _)) if frame.people[i].counted() => {
                    s.found += 1;
                    s.by_height[band(&frame.people[i])].0 += 1;
                    counted_skeletons += 1;
                }
                Some(_) => s.ignored += 1,
            }
        }
        for &(i, j) in &pairs {
            let p = &frame.people[i];
            if p.counted() {
                tracks_on
                    .entry(p.id)
                    .or_default()
                    .push((frame.frame, here[j].track));
                *together.entry((p.id, here[j].track)).or_default() += 1;
            }
        }
    }
    s.recall = ratio(s.found, s.counted);
    s.precision = ratio(s.found, s.found + s.false_skeletons);
    s.people_per_frame = ratio(s.counted, s.frames);
    // IDF1: the best one-to-one map of ids to tracks.
    let ids: Vec<u32> = together
        .keys()
        .map(|k| k.0)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let tracks: Vec<u32> = together
        .keys()
        .map(|k| k.1)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let idtp = if ids.is_empty() {
        0
    } else {
        let n = ids.len().max(tracks.len());
        let weights = Matrix::from_fn(n, n, |(r, c)| match (ids.get(r), tracks.get(c)) {
            (Some(&i), Some(&t)) => together.get(&(i, t)).copied().unwrap_or(0) as i64,
            _ => 0,
        });
        kuhn_munkres(&weights).0.max(0) as usize
    };
    // Skeletons that count: on counted people or on nobody.
    let skeletons = counted_skeletons + s.false_skeletons;
    s.idf1 = ratio(2 * idtp, s.counted + skeletons);
    // Switches: the track on a person changing between their matched frames.
    for (id, seen) in &tracks_on {
        let switches = seen.windows(2).filter(|w| w[0].1 != w[1].1).count();
        s.id_switches += switches;
        let (a, b) = span[id];
        let frames = (b - a).max(200) as f64;
        s.worst_switches_per_200 = s
            .worst_switches_per_200
            .max(switches as f64 * 200.0 / frames);
    }
    s
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

/// The skeletons of a recording made by `posestream run --video ... --record R`: per
/// frame and track the one with the smallest lag (the first estimate, what a live user
/// gets first), the median of its 2D joints.
pub fn found_in_recording(path: &Path, fps: f64) -> Result<Vec<Found>, String> {
    let skeletons = posestream::recording::read_topic::<posestream::msgs::Skeleton3D>(
        path,
        "/posestream/skeletons",
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    let mut best: BTreeMap<(u64, u32), (u32, Found)> = BTreeMap::new();
    for (_, s) in skeletons {
        let frame = (s.header.stamp.nanos() as f64 * fps / 1e9).round() as u64;
        let (Some(x), Some(y)) = (median_of(&s.keypoints, 0), median_of(&s.keypoints, 1)) else {
            continue;
        };
        let f = Found {
            frame,
            track: s.track_id,
            at: (x, y),
        };
        let e = best.entry((frame, s.track_id)).or_insert((s.lag, f));
        if s.lag < e.0 {
            *e = (s.lag, f);
        }
    }
    Ok(best.into_values().map(|(_, f)| f).collect())
}

/// The median of coordinate `axis` (0: x, 1: y) of interleaved 2D points, finite ones.
fn median_of(points: &[f64], axis: usize) -> Option<f64> {
    let mut v: Vec<f64> = points
        .chunks_exact(2)
        .map(|c| c[axis])
        .filter(|v| v.is_finite())
        .collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn person(id: u32, x: f64) -> Person {
        Person {
            id,
            bbox: [x, 100.0, x + 30.0, 180.0],
            uncertain: false,
        }
    }

    #[test]
    fn scores_count_what_they_say() {
        let clip = Clip {
            clip: "c".into(),
            source: String::new(),
            width: 640,
            height: 480,
            fps: 10.0,
            frames: (0..4)
                .map(|f| Frame {
                    frame: f * 10,
                    people: vec![person(1, 0.0), person(2, 100.0)],
                })
                .collect(),
        };
        let on = |frame, track, x: f64| Found {
            frame,
            track,
            at: (x + 15.0, 140.0),
        };
        // Person 1 found throughout by track 7; person 2 by 8, then 9 (a switch);
        // one false skeleton at x = 400.
        let found = vec![
            on(0, 7, 0.0),
            on(10, 7, 0.0),
            on(20, 7, 0.0),
            on(30, 7, 0.0),
            on(0, 8, 100.0),
            on(10, 8, 100.0),
            on(20, 9, 100.0),
            on(30, 9, 100.0),
            on(30, 5, 400.0),
        ];
        let s = score(&clip, &found);
        assert_eq!((s.counted, s.found, s.false_skeletons), (8, 8, 1));
        assert_eq!(s.recall, 1.0);
        assert!((s.precision - 8.0 / 9.0).abs() < 1e-12);
        // IDTP = 4 (1 -> 7) + 2 (2 -> 8 or 9) = 6; IDF1 = 12 / (8 + 9).
        assert!((s.idf1 - 12.0 / 17.0).abs() < 1e-12, "{}", s.idf1);
        assert_eq!(s.id_switches, 1);
    }
}
