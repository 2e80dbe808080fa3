//! Finding people not followed (step 2 of [`ImageDetector::detect`]): what moves that
//! nobody followed explains, the tracker's verdicts on the search's boxes and the motion
//! proposals, the landmark model's looks at them (until its box settles), and the people
//! found admitted (found again, newcomers, candidates); the places where nobody was are
//! refused for a while.

use super::looks::{
    BODY_LANDMARKS, HEAD_PER_HEIGHT, Look, SAME_PERSON_IOU, Sighting, appearance, around, centre,
    confirms, contains, extent, masks_for, part_of, same_person, within_body,
};
use super::{DetectorError, ImageDetector};
use crate::images::ImageFrame;
use crate::tracker::{Assignment, Observation, iou};
use posestream_base::CropBox;

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
/// Looks at most at a newly found person: the detector's box, then the landmarks' box
/// until it settles.
const ACQUISITION_LOOKS: usize = 3;
/// A landmark box overlapping the box looked at by more than this (IoU) has settled.
const SETTLED_IOU: f64 = 0.7;

/// The boxes to give the tracker: the search's sightings, then the motion proposals they
/// do not hold.
struct Proposed {
    /// Every box, the sightings' first.
    observations: Vec<Observation>,
    /// Where each box's person's head is, if known.
    heads: Vec<Option<CropBox>>,
    /// The body the pedestrian detector saw, of each sighting (none for the proposals).
    bodies: Vec<Option<CropBox>>,
    /// Where the proposals begin in `observations`.
    proposed_from: usize,
}

/// What is blacked out in the looks at the boxes looked at (by their place among them).
struct Masks {
    /// The other people's heads.
    heads: Vec<Vec<CropBox>>,
    /// The body the pedestrian detector saw (all around it is blacked out).
    bodies: Vec<Option<CropBox>>,
}

impl Masks {
    /// The masks of the `n`th box looked at, in a look at `crop`.
    fn at(&self, n: usize, crop: &CropBox) -> Vec<CropBox> {
        let mut masks = self.heads[n].clone();
        if let Some(body) = &self.bodies[n] {
            masks.extend(around(body, crop));
        }
        masks
    }
}

impl ImageDetector {
    /// The moving blobs of `frame` (the `now`th) that none of the people `kept` explains
    /// and that are not at a refused place, at most `MOTION_LOOKS`, the tallest first;
    /// none while motion keeps turning out to be nobody. Ages the refused places and
    /// motion's looks.
    pub(super) fn unexplained_motion(
        &mut self,
        frame: &ImageFrame,
        now: u64,
        kept: &[(u32, Look)],
    ) -> Vec<CropBox> {
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
        moving
            .into_iter()
            .filter(|_| !fruitless)
            .filter(|b| {
                let c = centre(b);
                !kept.iter().any(|(_, k)| within_body(k, c))
                    && !self.waiting.iter().any(|(_, w)| contains(w, c))
                    && !self.refused.iter().any(|(r, _)| iou(r, b) > REFUSED_IOU)
            })
            .take(MOTION_LOOKS)
            .collect()
    }

    /// Looks for people at the search's `sightings` (`searching`: there was a search)
    /// and the moving blobs `unexplained`, in `frame` (the `now`th): the tracker's
    /// verdicts, the landmark model's looks, the people found added to `kept` (found
    /// again, newcomers, a candidate confirmed), the places where nobody was refused.
    pub(super) fn acquire(
        &mut self,
        frame: &ImageFrame,
        now: u64,
        searching: bool,
        sightings: &[Sighting],
        unexplained: Vec<CropBox>,
        kept: &mut Vec<(u32, Look)>,
    ) -> Result<(), DetectorError> {
        let proposed = self.propose(sightings, unexplained);
        let mut verdicts = self.verdicts(searching, &proposed);
        self.allow_one_candidate(&mut verdicts, &proposed.heads, kept, now);
        let looked: Vec<usize> = (0..verdicts.len())
            .filter(|&i| verdicts[i] != Assignment::Ignored)
            .collect();
        let masks = acquisition_masks(&proposed, &verdicts, &looked, kept);
        let current = self.look_until_settled(frame, &proposed, &verdicts, &looked, &masks)?;
        self.trace_boxes(now, &proposed, &verdicts, &looked, &current);
        self.refuse_nobody(&current, &looked, &proposed, now);
        let proposals: Vec<usize> = looked
            .iter()
            .copied()
            .filter(|&i| i >= proposed.proposed_from)
            .collect();
        self.stats.motion_proposals += proposals.len() as u64;
        let taken = self.admit(frame, current, &looked, &verdicts, &proposed.heads, kept);
        self.judge_proposals(proposals, &taken, &proposed.observations, now);
        Ok(())
    }

