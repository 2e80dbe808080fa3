//! Properties of the solver that must hold whatever the data.

mod common;

use common::{fixture, k128, read, small_dictionary, three_basis_sequence};
use nalgebra::{Rotation3, Vector3};
use posestream::LoadDictionary;
use posestream::solver::bcd::{self, BcdWorkspace};
use posestream::solver::coefficients::{
    CoefficientProblem, CoefficientSolver, CoefficientWorkspace, basis_gram_max, lipschitz_bound,
};
use posestream::solver::normalise::keypoint_scale;
use posestream::solver::{Anchors, FrameFit, Observations};
use posestream::{Dictionary, Estimator, InitMethod, Keypoints, Params};

#[test]
fn recovers_a_three_basis_pose_exactly_from_noise_free_2d() {
    // 8 bases: 2D joints of 17 joints determine pose and rotation (with all 128 they do
    // not, and only the sparsity prior picks a pose).
    let dict = small_dictionary(8);
    let p = dict.num_joints();
    let (xy, truth) = three_basis_sequence(&dict, 3);
    // The convex initialisations; alternation is a local method and may land on the
    // depth-flipped pose.
    for init in [InitMethod::ConvexRobustRefine, InitMethod::ConvexRefine] {
        let params = Params {
            alpha: 1e-6,
            init: Some(init),
            tolerance: 1e-10,
            cd_objective_tolerance: 0.0,
            max_apg_steps: 2000,
            max_rounds: 30,
            ..Params::default().without_smoothness()
        };
        let est = Estimator::new(dict.clone(), params).expect("estimator");
        let e = est
            .lift_keypoints(&Keypoints {
                joints: p,
                xy: xy.clone(),
                confidence: None,
            })
            .expect("lift");
        // Poses come out in normalised units: undo the keypoint scale.
        let scale = keypoint_scale(&xy, &vec![1.0; xy.len() / 2], p);
        let num: f64 = e
            .poses
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a * scale - b).powi(2))
            .sum();
        let den: f64 = truth.iter().map(|b| b * b).sum();
        let rel = (num / den).sqrt();
        println!("{init}: relative error {rel:.2e}");
        assert!(rel < 1e-3, "{init}: relative error {rel}");
    }
}

#[test]
fn the_objective_never_increases_over_rounds() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    let kp = read(fixture("synthetic-s1").join("keypoints.npy"));
    for solver in [
        CoefficientSolver::ActiveSet,
        CoefficientSolver::CoordinateDescent,
        CoefficientSolver::Apg,
    ] {
        for init in [InitMethod::Altern, InitMethod::ConvexRobustRefine] {
            let params = Params {
                init: Some(init),
                coefficient_solver: solver,
                max_rounds: 20,
                tolerance: 1e-9,
                ..Params::default()
            };
            let est = Estimator::new(dict.clone(), params).expect("estimator");
            let e = est
                .lift_keypoints(&Keypoints {
                    joints: 17,
                    xy: kp.data.clone(),
                    confidence: None,
                })
                .expect("lift");
            let obj = &e.report.objective_rounds;
            assert!(obj.len() >= 2);
            for w in obj.windows(2) {
                assert!(w[1] <= w[0] * (1.0 + 1e-12), "{solver:?} {init}: {obj:?}");
            }
        }
    }
}

/// The fits of Algorithm 1 on fixture `synthetic-s0`, and the observations (normalised
/// units) of its frames `from..from + frames`.
fn lifted_window(dict: &Dictionary, from: usize, frames: usize) -> (Vec<FrameFit>, Observations) {
    let kp = read(fixture("synthetic-s0").join("keypoints.npy"));
    let fits = Estimator::new(dict.clone(), Params::default())
        .expect("estimator")
        .lift_keypoints(&Keypoints {
            joints: 17,
            xy: kp.data.clone(),
            confidence: None,
        })
        .expect("lift")
        .fits;
    let scale = keypoint_scale(&kp.data, &vec![1.0; kp.data.len() / 2], 17);
    let obs = Observations {
        joints: 17,
        xy: kp.data[from * 34..(from + frames) * 34]
            .iter()
            .map(|v| v / scale)
            .collect(),
        weights: vec![1.0; frames * 17],
    };
    (fits, obs)
}

