//! The ROS4HRI messages (REP-155, package `hri_msgs`) posestream publishes about the bodies
//! it tracks. Their `.msg` files are mirrored unchanged from ros4hri's `hri_msgs`
//! (`msgs/hri_msgs/`, BSD 3-clause, PAL Robotics; its README says from where) and included
//! here, so the layout is theirs.

use super::Header;
use crate::ros_message;

ros_message! {
    /// `hri_msgs/IdsList`: the ids of the bodies (faces, persons, ...) seen now.
    IdsList = "hri_msgs/msg/IdsList", "hri_msgs/IdsList",
        include_str!("../../../msgs/hri_msgs/msg/IdsList.msg");
    /// Stamp of the image and its camera frame id.
    header: Header,
    /// The ids.
    ids: Vec<String>,
}

ros_message! {
    /// `hri_msgs/NormalizedPointOfInterest2D`: a point of an image, coordinates in
    /// `[0, 1]` of its width and height, with a confidence.
    NormalizedPointOfInterest2D = "hri_msgs/msg/NormalizedPointOfInterest2D",
        "hri_msgs/NormalizedPointOfInterest2D",
        include_str!("../../../msgs/hri_msgs/msg/NormalizedPointOfInterest2D.msg");
    /// Column, as a fraction of the width (0: the left edge).
    x: f32,
    /// Row, as a fraction of the height (0: the top edge).
    y: f32,
    /// Confidence in `[0, 1]` (0: not observed).
    c: f32,
}

ros_message! {
    /// `hri_msgs/Skeleton2D`: a body's 18 keypoints in the image (OpenPose's COCO order,
    /// the `*` constants below).
    Skeleton2D = "hri_msgs/msg/Skeleton2D", "hri_msgs/Skeleton2D",
        include_str!("../../../msgs/hri_msgs/msg/Skeleton2D.msg");
    /// Capture time of the image and its camera frame id.
    header: Header,
    /// One point per keypoint, in the order of [`SKELETON2D_KEYPOINTS`].
    skeleton: [NormalizedPointOfInterest2D; 18],
}

ros_message! {
    /// `hri_msgs/NormalizedRegionOfInterest2D`: a part of an image, its corners in
    /// `[0, 1]` of the image's width and height, with a confidence.
    NormalizedRegionOfInterest2D = "hri_msgs/msg/NormalizedRegionOfInterest2D",
        "hri_msgs/NormalizedRegionOfInterest2D",
        include_str!("../../../msgs/hri_msgs/msg/NormalizedRegionOfInterest2D.msg");
    /// Capture time of the image and its camera frame id.
    header: Header,
    /// Left edge, as a fraction of the width.
    xmin: f32,
    /// Top edge, as a fraction of the height.
    ymin: f32,
    /// Right edge, as a fraction of the width.
    xmax: f32,
    /// Bottom edge, as a fraction of the height.
    ymax: f32,
    /// Confidence in `[0, 1]`.
    c: f32,
}

/// The keypoints of `Skeleton2D.skeleton`, in order (the `.msg`'s constants, lower case).
pub const SKELETON2D_KEYPOINTS: [&str; 18] = [
    "nose",
    "neck",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_hip",
    "left_knee",
    "left_ankle",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
];
