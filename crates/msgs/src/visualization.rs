//! `visualization_msgs/MarkerArray` and the standard messages it needs, mirrored from
//! ROS 2 Jazzy's `visualization_msgs`, `geometry_msgs`, `std_msgs`, `sensor_msgs` and
//! `builtin_interfaces` packages (field for field: the CDR layout must match what RViz2
//! and Foxglove decode). Constants and comments of the upstream files are left out.

use super::Header;
pub use super::sensor::CompressedImage;
use crate::ros_message;

ros_message! {
    /// `builtin_interfaces/Duration`.
    Duration = "builtin_interfaces/msg/Duration", "builtin_interfaces/Duration",
        "int32 sec\nuint32 nanosec\n";
    /// Whole seconds.
    sec: i32,
    /// Nanoseconds within the second.
    nanosec: u32,
}

ros_message! {
    /// `geometry_msgs/Point`.
    Point = "geometry_msgs/msg/Point", "geometry_msgs/Point",
        "float64 x\nfloat64 y\nfloat64 z\n";
    /// x.
    x: f64,
    /// y.
    y: f64,
    /// z.
    z: f64,
}

ros_message! {
    /// `geometry_msgs/Quaternion`.
    Quaternion = "geometry_msgs/msg/Quaternion", "geometry_msgs/Quaternion",
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n";
    /// x.
    x: f64,
    /// y.
    y: f64,
    /// z.
    z: f64,
    /// w (1 for the identity).
    w: f64,
}

ros_message! {
    /// `geometry_msgs/Pose`.
    Pose = "geometry_msgs/msg/Pose", "geometry_msgs/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n";
    /// Position.
    position: Point,
    /// Orientation.
    orientation: Quaternion,
}

ros_message! {
    /// `geometry_msgs/Vector3`.
    Vector3 = "geometry_msgs/msg/Vector3", "geometry_msgs/Vector3",
        "float64 x\nfloat64 y\nfloat64 z\n";
    /// x.
    x: f64,
    /// y.
    y: f64,
    /// z.
    z: f64,
}

ros_message! {
    /// `std_msgs/ColorRGBA`, components in [0, 1].
    ColorRGBA = "std_msgs/msg/ColorRGBA", "std_msgs/ColorRGBA",
        "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n";
    /// Red.
    r: f32,
    /// Green.
    g: f32,
    /// Blue.
    b: f32,
    /// Alpha (opacity).
    a: f32,
}

ros_message! {
    /// `visualization_msgs/UVCoordinate`.
    UVCoordinate = "visualization_msgs/msg/UVCoordinate", "visualization_msgs/UVCoordinate",
        "float32 u\nfloat32 v\n";
    /// u.
    u: f32,
    /// v.
    v: f32,
}

ros_message! {
    /// `visualization_msgs/MeshFile`.
    MeshFile = "visualization_msgs/msg/MeshFile", "visualization_msgs/MeshFile",
        "string filename\nuint8[] data\n";
    /// The file name (its extension tells the format).
    filename: String,
    /// The file's bytes.
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
}

ros_message! {
    /// `visualization_msgs/Marker`: one shape for RViz2 / Foxglove.
    Marker = "visualization_msgs/msg/Marker", "visualization_msgs/Marker",
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\n\nint32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\nstd_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\nsensor_msgs/CompressedImage texture\nvisualization_msgs/UVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\nvisualization_msgs/MeshFile mesh_file\nbool mesh_use_embedded_materials\n";
    /// Stamp and frame of the shape.
    header: Header,
    /// Namespace (with `id`, identifies the marker).
    ns: String,
    /// Id within the namespace.
    id: i32,
    /// Shape (`LINE_LIST` = 5, `SPHERE_LIST` = 7, ...).
    r#type: i32,
    /// `ADD` (0), `DELETE` (2), `DELETEALL` (3).
    action: i32,
    /// Pose of the shape's frame.
    pose: Pose,
    /// Size (lines: x is the width; spheres: the diameters).
    scale: Vector3,
    /// Colour.
    color: ColorRGBA,
    /// How long the marker stays (0: until replaced).
    lifetime: Duration,
    /// Follow the frame.
    frame_locked: bool,
    /// Points of list shapes.
    points: Vec<Point>,
    /// Per-point colours (empty: `color`).
    colors: Vec<ColorRGBA>,
    /// Texture (unused).
    texture_resource: String,
    /// Texture (unused).
    texture: CompressedImage,
    /// Texture coordinates (unused).
    uv_coordinates: Vec<UVCoordinate>,
    /// Text of `TEXT_VIEW_FACING`.
    text: String,
    /// Mesh (unused).
    mesh_resource: String,
    /// Mesh (unused).
    mesh_file: MeshFile,
    /// Mesh (unused).
    mesh_use_embedded_materials: bool,
}

ros_message! {
    /// `visualization_msgs/MarkerArray`.
    MarkerArray = "visualization_msgs/msg/MarkerArray", "visualization_msgs/MarkerArray",
        "visualization_msgs/Marker[] markers\n";
    /// The markers.
    markers: Vec<Marker>,
}

ros_message! {
    /// `visualization_msgs/ImageMarker`: a shape drawn over an image, in its pixels (the
    /// Foxglove app's Image panel and `rqt`'s image overlays draw it).
    ImageMarker = "visualization_msgs/msg/ImageMarker", "visualization_msgs/ImageMarker",
        "int32 CIRCLE=0\nint32 LINE_STRIP=1\nint32 LINE_LIST=2\nint32 POLYGON=3\nint32 POINTS=4\n\nint32 ADD=0\nint32 REMOVE=1\n\nstd_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Point position\nfloat32 scale\nstd_msgs/ColorRGBA outline_color\nuint8 filled\nstd_msgs/ColorRGBA fill_color\nbuiltin_interfaces/Duration lifetime\ngeometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] outline_colors\n";
    /// Stamp (the image's) and frame.
    header: Header,
    /// Namespace (with `id`, identifies the marker).
    ns: String,
    /// Id within the namespace.
    id: i32,
    /// Shape (`IMAGE_LINE_LIST` = 2, ...).
    r#type: i32,
    /// `ADD` (0) or `REMOVE` (1).
    action: i32,
    /// Position of a `CIRCLE`, pixels.
    position: Point,
    /// Line width, or a circle's diameter, pixels.
    scale: f32,
    /// Colour of the lines.
    outline_color: ColorRGBA,
    /// Whether to fill the shape (1) or not (0).
    filled: u8,
    /// Fill colour.
    fill_color: ColorRGBA,
    /// How long the marker stays (0: until replaced).
    lifetime: Duration,
    /// Points of lists and strips, pixels (z unused).
    points: Vec<Point>,
    /// Per-point colours (empty: `outline_color`).
    outline_colors: Vec<ColorRGBA>,
}

/// `ImageMarker::type` of a list of line segments.
pub const IMAGE_LINE_LIST: i32 = 2;

/// `Marker::type` of a list of line segments.
pub const LINE_LIST: i32 = 5;
/// `Marker::type` of a list of spheres.
pub const SPHERE_LIST: i32 = 7;
/// `Marker::type` of a text that always faces the viewer.
pub const TEXT_VIEW_FACING: i32 = 9;
/// `Marker::action` that adds or replaces.
pub const ADD: i32 = 0;
