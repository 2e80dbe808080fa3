//! Heat maps with the failure modes of real detectors, from a seeded error model.
//!
//! Each map is `h x w` cells spread over the frame's crop box (cell `(r, c)` centred at
//! map point `x = c, y = r`, as [`CropBox::pixel_map`] says). A joint normally gets a
//! Gaussian blob of amplitude 1 at its true position plus localisation noise. Episodes,
//! each starting with a per-frame probability and lasting several frames, model what
//! detectors get wrong:
//! - **left/right swap**: both joints of a left/right pair peak at each other's place;
//! - **occlusion**: a weak broad peak at the true place and a sharper distractor nearby;
//! - **missing**: no peak at all.
//!
//! Uniform background noise covers every map (a small floor keeps an empty map valid).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use posestream_base::CropBox;
use posestream_math::error::EstimateError;
use posestream_math::heatmaps::HeatMapSequence;
use posestream_math::skeleton::Skeleton;

/// The error model; lengths in map cells, rates per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ErrorModel {
    /// Map height and width, cells.
    pub size: [usize; 2],
    /// Standard deviation of the peak's localisation noise, cells.
    pub noise: f64,
    /// Standard deviation of a peak, cells.
    pub blob: f64,
    /// Probability per frame and left/right pair that a swap starts.
    pub swap_rate: f64,
    /// Probability per frame and joint that an occlusion starts.
    pub occlusion_rate: f64,
    /// Probability per frame and joint that the joint goes missing.
    pub missing_rate: f64,
    /// Frames an episode (swap, occlusion, missing) lasts.
    pub episode_frames: usize,
    /// Amplitude of the uniform background noise.
    pub background: f64,
    /// Seed of the random generator.
    pub seed: u64,
}

impl Default for ErrorModel {
    fn default() -> Self {
        Self {
            size: [64, 64],
            noise: 0.7,
            blob: 1.5,
            swap_rate: 0.01,
            occlusion_rate: 0.01,
            missing_rate: 0.003,
            episode_frames: 8,
            background: 0.05,
            seed: 0,
        }
    }
}

impl ErrorModel {
    /// No errors beyond the blob itself: peaks exactly at the true joints.
    pub fn clean() -> Self {
        Self {
            noise: 0.0,
            swap_rate: 0.0,
            occlusion_rate: 0.0,
            missing_rate: 0.0,
            background: 0.0,
            ..Self::default()
        }
    }

    /// Checks the values.
    pub fn validate(&self) -> Result<(), String> {
        if self.size.iter().any(|&s| s < 2) {
            return Err(format!("map size {:?} must be at least 2 x 2", self.size));
        }
        let rates = [self.swap_rate, self.occlusion_rate, self.missing_rate];
        if rates.iter().any(|r| !(0.0..=1.0).contains(r)) {
            return Err("swap, occlusion and missing rates must lie in [0, 1]".into());
        }
        let non_negative = |v: f64| v.is_finite() && v >= 0.0;
        if !(non_negative(self.noise) && non_negative(self.background)) {
            return Err("noise and background must be finite and >= 0".into());
        }
        if !(self.blob.is_finite() && self.blob > 0.0) {
            return Err(format!("blob width must be positive, got {}", self.blob));
        }
        if self.episode_frames == 0 {
            return Err("episodes must last at least 1 frame".into());
        }
        Ok(())
    }
}

/// Counts of the episodes a rendering contains.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct EpisodeCounts {
    /// Joint-frames rendered at the counterpart's place.
    pub swapped: usize,
    /// Joint-frames occluded.
    pub occluded: usize,
    /// Joint-frames with no peak.
    pub missing: usize,
    /// Joint-frames hidden by another person (a weak peak at the joint, a strong one on
    /// the other person's limb in front of it).
    pub hidden: usize,
}

/// Rendered heat maps and the truth in map cells.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedMaps {
    /// The maps, F x p x h x w.
    pub maps: HeatMapSequence,
    /// True joints in map cells (F, p, 2).
    pub truth: Vec<f64>,
    /// What went wrong, and how often.
    pub episodes: EpisodeCounts,
}

/// Renders heat maps of the joints `image_2d` (pixels, F x p x 2) in each frame's crop.
pub fn render(
    image_2d: &[f64],
    boxes: &[CropBox],
    skeleton: &Skeleton,
    model: &ErrorModel,
) -> Result<RenderedMaps, EstimateError> {
    render_hidden(image_2d, boxes, skeleton, model, &[])
}

