//! The alternating initialisation (the reference's `altern`): start from the average
//! basis and the identity rotation; alternate the rotation that best maps the current
//! shape onto the 2D joints (least squares, projected to orthonormal rows) and an APG
//! step on the coefficients; stop on relative change of the objective
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

/// Initialises one frame by alternation.
pub fn initialise(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    ws: &mut InitWorkspace,
) -> (FrameFit, InitInfo) {
    let (k, p) = (dict.num_bases(), dict.num_joints());
    let d: Vec<f64> = visible.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect();
    let mut s = dict.average_basis();
    let mut r = Matrix3::identity();
    // Translation: mean of the visible joints (the bases are centred).
    let tr = best_translation(&vec![0.0; 3 * p], w, &d, &Matrix3::zeros());
    let wc: Vec<f64> = w
        .chunks_exact(2)
        .flat_map(|xy| [xy[0] - tr.x, xy[1] - tr.y])
        .collect();
    let mut c = vec![0.0; k];
    let mut fval = f64::INFINITY;
    let mut iterations = 0;
    for _ in 0..params.max_init_iterations {
        iterations += 1;
        // Greedy rotation: R2 = (W D S')(S D S')^-1, projected to orthonormal rows.
        let terms = FrameTerms::new(&s, &wc, nalgebra::Vector2::zeros(), &d);
        if let Some(inv) = terms.a.try_inverse() {
            let r2: Matrix2x3<f64> = terms.k * inv;
            if let Some(q) = nearest_orthonormal_rows(&r2) {
                r = complete_rotation(&q);
            }
        }
        single_frame_coefficients(dict, cache, &wc, &d, &r, &mut c, params, ws);
        dict.compose_into(&c, &mut s);
        let prev = fval;
        fval = frame_data_cost(&s, &wc, &d, &r, &nalgebra::Vector2::zeros())
            + params.alpha * c.iter().map(|v| v.abs()).sum::<f64>();
        if ((fval - prev) / prev).abs() < params.tolerance {
            break;
        }
    }
    (
        FrameFit {
            coefficients: c,
            rotation: r,
            translation: tr,
        },
        InitInfo {
            admm_iterations: 0,
            alternations: iterations,
        },
    )
}
