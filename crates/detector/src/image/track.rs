//! Following the people already tracked (step 1 of [`ImageDetector::detect`]): a look
//! at each one's predicted box, the other people's heads blacked out; a look whose head
//! jumped onto someone else's is a miss; two tracks on one person are one.

use super::looks::{Look, head_jump, masks_for, same_person};
use super::{DetectorError, ImageDetector};
use crate::images::ImageFrame;
use posestream_base::CropBox;

/// A lost person's head is blacked out in the others' looks for this many frames after
/// they were last seen (then it may be where someone else is now).
const MASKED_HEAD_FRAMES: u64 = 2;

impl ImageDetector {
    /// Follows the people tracked in `frame` (the `now`th): a look at the box the
    /// tracker predicts for each the schedule chose, seen or missed as the look says
    /// (the others wait, in `waiting`). Returns the people seen (track id and look),
    /// the older track first, each person once.
    pub(super) fn follow(
        &mut self,
        frame: &ImageFrame,
        now: u64,
    ) -> Result<Vec<(u32, Look)>, DetectorError> {
        let height = f64::from(frame.rgb.height());
        let (ids, boxes): (Vec<u32>, Vec<CropBox>) = self
            .tracker
            .scheduled(height, &mut self.waiting)
            .into_iter()
            .unzip();
        self.stats.waits += self.waiting.len() as u64;
        let masks = self.follow_masks(&ids, now);
        let looks = self.look_all(frame, &boxes, &masks)?;
        let mut kept = self.judge_follow(ids, looks);
        self.drop_duplicates(&mut kept);
        Ok(kept)
    }

    /// The heads to black out in each of the looks at the people `ids`: the other
    /// people's seen in the last `MASKED_HEAD_FRAMES` frames or waiting for a look now
    /// (where their last look saw it), but for one overlapping the person's own
    /// (`masks_for`).
    fn follow_masks(&self, ids: &[u32], now: u64) -> Vec<Vec<CropBox>> {
        let heads = &self.heads;
        // Not tried again: all around a person's body as last seen blacked out when
        // their box overlaps someone else's (as a new body's look is): it lost people
        // followed by their face (vtest.avi's first 91 frames, faces only: recall 0.45
        // -> 0.27) and found no one more with the pedestrian detector on.
        ids.iter()
            .map(|&id| {
                let own = heads.iter().find(|h| h.id == id).map(|h| &h.region);
                masks_for(
                    own,
                    heads
                        .iter()
                        .filter(|h| {
                            h.id != id
                                && (now - h.seen <= MASKED_HEAD_FRAMES
                                    || self.waiting.iter().any(|(w, _)| *w == h.id))
                        })
                        .map(|h| h.region),
                )
            })
            .collect()
    }

    /// Tells the tracker whether each of the people `ids` was seen in their look
    /// (`looks`, in the same order): a person found, whose head did not jump onto
    /// someone else's. Returns those seen, with their looks.
    fn judge_follow(&mut self, ids: Vec<u32>, looks: Vec<Look>) -> Vec<(u32, Look)> {
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
        kept
    }

    /// Two followed boxes on one person (their landmarks coincide): the older track
    /// (first) keeps them; the other's look is a miss, counted as a duplicate.
    fn drop_duplicates(&mut self, kept: &mut Vec<(u32, Look)>) {
        let mut k = 0;
        while k < kept.len() {
            if kept[..k].iter().any(|(_, o)| same_person(o, &kept[k].1)) {
                let (id, _) = kept.remove(k);
                self.tracker.duplicate(id);
            } else {
                k += 1;
            }
        }
    }
}
