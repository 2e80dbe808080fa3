//! A person's first frame: from the heat maps' arg-maxes, triangulated when two views or
//! more see them, else one camera's monocular start.

use nalgebra::{Matrix3, Vector3};

use super::ViewCamera;
use super::estep::{MIN_DEPTH, units_per_metre};
use super::frame::Frame;
use crate::dictionary::Dictionary;
use crate::geometry::fit_similarity;
use crate::heatmaps::argmax;
use crate::solver::init::{InitCache, InitWorkspace, initialise_frame_into};
use crate::solver::normalise::heatmap_scale;
use crate::solver::perspective::{PerspectiveParams, mean_limb_length, start_from_weak_fit};
use crate::solver::{FrameFit, InitMethod, Params};
use posestream_base::PixelMap;

/// Buffers of the start.
#[derive(Debug, Clone, Default)]
pub(super) struct StartBuffers {
    points: Vec<Vector3<f64>>,
    model: Vec<Vector3<f64>>,
    w: Vec<f64>,
    shape: Vec<f64>,
    xy: Vec<f64>,
    visible: Vec<bool>,
    init: InitWorkspace,
}

/// What a start found: the window's size (`m`, metres per unit, and `limb0`, the pose's
/// mean bone length in normalised units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Started {
    pub metres_per_unit: f64,
    pub limb0: f64,
}

/// The arg-max of every map of every view as rays (weight 1 where its peak is above
/// `threshold`), the pose placed by them: triangulated joints when two views see four
/// joints or more, each with three or more peaks, else the view with the most peaks
/// alone (the single-camera initialisation, placed by the assumed size). Then every
/// ray's weight is [`units_per_metre`] squared at the body's depth. `None` when no view
/// has three peaks.
pub(super) fn start(
    dict: &Dictionary,
    cache: &InitCache,
    params: &Params,
    cameras: &[ViewCamera],
    (mean_limb_length_m, size_range, threshold): (f64, f64, f32),
    frame: &mut Frame,
    b: &mut StartBuffers,
) -> Option<Started> {
    let p = dict.num_joints();
    for vd in frame.views_mut() {
        let cam = &cameras[vd.view];
        vd.origin = cam.centre();
        vd.dirs.resize(p, Vector3::zeros());
        vd.weights.resize(p, 0.0);
        vd.keypoints.resize(p, [0.0; 2]);
        vd.variance.resize(p, 0.0);
        vd.depth.resize(p, 0.0);
        let n = vd.height * vd.width;
        for j in 0..p {
            let (x, y, peak) = argmax(&vd.maps[j * n..(j + 1) * n], vd.width);
            let [u, v] = vd.to_image.apply(x, y);
            vd.keypoints[j] = [u, v];
            vd.dirs[j] = cam.ray(u, v);
            vd.weights[j] = if peak > threshold && vd.evidence {
                1.0
            } else {
                0.0
            };
        }
    }
    let started = match triangulated(dict, cameras, (mean_limb_length_m, size_range), frame, b) {
        Some(s) => s,
        None => monocular(dict, cache, params, cameras, mean_limb_length_m, frame, b)?,
    };
    let body = frame.pose.translation;
    for vd in frame.views_mut() {
        let cam = &cameras[vd.view];
        let z = cam.to_camera(&body).z;
        // A camera the body is not in front of sees none of it.
        let k = if z >= MIN_DEPTH {
            units_per_metre(cam, vd.to_image.mean_scale(), vd.height, z)
        } else {
            0.0
        };
        vd.weights.iter_mut().for_each(|w| *w *= k * k);
    }
    Some(started)
}

