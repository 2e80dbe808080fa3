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
//! One view pins the joint to its ray, the depth the model's; none leaves the model's
//! joint; more views outweigh the prior.
//!
//! The deviations `x - m_j` are then the median over [`DeviationSettings::frames`]
//! frames centred on the one put out (smooth motion; a peak wrong once moves nothing).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::camera::ViewCamera;
use super::frame::ViewData;
use super::triangulation::{PeakView, median, robust_point, worst_reprojection};
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
    /// Degrees of freedom of the Student-t prior used where enough views agree (0: the
    /// Gaussian prior everywhere).
    pub prior_dof: f64,
    /// Views that must agree on a joint (each within `outlier_cells` of their robust
    /// triangulation) before the prior's tail is heavy (at least 2; fewer views sending
    /// the frame need all of them).
    pub agreeing_views: usize,
    /// The fused joints' standard deviation as a factor of the deviations' own (the
    /// views' spreads and the prior, grown by the views' disagreement): the median over
    /// `frames` narrows it, by less than independent frames would (calibrated on the
    /// walking rooms of `posestream scenes --rooms`, docs/results.md).
    pub std_scale: f64,
    /// A joint moved far off the model is less sure: its variance grows by this times
    /// the squared move per axis (`|x - m|^2 / 3`), before `std_scale` (0.2 adds, after
    /// the scale, 0.016 of it).
    pub move_variance: f64,
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
            prior_dof: 1.0,
            agreeing_views: 3,
            std_scale: 0.53,
            move_variance: 0.2,
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
        check_real("prior_dof", self.prior_dof, 0.0, 1e6, false)?;
        check_range("agreeing_views", self.agreeing_views, 2, 64)?;
        check_real("std_scale", self.std_scale, 0.0, 1e3, true)?;
        check_real("move_variance", self.move_variance, 0.0, 1e3, false)?;
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
    /// Each peak's agreement factor (Cauchy, of its reprojection distance).
    agree: Vec<f64>,
    /// Per frame of the median, per joint, the deviation.
    deviations: Vec<Vec<Vector3<f64>>>,
    values: Vec<f64>,
}

/// The peaks of joint `j` in `views` (sent, with evidence, above
/// [`DeviationSettings::min_peak`], finite) with their cells and ray origins, into `b`.
fn collect(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    views: &[ViewData],
    j: usize,
    b: &mut DeviationBuffers,
) {
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
}

/// How far the views place the body from `model` (`[x, y, z]` per joint, world): the
/// per-axis median, over the joints two or more views triangulate (robustly), of the
/// point's offset from the model's joint; `None` when fewer than half the joints are
/// triangulated. A new frame starts there: a body moving fast (a dash) is not found
/// where it was a frame ago, and the E-step's pull towards the projection would keep it
/// back.
pub(super) fn views_offset(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    views: &[ViewData],
    model: &[f64],
    b: &mut DeviationBuffers,
) -> Option<Vector3<f64>> {
    let p = model.len() / 3;
    let mut offsets = std::mem::take(&mut b.deviations);
    if offsets.is_empty() {
        offsets.push(Vec::new());
    }
    offsets[0].clear();
    for j in 0..p {
        collect(settings, cameras, views, j, b);
        if b.peaks.len() < 2 {
            continue;
        }
        let gate = 2.0 * settings.outlier_cells * b.cells.iter().copied().fold(0.0, f64::max);
        // Only a point every view it came from agrees with (two views' point is not
        // checked by the triangulation itself).
        if let Some(x) = robust_point(&b.peaks, gate)
            && (b.peaks.len() > 2 || worst_reprojection(&x, &b.peaks) <= gate)
        {
            offsets[0].push(x - Vector3::new(model[3 * j], model[3 * j + 1], model[3 * j + 2]));
        }
    }
    let found = offsets[0].len();
    let mut shift = Vector3::zeros();
    for axis in 0..3 {
        b.values.clear();
        b.values.extend(offsets[0].iter().map(|d| d[axis]));
        shift[axis] = median(&mut b.values).unwrap_or(0.0);
    }
    b.deviations = offsets;
    let plausible = shift.iter().all(|v| v.is_finite()) && shift.norm() <= MAX_START_SHIFT;
    (found > 0 && 2 * found >= p && plausible).then_some(shift)
}

/// The farthest a new frame's start is moved from the frame before's, metres (a person
/// at 10 m/s over a 0.1 s gap): beyond it, a camera's track is more likely on someone
/// else than the person that far away.
const MAX_START_SHIFT: f64 = 1.0;

