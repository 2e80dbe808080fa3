//! The scores: running means ([`Mean`]), a method's [`Score`] over the cases (with the
//! calibration histograms of its deviations, [`RatioHistogram`]), and the results of one
//! dictionary ([`DictionaryResults`]).

use std::collections::BTreeMap;

use posestream_math::accuracy;

/// A running, frame-weighted mean.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mean {
    sum: f64,
    weight: f64,
}

impl Mean {
    /// Adds `value` with weight `weight`.
    pub fn add(&mut self, value: f64, weight: f64) {
        self.sum += value * weight;
        self.weight += weight;
    }

    /// Adds another mean's sums.
    pub fn merge(&mut self, other: &Self) {
        self.sum += other.sum;
        self.weight += other.weight;
    }

    /// The mean (NaN when empty).
    pub fn get(&self) -> f64 {
        if self.weight > 0.0 {
            self.sum / self.weight
        } else {
            f64::NAN
        }
    }
}

/// Scores of one method over the cases.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Score {
    /// P-MPJPE, mm.
    pub p_mpjpe_mm: Mean,
    /// 2D error, pixels of a 256-pixel crop (heat maps only).
    pub error_2d: Mean,
    /// PCK, percent (heat maps only).
    pub pck: Mean,
    /// Seconds per frame.
    pub seconds_per_frame: Mean,
    /// P-MPJPE per action, mm.
    pub per_action: BTreeMap<String, Mean>,
    /// P-MPJPE of every frame, mm (for percentiles).
    pub frames_mm: Vec<f64>,
    /// Calibration of the per-joint standard deviations: how many pose coordinates
    /// (after the similarity alignment, the deviation scaled with the pose) have
    /// `|error| / std` in each bin of [`RatioHistogram`].
    pub ratios: RatioHistogram,
    /// The same for the lateral coordinates (x, y) alone.
    pub lateral_ratios: RatioHistogram,
    /// The same for the depth coordinate (z) alone.
    pub depth_ratios: RatioHistogram,
}

/// A histogram of `|error| / std` over log-spaced bins (1e-3 to 1e3, 100 per decade),
/// for the fraction within any number of deviations and the scale that calibrates.
#[derive(Debug, Clone, PartialEq)]
pub struct RatioHistogram {
    bins: Vec<f64>,
    total: f64,
}

impl Default for RatioHistogram {
    fn default() -> Self {
        Self {
            bins: vec![0.0; Self::BINS + 2],
            total: 0.0,
        }
    }
}

impl RatioHistogram {
    const BINS: usize = 600;
    const LOG_MIN: f64 = -3.0;
    const PER_DECADE: f64 = 100.0;

    fn bin(ratio: f64) -> usize {
        if ratio.is_nan() {
            return Self::BINS + 1;
        }
        let x = (ratio.log10() - Self::LOG_MIN) * Self::PER_DECADE;
        if x < 0.0 {
            0
        } else if x < Self::BINS as f64 {
            x.floor() as usize + 1
        } else {
            // Beyond the last bin, +inf (a zero deviation) included.
            Self::BINS + 1
        }
    }

    /// Adds one `|error| / std`.
    pub fn add(&mut self, ratio: f64) {
        self.bins[Self::bin(ratio)] += 1.0;
        self.total += 1.0;
    }

    /// True when nothing was added.
    pub fn is_empty(&self) -> bool {
        self.total == 0.0
    }

    /// The fraction within `z` deviations (to the bins' resolution, 2.3 %).
    pub fn within(&self, z: f64) -> f64 {
        let last = Self::bin(z);
        self.bins[..last].iter().sum::<f64>() / self.total
    }

    /// The factor on the deviations that puts a fraction `q` within one deviation: the
    /// `q`-quantile of `|error| / std`.
    pub fn scale_for(&self, q: f64) -> f64 {
        let mut sum = 0.0;
        for (i, n) in self.bins.iter().enumerate() {
            sum += n;
            if sum >= q * self.total {
                return 10f64.powf(Self::LOG_MIN + i as f64 / Self::PER_DECADE);
            }
        }
        f64::INFINITY
    }

    fn merge(&mut self, other: &Self) {
        self.bins
            .iter_mut()
            .zip(&other.bins)
            .for_each(|(a, b)| *a += b);
        self.total += other.total;
    }
}

/// The deviations of the calibration table and the fraction of a normal distribution
/// within each: 50 %, 68.3 %, 90 %, 95.4 %.
pub const CALIBRATION_Z: [(f64, f64); 4] = [
    (0.674_49, 50.0),
    (1.0, 68.27),
    (1.644_85, 90.0),
    (2.0, 95.45),
];

