//! One look of the landmark model at a box ([`Look`], the runs of [`ImageDetector::look_all`])
//! and the geometry of boxes, faces and bodies the detector's stages judge looks by
//! (heads, masks, jumps, parts, one person seen twice), with what the stages pass
//! between them ([`Sighting`], [`Head`], [`Found`]).

use std::time::Instant;

use rayon::prelude::*;

use super::{DetectorError, ImageDetector};
use crate::appearance::Appearance;
use crate::crop::{box_from_alignment, crop_input, mask_input};
use crate::images::ImageFrame;
use crate::models::landmarks::INPUT_SIZE;
use crate::models::litert::Landmarks;
use crate::tracker::{Observation, iou};
use posestream_base::CropBox;

/// BlazePose's alignment landmarks: the hips' midpoint and the body circle's scale point.
const ALIGNMENT: [usize; 2] = [33, 34];
/// Values per landmark in the model's output (x, y, z, visibility, presence).
const LANDMARK_VALUES: usize = 5;
/// BlazePose's body landmarks (the rest are auxiliary).
pub(super) const BODY_LANDMARKS: usize = 33;
/// Landmarks spread over less than this fraction of the crop's side: collapsed to a
/// point, the box has drifted off its person.
const COLLAPSED_SPREAD: f64 = 0.05;
/// Person-detector boxes from different search regions overlapping more than this
/// (IoU) are one person.
pub(super) const SAME_PERSON_IOU: f64 = 0.4;
/// Landmarks closer than this fraction of the body's extent, on average: one person.
const SAME_PERSON_DISTANCE: f64 = 0.15;
/// Faces closer than this fraction of the body's extent, on average: one person.
const SAME_FACE_DISTANCE: f64 = 0.3;
/// BlazePose's face landmarks (nose, eyes, ears, mouth) come first.
pub(super) const FACE_LANDMARKS: usize = 11;
/// A head's side over the person's height.
pub(super) const HEAD_PER_HEIGHT: f64 = 0.15;
/// The margin around a pedestrian box kept visible to the landmark model (the rest of
/// its crop blacked out), as a share of the box's height: across, and half that
/// above and below.
const BODY_MARGIN: f64 = 0.1;
/// A newcomer's look whose body landmarks lie within someone's (this share of them)...
const PART_INSIDE: f64 = 0.9;
/// ... and span at most this share of their height is a part of them (`part_of`).
const PART_HEIGHT: f64 = 0.75;
/// The head's side over the face landmarks' extent (nose, eyes, ears, mouth: the ears
/// span about two thirds of a head).
const HEAD_PER_FACE: f64 = 2.0;
/// A face the landmark model finds and the person detector's head box differ in size by
/// at most this factor when they are the same head.
const HEAD_SIZE_RATIO: f64 = 3.0;

/// One model run on one box.
pub(super) struct Look {
    pub(super) crop: CropBox,
    pub(super) pose_flag: f32,
    /// The box the landmarks give for the next frame.
    pub(super) next_box: Option<CropBox>,
    /// The body landmarks' extent over the crop's side.
    pub(super) spread: f64,
    /// The body landmarks, image pixels.
    pub(super) points: Vec<[f64; 2]>,
    /// Where the head is: a square around the face landmarks, image pixels.
    pub(super) face: Option<CropBox>,
    pub(super) logits: Vec<f32>,
    pub(super) seconds: f64,
}

