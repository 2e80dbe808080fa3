//! Unit tests of `shm`.

use super::*;

/// The tables of `msgs/SHARED_MEMORY.md`.
#[test]
fn payload_layouts_are_the_documented_ones() {
    use std::mem::{align_of, offset_of, size_of};
    assert_eq!(
        (size_of::<SkeletonSample>(), align_of::<SkeletonSample>()),
        (3688, 8)
    );
    let s = [
        offset_of!(SkeletonSample, stamp_ns),
        offset_of!(SkeletonSample, sequence),
        offset_of!(SkeletonSample, track_id),
        offset_of!(SkeletonSample, joints),
        offset_of!(SkeletonSample, lag),
        offset_of!(SkeletonSample, state),
        offset_of!(SkeletonSample, units),
        offset_of!(SkeletonSample, metric_source),
        offset_of!(SkeletonSample, frames_since_look),
        offset_of!(SkeletonSample, frame_id),
        offset_of!(SkeletonSample, joint_names),
        offset_of!(SkeletonSample, positions),
        offset_of!(SkeletonSample, position_std),
        offset_of!(SkeletonSample, keypoints),
        offset_of!(SkeletonSample, keypoint_std),
        offset_of!(SkeletonSample, projected),
        offset_of!(SkeletonSample, mean_bone_length),
    ];
    assert_eq!(
        s,
        [
            0, 8, 16, 20, 24, 28, 29, 30, 31, 32, 96, 864, 1632, 2400, 2912, 3168, 3680
        ]
    );
    assert_eq!(
        (size_of::<HeatMapsHeader>(), align_of::<HeatMapsHeader>()),
        (904, 8)
    );
    let h = [
        offset_of!(HeatMapsHeader, stamp_ns),
        offset_of!(HeatMapsHeader, sequence),
        offset_of!(HeatMapsHeader, track_id),
        offset_of!(HeatMapsHeader, joints),
        offset_of!(HeatMapsHeader, height),
        offset_of!(HeatMapsHeader, width),
        offset_of!(HeatMapsHeader, crop),
        offset_of!(HeatMapsHeader, frame_id),
        offset_of!(HeatMapsHeader, joint_names),
        offset_of!(HeatMapsHeader, frames_since_look),
        offset_of!(HeatMapsHeader, reserved),
    ];
    assert_eq!(h, [0, 8, 16, 20, 24, 28, 32, 64, 128, 896, 900]);
    let doc = include_str!("../../../../msgs/SHARED_MEMORY.md");
    for line in [
        "| 3168 | `projected`",
        "| 30 | `metric_source`",
        "| 1632 | `position_std`",
        "| 128 | `joint_names`",
        "3,688 bytes",
        "| 3680 | `mean_bone_length`",
        "904 bytes",
        "| 31 | `frames_since_look`",
        "| 896 | `frames_since_look`",
    ] {
        assert!(doc.contains(line), "{line}");
    }
}

#[test]
fn too_many_joints_and_long_names_are_refused() {
    let mut m = Skeleton3D {
        joint_names: vec!["j".into(); MAX_JOINTS + 1],
        ..Skeleton3D::default()
    };
    assert!(SkeletonSample::from_message(&m).is_err());
    m.joint_names = vec!["x".repeat(NAME_BYTES + 1)];
    m.positions = vec![0.0; 3];
    m.position_std = vec![0.0; 3];
    m.keypoints = vec![0.0; 2];
    m.keypoint_std = vec![0.0];
    m.projected = vec![0.0; 2];
    assert!(SkeletonSample::from_message(&m).is_err());
    m.joint_names = vec!["x".into()];
    assert!(SkeletonSample::from_message(&m).is_ok());
    m.positions.pop();
    assert!(SkeletonSample::from_message(&m).is_err());
}

#[test]
fn a_look_age_past_the_sample_s_byte_is_held_at_255_and_the_header_s_whole() {
    for (age, byte) in [(0, 0), (3, 3), (255, 255), (256, 255), (u32::MAX, 255)] {
        let m = Skeleton3D {
            frames_since_look: age,
            ..Skeleton3D::default()
        };
        let s = SkeletonSample::from_message(&m).expect("sample");
        assert_eq!(s.frames_since_look, byte, "{age}");
        assert_eq!(
            s.to_message().expect("message").frames_since_look,
            u32::from(byte)
        );
        let h = HeatMapsHeader::from_message(&HeatMaps {
            frames_since_look: age,
            ..HeatMaps::default()
        })
        .expect("header");
        assert_eq!(h.frames_since_look, age);
    }
}