/// The point of joint `j` from the `views` (their peaks, `cameras` by their index)
/// against the model's joint `model` (module docs), and its per-axis variance: the last
/// solve's, grown by the views' disagreement and by `move_variance` of the squared move
/// off the model, times `std_scale` squared (NaN where no view saw the joint).
fn joint_point(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    views: &[ViewData],
    j: usize,
    model: Vector3<f64>,
    b: &mut DeviationBuffers,
) -> (Vector3<f64>, f64) {
    collect(settings, cameras, views, j, b);
    if b.peaks.is_empty() {
        return (model, f64::NAN);
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
    let sending = views.iter().filter(|vd| !vd.bridged && vd.evidence).count();
    let prior = prior * heavy_tail(settings, sending, &x, &model, b);
    let mut variance = f64::NAN;
    for round in 0..settings.rounds {
        agreement(settings, &x, b);
        match solve(settings, prior, &model, &x, b) {
            Some((next, covariance)) => {
                x = next;
                variance = covariance.trace() / 3.0;
            }
            // Nothing solved: the model's joint, not an unweighted start.
            None if round == 0 => return (model, f64::NAN),
            None => break,
        }
    }
    // Where the views disagree beyond their spreads (a swap, an occlusion, a camera
    // off), the variance grows by their disagreement: squared ray distances from the
    // point over the spreads, per degree of freedom, when above 1.
    if variance.is_finite() {
        // Each view as the point weighed it (a swap it let go of counts for little).
        let (mut chi2, mut n) = (0.0, 0.0);
        for ray in weighted_rays(settings, &x, b) {
            let r = (x - ray.origin) - ray.direction * ray.direction.dot(&(x - ray.origin));
            chi2 += ray.weight * r.norm_squared();
            n += 2.0 * ray.agree;
        }
        // The point takes 3 of the ray coordinates' degrees of freedom (fewer than 4
        // coordinates: one view, the prior holds the rest).
        let dof = if n > 3.0 { n - 3.0 } else { n };
        if n > 0.0 && chi2.is_finite() {
            variance *= (chi2 / dof).max(1.0);
        }
        // A joint moved far off the model is less sure of where it is.
        variance += settings.move_variance * (x - model).norm_squared() / 3.0;
        variance *= settings.std_scale * settings.std_scale;
    }
    (x, variance)
}

/// The prior's weight where [`DeviationSettings::agreeing_views`] or more views agree
/// on the joint at `x` (their robust triangulation; of fewer views sending the frame,
/// `sending`, all, at least 2): a Student-t prior of [`DeviationSettings::prior_dof`]
/// degrees of freedom, its EM weight `(dof + 3) / (dof + m^2)` (at most 1), `m^2` the
/// squared Mahalanobis distance of `x` from `model` under the views' covariance plus
/// the prior's. Where views that agree place a joint far from the model (a kicking foot
/// the dictionary cannot bend to), the model lets go; elsewhere (fewer views, or a
/// disagreement) it is the Gaussian prior.
/// Leaves `b.agree` the agreement at `x`.
fn heavy_tail(
    settings: &DeviationSettings,
    sending: usize,
    x: &Vector3<f64>,
    model: &Vector3<f64>,
    b: &mut DeviationBuffers,
) -> f64 {
    let dof = settings.prior_dof;
    if dof <= 0.0 || b.peaks.len() < 2 {
        return 1.0;
    }
    agreement(settings, x, b);
    let agreeing = b.agree.iter().filter(|&&a| a >= 0.5).count();
    // Two views sending have no third to outvote a pair agreeing on a wrong point.
    if agreeing < settings.agreeing_views.min(sending).max(2) {
        return 1.0;
    }
    let information: Matrix3<f64> = weighted_rays(settings, x, b)
        .map(|ray| ray.across() * ray.weight)
        .sum();
    let prior_var = settings.joint_std * settings.joint_std;
    let m2 = information
        .try_inverse()
        .and_then(|cov| (cov + Matrix3::identity() * prior_var).try_inverse())
        .map(|inv| {
            let diff = x - model;
            diff.dot(&(inv * diff))
        });
    match m2 {
        Some(m2) if m2.is_finite() => ((dof + 3.0) / (dof + m2)).min(1.0),
        _ => 1.0,
    }
}

/// One view's ray through its peak, as the deviations weigh it.
struct WeightedRay {
    /// Unit direction, world frame.
    direction: Vector3<f64>,
    /// Where it starts (the camera centre moved back over the view's time offset).
    origin: Vector3<f64>,
    /// Its agreement factor over its peak's spread at the joint's depth, squared.
    weight: f64,
    /// Its agreement factor ([`agreement`]).
    agree: f64,
}

impl WeightedRay {
    /// The projector onto the plane square to the ray (distances across it).
    fn across(&self) -> Matrix3<f64> {
        Matrix3::identity() - self.direction * self.direction.transpose()
    }
}

/// The views' rays of `b` weighed at the joint's place `at` (a view `at` is behind is
/// left out); `b.agree` as [`agreement`] left it.
fn weighted_rays<'a>(
    settings: &'a DeviationSettings,
    at: &'a Vector3<f64>,
    b: &'a DeviationBuffers,
) -> impl Iterator<Item = WeightedRay> + 'a {
    b.peaks
        .iter()
        .zip(&b.cells)
        .zip(&b.origins)
        .zip(&b.agree)
        .filter_map(move |(((pv, &cell), origin), &agree)| {
            let cam = &pv.camera;
            let (_, z) = cam.project(&(at + (cam.centre() - origin)))?;
            let spread = settings.peak_std * cell * z / cam.intrinsics.focal();
            Some(WeightedRay {
                direction: cam.ray(pv.pixel[0], pv.pixel[1]),
                origin: *origin,
                weight: agree / (spread * spread),
                agree,
            })
        })
}

