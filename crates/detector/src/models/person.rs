//! BlazePose's person detector (`pose_detection.tflite`) run by `tract` or LiteRT: a 224 x 224
//! letterboxed image in, people out, each with a box and four keypoints, the first two
//! of which (hips' midpoint, body-circle point) place the landmark model's crop.
//!
//! The post-processing is MediaPipe's, re-implemented from its graph configuration
//! (`pose_detection_cpu.pbtxt`): SSD anchors (5 layers, strides 8, 16, 32, 32, 32,
//! fixed size, 2254 in all), box decoding with scale 224, sigmoid scores, and weighted
//! non-maximum suppression (IoU 0.3).

use super::engine::{Detector, Network, Output};

/// Input side, pixels.
pub const INPUT_SIZE: usize = 224;
/// Anchors (boxes the network scores).
pub const ANCHORS: usize = 2254;
/// Values per anchor: box (x centre, y centre, width, height) and 4 keypoints (x, y).
pub const VALUES_PER_ANCHOR: usize = 12;
/// Keypoints per detection.
pub const KEYPOINTS: usize = 4;
/// Overlap above which two detections are merged.
pub const NMS_IOU: f32 = 0.3;

/// One person found, in input coordinates normalised to [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersonDetection {
    /// Probability.
    pub score: f32,
    /// Box centre x, y and width, height.
    pub centre: [f32; 2],
    /// Box width, height.
    pub size: [f32; 2],
    /// Keypoints: hips' midpoint, the body circle's point, and two more.
    pub keypoints: [[f32; 2]; KEYPOINTS],
}

impl PersonDetection {
    fn iou(&self, other: &Self) -> f32 {
        let lo = |c: f32, s: f32| c - 0.5 * s;
        let hi = |c: f32, s: f32| c + 0.5 * s;
        let overlap = |k: usize| {
            (hi(self.centre[k], self.size[k]).min(hi(other.centre[k], other.size[k]))
                - lo(self.centre[k], self.size[k]).max(lo(other.centre[k], other.size[k])))
            .max(0.0)
        };
        let inter = overlap(0) * overlap(1);
        let union = self.size[0] * self.size[1] + other.size[0] * other.size[1] - inter;
        if union > 0.0 { inter / union } else { 0.0 }
    }
}

/// MediaPipe's SSD anchor centres for the detector (fixed size 1), in its output order.
pub fn anchors() -> Vec<[f32; 2]> {
    let strides = [8_usize, 16, 32, 32, 32];
    let mut out = Vec::with_capacity(ANCHORS);
    let mut layer = 0;
    while layer < strides.len() {
        // Consecutive layers of one stride share their grid: 2 anchors per layer
        // (aspect ratio 1 and the interpolated scale) at each cell.
        let mut per_cell = 0;
        let stride = strides[layer];
        while layer < strides.len() && strides[layer] == stride {
            per_cell += 2;
            layer += 1;
        }
        let cells = INPUT_SIZE.div_ceil(stride);
        for y in 0..cells {
            for x in 0..cells {
                let centre = [
                    (x as f32 + 0.5) / cells as f32,
                    (y as f32 + 0.5) / cells as f32,
                ];
                out.extend(std::iter::repeat_n(centre, per_cell));
            }
        }
    }
    out
}

/// Decodes the raw outputs (`2254 x 12` box values, `2254` score logits): the
/// detections scoring at least `threshold`, best first, merged by weighted
/// non-maximum suppression.
pub fn decode(
    boxes: &[f32],
    scores: &[f32],
    anchors: &[[f32; 2]],
    threshold: f32,
) -> Vec<PersonDetection> {
    let scale = INPUT_SIZE as f32;
    let mut candidates: Vec<PersonDetection> = anchors
        .iter()
        .enumerate()
        .filter_map(|(i, anchor)| {
            let score = 1.0 / (1.0 + (-scores.get(i)?.clamp(-100.0, 100.0)).exp());
            if score < threshold {
                return None;
            }
            let raw = boxes.get(i * VALUES_PER_ANCHOR..(i + 1) * VALUES_PER_ANCHOR)?;
            let point = |k: usize| [raw[k] / scale + anchor[0], raw[k + 1] / scale + anchor[1]];
            Some(PersonDetection {
                score,
                centre: point(0),
                size: [raw[2] / scale, raw[3] / scale],
                keypoints: std::array::from_fn(|k| point(4 + 2 * k)),
            })
        })
        .collect();
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut out = Vec::new();
    while let Some(best) = candidates.first().copied() {
        let (cluster, rest): (Vec<PersonDetection>, Vec<PersonDetection>) =
            candidates.into_iter().partition(|d| best.iou(d) > NMS_IOU);
        candidates = rest;
        // The cluster's box and keypoints, weighted by score; the best one's score.
        let total: f32 = cluster.iter().map(|d| d.score).sum();
        let mean = |f: &dyn Fn(&PersonDetection) -> f32| {
            cluster.iter().map(|d| d.score * f(d)).sum::<f32>() / total
        };
        out.push(PersonDetection {
            score: best.score,
            centre: [mean(&|d| d.centre[0]), mean(&|d| d.centre[1])],
            size: [mean(&|d| d.size[0]), mean(&|d| d.size[1])],
            keypoints: std::array::from_fn(|k| {
                [mean(&|d| d.keypoints[k][0]), mean(&|d| d.keypoints[k][1])]
            }),
        });
        if cluster.is_empty() {
            break;
        }
    }
    out
}

