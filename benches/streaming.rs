//! The streaming update: one new frame through a full window (size 30, lag 10, k = 128,
//! the shipped dictionary and `config/default.toml`), on a shipped recording. Criterion
//! reports the mean over frames, so the window's EM every `window_every` frames is in it;
//! `posestream replay` reports the median and p99 per frame. The second benchmark runs
//! the schedule before "Beyond the paper" (2 local iterations over the newest 4 frames,
//! `lag_iterations = 0`, `window_every = 10`, joints weighing 1, no swap model), so the
//! cost of the new schedule and model is measured on the same day.

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::msgs;
use posestream::nodes::ServiceConfig;
use posestream::recording::read_topic;
use posestream::streaming::{Estimates, FrameMaps, StreamSettings, WindowEstimator};
use posestream::{Estimator, Params};

fn bench(c: &mut Criterion) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = ServiceConfig::load(root.join("config/default.toml")).expect("config");
    let messages: Vec<(u64, msgs::HeatMaps)> =
        read_topic(&root.join("recordings/byebye.mcap"), "/posestream/heatmaps").expect("reads");
    let frames: Vec<Vec<f32>> = messages
        .iter()
        .map(|(_, m)| {
            let mut v = Vec::new();
            m.values_into(&mut v).expect("values");
            v
        })
        .collect();
    let dict = posestream::msgs::shipped::load_dictionary(&config.estimator.dictionary)
        .expect("dictionary");
    let estimator =
        Estimator::new(dict.clone(), config.estimator.params.clone()).expect("estimator");
    let mut window =
        WindowEstimator::new(estimator, config.estimator.window.clone()).expect("window");
    let before = Params {
        confidence_spread: 0.0,
        swap_prior: 0.0,
        ..config.estimator.params.clone()
    };
    let mut before = WindowEstimator::new(
        Estimator::new(dict, before).expect("estimator"),
        StreamSettings {
            local_frames: 4,
            local_iterations: 2,
            lag_iterations: 0,
            window_every: 10,
            ..config.estimator.window.clone()
        },
    )
    .expect("window");
    let mut out = Estimates::default();
    let mut seq = 0_u64;
    let mut push = |window: &mut WindowEstimator, out: &mut Estimates| {
        let t = (seq as usize) % frames.len();
        let frame = FrameMaps {
            sequence: seq,
            stamp_ns: seq as i64 * 33_333_333,
            height: 64,
            width: 64,
            values: (&frames[t]).into(),
        };
        // Wrap-around jumps the pose: restart the track there, as a real stream would.
        if t == 0 {
            window.reset();
        }
        out.clear();
        window.push_into(&frame, out).expect("frame");
        seq += 1;
    };
    for _ in 0..40 {
        push(&mut window, &mut out);
    }
    c.bench_function("streaming update (window 30, lag 10, k 128)", |b| {
        b.iter(|| push(&mut window, &mut out))
    });
    for _ in 0..40 {
        push(&mut before, &mut out);
    }
    c.bench_function(
        "streaming update, the schedule before the lag pass (window EM every 10)",
        |b| b.iter(|| push(&mut before, &mut out)),
    );
}

/// One fit of the learnt floor (`FloorLearner`, every 30 person-frames on the solver's
/// thread): 3600 roots of two people kept, the fit and its jackknife.
fn learnt_floor(c: &mut Criterion) {
    use nalgebra::Vector3;
    use posestream::learnt_floor::{FloorLearner, LearningSettings};
    let mut learner = FloorLearner::new(LearningSettings {
        refit_every: 1,
        ..LearningSettings::default()
    });
    let root = |t: usize| {
        let (k, t) = (t % 2, (t / 2) as f64 / 30.0);
        let ahead = 6.5 + 3.5 * (0.3 * t + k as f64).sin();
        let left = -2.0 + 2.0 * k as f64 + 0.5 * (0.2 * t).cos();
        // A level camera 2 m up: x right, y down, z forward.
        (k as u32, Vector3::new(-left, 2.0 - 0.99, ahead))
    };
    for t in 0..3600 {
        let (k, r) = root(t);
        learner.note(k, r);
    }
    let mut t = 3600;
    c.bench_function("learnt floor: a fit (3600 roots, two people)", |b| {
        b.iter(|| {
            let (k, r) = root(t);
            t += 1;
            learner.note(k, r)
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(200);
    targets = bench, learnt_floor
}
criterion_main!(benches);
