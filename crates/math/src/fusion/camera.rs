//! One camera of a rig: its pinhole [`Intrinsics`] and where it stands in the world.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::camera::Intrinsics;

/// A calibrated camera of a rig: intrinsics and the camera frame in the world frame
/// (`world_from_camera`; the camera frame is x right, y down, z forward, as everywhere
/// in posestream).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewCamera {
    /// The pinhole camera, pixels.
    pub intrinsics: Intrinsics,
    /// The camera frame in the world frame.
    pub world_from_camera: Isometry3<f64>,
}

impl ViewCamera {
    /// Checks the values: intrinsics as [`Intrinsics::new`] takes them, a finite pose.
    pub fn check(&self) -> Result<(), String> {
        let k = &self.intrinsics;
        Intrinsics::new(k.fx, k.fy, k.cx, k.cy)?;
        let pose = &self.world_from_camera;
        let finite = pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite());
        if finite {
            Ok(())
        } else {
            Err("the camera's pose must be finite".into())
        }
    }

    /// The camera centre, world frame.
    pub fn centre(&self) -> Vector3<f64> {
        self.world_from_camera.translation.vector
    }

    /// The unit direction of the ray through image pixel `(u, v)`, world frame.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        (self.world_from_camera.rotation * self.intrinsics.ray(u, v)).normalize()
    }

    /// A world point in the camera frame.
    pub fn to_camera(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.world_from_camera
            .inverse_transform_point(&Point3::from(*p))
            .coords
    }

    /// The image of a world point (pixels) and its depth, or `None` when it is not in
    /// front of the camera.
    pub fn project(&self, p: &Vector3<f64>) -> Option<([f64; 2], f64)> {
        let c = self.to_camera(p);
        (c.z > 1e-6).then(|| (self.intrinsics.project(&c), c.z))
    }
}

/// Cameras for tests.
#[cfg(test)]
pub(super) mod test_rigs {
    use super::*;
    use nalgebra::Isometry3;

    /// Cameras on a ring of radius `r` around the origin at 1.5 m, looking at it.
    pub(in crate::fusion) fn ring(n: usize, r: f64) -> Vec<ViewCamera> {
        (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                let eye = Point3::new(r * a.cos(), r * a.sin(), 1.5);
                // Camera frame: z forward, y down (world z up).
                let view = Isometry3::look_at_rh(&eye, &Point3::new(0.0, 0.0, 1.0), &-Vector3::z());
                ViewCamera {
                    intrinsics: Intrinsics::new(800.0, 800.0, 640.0, 360.0).expect("valid"),
                    world_from_camera: view.inverse()
                        * Isometry3::rotation(Vector3::new(0.0, std::f64::consts::PI, 0.0)),
                }
            })
            .collect()
    }
}

#[cfg(test)]
pub(super) use test_rigs::ring;

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn a_projected_point_lies_on_the_ray_of_its_image() {
        let cam = ViewCamera {
            intrinsics: Intrinsics::new(800.0, 800.0, 320.0, 240.0).expect("valid"),
            world_from_camera: Isometry3::from_parts(
                Translation3::new(1.0, -2.0, 1.5),
                UnitQuaternion::from_euler_angles(-1.7, 0.1, 0.4),
            ),
        };
        let p = Vector3::new(2.0, 3.0, 0.9);
        let ([u, v], z) = cam.project(&p).expect("in front");
        let d = cam.ray(u, v);
        let along = d.dot(&(p - cam.centre()));
        assert!((cam.centre() + d * along - p).norm() < 1e-9);
        assert!((cam.to_camera(&p).z - z).abs() < 1e-12);
        // Behind the camera: no image.
        let behind = cam.centre() * 2.0 - p;
        assert!(cam.project(&behind).is_none());
    }
}
