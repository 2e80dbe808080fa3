//! Which of the people followed get a landmark look this frame (`looks_per_frame`,
//! `max_wait_frames`): with many people in view a look each every frame costs more than
//! a frame's time, so the others wait a frame or two, expected where their velocity
//! takes them, neither seen nor missed; the image detector sends their newest look's
//! heat maps again, moved with them ([`Tracker::carried`], `frames_since_look`).
//!
//! Who is looked at first (the project's own rule, after the list: new, fast,
//! near someone else, near the camera): everyone newly found and everyone who waited
//! `max_wait_frames` in a row; then, while the budget lasts, the most urgent, urgency
//! being the frames waited plus one times `1 + 10 speed + 2 overlap + size` (speed: the
//! box's centre's move per frame in box sides, a walker at 10 frames/s about 0.1;
//! overlap: the most its box overlaps another's, IoU; size: its side over the image's
//! height). The people who must be looked at are looked at even past the budget: the
//! wait is bounded, the budget is what is spent when it can be.

#[cfg(test)]
use super::Assignment;
use super::{Observation, Tracker, centre_side, iou};
use posestream_base::CropBox;

/// A track seen in fewer frames in a row than this is newly found: looked at every frame.
const FRESH_HITS: u32 = 4;

/// What a followed person's need of a look is made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Need {
    /// Frames in a row followed without a look.
    pub waited: u32,
    /// Newly found (seen in fewer than `FRESH_HITS` frames in a row).
    pub fresh: bool,
    /// The box's centre's move per frame, in box sides.
    pub speed: f64,
    /// The most the box overlaps another followed person's (IoU).
    pub overlap: f64,
    /// The box's side over the image's height.
    pub size: f64,
}

impl Need {
    /// How urgent a look is (the higher, the sooner).
    fn urgency(&self) -> f64 {
        let weight = 1.0 + 10.0 * self.speed + 2.0 * self.overlap + self.size;
        let u = f64::from(self.waited.saturating_add(1)) * weight;
        // A NaN (a box gone wrong) is the least urgent; an infinity the most.
        if u.is_nan() { 0.0 } else { u.min(f64::MAX) }
    }
}

/// Marks in `chosen` (one per need) who is looked at: everyone when `looks` is 0 or
/// covers them all; else the fresh, those who waited `max_wait` frames, and the most
/// urgent others up to `looks` in all.
pub fn choose(needs: &[Need], looks: usize, max_wait: u32, chosen: &mut Vec<bool>) {
    chosen.clear();
    if looks == 0 || needs.len() <= looks {
        chosen.resize(needs.len(), true);
        return;
    }
    chosen.extend(needs.iter().map(|n| n.fresh || n.waited >= max_wait));
    let spent = chosen.iter().filter(|&&c| c).count();
    let mut order: Vec<usize> = (0..needs.len()).filter(|&i| !chosen[i]).collect();
    order.sort_by(|&a, &b| needs[b].urgency().total_cmp(&needs[a].urgency()));
    for &i in order.iter().take(looks.saturating_sub(spent)) {
        chosen[i] = true;
    }
}

impl Need {
    /// The need of a person followed at `region` (their box expected now), moving
    /// `velocity` pixels per frame, seen `hits` frames in a row and without a look the
    /// last `waited`, beside the other people's boxes `others`, in an image
    /// `image_height` pixels high.
    pub fn of(
        region: &CropBox,
        velocity: [f64; 2],
        hits: u32,
        waited: u32,
        others: impl Iterator<Item = CropBox>,
        image_height: f64,
    ) -> Self {
        let (_, _, side) = centre_side(region);
        let speed = velocity[0].hypot(velocity[1]) / side.max(1.0);
        let overlap = others.map(|b| iou(region, &b)).fold(0.0, f64::max);
        Self {
            waited,
            fresh: hits < FRESH_HITS && waited == 0,
            speed: if speed.is_finite() { speed } else { 0.0 },
            overlap,
            size: side / image_height.max(1.0),
        }
    }
}

impl Tracker {
    /// The people to look at this frame, of those followed ([`Tracker::predictions`],
    /// in its order), chosen by [`choose`] in an image `image_height` pixels high; the
    /// others wait ([`Tracker::wait`]), into `waiting` (id and box expected now).
    pub fn scheduled(
        &mut self,
        image_height: f64,
        waiting: &mut Vec<(u32, CropBox)>,
    ) -> Vec<(u32, CropBox)> {
        waiting.clear();
        let followed: Vec<(u32, CropBox)> = self.predictions().collect();
        let needs: Vec<Need> = self
            .tracks
            .iter()
            .filter(|t| t.misses == 0)
            .zip(&followed)
            .map(|(t, (id, region))| {
                let others = followed.iter().filter(|(o, _)| o != id).map(|(_, b)| *b);
                Need::of(region, t.velocity, t.hits, t.waited, others, image_height)
            })
            .collect();
        let mut chosen = Vec::with_capacity(needs.len());
        choose(
            &needs,
            self.settings.looks_per_frame,
            self.settings.max_wait_frames,
            &mut chosen,
        );
        let mut looked = Vec::with_capacity(followed.len());
        for ((id, region), c) in followed.into_iter().zip(chosen) {
            if c {
                looked.push((id, region));
            } else {
                self.wait(id);
                waiting.push((id, region));
            }
        }
        looked
    }

