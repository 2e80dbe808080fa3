//! The convex initialisation (Zhou et al., CVPR 2015; robust variant, TPAMI 2017).
//!
//! Replace `c_i R` by free 2 x 3 blocks `M_i` and solve
//!
//! ```text
//! min_M,E,T  1/2 |W - M B - E - T 1'|^2 + lambda sum_i ||M_i||_2 + beta_o |E|_1
//! ```
//!
//! by ADMM on the split `M = Z`: a least-squares step on Z, a per-block proximal step of
//! the spectral norm, the outlier soft threshold and translation (robust variant), a dual
//! step, and the adaptive penalty `mu` (doubled or halved by the ratio of primal and dual
//! residuals). The least-squares step needs `(B B' + mu I)^-1`; with the thin SVD
//! `B = U S V'` (rank r <= p) that is `U diag(1/(s^2+mu) - 1/mu) U' + I/mu`, so a change
//! of `mu` costs a diagonal, and a step O(k p r) instead of O(k^2 p).
//!
//! Then one rotation is recovered from the blocks ([`synchronise_rotation`], the rank-2
//! "deformable" projection of Del Bue et al.) and refined by alternating a local rotation
//! fit (Riemannian Newton) with an APG coefficient step, keeping the outlier term.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Matrix3x2, Vector2};

use super::{InitCache, InitInfo, complete_rotation, fit_rotation, single_frame_coefficients};
use crate::dictionary::Dictionary;
use crate::solver::coefficients::{CoefficientProblem, CoefficientWorkspace};
use crate::solver::{FrameFit, Params, soft};

/// The basis matrix restricted to some joints and its thin SVD.
#[derive(Debug, Clone)]
pub struct BasisFactor {
    /// The joints (columns) kept.
    pub joints: Vec<usize>,
    /// Rows `3k`.
    rows: usize,
    /// `B` restricted to `joints`, row-major (3k x q).
    b: Vec<f64>,
    /// Left singular vectors, column-major (3k x r).
    u: Vec<f64>,
    /// Squared singular values (r).
    s2: Vec<f64>,
}

impl BasisFactor {
    /// Factorises the bases of `dict` restricted to `joints`.
    pub fn new(dict: &Dictionary, joints: &[usize]) -> Self {
        let (k, p, q) = (dict.num_bases(), dict.num_joints(), joints.len());
        let rows = 3 * k;
        let mut b = vec![0.0; rows * q];
        for i in 0..k {
            let bi = dict.basis(i);
            for d in 0..3 {
                for (jj, &j) in joints.iter().enumerate() {
                    b[(3 * i + d) * q + jj] = bi[d * p + j];
                }
            }
        }
        let m = faer::Mat::<f64>::from_fn(rows, q, |r, c| b[r * q + c]);
        let (mut u, mut s2) = (Vec::new(), Vec::new());
        if let Ok(svd) = m.thin_svd() {
            let sv = svd.S().column_vector();
            let smax = (0..sv.nrows()).map(|i| sv[i]).fold(0.0, f64::max);
            for c in 0..sv.nrows() {
                // Drop the null directions (centring makes B rank-deficient).
                if sv[c] > 1e-10 * smax {
                    s2.push(sv[c] * sv[c]);
                    u.extend((0..rows).map(|r| svd.U()[(r, c)]));
                }
            }
        }
        Self {
            joints: joints.to_vec(),
            rows,
            b,
            u,
            s2,
        }
    }
}

/// Prox of `lam ||.||_2` (spectral norm) of a 2 x 3 block: returns the block and its
/// spectral norm.
fn prox_spectral(q: &Matrix2x3<f64>, lam: f64) -> (Matrix2x3<f64>, f64) {
    let svd = q.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return (Matrix2x3::zeros(), 0.0);
    };
    let (mut s1, mut s2) = (svd.singular_values[0], svd.singular_values[1]);
    let swap = s2 > s1;
    if swap {
        std::mem::swap(&mut s1, &mut s2);
    }
    let (w1, w2) = if s1 + s2 <= lam {
        (0.0, 0.0)
    } else if s1 - s2 <= lam {
        let w = 0.5 * (s1 + s2 - lam);
        (w, w)
    } else {
        (s1 - lam, s2)
    };
    let d = if swap {
        Matrix2::new(w2, 0.0, 0.0, w1)
    } else {
        Matrix2::new(w1, 0.0, 0.0, w2)
    };
    (u * d * vt, w1)
}

