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

use super::{
    InitCache, InitInfo, InitWorkspace, complete_rotation, fit_rotation, single_frame_coefficients,
};
use crate::dictionary::Dictionary;
use crate::solver::{FrameFit, Params, axpy, dot, soft};

/// The basis matrix restricted to some joints and its thin SVD.
#[derive(Debug, Clone)]
pub struct BasisFactor {
    /// The joints (columns) kept.
    pub joints: Vec<usize>,
    /// Rows `3k`.
    rows: usize,
    /// Left singular vectors, column-major (3k x r).
    u: Vec<f64>,
    /// Squared singular values (r).
    s2: Vec<f64>,
    /// `B' U`, column-major (q x r): the image of the data in the range of `U`.
    bu: Vec<f64>,
    /// `B` column-major (each joint's 3k values contiguous).
    b_cols: Vec<f64>,
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
        let r = s2.len();
        let mut bu = vec![0.0; q * r];
        for c in 0..r {
            for jj in 0..q {
                bu[c * q + jj] = (0..rows)
                    .map(|row| b[row * q + jj] * u[c * rows + row])
                    .sum();
            }
        }
        let b_cols = (0..q)
            .flat_map(|jj| (0..rows).map(move |row| (row, jj)))
            .map(|(row, jj)| b[row * q + jj])
            .collect();
        Self {
            joints: joints.to_vec(),
            rows,
            u,
            s2,
            bu,
            b_cols,
        }
    }
}

/// Prox of `lam ||.||_2` (spectral norm) of a 2 x 3 block: returns the block and its
/// spectral norm.
///
/// With `Q = U S V'`, the prox shrinks the singular values: both to `w = (s1+s2-lam)/2`
/// when they are within `lam` of each other, else only the largest by `lam`. Both cases
/// are closed-form matrix functions of the 2 x 2 Gram matrix `A = Q Q'` (Cayley-Hamilton),
/// with `s1^2 + s2^2 = tr A` and `s1 s2 = sqrt(det A)`:
/// - `w U V' = w (s1 + s2) (A + s1 s2 I)^-1 Q`, since `sqrt(A) = (A + s1 s2 I)/(s1 + s2)`;
/// - `Q - lam u1 v1' = Q - lam/s1 (A - s2^2 I)/(s1^2 - s2^2) Q`, the projector on the top
///   singular direction being `(A - s2^2 I)/(s1^2 - s2^2)`.
fn prox_spectral(q: &Matrix2x3<f64>, lam: f64) -> (Matrix2x3<f64>, f64) {
    let a = q * q.transpose();
    let (tr, det) = (a.trace(), a.determinant().max(0.0));
    let half_gap = (0.25 * tr * tr - det).max(0.0).sqrt();
    let (l1, l2) = (0.5 * tr + half_gap, (0.5 * tr - half_gap).max(0.0));
    let (s1, s2) = (l1.sqrt(), l2.sqrt());
    if s1 + s2 <= lam {
        (Matrix2x3::zeros(), 0.0)
    } else if s1 - s2 <= lam {
        // Here s2 > 0 (s2 = 0 would need s1 > lam and s1 <= lam at once), so the
        // shifted Gram matrix is positive definite.
        let w = 0.5 * (s1 + s2 - lam);
        let shifted = a + Matrix2::identity() * (s1 * s2);
        match shifted.try_inverse() {
            Some(inv) => (inv * q * (w * (s1 + s2)), w),
            None => (Matrix2x3::zeros(), 0.0),
        }
    } else {
        // Here s1^2 - s2^2 > lam (s1 + s2) > 0.
        let projector = (a - Matrix2::identity() * l2) / (l1 - l2);
        (q - projector * q * (lam / s1), s1 - lam)
    }
}

/// Initialises one frame by the convex relaxation, then refines.
pub fn initialise(
    dict: &Dictionary,
    cache: &InitCache,
    w: &[f64],
    visible: &[bool],
    params: &Params,
    robust: bool,
    ws: &mut InitWorkspace,
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
    let admm_iterations = admm(
        factor,
        &wv,
        q,
        params.alpha,
        beta_o,
        params.max_init_iterations,
        &mut ws.admm,
    );
    let (r, c) = synchronise_rotation(&ws.admm.m, dict.num_bases());
    // Outliers back on the full joint list.
    let mut e_full = vec![0.0; w.len()];
    for (jj, &j) in joints.iter().enumerate() {
        e_full[2 * j] = ws.admm.e[2 * jj];
        e_full[2 * j + 1] = ws.admm.e[2 * jj + 1];
    }
    let s0 = dict.compose(&c);
    let (fit, alternations) = refine(dict, cache, w, visible, params, beta_o, &s0, r, e_full, ws);
    (
        fit,
        InitInfo {
            admm_iterations,
            alternations,
        },
    )
}

