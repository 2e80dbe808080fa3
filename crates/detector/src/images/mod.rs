//! Camera frames for the image detector, from any of its sources, as one type
//! ([`ImageFrame`]): every source is a [`Source<ImageFrame>`](posestream_base::Source),
//! so the detector does not know where its frames come from.
//!
//! - [`folder`]: the image files of a folder, in name order;
//! - [`video`]: a video file, decoded by the `ffmpeg` program;
//! - [`messages`]: `sensor_msgs/Image` or `CompressedImage` messages from any transport
//!   (a ROS 2 topic, a recording).

use posestream_msgs::limits::Limits;

pub mod folder;
pub mod messages;
pub mod video;

pub use folder::FolderSource;
pub use messages::{DecodedImages, decode_compressed, decode_image};
pub use video::VideoSource;

/// One camera frame, decoded to 8-bit RGB.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageFrame {
    /// Frame number in the source, from 0.
    pub sequence: u64,
    /// Capture time, nanoseconds (a file source spaces frames by its frame rate).
    pub stamp_ns: u64,
    /// Camera frame id for the messages' headers.
    pub frame_id: String,
    /// Where it came from, for messages (a file name, `frame 12`).
    pub name: String,
    /// The pixels.
    pub rgb: image::RgbImage,
}

/// The error of a file source that cannot start.
pub(crate) fn setup_error(
    transport: &'static str,
    path: &std::path::Path,
    reason: impl Into<String>,
) -> posestream_base::TransportError {
    posestream_base::TransportError::Setup {
        transport,
        what: path.display().to_string(),
        reason: reason.into(),
    }
}

impl ImageFrame {
    /// Frame `index` of a file source running at `fps`, as a received message stamped
    /// with its capture time.
    pub(crate) fn from_file(
        index: u64,
        fps: f64,
        frame_id: &str,
        name: String,
        rgb: image::RgbImage,
    ) -> posestream_base::Received<Self> {
        let stamp_ns = frame_stamp(index, fps);
        let frame = Self {
            sequence: index,
            stamp_ns,
            frame_id: frame_id.to_string(),
            name,
            rgb,
        };
        posestream_base::Received::Message(frame, stamp_ns)
    }
}

/// Decodes an image file's bytes (PNG, JPEG or GIF, the format read from the bytes) to
/// 8-bit RGB. Its size is read from its header first and checked against `limits`
/// ([`Limits::image`]); the decoder itself is held to the same budget. A panic in a
/// decoder (the image crate's) is an undecodable image, not the end of the service:
/// zune-jpeg overflows on a crafted JPEG's DC coefficient, a panic where overflow is
/// checked (`fuzz/regressions/sensor_image`).
pub fn decode_bytes(bytes: &[u8], limits: &Limits) -> Result<image::RgbImage, String> {
    posestream_base::contain_panics(|| decode_within(bytes, limits))
        .map_err(|panic| format!("the image decoder failed: {panic}"))?
}

fn decode_within(bytes: &[u8], limits: &Limits) -> Result<image::RgbImage, String> {
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| e.to_string())
    };
    let (w, h) = reader()?.into_dimensions().map_err(|e| e.to_string())?;
    limits
        .image(u64::from(w), u64::from(h))
        .map_err(|e| e.to_string())?;
    let mut budget = image::Limits::default();
    budget.max_image_width = Some(w);
    budget.max_image_height = Some(h);
    // 16-bit RGBA at most, plus the RGB copy.
    budget.max_alloc = Some(limits.max_image_pixels.saturating_mul(11));
    let mut r = reader()?;
    r.limits(budget);
    Ok(r.decode().map_err(|e| e.to_string())?.to_rgb8())
}

/// The time of frame `index` of a source running at `fps` frames per second.
pub fn frame_stamp(index: u64, fps: f64) -> u64 {
    (index as f64 * 1e9 / fps).round() as u64
}
