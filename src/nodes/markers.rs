//! Skeletons as `visualization_msgs/MarkerArray`, so RViz2 and Foxglove draw them: per
//! skeleton a `LINE_LIST` of the bones, a `SPHERE_LIST` of the joints and a
//! `TEXT_VIEW_FACING` label with the track id above the highest joint, in the
//! skeleton's frame and units, namespace `posestream/lag<L>` (the newest and the refined
//! estimate side by side), ids and colour from the track (each person a hue of their
//! own; the newest estimate lighter than the refined one; a lost track grey).
//!
//! And each image's skeletons over the image ([`image_markers`]): one
//! `visualization_msgs/ImageMarker`, a `LINE_LIST` of every person's bones where the
//! model reprojects them (image pixels), each person in the colour of their 3D markers,
//! so an image view (the Foxglove app's Image panel) shows the 2D overlay.

use crate::msgs::visualization::{
    ADD, ColorRGBA, Duration, IMAGE_LINE_LIST, ImageMarker, LINE_LIST, Marker, MarkerArray, Point,
    Pose, Quaternion, SPHERE_LIST, TEXT_VIEW_FACING, Vector3,
};
use crate::msgs::{Skeleton3D, Skeleton3DArray, SkeletonState};

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
        (_, 0) => track_color(skeleton.track_id, 0.75),
        _ => track_color(skeleton.track_id, 0.5),
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
    // Three markers per track: ids 3t, 3t + 1 and 3t + 2 (track ids past 2^29 wrap
    // around).
    let id = (skeleton.track_id % (1 << 29)) as i32;
    let line = 0.015 * extent;
    let sphere = 0.035 * extent;
    // The label: above the highest joint (image up is -y in the camera frame).
    let top = joints
        .iter()
        .min_by(|a, b| a.y.total_cmp(&b.y))
        .map(|p| Point {
            x: p.x,
            y: p.y - 0.08 * extent,
            z: p.z,
        })
        .unwrap_or_default();
    let label = Marker {
        id: 3 * id + 2,
        r#type: TEXT_VIEW_FACING,
        pose: Pose {
            position: top,
            ..base.pose.clone()
        },
        scale: Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.06 * extent,
        },
        text: format!("{}", skeleton.track_id),
        ..base.clone()
    };
    let bones_marker = Marker {
        id: 3 * id,
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
        id: 3 * id + 1,
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
        markers: vec![bones_marker, joints_marker, label],
    }
}

/// The skeletons of one image drawn over it, written into `out` (its vectors reused):
/// every person's bones (`bones`, index pairs) between the model's reprojected joints
/// (`Skeleton3D::projected`, image pixels), each person in their track's colour; lost
/// tracks and joints that are not finite are left out. Stamped and framed as the image.
pub fn image_markers(array: &Skeleton3DArray, bones: &[(usize, usize)], out: &mut ImageMarker) {
    // Field by field: a derived clone_from of the header would allocate its frame id.
    out.header.stamp = array.header.stamp.clone();
    out.header.frame_id.clone_from(&array.header.frame_id);
    if out.ns != "posestream" {
        out.ns = "posestream".into();
    }
    out.id = 0;
    out.r#type = IMAGE_LINE_LIST;
    out.action = ADD;
    out.scale = 2.0;
    out.outline_color = rgba(1.0, 1.0, 1.0);
    out.lifetime = Duration {
        sec: 0,
        nanosec: LIFETIME_NS,
    };
    out.points.clear();
    out.outline_colors.clear();
    for s in &array.skeletons {
        if s.state == SkeletonState::Lost as u8 {
            continue;
        }
        let color = track_color(s.track_id, 0.6);
        let at = |j: usize| {
            let (u, v) = (*s.projected.get(2 * j)?, *s.projected.get(2 * j + 1)?);
            (u.is_finite() && v.is_finite()).then_some(Point { x: u, y: v, z: 0.0 })
        };
        for &(a, b) in bones {
            if let (Some(pa), Some(pb)) = (at(a), at(b)) {
                out.points.extend([pa, pb]);
                out.outline_colors.extend([color.clone(), color.clone()]);
            }
        }
    }
}

fn rgba(r: f32, g: f32, b: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a: 1.0 }
}

