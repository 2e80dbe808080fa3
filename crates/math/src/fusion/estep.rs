//! The E-step of each view: the fused pose projected through the view's camera (full
//! perspective) into its heat maps, and the expected joints there as rays in the world.

use nalgebra::Vector3;

use super::ViewCamera;
use super::frame::Frame;
use crate::dictionary::Dictionary;
use crate::solver::Params;
use crate::solver::estep::{self, EStepWorkspace, Expectation};
use crate::solver::normalise::heatmap_scale;

/// Buffers of the E-step, reused from frame to frame.
#[derive(Debug, Clone, Default)]
pub(super) struct EStepBuffers {
    estep: EStepWorkspace,
    swapped: Vec<f64>,
    expected: Vec<Expectation>,
    projected: Vec<[f64; 2]>,
    visible: Vec<bool>,
    shape: Vec<f64>,
}

/// Joints nearer a camera than this (metres) are not seen by it.
pub(super) const MIN_DEPTH: f64 = 0.05;

/// How much a metre off a ray weighs in view `camera` at depth `z`: the normalised units
/// (heat-map pixels / [`heatmap_scale`]) a metre spans there, squared. The M-step's
/// distances from the rays, times this, are the single-camera EM's image residuals.
pub(super) fn units_per_metre(camera: &ViewCamera, cell_pixels: f64, height: usize, z: f64) -> f64 {
    camera.intrinsics.focal() / (z.max(MIN_DEPTH) * cell_pixels * heatmap_scale(height))
}

/// The E-step of `frame`: for each view, each joint of the pose (moved by `velocity`
/// over the view's time offset) projected into the view's heat maps, the expectation
/// under the map and a Gaussian of [`Params::sigma`] around it (with the left/right swap
/// mixture of [`Params::swap_prior`]), as a ray from the camera and a weight: its
/// confidence ([`Params::confidence_spread`]) times [`units_per_metre`] squared. A joint
/// behind a camera, or a view without evidence, weighs 0.
pub(super) fn e_step(
    dict: &Dictionary,
    params: &Params,
    cameras: &[ViewCamera],
    m: f64,
    velocity: &Vector3<f64>,
    frame: &mut Frame,
    b: &mut EStepBuffers,
) {
    let p = dict.num_joints();
    b.shape.resize(3 * p, 0.0);
    dict.compose_into(&frame.pose.coefficients, &mut b.shape);
    b.expected.resize(p, Expectation::default());
    b.projected.resize(p, [0.0; 2]);
    b.visible.resize(p, false);
    let Frame {
        pose,
        views,
        n_views,
        ..
    } = frame;
    for vd in &mut views[..*n_views] {
        let cam = &cameras[vd.view];
        vd.dirs.resize(p, Vector3::zeros());
        vd.weights.resize(p, 0.0);
        vd.keypoints.resize(p, [0.0; 2]);
        vd.variance.resize(p, 0.0);
        vd.depth.resize(p, 0.0);
        vd.origin = cam.centre() - velocity * vd.dt;
        if !vd.evidence {
            vd.weights.fill(0.0);
            continue;
        }
        let (h, w) = (vd.height, vd.width);
        let scale = heatmap_scale(h);
        let sigma = params.sigma * scale;
        let bound = params.confidence_spread * 2.0 * sigma * sigma;
        let map = vd.to_image;
        let cell_pixels = map.mean_scale();
        for j in 0..p {
            let at = pose.joint(&b.shape, j, m) + velocity * vd.dt;
            // Nearer a camera than 5 cm: no image to speak of (its weight would grow
            // as 1 / depth^2 and swamp every other joint).
            match cam.project(&at).filter(|&(_, z)| z >= MIN_DEPTH) {
                Some(([u, v], z)) => {
                    b.projected[j] = [
                        (u - map.offset[0]) / map.scale[0],
                        (v - map.offset[1]) / map.scale[1],
                    ];
                    b.visible[j] = true;
                    vd.depth[j] = z;
                }
                None => {
                    b.projected[j] = [0.5 * w as f64, 0.5 * h as f64];
                    b.visible[j] = false;
                }
            }
        }
        let n = h * w;
        let (maps, moments) = (&vd.maps, &vd.moments);
        estep::expect_joints(
            |j| (&maps[j * n..(j + 1) * n], &moments[j]),
            h,
            w,
            &b.projected,
            sigma,
            params.swap_prior,
            dict.left_right_pairs(),
            &mut b.estep,
            &mut b.swapped,
            &mut b.expected,
        );
        for (j, e) in b.expected.iter().enumerate() {
            if !b.visible[j] {
                vd.weights[j] = 0.0;
                continue;
            }
            let confidence = if bound > 0.0 && e.variance > bound {
                bound / e.variance
            } else {
                1.0
            };
            let [u, v] = map.apply(e.x, e.y);
            vd.keypoints[j] = [u, v];
            vd.dirs[j] = cam.ray(u, v);
            vd.variance[j] = map.variance(e.variance);
            let k = units_per_metre(cam, cell_pixels, h, vd.depth[j]);
            vd.weights[j] = confidence * k * k;
        }
    }
}
