//! The geometry and scores of one frame of heat maps, as every layer sees them: the
//! [`CropBox`] the maps were computed in, the [`PixelMap`] from a map's cells to image
//! pixels, and the [`Scores`] themselves, borrowed where they arrived.
//!
//! Pixel convention everywhere: pixel (row r, col c) is centred at x = c, y = r (x right,
//! y down), in heat maps and in images alike. A crop box `(x0, y0, width, height)` covers
//! image pixels `x0 .. x0 + width - 1` and `y0 .. y0 + height - 1`; a heat map of
//! `w x h` cells spread over it maps cell centre `x` to `x0 + (x + 0.5) width / w - 0.5`,
//! so each cell's centre lands on the centre of the image pixels it covers.

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

    /// This box moved as `from` moved to `to` (by the move of their centres; its size
    /// kept): a crop carried with the person it was made for.
    pub fn moved_as(&self, from: &CropBox, to: &CropBox) -> Self {
        let dx = (to.x0 + 0.5 * to.width) - (from.x0 + 0.5 * from.width);
        let dy = (to.y0 + 0.5 * to.height) - (from.y0 + 0.5 * from.height);
        Self {
            x0: self.x0 + dx,
            y0: self.y0 + dy,
            ..*self
        }
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

/// A frame's scores as they came, borrowed: f32, or u8 with a scale (`q x scale`). The
/// window dequantises them (and clips negatives) once, into its ring.
#[derive(Debug, Clone, Copy)]
pub enum Scores<'a> {
    /// Scores as f32.
    F32(&'a [f32]),
    /// Scores quantised to u8: each is `q x scale`.
    U8 {
        /// The quantised scores.
        values: &'a [u8],
        /// The score of q = 1 (finite and positive, or the frame is refused).
        scale: f32,
    },
}

impl Scores<'_> {
    /// How many scores.
    pub fn len(&self) -> usize {
        match self {
            Self::F32(v) => v.len(),
            Self::U8 { values, .. } => values.len(),
        }
    }

    /// True without scores.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Writes the scores as f32 into `out` (as long as they are), negatives clipped to 0.
    pub fn clipped_into(&self, out: &mut [f32]) {
        match *self {
            Self::F32(v) => {
                for (d, v) in out.iter_mut().zip(v) {
                    *d = v.max(0.0);
                }
            }
            Self::U8 { values, scale } => {
                for (d, &q) in out.iter_mut().zip(values) {
                    *d = (f32::from(q) * scale).max(0.0);
                }
            }
        }
    }
}

impl<'a> From<&'a [f32]> for Scores<'a> {
    fn from(v: &'a [f32]) -> Self {
        Self::F32(v)
    }
}

impl<'a> From<&'a Vec<f32>> for Scores<'a> {
    fn from(v: &'a Vec<f32>) -> Self {
        Self::F32(v)
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
    fn boxes_without_size_or_finite_values_are_refused() {
        assert!(CropBox::new(0.0, 0.0, 0.0, 10.0).is_err());
        assert!(CropBox::new(f64::NAN, 0.0, 10.0, 10.0).is_err());
        assert!(CropBox::new(0.0, 2e7, 10.0, 10.0).is_err());
    }

    #[test]
    fn u8_scores_are_dequantised_and_negatives_clipped() {
        let mut out = [0.0_f32; 3];
        Scores::U8 {
            values: &[0, 2, 255],
            scale: 0.5,
        }
        .clipped_into(&mut out);
        assert_eq!(out, [0.0, 1.0, 127.5]);
        Scores::F32(&[-1.0, 0.25, 3.0]).clipped_into(&mut out);
        assert_eq!(out, [0.0, 0.25, 3.0]);
    }

    #[test]
    fn a_box_moves_as_another_moved_and_keeps_its_size() {
        let crop = CropBox::new(10.0, 20.0, 100.0, 100.0).unwrap();
        let from = CropBox::new(30.0, 40.0, 50.0, 60.0).unwrap();
        let to = CropBox::new(35.0, 38.0, 70.0, 60.0).unwrap();
        // Centres (55, 70) -> (70, 68).
        assert_eq!(
            crop.moved_as(&from, &to),
            CropBox::new(25.0, 18.0, 100.0, 100.0).unwrap()
        );
        assert_eq!(crop.moved_as(&from, &from), crop);
    }
}
