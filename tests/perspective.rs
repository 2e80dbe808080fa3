//! The perspective adjustment: metric poses under a pinhole camera.

mod common;

use common::{fixture, k128, read, small_dictionary, three_basis_sequence};
use nalgebra::Vector3;
use posestream::LoadDictionary;
use posestream::accuracy::root_aligned_mpjpe;
use posestream::solver::perspective::PerspectiveParams;
use posestream::{
    Dictionary, Estimate, Estimator, Intrinsics, Keypoints, MetricEstimate, Params, PixelMap,
    Skeleton,
};

const LIMB: f64 = 0.25;

fn camera() -> Intrinsics {
    Intrinsics::new(1000.0, 1000.0, 640.0, 360.0).expect("camera")
}

/// Mean bone length of a pose given as `[x, y, z]` per joint.
fn mean_limb(skeleton: &Skeleton, pose: &[f64]) -> f64 {
    let bones: Vec<(usize, usize)> = skeleton.bones().collect();
    bones
        .iter()
        .map(|&(a, b)| {
            (0..3)
                .map(|i| (pose[3 * a + i] - pose[3 * b + i]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum::<f64>()
        / bones.len() as f64
}

/// Each frame of `poses` (`[x, y, z]` per joint, any units) scaled to mean limb `LIMB` and
/// moved by `offset` (metres); with their perspective images.
fn place(skeleton: &Skeleton, poses: &[f64], offset: Vector3<f64>) -> (Vec<f64>, Vec<f64>) {
    let p = skeleton.len();
    let cam = camera();
    let (mut metric, mut uv) = (Vec::new(), Vec::new());
    for pose in poses.chunks_exact(3 * p) {
        let s = LIMB / mean_limb(skeleton, pose);
        let mean: Vector3<f64> = pose
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .sum::<Vector3<f64>>()
            / p as f64;
        for c in pose.chunks_exact(3) {
            let q = (Vector3::new(c[0], c[1], c[2]) - mean) * s + offset;
            metric.extend([q.x, q.y, q.z]);
            uv.extend(cam.project(&q));
        }
    }
    (metric, uv)
}

/// The weak-perspective poses of an estimate scaled to mean limb `LIMB`, frame by frame.
fn weak_metric(skeleton: &Skeleton, poses: &[f64]) -> Vec<f64> {
    let p = skeleton.len();
    poses
        .chunks_exact(3 * p)
        .flat_map(|pose| {
            let s = LIMB / mean_limb(skeleton, pose);
            pose.iter().map(move |v| v * s).collect::<Vec<_>>()
        })
        .collect()
}

/// Lifts `uv` (image pixels) with `est`, then adjusts the estimate to perspective.
/// Where the close scenes stand before the camera, metres.
const CLOSE: Vector3<f64> = Vector3::new(-0.3, 0.1, 2.5);

/// The s0 fixture's poses (its first `frames`; all: `None`) at [`CLOSE`] before a
/// pinhole camera, with an estimator of the full K128 dictionary and default settings:
/// (estimator, skeleton, true poses, keypoints).
fn close_scene(frames: Option<usize>) -> (Estimator, Skeleton, Vec<f64>, Vec<f64>) {
    let dict = Dictionary::load(k128()).expect("dictionary");
    let skel = dict.skeleton().clone();
    let gt = read(fixture("synthetic-s0").join("gt_3d.npy"));
    let n = frames.map_or(gt.data.len(), |f| f * 3 * dict.num_joints());
    let (truth, uv) = place(&skel, &gt.data[..n], CLOSE);
    let est = Estimator::new(dict, Params::default()).expect("estimator");
    (est, skel, truth, uv)
}

fn lift_and_adjust(
    est: &Estimator,
    uv: Vec<f64>,
    confidence: Option<Vec<f64>>,
    params: &PerspectiveParams,
) -> (Estimate, MetricEstimate) {
    let weak = est
        .lift_keypoints(&Keypoints {
            joints: est.dictionary().num_joints(),
            xy: uv,
            confidence,
        })
        .expect("lift");
    let adjusted = est
        .adjust_perspective(&weak, &camera(), &[PixelMap::IDENTITY], params)
        .expect("adjust");
    (weak, adjusted)
}

#[test]
fn recovers_a_three_basis_pose_seen_close_up_in_perspective() {
    // The first 8 bases of K128, a pose of 3 of them 1.8 m in front of the camera and off
    // its axis: the body's depth range changes its image scale by about +-10 %.
    let dict = small_dictionary(8);
    let skel = dict.skeleton().clone();
    let p = dict.num_joints();
    let (_, poses) = three_basis_sequence(&dict, 3);
    let (truth, uv) = place(&skel, &poses, Vector3::new(0.4, -0.2, 1.8));
    // The paper's model: the pose is in the dictionary's span, and the shape offset
    // of the adapted model would take in part of the perspective distortion the
    // adjustment is there to undo (three frames, one view).
    let params = Params {
        alpha: 1e-6,
        tolerance: 1e-10,
        max_rounds: 30,
        ..Params::reference().without_smoothness()
    };
    let est = Estimator::new(dict, params).expect("estimator");
    let (weak, adjusted) = lift_and_adjust(
        &est,
        uv,
        None,
        &PerspectiveParams {
            alpha: 1e-6,
            tolerance: 1e-14,
            max_iterations: 5000,
            apg_steps: 20,
            ..PerspectiveParams::default()
        },
    );
    let weak_error = root_aligned_mpjpe(&weak_metric(&skel, &weak.poses), &truth, p, skel.root());
    let error = root_aligned_mpjpe(&adjusted.poses, &truth, p, skel.root());
    let absolute = posestream::accuracy::mpjpe(&adjusted.poses, &truth);
    let reprojection =
        posestream::accuracy::mean_error_2d(&adjusted.projected, &adjusted.keypoints);
    eprintln!(
        "weak {weak_error:.5} m, perspective {error:.6} m root-aligned, {absolute:.6} m absolute, \
         reprojection {reprojection:.5} px, iterations {:?}",
        adjusted
            .fits
            .iter()
            .map(|f| f.iterations)
            .collect::<Vec<_>>()
    );
    assert!(
        weak_error > 0.01,
        "the weak fit should be visibly off: {weak_error}"
    );
    assert!(error < 1e-3, "root-aligned error {error} m");
    assert!(absolute < 2e-3, "absolute error {absolute} m");
    assert!(reprojection < 0.05, "reprojection {reprojection} px");
}

#[test]
fn perspective_beats_weak_perspective_on_a_close_sequence() {
    // The s0 fixture's poses at 2.5 m, seen by a pinhole camera; the full K128 dictionary
    // and default settings.
    let (est, skel, truth, uv) = close_scene(None);
    let p = est.dictionary().num_joints();
    let offset = CLOSE;
    let (weak, adjusted) = lift_and_adjust(&est, uv, None, &PerspectiveParams::default());
    let weak_error = root_aligned_mpjpe(&weak_metric(&skel, &weak.poses), &truth, p, skel.root());
    let error = root_aligned_mpjpe(&adjusted.poses, &truth, p, skel.root());
    let depth_error = adjusted
        .fits
        .iter()
        .map(|f| (f.translation.z - offset.z).abs() / offset.z)
        .fold(0.0, f64::max);
    let iterations: usize = adjusted.fits.iter().map(|f| f.iterations).sum();
    eprintln!(
        "weak {weak_error:.4} m, perspective {error:.4} m, worst depth error {:.2} %, \
         {:.1} iterations/frame, {:.3} ms/frame",
        100.0 * depth_error,
        iterations as f64 / adjusted.fits.len() as f64,
        1e3 * adjusted.seconds / adjusted.fits.len() as f64
    );
    assert!(
        error < 0.8 * weak_error,
        "perspective {error} m against weak {weak_error} m"
    );
    assert!(depth_error < 0.03, "depth off by {} %", 100.0 * depth_error);
    assert!(adjusted.poses.iter().all(|v| v.is_finite()));
}

#[test]
fn unobserved_joints_follow_the_model() {
    // As above, 10 frames, with two joints (a wrist and an ankle) not observed.
    let (est, skel, truth, uv) = close_scene(Some(10));
    let p = est.dictionary().num_joints();
    let mut confidence = vec![1.0; 10 * p];
    for t in 0..10 {
        confidence[t * p + 3] = 0.0;
        confidence[t * p + p - 1] = 0.0;
    }
    let (weak, adjusted) =
        lift_and_adjust(&est, uv, Some(confidence), &PerspectiveParams::default());
    assert!(adjusted.poses.iter().all(|v| v.is_finite()));
    let weak_error = root_aligned_mpjpe(&weak_metric(&skel, &weak.poses), &truth, p, skel.root());
    let error = root_aligned_mpjpe(&adjusted.poses, &truth, p, skel.root());
    eprintln!("two joints unobserved: weak {weak_error:.4} m, perspective {error:.4} m");
    assert!(
        error < weak_error,
        "perspective {error} m against weak {weak_error} m"
    );
}

#[test]
fn bad_settings_and_box_counts_are_errors() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    let p = dict.num_joints();
    let gt = read(fixture("synthetic-s0").join("keypoints.npy"));
    let est = Estimator::new(dict, Params::default()).expect("estimator");
    let weak = est
        .lift_keypoints(&Keypoints {
            joints: p,
            xy: gt.data[..2 * p * 3].to_vec(),
            confidence: None,
        })
        .expect("lift");
    let two = [PixelMap::IDENTITY; 2];
    assert!(
        est.adjust_perspective(&weak, &camera(), &two, &PerspectiveParams::default())
            .is_err()
    );
    for bad in [
        PerspectiveParams {
            mean_limb_length: 0.0,
            ..PerspectiveParams::default()
        },
        PerspectiveParams {
            alpha: f64::NAN,
            ..PerspectiveParams::default()
        },
    ] {
        assert!(
            est.adjust_perspective(&weak, &camera(), &[PixelMap::IDENTITY], &bad)
                .is_err()
        );
    }
}

/// The streaming metric step's setting: the C-step's momentum carried across the
/// iterations gets further in 35 iterations than restarting it each iteration does
/// (lower ray distance on most frames, and on average), without losing the pose.
#[test]
fn momentum_across_iterations_gets_further_in_the_same_iterations() {
    let (est, skel, truth, uv) = close_scene(None);
    let p = est.dictionary().num_joints();
    let run = |momentum: bool| {
        let params = PerspectiveParams {
            max_iterations: 35,
            momentum,
            ..PerspectiveParams::default()
        };
        lift_and_adjust(&est, uv.clone(), None, &params).1
    };
    let (plain, carried) = (run(false), run(true));
    let distance = |m: &MetricEstimate| {
        m.fits.iter().map(|f| f.ray_distance).sum::<f64>() / m.fits.len() as f64
    };
    let further = plain
        .fits
        .iter()
        .zip(&carried.fits)
        .filter(|(a, b)| b.ray_distance < a.ray_distance)
        .count();
    let error = |m: &MetricEstimate| root_aligned_mpjpe(&m.poses, &truth, p, skel.root());
    eprintln!(
        "ray distance {:.5} -> {:.5} m ({further} of {} frames further), root-aligned {:.4} -> {:.4} m",
        distance(&plain),
        distance(&carried),
        plain.fits.len(),
        error(&plain),
        error(&carried)
    );
    assert!(distance(&carried) < distance(&plain));
    assert!(2 * further > plain.fits.len());
    assert!(error(&carried) < 1.1 * error(&plain));
}

/// A keypoint that is not a number makes the ray distance NaN: the adjustment stops at
/// once (its result is refused by the caller) instead of running every iteration.
#[test]
fn a_nan_keypoint_ends_the_adjustment_at_once() {
    let (est, _, _, uv) = close_scene(None);
    let p = est.dictionary().num_joints();
    let (_, adjusted) = lift_and_adjust(&est, uv.clone(), None, &PerspectiveParams::default());
    let mut fit = adjusted.fits[0].clone();
    let mut frame = uv[..2 * p].to_vec();
    frame[3] = f64::NAN;
    let params = PerspectiveParams {
        momentum: true,
        ..PerspectiveParams::default()
    };
    posestream::solver::perspective::adjust_frame(
        est.dictionary(),
        est.basis_gram_max(),
        &camera(),
        &frame,
        &vec![1.0; p],
        &mut fit,
        &params,
        &mut posestream::solver::perspective::PerspectiveWorkspace::default(),
    );
    assert!(fit.iterations <= 1, "{} iterations", fit.iterations);
    assert!(fit.ray_distance.is_nan());
}