/// Initialises one frame by the convex relaxation, then refines.
pub fn initialise(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    robust: bool,
) -> (FrameFit, InitInfo) {
    let joints: Vec<usize> = (0..visible.len()).filter(|&j| visible[j]).collect();
    let owned;
    let factor = if joints.len() == dict.num_joints() {
        &cache.all_visible
    } else {
        owned = BasisFactor::new(dict, &joints);
        &owned
    };
    let q = joints.len();
    let wv: Vec<f64> = joints
        .iter()
        .flat_map(|&j| [w[2 * j], w[2 * j + 1]])
        .collect();
    let beta_o = if robust {
        params.robust_threshold
    } else {
        f64::INFINITY
    };
    let admm = admm(
        factor,
        &wv,
        q,
        params.alpha,
        beta_o,
        params.max_init_iterations,
    );
    let (r, c) = synchronise_rotation(&admm.m, dict.num_bases());
    // Outliers back on the full joint list.
    let mut e_full = vec![0.0; w.len()];
    for (jj, &j) in joints.iter().enumerate() {
        e_full[2 * j] = admm.e[2 * jj];
        e_full[2 * j + 1] = admm.e[2 * jj + 1];
    }
    let s0 = dict.compose(&c);
    let (fit, alternations) = refine(dict, cache, w, visible, params, beta_o, &s0, r, e_full);
    (
        fit,
        InitInfo {
            admm_iterations: admm.iterations,
            alternations,
        },
    )
}

/// Result of the ADMM.
#[derive(Debug, Clone)]
pub struct AdmmResult {
    /// Blocks `M_i`, row-major 2 x 3k.
    pub m: Vec<f64>,
    /// Outliers, `[x, y]` per kept joint.
    pub e: Vec<f64>,
    /// Translation.
    pub t: Vector2<f64>,
    /// Iterations run.
    pub iterations: usize,
}

