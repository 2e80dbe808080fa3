//! [`Estimator`]: a [`Dictionary`] plus [`Params`], lifting 2D joints or heat maps of a
//! sequence to 3D poses. The entry point of the library; the batch `lift` command and the
//! streaming nodes are thin adapters over it.

use serde::Serialize;

use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::solver::coefficients::basis_gram_max;
use crate::solver::init::{InitCache, InitWorkspace, initialise_frame_into};
use crate::solver::perspective::PerspectiveFit;
use crate::solver::{FrameFit, InitMethod, Params};

/// Frames running that the sliding window's initialisation swaps a left/right pair's
/// maps back at most (a third of a second at 30 frames/s): a detector's swap is an
/// episode, a "swap" that lasts is the person's own (the maps then stand).
pub const MAX_SWAP_FRAMES: u32 = 10;

/// Frames after it a frame's fit has seen when the batch EM starts from it
/// ([`Params::start_from_window`]): the window's estimate that many frames back. On the
/// training files (`posestream eval --train --max-files-per-action 1 --no-scenes`, our
/// K128, EM P-MPJPE / 90th-percentile frame, mm) lag 0: 46.4 / 82.0, 2: 45.5 / 77.2,
/// 3: 45.6 / 76.8, 5: 45.5 / 77.3, 10 (the window's default): 46.3 / 77.5, 20: 46.9 /
/// 81.3; the authors' K128 66.8-66.9 for all. A fit refined further is not a better
/// start: the batch EM refines it with every frame after it anyway.
pub const START_LAG: usize = 3;

/// How much nearer (summed squared distance) a left/right pair's peaks must lie to the
/// track's previous peaks (each joint's last seen, as put back) swapped than as they are
/// for the sliding window's initialisation to put them back: at 1, two limbs crossing
/// in the image (a kick seen from the side) were put back on noise and held the fit on
/// the mirrored side (the held-out kick, docs/beyond-the-paper.md); on the training
/// files 2 leaves the window's errors as they were (`posestream eval --train
/// --max-files-per-action 1`). A joint unseen for a while keeps its last peak as the
/// reference (no expiry yet).
pub const SWAP_MARGIN: f64 = 2.0;

/// 2D joints of a sequence in pixels, with optional per-joint confidence in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Keypoints {
    /// Joints per frame.
    pub joints: usize,
    /// `[x, y]` per joint, frame-major (x right, y down).
    pub xy: Vec<f64>,
    /// Confidence per joint (`t*p + j`); `None` means all 1. A joint with confidence 0 is
    /// not observed.
    pub confidence: Option<Vec<f64>>,
}

impl Keypoints {
    /// Number of frames.
    pub fn frames(&self) -> usize {
        if self.joints == 0 {
            0
        } else {
            self.xy.len() / (2 * self.joints)
        }
    }
}

/// How the estimate was reached.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct Report {
    /// Frames.
    pub frames: usize,
    /// Initialisation method.
    pub init: String,
    /// EM iterations (1 for given 2D joints).
    pub em_iterations: usize,
    /// Block-coordinate rounds per EM iteration.
    pub rounds: Vec<usize>,
    /// Objective after initialisation.
    pub objective_init: f64,
    /// Objective at the end.
    pub objective: f64,
    /// Objective history: for given 2D joints, before Algorithm 1 and after each of its
    /// rounds (never increasing); for heat maps, after each EM iteration's M-step (each
    /// E-step changes the data, so this sequence may rise slightly).
    pub objective_rounds: Vec<f64>,
    /// Seconds spent initialising.
    pub seconds_init: f64,
    /// Seconds in total.
    pub seconds: f64,
}

