//! `posestream_msgs/HeatMaps`: one frame of per-joint heat maps.

use super::{DecodeError, Header, Time};
use crate::ros_message;
use posestream_base::CropBox;
use posestream_base::Scores;

/// How the scores of a [`HeatMaps`] message are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeatMapEncoding {
    /// `values`, one f32 per score.
    Float32,
    /// `quantized_values`, one u8 per score, times `quantization_scale`.
    Uint8,
}

impl HeatMapEncoding {
    /// The wire value (`ENCODING_*` in the `.msg`).
    pub fn code(self) -> u8 {
        match self {
            Self::Float32 => 0,
            Self::Uint8 => 1,
        }
    }

    /// The encoding of a wire value, if it is one.
    pub fn from_code(code: u8) -> Option<Self> {
        [Self::Float32, Self::Uint8]
            .into_iter()
            .find(|e| e.code() == code)
    }
}

ros_message! {
    /// One frame of per-joint heat maps (`msgs/msg/HeatMaps.msg` documents each field).
    HeatMaps = "posestream_msgs/msg/HeatMaps", "posestream_msgs/HeatMaps",
        include_str!("../../../msgs/msg/HeatMaps.msg"), added_tail = 4;
    /// Capture time and camera frame id.
    header: Header,
    /// The detector's frame number.
    sequence: u64,
    /// The person tracked, from 1; 0: unknown (the estimator gives the person an id).
    track_id: u32,
    /// Joint of each map.
    joint_names: Vec<String>,
    /// Map rows.
    height: u32,
    /// Map columns.
    width: u32,
    /// Crop box, image pixels: left.
    crop_x: f64,
    /// Crop box: top.
    crop_y: f64,
    /// Crop box: width.
    crop_width: f64,
    /// Crop box: height.
    crop_height: f64,
    /// `ENCODING_FLOAT32` (0) or `ENCODING_UINT8` (1).
    encoding: u8,
    /// Scores (float32 encoding).
    values: Vec<f32>,
    /// Quantised scores (uint8 encoding). Read and written as one block of bytes
    /// (`serde_bytes`), not byte by byte; on the wire it is the same `uint8[]`.
    #[serde(with = "serde_bytes")]
    quantized_values: Vec<u8>,
    /// Score per quantisation step (uint8 encoding).
    quantization_scale: f32,
    /// 0: looked at in this image; n: the maps of the look n images before, moved to
    /// the box expected now. Absent (older recordings): 0 (`added_tail`).
    frames_since_look: u32,
}

impl HeatMaps {
    /// A message holding `values` (joint-major, row-major maps), stored as `encoding`
    /// (uint8 maps each score to the nearest of 256 steps up to the frame's largest).
    pub fn from_values(
        header: Header,
        sequence: u64,
        joint_names: Vec<String>,
        height: u32,
        width: u32,
        crop: CropBox,
        values: &[f32],
        encoding: HeatMapEncoding,
    ) -> Self {
        let mut msg = Self {
            header,
            sequence,
            joint_names,
            height,
            width,
            crop_x: crop.x0,
            crop_y: crop.y0,
            crop_width: crop.width,
            crop_height: crop.height,
            encoding: encoding.code(),
            ..Self::default()
        };
        match encoding {
            HeatMapEncoding::Float32 => msg.values = values.to_vec(),
            HeatMapEncoding::Uint8 => {
                let max = values.iter().cloned().fold(0.0_f32, f32::max);
                let scale = if max > 0.0 { max / 255.0 } else { 1.0 };
                msg.quantization_scale = scale;
                msg.quantized_values = values
                    .iter()
                    .map(|v| (v.max(0.0) / scale).round().min(255.0) as u8)
                    .collect();
            }
        }
        msg
    }

    /// The message as a borrowed frame (what the estimator node reads).
    pub fn view(&self) -> HeatMapsView<'_> {
        HeatMapsView {
            stamp_ns: self.header.stamp.nanos(),
            frame_id: &self.header.frame_id,
            sequence: self.sequence,
            track_id: self.track_id,
            joint_names: &self.joint_names,
            height: self.height,
            width: self.width,
            crop: [self.crop_x, self.crop_y, self.crop_width, self.crop_height],
            encoding: self.encoding,
            values: &self.values,
            quantized_values: &self.quantized_values,
            quantization_scale: self.quantization_scale,
            frames_since_look: self.frames_since_look,
        }
    }

    /// The crop box.
    pub fn crop(&self) -> Result<CropBox, DecodeError> {
        self.view().crop()
    }

    /// Checks the sizes and writes the scores as f32 into `out` (resized).
    pub fn values_into(&self, out: &mut Vec<f32>) -> Result<(), DecodeError> {
        let scores = self.scores()?;
        out.clear();
        match scores {
            Scores::F32(v) => out.extend_from_slice(v),
            Scores::U8 { values, scale } => {
                out.extend(values.iter().map(|&q| f32::from(q) * scale));
            }
        }
        Ok(())
    }

    /// Checks the sizes (and a u8 frame's scale) and lends out the scores as they are
    /// in the message, without copying them.
    pub fn scores(&self) -> Result<Scores<'_>, DecodeError> {
        self.view().scores()
    }
}

