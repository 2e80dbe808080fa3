//! `sensor_msgs/Image`, `sensor_msgs/CompressedImage` and `sensor_msgs/CameraInfo`,
//! mirrored field for field from ROS 2 Jazzy's `sensor_msgs` (comments and constants
//! left out; the same in Humble): the camera frames the image detector reads from a ROS 2
//! topic or a recording, and the camera's calibration the estimator's metric step uses.

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

ros_message! {
    /// `sensor_msgs/RegionOfInterest`: a part of an image.
    RegionOfInterest = "sensor_msgs/msg/RegionOfInterest", "sensor_msgs/RegionOfInterest",
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n";
    /// Leftmost column.
    x_offset: u32,
    /// Topmost row.
    y_offset: u32,
    /// Rows.
    height: u32,
    /// Columns.
    width: u32,
    /// True if a rectified image of the region is wanted.
    do_rectify: bool,
}

ros_message! {
    /// `sensor_msgs/CameraInfo`: a camera's calibration (`image_pipeline`'s convention:
    /// `k` is the row-major 3 x 3 intrinsic matrix of the raw images, pixels).
    CameraInfo = "sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
         float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
         uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n";
    /// Capture time and camera frame id.
    header: Header,
    /// Rows of the images.
    height: u32,
    /// Columns of the images.
    width: u32,
    /// `plumb_bob`, `rational_polynomial`, ... (empty: none).
    distortion_model: String,
    /// Distortion coefficients.
    d: Vec<f64>,
    /// Intrinsics `[fx, 0, cx, 0, fy, cy, 0, 0, 1]`.
    k: [f64; 9],
    /// Rectification rotation.
    r: [f64; 9],
    /// Projection matrix of the rectified images, 3 x 4.
    p: [f64; 12],
    /// Horizontal binning.
    binning_x: u32,
    /// Vertical binning.
    binning_y: u32,
    /// Region of interest.
    roi: RegionOfInterest,
}
