//! The messages: `.msg` text and Rust types agree, CDR round trips, bad bytes are errors.

mod common;

use posestream::CropBox;
use posestream::msgs::{
    self, CDR_LE_HEADER, Header, HeatMapEncoding, HeatMaps, RosMessage, Skeleton3D, Time,
    parse_definition,
};

fn fields_of<M: RosMessage>() -> Vec<(String, String)> {
    M::fields()
        .into_iter()
        .map(|f| (f.ros_type, f.name.to_string()))
        .collect()
}

#[test]
fn every_msg_file_declares_exactly_the_fields_of_its_rust_type() {
    assert_eq!(
        parse_definition(HeatMaps::DEFINITION),
        fields_of::<HeatMaps>()
    );
    assert_eq!(
        parse_definition(Skeleton3D::DEFINITION),
        fields_of::<Skeleton3D>()
    );
    assert_eq!(
        parse_definition(msgs::Skeleton3DArray::DEFINITION),
        fields_of::<msgs::Skeleton3DArray>()
    );
    assert_eq!(parse_definition(Header::DEFINITION), fields_of::<Header>());
    assert_eq!(parse_definition(Time::DEFINITION), fields_of::<Time>());
    use posestream::msgs::visualization as v;
    assert_eq!(
        parse_definition(v::Marker::DEFINITION),
        fields_of::<v::Marker>()
    );
    assert_eq!(
        parse_definition(v::MarkerArray::DEFINITION),
        fields_of::<v::MarkerArray>()
    );
    assert_eq!(
        parse_definition(v::Pose::DEFINITION),
        fields_of::<v::Pose>()
    );
    assert_eq!(
        parse_definition(v::CompressedImage::DEFINITION),
        fields_of::<v::CompressedImage>()
    );
    use posestream::msgs::sensor;
    assert_eq!(
        parse_definition(sensor::Image::DEFINITION),
        fields_of::<sensor::Image>()
    );
    assert_eq!(
        parse_definition(sensor::CameraInfo::DEFINITION),
        fields_of::<sensor::CameraInfo>()
    );
    assert_eq!(
        parse_definition(sensor::RegionOfInterest::DEFINITION),
        fields_of::<sensor::RegionOfInterest>()
    );
    assert_eq!(
        parse_definition(v::MeshFile::DEFINITION),
        fields_of::<v::MeshFile>()
    );
    assert_eq!(
        parse_definition(v::ImageMarker::DEFINITION),
        fields_of::<v::ImageMarker>()
    );
    // The files on disk are the ones compiled in (msgs/ is a ROS 2 package).
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for (file, text) in [
        ("msgs/msg/HeatMaps.msg", HeatMaps::DEFINITION),
        ("msgs/msg/Skeleton3D.msg", Skeleton3D::DEFINITION),
        (
            "msgs/msg/Skeleton3DArray.msg",
            msgs::Skeleton3DArray::DEFINITION,
        ),
    ] {
        let cmake = std::fs::read_to_string(root.join("msgs/CMakeLists.txt")).expect("cmake");
        assert!(cmake.contains(file.trim_start_matches("msgs/")), "{file}");
        assert_eq!(std::fs::read_to_string(root.join(file)).expect(file), text);
    }
}

#[test]
fn tf_and_rep155_messages_declare_the_upstream_fields() {
    use posestream::msgs::{hri, tf};
    assert_eq!(
        parse_definition(tf::TFMessage::DEFINITION),
        fields_of::<tf::TFMessage>()
    );
    assert_eq!(
        parse_definition(tf::TransformStamped::DEFINITION),
        fields_of::<tf::TransformStamped>()
    );
    assert_eq!(
        parse_definition(tf::Transform::DEFINITION),
        fields_of::<tf::Transform>()
    );
    // The ros4hri files name their own package's types without it.
    let qualified = |text: &str| -> Vec<(String, String)> {
        parse_definition(text)
            .into_iter()
            .map(|(ty, name)| {
                let primitive = ty.chars().next().is_some_and(|c| c.is_ascii_lowercase());
                let ty = if ty.contains('/') || primitive {
                    ty
                } else {
                    format!("hri_msgs/{ty}")
                };
                (ty, name)
            })
            .collect()
    };
    assert_eq!(
        qualified(hri::IdsList::DEFINITION),
        fields_of::<hri::IdsList>()
    );
    assert_eq!(
        qualified(hri::Skeleton2D::DEFINITION),
        fields_of::<hri::Skeleton2D>()
    );
    assert_eq!(
        qualified(hri::NormalizedPointOfInterest2D::DEFINITION),
        fields_of::<hri::NormalizedPointOfInterest2D>()
    );
    assert_eq!(
        qualified(hri::NormalizedRegionOfInterest2D::DEFINITION),
        fields_of::<hri::NormalizedRegionOfInterest2D>()
    );
    // The keypoint order is the .msg's constants'.
    for (k, name) in hri::SKELETON2D_KEYPOINTS.iter().enumerate() {
        let constant = format!("uint8 {} = {k}\n", name.to_uppercase());
        assert!(
            hri::Skeleton2D::DEFINITION.contains(&constant),
            "{constant}"
        );
    }
    // A fixed array: 18 points without a length in CDR (after the encapsulation, a
    // stamp of 8 bytes and an empty frame id of 5, padded to 16).
    let bytes = msgs::encode(&hri::Skeleton2D::default()).expect("encodes");
    assert_eq!(bytes.len(), 4 + 16 + 18 * 12);
}