/// One frame of heat maps, borrowed from where it arrived: a decoded [`HeatMaps`]
/// message ([`HeatMaps::view`]) or a transport's buffer (an iceoryx2 sample), so that
/// the estimator node reads the scores where they are. The fields are the message's,
/// unchecked: [`HeatMapsView::crop`] and [`HeatMapsView::scores`] check them.
#[derive(Debug, Clone, Copy)]
pub struct HeatMapsView<'a> {
    /// Capture time, nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// Camera frame id.
    pub frame_id: &'a str,
    /// The detector's frame number.
    pub sequence: u64,
    /// The person tracked.
    pub track_id: u32,
    /// Joint of each map.
    pub joint_names: &'a [String],
    /// Map rows.
    pub height: u32,
    /// Map columns.
    pub width: u32,
    /// Crop box, image pixels: left, top, width, height.
    pub crop: [f64; 4],
    /// `ENCODING_FLOAT32` (0) or `ENCODING_UINT8` (1).
    pub encoding: u8,
    /// Scores (float32 encoding).
    pub values: &'a [f32],
    /// Quantised scores (uint8 encoding).
    pub quantized_values: &'a [u8],
    /// Score per quantisation step (uint8 encoding).
    pub quantization_scale: f32,
    /// 0: looked at in this image; n: carried over from the look n images before.
    pub frames_since_look: u32,
}

impl<'a> HeatMapsView<'a> {
    /// The crop box.
    pub fn crop(&self) -> Result<CropBox, DecodeError> {
        let [x, y, w, h] = self.crop;
        CropBox::new(x, y, w, h).map_err(|reason| self.invalid(reason))
    }

    /// Checks the sizes (and a u8 frame's scale) and lends out the scores.
    pub fn scores(&self) -> Result<Scores<'a>, DecodeError> {
        let n = (self.joint_names.len() as u64)
            .checked_mul(u64::from(self.height))
            .and_then(|n| n.checked_mul(u64::from(self.width)))
            .and_then(|n| usize::try_from(n).ok())
            .ok_or_else(|| {
                self.invalid(format!(
                    "{} joints x {} x {} overflows",
                    self.joint_names.len(),
                    self.height,
                    self.width
                ))
            })?;
        if n == 0 {
            return Err(self.invalid("no joints or empty maps".into()));
        }
        let encoding = HeatMapEncoding::from_code(self.encoding)
            .ok_or_else(|| self.invalid(format!("unknown encoding {}", self.encoding)))?;
        let found = match encoding {
            HeatMapEncoding::Float32 => self.values.len(),
            HeatMapEncoding::Uint8 => self.quantized_values.len(),
        };
        if found != n {
            return Err(self.invalid(format!(
                "{found} values for {} joints x {} x {}",
                self.joint_names.len(),
                self.height,
                self.width
            )));
        }
        Ok(match encoding {
            HeatMapEncoding::Float32 => Scores::F32(self.values),
            HeatMapEncoding::Uint8 => {
                let s = self.quantization_scale;
                if !(s.is_finite() && s > 0.0) {
                    return Err(self.invalid(format!("quantization scale {s}")));
                }
                Scores::U8 {
                    values: self.quantized_values,
                    scale: s,
                }
            }
        })
    }

    /// The frame as an owned message (a copy).
    pub fn to_message(&self) -> HeatMaps {
        HeatMaps {
            header: Header {
                stamp: Time::from_nanos(self.stamp_ns),
                frame_id: self.frame_id.to_owned(),
            },
            sequence: self.sequence,
            track_id: self.track_id,
            joint_names: self.joint_names.to_vec(),
            height: self.height,
            width: self.width,
            crop_x: self.crop[0],
            crop_y: self.crop[1],
            crop_width: self.crop[2],
            crop_height: self.crop[3],
            encoding: self.encoding,
            values: self.values.to_vec(),
            quantized_values: self.quantized_values.to_vec(),
            quantization_scale: self.quantization_scale,
            frames_since_look: self.frames_since_look,
        }
    }

    fn invalid(&self, reason: String) -> DecodeError {
        DecodeError::Invalid {
            message: "posestream_msgs/msg/HeatMaps",
            reason: format!("frame {}: {reason}", self.sequence),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{decode, decode_into, encode};

    fn frame(sequence: u64, joints: usize, side: u32, encoding: HeatMapEncoding) -> HeatMaps {
        let values: Vec<f32> = (0..joints * (side * side) as usize)
            .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
            .collect();
        HeatMaps::from_values(
            Header {
                stamp: Time::from_nanos(sequence as i64 * 33_333_333),
                frame_id: format!("camera_{sequence}"),
            },
            sequence,
            (0..joints).map(|j| format!("joint-{j}")).collect(),
            side,
            side,
            CropBox::new(10.0, 20.0, 64.0, 64.0).expect("crop"),
            &values,
            encoding,
        )
    }

    #[test]
    fn a_frame_decoded_over_another_is_the_frame_and_keeps_its_buffers() {
        for encoding in [HeatMapEncoding::Float32, HeatMapEncoding::Uint8] {
            let mut place = frame(1, 17, 16, encoding);
            let capacity = (place.values.capacity(), place.joint_names[3].capacity());
            // Smaller, then larger, then of the same size as the first.
            for next in [frame(2, 5, 8, encoding), frame(3, 17, 16, encoding)] {
                let bytes = encode(&next).expect("encodes");
                decode_into(&bytes, &mut place).expect("decodes");
                assert_eq!(place, next);
                assert_eq!(place, decode::<HeatMaps>(&bytes).expect("decodes"));
            }
            if encoding == HeatMapEncoding::Float32 {
                assert_eq!(
                    (place.values.capacity(), place.joint_names[3].capacity()),
                    capacity,
                    "the buffers were reused"
                );
            }
        }
    }

    #[test]
    fn a_frame_that_does_not_decode_is_an_error_over_another_too() {
        let mut place = frame(1, 3, 4, HeatMapEncoding::Float32);
        let bytes = encode(&frame(2, 3, 4, HeatMapEncoding::Float32)).expect("encodes");
        assert!(decode_into(&bytes[..bytes.len() / 2], &mut place).is_err());
        assert!(decode_into(&[9, 9, 9, 9, 0, 0], &mut place).is_err());
    }
}
