//! Parity with the authors' MATLAB code (run under Octave): with default settings our
//! P-MPJPE (proper rotations) is at most 1.05x the best reference mode's, and the 2D
//! error of our EM estimate at most 1.05x the reference's. The bounds are read from each
//! fixture's `reference/summary.json`.

mod common;

use common::{fixture, k128, read};
use posestream::LoadDictionary;
use posestream::npy::{self, Array};
use posestream::{Dictionary, Estimator, HeatMapSequence, Keypoints, Params, accuracy};

fn summary(name: &str) -> serde_json::Value {
    let path = fixture(name).join("reference/summary.json");
    serde_json::from_slice(&std::fs::read(&path).expect("summary.json")).expect("json")
}

/// The best (smallest) value of `key` over the reference modes that read `input`.
fn best(summary: &serde_json::Value, input: &str, key: &str) -> Option<f64> {
    summary
        .as_object()?
        .values()
        .filter(|m| m["input"] == input)
        .filter_map(|m| m[key].as_f64())
        .reduce(f64::min)
}

fn estimator() -> Estimator {
    let dict = Dictionary::load(k128()).expect("dictionary");
    Estimator::new(dict, Params::reference()).expect("estimator")
}

fn heatmaps(name: &str) -> HeatMapSequence {
    let a: Array<f32> = npy::read(&fixture(name).join("heatmaps.npy")).expect("heatmaps");
    HeatMapSequence::new(a.shape[0], a.shape[1], a.shape[2], a.shape[3], a.data)
        .expect("valid maps")
}

#[test]
fn given_2d_is_within_5_percent_of_the_reference_on_s0() {
    let name = "synthetic-s0";
    let bound = 1.05 * best(&summary(name), "keypoints.npy", "p_mpjpe").expect("reference");
    let kp = read(fixture(name).join("keypoints.npy"));
    let gt = read(fixture(name).join("gt_3d.npy"));
    let est = estimator()
        .lift_keypoints(&Keypoints {
            joints: 17,
            xy: kp.data,
            confidence: None,
        })
        .expect("lift");
    let err = accuracy::p_mpjpe(&est.poses, &gt.data, 17);
    println!("{name} given 2D: P-MPJPE {err:.4} (bound {bound:.4})");
    assert!(err <= bound, "P-MPJPE {err} > {bound}");
}

fn check_heatmaps(name: &str) {
    let s = summary(name);
    let bound3d = 1.05 * best(&s, "heatmaps.npy", "p_mpjpe").expect("reference");
    let bound2d = 1.05 * best(&s, "heatmaps.npy", "err2d_px").expect("reference");
    let gt = read(fixture(name).join("gt_3d.npy"));
    let gt2 = read(fixture(name).join("gt_2d_heatmap.npy"));
    let est = estimator().lift_heatmaps(&heatmaps(name)).expect("lift");
    let err3d = accuracy::p_mpjpe(&est.poses, &gt.data, 17);
    let err2d = accuracy::mean_error_2d(&est.keypoints, &gt2.data);
    let argmax = s["heatmap_altern"]["err2d_argmax_px"]
        .as_f64()
        .unwrap_or(f64::INFINITY);
    println!(
        "{name} heat maps: P-MPJPE {err3d:.4} (bound {bound3d:.4}), 2D {err2d:.4} px (bound {bound2d:.4})"
    );
    assert!(err3d <= bound3d, "P-MPJPE {err3d} > {bound3d}");
    assert!(err2d <= bound2d, "2D error {err2d} > {bound2d}");
    assert!(err2d < argmax, "EM must beat the arg-max start");
    let var = est.variance.expect("variance");
    assert!(var.iter().all(|v| v.is_finite() && *v > 0.0));
}

#[test]
fn heat_maps_are_within_5_percent_of_the_reference_on_s0() {
    check_heatmaps("synthetic-s0");
}

#[test]
fn heat_maps_are_within_5_percent_of_the_reference_on_s1() {
    check_heatmaps("synthetic-s1");
}
