//! `posestream_msgs/HeatMaps`: one frame of per-joint heat maps.

use super::{DecodeError, Header};
use crate::ros_message;
use posestream_math::camera::CropBox;
use posestream_math::streaming::Scores;

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
        include_str!("../../../msgs/msg/HeatMaps.msg");
    /// Capture time and camera frame id.
    header: Header,
    /// The detector's frame number.
    sequence: u64,
    /// The person tracked.
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

    /// The crop box.
    pub fn crop(&self) -> Result<CropBox, DecodeError> {
        CropBox::new(self.crop_x, self.crop_y, self.crop_width, self.crop_height)
            .map_err(|reason| self.invalid(reason))
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
            HeatMapEncoding::Float32 => Scores::F32(&self.values),
            HeatMapEncoding::Uint8 => {
                let s = self.quantization_scale;
                if !(s.is_finite() && s > 0.0) {
                    return Err(self.invalid(format!("quantization scale {s}")));
                }
                Scores::U8 {
                    values: &self.quantized_values,
                    scale: s,
                }
            }
        })
    }

    fn invalid(&self, reason: String) -> DecodeError {
        DecodeError::Invalid {
            message: "posestream_msgs/msg/HeatMaps",
            reason: format!("frame {}: {reason}", self.sequence),
        }
    }
}
