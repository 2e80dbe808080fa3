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
    /// looks among `kept`, into `found` (its buffers reused); counts the frame as with
    /// or without anyone.
    pub(super) fn decode(
        &mut self,
        reported: &[(u32, CropBox)],
        kept: &[(u32, Look)],
    ) -> Result<(), DetectorError> {
        self.found_len = 0;
        for (id, _) in reported {
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
        Ok(())
    }

    /// The people of the current frame (what `decode` made), their
    /// heat maps lent until the next frame.
    pub(super) fn detections(&self) -> Vec<Detection<'_>> {
        self.found[..self.found_len]
            .iter()
            .map(|f| Detection {
                crop: f.crop,
                maps: &f.maps,
                size: HEATMAP_SIZE,
                track_id: f.track_id,
            })
            .collect()
    }
}