/// Each view's Cauchy factor of its reprojection distance from `x`, in heat-map cells,
/// into `b.agree` (0 for a view `x` is behind).
fn agreement(settings: &DeviationSettings, x: &Vector3<f64>, b: &mut DeviationBuffers) {
    b.agree.clear();
    for ((pv, &cell), origin) in b.peaks.iter().zip(&b.cells).zip(&b.origins) {
        let cam = &pv.camera;
        // The joint as the camera saw it at its time offset: the ray's origin is the
        // camera centre moved back by the body's motion over it.
        let factor = match cam.project(&(x + (cam.centre() - origin))) {
            Some(([u, v], _)) => {
                let off = (u - pv.pixel[0]).hypot(v - pv.pixel[1]) / cell;
                1.0 / (1.0 + (off / settings.outlier_cells).powi(2))
            }
            None => 0.0,
        };
        b.agree.push(factor);
    }
}

/// The point minimising the prior of weight `prior` around `model` plus the views' ray
/// distances, each weighted by its agreement factor over its peak's spread at the depth
/// of `at`, squared, and its covariance (the inverse of the information); `None` when
/// undetermined.
fn solve(
    settings: &DeviationSettings,
    prior: f64,
    model: &Vector3<f64>,
    at: &Vector3<f64>,
    b: &DeviationBuffers,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let mut a = Matrix3::identity() * prior;
    let mut rhs = model * prior;
    for ray in weighted_rays(settings, at, b) {
        let proj = ray.across() * ray.weight;
        a += proj;
        rhs += proj * ray.origin;
    }
    a.try_inverse()
        .map(|inv| (inv * rhs, inv))
        .filter(|(x, _)| x.iter().all(|v| v.is_finite()))
}