/// The result of lifting a sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Joints per frame.
    pub joints: usize,
    /// 3D poses `R_t S_t`, camera frame (x right, y down, z forward), dictionary units,
    /// centred: `[x, y, z]` per joint, frame-major.
    pub poses: Vec<f64>,
    /// The 2D joints the model was fitted to, in input pixels: the given keypoints, or the
    /// EM's expected joints.
    pub keypoints: Vec<f64>,
    /// The model's reprojection `Pi R_t S_t + T_t`, in input pixels.
    pub projected: Vec<f64>,
    /// Per-joint 2D variance (trace of the covariance, pixels^2) from the E-step; heat-map
    /// input only.
    pub variance: Option<Vec<f64>>,
    /// The model parameters per frame (normalised units).
    pub fits: Vec<FrameFit>,
    /// Input pixels per normalised unit (the fits' units).
    pub pixels_per_unit: f64,
    /// Weight of each joint in the fit (`t*p + j`): the keypoints' confidence, the last
    /// EM iteration's E-step weights on heat maps ([`Params::confidence_spread`]), or 1.
    pub weights: Vec<f64>,
    /// The person's shape beyond the dictionary the fits were composed with (row-major
    /// 3 x p, [`crate::solver::adapt`]; zero for the paper's model).
    pub offset: Vec<f64>,
    /// How it was reached.
    pub report: Report,
}

/// The result of the perspective adjustment of an [`Estimate`]
/// ([`Estimator::adjust_perspective`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MetricEstimate {
    /// Joints per frame.
    pub joints: usize,
    /// 3D poses, metres, camera frame (x right, y down, z forward), absolute position:
    /// `[x, y, z]` per joint, frame-major.
    pub poses: Vec<f64>,
    /// The 2D joints the model was fitted to, image pixels.
    pub keypoints: Vec<f64>,
    /// The perspective projection of the poses, image pixels.
    pub projected: Vec<f64>,
    /// The model per frame.
    pub fits: Vec<PerspectiveFit>,
    /// Seconds spent.
    pub seconds: f64,
}

/// Lifts 2D joints or heat maps to 3D with one dictionary and one parameter set.
///
/// ```
/// use posestream_math::skeleton::default_layout;
/// use posestream_math::{Dictionary, Estimator, Keypoints, Params};
///
/// // A dictionary of 8 bases over the default 17 joints (a real one is loaded from a
/// // file: `posestream_msgs::formats::LoadDictionary`).
/// let bases = (0..8 * 3 * 17).map(|i| ((i * 37 % 101) as f64 / 101.0 - 0.5)).collect();
/// let dict = Dictionary::new(default_layout(), bases, vec![0.0; 3 * 17])?;
/// let estimator = Estimator::new(dict, Params::default())?;
/// // Two frames of 17 joints, pixels (x right, y down): a standing figure, 100 px tall.
/// let standing: [f64; 34] = [
///     50., 50., 58., 50., 58., 75., 58., 100., 42., 50., 42., 75., 42., 100., 50., 35.,
///     50., 20., 50., 12., 50., 0., 60., 22., 68., 38., 70., 52., 40., 22., 32., 38.,
///     30., 52.,
/// ];
/// let xy: Vec<f64> = standing.iter().chain(&standing).copied().collect();
/// let estimate = estimator.lift_keypoints(&Keypoints { joints: 17, xy, confidence: None })?;
/// assert_eq!(estimate.poses.len(), 2 * 17 * 3); // (F, p, 3), dictionary units
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone)]
pub struct Estimator {
    pub(crate) dict: Dictionary,
    pub(crate) params: Params,
    pub(crate) cache: InitCache,
    pub(crate) gram_max: f64,
}

impl Estimator {
    /// Prepares an estimator (precomputes the dictionary's factorisations).
    pub fn new(dict: Dictionary, params: Params) -> Result<Self, EstimateError> {
        params.validate()?;
        let gram_max = basis_gram_max(&dict);
        let cache = InitCache::new(&dict, gram_max);
        Ok(Self {
            dict,
            params,
            cache,
            gram_max,
        })
    }

    /// The dictionary, to set a track's offset ([`crate::solver::adapt`]).
    pub(crate) fn dictionary_mut(&mut self) -> &mut Dictionary {
        &mut self.dict
    }

    /// The dictionary.
    pub fn dictionary(&self) -> &Dictionary {
        &self.dict
    }

    /// The parameters.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Precomputed quantities of the initialisation.
    pub fn init_cache(&self) -> &InitCache {
        &self.cache
    }

    /// `lambda_max` of the vectorised bases' Gram matrix (Lipschitz bound of the C-step).
    pub fn basis_gram_max(&self) -> f64 {
        self.gram_max
    }

    /// The initialisation used for given 2D joints (default: convex+robust+refine).
    pub fn keypoint_init(&self) -> InitMethod {
        self.params.init.unwrap_or(InitMethod::ConvexRobustRefine)
    }

