//! Where the views agree, they win: each fused joint moved off the dictionary's shape
//! towards its views' heat-map peaks. The dictionary spans the poses it learnt (walks,
//! dances, gestures); a crouch or a climb lies outside it, and three views that agree
//! on a knee should not be pulled back into that span.
//!
//! Per joint `j` of a frame, the point `x` minimising
//!
//! ```text
//! |x - m_j|^2 / s^2  +  sum over views v  w_v |(I - d_v d_v^T)(x - o_v)|^2
//! ```
//!
//! where `m_j` is the model's joint, `s` [`DeviationSettings::joint_std`] (how far a
//! joint may leave the dictionary's shape), `o_v` the view's ray origin and `d_v` the ray
//! through its peak. A view's weight is one over its peak's spread at the joint's depth
//! ([`DeviationSettings::peak_std`] heat-map cells), squared, times a Cauchy factor of
//! its reprojection distance ([`DeviationSettings::outlier_cells`]): a swapped joint or
//! a wrong camera weighs little where the others agree (iteratively reweighted, from
//! the views' robust triangulation when two see the joint, else the model's joint).
//! One view pins the joint to its ray and leaves the depth to the model; none leaves
//! the model's joint. Seen by more views the evidence outweighs the prior.
//!
//! The deviations `x - m_j` are then the median over [`DeviationSettings::frames`]
//! frames centred on the one put out (the model's motion stays smooth; a peak wrong in
//! one frame moves nothing).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::camera::ViewCamera;
use super::frame::ViewData;
use super::triangulation::{PeakView, median, robust_point};
use posestream_base::{OutOfDomain, check_range, check_real};

/// How far the views may move the fused joints off the dictionary's shape
/// (`[estimator.fusion.deviation]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviationSettings {
    /// The prior's standard deviation of a joint off the model's, metres (0: the model's
    /// joints as they are).
    pub joint_std: f64,
    /// A heat-map peak's standard deviation, heat-map cells.
    pub peak_std: f64,
    /// Reprojection distance, heat-map cells, at which a view's weight is halved.
    pub outlier_cells: f64,
    /// Peaks at or below this are no view of the joint.
    pub min_peak: f64,
    /// Frames of the centred median of the deviations (odd; 1: none).
    pub frames: usize,
    /// Reweighting rounds.
    pub rounds: usize,
}

impl Default for DeviationSettings {
    fn default() -> Self {
        Self {
            joint_std: 0.05,
            peak_std: 0.8,
            outlier_cells: 2.0,
            min_peak: 0.1,
            frames: 5,
            rounds: 3,
        }
    }
}

impl DeviationSettings {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_real("joint_std", self.joint_std, 0.0, 10.0, false)?;
        if self.joint_std > 0.0 && self.joint_std < 1e-4 {
            return Err(OutOfDomain::new(
                "joint_std",
                "0, or in [1e-4, 10] metres",
                self.joint_std,
            ));
        }
        check_real("peak_std", self.peak_std, 1e-3, 1e3, false)?;
        check_real("outlier_cells", self.outlier_cells, 0.0, 1e6, true)?;
        check_real("min_peak", self.min_peak, 0.0, 1e30, false)?;
        check_range("frames", self.frames, 1, 99)?;
        if self.frames.is_multiple_of(2) {
            return Err(OutOfDomain::new(
                "frames",
                "odd (the median is centred on the frame put out)",
                self.frames,
            ));
        }
        check_range("rounds", self.rounds, 1, 100)
    }
}

/// Buffers of the deviations (kept: nothing is allocated once they have grown).
#[derive(Debug, Clone, Default)]
pub(super) struct DeviationBuffers {
    peaks: Vec<PeakView>,
    /// Each peak's heat-map cell, image pixels.
    cells: Vec<f64>,
    /// Each peak's ray origin (the camera centre moved back by the body's motion over
    /// the view's time offset, as the E-step's).
    origins: Vec<Vector3<f64>>,
    /// Per frame of the median, per joint, the deviation.
    deviations: Vec<Vec<Vector3<f64>>>,
    values: Vec<f64>,
}

