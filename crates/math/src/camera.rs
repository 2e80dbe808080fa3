//! The pinhole camera of the perspective adjustment: [`Intrinsics`]. (The crop a heat map
//! was computed in and the map from its cells to image pixels are the foundation's:
//! [`posestream_base::CropBox`], [`posestream_base::PixelMap`], with the pixel
//! convention every layer shares.)

use nalgebra::Vector3;

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_projected_and_its_ray_agree() {
        let a = Intrinsics::new(800.0, 810.0, 320.0, 240.0).expect("valid");
        let p = Vector3::new(0.3, -0.2, 2.0);
        let [u, v] = a.project(&p);
        let r = a.ray(u, v) * p.z;
        assert!((r - p).norm() < 1e-12);
        assert!(Intrinsics::new(-1.0, 800.0, 0.0, 0.0).is_err());
    }
}