    /// After [`Tracker::end`]: the confirmed tracks that waited for a look this frame,
    /// each with the box expected now and the frames since their last look.
    pub fn carried(&self) -> Vec<(u32, CropBox, u32)> {
        self.tracks
            .iter()
            .filter(|t| t.waiting && t.seen.is_none() && t.state == super::State::Confirmed)
            .map(|t| (t.id, t.predicted(t.waited), t.waited))
            .collect()
    }

    /// [`Tracker::frame_of_boxes`] as the image detector's frame goes: the schedule
    /// first ([`Tracker::scheduled`], in an image `image_height` pixels high), so that a
    /// box on someone who waits is theirs, unseen (their maps carried:
    /// [`Tracker::carried`]). Each box's reported track id.
    pub fn scheduled_frame_of_boxes(
        &mut self,
        observations: &[Observation],
        image_height: f64,
    ) -> Vec<Option<u32>> {
        self.begin();
        let mut waiting = Vec::new();
        self.scheduled(image_height, &mut waiting);
        self.boxes_seen(observations)
    }

    /// Track `id`, followed, is not looked at this frame: it is neither seen (not among
    /// [`Tracker::end`]'s, but among [`Tracker::carried`]) nor missed, and expected
    /// where its velocity takes it from the box last seen.
    pub fn wait(&mut self, id: u32) {
        if let Some(t) = self.tracks.iter_mut().find(|t| t.id == id) {
            t.waiting = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn need(waited: u32, speed: f64) -> Need {
        Need {
            waited,
            fresh: false,
            speed,
            overlap: 0.0,
            size: 0.2,
        }
    }

    #[test]
    fn everyone_is_looked_at_within_the_budget_or_without_one() {
        let needs = vec![need(0, 0.1); 3];
        let mut chosen = Vec::new();
        choose(&needs, 0, 1, &mut chosen);
        assert_eq!(chosen, vec![true; 3]);
        choose(&needs, 3, 1, &mut chosen);
        assert_eq!(chosen, vec![true; 3]);
        choose(&[], 2, 1, &mut chosen);
        assert!(chosen.is_empty());
    }

    #[test]
    fn the_fresh_and_the_longest_waiting_come_first_even_past_the_budget() {
        let mut needs = vec![need(0, 0.0), need(1, 0.0), need(0, 0.5), need(0, 0.0)];
        needs[3].fresh = true;
        let mut chosen = Vec::new();
        // Budget 1: the fresh one and the one who waited max_wait (1) are looked at
        // anyway; nobody else.
        choose(&needs, 1, 1, &mut chosen);
        assert_eq!(chosen, vec![false, true, false, true]);
        // Budget 3: the fast one next, the slow one who just had a look waits.
        choose(&needs, 3, 1, &mut chosen);
        assert_eq!(chosen, vec![false, true, true, true]);
        // A longer wait allowed: the one who waited is no longer a must, and the fast
        // one is more urgent (1 x 6.2 against 2 x 1.2).
        choose(&needs, 2, 5, &mut chosen);
        assert_eq!(chosen, vec![false, false, true, true]);
    }

    #[test]
    fn urgency_grows_with_the_wait_speed_overlap_and_size_and_is_never_nan() {
        let base = need(0, 0.0);
        for more in [
            need(1, 0.0),
            need(0, 0.1),
            Need {
                overlap: 0.3,
                ..base
            },
            Need { size: 0.9, ..base },
        ] {
            assert!(more.urgency() > base.urgency(), "{more:?}");
        }
        let wild = Need {
            waited: u32::MAX,
            speed: f64::MAX,
            ..base
        };
        assert_eq!(wild.urgency(), f64::MAX);
        let nan = Need {
            speed: f64::NAN,
            ..base
        };
        let mut chosen = Vec::new();
        choose(&[nan, base, wild], 1, 10, &mut chosen);
        assert_eq!(chosen, vec![false, false, true]);
    }

    #[test]
    fn people_who_wait_are_carried_on_by_their_velocity_neither_seen_nor_missed() {
        let settings = crate::tracker::TrackingSettings {
            looks_per_frame: 1,
            max_wait_frames: 1,
            ..crate::tracker::TrackingSettings::default()
        };
        let mut tracker = Tracker::new(settings, 0.5);
        // Two people walking right 10 pixels a frame, 300 apart.
        let (at, obs) = (walker, |frame: usize| walkers(2, frame));
        let ids: Vec<u32> = tracker
            .frame_of_boxes(&obs(0))
            .into_iter()
            .map(|id| id.expect("reported on the scene's first frame"))
            .collect();
        let mut waiting = Vec::new();
        let mut looks = [0; 2];
        for frame in 1..12 {
            tracker.begin();
            let looked = tracker.scheduled(480.0, &mut waiting);
            if frame < FRESH_HITS as usize {
                assert_eq!(
                    looked.len(),
                    2,
                    "frame {frame}: newly found, both looked at"
                );
            } else {
                assert_eq!((looked.len(), waiting.len()), (1, 1), "frame {frame}");
            }
            // Once their velocity is learnt, whoever waits is expected where they are.
            for (id, region) in looked.iter().chain(&waiting).filter(|_| frame > 3) {
                let person = ids.iter().position(|i| i == id).expect("a known id");
                assert!(
                    iou(region, &at(person, frame)) > 0.9,
                    "frame {frame}: {region:?}"
                );
            }
            for (id, _) in &looked {
                let person = ids.iter().position(|i| i == id).expect("a known id");
                tracker.seen(*id, at(person, frame));
                looks[person] += 1;
            }
            // Nobody lost: the search is wanted only by `detect_every` (10).
            assert_eq!(tracker.wants_detections(), frame >= 10, "frame {frame}");
            let reported: Vec<u32> = tracker.end().into_iter().map(|(id, _)| id).collect();
            let looked_ids: Vec<u32> = looked.iter().map(|(id, _)| *id).collect();
            assert_eq!(reported, looked_ids, "frame {frame}: only those looked at");
        }
        // Taking turns: nobody missed or lost, each looked at every other frame.
        let stats = tracker.stats();
        assert_eq!((stats.deaths, stats.reacquisitions), (0, 0));
        assert_eq!(looks, [7, 7]);
    }

    /// People `0..n` walking right 10 pixels a frame, 300 apart: their box in `frame`.
    fn walker(person: usize, frame: usize) -> CropBox {
        CropBox::new(
            300.0 * person as f64 + 10.0 * frame as f64,
            50.0,
            100.0,
            100.0,
        )
        .expect("a box")
    }

    fn walkers(n: usize, frame: usize) -> Vec<Observation> {
        (0..n)
            .map(|p| Observation {
                region: walker(p, frame),
                score: 0.9,
            })
            .collect()
    }

    #[test]
    fn people_who_wait_five_frames_in_a_row_are_still_expected_where_they_are() {
        // Six people, one look a frame, up to five frames' wait: each looked at every
        // sixth frame; their velocity, learnt over the waits, keeps their expected box
        // on them (measured from the box carried on, its error doubled at every look).
        let settings = crate::tracker::TrackingSettings {
            looks_per_frame: 1,
            max_wait_frames: 5,
            ..crate::tracker::TrackingSettings::default()
        };
        let mut tracker = Tracker::new(settings, 0.5);
        let ids: Vec<u32> = tracker
            .frame_of_boxes(&walkers(6, 0))
            .into_iter()
            .map(|id| id.expect("reported on the scene's first frame"))
            .collect();
        let person = |id: &u32| ids.iter().position(|i| i == id).expect("a known id");
        let mut waiting = Vec::new();
        for frame in 1..120 {
            tracker.begin();
            let looked = tracker.scheduled(480.0, &mut waiting);
            // Once each has been looked at after a wait.
            let settled = frame >= 14;
            if settled {
                assert_eq!(looked.len(), 1, "frame {frame}");
                for (id, region) in looked.iter().chain(&waiting) {
                    let truth = walker(person(id), frame);
                    assert!(iou(region, &truth) > 0.9, "frame {frame}: {region:?}");
                }
            }
            for (id, _) in &looked {
                tracker.seen(*id, walker(person(id), frame));
            }
            tracker.end();
            for (id, now, waited) in tracker.carried() {
                assert!(waited <= 5, "frame {frame}: {id} waited {waited}");
                let on = iou(&now, &walker(person(&id), frame));
                assert!(!settled || on > 0.9, "frame {frame}: {on}");
            }
        }
        let stats = tracker.stats();
        assert_eq!((stats.deaths, stats.reacquisitions), (0, 0));
    }

    #[test]
    fn a_search_s_box_on_someone_who_waits_is_theirs_not_a_newcomer() {
        let settings = crate::tracker::TrackingSettings {
            looks_per_frame: 1,
            ..crate::tracker::TrackingSettings::default()
        };
        let mut tracker = Tracker::new(settings, 0.5);
        tracker.frame_of_boxes(&walkers(2, 0));
        let mut waiting = Vec::new();
        for frame in 1..8 {
            tracker.begin();
            let looked = tracker.scheduled(480.0, &mut waiting);
            if waiting.len() == 1 {
                // Both boxes found by a search: the one on the person looked at is
                // theirs; the one on who waits is passed over (no birth, no look).
                let what = tracker.associate(&walkers(2, frame));
                let on = |p: usize| iou(&walker(p, frame), &waiting[0].1);
                let wait_index = if on(0) > on(1) { 0 } else { 1 };
                assert_eq!(what[wait_index], Assignment::Ignored, "{what:?}");
                assert_eq!(what[1 - wait_index], Assignment::Track(looked[0].0));
                assert_eq!(tracker.stats().births, 2);
                return;
            }
            for (id, b) in &looked {
                let p = if iou(b, &walker(0, frame)) > 0.5 {
                    0
                } else {
                    1
                };
                tracker.seen(*id, walker(p, frame));
            }
            tracker.end();
        }
        panic!("nobody waited");
    }
}
