//! Camera frames from `sensor_msgs/Image` and `sensor_msgs/CompressedImage` messages,
//! whatever transport brings them (a ROS 2 topic, a recording): [`DecodedImages`]
//! wraps a message source. Undecodable messages are reported as malformed and skipped.

use std::time::Duration;

use super::ImageFrame;
use posestream_base::{Received, Source, TransportError};
use posestream_msgs::limits::Limits;
use posestream_msgs::{CompressedImage, Header, Image};

/// An 8-bit RGB image from a `sensor_msgs/Image` (`rgb8`, `bgr8`, `rgba8`, `bgra8`,
/// `mono8`). The message's width, height and row step are checked (checked arithmetic,
/// [`Limits::image`]) against its data before anything is allocated.
pub fn decode_image(msg: &Image, limits: &Limits) -> Result<image::RgbImage, String> {
    let channels = match msg.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" | "8UC1" => 1,
        other => {
            return Err(format!(
                "image encoding `{other}` is not read (8-bit RGB, BGR, RGBA, BGRA or mono)"
            ));
        }
    };
    let (w, h, step) = (msg.width as usize, msg.height as usize, msg.step as usize);
    if w == 0 || h == 0 {
        return Err(format!("empty image ({w} x {h})"));
    }
    limits
        .image(u64::from(msg.width), u64::from(msg.height))
        .map_err(|e| e.to_string())?;
    let row = w.checked_mul(channels);
    let needed = row.and_then(|row| step.checked_mul(h - 1)?.checked_add(row));
    match (row, needed) {
        (Some(row), Some(needed)) if step >= row && msg.data.len() >= needed => {}
        _ => {
            return Err(format!(
                "{} bytes for {w} x {h} {} with rows of {step} bytes",
                msg.data.len(),
                msg.encoding
            ));
        }
    }
    let bgr = msg.encoding.starts_with("bgr");
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in msg.data.chunks(step).take(h) {
        for px in row[..w * channels].chunks_exact(channels) {
            match (channels, bgr) {
                (1, _) => rgb.extend_from_slice(&[px[0]; 3]),
                (_, true) => rgb.extend_from_slice(&[px[2], px[1], px[0]]),
                (_, false) => rgb.extend_from_slice(&px[..3]),
            }
        }
    }
    image::RgbImage::from_raw(msg.width, msg.height, rgb).ok_or_else(|| "image size".into())
}

/// An 8-bit RGB image from a `sensor_msgs/CompressedImage` (JPEG or PNG; the format
/// is read from the bytes), within `limits`.
pub fn decode_compressed(
    msg: &CompressedImage,
    limits: &Limits,
) -> Result<image::RgbImage, String> {
    super::decode_bytes(&msg.data, limits)
        .map_err(|e| format!("compressed image (`{}`): {e}", msg.format))
}

/// A message that carries one camera frame.
pub trait CameraMessage: Send + 'static {
    /// Its header.
    fn header(&self) -> &Header;
    /// Its pixels.
    fn decode(&self, limits: &Limits) -> Result<image::RgbImage, String>;
}

impl CameraMessage for Image {
    fn header(&self) -> &Header {
        &self.header
    }
    fn decode(&self, limits: &Limits) -> Result<image::RgbImage, String> {
        decode_image(self, limits)
    }
}

impl CameraMessage for CompressedImage {
    fn header(&self) -> &Header {
        &self.header
    }
    fn decode(&self, limits: &Limits) -> Result<image::RgbImage, String> {
        decode_compressed(self, limits)
    }
}

/// Frames decoded from the camera messages `M` of `source`, numbered in arrival order.
pub struct DecodedImages<M, S> {
    source: S,
    topic: String,
    limits: Limits,
    next: u64,
    _message: std::marker::PhantomData<fn() -> M>,
}

impl<M, S> DecodedImages<M, S> {
    /// Wraps `source` (reading `topic`, named in errors); images beyond `limits` are
    /// refused as malformed.
    pub fn new(source: S, topic: &str, limits: &Limits) -> Self {
        Self {
            source,
            topic: topic.to_string(),
            limits: limits.clone(),
            next: 0,
            _message: std::marker::PhantomData,
        }
    }
}

impl<M: CameraMessage, S: Source<M>> Source<ImageFrame> for DecodedImages<M, S> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<ImageFrame>, TransportError> {
        let (msg, stamp) = match self.source.recv(timeout)? {
            Received::Message(m, stamp) => (m, stamp),
            Received::Idle => return Ok(Received::Idle),
            Received::Closed => return Ok(Received::Closed),
        };
        let index = self.next;
        self.next += 1;
        let rgb = msg
            .decode(&self.limits)
            .map_err(|reason| TransportError::Malformed {
                transport: "images",
                topic: self.topic.clone(),
                reason,
            })?;
        let header = msg.header();
        let stamp_ns = u64::try_from(header.stamp.nanos()).unwrap_or(stamp);
        Ok(Received::Message(
            ImageFrame {
                sequence: index,
                stamp_ns,
                frame_id: header.frame_id.clone(),
                name: format!("{} #{index}", self.topic),
                rgb,
            },
            stamp_ns,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(encoding: &str, channels: usize, pad: usize) -> Image {
        let (w, h) = (2_usize, 2_usize);
        let step = w * channels + pad;
        let mut data = vec![0_u8; step * h];
        for y in 0..h {
            for x in 0..w {
                for c in 0..channels {
                    data[y * step + x * channels + c] = (10 * (y * w + x) + c) as u8;
                }
            }
        }
        Image {
            height: h as u32,
            width: w as u32,
            encoding: encoding.into(),
            step: step as u32,
            data,
            ..Default::default()
        }
    }

    #[test]
    fn raw_encodings_become_rgb_with_row_padding_skipped() {
        let rgb = decode_image(&image("rgb8", 3, 2), &Limits::default()).expect("rgb8");
        assert_eq!(rgb.get_pixel(1, 1).0, [30, 31, 32]);
        let bgr = decode_image(&image("bgr8", 3, 0), &Limits::default()).expect("bgr8");
        assert_eq!(bgr.get_pixel(1, 0).0, [12, 11, 10]);
        let bgra = decode_image(&image("bgra8", 4, 0), &Limits::default()).expect("bgra8");
        assert_eq!(bgra.get_pixel(0, 1).0, [22, 21, 20]);
        let mono = decode_image(&image("mono8", 1, 1), &Limits::default()).expect("mono8");
        assert_eq!(mono.get_pixel(1, 1).0, [30, 30, 30]);
    }

    #[test]
    fn unknown_encodings_and_short_data_are_errors() {
        assert!(decode_image(&image("16UC1", 2, 0), &Limits::default()).is_err());
        let mut short = image("rgb8", 3, 0);
        short.data.pop();
        assert!(
            decode_image(&short, &Limits::default())
                .expect_err("short")
                .contains("bytes")
        );
        let bad = CompressedImage {
            format: "jpeg".into(),
            data: b"no".to_vec(),
            ..Default::default()
        };
        assert!(decode_compressed(&bad, &Limits::default()).is_err());
    }

    #[test]
    fn compressed_png_decodes() {
        let mut png = Vec::new();
        image::RgbImage::from_pixel(3, 2, image::Rgb([1, 2, 3]))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        let msg = CompressedImage {
            format: "png".into(),
            data: png,
            ..Default::default()
        };
        let rgb = decode_compressed(&msg, &Limits::default()).expect("png");
        assert_eq!(
            (rgb.dimensions(), rgb.get_pixel(2, 1).0),
            ((3, 2), [1, 2, 3])
        );
    }
}