    /// The search's `sightings`, then the moving blobs `unexplained` that none of them
    /// holds, each with where its person's head is.
    fn propose(&self, sightings: &[Sighting], unexplained: Vec<CropBox>) -> Proposed {
        let mut observations: Vec<Observation> = sightings.iter().map(|s| s.observation).collect();
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
        Proposed {
            observations,
            heads,
            bodies,
            proposed_from,
        }
    }

    /// The tracker's verdict on each box `proposed` (the sightings associated as a
    /// search's, else the proposals alone); the detectors' boxes at a refused place
    /// ignored.
    fn verdicts(&mut self, searching: bool, proposed: &Proposed) -> Vec<Assignment> {
        let observations = &proposed.observations;
        let mut verdicts = if searching {
            self.tracker.associate(observations)
        } else {
            self.tracker.associate_proposals(observations)
        };
        // Nor the detectors' boxes at a refused place, those matched to a lost track
        // too (looking there for them anyway found the cyclist of bikes.mp4 in 68
        // frames instead of 77: the box is not them, and their track lives on).
        for (v, o) in verdicts
            .iter_mut()
            .zip(&observations[..proposed.proposed_from])
        {
            if *v != Assignment::Ignored
                && self
                    .refused
                    .iter()
                    .any(|(r, _)| iou(r, &o.region) > REFUSED_IOU)
            {
                *v = Assignment::Ignored;
            }
        }
        verdicts
    }

