//! The pinhole camera of the perspective adjustment: [`Intrinsics`], the square crop
//! [`CropBox`] a heat map was computed in, and the [`PixelMap`] from a 2D input's pixels
//! to image pixels.
//!
//! Pixel convention everywhere: pixel (row r, col c) is centred at x = c, y = r (x right,
//! y down), in heat maps and in images alike. A crop box `(x0, y0, width, height)` covers
//! image pixels `x0 .. x0 + width - 1` and `y0 .. y0 + height - 1`; a heat map of
//! `w x h` cells spread over it maps cell centre `x` to `x0 + (x + 0.5) width / w - 0.5`,
//! so each cell's centre lands on the centre of the image pixels it covers.

use std::path::Path;

use nalgebra::Vector3;
use serde::Deserialize;

use crate::error::CameraError;

/// Pinhole intrinsics in pixels: `u = fx X / Z + cx`, `v = fy Y / Z + cy` in the camera
/// frame (x right, y down, z forward).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

/// The JSON forms [`Intrinsics::load`] accepts.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum IntrinsicsFile {
    /// `{"fx": 1000, "fy": 1000, "cx": 640, "cy": 360}`.
    Named(NamedIntrinsics),
    /// `{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}` (a row-major 3 x 3 matrix).
    Matrix(MatrixIntrinsics),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NamedIntrinsics {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MatrixIntrinsics {
    #[serde(rename = "K")]
    k: Vec<Vec<f64>>,
}

impl Intrinsics {
    /// Checks the values: finite, focal lengths in `[1, 1e7]` pixels and a principal
    /// point within 1e7 pixels of the origin (as crop boxes are): beyond them no camera
    /// is described, and metres computed with them would be nonsense.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self, String> {
        if ![fx, fy, cx, cy].iter().all(|v| v.is_finite()) {
            return Err("intrinsics must be finite".into());
        }
        if fx <= 0.0 || fy <= 0.0 {
            return Err(format!("focal lengths must be positive (fx {fx}, fy {fy})"));
        }
        if !(1.0..=1e7).contains(&fx) || !(1.0..=1e7).contains(&fy) {
            return Err(format!(
                "focal lengths must be 1 to 1e7 pixels (fx {fx}, fy {fy})"
            ));
        }
        if cx.abs() > 1e7 || cy.abs() > 1e7 {
            return Err(format!(
                "the principal point must be within 1e7 pixels (cx {cx}, cy {cy})"
            ));
        }
        Ok(Self { fx, fy, cx, cy })
    }

    /// Parses JSON: either `{"fx", "fy", "cx", "cy"}` or `{"K": 3 x 3 rows}` with zero
    /// skew and a last row `[0, 0, 1]`.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let file: IntrinsicsFile = serde_json::from_str(text).map_err(|_| {
            "expected {\"fx\", \"fy\", \"cx\", \"cy\"} or {\"K\": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}"
                .to_string()
        })?;
        match file {
            IntrinsicsFile::Named(n) => Self::new(n.fx, n.fy, n.cx, n.cy),
            IntrinsicsFile::Matrix(m) => {
                if m.k.len() != 3 || m.k.iter().any(|row| row.len() != 3) {
                    return Err("K must be 3 rows of 3 numbers".into());
                }
                let k = &m.k;
                if k[0][1] != 0.0 || k[1][0] != 0.0 || k[2] != [0.0, 0.0, 1.0] {
                    return Err(
                        "K must have zero skew and last row [0, 0, 1] (a pinhole camera)".into(),
                    );
                }
                Self::new(k[0][0], k[1][1], k[0][2], k[1][2])
            }
        }
    }

    /// Reads a JSON file (see [`Intrinsics::from_json`]).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CameraError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| CameraError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text).map_err(|detail| CameraError::Invalid {
            path: path.to_path_buf(),
            detail,
        })
    }

    /// The ray through image point `(u, v)`, scaled to depth 1: `(x, y, 1)`.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// The image of camera-frame point `p` (`p.z > 0`).
    pub fn project(&self, p: &Vector3<f64>) -> [f64; 2] {
        [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy]
    }

    /// The mean focal length.
    pub fn focal(&self) -> f64 {
        0.5 * (self.fx + self.fy)
    }
}

/// The crop a heat map was computed in: top-left pixel and size, image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CropBox {
    /// Left column.
    pub x0: f64,
    /// Top row.
    pub y0: f64,
    /// Width, pixels (> 0).
    pub width: f64,
    /// Height, pixels (> 0).
    pub height: f64,
}

impl CropBox {
    /// Coordinates and sizes allowed at most, in pixels: far beyond any camera, small
    /// enough that every pixel position computed from a box stays finite.
    pub const MAX_PIXELS: f64 = 1e7;

