//! [`HeatMapSequence`]: per-frame, per-joint 2D score maps from a detector, F frames of
//! them (the batch estimator's input; the wire message `HeatMaps` holds one frame).
//!
//! Pixel `(row r, col c)` is centred at `x = c, y = r` (x right, y down). Values are
//! scores, not necessarily normalised; negative values are clipped to 0 by the E-step,
//! as in the reference. A map with no positive value locates nothing and is rejected.

use crate::error::EstimateError;

/// Heat maps of F frames x p joints, each h x w, row-major `values[((t*p + j)*h + r)*w + c]`.
#[derive(Debug, Clone, PartialEq)]
pub struct HeatMapSequence {
    /// Frames.
    pub frames: usize,
    /// Joints per frame.
    pub joints: usize,
    /// Map height (rows).
    pub height: usize,
    /// Map width (columns).
    pub width: usize,
    /// The scores.
    pub values: Vec<f32>,
}

impl HeatMapSequence {
    /// Wraps `values`, checking the size, finiteness and that every map has a positive value.
    pub fn new(
        frames: usize,
        joints: usize,
        height: usize,
        width: usize,
        values: Vec<f32>,
    ) -> Result<Self, EstimateError> {
        if frames == 0 {
            return Err(EstimateError::NoFrames);
        }
        let n = height * width;
        if values.len() != frames * joints * n || n == 0 {
            return Err(EstimateError::Parameter(format!(
                "heat maps hold {} values, expected {frames} x {joints} x {height} x {width}",
                values.len()
            )));
        }
        for (m, map) in values.chunks_exact(n).enumerate() {
            let (frame, joint) = (m / joints, m % joints);
            if map.iter().any(|v| !v.is_finite()) {
                return Err(EstimateError::NonFinite { frame, joint });
            }
            if !map.iter().any(|&v| v > 0.0) {
                return Err(EstimateError::EmptyHeatMap { frame, joint });
            }
        }
        Ok(Self {
            frames,
            joints,
            height,
            width,
            values,
        })
    }

    /// Sets negative scores to 0, as the E-step reads them; then the estimator works on
    /// these maps without a clipped copy.
    pub fn clip_negatives(&mut self) {
        self.values.iter_mut().for_each(|v| *v = v.max(0.0));
    }

    /// The map of frame `t`, joint `j` (h*w values, row-major).
    pub fn map(&self, t: usize, j: usize) -> &[f32] {
        let n = self.height * self.width;
        let m = t * self.joints + j;
        &self.values[m * n..(m + 1) * n]
    }

    /// The arg-max pixel `(x, y)` of a map and its value (first maximum in row-major order).
    pub fn argmax(&self, t: usize, j: usize) -> (f64, f64, f32) {
        argmax(self.map(t, j), self.width)
    }
}

/// [`argmax`] refined to a fraction of a cell: the centroid of the positive values of
/// its 3 x 3 neighbourhood (the arg-max itself where they sum to nothing). The value is
/// the arg-max's.
pub fn refined_argmax(map: &[f32], width: usize) -> (f64, f64, f32) {
    if width == 0 || map.is_empty() {
        return (0.0, 0.0, f32::NEG_INFINITY);
    }
    let (x, y, best) = argmax(map, width);
    let height = map.len() / width;
    let (cx, cy) = (x as usize, y as usize);
    let (mut sum, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
    for row in cy.saturating_sub(1)..(cy + 2).min(height) {
        for col in cx.saturating_sub(1)..(cx + 2).min(width) {
            let v = f64::from(map[row * width + col]);
            if v > 0.0 && v.is_finite() {
                sum += v;
                sx += v * col as f64;
                sy += v * row as f64;
            }
        }
    }
    if sum > 0.0 && sum.is_finite() {
        (sx / sum, sy / sum, best)
    } else {
        (x, y, best)
    }
}

/// The arg-max pixel `(x, y)` of one row-major map of `width` columns and its value
/// (first maximum in row-major order).
pub fn argmax(map: &[f32], width: usize) -> (f64, f64, f32) {
    let (mut best, mut at) = (f32::NEG_INFINITY, 0);
    for (i, &v) in map.iter().enumerate() {
        if v > best {
            best = v;
            at = i;
        }
    }
    ((at % width) as f64, (at / width) as f64, best)
}

#[cfg(test)]
mod refined_tests {
    use super::*;

    #[test]
    fn the_refined_peak_lies_between_the_cells_by_their_weights_and_nothing_panics() {
        // 3 x 3 map, peak at (1, 1), its right neighbour half as high.
        let map = [0.0, 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0];
        let (x, y, v) = refined_argmax(&map, 3);
        assert!(
            (x - 4.0 / 3.0).abs() < 1e-12 && (y - 1.0).abs() < 1e-12,
            "{x} {y}"
        );
        assert_eq!(v, 1.0);
        // At an edge, NaN or negative neighbours are left out.
        let edge = [1.0, f32::NAN, -3.0, 0.0];
        assert_eq!(refined_argmax(&edge, 2), (0.0, 0.0, 1.0));
        assert_eq!(refined_argmax(&[], 3).2, f32::NEG_INFINITY);
        assert_eq!(refined_argmax(&map, 0).2, f32::NEG_INFINITY);
    }
}
