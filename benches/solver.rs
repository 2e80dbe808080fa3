//! Criterion benchmarks of the estimator on the parity fixture `synthetic-s0` (60 frames,
//! K128 dictionary, one core). Every figure is **per frame**: a whole-sequence run timed
//! and divided by the number of frames (`iter_custom`), so init, the window solve and
//! the E-steps are all included where they belong.
//!
//! - given 2D per frame: initialisation (convex+robust+refine) + Algorithm 1;
//! - heat-map EM per frame: initialisation (altern) + Algorithm 2;
//! - E-step per frame: the 17 joints of a frame, at a fitted state;
//! - ADMM per frame: the robust convex relaxation of one frame, cold and warm-started
//!   from the previous frame (as the estimator runs it);
//! - perspective adjustment per frame, of the heat-map estimate (default settings).
//!
//! Run: `cargo bench --bench solver`.

use posestream::LoadDictionary;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::npy::{self, Array};
use posestream::solver::Observations;
use posestream::solver::em::{self, EmWorkspace, PreparedMaps};
use posestream::solver::init::convex::{self, AdmmState};
use posestream::solver::normalise::{heatmap_scale, keypoint_scale};
use posestream::solver::perspective::PerspectiveParams;
use posestream::{CropBox, Dictionary, Estimator, HeatMapSequence, Intrinsics, Keypoints, Params};

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference")
}

/// Times `iters` runs of `run` over `frames` frames and reports the time per frame.
fn per_frame(iters: u64, frames: usize, mut run: impl FnMut()) -> Duration {
    let start = Instant::now();
    for _ in 0..iters {
        run();
    }
    start.elapsed() / frames as u32
}

fn bench(c: &mut Criterion) {
    let dict =
        Dictionary::load(shared().join("monocap-dicts/poseDict-all-K128.mat")).expect("dictionary");
    let dir = shared().join("parity/synthetic-s0");
    let kp: Array<f64> = npy::read(&dir.join("keypoints.npy")).expect("keypoints");
    let hm: Array<f32> = npy::read(&dir.join("heatmaps.npy")).expect("heatmaps");
    let mut maps =
        HeatMapSequence::new(hm.shape[0], hm.shape[1], hm.shape[2], hm.shape[3], hm.data)
            .expect("maps");
    // As `posestream lift` reads them.
    maps.clip_negatives();
    let frames = maps.frames;
    // The paper's model: the speed-up is against the authors' release (docs/speed.md).
    let est = Estimator::new(dict.clone(), Params::reference()).expect("estimator");
    let keypoints = Keypoints {
        joints: 17,
        xy: kp.data.clone(),
        confidence: None,
    };

    let mut g = c.benchmark_group("synthetic-s0, per frame");
    g.sample_size(20);
    g.bench_function("given 2D: init + BCD", |b| {
        b.iter_custom(|iters| {
            per_frame(iters, frames, || {
                black_box(est.lift_keypoints(&keypoints).expect("lift"));
            })
        })
    });
    g.bench_function("heat maps: init + EM", |b| {
        b.iter_custom(|iters| {
            per_frame(iters, frames, || {
                black_box(est.lift_heatmaps(&maps).expect("lift"));
            })
        })
    });
    // E-step alone at a fitted state.
    let fitted = est.lift_heatmaps(&maps).expect("lift");
    let prepared = PreparedMaps::new(&maps);
    let mut obs = Observations::new(17, vec![0.0; 2 * 17 * frames]);
    let mut ws = EmWorkspace::default();
    let scale = heatmap_scale(maps.height);
    // The paper's E-step, and posestream's (the joints' weights and the swap model).
    for (name, params) in [
        ("E-step (17 joints)", Params::reference()),
        ("E-step, posestream's model (17 joints)", Params::default()),
    ] {
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                per_frame(iters, frames, || {
                    em::e_step(
                        &dict,
                        &prepared,
                        &fitted.fits,
                        scale,
                        &params,
                        &mut obs,
                        None,
                        &mut ws,
                    )
                })
            })
        });
    }
    // ADMM alone, on the keypoints normalised as the estimator does.
    let factor = &est.init_cache().all_visible;
    let kscale = keypoint_scale(&kp.data, &vec![1.0; 17 * frames], 17);
    let w: Vec<f64> = kp.data.iter().map(|v| v / kscale).collect();
    let mut state = AdmmState::default();
    g.bench_function("ADMM (robust), cold start", |b| {
        b.iter_custom(|iters| {
            per_frame(iters, frames, || {
                for t in 0..frames {
                    state.reset();
                    let wt = &w[34 * t..34 * (t + 1)];
                    black_box(convex::admm(factor, wt, 17, 0.5, 1.0, 1000, &mut state));
                }
            })
        })
    });
    g.bench_function("ADMM (robust), warm start", |b| {
        b.iter_custom(|iters| {
            per_frame(iters, frames, || {
                state.reset();
                for t in 0..frames {
                    let wt = &w[34 * t..34 * (t + 1)];
                    black_box(convex::admm(factor, wt, 17, 0.5, 1.0, 1000, &mut state));
                }
            })
        })
    });
    // The perspective adjustment of the fitted heat-map estimate, the maps taken as
    // 256-pixel crops seen by a 1000-pixel focal length.
    let camera = Intrinsics::new(1000.0, 1000.0, 640.0, 360.0).expect("camera");
    let to_image = [CropBox::new(300.0, 100.0, 256.0, 256.0)
        .expect("box")
        .pixel_map(maps.width, maps.height)];
    let perspective = PerspectiveParams::default();
    g.bench_function("perspective adjustment", |b| {
        b.iter_custom(|iters| {
            per_frame(iters, frames, || {
                black_box(
                    est.adjust_perspective(&fitted, &camera, &to_image, &perspective)
                        .expect("adjust"),
                );
            })
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
