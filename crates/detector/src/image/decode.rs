//! The end of a frame (step 3 of [`ImageDetector::detect`]): the heads seen kept for
//! the next frame's masks, and the heat maps of the people the tracker reports, made
//! from their looks' logits through the channel mapping.

use super::looks::{Found, Head, Look};
use super::{Detection, DetectorError, ImageDetector};
use crate::models::landmarks::HEATMAP_SIZE;
use posestream_base::CropBox;

impl ImageDetector {
    /// Keeps each person's head where it was seen in the `now`th frame (the faces of
    /// the looks `kept`); a person lost keeps theirs until their track ends (a head
    /// jumping there is theirs; blacked out for a few frames).
    pub(super) fn update_heads(&mut self, kept: &[(u32, Look)], now: u64) {
        // Heads where they were seen this frame; a person lost keeps theirs until their
        // track ends (a head jumping there is theirs; blacked out for a few frames).
        for (id, l) in kept {
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
    }

    /// The heat maps of the people `reported` (the tracker's, in its order) from their
    /// looks among `kept`, then those of the people who waited for a look (their newest
    /// look's maps, moved with them): into `found` (its buffers reused, a slot per
    /// person tracked), the frame's in `shown`; counts the frame as with or without
    /// anyone.
    pub(super) fn decode(
        &mut self,
        reported: &[(u32, CropBox)],
        kept: &[(u32, Look)],
    ) -> Result<(), DetectorError> {
        self.shown.clear();
        // The slots of people no longer tracked are free (bounded by max_people).
        for f in &mut self.found {
            if f.track_id != 0 && !self.tracker.is_live(f.track_id) {
                f.track_id = 0;
            }
        }
        for &(id, person) in reported {
            let Some((_, l)) = kept.iter().find(|(k, _)| *k == id) else {
                continue;
            };
            let slot = self.slot_of(id, l.crop);
            let f = &mut self.found[slot];
            f.crop = l.crop;
            f.person = person;
            f.frames_since_look = 0;
            self.mapping
                .apply(&l.logits, HEATMAP_SIZE, HEATMAP_SIZE, &mut f.maps)
                .map_err(|source| DetectorError::Maps(Box::new(source)))?;
            self.shown.push(slot);
        }
        // Whoever waited for a look: the maps of their newest one, in its box moved as
        // they are expected to have moved since.
        for (id, now, waited) in self.tracker.carried() {
            let Some(slot) = self
                .found
                .iter()
                .position(|f| f.track_id == id && !f.maps.is_empty())
            else {
                continue;
            };
            let f = &mut self.found[slot];
            f.crop = f.crop.moved_as(&f.person, &now);
            f.person = now;
            f.frames_since_look = waited;
            self.shown.push(slot);
        }
        if self.shown.is_empty() {
            self.stats.no_person += 1;
        } else {
            self.stats.detected += 1;
            self.stats.people += self.shown.len() as u64;
        }
        Ok(())
    }

    /// The slot of person `id` in `found`: theirs, else a free one, else a new one
    /// (its boxes `crop` until written).
    fn slot_of(&mut self, id: u32, crop: CropBox) -> usize {
        if let Some(k) = self.found.iter().position(|f| f.track_id == id) {
            return k;
        }
        let k = match self.found.iter().position(|f| f.track_id == 0) {
            Some(k) => k,
            None => {
                self.found.push(Found {
                    crop,
                    person: crop,
                    track_id: 0,
                    maps: Vec::new(),
                    frames_since_look: 0,
                });
                self.found.len() - 1
            }
        };
        self.found[k].track_id = id;
        k
    }

    /// The people of the current frame (what `decode` made), their
    /// heat maps lent until the next frame.
    pub(super) fn detections(&self) -> Vec<Detection<'_>> {
        self.shown
            .iter()
            .map(|&k| {
                let f = &self.found[k];
                Detection {
                    crop: f.crop,
                    maps: &f.maps,
                    size: HEATMAP_SIZE,
                    track_id: f.track_id,
                    frames_since_look: f.frames_since_look,
                }
            })
            .collect()
    }
}