    /// One candidate (the best whose face the detector saw off everyone followed, in
    /// `kept`) every `detect_every` frames at most: the other candidates of `verdicts`
    /// ignored.
    fn allow_one_candidate(
        &mut self,
        verdicts: &mut [Assignment],
        heads: &[Option<CropBox>],
        kept: &[(u32, Look)],
        now: u64,
    ) {
        let mut allowed = self
            .last_candidate
            .is_none_or(|at| now.saturating_sub(at) >= self.candidate_every);
        for (v, head) in verdicts.iter_mut().zip(heads) {
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
    }

    /// The landmark model's looks at the boxes `looked` (of `proposed`) in `frame`, each
    /// with its `masks`, `ACQUISITION_LOOKS` at most: the last look that found a
    /// person, or `None`.
    fn look_until_settled(
        &mut self,
        frame: &ImageFrame,
        proposed: &Proposed,
        verdicts: &[Assignment],
        looked: &[usize],
        masks: &Masks,
    ) -> Result<Vec<Option<Look>>, DetectorError> {
        let boxes: Vec<CropBox> = looked
            .iter()
            .map(|&i| proposed.observations[i].region)
            .collect();
        let first_masks: Vec<Vec<CropBox>> = boxes
            .iter()
            .enumerate()
            .map(|(n, b)| masks.at(n, b))
            .collect();
        // Look at each box; while the landmarks found give a box unlike the one
        // looked at (a detector box is a rough guess), look again there (a
        // candidate is looked at once).
        let first = self.look_all(frame, &boxes, &first_masks)?;
        for (n, l) in first.iter().enumerate() {
            tracing::trace!(
                "look at box {}: pose flag {:.2}, spread {:.2}, {} masks",
                looked[n],
                l.pose_flag,
                l.spread,
                first_masks[n].len()
            );
        }
        let mut current: Vec<Option<Look>> = first
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
                .map(|(&n, b)| masks.at(n, b))
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
        Ok(current)
    }

    /// Each box `proposed` in the `now`th image at debug level: its body (the
    /// detector's box, else the crop), score, whether at a refused place, the tracker's
    /// verdict and the look's pose flag (`None`: not looked at; `Some(None)`: nobody).
    /// `benches/footage/missed.py` reads these lines to say where each missed person
    /// was lost.
    fn trace_boxes(
        &self,
        now: u64,
        proposed: &Proposed,
        verdicts: &[Assignment],
        looked: &[usize],
        current: &[Option<Look>],
    ) {
        if !tracing::enabled!(tracing::Level::DEBUG) {
            return;
        }
        for (i, o) in proposed.observations.iter().enumerate() {
            let look = looked
                .iter()
                .position(|&k| k == i)
                .map(|n| current[n].as_ref().map(|l| l.pose_flag));
            let body = proposed.bodies.get(i).copied().flatten();
            let b = body.unwrap_or(o.region);
            let refused = self
                .refused
                .iter()
                .any(|(r, _)| iou(r, &o.region) > REFUSED_IOU);
            tracing::debug!(
                "image {}: box {i} body {:.0},{:.0},{:.0},{:.0} score {:.2} detector box {} \
                 refused {refused} verdict {:?} look {:?}",
                now.saturating_sub(1),
                b.x0,
                b.y0,
                b.x0 + b.width,
                b.y0 + b.height,
                o.score,
                body.is_some(),
                verdicts[i],
                look
            );
        }
    }

    /// A detector's box where the landmark model found nobody (`current`, of the boxes
    /// `looked`) is a refused place, as a moving blob's is (a poster, a shadow the
    /// detector scores as a person): not looked at again for `REFUSED_FRAMES`.
    fn refuse_nobody(
        &mut self,
        current: &[Option<Look>],
        looked: &[usize],
        proposed: &Proposed,
        now: u64,
    ) {
        for (n, l) in current.iter().enumerate() {
            if l.is_none() && looked[n] < proposed.proposed_from {
                self.refused
                    .push((proposed.observations[looked[n]].region, now));
                self.stats.refused_sightings += 1;
            }
        }
    }

    /// Admits the people found (`current`, of the boxes `looked`) to `kept`: people
    /// found again first (they keep their places), then newcomers, then candidates; not
    /// one already present or a part of them, nor a candidate its look does not
    /// confirm. Returns the boxes whose person was taken (their places in `verdicts`).
    fn admit(
        &mut self,
        frame: &ImageFrame,
        current: Vec<Option<Look>>,
        looked: &[usize],
        verdicts: &[Assignment],
        heads: &[Option<CropBox>],
        kept: &mut Vec<(u32, Look)>,
    ) -> Vec<usize> {
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
            // Someone else who waits for their look: them (a newcomer, or a lost track
            // found on them).
            let own = match verdicts[i] {
                Assignment::Track(id) => Some(id),
                _ => None,
            };
            let on_waiting = |b: &CropBox| {
                self.waiting
                    .iter()
                    .any(|(id, w)| Some(*id) != own && iou(w, b) > SAME_PERSON_IOU)
            };
            if kept
                .iter()
                .any(|(_, o)| same_person(o, &l) || (newcomer && part_of(o, &l)))
                || l.person(self.threshold).is_some_and(|b| on_waiting(&b))
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
                // A newcomer who looks like someone lost may be them (a candidate is
                // not: a low score must be followed `birth_frames` before it counts).
                Assignment::Birth => {
                    match self.tracker.born_like(next, appearance(frame, &l).as_ref()) {
                        Some(id) => id,
                        None => continue,
                    }
                }
                _ => match self.tracker.born(next) {
                    Some(id) => id,
                    None => continue,
                },
            };
            taken.push(i);
            kept.push((id, l));
        }
        taken
    }

    /// Counts motion's looks at the `proposals` (someone there, or nobody: a refused
    /// place), given the boxes whose person was `taken`.
    fn judge_proposals(
        &mut self,
        proposals: Vec<usize>,
        taken: &[usize],
        observations: &[Observation],
        now: u64,
    ) {
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
}

/// What is blacked out in each look at the boxes `looked` (of `proposed`): the other
/// people (those followed this frame, in `kept`, and the heads the detector saw of the
/// others looked at now) but for a head overlapping this one's (as the detector saw
/// it; unknown: none), and all around a body the pedestrian detector saw. Nothing for a
/// candidate.
fn acquisition_masks(
    proposed: &Proposed,
    verdicts: &[Assignment],
    looked: &[usize],
    kept: &[(u32, Look)],
) -> Masks {
    let heads = &proposed.heads;
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
            (_, Some(own)) => masks_for(Some(own), others.iter().copied().filter(|h| h != own)),
        })
        .collect();
    // A body the pedestrian detector saw: all around it blacked out too (the
    // people beside it, whose heads may not be known), in every look at it.
    let looked_bodies: Vec<Option<CropBox>> = looked
        .iter()
        .map(|&i| match verdicts[i] {
            Assignment::Candidate => None,
            _ => proposed.bodies.get(i).copied().flatten(),
        })
        .collect();
    Masks {
        heads: head_masks,
        bodies: looked_bodies,
    }
}
