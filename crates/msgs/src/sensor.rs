//! `sensor_msgs/Image` and `sensor_msgs/CompressedImage`, mirrored field for field from
//! ROS 2 Jazzy's `sensor_msgs` (comments and constants left out): the camera frames the
//! image detector reads from a ROS 2 topic or a recording.

use super::Header;
use crate::ros_message;

ros_message! {
    /// `sensor_msgs/Image`: an uncompressed image.
    Image = "sensor_msgs/msg/Image", "sensor_msgs/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
         uint8 is_bigendian\nuint32 step\nuint8[] data\n";
    /// Capture time and camera frame id.
    header: Header,
    /// Rows.
    height: u32,
    /// Columns.
    width: u32,
    /// Pixel encoding (`rgb8`, `bgr8`, `mono8`, `rgba8`, `bgra8`, ...).
    encoding: String,
    /// 1 if multi-byte values are big-endian.
    is_bigendian: u8,
    /// Bytes per row.
    step: u32,
    /// `step x height` bytes.
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
}

ros_message! {
    /// `sensor_msgs/CompressedImage`: a JPEG or PNG image (`image_transport`'s
    /// `compressed` topics).
    CompressedImage = "sensor_msgs/msg/CompressedImage", "sensor_msgs/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n";
    /// Capture time and camera frame id.
    header: Header,
    /// `jpeg`, `png`, or `image_transport`'s `rgb8; jpeg compressed bgr8` form.
    format: String,
    /// The compressed bytes.
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
}
