//! `tf2_msgs/TFMessage` and the `geometry_msgs` it needs, mirrored from ROS 2's
//! `tf2_msgs` and `geometry_msgs` packages (the same from Humble to Kilted; field for field:
//! the CDR layout must match what `tf2_ros` decodes). Comments of the upstream files are
//! left out.

use super::Header;
use super::visualization::{Quaternion, Vector3};
use crate::ros_message;

/// The topic transforms came on, as tf2 tells them apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TfTopic {
    /// `/tf_static`: each sent once, latched; kept for good.
    Static,
    /// `/tf`: sent again and again; kept while they are fresh or asked for.
    Dynamic,
}

ros_message! {
    /// `geometry_msgs/Transform`: a frame's origin and axes in its parent frame.
    Transform = "geometry_msgs/msg/Transform", "geometry_msgs/Transform",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n";
    /// The child frame's origin in the parent frame.
    translation: Vector3,
    /// The child frame's axes in the parent frame.
    rotation: Quaternion,
}

ros_message! {
    /// `geometry_msgs/TransformStamped`: frame `child_frame_id` in frame
    /// `header.frame_id` at `header.stamp`.
    TransformStamped = "geometry_msgs/msg/TransformStamped", "geometry_msgs/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n";
    /// Time and parent frame.
    header: Header,
    /// The frame placed.
    child_frame_id: String,
    /// Where it is.
    transform: Transform,
}

impl TransformStamped {
    /// Frame `child` in the frame of `header`: its origin at `translation` (x, y, z) and
    /// its axes turned by the unit quaternion `rotation` (x, y, z, w: ROS's order).
    pub fn new(
        header: Header,
        child: impl Into<String>,
        translation: [f64; 3],
        rotation: [f64; 4],
    ) -> Self {
        let [x, y, z] = translation;
        let [qx, qy, qz, qw] = rotation;
        Self {
            header,
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3 { x, y, z },
                rotation: Quaternion {
                    x: qx,
                    y: qy,
                    z: qz,
                    w: qw,
                },
            },
        }
    }
}

ros_message! {
    /// `tf2_msgs/TFMessage`: what `/tf` carries.
    TFMessage = "tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage",
        "geometry_msgs/TransformStamped[] transforms\n";
    /// The transforms.
    transforms: Vec<TransformStamped>,
}