/// The ADMM's iterates, kept from one call to the next: a frame's ADMM starts from the
/// previous frame's solution. The problem is convex, so the start changes the number of
/// iterations, not the minimiser (up to the stopping tolerance).
#[derive(Debug, Clone, Default)]
pub struct AdmmState {
    /// Blocks `M_i`, row-major 2 x 3k.
    pub m: Vec<f64>,
    /// Outliers, `[x, y]` per kept joint.
    pub e: Vec<f64>,
    /// Translation.
    pub t: Vector2<f64>,
    y: Vec<f64>,
    mu: f64,
    /// Shape `(3k, q)` of the problem the iterates belong to; `None`: cold start.
    shape: Option<(usize, usize)>,
    z: Vec<f64>,
    z0: Vec<f64>,
    tmp: Vec<f64>,
    coef: Vec<f64>,
    data_u: Vec<f64>,
    resid: Vec<f64>,
    zb: Vec<f64>,
}

impl AdmmState {
    /// Forgets the iterates: the next call starts cold.
    pub fn reset(&mut self) {
        self.shape = None;
    }
}

/// ADMM on the convex relaxation; `w` holds `[x, y]` of the `q` kept joints. Starts from
/// `state` when it holds a problem of the same shape; returns the iterations run and
/// leaves the solution in `state`.
pub fn admm(
    f: &BasisFactor,
    w: &[f64],
    q: usize,
    lam: f64,
    beta_o: f64,
    max_iterations: usize,
    state: &mut AdmmState,
) -> usize {
    let n = f.rows; // 3k
    let k = n / 3;
    let r = f.s2.len();
    let tol = 1e-3;
    let st = state;
    let mean = |v: &[f64]| -> Vector2<f64> {
        let (mut sx, mut sy) = (0.0, 0.0);
        for xy in v.chunks_exact(2) {
            sx += xy[0];
            sy += xy[1];
        }
        Vector2::new(sx / q as f64, sy / q as f64)
    };
    if st.shape != Some((n, q)) {
        st.m.clear();
        st.m.resize(2 * n, 0.0);
        st.y.clear();
        st.y.resize(2 * n, 0.0);
        st.z.clear();
        st.z.resize(2 * n, 0.0);
        st.e.clear();
        st.e.resize(2 * q, 0.0);
        st.t = mean(w);
        let mean_abs = w.iter().map(|v| v.abs()).sum::<f64>() / w.len() as f64;
        st.mu = 1.0 / mean_abs.max(f64::MIN_POSITIVE);
        st.shape = Some((n, q));
    }
    st.z0.resize(2 * n, 0.0);
    st.tmp.resize(2 * n, 0.0);
    st.coef.resize(2 * r, 0.0);
    st.data_u.resize(2 * r, 0.0);
    st.resid.resize(2 * q, 0.0);
    st.zb.resize(2 * q, 0.0);
    let w_max = w.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let robust = beta_o <= w_max;
    if !robust {
        st.e.iter_mut().for_each(|v| *v = 0.0);
        st.t = mean(w);
    }
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        let mu = st.mu;
        st.z0.copy_from_slice(&st.z);
        // Z-step: Z = ((W - E - T 1') B' + mu M + Y) (B B' + mu I)^-1. With B = U S V'
        // and D = W - E - T 1', D B' = (D B'U) U', so
        // Z = M + Y/mu + [D B'U / mu + (D B'U + (mu M + Y) U) diag(1/(s2+mu) - 1/mu)] U'.
        for row in 0..2 {
            for jj in 0..q {
                st.resid[row * q + jj] = w[2 * jj + row] - st.e[2 * jj + row] - st.t[row];
            }
        }
        for row in 0..2 {
            let d = &st.resid[row * q..(row + 1) * q];
            let tmp = &mut st.tmp[row * n..(row + 1) * n];
            for ((tmp, m), y) in tmp.iter_mut().zip(&st.m[row * n..]).zip(&st.y[row * n..]) {
                *tmp = mu * m + y;
            }
            for c in 0..r {
                let du = dot(d, &f.bu[c * q..(c + 1) * q]);
                let mu_u = dot(tmp, &f.u[c * n..(c + 1) * n]);
                st.coef[row * r + c] = du / mu + (du + mu_u) * (1.0 / (f.s2[c] + mu) - 1.0 / mu);
            }
            let z = &mut st.z[row * n..(row + 1) * n];
            for ((z, m), y) in z.iter_mut().zip(&st.m[row * n..]).zip(&st.y[row * n..]) {
                *z = m + y / mu;
            }
            for c in 0..r {
                axpy(st.coef[row * r + c], &f.u[c * n..(c + 1) * n], z);
            }
        }
        // M-step: per-block prox of the spectral norm at Z - Y/mu.
        for i in 0..k {
            let qb = Matrix2x3::from_fn(|row, d| {
                let idx = row * n + 3 * i + d;
                st.z[idx] - st.y[idx] / mu
            });
            let (mb, _) = prox_spectral(&qb, lam / mu);
            for row in 0..2 {
                for d in 0..3 {
                    st.m[row * n + 3 * i + d] = mb[(row, d)];
                }
            }
        }
        if robust {
            // E = soft(W - Z B - T), T = mean(W - Z B - E).
            for jj in 0..q {
                let col = &f.b_cols[jj * n..(jj + 1) * n];
                st.zb[2 * jj] = dot(&st.z[..n], col);
                st.zb[2 * jj + 1] = dot(&st.z[n..], col);
            }
            for i in 0..2 * q {
                st.e[i] = soft(w[i] - st.zb[i] - st.t[i % 2], beta_o);
            }
            let (mut sx, mut sy) = (0.0, 0.0);
            for jj in 0..q {
                sx += w[2 * jj] - st.zb[2 * jj] - st.e[2 * jj];
                sy += w[2 * jj + 1] - st.zb[2 * jj + 1] - st.e[2 * jj + 1];
            }
            st.t = Vector2::new(sx / q as f64, sy / q as f64);
        }
        let (mut prim, mut dual, mut nz0) = (0.0, 0.0, 0.0);
        for i in 0..2 * n {
            st.y[i] += mu * (st.m[i] - st.z[i]);
            prim += (st.m[i] - st.z[i]).powi(2);
            dual += (st.z[i] - st.z0[i]).powi(2);
            nz0 += st.z0[i] * st.z0[i];
        }
        if nz0 == 0.0 {
            continue; // first step: residuals undefined, as in the reference
        }
        let (prim, dual) = (prim.sqrt() / nz0.sqrt(), mu * dual.sqrt() / nz0.sqrt());
        if prim < tol && dual < tol {
            break;
        }
        if prim > 10.0 * dual {
            st.mu *= 2.0;
        } else if dual > 10.0 * prim {
            st.mu /= 2.0;
        }
    }
    iterations
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
    ws: &mut InitWorkspace,
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
    let mut fval = f64::INFINITY;
    let mut iterations = 0;
    for _ in 0..params.max_init_iterations {
        iterations += 1;
        for j in 0..p {
            fit_w[2 * j] = w[2 * j] - e[2 * j] - t.x;
            fit_w[2 * j + 1] = w[2 * j + 1] - e[2 * j + 1] - t.y;
        }
        fit_rotation(&s, &fit_w, &d, &mut r);
        single_frame_coefficients(dict, cache, &fit_w, &d, &r, &mut c, params, ws);
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
        let rank_one = Matrix2x3::new(1.0, 2.0, -0.5, 2.0, 4.0, -1.0);
        let equal = Matrix2x3::new(2.0, 0.0, 0.0, 0.0, 0.0, 2.0);
        // Singular values of q: 3.27, 2.25. Zero, both shrink, only the top one shrinks.
        for (q, lam) in [
            (q, 0.7),
            (q, 2.0),
            (q, 6.0),
            (rank_one, 0.5),
            (rank_one, 8.0),
            (equal, 0.3),
        ] {
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
                    assert!(obj(&y) >= best - 1e-12, "{q} {lam}");
                }
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
