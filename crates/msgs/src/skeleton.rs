//! `posestream_msgs/Skeleton3D`: one estimated 3D skeleton.

use super::Header;
use crate::ros_message;

/// Where the track stood (`STATE_*` in the `.msg`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SkeletonState {
    /// Fewer frames than the lag since the track started.
    Initialising = 0,
    /// Running normally.
    Tracking = 1,
    /// The last estimates of a track that ended.
    Lost = 2,
}

/// Units of the positions (`UNITS_*` in the `.msg`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Units {
    /// Centred, dictionary units (no metric scale).
    Dictionary = 0,
    /// Metres, camera frame.
    Metres = 1,
}

/// Where the metres' scale came from (`METRIC_*` in the `.msg`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MetricSource {
    /// Not in metres (dictionary units).
    None = 0,
    /// The assumed body size.
    Size = 1,
    /// The person's feet on the floor.
    Floor = 2,
    /// Several calibrated cameras (a fused skeleton, world frame).
    Views = 3,
}

ros_message! {
    /// One estimated 3D skeleton (`msgs/msg/Skeleton3D.msg` documents each field).
    Skeleton3D = "posestream_msgs/msg/Skeleton3D", "posestream_msgs/Skeleton3D",
        include_str!("../../../msgs/msg/Skeleton3D.msg"), added_tail = 24;
    /// Stamp of the frame described and the camera frame id.
    header: Header,
    /// Sequence number of the frame described.
    sequence: u64,
    /// The person tracked.
    track_id: u32,
    /// Joint of each entry.
    joint_names: Vec<String>,
    /// `UNITS_DICTIONARY` (0) or `UNITS_METRES` (1).
    units: u8,
    /// `[x, y, z]` per joint.
    positions: Vec<f64>,
    /// Standard deviation per joint and axis, `[x, y, z]` per joint.
    position_std: Vec<f64>,
    /// Expected 2D joints `[u, v]`, image pixels.
    keypoints: Vec<f64>,
    /// Standard deviation per 2D joint, image pixels.
    keypoint_std: Vec<f64>,
    /// The model's reprojection `[u, v]`, image pixels.
    projected: Vec<f64>,
    /// Frames after this one seen before it was estimated.
    lag: u32,
    /// `STATE_INITIALISING` (0), `STATE_TRACKING` (1) or `STATE_LOST` (2).
    state: u8,
    /// `METRIC_NONE` (0), `METRIC_SIZE` (1), `METRIC_FLOOR` (2) or `METRIC_VIEWS` (3);
    /// absent (older recordings): 0 (`added_tail`).
    metric_source: u8,
    /// A fused skeleton: the frame ids of the cameras whose heat maps this frame's
    /// estimate used; empty for one camera's (the header's). Absent (older recordings):
    /// empty (`added_tail`: up to 3 bytes of alignment and the length, with the byte
    /// before).
    views: Vec<String>,
    /// The heat maps of the frame described: 0, a look at this person in that image;
    /// n, carried over from the look n images before. Absent (older recordings): 0
    /// (`added_tail`: up to 3 bytes of alignment after `views`, and the value).
    frames_since_look: u32,
    /// The person's mean bone length as the metric step takes it, metres; 0: not
    /// estimated. Absent (older recordings): 0 (`added_tail`: up to 4 bytes of alignment
    /// after `frames_since_look`, and the value).
    mean_bone_length: f64,
}

ros_message! {
    /// The skeletons of every person in one image at one lag
    /// (`msgs/msg/Skeleton3DArray.msg`).
    Skeleton3DArray = "posestream_msgs/msg/Skeleton3DArray", "posestream_msgs/Skeleton3DArray",
        include_str!("../../../msgs/msg/Skeleton3DArray.msg");
    /// Stamp of the image described and the camera frame id.
    header: Header,
    /// Sequence number of the image described.
    sequence: u64,
    /// Frames after the image seen before these estimates were made.
    lag: u32,
    /// One skeleton per person.
    skeletons: Vec<Skeleton3D>,
}

impl Skeleton3D {
    /// The state, if the code is known.
    pub fn state(&self) -> Option<SkeletonState> {
        match self.state {
            0 => Some(SkeletonState::Initialising),
            1 => Some(SkeletonState::Tracking),
            2 => Some(SkeletonState::Lost),
            _ => None,
        }
    }

    /// True if every number in the message is finite (nothing else is published).
    pub fn is_finite(&self) -> bool {
        self.mean_bone_length.is_finite()
            && [
                &self.positions,
                &self.position_std,
                &self.keypoints,
                &self.keypoint_std,
                &self.projected,
            ]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
    }
}
