//! What the service accepts from outside at most (`[limits]` in the configuration).
//!
//! Every size that a peer or a file declares (a frame's joints, rows and columns, a
//! record's length, an image's width and height) is checked against these limits, with
//! checked arithmetic, before anything of that size is allocated. A frame beyond them is
//! refused and counted and the stream goes on; a file record beyond them ends reading with
//! one error, keeping everything before it. docs/limits.md ("Size limits") lists
//! the defaults and what each costs.

use serde::{Deserialize, Serialize};

use posestream_base::{OutOfDomain, check_range};

/// `[limits]`: the largest inputs the service takes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Joints (maps) of one heat-map frame at most.
    pub max_joints: usize,
    /// Rows, and columns, of one heat map at most.
    pub max_map_size: usize,
    /// Bytes of one frame's scores as f32 (`joints x rows x columns x 4`) at most; the
    /// estimator keeps `window.size` such frames per track.
    pub max_message_bytes: usize,
    /// Bytes of one record of a recording at most: a message, or a chunk of messages
    /// (compressed and decompressed). A longer record ends reading with an error.
    pub max_record_bytes: usize,
    /// Pixels (width x height) of one camera image at most.
    pub max_image_pixels: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_joints: 64,
            max_map_size: 128,
            max_message_bytes: 8 << 20,
            max_record_bytes: 64 << 20,
            max_image_pixels: 4096 * 4096,
        }
    }
}

/// A declared size beyond the [`Limits`] (or beyond what the machine can count).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{what} is beyond the limit ({limit}; see [limits] in the configuration)")]
pub struct LimitError {
    /// What was declared (`17 x 2048 x 2048 maps`).
    pub what: String,
    /// The limit it exceeds.
    pub limit: String,
}

impl Limits {
    /// Checks every value is in its domain; the error names the key (`[limits]`).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_range("max_joints", self.max_joints, 1, 1024)?;
        check_range("max_map_size", self.max_map_size, 1, 4096)?;
        check_range(
            "max_message_bytes",
            self.max_message_bytes,
            1 << 10,
            1 << 30,
        )?;
        check_range("max_record_bytes", self.max_record_bytes, 64 << 10, 1 << 32)?;
        check_range("max_image_pixels", self.max_image_pixels, 1, 1 << 28)?;
        Ok(())
    }

    /// The number of scores of `joints` maps of `height x width`, if every size is within
    /// the limits (checked arithmetic: a product that overflows is beyond them too).
    pub fn heatmap_values(
        &self,
        joints: u64,
        height: u64,
        width: u64,
    ) -> Result<usize, LimitError> {
        let beyond = |limit: String| LimitError {
            what: format!("{joints} x {height} x {width} maps"),
            limit,
        };
        if joints > self.max_joints as u64 {
            return Err(beyond(format!("at most {} joints", self.max_joints)));
        }
        let side = self.max_map_size as u64;
        if height > side || width > side {
            return Err(beyond(format!("maps of at most {side} x {side}")));
        }
        let bytes_limit = || beyond(format!("at most {} bytes", self.max_message_bytes));
        let n = joints
            .checked_mul(height)
            .and_then(|n| n.checked_mul(width))
            .ok_or_else(bytes_limit)?;
        match n.checked_mul(4) {
            Some(bytes) if bytes <= self.max_message_bytes as u64 => {
                usize::try_from(n).map_err(|_| bytes_limit())
            }
            _ => Err(bytes_limit()),
        }
    }

    /// Checks an image of `width x height` pixels.
    pub fn image(&self, width: u64, height: u64) -> Result<(), LimitError> {
        match width.checked_mul(height) {
            Some(n) if n <= self.max_image_pixels => Ok(()),
            _ => Err(LimitError {
                what: format!("a {width} x {height} image"),
                limit: format!("at most {} pixels", self.max_image_pixels),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_inside_their_domains() {
        Limits::default().check().expect("valid");
    }

    #[test]
    fn sizes_whose_product_wraps_around_are_beyond_the_limits() {
        let mut l = Limits {
            max_map_size: 4096,
            max_joints: 1024,
            max_message_bytes: 1 << 30,
            ..Limits::default()
        };
        // 17 x 3537046315 x 4294949781 wraps to 96631 in 64 bits.
        assert!(l.heatmap_values(17, 3_537_046_315, 4_294_949_781).is_err());
        assert_eq!(l.heatmap_values(17, 64, 64), Ok(17 * 64 * 64));
        l.max_message_bytes = 17 * 64 * 64 * 4 - 1;
        assert!(l.heatmap_values(17, 64, 64).is_err());
        assert!(l.image(u64::MAX, 2).is_err());
        assert!(Limits::default().image(640, 480).is_ok());
    }
}
