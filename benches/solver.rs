//! Criterion benchmarks of the estimator on the parity fixtures (one core):
//! given 2D per frame (init + BCD), heat-map EM per frame, the E-step alone, and the ADMM
//! initialisation alone. Run: `cargo bench --bench solver`.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::npy::{self, Array};
use posestream::solver::Observations;
use posestream::solver::em::{self, EmWorkspace, PreparedMaps};
use posestream::solver::init::convex;
use posestream::solver::normalise::heatmap_scale;
use posestream::{Dictionary, Estimator, HeatMaps, Keypoints, Params};

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference")
}

fn bench(c: &mut Criterion) {
    let dict =
        Dictionary::load(shared().join("monocap-dicts/poseDict-all-K128.mat")).expect("dictionary");
    let dir = shared().join("parity/synthetic-s0");
    let kp: Array<f64> = npy::read(&dir.join("keypoints.npy")).expect("keypoints");
    let hm: Array<f32> = npy::read(&dir.join("heatmaps.npy")).expect("heatmaps");
    let maps =
        HeatMaps::new(hm.shape[0], hm.shape[1], hm.shape[2], hm.shape[3], hm.data).expect("maps");
    let est = Estimator::new(dict.clone(), Params::default()).expect("estimator");
    let keypoints = Keypoints {
        joints: 17,
        xy: kp.data.clone(),
        confidence: None,
    };

    let mut g = c.benchmark_group("synthetic-s0 (60 frames)");
    g.sample_size(10);
    g.bench_function("given 2D: init + BCD, whole sequence", |b| {
        b.iter(|| black_box(est.lift_keypoints(&keypoints).expect("lift")))
    });
    g.bench_function("heat maps: init + EM, whole sequence", |b| {
        b.iter(|| black_box(est.lift_heatmaps(&maps).expect("lift")))
    });
    // E-step alone: all 60 x 17 maps once, at a fitted state.
    let fitted = est.lift_heatmaps(&maps).expect("lift");
    let prepared = PreparedMaps::new(&maps);
    let mut obs = Observations::new(17, vec![0.0; 2 * 17 * maps.frames]);
    let mut ws = EmWorkspace::default();
    let scale = heatmap_scale(maps.height);
    g.bench_function("E-step, whole sequence", |b| {
        b.iter(|| {
            em::e_step(
                &dict,
                &prepared,
                &fitted.fits,
                scale,
                0.5,
                &mut obs,
                None,
                &mut ws,
            )
        })
    });
    g.finish();
    // ADMM alone on one frame of keypoints (normalised as the estimator does).
    let factor = &est.init_cache().all_visible;
    let w: Vec<f64> = kp.data[..34].iter().map(|v| v / 0.9).collect();
    c.bench_function("ADMM (robust convex relaxation), one frame", |b| {
        b.iter(|| black_box(convex::admm(factor, &w, 17, 0.5, 1.0, 1000)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
