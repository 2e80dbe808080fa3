//! The fused update: one person's new frame seen by four cameras (a room of
//! `posestream scenes --rooms`: a held-out walk, cameras 6 m around it, the heat maps'
//! error model) through the multi-view window (`config/default.toml`'s
//! `[estimator.fusion]`, the shipped dictionary). Criterion reports the mean over
//! frames, so the whole window's EM every `window_every` frames is in it. The same with
//! two cameras for comparison, the same without the deviations from the dictionary's
//! shape (`[estimator.fusion.deviation] joint_std = 0`), and the triangulation baseline
//! (`fusion::Triangulator`) on the same frames.

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::Estimator;
use posestream::fusion::matching::peaks_into;
use posestream::fusion::{
    FusedEstimate, FusedWindow, TriangulationSettings, Triangulator, ViewMaps,
};
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
        for deviation in [true, false] {
            let mut fusion = config.estimator.fusion.clone();
            if !deviation {
                fusion.deviation.joint_std = 0.0;
            }
            let mut window =
                FusedWindow::new(&estimator, room.view_cameras(), fusion).expect("window");
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
            let name = if deviation { "" } else { ", no deviations" };
            c.bench_function(
                &format!("fused update, {cameras} cameras (one person-frame){name}"),
                |b| b.iter(|| push(&mut window, &mut out)),
            );
        }
        // The baseline: each view's peaks, then the triangulation and its median.
        let cams = room.view_cameras();
        let mut baseline =
            Triangulator::new(mapping.layout.len(), TriangulationSettings::default());
        let mut peaks: Vec<Vec<[f64; 3]>> = vec![Vec::new(); cams.len()];
        let mut joints = Vec::new();
        let mut t = 0usize;
        c.bench_function(
            &format!("triangulation baseline, {cameras} cameras (one person-frame)"),
            |b| {
                b.iter(|| {
                    let frame = t % room.frames();
                    t += 1;
                    for p in &mut peaks {
                        p.clear();
                    }
                    for view in views(&room, frame) {
                        let Scores::F32(values) = view.values else {
                            continue;
                        };
                        let to_image = &view.to_image;
                        peaks_into(
                            values,
                            view.height,
                            view.width,
                            to_image,
                            &mut peaks[view.view],
                        );
                    }
                    let seen: Vec<_> = cams
                        .iter()
                        .zip(&peaks)
                        .map(|(c, p)| (c, p.as_slice()))
                        .collect();
                    baseline.push(&seen, &mut joints)
                })
            },
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
