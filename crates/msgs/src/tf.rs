//! `tf2_msgs/TFMessage` and the `geometry_msgs` it needs (and
//! `geometry_msgs/PoseWithCovarianceStamped`: a frame with its uncertainty), mirrored from ROS 2's
//! `tf2_msgs` and `geometry_msgs` packages (the same from Humble to Kilted; field for field:
//! the CDR layout must match what `tf2_ros` decodes). Comments of the upstream files are
//! left out.

use super::Header;
use super::visualization::{Pose, Quaternion, Vector3};
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

/// The 36 numbers of a 6 x 6 covariance, row by row (`float64[36]`): of x, y, z and the
/// rotations about the x, y and z axes (radians), as `geometry_msgs` orders them. A type
/// of its own because serde derives arrays of at most 32; in CDR, as any fixed-size
/// array, its elements without a length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance(pub [f64; 36]);

impl Default for Covariance {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Covariance {
    /// Zero but for the diagonal, which is `variances`.
    pub fn diagonal(variances: [f64; 6]) -> Self {
        let mut c = Self::default();
        for (i, v) in variances.into_iter().enumerate() {
            c.0[i * 6 + i] = v;
        }
        c
    }
}

impl crate::RosType for Covariance {
    fn ros_type() -> String {
        "float64[36]".into()
    }
}

impl serde::Serialize for Covariance {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> serde::Deserialize<'de> for Covariance {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Numbers;
        impl<'de> serde::de::Visitor<'de> for Numbers {
            type Value = Covariance;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 float64")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Covariance, A::Error> {
                let mut c = Covariance::default();
                for (i, slot) in c.0.iter_mut().enumerate() {
                    *slot = seq
                        .next_element()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                Ok(c)
            }
        }
        d.deserialize_tuple(36, Numbers)
    }
}

ros_message! {
    /// `geometry_msgs/PoseWithCovariance`: a pose and how uncertain it is.
    PoseWithCovariance = "geometry_msgs/msg/PoseWithCovariance", "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose pose\nfloat64[36] covariance\n";
    /// The pose.
    pose: Pose,
    /// Its covariance ([`Covariance`]), in the axes of the frame the pose is in.
    covariance: Covariance,
}

ros_message! {
    /// `geometry_msgs/PoseWithCovarianceStamped`: a pose in frame `header.frame_id`, with
    /// its covariance.
    PoseWithCovarianceStamped = "geometry_msgs/msg/PoseWithCovarianceStamped",
        "geometry_msgs/PoseWithCovarianceStamped",
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n";
    /// Time and frame.
    header: Header,
    /// The pose and its covariance.
    pose: PoseWithCovariance,
}
