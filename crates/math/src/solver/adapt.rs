//! Fitting the person, not only the dictionary: a per-track shape offset `D` (3 x p, in
//! the dictionary's frame) added to every pose, `S_t = D + sum_i c_it B_i`.
//!
//! A sparse dictionary cannot leave the span of its training skeletons: a person whose
//! joints sit elsewhere (another mocap system's pelvis or head-top, other proportions)
//! stays wrong however good the 2D evidence. `D` is the same in every frame of a track,
//! so frames that see the person from different sides (the person turns, the camera
//! moves) pin all three of its axes; a ridge prior `lambda/2 |D|^2` keeps an axis no
//! frame sees at zero. With the rest of the model fixed its step is closed form, one
//! 3 x 3 system per joint:
//!
//! ```text
//! (sum_t w_tj P_t' P_t + lambda I) d_j = sum_t w_tj P_t' (W_tj - T_t - P_t s_tj)
//! ```
//!
//! with `P_t = Pi R_t` (so `P_t' P_t = I - r_t r_t'`, `r_t` the camera's depth axis in the
//! dictionary's frame) and `s_tj` joint j of `sum_i c_it B_i`. `lambda` counts frames:
//! a prior worth `lambda` frames of one joint's evidence. Each joint's offset is capped
//! at [`Adaptation::max_offset`] times the fit's mean bone length, so a bad window cannot
//! run away.
//!
//! The statistics are sums over frames ([`ShapeStats`]): a batch adds every frame, a
//! sliding window the frames it freezes (with a forgetting factor).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::{FrameFit, Observations};
use crate::dictionary::Dictionary;
use posestream_base::{OutOfDomain, check_range, check_real};

/// Settings of the shape adaptation (`[estimator.params.adaptation]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Adaptation {
    /// Adapt at all (false: the paper's model, poses in the dictionary's span).
    pub enabled: bool,
    /// Weight of the prior `lambda/2 |d_j|^2`, in frames of evidence.
    pub prior_frames: f64,
    /// A joint's offset at most, times the mean bone length of the fit.
    pub max_offset: f64,
    /// Offset steps of the batch estimator at most, each followed by a warm-started
    /// solve (Algorithm 1 or the EM); they stop once the offset settles.
    pub passes: usize,
    /// The sliding window's memory: each frame leaving the window adds its evidence,
    /// and older evidence fades with this time constant (frames).
    pub memory_frames: f64,
}

impl Default for Adaptation {
    fn default() -> Self {
        Self {
            enabled: true,
            prior_frames: 100.0,
            max_offset: 0.5,
            passes: 2,
            memory_frames: 300.0,
        }
    }
}

impl Adaptation {
    /// The paper's model: no adaptation.
    pub fn off() -> Self {
        Self {
            enabled: false,
            ..Self::default()
        }
    }

    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_real("adaptation.prior_frames", self.prior_frames, 0.0, 1e9, true)?;
        check_real("adaptation.max_offset", self.max_offset, 0.0, 10.0, false)?;
        check_range("adaptation.passes", self.passes, 0, 100)?;
        check_real(
            "adaptation.memory_frames",
            self.memory_frames,
            1.0,
            1e9,
            false,
        )?;
        Ok(())
    }
}

/// Sufficient statistics of the offset step, per joint: `A_j = sum w P'P` and
/// `b_j = sum w P' r`, and the bone lengths seen (for the cap).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ShapeStats {
    a: Vec<Matrix3<f64>>,
    b: Vec<Vector3<f64>>,
    bone_sum: f64,
    bone_count: f64,
    shape: Vec<f64>,
}

impl ShapeStats {
    /// Empty statistics of `p` joints.
    pub fn new(p: usize) -> Self {
        Self {
            a: vec![Matrix3::zeros(); p],
            b: vec![Vector3::zeros(); p],
            bone_sum: 0.0,
            bone_count: 0.0,
            shape: vec![0.0; 3 * p],
        }
    }

    /// Forgets everything (keeping the buffers).
    pub fn clear(&mut self) {
        self.a.fill(Matrix3::zeros());
        self.b.fill(Vector3::zeros());
        self.bone_sum = 0.0;
        self.bone_count = 0.0;
    }

