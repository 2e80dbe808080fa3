//! Skeletons as REP-155 (ROS4HRI) describes bodies: each body's region of interest
//! (`sensor_msgs/RegionOfInterest`) and 2D skeleton (`hri_msgs/Skeleton2D`) in the image,
//! and the ids of the bodies tracked (`hri_msgs/IdsList`). Ids are [`body_id`]s; the
//! body's 3D frames are [`frames`](super::frames)'.
//!
//! Both image messages need the images' size (Skeleton2D's coordinates are fractions of
//! it, a region must lie in the image): the caller has it from the camera's calibration.

pub use super::frames::body_id;
use crate::msgs::hri::{
    NormalizedPointOfInterest2D, NormalizedRegionOfInterest2D, SKELETON2D_KEYPOINTS, Skeleton2D,
};
use crate::msgs::sensor::RegionOfInterest;
use crate::msgs::{Header, Skeleton3D};

/// Our joints of Skeleton2D's 18 keypoints (OpenPose's COCO order): its neck is the
/// thorax (between the shoulders); nose, eyes and ears are not in the dictionary's
/// layout and stay unobserved (`c = 0`).
const FROM_JOINTS: [(&str, &str); 13] = [
    ("neck", "thorax"),
    ("right_shoulder", "r-shoulder"),
    ("right_elbow", "r-elbow"),
    ("right_wrist", "r-wrist"),
    ("left_shoulder", "l-shoulder"),
    ("left_elbow", "l-elbow"),
    ("left_wrist", "l-wrist"),
    ("right_hip", "r-hip"),
    ("right_knee", "r-knee"),
    ("right_ankle", "r-ankle"),
    ("left_hip", "l-hip"),
    ("left_knee", "l-knee"),
    ("left_ankle", "l-ankle"),
];

/// A keypoint's confidence is `exp(-(s / r)^2 / 2)` for its 2D standard deviation `s`
/// (pixels) and `r` this fraction of the image's longer side; 0 outside the image.
const CONFIDENCE_SPREAD: f64 = 0.05;

/// A body's region is its joints' bounding box grown by this fraction of its size on
/// each side (the joints are inside the body: the head's top, hands and feet reach out).
const ROI_MARGIN: f64 = 0.1;

/// How a skeleton layout's joints become REP-155 body messages; made once from the
/// dictionary's joint names.
#[derive(Debug, Clone)]
pub struct HriBodies {
    /// The joint of each Skeleton2D keypoint, if the layout has it.
    keypoints: [Option<usize>; 18],
}

impl HriBodies {
    /// For skeletons whose joints are `joint_names`.
    pub fn new(joint_names: &[String]) -> Self {
        let mut keypoints = [None; 18];
        for (k, name) in SKELETON2D_KEYPOINTS.iter().enumerate() {
            keypoints[k] = FROM_JOINTS
                .iter()
                .find(|(kp, _)| kp == name)
                .and_then(|(_, joint)| joint_names.iter().position(|j| j == joint));
        }
        Self { keypoints }
    }

    /// The body's 2D skeleton in images of `size` (columns, rows) pixels.
    pub fn skeleton2d(&self, skeleton: &Skeleton3D, size: (f64, f64)) -> Skeleton2D {
        let (width, height) = size;
        let reference = CONFIDENCE_SPREAD * width.max(height);
        let mut out = Skeleton2D {
            header: skeleton.header.clone(),
            ..Skeleton2D::default()
        };
        for (point, joint) in out.skeleton.iter_mut().zip(self.keypoints) {
            let Some(j) = joint else { continue };
            let (Some(uv), Some(&s)) = (
                skeleton.keypoints.get(2 * j..2 * j + 2),
                skeleton.keypoint_std.get(j),
            ) else {
                continue;
            };
            let (x, y) = (uv[0] / width, uv[1] / height);
            let c = (-0.5 * (s / reference).powi(2)).exp();
            if x.is_finite() && y.is_finite() && c.is_finite() {
                // A joint outside the image: on its edge, and not seen there.
                let inside = (0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y);
                *point = NormalizedPointOfInterest2D {
                    x: x.clamp(0.0, 1.0) as f32,
                    y: y.clamp(0.0, 1.0) as f32,
                    c: if inside { c as f32 } else { 0.0 },
                };
            }
        }
        out
    }

    /// The body's region in images of `size` (columns, rows) pixels: its joints'
    /// bounding box with a margin, clipped to the image; `None` when that leaves nothing.
    pub fn roi(&self, skeleton: &Skeleton3D, size: (f64, f64)) -> Option<RegionOfInterest> {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for uv in skeleton.keypoints.chunks_exact(2) {
            for a in 0..2 {
                lo[a] = lo[a].min(uv[a]);
                hi[a] = hi[a].max(uv[a]);
            }
        }
        let limits = [size.0, size.1];
        let mut span = [0u32; 2];
        let mut start = [0u32; 2];
        for a in 0..2 {
            let margin = ROI_MARGIN * (hi[a] - lo[a]);
            let from = (lo[a] - margin).max(0.0).floor();
            let to = (hi[a] + margin).min(limits[a]).ceil();
            if !(from.is_finite() && to.is_finite() && to > from) {
                return None;
            }
            // In 0..=size, which is below 2^32 (a CameraInfo's width and height).
            start[a] = from as u32;
            span[a] = (to - from) as u32;
        }
        Some(RegionOfInterest {
            x_offset: start[0],
            y_offset: start[1],
            width: span[0],
            height: span[1],
            do_rectify: false,
        })
    }
}