/// Moves `joints` (frame `centre` of `n` frames, `[x, y, z]` per joint, world frame) by
/// the median of the deviations of the frames within `settings.frames / 2` of it (of
/// those there are). `frame(k)` gives frame `k`'s model joints and views. Writes to
/// `variance` (one per joint) each joint's per-axis variance in frame `centre` as its
/// views and the prior have it (NaN where no view saw it).
#[allow(
    clippy::too_many_arguments,
    reason = "the frames, the one put out, and its outputs"
)]
pub(super) fn deviate<'a>(
    settings: &DeviationSettings,
    cameras: &[ViewCamera],
    n: usize,
    frame: impl Fn(usize) -> (&'a [f64], &'a [ViewData]),
    centre: usize,
    joints: &mut [f64],
    variance: &mut [f64],
    b: &mut DeviationBuffers,
) {
    variance.fill(f64::NAN);
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
            let (x, var) = joint_point(settings, cameras, views, j, m, b);
            if first + k == centre
                && let Some(v) = variance.get_mut(j)
            {
                *v = var;
            }
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
        moved_with(&DeviationSettings::default(), cams, model, views).0
    }

    /// The joint moved, and its per-axis variance.
    fn moved_with(
        settings: &DeviationSettings,
        cams: &[ViewCamera],
        model: Vector3<f64>,
        views: &[ViewData],
    ) -> (Vector3<f64>, f64) {
        let mut joints = vec![model.x, model.y, model.z];
        let model = joints.clone();
        let mut variance = [0.0];
        deviate(
            settings,
            cams,
            1,
            |_| (&model[..], views),
            0,
            &mut joints,
            &mut variance,
            &mut DeviationBuffers::default(),
        );
        (Vector3::new(joints[0], joints[1], joints[2]), variance[0])
    }

    #[test]
    fn where_three_views_agree_a_model_far_off_lets_go() {
        let cams = ring(3, 5.0);
        let truth = Vector3::new(0.1, 0.3, 0.5);
        // A kicking foot 0.4 m from where the dictionary can put it.
        let model = truth + Vector3::new(0.0, -0.3, 0.25);
        let views = seen(&cams, &truth, &[[0.3, 0.0], [0.0, -0.3], [-0.3, 0.3]]);
        let heavy = moved(&cams, model, &views);
        let gaussian = moved_with(
            &DeviationSettings {
                prior_dof: 0.0,
                ..DeviationSettings::default()
            },
            &cams,
            model,
            &views,
        )
        .0;
        let (heavy, gaussian) = ((heavy - truth).norm(), (gaussian - truth).norm());
        assert!(heavy < 0.01, "{heavy} m off");
        assert!(
            gaussian > 3.0 * heavy,
            "the Gaussian prior {gaussian} m off"
        );
        // Two cameras of three agreeing are no licence: the third might be the one
        // that is right, so the prior stays Gaussian.
        let two = moved(&cams[..2], model, &views[..2]);
        let gaussian_two = moved_with(
            &DeviationSettings {
                prior_dof: 0.0,
                ..DeviationSettings::default()
            },
            &cams[..2],
            model,
            &views[..2],
        )
        .0;
        // In a rig of two (or of three, one silent), both agreeing lets go too.
        assert!((two - truth).norm() < 0.5 * (gaussian_two - truth).norm());
        assert!((moved(&cams, model, &views[..2]) - two).norm() < 1e-9);
        let mut third_missing = views.clone();
        third_missing[2].peaks[0][2] = 0.0;
        let held = moved(&cams, model, &third_missing);
        assert!(
            (held - truth).norm() > 2.0 * (two - truth).norm(),
            "two of three views: {} m off",
            (held - truth).norm()
        );
        let gaussian_held = moved_with(
            &DeviationSettings {
                prior_dof: 0.0,
                ..DeviationSettings::default()
            },
            &cams,
            model,
            &third_missing,
        )
        .0;
        assert!(
            (held - gaussian_held).norm() < 1e-9,
            "two of three: the Gaussian prior"
        );
    }

    #[test]
    fn the_variance_grows_where_views_disagree_and_is_nan_where_none_sees() {
        let cams = ring(3, 5.0);
        let truth = Vector3::new(0.0, 0.2, 1.0);
        // The disagreement alone (not the move off the model).
        let settings = DeviationSettings {
            move_variance: 0.0,
            ..DeviationSettings::default()
        };
        let agree = seen(&cams, &truth, &[[0.2, 0.0], [0.0, 0.2], [-0.2, 0.0]]);
        let (_, calm) = moved_with(&settings, &cams, truth, &agree);
        // Peaks 3 cells (12 px) apart: not outliers, not agreeing either.
        let split = seen(&cams, &truth, &[[12.0, 0.0], [-12.0, 0.0], [0.0, 12.0]]);
        let (_, restless) = moved_with(&settings, &cams, truth, &split);
        assert!(calm > 0.0 && calm.sqrt() < 0.02, "{} m", calm.sqrt());
        assert!(restless > 2.0 * calm, "{restless} against {calm}");
        let (_, unseen) = moved_with(&settings, &cams, truth, &[]);
        assert!(unseen.is_nan());
    }

    #[test]
    fn the_views_place_a_body_that_moved_fast() {
        let cams = ring(3, 5.0);
        // Four joints seen by every camera, the model 0.25 m behind.
        let truth = [
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(0.2, 0.0, 0.9),
            Vector3::new(-0.2, 0.1, 0.5),
            Vector3::new(0.0, 0.1, 1.5),
        ];
        let behind = Vector3::new(-0.25, 0.05, 0.0);
        let model: Vec<f64> = truth
            .iter()
            .flat_map(|t| (t + behind).iter().copied().collect::<Vec<_>>())
            .collect();
        let views: Vec<ViewData> = cams
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let mut vd = view(c, [0.0; 2]);
                vd.peaks = truth
                    .iter()
                    .map(|t| {
                        let ([u, v], _) = cam.project(t).expect("in front");
                        [u, v, 1.0]
                    })
                    .collect();
                vd
            })
            .collect();
        let settings = DeviationSettings::default();
        let mut b = DeviationBuffers::default();
        let shift = views_offset(&settings, &cams, &views, &model, &mut b).expect("placed");
        assert!((shift + behind).norm() < 1e-6, "{shift:?}");
        // One joint of four triangulated is too little to move the body by.
        let mut few = views.clone();
        for vd in &mut few {
            for peak in &mut vd.peaks[1..] {
                peak[2] = 0.0;
            }
        }
        assert!(views_offset(&settings, &cams, &few, &model, &mut b).is_none());
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
