//! Scratch probe: parity numbers on the fixtures.
use posestream::npy::{read, Array};
use posestream::*;
use std::path::Path;

fn main() {
    let root = Path::new("../shared/reference/parity");
    let dict = Dictionary::load("../shared/reference/monocap-dicts/poseDict-all-K128.mat").expect("dict");
    let args: Vec<String> = std::env::args().collect();
    let init: Option<InitMethod> = args.get(1).filter(|s| *s != "auto").map(|s| s.parse().expect("init"));
    let solver = args.get(2).map(|s| s.parse().expect("solver")).unwrap_or_default();
    for fixture in ["synthetic-s0", "synthetic-s1"] {
        let dir = root.join(fixture);
        let gt: Array<f64> = read(&dir.join("gt_3d.npy")).expect("gt");
        let gt2: Array<f64> = read(&dir.join("gt_2d_heatmap.npy")).expect("gt2");
        let kp: Array<f64> = read(&dir.join("keypoints.npy")).expect("kp");
        let hm: Array<f32> = read(&dir.join("heatmaps.npy")).expect("hm");
        let params = Params { init, coefficient_solver: solver, ..Params::default() };
        let est = Estimator::new(dict.clone(), params).expect("est");
        let e = est.lift_keypoints(&Keypoints { joints: 17, xy: kp.data.clone(), confidence: None }).expect("lift");
        println!("{fixture} given2d: p-mpjpe {:.4} rounds {:?} obj {:?} t {:.3}s init {:.3}s", metrics::p_mpjpe(&e.poses, &gt.data, 17), e.report.rounds, e.report.objective_rounds, e.report.seconds, e.report.seconds_init);
        let maps = HeatMaps::new(hm.shape[0], hm.shape[1], hm.shape[2], hm.shape[3], hm.data.clone()).expect("maps");
        let e = est.lift_heatmaps(&maps).expect("lift");
        println!("{fixture} heatmap: p-mpjpe {:.4} (refl {:.4}) 2d {:.4} proj {:.4} em {} rounds {:?} t {:.3}s init {:.3}s", metrics::p_mpjpe(&e.poses, &gt.data, 17), metrics::p_mpjpe_with_reflections(&e.poses, &gt.data, 17), metrics::mean_error_2d(&e.keypoints, &gt2.data), metrics::mean_error_2d(&e.projected, &gt2.data), e.report.em_iterations, e.report.rounds, e.report.seconds, e.report.seconds_init);
    }
}