    /// Forgets: every sum times `keep` (in 0..=1).
    pub fn decay(&mut self, keep: f64) {
        self.a.iter_mut().for_each(|a| *a *= keep);
        self.b.iter_mut().for_each(|b| *b *= keep);
        self.bone_sum *= keep;
        self.bone_count *= keep;
    }

    /// Adds frame `t` of `obs` under `fit` (composed with `dict`, whose own offset is
    /// taken out of the residual).
    pub fn add_frame(&mut self, dict: &Dictionary, obs: &Observations, t: usize, fit: &FrameFit) {
        let p = dict.num_joints();
        if self.a.len() != p {
            *self = Self::new(p);
        }
        dict.compose_into(&fit.coefficients, &mut self.shape);
        // The pose without the offset, in place.
        let s = &mut self.shape;
        s.iter_mut().zip(dict.offset()).for_each(|(s, d)| *s -= d);
        let r = &fit.rotation;
        // Rows 0 and 1 of R project; P'P = R' diag(1, 1, 0) R.
        let r0 = Vector3::new(r[(0, 0)], r[(0, 1)], r[(0, 2)]);
        let r1 = Vector3::new(r[(1, 0)], r[(1, 1)], r[(1, 2)]);
        let ptp = r0 * r0.transpose() + r1 * r1.transpose();
        let (xy, w) = (obs.frame(t), obs.frame_weights(t));
        for j in 0..p {
            if !(w[j] > 0.0 && w[j].is_finite()) {
                continue;
            }
            let q = Vector3::new(s[j], s[p + j], s[2 * p + j]);
            let ru = xy[2 * j] - fit.translation.x - r0.dot(&q);
            let rv = xy[2 * j + 1] - fit.translation.y - r1.dot(&q);
            let b = r0 * ru + r1 * rv;
            // Evidence that is not finite (a degenerate fit) is left out: the sums would
            // never recover from it.
            if b.iter().chain(ptp.iter()).all(|v| v.is_finite()) {
                self.a[j] += w[j] * ptp;
                self.b[j] += w[j] * b;
            }
        }
        // Bone lengths of the dictionary's part alone: the offset does not raise its own
        // cap.
        for (a, b) in dict.skeleton().bones() {
            let l = (0..3)
                .map(|i| (s[i * p + a] - s[i * p + b]).powi(2))
                .sum::<f64>()
                .sqrt();
            if l.is_finite() {
                self.bone_sum += l;
                self.bone_count += 1.0;
            }
        }
    }

    /// True before any frame's evidence.
    pub fn is_empty(&self) -> bool {
        self.bone_count <= 0.0
    }

    /// The offset (row-major 3 x p) these statistics give under `settings`, written into
    /// `out`: centred, then each joint capped (so [`Dictionary::set_offset`]'s centring
    /// moves it by at most the mean of what the caps took).
    pub fn solve(&self, settings: &Adaptation, out: &mut [f64]) {
        let p = self.a.len();
        out.iter_mut().for_each(|v| *v = 0.0);
        if self.is_empty() {
            return;
        }
        for j in 0..p {
            let m = self.a[j] + Matrix3::identity() * settings.prior_frames;
            let Some(d) = m.cholesky().map(|c| c.solve(&self.b[j])) else {
                continue;
            };
            if d.iter().all(|v| v.is_finite()) {
                for i in 0..3 {
                    out[i * p + j] = d[i];
                }
            }
        }
        // Centred first (a shift of every joint is the translation's), then each joint
        // capped.
        for row in out.chunks_exact_mut(p) {
            let m = row.iter().sum::<f64>() / p as f64;
            row.iter_mut().for_each(|v| *v -= m);
        }
        let cap = settings.max_offset * self.bone_sum / self.bone_count;
        for j in 0..p {
            let n = (0..3).map(|i| out[i * p + j].powi(2)).sum::<f64>().sqrt();
            if n > cap {
                let f = if cap > 0.0 { cap / n } else { 0.0 };
                (0..3).for_each(|i| out[i * p + j] *= f);
            }
        }
    }
}

