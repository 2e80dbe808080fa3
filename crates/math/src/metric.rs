//! Metres for streamed estimates: the perspective adjustment
//! ([`crate::solver::perspective`], the paper's last stage) of one [`FrameEstimate`] at a
//! time, after the window, and a 3D standard deviation for each joint.
//!
//! The window's estimate of a frame is centred and in the dictionary's units. With the
//! camera's [`Intrinsics`] and the map from the frame's heat-map pixels to image pixels
//! (its crop box), [`MetricStep::adjust`] places the person in the camera frame, in
//! metres: the weak fit scaled so that the skeleton's mean bone length is
//! [`PerspectiveParams::mean_limb_length`], put at the depth where its image has the
//! fitted size, then refined under the pinhole camera (per-joint depths on the rays, a
//! similarity fit whose scale becomes depth, the coefficients against the rays).
//!
//! **Uncertainty** (per axis, metres). Two sources, independent:
//! - the 2D spread of the E-step (`keypoint_std`, image pixels) moved to the joint's
//!   depth: `s_l = z_j s_px / f` on x and y, and the same on z (the depth of a joint
//!   relative to the body is no better known than its image position);
//! - the metric scale: the person's true mean bone length differs from the assumed one
//!   by a relative standard deviation `scale_std`, and a scene scaled about the camera
//!   centre gives the same image, so every joint moves along its ray: `P_j scale_std`
//!   on each axis (`z_j scale_std` in depth: the largest term at a distance).
//!
//! `s_x^2 = s_l^2 + (x_j r)^2`, `s_y^2 = s_l^2 + (y_j r)^2`, `s_z^2 = s_l^2 + (z_j r)^2`
//! with `r = scale_std`. How often the true error lies within 1 and 2 of these is
//! measured on synthetic data (`tests/metric.rs`, docs/metric.md).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera::{Intrinsics, PixelMap};
use crate::dictionary::Dictionary;
use crate::error::{EstimateError, OutOfDomain, check_range, check_real};
use crate::estimator::Estimator;
use crate::solver::perspective::{
    self, PerspectiveFit, PerspectiveParams, PerspectiveWorkspace, start_from_weak_fit,
};
use crate::streaming::FrameEstimate;

/// Settings of the metric step (`[estimator.metric]`). The perspective adjustment's
/// keys are listed here again rather than flattened from [`PerspectiveParams`]: serde
/// cannot refuse unknown keys of a flattened struct ([`MetricSettings::perspective`]
/// gives them back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MetricSettings {
    /// The camera, `[fx, fy, cx, cy]` in pixels of the images the heat maps' crop boxes
    /// are in; empty: no metric step (skeletons in dictionary units).
    pub intrinsics: Vec<f64>,
    /// Mean bone length of the skeleton, metres: sets the metric scale
    /// ([`PerspectiveParams::mean_limb_length`]).
    pub mean_limb_length: f64,
    /// Relative standard deviation of the metric scale: how far a person's mean bone
    /// length may be from `mean_limb_length`, as a fraction (0.1: 10 %).
    pub scale_std: f64,
    /// L1 weight of the perspective C-step ([`PerspectiveParams::alpha`]).
    pub alpha: f64,
    /// Iterations per frame at most ([`PerspectiveParams::max_iterations`]).
    pub max_iterations: usize,
    /// APG steps per C-step ([`PerspectiveParams::apg_steps`]).
    pub apg_steps: usize,
    /// Relative tolerance ([`PerspectiveParams::tolerance`]).
    pub tolerance: f64,
}

impl Default for MetricSettings {
    fn default() -> Self {
        let p = PerspectiveParams::default();
        Self {
            intrinsics: Vec::new(),
            mean_limb_length: p.mean_limb_length,
            scale_std: 0.1,
            alpha: p.alpha,
            // With momentum (`perspective`), 35 matched 100 without it.
            max_iterations: 35,
            apg_steps: p.apg_steps,
            tolerance: p.tolerance,
        }
    }
}

impl MetricSettings {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        if !self.intrinsics.is_empty() {
            self.camera_checked().map_err(|message| {
                OutOfDomain::new(
                    "intrinsics",
                    "[] or [fx, fy, cx, cy] with fx, fy > 0, all finite",
                    format!("{:?} ({message})", self.intrinsics),
                )
            })?;
        }
        check_real("mean_limb_length", self.mean_limb_length, 0.0, 10.0, true)?;
        check_real("scale_std", self.scale_std, 0.0, 1.0, false)?;
        check_real("alpha", self.alpha, 0.0, 1e3, false)?;
        check_range("max_iterations", self.max_iterations, 1, 100_000)?;
        check_range("apg_steps", self.apg_steps, 1, 10_000)?;
        check_real("tolerance", self.tolerance, 0.0, 1.0, true)
    }

    /// The camera, if one is configured.
    pub fn camera(&self) -> Option<Intrinsics> {
        self.camera_checked().ok()
    }

    fn camera_checked(&self) -> Result<Intrinsics, String> {
        match self.intrinsics[..] {
            [fx, fy, cx, cy] => Intrinsics::new(fx, fy, cx, cy),
            _ => Err(format!("{} values", self.intrinsics.len())),
        }
    }

    /// The perspective adjustment's parameters.
    pub fn perspective(&self) -> PerspectiveParams {
        PerspectiveParams {
            mean_limb_length: self.mean_limb_length,
            alpha: self.alpha,
            max_iterations: self.max_iterations,
            apg_steps: self.apg_steps,
            tolerance: self.tolerance,
            momentum: true,
        }
    }
}