    /// The initialisation used for heat maps (default: altern, the reference's most
    /// accurate heat-map mode: P-MPJPE 0.123 against 0.163 for its convex default).
    pub fn heatmap_init(&self) -> InitMethod {
        self.params.init.unwrap_or(InitMethod::Altern)
    }

    /// The per-frame initialisation from heat maps (`map(j)`: joint j's map, `width`
    /// columns; `scale` pixels per unit): each joint at its map's arg-max, visible if its
    /// peak is above the visibility threshold (all, if fewer than two are). Leaves the
    /// arg-max (normalised units) in `xy` and the visibility in `visible`, and the fit
    /// in `fit` (its buffers reused). Shared by the batch EM and the sliding window
    /// (which caps the iterations in `params`, and gives the track's `previous`
    /// arg-maxes, normalised units, each joint where it was last seen, NaN where never,
    /// and per left/right pair the frames its maps have run swapped against them: with
    /// [`Params::swap_prior`] positive, a pair whose arg-maxes lie [`SWAP_MARGIN`] times
    /// nearer those swapped than as they are is swapped back, for a while; `previous`
    /// is then moved to this frame's arg-maxes, as put back).
    pub(crate) fn initialise_from_argmax<'m>(
        &self,
        map: impl Fn(usize) -> &'m [f32],
        width: usize,
        scale: f64,
        xy: &mut [f64],
        visible: &mut [bool],
        params: &Params,
        previous: Option<(&mut [f64], &mut [u32])>,
        ws: &mut InitWorkspace,
        fit: &mut FrameFit,
    ) {
        for (j, v) in visible.iter_mut().enumerate() {
            let (x, y, peak) = crate::heatmaps::argmax(map(j), width);
            xy[2 * j] = x / scale;
            xy[2 * j + 1] = y / scale;
            *v = f64::from(peak) > self.params.visibility_threshold;
        }
        // A detector's left/right swap (the swap model on): a pair whose peaks (both
        // seen) lie clearly nearer the track's previous peaks (each joint's last seen,
        // as put back) swapped than as they are is swapped back, for at most
        // `MAX_SWAP_FRAMES` frames running (a swap that lasts is the person's own, not
        // the detector's: the maps then stand), and not when most pairs are (a
        // whole-body flip of the detector's: the maps stand). Against the maps' own past,
        // not the fit's projection: a fit on a wrong branch would otherwise reorder
        // every new frame to its side, and stay there.
        if let Some((prev, runs)) = previous.filter(|_| self.params.swap_prior > 0.0) {
            let d2 = |xy: &[f64], a: usize, b: usize| {
                (xy[2 * a] - prev[2 * b]).powi(2) + (xy[2 * a + 1] - prev[2 * b + 1]).powi(2)
            };
            let pairs = self.dict.left_right_pairs();
            // Pairs with both joints seen (an empty map's arg-max says nothing).
            let mirrored = |xy: &[f64], seen: &[bool], (l, r): (usize, usize)| {
                seen[l]
                    && seen[r]
                    && SWAP_MARGIN * (d2(xy, l, r) + d2(xy, r, l)) < d2(xy, l, l) + d2(xy, r, r)
            };
            let most = 2 * pairs
                .iter()
                .filter(|&&pair| mirrored(xy, visible, pair))
                .count()
                > pairs.len();
            for (&(l, r), run) in pairs.iter().zip(runs.iter_mut()) {
                if !mirrored(xy, visible, (l, r)) {
                    *run = 0;
                    continue;
                }
                *run = run.saturating_add(1);
                if !most && *run <= MAX_SWAP_FRAMES {
                    xy.swap(2 * l, 2 * r);
                    xy.swap(2 * l + 1, 2 * r + 1);
                    visible.swap(l, r);
                }
            }
            // Where the track's joints were last seen.
            for (j, _) in visible.iter().enumerate().filter(|(_, v)| **v) {
                prev[2 * j..2 * j + 2].copy_from_slice(&xy[2 * j..2 * j + 2]);
            }
        }
        if visible.iter().filter(|&&v| v).count() < 2 {
            visible.iter_mut().for_each(|v| *v = true);
        }
        initialise_frame_into(
            &self.dict,
            &self.cache,
            xy,
            visible,
            self.heatmap_init(),
            params,
            ws,
            fit,
        );
    }
}

#[cfg(test)]
mod tests;
