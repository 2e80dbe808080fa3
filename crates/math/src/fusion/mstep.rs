//! The M-step of the multi-view EM: one pose per frame against every view's rays.
//!
//! With the E-step's rays (origin `o`, unit direction `d`, weight `w` per view and joint)
//! the objective of frames `a..b` is
//!
//! ```text
//! 1/2 sum_t sum_v sum_j w_tvj |(I - d d')(m R_t S_j(c_t) + T_t - o_tv)|^2
//!   + alpha |C|_1 + beta/2 sum_t |c_t - c_t+1|^2
//! ```
//!
//! (the distances of the joints from their rays, in the E-step's normalised units through
//! the weights; the smoothness reaches the frames just outside `a..b`, which stay fixed).
//! Each round:
//! 1. [`rigid`]: per frame, the points of the rays nearest the model's joints, and the
//!    weighted similarity (Procrustes) of the body's shape onto them: its rotation and
//!    translation are the frame's. Seen by two views or more, the similarity's scale is
//!    the person's size seen by triangulation (collected for the window's one size per
//!    person); seen by one, a scale about that camera's centre changes no image, so it
//!    moves the body in depth instead, as the single-camera perspective step does
//!    ([`crate::solver::perspective`]);
//! 2. [`c_step`]: APG steps on the coefficients of every frame of `a..b` together, then
//!    each frame's pose rescaled to the window's mean bone length (the size is `m`'s).

use std::collections::VecDeque;

use nalgebra::Vector3;

use super::frame::Frame;
use crate::dictionary::Dictionary;
use crate::geometry::fit_similarity;
use crate::solver::perspective::mean_limb_length;
use crate::solver::{dot, soft};

/// Nearest a ray point may come to its camera, metres.
const MIN_DEPTH: f64 = 0.05;

/// Buffers of the M-step, reused from frame to frame.
#[derive(Debug, Clone, Default)]
pub(super) struct MStepBuffers {
    shape: Vec<f64>,
    model: Vec<Vector3<f64>>,
    target: Vec<Vector3<f64>>,
    w: Vec<f64>,
    g: Vec<f64>,
    z: Vec<f64>,
    prev: Vec<f64>,
    grad: Vec<f64>,
}

/// The size seen in a frame by two views or more: the similarity's scale, the weight of
/// the evidence behind it, and its centroids (model, metres in the body frame; target,
/// world), from which the frame's translation follows once the window's size is set
/// ([`SizeEvidence::translation`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct SizeEvidence {
    pub scale: f64,
    pub weight: f64,
    source_centroid: Vector3<f64>,
    target_centroid: Vector3<f64>,
}

impl SizeEvidence {
    /// The translation that puts the model's centroid, resized by `applied` (the new size
    /// over the one the fit was made with), on the target's.
    pub fn translation(&self, rotation: &nalgebra::Matrix3<f64>, applied: f64) -> Vector3<f64> {
        self.target_centroid - rotation * self.source_centroid * applied
    }
}

/// The rigid step of one frame (module docs, 1.). Seen by two views or more (three
/// joints or more each), it sets the rotation and returns the size evidence: the caller
/// sets the translation with the size it applies. Seen by one, it sets both.
pub(super) fn rigid(
    dict: &Dictionary,
    m: f64,
    frame: &mut Frame,
    b: &mut MStepBuffers,
) -> Option<SizeEvidence> {
    let p = dict.num_joints();
    b.shape.resize(3 * p, 0.0);
    dict.compose_into(&frame.pose.coefficients, &mut b.shape);
    b.model.clear();
    b.target.clear();
    b.w.clear();
    let (mut usable, mut origin) = (0, Vector3::zeros());
    for vd in frame.views() {
        if !vd.usable() {
            continue;
        }
        usable += 1;
        origin = vd.origin;
        for j in 0..p {
            let w = vd.weights[j];
            if w <= 0.0 {
                continue;
            }
            let s = Vector3::new(b.shape[j], b.shape[p + j], b.shape[2 * p + j]) * m;
            let at = frame.pose.rotation * s + frame.pose.translation;
            let d = vd.dirs[j];
            let along = d.dot(&(at - vd.origin)).max(MIN_DEPTH);
            b.model.push(s);
            b.target.push(vd.origin + d * along);
            b.w.push(w);
        }
    }
    if usable == 0 {
        return None;
    }
    let sim = fit_similarity(&b.model, &b.target, Some(&b.w), false)?;
    let scale = if sim.scale > 0.0 && sim.scale.is_finite() {
        sim.scale
    } else {
        1.0
    };
    let pose = &mut frame.pose;
    pose.rotation = sim.rotation;
    let t = sim.target_centroid - sim.rotation * sim.source_centroid * scale;
    if usable >= 2 {
        pose.translation = t;
        Some(SizeEvidence {
            scale,
            weight: b.w.iter().sum(),
            source_centroid: sim.source_centroid,
            target_centroid: sim.target_centroid,
        })
    } else {
        // One view: scaling about its camera centre leaves its image alone, so the body
        // keeps its size and moves in depth.
        pose.translation = origin + (t - origin) / scale;
        None
    }
}