/// [`render`] of a person whom others hide: `hidden` (empty, or F x p) holds, for each
/// joint hidden in a frame, where the limb in front of it is (pixels,
/// [`super::hidden_by_others`]). Such a joint's map has a weak broad peak at the joint
/// and a strong one on that limb, as a detector that sees the person in front.
pub fn render_hidden(
    image_2d: &[f64],
    boxes: &[CropBox],
    skeleton: &Skeleton,
    model: &ErrorModel,
    hidden: &[Option<[f64; 2]>],
) -> Result<RenderedMaps, EstimateError> {
    model.validate().map_err(EstimateError::Parameter)?;
    let p = skeleton.len();
    let frames = boxes.len();
    if image_2d.len() != frames * p * 2 {
        return Err(EstimateError::Parameter(format!(
            "{} image coordinates for {frames} boxes of {p} joints",
            image_2d.len()
        )));
    }
    if !hidden.is_empty() && hidden.len() != frames * p {
        return Err(EstimateError::Parameter(format!(
            "{} hidden flags for {frames} frames of {p} joints",
            hidden.len()
        )));
    }
    let [h, w] = model.size;
    let mut rng = ChaCha8Rng::seed_from_u64(model.seed);
    let noise = Normal::new(0.0, model.noise.max(1e-300))
        .map_err(|e| EstimateError::Parameter(format!("noise: {e}")))?;
    let pairs = skeleton.left_right_pairs();
    let mut counterpart: Vec<Option<usize>> = vec![None; p];
    for &(l, r) in &pairs {
        counterpart[l] = Some(r);
        counterpart[r] = Some(l);
    }
    // Frames left in the current episode, per pair / joint.
    let mut swap_left = vec![0usize; pairs.len()];
    let mut occl_left = vec![0usize; p];
    let mut miss_left = vec![0usize; p];
    let mut distractor = vec![[0.0f64; 2]; p];
    let mut values = vec![0.0f32; frames * p * h * w];
    let mut truth = Vec::with_capacity(frames * p * 2);
    let mut episodes = EpisodeCounts::default();
    for (t, b) in boxes.iter().enumerate() {
        let map = b.pixel_map(w, h);
        let cell = |j: usize| {
            let x = image_2d[2 * (t * p + j)];
            let y = image_2d[2 * (t * p + j) + 1];
            [
                (x - map.offset[0]) / map.scale[0],
                (y - map.offset[1]) / map.scale[1],
            ]
        };
        for j in 0..p {
            truth.extend(cell(j));
        }
        // Start or continue episodes.
        let mut swapped = vec![false; p];
        for (i, &(l, r)) in pairs.iter().enumerate() {
            if swap_left[i] == 0 && rng.random::<f64>() < model.swap_rate {
                swap_left[i] = model.episode_frames;
            }
            if swap_left[i] > 0 {
                swap_left[i] -= 1;
                swapped[l] = true;
                swapped[r] = true;
            }
        }
        for j in 0..p {
            let frame_maps = &mut values[(t * p + j) * h * w..(t * p + j + 1) * h * w];
            if model.background > 0.0 {
                for v in frame_maps.iter_mut() {
                    *v = (model.background * rng.random::<f64>()) as f32;
                }
            }
            if miss_left[j] == 0 && rng.random::<f64>() < model.missing_rate {
                miss_left[j] = model.episode_frames;
            }
            if occl_left[j] == 0 && rng.random::<f64>() < model.occlusion_rate {
                occl_left[j] = model.episode_frames;
                // A distractor a few blob widths away, kept for the episode.
                let angle = rng.random::<f64>() * std::f64::consts::TAU;
                let reach = 0.1 * w.min(h) as f64 * (1.0 + rng.random::<f64>());
                distractor[j] = [reach * angle.cos(), reach * angle.sin()];
            }
            let source = match (swapped[j], counterpart[j]) {
                (true, Some(c)) => {
                    episodes.swapped += 1;
                    c
                }
                _ => j,
            };
            let [x, y] = cell(source);
            let jitter = |rng: &mut ChaCha8Rng| {
                if model.noise > 0.0 {
                    noise.sample(rng)
                } else {
                    0.0
                }
            };
            let (x, y) = (x + jitter(&mut rng), y + jitter(&mut rng));
            let front = hidden.get(t * p + j).copied().flatten();
            if miss_left[j] > 0 {
                miss_left[j] -= 1;
                episodes.missing += 1;
            } else if let Some(limb) = front {
                // (An occlusion episode runs on underneath, as it would unseen.)
                occl_left[j] = occl_left[j].saturating_sub(1);
                episodes.hidden += 1;
                add_blob(frame_maps, w, [x, y], 3.0 * model.blob, 0.3);
                let c = [
                    (limb[0] - map.offset[0]) / map.scale[0],
                    (limb[1] - map.offset[1]) / map.scale[1],
                ];
                add_blob(frame_maps, w, c, model.blob, 0.8);
            } else if occl_left[j] > 0 {
                occl_left[j] -= 1;
                episodes.occluded += 1;
                add_blob(frame_maps, w, [x, y], 3.0 * model.blob, 0.3);
                let d = distractor[j];
                add_blob(frame_maps, w, [x + d[0], y + d[1]], model.blob, 0.6);
            } else {
                add_blob(frame_maps, w, [x, y], model.blob, 1.0);
            }
            // A floor keeps a map without a peak (and without background) valid: it then
            // says nothing about the joint.
            for v in frame_maps.iter_mut() {
                *v += 1e-4;
            }
        }
    }
    let maps = HeatMapSequence::new(frames, p, h, w, values)?;
    Ok(RenderedMaps {
        maps,
        truth,
        episodes,
    })
}