#[test]
fn the_c_step_solvers_reach_the_same_minimum_with_and_without_an_anchor() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    let (fits, obs) = lifted_window(&dict, 0, 12);
    // A window of 12 frames under the estimate's rotations and translations.
    let f = 12;
    let translations: Vec<_> = fits[..f].iter().map(|x| x.translation).collect();
    let mut problem = CoefficientProblem::default();
    problem.build(
        &dict,
        &obs,
        fits[..f].iter().map(|x| x.rotation),
        &translations,
    );
    let (alpha, beta) = (0.5, 20.0);
    // Unanchored, anchored before on the fit of the frame after the window (any fixed
    // neighbour will do), anchored after on it, and anchored on both sides.
    let (near, far) = (
        Some(fits[f].coefficients.as_slice()),
        Some(fits[0].coefficients.as_slice()),
    );
    for (anchor, after) in [(None, None), (near, None), (None, near), (far, near)] {
        problem.set_anchors(anchor, after);
        let lipschitz = lipschitz_bound(basis_gram_max(&dict), 1.0, beta, f + 2);
        let mut ws = CoefficientWorkspace::default();
        let mut reached = Vec::new();
        for solver in [
            CoefficientSolver::ActiveSet,
            CoefficientSolver::CoordinateDescent,
            CoefficientSolver::Apg,
        ] {
            let mut c = vec![0.0; f * dict.num_bases()];
            let info = problem.solve_with(
                solver, &mut c, alpha, beta, lipschitz, 1e-14, 0.0, 20_000, 8, &mut ws,
            );
            assert!(info.objective_after <= info.objective_before);
            reached.push(info.objective_after);
        }
        println!(
            "anchors before {}, after {}: active set, cd, apg: {reached:?}",
            anchor.is_some(),
            after.is_some()
        );
        let (active, cd, apg) = (reached[0], reached[1], reached[2]);
        // The active-set method ends at a KKT point: nothing below it, and the first-order
        // methods approach it from above.
        assert!(active <= cd.min(apg) + 1e-9 * active.abs(), "{reached:?}");
        assert!(cd - active <= 1e-5 * active.abs(), "{reached:?}");
        assert!(apg - active <= 1e-3 * active.abs(), "{reached:?}");
    }
}

#[test]
fn an_anchored_window_never_raises_its_objective_and_follows_its_anchor() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    // Frames 1..9, anchored on frame 0's fit or on a far-away one.
    let f = 8;
    let (fits, obs) = lifted_window(&dict, 1, f);
    let params = Params {
        beta: 200.0,
        gamma: 200.0,
        tolerance: 1e-9,
        max_rounds: 20,
        ..Params::default()
    };
    let gram = basis_gram_max(&dict);
    let mut far = fits[0].clone();
    far.coefficients.iter_mut().for_each(|c| *c = -*c + 1.0);
    let mut distance = Vec::new();
    for anchor in [None, Some(&fits[0]), Some(&far)] {
        let mut window = fits[1..=f].to_vec();
        let mut ws = BcdWorkspace::default();
        let info = bcd::solve_anchored(&dict, gram, &obs, &mut window, anchor, &params, &mut ws);
        for w in info.objective.windows(2) {
            assert!(w[1] <= w[0] * (1.0 + 1e-12), "{:?}", info.objective);
        }
        let end = bcd::objective_anchored(&dict, &obs, &window, anchor, &params);
        let last = info.objective.last().copied().unwrap_or(f64::NAN);
        assert!((end - last).abs() <= 1e-9 * end.abs(), "{end} {last}");
        let to_far: f64 = window[0]
            .coefficients
            .iter()
            .zip(&far.coefficients)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        distance.push(to_far.sqrt());
    }
    println!("distance of the first frame to the far anchor: {distance:?}");
    assert!(distance[2] < 0.9 * distance[0], "{distance:?}");
    assert!(distance[2] < 0.9 * distance[1], "{distance:?}");
}