/// The point of joint `j` from the `views` (their peaks, `cameras` by their index)
/// against the model's joint `model` (module docs).
fn joint_point(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    views: &[ViewData],
    j: usize,
    model: Vector3<f64>,
    b: &mut DeviationBuffers,
) -> Vector3<f64> {
    b.peaks.clear();
    b.cells.clear();
    b.origins.clear();
    for vd in views.iter().filter(|vd| !vd.bridged && vd.evidence) {
        let Some(&[u, v, score]) = vd.peaks.get(j) else {
            continue;
        };
        if score > settings.min_peak && u.is_finite() && v.is_finite() {
            b.peaks.push(PeakView {
                camera: cameras[vd.view],
                pixel: [u, v],
                score,
            });
            b.cells
                .push(vd.to_image.mean_scale().max(f64::MIN_POSITIVE));
            b.origins.push(vd.origin);
        }
    }
    if b.peaks.is_empty() {
        return model;
    }
    let prior = 1.0 / (settings.joint_std * settings.joint_std);
    // From the views' robust triangulation (all views where they agree within twice the
    // outlier distance of the largest cell, else the pair that agrees best).
    let gate = 2.0 * settings.outlier_cells * b.cells.iter().copied().fold(0.0, f64::max);
    let mut x = if b.peaks.len() >= 2 {
        robust_point(&b.peaks, gate).unwrap_or(model)
    } else {
        model
    };
    for round in 0..settings.rounds {
        let mut a = Matrix3::identity() * prior;
        let mut rhs = model * prior;
        for ((pv, &cell), origin) in b.peaks.iter().zip(&b.cells).zip(&b.origins) {
            let cam = &pv.camera;
            // The joint as the camera saw it at its time offset: the ray's origin is
            // the camera centre moved back by the body's motion over it.
            let Some(([u, v], z)) = cam.project(&(x + (cam.centre() - origin))) else {
                continue;
            };
            let off = (u - pv.pixel[0]).hypot(v - pv.pixel[1]) / cell;
            let robust = 1.0 / (1.0 + (off / settings.outlier_cells).powi(2));
            let spread = settings.peak_std * cell * z / cam.intrinsics.focal();
            let w = robust / (spread * spread);
            let d = cam.ray(pv.pixel[0], pv.pixel[1]);
            let proj = Matrix3::identity() - d * d.transpose();
            a += proj * w;
            rhs += proj * origin * w;
        }
        match a.try_inverse().map(|inv| inv * rhs) {
            Some(next) if next.iter().all(|v| v.is_finite()) => x = next,
            // Nothing solved: the model's joint, not an unweighted start.
            _ if round == 0 => return model,
            _ => break,
        }
    }
    x
}