/// [`HriBodies::roi`] as fractions of images of `size` (columns, rows), for ROS4HRI's
/// libhri 2.x; its confidence is the mean of `points`' observed keypoints' (0 when none).
pub fn normalized_roi(
    roi: &RegionOfInterest,
    points: &Skeleton2D,
    size: (f64, f64),
) -> NormalizedRegionOfInterest2D {
    let (width, height) = size;
    let (sum, seen) = points
        .skeleton
        .iter()
        .filter(|p| p.c > 0.0)
        .fold((0.0_f32, 0_u32), |(sum, n), p| (sum + p.c, n + 1));
    let c = if seen == 0 { 0.0 } else { sum / seen as f32 };
    let x = |v: u32| (f64::from(v) / width).clamp(0.0, 1.0) as f32;
    let y = |v: u32| (f64::from(v) / height).clamp(0.0, 1.0) as f32;
    NormalizedRegionOfInterest2D {
        header: points.header.clone(),
        xmin: x(roi.x_offset),
        ymin: y(roi.y_offset),
        xmax: x(roi.x_offset.saturating_add(roi.width)),
        ymax: y(roi.y_offset.saturating_add(roi.height)),
        c,
    }
}

/// The ids of the bodies followed in `skeletons` (one image's), stamped as `header`: a
/// track's last estimates (`STATE_LOST`) describe a person no longer followed.
pub fn tracked(header: &Header, skeletons: &[Skeleton3D]) -> crate::msgs::hri::IdsList {
    crate::msgs::hri::IdsList {
        header: header.clone(),
        ids: skeletons
            .iter()
            .filter(|s| s.state != crate::msgs::SkeletonState::Lost as u8)
            .map(|s| body_id(s.track_id))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> Vec<String> {
        ["pelvis", "r-hip", "l-hip", "thorax", "r-wrist"]
            .map(String::from)
            .to_vec()
    }

    fn skeleton() -> Skeleton3D {
        Skeleton3D {
            track_id: 4,
            joint_names: names(),
            keypoints: vec![
                100.0, 200.0, 90.0, 200.0, 110.0, 200.0, 100.0, 100.0, 700.0, 50.0,
            ],
            keypoint_std: vec![5.0, 64.0, 5.0, 0.0, 5.0],
            ..Skeleton3D::default()
        }
    }

    #[test]
    fn keypoints_are_fractions_of_the_image_with_a_confidence() {
        let bodies = HriBodies::new(&names());
        let s = bodies.skeleton2d(&skeleton(), (640.0, 480.0));
        let at = |name: &str| {
            let k = SKELETON2D_KEYPOINTS
                .iter()
                .position(|k| *k == name)
                .expect(name);
            s.skeleton[k].clone()
        };
        // The thorax is the neck, seen for certain (std 0).
        let neck = at("neck");
        assert_eq!(
            (neck.x, neck.y, neck.c),
            (100.0 / 640.0, 100.0 / 480.0, 1.0)
        );
        // Past the image's edge: on it, not seen.
        let wrist = at("right_wrist");
        assert_eq!((wrist.x, wrist.c), (1.0, 0.0));
        // A spread of 2 r: confidence exp(-2).
        let hip = at("right_hip");
        assert!((f64::from(hip.c) - (-2.0f64).exp()).abs() < 1e-6, "{hip:?}");
        assert_eq!(at("left_hip").x, 110.0 / 640.0);
        // Not in the layout: unobserved.
        for k in ["nose", "left_eye", "right_ear", "left_knee"] {
            assert_eq!(at(k).c, 0.0, "{k}");
        }
    }

    #[test]
    fn the_region_holds_the_joints_inside_the_image() {
        let bodies = HriBodies::new(&names());
        let roi = bodies.roi(&skeleton(), (640.0, 480.0)).expect("a region");
        // x from 90 - 61 = 29 to 640 (clipped); y from 50 - 15 = 35 to 200 + 15.
        assert_eq!((roi.x_offset, roi.width), (29, 611));
        assert_eq!((roi.y_offset, roi.height), (35, 180));
        let outside = Skeleton3D {
            keypoints: vec![-50.0, -50.0, -10.0, -20.0],
            ..skeleton()
        };
        assert_eq!(bodies.roi(&outside, (640.0, 480.0)), None);
        let nan = Skeleton3D {
            keypoints: vec![f64::NAN, 1.0],
            ..skeleton()
        };
        assert_eq!(bodies.roi(&nan, (640.0, 480.0)), None);
        // As fractions, for libhri 2.x: the same corners; the confidence of the joints
        // seen.
        let points = bodies.skeleton2d(&skeleton(), (640.0, 480.0));
        let n = normalized_roi(&roi, &points, (640.0, 480.0));
        assert_eq!((n.xmin, n.xmax), (29.0 / 640.0, 1.0));
        assert_eq!((n.ymin, n.ymax), (35.0 / 480.0, 215.0 / 480.0));
        assert!(n.c > 0.0 && n.c <= 1.0, "{n:?}");
    }
}