    /// Checks the values: finite, within [`Self::MAX_PIXELS`], positive size.
    pub fn new(x0: f64, y0: f64, width: f64, height: f64) -> Result<Self, String> {
        if ![x0, y0, width, height].iter().all(|v| v.is_finite()) {
            return Err("box values must be finite".into());
        }
        if ![x0, y0, width, height]
            .iter()
            .all(|v| v.abs() <= Self::MAX_PIXELS)
        {
            return Err(format!(
                "box values must be within {:e} pixels (x {x0}, y {y0}, width {width}, height {height})",
                Self::MAX_PIXELS
            ));
        }
        if width <= 0.0 || height <= 0.0 {
            return Err(format!(
                "box size must be positive (width {width}, height {height})"
            ));
        }
        Ok(Self {
            x0,
            y0,
            width,
            height,
        })
    }

    /// The map from a `map_width x map_height` heat map spread over this box to image
    /// pixels.
    pub fn pixel_map(&self, map_width: usize, map_height: usize) -> PixelMap {
        let sx = self.width / map_width as f64;
        let sy = self.height / map_height as f64;
        PixelMap {
            scale: [sx, sy],
            offset: [self.x0 + 0.5 * sx - 0.5, self.y0 + 0.5 * sy - 0.5],
        }
    }
}

/// An axis-aligned map `image = offset + scale * input` from input pixels (heat-map cells
/// or keypoint pixels) to image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelMap {
    /// Image pixels per input pixel, x and y.
    pub scale: [f64; 2],
    /// Image position of input pixel (0, 0).
    pub offset: [f64; 2],
}

impl PixelMap {
    /// Input pixels are image pixels.
    pub const IDENTITY: Self = Self {
        scale: [1.0, 1.0],
        offset: [0.0, 0.0],
    };

    /// Image pixels of input point `(x, y)`.
    pub fn apply(&self, x: f64, y: f64) -> [f64; 2] {
        [
            self.offset[0] + self.scale[0] * x,
            self.offset[1] + self.scale[1] * y,
        ]
    }

    /// Image pixels^2 of a variance (trace of a 2D covariance) in input pixels^2, for a
    /// covariance spread evenly over both axes.
    pub fn variance(&self, v: f64) -> f64 {
        v * 0.5 * (self.scale[0] * self.scale[0] + self.scale[1] * self.scale[1])
    }

    /// Mean image pixels per input pixel.
    pub fn mean_scale(&self) -> f64 {
        0.5 * (self.scale[0] + self.scale[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heat_map_cells_land_on_the_centres_of_the_pixels_they_cover() {
        // A 64-cell map over a 256-pixel box at (100, 50): cell c covers pixels
        // 100 + 4c .. 100 + 4c + 3, centre 100 + 4c + 1.5.
        let b = CropBox::new(100.0, 50.0, 256.0, 256.0).expect("valid");
        let m = b.pixel_map(64, 64);
        assert_eq!(m.apply(0.0, 0.0), [101.5, 51.5]);
        assert_eq!(m.apply(63.0, 10.0), [100.0 + 4.0 * 63.0 + 1.5, 50.0 + 41.5]);
        // The outer edges of the map are the outer edges of the box.
        assert_eq!(m.apply(-0.5, -0.5), [99.5, 49.5]);
        assert_eq!(m.apply(63.5, 63.5), [355.5, 305.5]);
        // A box of the map's size is a shift.
        let same = CropBox::new(7.0, 3.0, 64.0, 64.0)
            .expect("valid")
            .pixel_map(64, 64);
        assert_eq!(same.apply(5.0, 6.0), [12.0, 9.0]);
    }

    #[test]
    fn intrinsics_parse_both_forms_and_reject_bad_values() {
        let a = Intrinsics::from_json(r#"{"fx": 800, "fy": 810, "cx": 320, "cy": 240}"#)
            .expect("named");
        let b = Intrinsics::from_json(r#"{"K": [[800, 0, 320], [0, 810, 240], [0, 0, 1]]}"#)
            .expect("matrix");
        assert_eq!(a, b);
        let p = Vector3::new(0.3, -0.2, 2.0);
        let [u, v] = a.project(&p);
        let r = a.ray(u, v) * p.z;
        assert!((r - p).norm() < 1e-12);
        for bad in [
            r#"{"fx": -1, "fy": 800, "cx": 0, "cy": 0}"#,
            r#"{"fx": 800, "fy": 800, "cx": 0}"#,
            r#"{"fx": 800, "fy": 800, "cx": 0, "cy": 0, "skew": 1}"#,
            r#"{"K": [[800, 0, 320], [0, 800, 240]]}"#,
            r#"{"K": [[800, 1, 320], [0, 800, 240], [0, 0, 1]]}"#,
            r#"[1, 2, 3]"#,
        ] {
            assert!(Intrinsics::from_json(bad).is_err(), "{bad}");
        }
        assert!(CropBox::new(0.0, 0.0, 0.0, 10.0).is_err());
        assert!(CropBox::new(f64::NAN, 0.0, 10.0, 10.0).is_err());
    }
}