/// The raw outputs of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct PersonOutput {
    /// `2254 x 12` box values.
    pub boxes: Vec<f32>,
    /// `2254` score logits.
    pub scores: Vec<f32>,
}

/// BlazePose's person detector, as a [`Detector`].
#[derive(Debug)]
pub struct PersonDetector;

impl Detector for PersonDetector {
    const INPUT_SIZE: usize = INPUT_SIZE;
    /// Box values, score logits.
    const OUTPUTS: [Output<'static>; 2] = [
        Output {
            shape: &[1, ANCHORS, VALUES_PER_ANCHOR],
            floats: ANCHORS * VALUES_PER_ANCHOR,
        },
        Output {
            shape: &[1, ANCHORS, 1],
            floats: ANCHORS,
        },
    ];
    /// A search's lone run (the whole image while nobody is followed) on all the
    /// workers' threads: bikes.mp4's mean run 11.2-12.2 -> 10.1-10.8 ms, lone and
    /// parallel ones together.
    const LONE_RUN: bool = true;
    type Anchor = [f32; 2];
    type Raw = PersonOutput;
    type Found = PersonDetection;

    fn anchors() -> Vec<[f32; 2]> {
        anchors()
    }

    fn raw([boxes, scores]: [Vec<f32>; 2]) -> PersonOutput {
        PersonOutput { boxes, scores }
    }

    fn found(raw: &PersonOutput, anchors: &[[f32; 2]], threshold: f32) -> Vec<PersonDetection> {
        decode(&raw.boxes, &raw.scores, anchors, threshold)
    }
}

/// A loaded person detector: the original model on LiteRT, or the one rewritten for
/// tract ([`super::rewrite`]).
pub type PersonNetwork = Network<PersonDetector>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_anchor_grid_has_mediapipes_2254_centres() {
        let a = anchors();
        assert_eq!(a.len(), ANCHORS);
        // 28 x 28 x 2, then 14 x 14 x 2, then 7 x 7 x 6.
        assert_eq!(a[0], [0.5 / 28.0, 0.5 / 28.0]);
        assert_eq!(a[1], a[0]);
        assert_eq!(a[2], [1.5 / 28.0, 0.5 / 28.0]);
        assert_eq!(a[1568], [0.5 / 14.0, 0.5 / 14.0]);
        assert_eq!(a[1568 + 392], [0.5 / 7.0, 0.5 / 7.0]);
        assert_eq!(a[ANCHORS - 1], [6.5 / 7.0, 6.5 / 7.0]);
    }

    #[test]
    fn overlapping_detections_merge_weighted_by_score_and_others_stay() {
        let anchors = [[0.5, 0.5], [0.5, 0.5], [0.1, 0.1]];
        let mut boxes = vec![0.0_f32; 3 * VALUES_PER_ANCHOR];
        for (i, dx) in [(0, 0.0_f32), (1, 22.4), (2, 0.0)] {
            boxes[i * 12] = dx;
            boxes[i * 12 + 2] = 44.8;
            boxes[i * 12 + 3] = 44.8;
        }
        // Scores: sigmoid(2) = 0.88, sigmoid(0) = 0.5, sigmoid(1) = 0.73; threshold 0.45.
        let out = decode(&boxes, &[2.0, 0.0, 1.0], &anchors, 0.45);
        assert_eq!(out.len(), 2);
        let w = 0.880_797 / (0.880_797 + 0.5);
        // The first two overlap (IoU 1/3 > 0.3): merged, x centre weighted.
        assert!(
            (out[0].centre[0] - (0.5 * w + 0.6 * (1.0 - w))).abs() < 1e-5,
            "{out:?}"
        );
        assert!((out[0].score - 0.880_797).abs() < 1e-5);
        assert!((out[1].centre[0] - 0.1).abs() < 1e-6);
        assert!(decode(&boxes, &[2.0, 0.0, 1.0], &anchors, 0.95).is_empty());
    }
}
