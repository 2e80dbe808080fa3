//! What the fused window holds per frame: the pose and each view's heat maps with their
//! E-step.

use nalgebra::{Matrix3, Vector3};

use crate::dictionary::Dictionary;
use crate::solver::estep::MapMoments;
use posestream_base::PixelMap;

/// One person's pose in one frame, world frame: joint `j` is at `m R S_j(c) + T`, with
/// `m` the window's metres per unit ([`super::FusedWindow`] holds it: one size per
/// person).
#[derive(Debug, Clone, PartialEq)]
pub struct FusedPose {
    /// Coefficients `c` of the dictionary's bases (normalised units, the pose's mean bone
    /// length kept at the window's).
    pub coefficients: Vec<f64>,
    /// Rotation, body to world.
    pub rotation: Matrix3<f64>,
    /// Translation, metres, world frame.
    pub translation: Vector3<f64>,
}

impl FusedPose {
    /// Joint `j` of the composed shape `shape` (row-major 3 x p), metres, world frame.
    pub fn joint(&self, shape: &[f64], j: usize, m: f64) -> Vector3<f64> {
        let p = shape.len() / 3;
        self.rotation * Vector3::new(shape[j], shape[p + j], shape[2 * p + j]) * m
            + self.translation
    }

    /// True when every value is finite.
    pub fn is_finite(&self) -> bool {
        self.coefficients.iter().all(|c| c.is_finite())
            && self.rotation.iter().all(|r| r.is_finite())
            && self.translation.iter().all(|t| t.is_finite())
    }

    /// Every joint, metres, world frame: `[x, y, z]` per joint, into `out`.
    pub fn joints_into(&self, dict: &Dictionary, m: f64, shape: &mut Vec<f64>, out: &mut Vec<f64>) {
        shape.resize(3 * dict.num_joints(), 0.0);
        dict.compose_into(&self.coefficients, shape);
        out.clear();
        for j in 0..dict.num_joints() {
            let q = self.joint(shape, j, m);
            out.extend([q.x, q.y, q.z]);
        }
    }
}

/// One view of a frame: the camera's heat maps of the person (their one copy, clipped
/// at 0) and what the last E-step made of them.
#[derive(Debug, Clone)]
pub(super) struct ViewData {
    /// The camera (index into the window's cameras).
    pub view: usize,
    /// Capture time of this view's image minus the frame's time, seconds.
    pub dt: f64,
    /// Heat-map cells to image pixels.
    pub to_image: PixelMap,
    pub height: usize,
    pub width: usize,
    /// p maps, `height x width` each.
    pub maps: Vec<f32>,
    pub moments: Vec<MapMoments>,
    /// Each map's peak, image pixels, and its score: `[u, v, score]`.
    pub peaks: Vec<[f64; 3]>,
    /// Whether any map has a positive score.
    pub evidence: bool,
    /// A copy of the frame before's view of this camera, standing in for the one it did
    /// not send ([`super::FusionSettings::bridge_seconds`]).
    pub bridged: bool,
    /// The E-step: the ray's origin (the camera centre moved back by the body's motion
    /// over `dt`), each joint's unit ray direction and weight (0: not seen), the
    /// expected joint (image pixels) and its spread (trace of the covariance, image
    /// pixels^2).
    pub origin: Vector3<f64>,
    pub dirs: Vec<Vector3<f64>>,
    pub weights: Vec<f64>,
    pub keypoints: Vec<[f64; 2]>,
    pub variance: Vec<f64>,
    /// Depth of each joint from the camera at the E-step, metres.
    pub depth: Vec<f64>,
}

impl ViewData {
    /// Empty buffers.
    pub fn new() -> Self {
        Self {
            view: 0,
            dt: 0.0,
            to_image: PixelMap::IDENTITY,
            height: 0,
            width: 0,
            maps: Vec::new(),
            moments: Vec::new(),
            peaks: Vec::new(),
            evidence: false,
            bridged: false,
            origin: Vector3::zeros(),
            dirs: Vec::new(),
            weights: Vec::new(),
            keypoints: Vec::new(),
            variance: Vec::new(),
            depth: Vec::new(),
        }
    }

    /// Views of three or more weighted joints: enough for a rigid fit.
    pub fn usable(&self) -> bool {
        self.weights.iter().filter(|&&w| w > 0.0).count() >= 3
    }
}

/// One frame of the window.
#[derive(Debug, Clone)]
pub(super) struct Frame {
    /// The frame's time, nanoseconds.
    pub stamp_ns: i64,
    /// Its views: the first `n_views` hold this frame's (the rest are spare buffers).
    pub views: Vec<ViewData>,
    pub n_views: usize,
    pub pose: FusedPose,
}

impl Frame {
    pub fn new(k: usize) -> Self {
        Self {
            stamp_ns: 0,
            views: Vec::new(),
            n_views: 0,
            pose: FusedPose {
                coefficients: vec![0.0; k],
                rotation: Matrix3::identity(),
                translation: Vector3::zeros(),
            },
        }
    }

    /// This frame's views.
    pub fn views(&self) -> &[ViewData] {
        &self.views[..self.n_views]
    }

    /// This frame's views, mutable.
    pub fn views_mut(&mut self) -> &mut [ViewData] {
        &mut self.views[..self.n_views]
    }

    /// Views with enough weighted joints for a rigid fit.
    pub fn usable_views(&self) -> usize {
        self.views().iter().filter(|v| v.usable()).count()
    }
}