impl Look {
    /// Where the person is, if there is one: the pose flag at least `threshold`, a box
    /// from the landmarks, the landmarks not collapsed.
    pub(super) fn person(&self, threshold: f32) -> Option<CropBox> {
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

impl ImageDetector {
    /// The landmark model on each of `boxes` of `frame`, in parallel, each with its
    /// `masks` (other people's heads) blacked out.
    pub(super) fn look_all(
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
}

/// The head around face landmarks `face`: a square twice their extent, centred on them.
pub(super) fn head_box(face: &[[f64; 2]]) -> Option<CropBox> {
    let (lo, hi) = extent(face);
    let side = HEAD_PER_FACE * (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    CropBox::new(centre[0] - 0.5 * side, centre[1] - 0.5 * side, side, side).ok()
}

/// The heads of other people to black out in a look at a person whose head is `own`:
/// every one of `heads` that does not overlap it (a head that does may be the person's
/// own, seen by another track); none when `own` is unknown (any might be theirs).
pub(super) fn masks_for(
    own: Option<&CropBox>,
    heads: impl Iterator<Item = CropBox>,
) -> Vec<CropBox> {
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
pub(super) fn head_jump<'a>(
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
pub(super) fn same_sighting(a: &Sighting, b: &Sighting) -> bool {
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
pub(super) fn part_of(whole: &Look, part: &Look) -> bool {
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
pub(super) fn around(body: &CropBox, crop: &CropBox) -> Vec<CropBox> {
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
pub(super) fn box_iou(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    let w = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let h = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = w * h;
    let union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// The centre of `b`.
pub(super) fn centre(b: &CropBox) -> [f64; 2] {
    [b.x0 + 0.5 * b.width, b.y0 + 0.5 * b.height]
}

/// Whether `p` lies in `b`.
pub(super) fn contains(b: &CropBox, p: [f64; 2]) -> bool {
    (b.x0..=b.x0 + b.width).contains(&p[0]) && (b.y0..=b.y0 + b.height).contains(&p[1])
}

/// Whether `p` lies within the extent of `look`'s body landmarks.
pub(super) fn within_body(look: &Look, p: [f64; 2]) -> bool {
    let (lo, hi) = extent(&look.points);
    (lo[0]..=hi[0]).contains(&p[0]) && (lo[1]..=hi[1]).contains(&p[1])
}

/// A look confirms a low-scoring detection (a candidate newcomer): the landmark model
/// found a face where the person detector saw one (its centre inside the detector's
/// head box), of a like size (within a factor `HEAD_SIZE_RATIO`), and not within the
/// body of anyone in `present` (their landmarks' extent). The lite model, shown a
/// hand held out that the detector took for a face at a low score, finds a whole
/// small person there, face on the hand, with a confident pose flag.
pub(super) fn confirms<'a>(
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

/// BlazePose's shoulders, hips, knees and ankles (left, right).
const SHOULDERS: [usize; 2] = [11, 12];
const HIPS: [usize; 2] = [23, 24];
const KNEES: [usize; 2] = [25, 26];
const ANKLES: [usize; 2] = [27, 28];
/// A part's box is at least this share of its height wide (a body seen from the side).
const PART_MIN_WIDTH: f64 = 0.4;
/// The middle share of a part's width sampled (the rest may be background).
const PART_MIDDLE: f64 = 0.6;

/// What the person of `look` looks like in `frame` ([`Appearance`]): the torso from the
/// shoulders to the hips, the legs from the hips to mid-shin, each the middle of its
/// landmarks' width; `None` where neither part is in the image.
pub(super) fn appearance(frame: &ImageFrame, look: &Look) -> Option<Appearance> {
    let p = &look.points;
    if p.len() < BODY_LANDMARKS {
        return None;
    }
    let mean_y = |pair: [usize; 2]| 0.5 * (p[pair[0]][1] + p[pair[1]][1]);
    let (top, hips) = (mean_y(SHOULDERS), mean_y(HIPS));
    let shins = 0.5 * (mean_y(KNEES) + mean_y(ANKLES));
    let part = |joints: &[usize], y0: f64, y1: f64| {
        let (lo, hi) = joints
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &j| {
                (lo.min(p[j][0]), hi.max(p[j][0]))
            });
        let height = y1 - y0;
        let width = (hi - lo).max(PART_MIN_WIDTH * height) * PART_MIDDLE;
        let middle = 0.5 * (lo + hi);
        [middle - 0.5 * width, y0, middle + 0.5 * width, y1]
    };
    let torso_joints = [SHOULDERS[0], SHOULDERS[1], HIPS[0], HIPS[1]];
    let legs_joints = [HIPS[0], HIPS[1], KNEES[0], KNEES[1]];
    // The torso below the neck, the legs below the hips' line.
    let neck = 0.1 * (hips - top);
    Appearance::of(
        &frame.rgb,
        part(&torso_joints, top + neck, hips),
        part(&legs_joints, hips + neck, shins),
    )
}

/// Whether the body of `look` (its landmarks' extent, grown by `BODY_MARGIN`) is clear
/// of every one of `others`' bodies.
pub(super) fn clear_of<'a>(look: &Look, mut others: impl Iterator<Item = &'a Look>) -> bool {
    let (lo, hi) = extent(&look.points);
    let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
    let grown = [
        lo[0] - BODY_MARGIN * w,
        lo[1] - BODY_MARGIN * h,
        hi[0] + BODY_MARGIN * w,
        hi[1] + BODY_MARGIN * h,
    ];
    !others.any(|o| {
        let (a, b) = extent(&o.points);
        a[0] < grown[2] && b[0] > grown[0] && a[1] < grown[3] && b[1] > grown[1]
    })
}

/// The corners of the box around `points`.
pub(super) fn extent(points: &[[f64; 2]]) -> ([f64; 2], [f64; 2]) {
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
pub(super) fn same_person(a: &Look, b: &Look) -> bool {
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
pub(super) struct Sighting {
    pub(super) observation: Observation,
    pub(super) head: Option<CropBox>,
    pub(super) body: Option<CropBox>,
}

/// Where a person's head was last seen, and the frame.
pub(super) struct Head {
    pub(super) id: u32,
    pub(super) region: CropBox,
    pub(super) seen: u64,
}

/// One person's heat maps, from their newest look (kept while they are tracked: a
/// person waiting for a look gets them again, moved; `track_id` 0: a free slot).
pub(super) struct Found {
    /// The box the maps cover.
    pub(super) crop: CropBox,
    /// The box the person filled then (the tracker's).
    pub(super) person: CropBox,
    pub(super) track_id: u32,
    pub(super) maps: Vec<f32>,
    /// Frames since the look the maps are of.
    pub(super) frames_since_look: u32,
}