/// The coefficient step of frames `a..b` of `frames` (module docs, 2.): `steps` APG
/// steps, the smoothness reaching `a - 1` and `b` when they exist, then every frame's
/// shape rescaled to mean bone length `limb0` (normalised units).
pub(super) fn c_step(
    dict: &Dictionary,
    gram_max: f64,
    m: f64,
    (alpha, beta, steps, limb0): (f64, f64, usize, f64),
    frames: &mut VecDeque<Frame>,
    a: usize,
    b: usize,
    buf: &mut MStepBuffers,
) {
    let (k, p) = (dict.num_bases(), dict.num_joints());
    let n = b - a;
    if n == 0 || steps == 0 {
        return;
    }
    // The data term's curvature bound: m^2 lambda_max(B'B) times the largest weight of a
    // joint summed over its views.
    let mut heaviest: f64 = 0.0;
    for f in frames.range(a..b) {
        for j in 0..p {
            let w: f64 = f
                .views()
                .iter()
                .map(|v| v.weights.get(j).copied().unwrap_or(0.0))
                .sum();
            heaviest = heaviest.max(w);
        }
    }
    let lipschitz = m * m * gram_max * heaviest + 4.0 * beta;
    if !(lipschitz > 0.0 && lipschitz.is_finite()) {
        return;
    }
    let step = 1.0 / lipschitz;
    buf.z.resize(n * k, 0.0);
    buf.prev.resize(n * k, 0.0);
    buf.grad.resize(n * k, 0.0);
    buf.shape.resize(3 * p, 0.0);
    buf.g.resize(3 * p, 0.0);
    for (i, f) in frames.range(a..b).enumerate() {
        buf.prev[i * k..(i + 1) * k].copy_from_slice(&f.pose.coefficients);
    }
    let (mut t_prev, mut t_cur) = (1.0f64, 1.0f64);
    for _ in 0..steps {
        let mom = (t_prev - 1.0) / t_cur;
        for (i, f) in frames.range(a..b).enumerate() {
            let c = &f.pose.coefficients;
            for q in 0..k {
                buf.z[i * k + q] = c[q] + mom * (c[q] - buf.prev[i * k + q]);
            }
        }
        for i in 0..n {
            let t = a + i;
            data_gradient(dict, m, &frames[t], i * k, buf);
            if beta > 0.0 {
                for nb in [t.wrapping_sub(1), t + 1] {
                    if nb >= frames.len() {
                        continue;
                    }
                    for q in 0..k {
                        let other = if (a..b).contains(&nb) {
                            buf.z[(nb - a) * k + q]
                        } else {
                            frames[nb].pose.coefficients[q]
                        };
                        buf.grad[i * k + q] += beta * (buf.z[i * k + q] - other);
                    }
                }
            }
        }
        for (i, f) in frames.range_mut(a..b).enumerate() {
            let c = &mut f.pose.coefficients;
            for q in 0..k {
                let at = i * k + q;
                buf.prev[at] = c[q];
                c[q] = soft(buf.z[at] - step * buf.grad[at], alpha * step);
            }
        }
        t_prev = t_cur;
        t_cur = 0.5 * (1.0 + (1.0 + 4.0 * t_cur * t_cur).sqrt());
    }
    for f in frames.range_mut(a..b) {
        rescale(dict, limb0, &mut f.pose.coefficients, &mut buf.shape);
    }
}

/// Rescales `c` so that its shape's mean bone length is `limb0` (left alone when the
/// shape has no size).
pub(super) fn rescale(dict: &Dictionary, limb0: f64, c: &mut [f64], shape: &mut Vec<f64>) {
    shape.resize(3 * dict.num_joints(), 0.0);
    dict.compose_into(c, shape);
    let limb = mean_limb_length(dict.skeleton(), shape);
    if limb > 0.0 && limb.is_finite() {
        let r = limb0 / limb;
        c.iter_mut().for_each(|v| *v *= r);
    }
}