/// ADMM on the convex relaxation; `w` holds `[x, y]` of the `q` kept joints.
pub fn admm(
    f: &BasisFactor,
    w: &[f64],
    q: usize,
    lam: f64,
    beta_o: f64,
    max_iterations: usize,
) -> AdmmResult {
    let n = f.rows; // 3k
    let k = n / 3;
    let r = f.s2.len();
    let tol = 1e-3;
    let mut m = vec![0.0; 2 * n];
    let mut z = vec![0.0; 2 * n];
    let mut y = vec![0.0; 2 * n];
    let mut z0 = vec![0.0; 2 * n];
    let mut rhs = vec![0.0; 2 * n];
    let mut e = vec![0.0; 2 * q];
    let mut zb = vec![0.0; 2 * q];
    let mut resid = vec![0.0; 2 * q];
    let mut ru = vec![0.0; 2 * r];
    let mean = |v: &[f64]| -> Vector2<f64> {
        let (mut sx, mut sy) = (0.0, 0.0);
        for xy in v.chunks_exact(2) {
            sx += xy[0];
            sy += xy[1];
        }
        Vector2::new(sx / q as f64, sy / q as f64)
    };
    let mut t = mean(w);
    let mean_abs = w.iter().map(|v| v.abs()).sum::<f64>() / w.len() as f64;
    let mut mu = 1.0 / mean_abs.max(f64::MIN_POSITIVE);
    let w_max = w.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let robust = beta_o <= w_max;
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        z0.copy_from_slice(&z);
        // rhs = (W - E - T 1') B' + mu M + Y, as 2 rows of length 3k.
        for row in 0..2 {
            for jj in 0..q {
                resid[row * q + jj] = w[2 * jj + row] - e[2 * jj + row] - t[row];
            }
        }
        for row in 0..2 {
            let d = &resid[row * q..(row + 1) * q];
            let out = &mut rhs[row * n..(row + 1) * n];
            for (col, o) in out.iter_mut().enumerate() {
                let b = &f.b[col * q..(col + 1) * q];
                *o = b.iter().zip(d).map(|(b, d)| b * d).sum::<f64>();
            }
            for col in 0..n {
                out[col] += mu * m[row * n + col] + y[row * n + col];
            }
        }
        // z = rhs (B B' + mu I)^-1 = rhs/mu + (rhs U) diag(1/(s2+mu) - 1/mu) U'.
        for row in 0..2 {
            let h = &rhs[row * n..(row + 1) * n];
            for c in 0..r {
                let uc = &f.u[c * n..(c + 1) * n];
                let dot: f64 = h.iter().zip(uc).map(|(a, b)| a * b).sum();
                ru[row * r + c] = dot * (1.0 / (f.s2[c] + mu) - 1.0 / mu);
            }
            let zr = &mut z[row * n..(row + 1) * n];
            for (zv, hv) in zr.iter_mut().zip(h) {
                *zv = hv / mu;
            }
            for c in 0..r {
                let coef = ru[row * r + c];
                let uc = &f.u[c * n..(c + 1) * n];
                for (zv, uv) in zr.iter_mut().zip(uc) {
                    *zv += coef * uv;
                }
            }
        }
        // M: per-block prox of the spectral norm at z - y/mu.
        for i in 0..k {
            let mut qb = Matrix2x3::zeros();
            for row in 0..2 {
                for d in 0..3 {
                    let idx = row * n + 3 * i + d;
                    qb[(row, d)] = z[idx] - y[idx] / mu;
                }
            }
            let (mb, _) = prox_spectral(&qb, lam / mu);
            for row in 0..2 {
                for d in 0..3 {
                    m[row * n + 3 * i + d] = mb[(row, d)];
                }
            }
        }
        if robust {
            // zb = Z B (2 x q); E = soft(W - ZB - T); T = mean(W - ZB - E).
            for row in 0..2 {
                for jj in 0..q {
                    let mut acc = 0.0;
                    for col in 0..n {
                        acc += z[row * n + col] * f.b[col * q + jj];
                    }
                    zb[2 * jj + row] = acc;
                }
            }
            for i in 0..2 * q {
                e[i] = soft(w[i] - zb[i] - t[i % 2], beta_o);
            }
            let (mut sx, mut sy) = (0.0, 0.0);
            for jj in 0..q {
                sx += w[2 * jj] - zb[2 * jj] - e[2 * jj];
                sy += w[2 * jj + 1] - zb[2 * jj + 1] - e[2 * jj + 1];
            }
            t = Vector2::new(sx / q as f64, sy / q as f64);
        }
        let (mut prim, mut dual, mut nz0) = (0.0, 0.0, 0.0);
        for i in 0..2 * n {
            y[i] += mu * (m[i] - z[i]);
            prim += (m[i] - z[i]).powi(2);
            dual += (z[i] - z0[i]).powi(2);
            nz0 += z0[i] * z0[i];
        }
        if nz0 == 0.0 {
            continue; // first step: residuals undefined, as in the reference
        }
        let (prim, dual) = (prim.sqrt() / nz0.sqrt(), mu * dual.sqrt() / nz0.sqrt());
        if prim < tol && dual < tol {
            break;
        }
        if prim > 10.0 * dual {
            mu *= 2.0;
        } else if dual > 10.0 * prim {
            mu /= 2.0;
        }
    }
    AdmmResult {
        m,
        e,
        t,
        iterations,
    }
}

