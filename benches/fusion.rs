//! The fused update: one person's new frame seen by four cameras (a room of
//! `posestream scenes --rooms`: a held-out walk, cameras 6 m around it, the heat maps'
//! error model) through the multi-view window (`config/default.toml`'s
//! `[estimator.fusion]`, the shipped dictionary). Criterion reports the mean over
//! frames, so the whole window's EM every `window_every` frames is in it. The same with
//! two cameras for comparison.

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::Estimator;
use posestream::fusion::{FusedEstimate, FusedWindow, ViewMaps};
use posestream::mocap::{Bvh, SkeletonMapping};
use posestream::nodes::ServiceConfig;
use posestream::streaming::Scores;
use posestream::synth::ErrorModel;
use posestream::synth::room::{self, Room, RoomCamera};

fn bench(c: &mut Criterion) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = ServiceConfig::load(root.join("config/default.toml")).expect("config");
    let mapping =
        SkeletonMapping::load(root.join("config/skeletons/bandai-namco.toml")).expect("mapping");
    let take = root.join("../shared/data/mocap/bandai-namco-1/dataset-1_walk-left_proud_001.bvh");
    let seq = mapping
        .apply(&Bvh::load(&take).expect("take"), "walk")
        .expect("mapped")
        .frames_from(0, 150)
        .expect("frames");
    let dict = posestream::msgs::shipped::load_dictionary(&config.estimator.dictionary)
        .expect("dictionary");
    let estimator = Estimator::new(dict, config.estimator.params.clone()).expect("estimator");
    for cameras in [4, 2] {
        let rig: Vec<RoomCamera> = (0..cameras)
            .map(|i| RoomCamera::at(45.0 + 360.0 * i as f64 / cameras as f64, 6.0))
            .collect();
        let room = room::render(
            std::slice::from_ref(&seq),
            &mapping.layout,
            &rig,
            &ErrorModel::default(),
            1.2,
            0.2,
        )
        .expect("room");
        let mut window = FusedWindow::new(
            &estimator,
            room.view_cameras(),
            config.estimator.fusion.clone(),
        )
        .expect("window");
        let mut out: Vec<FusedEstimate> = Vec::new();
        let mut t = 0usize;
        let mut push = |window: &mut FusedWindow, out: &mut Vec<FusedEstimate>| {
            let frame = t % room.frames();
            // Wrap-around jumps the pose: a new track there, as a real stream would.
            if frame == 0 {
                window.reset();
            }
            out.clear();
            window
                .push(room.frame_ns(t), &views(&room, frame), out)
                .expect("frame");
            t += 1;
        };
        for _ in 0..40 {
            push(&mut window, &mut out);
        }
        c.bench_function(
            &format!("fused update, {cameras} cameras (one person-frame)"),
            |b| b.iter(|| push(&mut window, &mut out)),
        );
    }
}

/// The views of person 0 in frame `t`.
fn views(room: &Room, t: usize) -> Vec<ViewMaps<'_>> {
    room.seen
        .iter()
        .enumerate()
        .filter_map(|(c, seen)| {
            let s = &seen[0];
            let dt = s.dt[t]?;
            let maps = &s.maps.maps;
            let n = maps.joints * maps.height * maps.width;
            Some(ViewMaps {
                view: c,
                dt,
                to_image: s.boxes[t].pixel_map(maps.width, maps.height),
                height: maps.height,
                width: maps.width,
                values: Scores::F32(&maps.values[t * n..(t + 1) * n]),
            })
        })
        .collect()
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench
}
criterion_main!(benches);