/// Triangulates each joint seen by two views or more (the point nearest their rays) and
/// fits the dictionary's average shape onto those points.
fn triangulated(
    dict: &Dictionary,
    cameras: &[ViewCamera],
    (mean_limb_length_m, size_range): (f64, f64),
    frame: &mut Frame,
    b: &mut StartBuffers,
) -> Option<Started> {
    let p = dict.num_joints();
    if frame.usable_views() < 2 {
        return None;
    }
    b.points.clear();
    b.model.clear();
    b.w.clear();
    let k = dict.num_bases();
    frame.pose.coefficients.fill(1.0 / k as f64);
    b.shape.resize(3 * p, 0.0);
    dict.compose_into(&frame.pose.coefficients, &mut b.shape);
    for j in 0..p {
        let (mut a, mut rhs, mut seen) = (Matrix3::zeros(), Vector3::zeros(), 0);
        for vd in frame.views().iter().filter(|v| v.usable()) {
            if vd.weights[j] <= 0.0 {
                continue;
            }
            let d = vd.dirs[j];
            let proj = Matrix3::identity() - d * d.transpose();
            a += proj;
            rhs += proj * vd.origin;
            seen += 1;
        }
        if seen < 2 {
            continue;
        }
        // Rays nearly parallel leave the point undetermined along them.
        let eig = a.symmetric_eigenvalues();
        if eig.min() < 1e-4 * eig.max() {
            continue;
        }
        let Some(x) = a.try_inverse().map(|inv| inv * rhs) else {
            continue;
        };
        b.points.push(x);
        b.model
            .push(Vector3::new(b.shape[j], b.shape[p + j], b.shape[2 * p + j]));
        b.w.push(1.0);
    }
    if b.points.len() < 4 {
        return None;
    }
    // The normalised units a metre spans at the body, as the single-camera EM's: the
    // pose's size in them is a weak fit's.
    let centroid = b.points.iter().sum::<Vector3<f64>>() / b.points.len() as f64;
    let (mut k_sum, mut views) = (0.0, 0);
    for vd in frame.views().iter().filter(|v| v.usable()) {
        let cam = &cameras[vd.view];
        let z = cam.to_camera(&centroid).z;
        if z > 0.0 {
            k_sum += units_per_metre(cam, vd.to_image.mean_scale(), vd.height, z);
            views += 1;
        }
    }
    if views == 0 {
        return None;
    }
    let units = k_sum / views as f64;
    let limb0 = mean_limb_length_m * units;
    let limb = mean_limb_length(dict.skeleton(), &b.shape);
    if !(limb > 0.0 && limb.is_finite()) {
        return None;
    }
    frame
        .pose
        .coefficients
        .iter_mut()
        .for_each(|v| *v *= limb0 / limb);
    let m = 1.0 / units;
    let model: Vec<Vector3<f64>> = b.model.iter().map(|s| s * (limb0 / limb) * m).collect();
    let sim = fit_similarity(&model, &b.points, Some(&b.w), false)?;
    // The size the triangulated joints show, within the window's range of the assumed.
    let scale = if sim.scale.is_finite() && sim.scale > 0.0 {
        sim.scale.clamp(1.0 / size_range, size_range)
    } else {
        1.0
    };
    frame.pose.rotation = sim.rotation;
    frame.pose.translation = sim.target_centroid - sim.rotation * sim.source_centroid * scale;
    Some(Started {
        metres_per_unit: m * scale,
        limb0,
    })
}

/// The single-camera start of the view with the most peaks: the alternating
/// initialisation on its arg-maxes, placed in front of its camera by the assumed size.
fn monocular(
    dict: &Dictionary,
    cache: &InitCache,
    params: &Params,
    cameras: &[ViewCamera],
    mean_limb_length_m: f64,
    frame: &mut Frame,
    b: &mut StartBuffers,
) -> Option<Started> {
    let p = dict.num_joints();
    let best = frame
        .views()
        .iter()
        .enumerate()
        .filter(|(_, v)| v.usable())
        .max_by_key(|(_, v)| v.weights.iter().filter(|&&w| w > 0.0).count())
        .map(|(i, _)| i)?;
    // Only the chosen view's rays stay: the others saw too little to place anything.
    for (i, vd) in frame.views_mut().iter_mut().enumerate() {
        if i != best {
            vd.weights.fill(0.0);
        }
    }
    let vd = &frame.views()[best];
    let cam = &cameras[vd.view];
    let scale = heatmap_scale(vd.height);
    let n = vd.height * vd.width;
    b.xy.clear();
    b.visible.clear();
    for j in 0..p {
        let (x, y, _) = argmax(&vd.maps[j * n..(j + 1) * n], vd.width);
        b.xy.extend([x / scale, y / scale]);
        b.visible.push(vd.weights[j] > 0.0);
    }
    let mut fit = FrameFit::zero(dict.num_bases());
    initialise_frame_into(
        dict,
        cache,
        &b.xy,
        &b.visible,
        InitMethod::Altern,
        params,
        &mut b.init,
        &mut fit,
    );
    let units_to_image = PixelMap {
        scale: vd.to_image.scale.map(|s| s * scale),
        offset: vd.to_image.offset,
    };
    let perspective = PerspectiveParams {
        mean_limb_length: mean_limb_length_m,
        ..PerspectiveParams::default()
    };
    let placed = start_from_weak_fit(dict, &fit, &units_to_image, &cam.intrinsics, &perspective)?;
    b.shape.resize(3 * p, 0.0);
    dict.compose_into(&placed.coefficients, &mut b.shape);
    let limb0 = mean_limb_length(dict.skeleton(), &b.shape);
    let pose = &mut frame.pose;
    pose.coefficients.copy_from_slice(&placed.coefficients);
    pose.rotation = cam
        .world_from_camera
        .rotation
        .to_rotation_matrix()
        .into_inner()
        * placed.rotation;
    pose.translation = cam
        .world_from_camera
        .transform_point(&placed.translation.into())
        .coords;
    Some(Started {
        metres_per_unit: placed.metres_per_unit,
        limb0,
    })
}