/// Recovers one rotation and signed coefficients from the blocks `M_i ≈ c_i R`
/// (row-major 2 x 3k): the rank-2 projection of Del Bue et al. (BALM, ECCV 2010, §5.1)
/// on the stacked transposed blocks, with the sign fixed by the largest coefficient.
pub fn synchronise_rotation(m: &[f64], k: usize) -> (Matrix3<f64>, Vec<f64>) {
    let n = 3 * k;
    let block =
        |i: usize| -> Matrix3x2<f64> { Matrix3x2::from_fn(|d, row| m[row * n + 3 * i + d]) };
    let mut a = Matrix3::zeros();
    for i in 0..k {
        let ai = block(i);
        a += ai * ai.transpose();
    }
    let vecs = sorted_eigenvectors3(&a);
    let mut qm =
        Matrix3x2::from_columns(&[vecs.column(0).into_owned(), vecs.column(1).into_owned()]);
    let (mut g1, mut g2) = (Matrix2::zeros(), Matrix2::zeros());
    for i in 0..k {
        let ti = qm.transpose() * block(i);
        let a1 = nalgebra::Vector2::new(ti[(0, 0)] + ti[(1, 1)], ti[(1, 0)] - ti[(0, 1)]);
        let a2 = nalgebra::Vector2::new(ti[(0, 0)] - ti[(1, 1)], ti[(0, 1)] + ti[(1, 0)]);
        g1 += a1 * a1.transpose();
        g2 += a2 * a2.transpose();
    }
    let (l1, u1) = top_eigen2(&g1);
    let (l2, u2) = top_eigen2(&g2);
    let rot2 = if l1 > l2 {
        Matrix2::new(u1.x, -u1.y, u1.y, u1.x)
    } else {
        Matrix2::new(u2.x, u2.y, u2.y, -u2.x)
    };
    qm *= rot2;
    let mut c: Vec<f64> = (0..k)
        .map(|i| 0.5 * (qm.transpose() * block(i)).trace())
        .collect();
    let imax = (0..k)
        .max_by(|&a, &b| c[a].abs().total_cmp(&c[b].abs()))
        .unwrap_or(0);
    let sign = if c.get(imax).copied().unwrap_or(0.0) < 0.0 {
        -1.0
    } else {
        1.0
    };
    c.iter_mut().for_each(|v| *v *= sign);
    let r2 = qm.transpose() * sign;
    (complete_rotation(&r2), c)
}

/// Eigenvectors of a symmetric 3 x 3 matrix as columns, eigenvalues descending (nalgebra).
fn sorted_eigenvectors3(a: &Matrix3<f64>) -> Matrix3<f64> {
    let eig = a.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
    Matrix3::from_columns(&[
        eig.eigenvectors.column(idx[0]).into_owned(),
        eig.eigenvectors.column(idx[1]).into_owned(),
        eig.eigenvectors.column(idx[2]).into_owned(),
    ])
}

/// Largest eigenvalue and its eigenvector of a symmetric 2 x 2 matrix (nalgebra).
fn top_eigen2(a: &Matrix2<f64>) -> (f64, nalgebra::Vector2<f64>) {
    let eig = a.symmetric_eigen();
    let i = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        0
    } else {
        1
    };
    (eig.eigenvalues[i], eig.eigenvectors.column(i).into_owned())
}