/// One offset step over a whole sequence: the offset `fits` on `obs` call for, set on
/// `dict` (which the fits were composed with). True when it moved no joint by more than
/// 1 % of the mean bone length (settled).
pub fn offset_step(
    dict: &mut Dictionary,
    obs: &Observations,
    fits: &[FrameFit],
    settings: &Adaptation,
    stats: &mut ShapeStats,
    out: &mut Vec<f64>,
) -> bool {
    let p = dict.num_joints();
    *stats = ShapeStats::new(p);
    for (t, fit) in fits.iter().enumerate() {
        stats.add_frame(dict, obs, t, fit);
    }
    out.resize(3 * p, 0.0);
    stats.solve(settings, out);
    let before = dict.offset().to_vec();
    dict.set_offset(out);
    let bone = stats.bone_sum / stats.bone_count.max(f64::MIN_POSITIVE);
    let moved = (0..p)
        .map(|j| {
            (0..3)
                .map(|i| (dict.offset()[i * p + j] - before[i * p + j]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max);
    moved <= 0.01 * bone
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::streaming::StreamSettings;

    /// Hostile values of the new configuration keys are refused by name, not used.
    #[test]
    fn hostile_settings_are_refused_naming_the_key() {
        let bad = [
            (
                "adaptation.prior_frames",
                Adaptation {
                    prior_frames: f64::NAN,
                    ..Adaptation::default()
                },
            ),
            (
                "adaptation.prior_frames",
                Adaptation {
                    prior_frames: 0.0,
                    ..Adaptation::default()
                },
            ),
            (
                "adaptation.max_offset",
                Adaptation {
                    max_offset: f64::INFINITY,
                    ..Adaptation::default()
                },
            ),
            (
                "adaptation.max_offset",
                Adaptation {
                    max_offset: -1.0,
                    ..Adaptation::default()
                },
            ),
            (
                "adaptation.passes",
                Adaptation {
                    passes: usize::MAX,
                    ..Adaptation::default()
                },
            ),
            (
                "adaptation.memory_frames",
                Adaptation {
                    memory_frames: 0.5,
                    ..Adaptation::default()
                },
            ),
        ];
        for (key, a) in bad {
            let e = a.check().expect_err(key).to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
        assert!(Adaptation::default().check().is_ok());
        for (key, s) in [
            (
                "depth_std_scale",
                StreamSettings {
                    depth_std_scale: f64::NAN,
                    ..StreamSettings::default()
                },
            ),
            (
                "std_scale",
                StreamSettings {
                    std_scale: 1e300,
                    ..StreamSettings::default()
                },
            ),
            (
                "std_scale",
                StreamSettings {
                    std_scale: 0.0,
                    ..StreamSettings::default()
                },
            ),
            (
                "newest_std_scale",
                StreamSettings {
                    newest_std_scale: f64::INFINITY,
                    ..StreamSettings::default()
                },
            ),
            (
                "newest_std_scale",
                StreamSettings {
                    newest_std_scale: -1.0,
                    ..StreamSettings::default()
                },
            ),
            (
                "newest_std_scale",
                StreamSettings {
                    newest_std_scale: 1e-308,
                    ..StreamSettings::default()
                },
            ),
            (
                "std_scale",
                StreamSettings {
                    std_scale: 1e-308,
                    ..StreamSettings::default()
                },
            ),
            (
                "depth_std_scale",
                StreamSettings {
                    depth_std_scale: 1e-308,
                    ..StreamSettings::default()
                },
            ),
        ] {
            let e = s.check().expect_err(key).to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }

    /// Evidence that is not finite is left out, and the offset stays finite and capped.
    #[test]
    fn non_finite_evidence_leaves_the_offset_finite() {
        let mut stats = ShapeStats::new(2);
        stats.a[0] = Matrix3::identity() * 5.0;
        stats.b[0] = Vector3::new(1e308, 1e308, 1e308);
        stats.bone_sum = 1.0;
        stats.bone_count = 1.0;
        let mut out = vec![0.0; 6];
        stats.solve(&Adaptation::default(), &mut out);
        assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
        let n0 = (0..3).map(|i| out[i * 2].powi(2)).sum::<f64>().sqrt();
        assert!(n0 <= 0.5 + 1e-12, "{n0}");
        stats.clear();
        assert!(stats.is_empty());
    }
}