/// The colour of a track: hues a golden angle apart, so that consecutive ids differ
/// most; `lightness` in (0, 1) (fully saturated at 0.5).
fn track_color(track_id: u32, lightness: f32) -> ColorRGBA {
    const GOLDEN: f64 = 0.618_033_988_749_895;
    let hue = (f64::from(track_id) * GOLDEN).fract() as f32 * 6.0;
    // HSL to RGB, saturation 1.
    let chroma = 1.0 - (2.0 * lightness - 1.0).abs();
    let x = chroma * (1.0 - (hue % 2.0 - 1.0).abs());
    let (r, g, b) = match hue as u32 {
        0 => (chroma, x, 0.0),
        1 => (x, chroma, 0.0),
        2 => (0.0, chroma, x),
        3 => (0.0, x, chroma),
        4 => (x, 0.0, chroma),
        _ => (chroma, 0.0, x),
    };
    let m = lightness - chroma / 2.0;
    rgba(r + m, g + m, b + m)
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
    fn an_image_s_people_are_drawn_over_it_in_their_colours() {
        let person = |track_id, state: SkeletonState, u: f64| Skeleton3D {
            track_id,
            state: state as u8,
            projected: vec![u, 10.0, u + 5.0, 20.0, f64::NAN, 30.0],
            ..Skeleton3D::default()
        };
        let mut array = Skeleton3DArray::default();
        array.header.frame_id = "camera".into();
        array.skeletons = vec![
            person(1, SkeletonState::Tracking, 100.0),
            person(2, SkeletonState::Tracking, 300.0),
            person(3, SkeletonState::Lost, 500.0),
        ];
        let mut m = ImageMarker::default();
        // Bone 1-2 has a joint that is not finite: left out.
        image_markers(&array, &[(0, 1), (1, 2)], &mut m);
        assert_eq!(m.r#type, IMAGE_LINE_LIST);
        assert_eq!(m.header.frame_id, "camera");
        let xs: Vec<f64> = m.points.iter().map(|p| p.x).collect();
        assert_eq!(xs, [100.0, 105.0, 300.0, 305.0]);
        assert_eq!(m.outline_colors.len(), m.points.len());
        assert_ne!(m.outline_colors[0], m.outline_colors[2]);
        assert_eq!(m.outline_colors[0], track_color(1, 0.6));
        let bytes = msgs::encode(&m).expect("encode");
        assert_eq!(msgs::decode::<ImageMarker>(&bytes).expect("decode"), m);
        // Reused: the next image replaces the points.
        array.skeletons.truncate(1);
        image_markers(&array, &[(0, 1)], &mut m);
        assert_eq!(m.points.len(), 2);
    }

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
        assert_eq!(m.markers.len(), 3);
        let (bones, joints, label) = (&m.markers[0], &m.markers[1], &m.markers[2]);
        assert_eq!((bones.r#type, bones.id), (LINE_LIST, 9));
        assert_eq!(
            bones.points.len(),
            4,
            "the bone to a joint that is not there is left out"
        );
        assert_eq!((joints.r#type, joints.id), (SPHERE_LIST, 10));
        assert_eq!((label.r#type, label.id), (TEXT_VIEW_FACING, 11));
        assert_eq!(label.text, "3");
        // Above the highest joint (y = 0), in the track's colour.
        assert!(label.pose.position.y < 0.0);
        assert_eq!(label.color, bones.color);
        assert_eq!(joints.points.len(), 3);
        assert_eq!(joints.ns, "posestream/lag10");
        assert!(joints.scale.x > 0.0 && bones.scale.x > 0.0);
        let bytes = msgs::encode(&m).expect("encode");
        assert_eq!(msgs::decode::<MarkerArray>(&bytes).expect("decode"), m);
        // Each person a colour of their own; the newest estimate lighter; lost grey.
        let colour = |track_id, lag, state: SkeletonState| {
            let s = Skeleton3D {
                track_id,
                lag,
                state: state as u8,
                ..s.clone()
            };
            skeleton_markers(&s, &[]).markers[0].color.clone()
        };
        let tracking = SkeletonState::Tracking;
        for (a, b) in [(0, 1), (1, 2), (0, 2), (3, 4), (7, 8)] {
            let (ca, cb) = (colour(a, 10, tracking), colour(b, 10, tracking));
            let distance = (ca.r - cb.r).abs() + (ca.g - cb.g).abs() + (ca.b - cb.b).abs();
            assert!(distance > 0.3, "tracks {a} and {b}: {ca:?} {cb:?}");
        }
        assert_ne!(colour(3, 0, tracking), colour(3, 10, tracking));
        let grey = colour(3, 10, SkeletonState::Lost);
        assert_eq!((grey.r, grey.g), (grey.g, grey.b));
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