/// A frame in metres, written by [`MetricStep::adjust`] (buffers reused).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MetricPose {
    /// Joint positions, metres, camera frame (x right, y down, z forward): `[x, y, z]`
    /// per joint.
    pub positions: Vec<f64>,
    /// Standard deviation of each joint's position per axis, metres: `[x, y, z]` per
    /// joint (module docs).
    pub position_std: Vec<f64>,
    /// The 2D joints the adjustment fitted, image pixels: `[u, v]` per joint.
    pub keypoints: Vec<f64>,
    /// Standard deviation of each 2D joint, image pixels.
    pub keypoint_std: Vec<f64>,
    /// The perspective projection of `positions`, image pixels: `[u, v]` per joint.
    pub projected: Vec<f64>,
    /// Depth of the body's centroid, metres.
    pub depth: f64,
}

/// The perspective adjustment of streamed estimates, one frame at a time; see the
/// module docs. Its buffers are kept from frame to frame.
#[derive(Debug, Clone)]
pub struct MetricStep {
    dict: Dictionary,
    gram_max: f64,
    settings: MetricSettings,
    params: PerspectiveParams,
    ws: PerspectiveWorkspace,
    weights: Vec<f64>,
    shape: Vec<f64>,
    fit: Option<PerspectiveFit>,
}

impl MetricStep {
    /// A step for the estimates of `estimator`'s dictionary.
    pub fn new(estimator: &Estimator, settings: MetricSettings) -> Result<Self, EstimateError> {
        settings.check()?;
        let params = settings.perspective();
        params.validate()?;
        let dict = estimator.dictionary().clone();
        Ok(Self {
            gram_max: estimator.basis_gram_max(),
            params,
            weights: vec![1.0; dict.num_joints()],
            shape: vec![0.0; 3 * dict.num_joints()],
            dict,
            settings,
            ws: PerspectiveWorkspace::default(),
            fit: None,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &MetricSettings {
        &self.settings
    }

    /// The perspective adjustment's iterations on the last estimate adjusted.
    pub fn iterations(&self) -> usize {
        self.fit.as_ref().map_or(0, |f| f.iterations)
    }

    /// Writes estimate `e` in metres into `out`: `to_image` maps its heat-map pixels to
    /// image pixels (the crop box), `camera` is the camera's. An error (the pose has no
    /// size, or the result is not finite) leaves `out` to be ignored.
    pub fn adjust(
        &mut self,
        e: &FrameEstimate,
        to_image: &PixelMap,
        camera: &Intrinsics,
        out: &mut MetricPose,
    ) -> Result<(), EstimateError> {
        let p = self.dict.num_joints();
        if e.offset.len() == 3 * p {
            if e.offset != self.dict.offset() {
                // The track's shape beyond the dictionary, as the window composed it.
                self.dict.set_offset(&e.offset);
            }
        } else if self.dict.has_offset() {
            // An estimate without one: the paper's model.
            self.shape.fill(0.0);
            self.dict.set_offset(&self.shape);
        }
        out.keypoints.clear();
        out.keypoints.extend(
            e.keypoints
                .chunks_exact(2)
                .flat_map(|xy| to_image.apply(xy[0], xy[1])),
        );
        let units_to_image = PixelMap {
            scale: to_image.scale.map(|s| s * e.pixels_per_unit),
            offset: to_image.offset,
        };
        let params = &self.params;
        let zero_size = || EstimateError::ZeroSize { frame: 0 };
        let started = start_from_weak_fit(&self.dict, &e.fit, &units_to_image, camera, params)
            .ok_or_else(zero_size)?;
        // The previous frame's fit keeps its vectors: written over.
        let fit = match &mut self.fit {
            Some(fit) => {
                fit.coefficients.clone_from(&started.coefficients);
                fit.metres_per_unit = started.metres_per_unit;
                fit.rotation = started.rotation;
                fit.translation = started.translation;
                fit
            }
            None => self.fit.insert(started),
        };
        perspective::adjust_frame(
            &self.dict,
            self.gram_max,
            camera,
            &out.keypoints,
            &self.weights,
            fit,
            params,
            &mut self.ws,
        );
        out.positions.clear();
        out.projected.clear();
        out.position_std.clear();
        out.keypoint_std.clear();
        let shape = &mut self.shape;
        self.dict.compose_into(&fit.coefficients, shape);
        let scale_std = self.settings.scale_std;
        let focal = camera.focal();
        let px = to_image.mean_scale();
        for j in 0..p {
            let q = fit.rotation
                * Vector3::new(shape[j], shape[p + j], shape[2 * p + j])
                * fit.metres_per_unit
                + fit.translation;
            out.positions.extend_from_slice(q.as_slice());
            out.projected.extend(camera.project(&q));
            let s_px = e.keypoint_std.get(j).copied().unwrap_or(0.0) * px;
            out.keypoint_std.push(s_px);
            let lateral = q.z.abs() * s_px / focal;
            for v in [q.x, q.y, q.z] {
                out.position_std.push(lateral.hypot(v * scale_std));
            }
        }
        out.depth = fit.translation.z;
        let finite = [&out.positions, &out.position_std, &out.projected]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()));
        if finite {
            Ok(())
        } else {
            Err(EstimateError::Parameter(
                "the metric pose has non-finite values".into(),
            ))
        }
    }
}