/// The data term's gradient of `frame` at coefficients `buf.z[at..at + k]`, into
/// `buf.grad[at..at + k]`.
fn data_gradient(dict: &Dictionary, m: f64, frame: &Frame, at: usize, buf: &mut MStepBuffers) {
    let (k, p) = (dict.num_bases(), dict.num_joints());
    dict.compose_into(&buf.z[at..at + k], &mut buf.shape);
    buf.g.fill(0.0);
    let pose = &frame.pose;
    let back = pose.rotation.transpose();
    for vd in frame.views() {
        for j in 0..p {
            let w = vd.weights[j];
            if w <= 0.0 {
                continue;
            }
            let at_j = pose.joint(&buf.shape, j, m);
            let r = at_j - vd.origin;
            let d = vd.dirs[j];
            let off = r - d * d.dot(&r);
            let gb = back * off * (w * m);
            buf.g[j] += gb.x;
            buf.g[p + j] += gb.y;
            buf.g[2 * p + j] += gb.z;
        }
    }
    for i in 0..k {
        buf.grad[at + i] = dot(dict.basis(i), &buf.g);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::frame::ViewData;
    use crate::skeleton::default_layout;
    use nalgebra::{Matrix3, Rotation3};

    /// A dictionary of 4 smooth bases over the default layout.
    fn dictionary() -> Dictionary {
        let skel = default_layout();
        let p = skel.len();
        let bases: Vec<f64> = (0..4 * 3 * p)
            .map(|i| ((i * 37 % 101) as f64 / 101.0 - 0.5) * (1.0 + (i % 7) as f64 * 0.1))
            .collect();
        Dictionary::new(skel, bases, vec![0.0; 3 * p]).expect("dictionary")
    }

    /// A frame of the dictionary's pose `c` seen by two views with noisy rays.
    fn frame(dict: &Dictionary, c: &[f64], origins: &[Vector3<f64>]) -> Frame {
        let p = dict.num_joints();
        let mut f = Frame::new(dict.num_bases());
        f.pose.coefficients.copy_from_slice(c);
        f.pose.rotation = Rotation3::from_euler_angles(0.2, -0.3, 0.5).into_inner();
        f.pose.translation = Vector3::new(0.3, -0.2, 1.0);
        for (v, o) in origins.iter().enumerate() {
            let mut vd = ViewData::new();
            vd.view = v;
            vd.origin = *o;
            vd.dirs = (0..p)
                .map(|j| {
                    let aim = Vector3::new(0.1 * j as f64, 0.05 * (j % 3) as f64, 0.9);
                    (aim - o).normalize()
                })
                .collect();
            vd.weights = (0..p).map(|j| 1.0 + 0.1 * j as f64).collect();
            f.views.push(vd);
            f.n_views += 1;
        }
        f
    }

    fn objective(dict: &Dictionary, m: f64, f: &Frame, c: &[f64]) -> f64 {
        let shape = dict.compose(c);
        let mut total = 0.0;
        for vd in f.views() {
            for j in 0..dict.num_joints() {
                let r = f.pose.joint(&shape, j, m) - vd.origin;
                let off = r - vd.dirs[j] * vd.dirs[j].dot(&r);
                total += 0.5 * vd.weights[j] * off.norm_squared();
            }
        }
        total
    }

    #[test]
    fn the_data_gradient_is_the_objectives_by_finite_differences() {
        let dict = dictionary();
        let k = dict.num_bases();
        let c = [0.4, -0.2, 0.7, 0.1];
        let f = frame(
            &dict,
            &c,
            &[Vector3::new(4.0, 0.0, 2.0), Vector3::new(0.0, 4.0, 2.0)],
        );
        let m = 0.7;
        let mut buf = MStepBuffers {
            z: c.to_vec(),
            grad: vec![0.0; k],
            shape: vec![0.0; 3 * dict.num_joints()],
            g: vec![0.0; 3 * dict.num_joints()],
            ..MStepBuffers::default()
        };
        data_gradient(&dict, m, &f, 0, &mut buf);
        for i in 0..k {
            let h = 1e-6;
            let (mut up, mut down) = (c.to_vec(), c.to_vec());
            up[i] += h;
            down[i] -= h;
            let numeric =
                (objective(&dict, m, &f, &up) - objective(&dict, m, &f, &down)) / (2.0 * h);
            assert!(
                (numeric - buf.grad[i]).abs() <= 1e-5 * numeric.abs().max(1.0),
                "coefficient {i}: {numeric} against {}",
                buf.grad[i]
            );
        }
    }

    #[test]
    fn one_view_moves_a_body_too_large_in_its_image_away_along_its_rays() {
        let dict = dictionary();
        let p = dict.num_joints();
        let c = [0.4, -0.2, 0.7, 0.1];
        let m = 1.0;
        // The truth at 4 m; the rays of its joints from one camera at the origin.
        let mut truth = frame(&dict, &c, &[Vector3::zeros()]);
        truth.pose.rotation = Matrix3::identity();
        truth.pose.translation = Vector3::new(0.0, 0.0, 4.0);
        let shape = dict.compose(&c);
        let dirs: Vec<Vector3<f64>> = (0..p)
            .map(|j| truth.pose.joint(&shape, j, m).normalize())
            .collect();
        truth.views[0].dirs = dirs;
        // Start at 3 m: the size fixed, the similarity's scale becomes depth.
        let mut f = truth.clone();
        f.pose.translation = Vector3::new(0.0, 0.0, 3.0);
        let mut buf = MStepBuffers::default();
        for _ in 0..50 {
            assert!(
                rigid(&dict, m, &mut f, &mut buf).is_none(),
                "one view: no size evidence"
            );
        }
        assert!(
            (f.pose.translation - truth.pose.translation).norm() < 0.05,
            "{:?}",
            f.pose.translation
        );
    }
}