#[test]
fn smoothness_lowers_the_temporal_variation_of_the_coefficients() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    let kp = read(fixture("synthetic-s0").join("keypoints.npy"));
    let variation = |params: Params| {
        let e = Estimator::new(dict.clone(), params)
            .expect("estimator")
            .lift_keypoints(&Keypoints {
                joints: 17,
                xy: kp.data.clone(),
                confidence: None,
            })
            .expect("lift");
        e.fits
            .windows(2)
            .map(|w| {
                w[0].coefficients
                    .iter()
                    .zip(&w[1].coefficients)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
            })
            .sum::<f64>()
    };
    let smooth = variation(Params::default());
    let rough = variation(Params::default().without_smoothness());
    assert!(smooth < rough, "smooth {smooth} rough {rough}");
}

#[test]
fn zero_confidence_joints_do_not_move_the_fit() {
    let dict = small_dictionary(8);
    let p = dict.num_joints();
    let (xy, _) = three_basis_sequence(&dict, 2);
    let params = Params {
        init: Some(InitMethod::Altern),
        ..Params::default()
    };
    let est = Estimator::new(dict, params).expect("estimator");
    let mut conf = vec![1.0; 2 * p];
    conf[5] = 0.0;
    conf[p + 9] = 0.0;
    let mut corrupted = xy.clone();
    corrupted[2 * 5] += 50.0;
    corrupted[2 * (p + 9) + 1] -= 80.0;
    let a = est
        .lift_keypoints(&Keypoints {
            joints: p,
            xy: xy.clone(),
            confidence: Some(conf.clone()),
        })
        .expect("lift");
    let b = est
        .lift_keypoints(&Keypoints {
            joints: p,
            xy: corrupted,
            confidence: Some(conf),
        })
        .expect("lift");
    // The keypoint scale uses only confident joints, so the two fits must coincide.
    let diff: f64 = a
        .poses
        .iter()
        .zip(&b.poses)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(diff < 1e-9, "max difference {diff}");
}

#[test]
fn a_window_part_between_two_anchors_never_raises_its_objective_and_follows_both() {
    let dict = Dictionary::load(k128()).expect("dictionary");
    // Frames 1..9 between anchors: the fits of frames 0 and 9, or far-away ones.
    let f = 8;
    let (fits, obs) = lifted_window(&dict, 1, f);
    let params = Params {
        beta: 200.0,
        gamma: 200.0,
        tolerance: 1e-9,
        max_rounds: 20,
        ..Params::default()
    };
    let gram = basis_gram_max(&dict);
    let far = |fit: &FrameFit| {
        let mut far = fit.clone();
        far.coefficients.iter_mut().for_each(|c| *c = -*c + 1.0);
        far
    };
    let (far_before, far_after) = (far(&fits[0]), far(&fits[f + 1]));
    let distance = |a: &FrameFit, b: &FrameFit| {
        let dc: f64 = a
            .coefficients
            .iter()
            .zip(&b.coefficients)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        dc.sqrt()
    };
    let mut to_far = Vec::new();
    for anchors in [
        Anchors::default(),
        Anchors {
            before: Some(&fits[0]),
            after: Some(&fits[f + 1]),
        },
        Anchors {
            before: Some(&far_before),
            after: Some(&far_after),
        },
        Anchors {
            before: None,
            after: Some(&far_after),
        },
    ] {
        let mut window = fits[1..=f].to_vec();
        let mut ws = BcdWorkspace::default();
        let info = bcd::solve_between(&dict, gram, &obs, &mut window, anchors, &params, &mut ws);
        for w in info.objective.windows(2) {
            assert!(w[1] <= w[0] * (1.0 + 1e-12), "{:?}", info.objective);
        }
        // The reported objective is the full objective, anchor terms included.
        let end = bcd::objective_between(&dict, &obs, &window, anchors, &params);
        let last = info.objective.last().copied().unwrap_or(f64::NAN);
        assert!((end - last).abs() <= 1e-9 * end.abs(), "{end} {last}");
        to_far.push((
            distance(&window[0], &far_before),
            distance(&window[f - 1], &far_after),
        ));
    }
    println!("distances of the first and last frames to the far anchors: {to_far:?}");
    let (free, near, both_far, after_far) = (to_far[0], to_far[1], to_far[2], to_far[3]);
    // Far anchors pull both ends towards them; one after pulls only the last frame's
    // end more than no anchor does.
    assert!(both_far.0 < 0.9 * free.0.min(near.0), "{to_far:?}");
    assert!(both_far.1 < 0.9 * free.1.min(near.1), "{to_far:?}");
    assert!(after_far.1 < 0.9 * free.1, "{to_far:?}");
}