/// Adds `amplitude * exp(-d^2 / 2 sigma^2)` around `centre` (map cells).
fn add_blob(map: &mut [f32], width: usize, centre: [f64; 2], sigma: f64, amplitude: f64) {
    let inv = 1.0 / (2.0 * sigma * sigma);
    for (r, row) in map.chunks_exact_mut(width).enumerate() {
        let dy = r as f64 - centre[1];
        let gy = (-dy * dy * inv).exp();
        if gy < 1e-8 {
            continue;
        }
        for (c, v) in row.iter_mut().enumerate() {
            let dx = c as f64 - centre[0];
            *v += (amplitude * gy * (-dx * dx * inv).exp()) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::default_layout;

    fn frame() -> (Vec<f64>, Vec<CropBox>) {
        // 17 joints spread over a 200-pixel box at (100, 100), 3 frames.
        let one: Vec<f64> = (0..17)
            .flat_map(|j| [120.0 + 9.0 * j as f64, 150.0 + 5.0 * (j % 5) as f64])
            .collect();
        let b = CropBox::new(100.0, 100.0, 200.0, 200.0).expect("box");
        (one.repeat(3), vec![b; 3])
    }

    #[test]
    fn clean_maps_peak_at_the_truth_and_are_reproducible() {
        let (xy, boxes) = frame();
        let skel = default_layout();
        let clean = render(&xy, &boxes, &skel, &ErrorModel::clean()).expect("render");
        for t in 0..3 {
            for j in 0..17 {
                let (x, y, _) = clean.maps.argmax(t, j);
                let i = 2 * (t * 17 + j);
                assert!((x - clean.truth[i]).abs() <= 0.5 && (y - clean.truth[i + 1]).abs() <= 0.5);
            }
        }
        let noisy = ErrorModel {
            swap_rate: 0.5,
            occlusion_rate: 0.2,
            missing_rate: 0.1,
            ..ErrorModel::default()
        };
        let a = render(&xy, &boxes, &skel, &noisy).expect("render");
        let b = render(&xy, &boxes, &skel, &noisy).expect("render");
        assert_eq!(a, b, "the same seed gives the same maps");
        assert!(a.episodes.swapped > 0 && a.episodes.occluded > 0 && a.episodes.missing > 0);
        let c = render(&xy, &boxes, &skel, &ErrorModel { seed: 1, ..noisy }).expect("render");
        assert_ne!(a.maps, c.maps);
    }

    #[test]
    fn a_joint_hidden_by_another_person_peaks_on_their_limb() {
        let (xy, boxes) = frame();
        let skel = default_layout();
        let mut hidden = vec![None; 3 * 17];
        // Joint 4 of frame 1 behind a limb at image (250, 250): cell (48, 48).
        hidden[17 + 4] = Some([250.0, 250.0]);
        let r = render_hidden(&xy, &boxes, &skel, &ErrorModel::clean(), &hidden).expect("render");
        assert_eq!(r.episodes.hidden, 1);
        let (x, y, _) = r.maps.argmax(1, 4);
        assert!(
            (x - 48.0).abs() <= 0.5 && (y - 48.0).abs() <= 0.5,
            "({x}, {y})"
        );
        // The same joint in the other frames, and the others, at the truth.
        let (x, _, _) = r.maps.argmax(0, 4);
        assert!((x - r.truth[2 * 4]).abs() <= 0.5);
        assert!(render_hidden(&xy, &boxes, &skel, &ErrorModel::clean(), &hidden[1..]).is_err());
    }

    #[test]
    fn rejects_bad_models() {
        let (xy, boxes) = frame();
        let skel = default_layout();
        for bad in [
            ErrorModel {
                swap_rate: 1.5,
                ..ErrorModel::default()
            },
            ErrorModel {
                blob: 0.0,
                ..ErrorModel::default()
            },
            ErrorModel {
                size: [1, 64],
                ..ErrorModel::default()
            },
            ErrorModel {
                noise: f64::NAN,
                ..ErrorModel::default()
            },
        ] {
            assert!(render(&xy, &boxes, &skel, &bad).is_err());
        }
    }
}
