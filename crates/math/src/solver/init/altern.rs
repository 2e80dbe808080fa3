//! The alternating initialisation (the reference's `altern`): start from the average
//! basis and the identity rotation; alternate the rotation that best maps the current
//! shape onto the 2D joints (least squares, projected to orthonormal rows) and a
//! coefficient step (the configured C-step solver: active-set by default, APG in the
//! reference); stop on relative change of the objective
//! `1/2 |W - Pi R S|^2 + alpha |c|_1`.

use nalgebra::{Matrix2x3, Matrix3};

use super::{
    InitCache, InitInfo, InitWorkspace, complete_rotation, nearest_orthonormal_rows,
    single_frame_coefficients,
};
use crate::dictionary::Dictionary;
use crate::solver::bcd::{best_translation, frame_data_cost};
use crate::solver::rotations::FrameTerms;
use crate::solver::{FrameFit, Params};

/// The alternation's buffers, reused from frame to frame.
#[derive(Debug, Clone, Default)]
pub(crate) struct AlternBuffers {
    /// Joint weights (1 visible, 0 not).
    d: Vec<f64>,
    /// The current shape (3 x p).
    s: Vec<f64>,
    /// The 2D joints less the translation.
    wc: Vec<f64>,
    /// A zero shape (3 x p).
    zeros: Vec<f64>,
}

/// Initialises one frame by alternation.
pub fn initialise(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    ws: &mut InitWorkspace,
) -> (FrameFit, InitInfo) {
    let mut fit = FrameFit::zero(dict.num_bases());
    let info = initialise_into(dict, cache, w, visible, params, ws, &mut fit);
    (fit, info)
}

/// [`initialise`] written over `fit`; allocates nothing once `ws` has seen a frame.
pub fn initialise_into(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    ws: &mut InitWorkspace,
    fit: &mut FrameFit,
) -> InitInfo {
    let (k, p) = (dict.num_bases(), dict.num_joints());
    let mut b = std::mem::take(&mut ws.altern);
    b.d.clear();
    b.d.extend(visible.iter().map(|&v| if v { 1.0 } else { 0.0 }));
    b.s.clear();
    b.s.extend_from_slice(&cache.average_basis);
    b.zeros.clear();
    b.zeros.resize(3 * p, 0.0);
    let (d, s) = (&b.d, &mut b.s);
    let mut r = Matrix3::identity();
    // Translation: mean of the visible joints (the bases are centred).
    let tr = best_translation(&b.zeros, w, d, &Matrix3::zeros());
    b.wc.clear();
    b.wc.extend(
        w.chunks_exact(2)
            .flat_map(|xy| [xy[0] - tr.x, xy[1] - tr.y]),
    );
    let wc = &b.wc;
    let c = &mut fit.coefficients;
    c.clear();
    c.resize(k, 0.0);
    let mut fval = f64::INFINITY;
    let mut iterations = 0;
    for _ in 0..params.max_init_iterations {
        iterations += 1;
        // Greedy rotation: R2 = (W D S')(S D S')^-1, projected to orthonormal rows.
        let terms = FrameTerms::new(s, wc, nalgebra::Vector2::zeros(), d);
        if let Some(inv) = terms.a.try_inverse() {
            let r2: Matrix2x3<f64> = terms.k * inv;
            if let Some(q) = nearest_orthonormal_rows(&r2) {
                r = complete_rotation(&q);
            }
        }
        single_frame_coefficients(dict, cache, wc, d, &r, c, params, ws);
        dict.compose_into(c, s);
        let prev = fval;
        fval = frame_data_cost(s, wc, d, &r, &nalgebra::Vector2::zeros())
            + params.alpha * c.iter().map(|v| v.abs()).sum::<f64>();
        if ((fval - prev) / prev).abs() < params.tolerance {
            break;
        }
    }
    fit.rotation = r;
    fit.translation = tr;
    ws.altern = b;
    InitInfo {
        admm_iterations: 0,
        alternations: iterations,
    }
}