/// A person outside the dictionary's span (a pose of three bases plus an offset no
/// combination of the bases makes), turning in front of an orthographic camera: the
/// paper's model stays off by the offset, the adapted model finds it.
#[test]
fn adaptation_fits_a_person_outside_the_dictionary_s_span() {
    let dict = small_dictionary(8);
    let p = dict.num_joints();
    let mut c = vec![0.0; dict.num_bases()];
    c[1] = 0.9;
    c[4] = 0.5;
    c[6] = 0.7;
    let mut s = dict.compose(&c);
    let size = (s.iter().map(|v| v * v).sum::<f64>() / s.len() as f64).sqrt();
    // Pelvis down, head-top forward, a wrist out: then centred over the joints.
    let mut offset = vec![0.0; 3 * p];
    offset[p] = 0.3 * size;
    offset[2 * p + 10] = 0.4 * size;
    offset[16] = -0.3 * size;
    for row in offset.chunks_exact_mut(p) {
        let m = row.iter().sum::<f64>() / p as f64;
        row.iter_mut().for_each(|v| *v -= m);
    }
    s.iter_mut().zip(&offset).for_each(|(s, d)| *s += d);
    let frames = 60;
    let (mut xy, mut truth) = (Vec::new(), Vec::new());
    for t in 0..frames {
        let r = Rotation3::from_euler_angles(0.2, 0.5 + 0.04 * t as f64, -0.1);
        for j in 0..p {
            let q = r * Vector3::new(s[j], s[p + j], s[2 * p + j]);
            xy.extend([q.x + 3.0, q.y - 1.0]);
            truth.extend([q.x, q.y, q.z]);
        }
    }
    let kp = Keypoints {
        joints: p,
        xy,
        confidence: None,
    };
    let error = |params: Params| {
        let est = Estimator::new(dict.clone(), params).expect("estimator");
        let e = est.lift_keypoints(&kp).expect("lift");
        (
            posestream::accuracy::p_mpjpe(&e.poses, &truth, p) / size,
            e.offset,
        )
    };
    // Next to no sparsity: the three bases' pose is in reach exactly.
    let exact = Params {
        alpha: 1e-6,
        tolerance: 1e-8,
        max_rounds: 30,
        ..Params::default()
    };
    let (paper, none) = error(Params {
        adaptation: Params::reference().adaptation,
        ..exact.clone()
    });
    let (adapted, _) = error(exact.clone());
    // A weak prior and more passes: the offset itself.
    let mut weak = exact;
    weak.adaptation.prior_frames = 1.0;
    weak.adaptation.passes = 30;
    let (fitted, found) = error(weak);
    println!("relative P-MPJPE: paper {paper:.4}, adapted {adapted:.4}, weak prior {fitted:.4}");
    assert!(
        none.iter().all(|&v| v == 0.0),
        "the paper's model has no offset"
    );
    assert!(paper > 0.05, "the offset is outside the span: {paper}");
    assert!(adapted < 0.9 * paper, "paper {paper}, adapted {adapted}");
    assert!(fitted < 0.4 * paper, "paper {paper}, weak prior {fitted}");
    // The offset found is the one put in (up to the scale of the normalised units).
    let dot: f64 = found.iter().zip(&offset).map(|(a, b)| a * b).sum();
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let cos = dot / (norm(&found) * norm(&offset));
    assert!(
        cos > 0.8,
        "cosine between the offset found and the truth: {cos}"
    );
}