#[test]
fn full_definitions_append_nested_messages_after_80_equals_signs() {
    let def = Skeleton3D::full_definition();
    let sep = format!("{}\n", "=".repeat(80));
    assert_eq!(def.matches(&sep).count(), 2, "{def}");
    assert!(def.contains(&format!("{sep}MSG: std_msgs/Header\n")));
    assert!(def.contains(&format!("{sep}MSG: builtin_interfaces/Time\n")));
    assert!(!def.contains("MSG: posestream_msgs/Skeleton3D"));
    assert_eq!(
        Skeleton3D::dds_type_name(),
        "posestream_msgs::msg::dds_::Skeleton3D_"
    );
    assert_eq!(HeatMaps::NAME, "posestream_msgs/msg/HeatMaps");
}

fn sample_maps(encoding: HeatMapEncoding) -> HeatMaps {
    let values: Vec<f32> = (0..2 * 3 * 4).map(|i| (i % 7) as f32 * 0.25).collect();
    HeatMaps::from_values(
        Header {
            stamp: Time::from_nanos(1_500_000_123),
            frame_id: "camera".into(),
        },
        42,
        vec!["a".into(), "b".into()],
        3,
        4,
        CropBox::new(10.0, 20.0, 128.0, 96.0).expect("box"),
        &values,
        encoding,
    )
}

#[test]
fn messages_round_trip_through_cdr_with_the_encapsulation_header() {
    for encoding in [HeatMapEncoding::Float32, HeatMapEncoding::Uint8] {
        let msg = sample_maps(encoding);
        let bytes = msgs::encode(&msg).expect("encodes");
        assert_eq!(bytes[..4], CDR_LE_HEADER);
        let back: HeatMaps = msgs::decode(&bytes).expect("decodes");
        assert_eq!(back, msg);
        let mut values = Vec::new();
        back.values_into(&mut values).expect("values");
        assert_eq!(values.len(), 24);
        // u8 quantisation keeps each score within half a step.
        let step = if encoding == HeatMapEncoding::Uint8 {
            1.5 / 255.0
        } else {
            0.0
        };
        for (i, v) in values.iter().enumerate() {
            let truth = (i % 7) as f32 * 0.25;
            assert!(
                (v - truth).abs() <= 0.5 * step + 1e-6,
                "{i}: {v} vs {truth}"
            );
        }
    }
    let skel = Skeleton3D {
        sequence: 7,
        joint_names: vec!["x".into()],
        positions: vec![1.0, -2.0, 3.5],
        lag: 10,
        state: 1,
        ..Skeleton3D::default()
    };
    let back: Skeleton3D = msgs::decode(&msgs::encode(&skel).expect("encodes")).expect("decodes");
    assert_eq!(back, skel);
    assert_eq!(Time::from_nanos(-1).nanos(), -1);
}

#[test]
fn a_skeleton_recorded_before_metric_source_views_looks_or_sizes_decodes_with_none() {
    let looked = Skeleton3D {
        sequence: 3,
        units: 1,
        state: 1,
        metric_source: msgs::MetricSource::Floor as u8,
        frames_since_look: 2,
        mean_bone_length: 0.231,
        ..Skeleton3D::default()
    };
    let sized = msgs::encode(&looked).expect("encodes");
    // `mean_bone_length` ends it: 8 bytes, here right after `frames_since_look` (2),
    // which ends on an 8-byte boundary. The layout before it reads it as 0.
    let n = sized.len();
    assert_eq!(sized[n - 12..n - 8], [2, 0, 0, 0]);
    let full = &sized[..n - 8];
    let looked = Skeleton3D {
        mean_bone_length: 0.0,
        ..looked
    };
    let before_size: Skeleton3D = msgs::decode(full).expect("decodes");
    assert_eq!(before_size, looked);
    // A size that is not a number is not a finite message (not published).
    let nan = Skeleton3D {
        mean_bone_length: f64::NAN,
        ..looked.clone()
    };
    assert!(looked.is_finite() && !nan.is_finite());
    // `frames_since_look` ends it (4 bytes, aligned after the empty `views`): the
    // layout before it reads it as 0.
    let before_looks: Skeleton3D = msgs::decode(&full[..full.len() - 4]).expect("decodes");
    let skel = Skeleton3D {
        frames_since_look: 0,
        ..looked
    };
    assert_eq!(before_looks, skel);
    let bytes = &full[..full.len() - 4];
    // `views` (empty) ends that: its length, 4 bytes, after the alignment (zeros) that
    // follows `metric_source` (2, not zero).
    let count = bytes.len() - 4;
    let metric = bytes[..count]
        .iter()
        .rposition(|&b| b != 0)
        .expect("metric_source");
    assert_eq!(bytes[metric], msgs::MetricSource::Floor as u8);
    // The layout before `views`: up to `metric_source`.
    let before_views: Skeleton3D = msgs::decode(&bytes[..metric + 1]).expect("decodes");
    assert_eq!(before_views, skel);
    // The older layout: everything up to `state`.
    let older: Skeleton3D = msgs::decode(&bytes[..metric]).expect("decodes");
    assert_eq!(
        older,
        Skeleton3D {
            metric_source: msgs::MetricSource::None as u8,
            ..skel.clone()
        }
    );
    // A fused skeleton's views go and come back.
    let fused = Skeleton3D {
        views: vec!["cam0".into(), "cam2".into()],
        metric_source: msgs::MetricSource::Views as u8,
        ..skel
    };
    let back: Skeleton3D = msgs::decode(&msgs::encode(&fused).expect("encodes")).expect("decodes");
    assert_eq!(back, fused);
}

