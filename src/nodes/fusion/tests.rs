//! Unit tests of `fusion`.

use super::*;
use crate::msgs::HeatMapEncoding;

const PERIOD: i64 = 33_333_333;

/// A node of cameras `a` and `b` (poses and intrinsics configured), fused frames at
/// 30 per second, waiting up to 1 s.
fn node() -> FusionNode {
    let dict = crate::msgs::shipped::load_dictionary(std::path::Path::new(
        "builtin:dictionaries/default-k128.json",
    ))
    .expect("dictionary");
    let estimator = Estimator::new(dict, crate::Params::default()).expect("estimator");
    let mut config = FusionConfig {
        cameras: vec!["a".into(), "b".into()],
        extrinsics: ExtrinsicsSource::Config,
        wait: 1.0,
        ..FusionConfig::default()
    };
    for (name, x) in [("a", 0.0), ("b", 5.0)] {
        config
            .poses
            .insert(name.into(), vec![x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        config
            .intrinsics
            .insert(name.into(), vec![600.0, 600.0, 320.0, 240.0]);
    }
    config
        .check(&super::super::config::Topics::default())
        .expect("config");
    FusionNode::new(
        estimator,
        &config,
        FusionSettings::default(),
        Limits::default(),
    )
    .expect("node")
}

/// Camera `camera`'s frame of track 1 at `stamp_ns` (maps without evidence: nothing
/// is estimated, the frames only placed).
fn frame(node: &FusionNode, camera: &str, stamp_ns: i64) -> HeatMaps {
    let p = node.joint_names().len();
    HeatMaps {
        track_id: 1,
        ..HeatMaps::from_values(
            Header {
                stamp: Time::from_nanos(stamp_ns),
                frame_id: camera.into(),
            },
            0,
            node.joint_names().to_vec(),
            4,
            4,
            CropBox::new(100.0, 100.0, 80.0, 80.0).expect("crop"),
            &vec![0.0; p * 16],
            HeatMapEncoding::Float32,
        )
    }
}

#[test]
fn a_camera_twice_as_fast_as_the_fused_frames_gives_each_its_frame_at_its_time() {
    let mut node = node();
    let mut out = Vec::new();
    for i in 0..40 {
        let stamp = 1_000_000_000 + i * PERIOD / 2;
        let msg = frame(&node, "a", stamp);
        node.heat_maps(0, &msg, stamp, &mut out).expect("taken");
        if i % 2 == 0 {
            // On a fused frame's time: that frame holds it, at no offset.
            let waiting: Vec<i64> = node
                .pending
                .iter()
                .flat_map(|s| s.frames.iter().map(|f| f.offset_ns))
                .collect();
            assert!(waiting.iter().all(|o| o.abs() <= 1), "{i}: {waiting:?}");
        }
    }
    // Every frame halfway between two fused frames gave way to one at its time.
    assert_eq!(node.counters().superseded, 20);
}

#[test]
fn a_stray_stamp_is_refused_and_a_time_that_jumped_for_good_starts_again() {
    let mut node = node();
    let mut out = Vec::new();
    let (mut now, mut stamp) = (0, 1_000_000_000_000);
    let mut send = |node: &mut FusionNode, cameras: &[&str], shift: i64| {
        now += PERIOD;
        stamp += PERIOD;
        for (c, name) in cameras.iter().enumerate() {
            let msg = frame(node, name, stamp + shift);
            let _ = node.heat_maps(c, &msg, now, &mut out);
        }
    };
    for _ in 0..10 {
        send(&mut node, &["a", "b"], 0);
    }
    // One camera's stray stamps, 100 s back or ahead: refused, nothing restarts.
    for shift in [-100_000_000_000, 100_000_000_000] {
        for _ in 0..JUMP_FRAMES + 5 {
            send(&mut node, &["a"], shift);
            send(&mut node, &["a", "b"], 0);
        }
    }
    assert_eq!(node.counters().restarts, 0);
    assert!(node.refused().of("late") > 0 && node.refused().of("clock") > 0);
    // Both cameras 100 s back for good (a replay started again): once they have
    // said so for JUMP_FRAMES frames, the fused frames start again, once.
    let fused = node.counters().fused;
    for _ in 0..JUMP_FRAMES + 10 {
        send(&mut node, &["a", "b"], -100_000_000_000);
    }
    assert_eq!(node.counters().restarts, 1);
    assert!(node.counters().fused > fused);
}

#[test]
fn hostile_frames_are_refused_by_kind_and_change_nothing() {
    let mut node = node();
    let mut out = Vec::new();
    let good = frame(&node, "a", 1_000_000_000);
    node.heat_maps(0, &good, 0, &mut out).expect("taken");
    let mut cases: Vec<(HeatMaps, &str)> = Vec::new();
    cases.push((
        HeatMaps {
            track_id: 0,
            ..good.clone()
        },
        "camera",
    ));
    cases.push((
        HeatMaps {
            crop_x: f64::NAN,
            ..good.clone()
        },
        "invalid",
    ));
    let mut short = good.clone();
    short.values.truncate(3);
    cases.push((short, "invalid"));
    let mut nan_scale = good.clone();
    nan_scale.encoding = HeatMapEncoding::Uint8.code();
    nan_scale.quantized_values = vec![1; good.values.len()];
    nan_scale.values.clear();
    nan_scale.quantization_scale = f32::NAN;
    cases.push((nan_scale, "invalid"));
    let mut other_frame = good.clone();
    other_frame.header.frame_id = "b".into();
    cases.push((other_frame, "camera"));
    let mut huge = good.clone();
    huge.height = u32::MAX;
    huge.width = u32::MAX;
    cases.push((huge, "beyond-limits"));
    let mut joints = good.clone();
    joints.joint_names.reverse();
    cases.push((joints, "joints"));
    for (stamp, kind) in [(i64::MIN, "late"), (i64::MAX, "clock")] {
        let mut far = good.clone();
        far.header.stamp = Time::from_nanos(stamp);
        cases.push((far, kind));
    }
    for (msg, kind) in &cases {
        let before = node.refused().of(kind);
        assert!(node.heat_maps(0, msg, 1, &mut out).is_err(), "{kind}");
        assert_eq!(node.refused().of(kind), before + 1, "{kind}");
    }
    // Camera b sending in camera a's frame (a mix-up of topics): refused, and b keeps
    // no frame of its own yet.
    let mixed = frame(&node, "a", 1_000_000_000);
    let before = node.refused().of("camera");
    assert!(node.heat_maps(1, &mixed, 1, &mut out).is_err());
    assert_eq!(node.refused().of("camera"), before + 1);
    assert_eq!(node.cameras()[1].frame_id, "");
    // Its calibration in camera a's frame too: refused as well, so neither its heat maps
    // nor its calibration make it camera a's twin.
    let info = crate::msgs::sensor::CameraInfo {
        header: Header {
            stamp: Time::from_nanos(1_000_000_000),
            frame_id: "a".into(),
        },
        width: 640,
        height: 480,
        k: [600.0, 0.0, 320.0, 0.0, 600.0, 240.0, 0.0, 0.0, 1.0],
        ..Default::default()
    };
    let before = node.refused().of("camera-info");
    node.camera_info(1, &info);
    assert_eq!(node.refused().of("camera-info"), before + 1);
    assert_eq!(node.cameras()[1].frame_id, "");
    assert!(node.heat_maps(1, &mixed, 1, &mut out).is_err());
    // Camera a's calibration in camera b's frame, after a's frame is known: refused each
    // time, a's intrinsics (configured here) and frame untouched.
    let mut other = info.clone();
    other.header.frame_id = "b".into();
    for _ in 0..2 {
        let before = node.refused().of("camera-info");
        node.camera_info(0, &other);
        assert_eq!(node.refused().of("camera-info"), before + 1);
    }
    // Only the good frame was taken; the camera's frame id is still its own.
    assert_eq!(node.counters().frames, 1);
    assert_eq!(node.cameras()[0].frame_id, "a");
}
