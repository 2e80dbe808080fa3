//! Skeletons as `visualization_msgs/MarkerArray`, so RViz2 and Foxglove draw them: one
//! `LINE_LIST` of the bones and one `SPHERE_LIST` of the joints per skeleton, in the
//! skeleton's frame and units, namespace `posestream/lag<L>` (the newest and the refined
//! estimate side by side), id from the track.

use crate::msgs::visualization::{
    ADD, ColorRGBA, Duration, LINE_LIST, Marker, MarkerArray, Point, Pose, Quaternion, SPHERE_LIST,
    Vector3,
};
use crate::msgs::{Skeleton3D, SkeletonState};

/// How long a marker stays without an update.
const LIFETIME_NS: u32 = 500_000_000;

/// The markers of `skeleton`, whose joints are joined by `bones` (index pairs).
pub fn skeleton_markers(skeleton: &Skeleton3D, bones: &[(usize, usize)]) -> MarkerArray {
    let joints: Vec<Point> = skeleton
        .positions
        .chunks_exact(3)
        .map(|p| Point {
            x: p[0],
            y: p[1],
            z: p[2],
        })
        .collect();
    // Sizes relative to the skeleton's extent (units may be metres or the dictionary's).
    let extent = bounding_diagonal(&joints).max(f64::MIN_POSITIVE);
    let color = match (skeleton.state(), skeleton.lag) {
        (Some(SkeletonState::Lost), _) => rgba(0.6, 0.6, 0.6),
        (_, 0) => rgba(1.0, 0.55, 0.0),
        _ => rgba(0.1, 0.75, 0.25),
    };
    let base = Marker {
        header: skeleton.header.clone(),
        ns: format!("posestream/lag{}", skeleton.lag),
        action: ADD,
        pose: Pose {
            orientation: Quaternion {
                w: 1.0,
                ..Quaternion::default()
            },
            ..Pose::default()
        },
        color,
        lifetime: Duration {
            sec: 0,
            nanosec: LIFETIME_NS,
        },
        ..Marker::default()
    };
    // Two markers per track: ids 2t and 2t + 1 (track ids past 2^30 wrap around).
    let id = (skeleton.track_id % (1 << 30)) as i32;
    let line = 0.015 * extent;
    let sphere = 0.035 * extent;
    let bones_marker = Marker {
        id: 2 * id,
        r#type: LINE_LIST,
        scale: Vector3 {
            x: line,
            y: line,
            z: line,
        },
        points: bones
            .iter()
            .filter(|(a, b)| *a < joints.len() && *b < joints.len())
            .flat_map(|&(a, b)| [joints[a].clone(), joints[b].clone()])
            .collect(),
        ..base.clone()
    };
    let joints_marker = Marker {
        id: 2 * id + 1,
        r#type: SPHERE_LIST,
        scale: Vector3 {
            x: sphere,
            y: sphere,
            z: sphere,
        },
        points: joints,
        ..base
    };
    MarkerArray {
        markers: vec![bones_marker, joints_marker],
    }
}

fn rgba(r: f32, g: f32, b: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a: 1.0 }
}

fn bounding_diagonal(points: &[Point]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for (i, v) in [p.x, p.y, p.z].into_iter().enumerate() {
            lo[i] = lo[i].min(v);
            hi[i] = hi[i].max(v);
        }
    }
    if points.is_empty() {
        return 0.0;
    }
    (0..3).map(|i| (hi[i] - lo[i]).powi(2)).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{self, RosMessage};

    #[test]
    fn a_skeleton_becomes_bones_and_joints() {
        let s = Skeleton3D {
            track_id: 3,
            lag: 10,
            state: SkeletonState::Tracking as u8,
            positions: vec![0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0],
            ..Skeleton3D::default()
        };
        let m = skeleton_markers(&s, &[(0, 1), (1, 2), (5, 0)]);
        assert_eq!(m.markers.len(), 2);
        let (bones, joints) = (&m.markers[0], &m.markers[1]);
        assert_eq!((bones.r#type, bones.id), (LINE_LIST, 6));
        assert_eq!(
            bones.points.len(),
            4,
            "the bone to a joint that is not there is left out"
        );
        assert_eq!((joints.r#type, joints.id), (SPHERE_LIST, 7));
        assert_eq!(joints.points.len(), 3);
        assert_eq!(joints.ns, "posestream/lag10");
        assert!(joints.scale.x > 0.0 && bones.scale.x > 0.0);
        let bytes = msgs::encode(&m).expect("encode");
        assert_eq!(msgs::decode::<MarkerArray>(&bytes).expect("decode"), m);
        let def = MarkerArray::full_definition();
        for nested in [
            "MSG: visualization_msgs/Marker\n",
            "MSG: geometry_msgs/Pose\n",
            "MSG: std_msgs/ColorRGBA\n",
            "MSG: sensor_msgs/CompressedImage\n",
            "MSG: builtin_interfaces/Duration\n",
        ] {
            assert!(def.contains(nested), "{nested}");
        }
    }
}