impl Score {
    /// The `q`-quantile (0..=1) of the per-frame P-MPJPE, mm (NaN without frames): the
    /// nearest rank.
    pub fn frame_quantile(&self, q: f64) -> f64 {
        let mut v: Vec<f64> = self
            .frames_mm
            .iter()
            .copied()
            .filter(|e| e.is_finite())
            .collect();
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
        v[i]
    }

    /// Adds another score's sums (the same method on other cases).
    pub fn merge(&mut self, other: &Self) {
        self.p_mpjpe_mm.merge(&other.p_mpjpe_mm);
        self.error_2d.merge(&other.error_2d);
        self.pck.merge(&other.pck);
        self.seconds_per_frame.merge(&other.seconds_per_frame);
        for (a, m) in &other.per_action {
            self.per_action.entry(a.clone()).or_default().merge(m);
        }
        self.frames_mm.extend_from_slice(&other.frames_mm);
        self.ratios.merge(&other.ratios);
        self.depth_ratios.merge(&other.depth_ratios);
        self.lateral_ratios.merge(&other.lateral_ratios);
    }

    /// Adds `|error| / std` of every coordinate of `poses` (`std`: per frame, joint and
    /// axis) against the truth, after each frame's similarity alignment (which scales
    /// the deviations too).
    pub(super) fn add_calibration(
        &mut self,
        poses: &[f64],
        std: &[f64],
        truth: &[f64],
        joints: usize,
    ) {
        let n = 3 * joints;
        for ((pred, truth), std) in poses
            .chunks_exact(n)
            .zip(truth.chunks_exact(n))
            .zip(std.chunks_exact(n))
        {
            let aligned = accuracy::procrustes_align(pred, truth, false);
            let spread = |v: &[f64]| {
                let mut c = [0.0; 3];
                for q in v.chunks_exact(3) {
                    (0..3).for_each(|i| c[i] += q[i] / joints as f64);
                }
                v.chunks_exact(3)
                    .map(|q| (0..3).map(|i| (q[i] - c[i]).powi(2)).sum::<f64>())
                    .sum::<f64>()
                    .sqrt()
            };
            let scale = spread(&aligned) / spread(pred);
            if !scale.is_finite() {
                continue;
            }
            for i in 0..n {
                let e = (aligned[i] - truth[i]).abs();
                self.ratios.add(e / (std[i] * scale));
                if i % 3 == 2 {
                    self.depth_ratios.add(e / (std[i] * scale));
                } else {
                    self.lateral_ratios.add(e / (std[i] * scale));
                }
            }
        }
    }

    /// Scores poses of `frames` frames against the truth: the mean and every frame's
    /// P-MPJPE, weighted by frame.
    pub(super) fn add_poses(
        &mut self,
        poses: &[f64],
        truth: &[f64],
        joints: usize,
        action: &str,
    ) -> f64 {
        let n = 3 * joints;
        let start = self.frames_mm.len();
        for (pred, truth) in poses.chunks_exact(n).zip(truth.chunks_exact(n)) {
            self.frames_mm
                .push(1000.0 * accuracy::p_mpjpe(pred, truth, joints));
        }
        let frames = self.frames_mm.len() - start;
        let e = self.frames_mm[start..].iter().sum::<f64>() / frames.max(1) as f64;
        self.p_mpjpe_mm.add(e, frames as f64);
        self.per_action
            .entry(action.to_string())
            .or_default()
            .add(e, frames as f64);
        e
    }
}

/// The results of one dictionary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DictionaryResults {
    /// Label of the dictionary.
    pub label: String,
    /// Table 1: (camera, method) -> score; camera "static" or "orbit", method "init" or
    /// "algorithm 1".
    pub given_2d: BTreeMap<(String, String), Score>,
    /// Table 3: method ("init (arg-max)", "EM", "EM, no smoothness") -> score.
    pub heatmaps: Vec<(String, Score)>,
    /// Frames evaluated.
    pub frames: usize,
    /// Sequences evaluated.
    pub cases: usize,
}

impl DictionaryResults {
    /// Adds the results of the same dictionary and model on other cases.
    pub fn merge(&mut self, other: &Self) {
        for (key, sc) in &other.given_2d {
            self.given_2d.entry(key.clone()).or_default().merge(sc);
        }
        for (m, sc) in &other.heatmaps {
            match self.heatmaps.iter_mut().find(|(n, _)| n == m) {
                Some((_, mine)) => mine.merge(sc),
                None => self.heatmaps.push((m.clone(), sc.clone())),
            }
        }
        self.frames += other.frames;
        self.cases += other.cases;
    }
}