/// Refinement by alternation (the reference's `ssr2D3D_alt` with manifold rotation
/// steps): local rotation fit, APG coefficient step, outliers and translation.
#[allow(clippy::too_many_arguments)]
fn refine(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    beta_o: f64,
    s0: &[f64],
    r0: Matrix3<f64>,
    mut e: Vec<f64>,
) -> (FrameFit, usize) {
    let (k, p) = (dict.num_bases(), dict.num_joints());
    let d: Vec<f64> = visible.iter().map(|&v| if v { 1.0 } else { 0.0 }).collect();
    let nvis = d.iter().sum::<f64>().max(1.0);
    let mut t = {
        let (mut sx, mut sy) = (0.0, 0.0);
        for j in 0..p {
            sx += d[j] * w[2 * j];
            sy += d[j] * w[2 * j + 1];
        }
        Vector2::new(sx / nvis, sy / nvis)
    };
    let w_max = (0..p).filter(|&j| visible[j]).fold(0.0_f64, |a, j| {
        a.max(w[2 * j].abs()).max(w[2 * j + 1].abs())
    });
    let robust = beta_o <= w_max;
    if !robust {
        e.iter_mut().for_each(|v| *v = 0.0);
    }
    let mut s = s0.to_vec();
    let mut r = r0;
    let mut c = vec![0.0; k];
    let mut fit_w = vec![0.0; 2 * p];
    let mut proj = vec![0.0; 2 * p];
    let (mut problem, mut apg) = (
        CoefficientProblem::default(),
        CoefficientWorkspace::default(),
    );
    let mut fval = f64::INFINITY;
    let mut iterations = 0;
    for _ in 0..params.max_init_iterations {
        iterations += 1;
        for j in 0..p {
            fit_w[2 * j] = w[2 * j] - e[2 * j] - t.x;
            fit_w[2 * j + 1] = w[2 * j + 1] - e[2 * j + 1] - t.y;
        }
        fit_rotation(&s, &fit_w, &d, &mut r);
        single_frame_coefficients(
            dict,
            cache,
            &fit_w,
            &d,
            &r,
            &mut c,
            params,
            &mut problem,
            &mut apg,
        );
        dict.compose_into(&c, &mut s);
        // Projection of the current shape.
        for j in 0..p {
            let (x, y, z) = (s[j], s[p + j], s[2 * p + j]);
            proj[2 * j] = r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z;
            proj[2 * j + 1] = r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z;
        }
        let mut l1e = 0.0;
        if robust {
            for j in 0..p {
                for a in 0..2 {
                    let i = 2 * j + a;
                    e[i] = if visible[j] {
                        soft(w[i] - proj[i] - t[a], beta_o)
                    } else {
                        0.0
                    };
                    l1e += e[i].abs();
                }
            }
            let (mut sx, mut sy) = (0.0, 0.0);
            for j in 0..p {
                sx += d[j] * (w[2 * j] - proj[2 * j] - e[2 * j]);
                sy += d[j] * (w[2 * j + 1] - proj[2 * j + 1] - e[2 * j + 1]);
            }
            t = Vector2::new(sx / nvis, sy / nvis);
        }
        let mut loss = 0.0;
        for j in 0..p {
            for a in 0..2 {
                let i = 2 * j + a;
                loss += d[j] * (w[i] - proj[i] - e[i] - t[a]).powi(2);
            }
        }
        let prev = fval;
        fval = 0.5 * loss
            + params.alpha * c.iter().map(|v| v.abs()).sum::<f64>()
            + if robust { beta_o * l1e } else { 0.0 };
        if ((fval - prev) / prev).abs() < params.tolerance {
            break;
        }
    }
    (
        FrameFit {
            coefficients: c,
            rotation: r,
            translation: t,
        },
        iterations,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prox_of_spectral_norm_matches_its_definition() {
        let q = Matrix2x3::new(1.0, 2.0, -0.5, 0.3, -1.0, 2.5);
        let lam = 0.7;
        let (x, nrm) = prox_spectral(&q, lam);
        let obj = |x: &Matrix2x3<f64>| {
            0.5 * (x - q).norm_squared() + lam * x.svd(false, false).singular_values.max()
        };
        let best = obj(&x);
        assert!((x.svd(false, false).singular_values.max() - nrm).abs() < 1e-9);
        // Any perturbation is no better.
        for i in 0..6 {
            for s in [-1e-3, 1e-3] {
                let mut y = x;
                y[i] += s;
                assert!(obj(&y) >= best - 1e-12);
            }
        }
    }

    #[test]
    fn synchronise_rotation_recovers_scaled_copies() {
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -1.2, 0.8).into_inner();
        let coeffs = [0.8, -0.0, 1.7, 0.4];
        let k = coeffs.len();
        let mut m = vec![0.0; 2 * 3 * k];
        for (i, c) in coeffs.iter().enumerate() {
            for row in 0..2 {
                for d in 0..3 {
                    m[row * 3 * k + 3 * i + d] = c * r[(row, d)];
                }
            }
        }
        let (rr, cc) = synchronise_rotation(&m, k);
        for i in 0..k {
            assert!((cc[i] - coeffs[i]).abs() < 1e-9, "{cc:?}");
        }
        assert!((rr.fixed_rows::<2>(0) - r.fixed_rows::<2>(0)).norm() < 1e-9);
    }
}