#[test]
fn malformed_bytes_are_errors_not_panics() {
    let message = HeatMaps {
        frames_since_look: 0x0102_0304,
        ..sample_maps(HeatMapEncoding::Float32)
    };
    let good = msgs::encode(&message).expect("encodes");
    // Big-endian encapsulation, too short, every truncation, garbage.
    let mut big = good.clone();
    big[1] = 0x00;
    assert!(msgs::decode::<HeatMaps>(&big).is_err());
    assert!(msgs::decode::<HeatMaps>(&[0, 1]).is_err());
    // Without its last field (`frames_since_look`, 4 bytes) it is a message of the
    // layout before it, read with 0. A cut inside that field reads the bytes left of it
    // (little-endian: its low bytes) and zeros for the rest, as the layout before it
    // padded: CDR cannot tell the two apart (as for Skeleton3D's added fields). Any
    // other cut is an error.
    let older = good.len() - 4;
    for cut in 4..good.len() {
        match msgs::decode::<HeatMaps>(&good[..cut]) {
            Ok(m) if cut >= older => {
                let kept = 8 * (cut - older) as u32;
                let low = if kept == 0 {
                    0
                } else {
                    0x0102_0304 & (u32::MAX >> (32 - kept))
                };
                assert_eq!(
                    m,
                    HeatMaps {
                        frames_since_look: low,
                        ..message.clone()
                    },
                    "cut at {cut}"
                );
            }
            Ok(_) => panic!("cut at {cut} decodes"),
            Err(_) => assert_ne!(cut, older, "the layout before frames_since_look"),
        }
    }
    let garbage: Vec<u8> = (0..200).map(|i| (i * 37 % 251) as u8).collect();
    let mut with_header = CDR_LE_HEADER.to_vec();
    with_header.extend(&garbage);
    let _ = msgs::decode::<HeatMaps>(&with_header);
    // Consistent CDR, inconsistent contents.
    let mut wrong = sample_maps(HeatMapEncoding::Float32);
    wrong.values.pop();
    assert!(wrong.values_into(&mut Vec::new()).is_err());
    wrong.encoding = 9;
    assert!(wrong.values_into(&mut Vec::new()).is_err());
    wrong.crop_width = -1.0;
    assert!(wrong.crop().is_err());
}

#[test]
fn markers_decode_alike_with_humble_and_jazzy_definitions() {
    // Humble's visualization_msgs (4.2) already has Marker's texture, uv_coordinates
    // and mesh_file fields (ros2/common_interfaces "Marker Textures", 2021-08, before
    // Humble branched); Jazzy only adds the ARROW_STRIP constant. So one layout serves
    // Humble to Kilted; Foxy and Galactic (end of life) lack those fields and misread.
    use posestream::msgs::{MarkerArray, SkeletonState};
    let s = Skeleton3D {
        track_id: 7,
        lag: 10,
        state: SkeletonState::Tracking as u8,
        positions: vec![0.0, 0.0, 3.0, 0.1, 0.5, 3.0, 0.2, 1.0, 3.1],
        ..Skeleton3D::default()
    };
    let markers: MarkerArray = posestream::nodes::markers::skeleton_markers(&s, &[(0, 1), (1, 2)]);
    assert!(markers.markers.len() >= 3);
    let ours: Vec<serde_json::Value> = markers
        .markers
        .iter()
        .map(|m| serde_json::json!([m.ns, m.id, m.r#type, m.points.len(), m.text]))
        .collect();
    let dir = tempfile::tempdir().expect("dir");
    let file = dir.path().join("markers.cdr");
    std::fs::write(&file, msgs::encode(&markers).expect("encode")).expect("write");
    let decoded = common::python_client("marker_distros.py", &[file.to_str().expect("utf-8")]);
    for distro in ["ros2_humble", "ros2_iron", "ros2_jazzy", "ros2_kilted"] {
        assert_eq!(
            decoded[distro],
            serde_json::Value::from(ours.clone()),
            "{distro}"
        );
    }
    for old in ["ros2_foxy", "ros2_galactic"] {
        assert_ne!(decoded[old], serde_json::Value::from(ours.clone()), "{old}");
    }
}