/// Moves `joints` (frame `centre` of `n` frames, `[x, y, z]` per joint, world frame) by
/// the median of the deviations of the frames within `settings.frames / 2` of it (of
/// those there are). `frame(k)` gives frame `k`'s model joints and views.
pub(super) fn deviate<'a>(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    n: usize,
    frame: impl Fn(usize) -> (&'a [f64], &'a [ViewData]),
    centre: usize,
    joints: &mut [f64],
    b: &mut DeviationBuffers,
) {
    if settings.joint_std <= 0.0 || centre >= n {
        return;
    }
    let p = joints.len() / 3;
    let half = settings.frames / 2;
    let first = centre.saturating_sub(half);
    let last = (centre + half).min(n - 1);
    let n = last + 1 - first;
    if b.deviations.len() < n {
        b.deviations.resize_with(n, Vec::new);
    }
    for k in 0..n {
        let (model, views) = frame(first + k);
        let mut out = std::mem::take(&mut b.deviations[k]);
        out.clear();
        for j in 0..p.min(model.len() / 3) {
            let m = Vector3::new(model[3 * j], model[3 * j + 1], model[3 * j + 2]);
            let x = joint_point(settings, cameras, views, j, m, b);
            out.push(x - m);
        }
        b.deviations[k] = out;
    }
    for j in 0..p {
        for axis in 0..3 {
            b.values.clear();
            b.values.extend(
                b.deviations[..n]
                    .iter()
                    .filter_map(|d| d.get(j).map(|v| v[axis])),
            );
            let Some(median) = median(&mut b.values) else {
                continue;
            };
            if median.is_finite() {
                joints[3 * j + axis] += median;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::camera::ring;
    use super::*;
    use posestream_base::PixelMap;

    /// A view of one joint by `camera` (index `view`) with its peak at `pixel`, cells of
    /// 4 px.
    fn view(view: usize, pixel: [f64; 2]) -> ViewData {
        let mut vd = ViewData::new();
        vd.view = view;
        vd.evidence = true;
        vd.to_image = PixelMap {
            scale: [4.0, 4.0],
            offset: [0.0, 0.0],
        };
        vd.peaks = vec![[pixel[0], pixel[1], 1.0]];
        vd
    }

    fn seen(cams: &[ViewCamera], at: &Vector3<f64>, off: &[[f64; 2]]) -> Vec<ViewData> {
        cams.iter()
            .enumerate()
            .map(|(c, cam)| {
                let ([u, v], _) = cam.project(at).expect("in front");
                let mut vd = view(c, [u + off[c][0], v + off[c][1]]);
                vd.origin = cam.centre();
                vd
            })
            .collect()
    }

    fn moved(cams: &[ViewCamera], model: Vector3<f64>, views: &[ViewData]) -> Vector3<f64> {
        let mut joints = vec![model.x, model.y, model.z];
        let model = joints.clone();
        deviate(
            &DeviationSettings::default(),
            cams,
            1,
            |_| (&model[..], views),
            0,
            &mut joints,
            &mut DeviationBuffers::default(),
        );
        Vector3::new(joints[0], joints[1], joints[2])
    }

    #[test]
    fn views_that_agree_move_the_joint_off_the_model() {
        let cams = ring(3, 5.0);
        let truth = Vector3::new(0.2, -0.1, 1.3);
        let model = truth + Vector3::new(0.15, 0.1, -0.1);
        let views = seen(&cams, &truth, &[[0.5, -0.5], [-0.5, 0.0], [0.0, 0.5]]);
        let x = moved(&cams, model, &views);
        // Each view's peak spreads 0.8 cells x 4 px at 5 m: 2 cm; the prior 5 cm. Three
        // views leave the model's pull at a few per cent of its 0.2 m.
        assert!((x - truth).norm() < 0.03, "{} m off", (x - truth).norm());
    }

    #[test]
    fn a_swapped_view_is_outweighed_by_two_that_agree() {
        let cams = ring(3, 5.0);
        let truth = Vector3::new(0.0, 0.1, 1.0);
        // The third view's peak is another joint's, 15 cells away.
        let views = seen(&cams, &truth, &[[0.0; 2], [1.0, 0.0], [60.0, 0.0]]);
        let x = moved(&cams, truth + Vector3::new(0.05, 0.0, 0.0), &views);
        let peaks: Vec<PeakView> = views
            .iter()
            .zip(&cams)
            .map(|(v, c)| PeakView {
                camera: *c,
                pixel: [v.peaks[0][0], v.peaks[0][1]],
                score: 1.0,
            })
            .collect();
        let all = super::super::triangulation::dlt(&peaks).expect("determined");
        assert!(
            (all - truth).norm() > 0.1,
            "all three: {} m off",
            (all - truth).norm()
        );
        assert!((x - truth).norm() < 0.04, "{} m off", (x - truth).norm());
    }

    #[test]
    fn a_swapped_view_cannot_drag_a_joint_the_model_has_far_off() {
        let cams = ring(4, 5.0);
        let truth = Vector3::new(-0.1, 0.2, 0.9);
        // The model 0.3 m off (a crouch the dictionary cannot make); the fourth view's
        // peak is another joint's, 20 cells away.
        let views = seen(
            &cams,
            &truth,
            &[[0.5, 0.0], [0.0, -0.5], [-0.5, 0.5], [0.0, 80.0]],
        );
        let x = moved(&cams, truth + Vector3::new(0.0, 0.0, 0.3), &views);
        assert!((x - truth).norm() < 0.04, "{} m off", (x - truth).norm());
    }

    #[test]
    fn a_camera_that_took_its_image_later_sees_the_joint_where_it_had_moved() {
        let cams = ring(3, 5.0);
        let truth = Vector3::new(0.0, 0.0, 1.0);
        // Camera 2 took its image 20 ms late of a body moving 1.5 m/s along x: its
        // peak is where the joint was then, its ray's origin moved back by as much.
        let motion = Vector3::new(0.03, 0.0, 0.0);
        let mut views = seen(&cams, &truth, &[[0.0; 2]; 3]);
        let late = seen(&cams[2..], &(truth + motion), &[[0.0; 2]]).remove(0);
        views[2].peaks = late.peaks;
        views[2].origin = cams[2].centre() - motion;
        let x = moved(&cams, truth + Vector3::new(0.1, 0.0, 0.0), &views);
        assert!((x - truth).norm() < 0.02, "{} m off", (x - truth).norm());
    }

    #[test]
    fn medians_of_even_counts_take_the_middle_two() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
    }

    #[test]
    fn even_frames_and_a_vanishing_prior_are_refused() {
        let ok = DeviationSettings::default();
        assert!(ok.check().is_ok());
        for bad in [
            DeviationSettings { frames: 4, ..ok },
            DeviationSettings {
                joint_std: 1e-160,
                ..ok
            },
            DeviationSettings {
                peak_std: 0.0,
                ..ok
            },
            DeviationSettings { rounds: 0, ..ok },
        ] {
            assert!(bad.check().is_err(), "{bad:?}");
        }
        assert!(
            DeviationSettings {
                joint_std: 0.0,
                ..ok
            }
            .check()
            .is_ok(),
            "0: off"
        );
    }

    #[test]
    fn one_view_pins_the_joint_to_its_ray_and_the_model_keeps_the_depth() {
        let cams = ring(1, 5.0);
        let truth = Vector3::new(0.1, 0.1, 1.2);
        let views = seen(&cams, &truth, &[[0.0; 2]]);
        // The model is off along the ray (depth) and across it.
        let ray = (truth - cams[0].centre()).normalize();
        let across = ray.cross(&Vector3::z()).normalize();
        let model = truth + ray * 0.3 + across * 0.05;
        let x = moved(&cams, model, &views);
        let from_ray = (x - cams[0].centre()).cross(&ray).norm();
        // The view (2 cm) against the prior (5 cm) across the ray: 400 / (400 + 2500) of
        // the model's 5 cm is left.
        assert!(from_ray < 0.01, "{from_ray} m off the ray");
        assert!(
            ((x - truth).dot(&ray) - 0.3).abs() < 0.01,
            "the depth stays the model's"
        );
    }

    #[test]
    fn no_view_or_broken_peaks_leave_the_model() {
        let cams = ring(2, 5.0);
        let model = Vector3::new(0.0, 0.0, 1.0);
        assert_eq!(moved(&cams, model, &[]), model);
        let mut bad = seen(&cams, &model, &[[0.0; 2], [0.0; 2]]);
        bad[0].peaks[0] = [f64::NAN, 1.0, 1.0];
        bad[1].peaks[0] = [1e300, -1e300, 1.0];
        let x = moved(&cams, model, &bad);
        assert!(x.iter().all(|v| v.is_finite()));
        // A peak at or below min_peak is no view.
        let mut weak = seen(
            &cams,
            &(model + Vector3::new(0.3, 0.0, 0.0)),
            &[[0.0; 2], [0.0; 2]],
        );
        for v in &mut weak {
            v.peaks[0][2] = 0.05;
        }
        assert_eq!(moved(&cams, model, &weak), model);
    }
}
