//! The skeletons of one image together: [`ImageArrays`] groups what the estimator node
//! releases for each image into `posestream_msgs/Skeleton3DArray` messages, one per
//! image described and lag.
//!
//! The heat maps of one image come as one message per person, so the node cannot know
//! that an image's last person has been handled until something else happens: the first
//! message of the next image (another capture time or frame number), a quiet input (the
//! loops' idle tick), or the end of the stream. An image is its capture time and frame
//! number together, so frames stamped alike cannot pile up into one image. An image's arrays go out then: one frame after its
//! skeletons at a steady camera rate. Each skeleton also goes out alone at once, as
//! before.

use crate::msgs::{Header, Skeleton3D, Skeleton3DArray};

/// Groups released skeletons by the image whose messages released them; see the module
/// docs. Arrays are written over those handed back ([`ImageArrays::recycle`]).
#[derive(Debug, Default)]
pub struct ImageArrays {
    /// The image whose messages are being handled: capture time and frame number.
    image: Option<(i64, u64)>,
    /// Its arrays so far, in the order their first skeleton came.
    pending: Vec<Skeleton3DArray>,
    spare: Vec<Skeleton3DArray>,
}

impl ImageArrays {
    /// Takes the skeletons that handling a heat-map message of `image` (its capture time
    /// and frame number) released (`None`: released by no message, as at the end of a
    /// stream); when that is another image than the last one, that image's arrays are
    /// moved to `ready` first.
    pub fn add(
        &mut self,
        image_ns: Option<(i64, u64)>,
        skeletons: &[Skeleton3D],
        ready: &mut Vec<Skeleton3DArray>,
    ) {
        if image_ns != self.image || image_ns.is_none() {
            self.flush(ready);
            self.image = image_ns;
        }
        for s in skeletons {
            let found = self
                .pending
                .iter()
                .position(|a| a.sequence == s.sequence && a.lag == s.lag);
            let array = match found {
                Some(i) => &mut self.pending[i],
                None => {
                    let mut a = self.spare.pop().unwrap_or_default();
                    a.header = Header {
                        stamp: s.header.stamp.clone(),
                        frame_id: s.header.frame_id.clone(),
                    };
                    a.sequence = s.sequence;
                    a.lag = s.lag;
                    a.skeletons.clear();
                    self.pending.push(a);
                    self.pending.last_mut().expect("just pushed")
                }
            };
            array.skeletons.push(s.clone());
        }
        if image_ns.is_none() {
            self.flush(ready);
        }
    }

    /// Moves every pending array to `ready` (the image is complete).
    pub fn flush(&mut self, ready: &mut Vec<Skeleton3DArray>) {
        ready.append(&mut self.pending);
        self.image = None;
    }

    /// True while an image's arrays wait for its end.
    pub fn is_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Takes back arrays that were sent, to be written over.
    pub fn recycle(&mut self, sent: &mut Vec<Skeleton3DArray>) {
        self.spare.append(sent);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::Time;

    fn skeleton(track_id: u32, sequence: u64, lag: u32) -> Skeleton3D {
        Skeleton3D {
            header: Header {
                stamp: Time::from_nanos(sequence as i64 * 1000),
                frame_id: "camera".into(),
            },
            sequence,
            track_id,
            lag,
            ..Skeleton3D::default()
        }
    }

    fn shape(arrays: &[Skeleton3DArray]) -> Vec<(u64, u32, Vec<u32>)> {
        arrays
            .iter()
            .map(|a| {
                (
                    a.sequence,
                    a.lag,
                    a.skeletons.iter().map(|s| s.track_id).collect(),
                )
            })
            .collect()
    }

    #[test]
    fn frames_stamped_alike_do_not_pile_up() {
        // A detector (or a peer) that stamps every frame alike: each message is still
        // its own image (its own sequence number), so nothing accumulates.
        let mut arrays = ImageArrays::default();
        let mut ready = Vec::new();
        for sequence in 0..1000 {
            let mut s = skeleton(1, sequence, 0);
            s.header.stamp = Time::from_nanos(5);
            arrays.add(Some((5, sequence)), &[s], &mut ready);
            assert!(
                arrays.pending.len() <= 1,
                "{} pending",
                arrays.pending.len()
            );
        }
        assert_eq!(ready.len(), 999);
    }

    #[test]
    fn an_image_s_arrays_go_out_when_the_next_image_begins() {
        let mut arrays = ImageArrays::default();
        let mut ready = Vec::new();
        // Image 20: person 1 (its newest estimate and the refined one of image 10), then
        // person 2.
        arrays.add(
            Some((20_000, 20)),
            &[skeleton(1, 10, 10), skeleton(1, 20, 0)],
            &mut ready,
        );
        arrays.add(
            Some((20_000, 20)),
            &[skeleton(2, 10, 10), skeleton(2, 20, 0)],
            &mut ready,
        );
        assert!(ready.is_empty() && arrays.is_pending());
        // Image 21 begins: image 20's arrays are complete.
        arrays.add(Some((21_000, 21)), &[skeleton(1, 21, 0)], &mut ready);
        assert_eq!(shape(&ready), [(10, 10, vec![1, 2]), (20, 0, vec![1, 2])]);
        assert_eq!(ready[1].header.stamp, Time::from_nanos(20_000));
        assert_eq!(ready[1].header.frame_id, "camera");
        arrays.recycle(&mut ready);
        // The end of the stream: image 21's array, then the owed estimates at once.
        arrays.add(None, &[skeleton(1, 15, 6), skeleton(1, 16, 5)], &mut ready);
        assert_eq!(
            shape(&ready),
            [(21, 0, vec![1]), (15, 6, vec![1]), (16, 5, vec![1])]
        );
        assert!(!arrays.is_pending());
    }
}
