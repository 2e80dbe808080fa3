//! The C-step: minimise over the coefficients C (F x k)
//!
//! ```text
//! f(C) = 1/2 sum_t |y_t - X_t c_t|^2 + alpha ||C||_1 + beta/2 sum_t |c_t - c_t+1|^2
//! ```
//!
//! where column `i` of `X_t` (2p) is `vec(Pi R_t B_i)` scaled by the square roots of the
//! joint weights, and `y_t` the weighted, centred 2D joints.
//!
//! Three solvers minimise it ([`CoefficientSolver`]):
//! - [`active_set`] (the default): feature-sign active-set steps with exact Newton
//!   solves over the window (block-tridiagonal in time);
//! - [`apg`]: accelerated proximal gradient (Nesterov) with step `1/L`, soft threshold
//!   `alpha/L` and adaptive restart (O'Donoghue & Candès, gradient scheme), stopping on
//!   the relative change of C: the paper's method. `L` must bound the
//!   Hessian `blockdiag(X_t' X_t) + beta (Lap ⊗ I)`: see [`lipschitz_bound`]. The
//!   reference takes it from the first frame only, which can be too small; ours holds
//!   for every frame;
//! - [`cd`]: coordinate descent with an active set.
//!
//! The dictionaries' atoms are strongly correlated (for the K128 dictionary
//! `lambda_max(Bvec'Bvec)` = 7015 against 65 per atom), so the global step `1/L` of APG
//! is ~100x shorter than a coordinate's, and even coordinate descent needs hundreds of
//! sweeps to settle; the active-set method's Newton steps do not care.

pub mod active_set;
pub mod apg;
pub mod cd;

use nalgebra::Matrix3;

pub(crate) use super::dot;
use super::{Observations, sq_norm};
use crate::dictionary::Dictionary;

/// Per-frame design matrices and data of one C-step.
#[derive(Debug, Clone, Default)]
pub struct CoefficientProblem {
    k: usize,
    rows: usize,
    frames: usize,
    /// Frame t, column i at `x[(t*k + i)*rows ..][..rows]`.
    x: Vec<f64>,
    /// Frame t at `y[t*rows..][..rows]`.
    y: Vec<f64>,
    /// `X_t' y_t`, frame t at `xty[t*k..][..k]`.
    xty: Vec<f64>,
    /// `|X_t[:, i]|^2`, frame t at `h[t*k..][..k]`.
    h: Vec<f64>,
    /// Coefficients of the frozen frame before the window (empty: none). With an anchor
    /// `a`, the smoothness term gains `beta/2 |c_0 - a|^2`.
    anchor: Vec<f64>,
    /// Coefficients of the frozen frame after the window (empty: none): the smoothness
    /// term gains `beta/2 |c_F-1 - b|^2`.
    after: Vec<f64>,
    /// Square roots of one frame's joint weights (a buffer of [`Self::build`]).
    sqrt_weights: Vec<f64>,
}

/// Which algorithm solves the C-step: `active-set`, `coordinate-descent` (or `cd`) or
/// `apg`, by one parser (serde's) for the configuration and, through
/// [`std::str::FromStr`], the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CoefficientSolver {
    /// Active-set (feature-sign) method with Newton steps over the window.
    #[default]
    #[serde(alias = "as")]
    ActiveSet,
    /// Coordinate descent with an active set.
    #[serde(alias = "cd")]
    CoordinateDescent,
    /// Accelerated proximal gradient with restart (the paper's choice).
    Apg,
}

impl std::str::FromStr for CoefficientSolver {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        super::from_name(s)
            .map_err(|_| format!("unknown C-step solver `{s}` (expected active-set, cd or apg)"))
    }
}

impl std::fmt::Display for CoefficientSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&super::name_of(self))
    }
}

/// What one C-step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoefficientInfo {
    /// APG steps taken.
    pub steps: usize,
    /// Objective before the step.
    pub objective_before: f64,
    /// Objective after the step (never above `objective_before`).
    pub objective_after: f64,
    /// The penalty part of `objective_after`: `alpha ||C||_1 + beta/2 |grad_t C|^2`.
    pub penalty: f64,
}

impl CoefficientProblem {
    /// The report of a finished iterative solve started at `ws.start` with objective
    /// `objective_before`: the objective at `c`, or, if `c` is worse, `c` put back to the
    /// start (so no solver ever returns a worse point than it was given).
    fn conclude(
        &self,
        c: &mut [f64],
        steps: usize,
        objective_before: f64,
        alpha: f64,
        beta: f64,
        ws: &mut CoefficientWorkspace,
    ) -> CoefficientInfo {
        let mut penalty = self.penalty(c, alpha, beta);
        let mut objective_after = self.loss(c, &mut ws.u) + penalty;
        if objective_after > objective_before {
            c.copy_from_slice(&ws.start);
            penalty = self.penalty(c, alpha, beta);
            objective_after = objective_before;
        }
        CoefficientInfo {
            steps,
            objective_before,
            objective_after,
            penalty,
        }
    }
}

/// Largest eigenvalue of the path-graph Laplacian on `f` nodes, `2 - 2 cos(pi (f-1)/f)`.
pub fn laplacian_max_eigenvalue(f: usize) -> f64 {
    if f < 2 {
        0.0
    } else {
        2.0 - 2.0 * (std::f64::consts::PI * (f as f64 - 1.0) / f as f64).cos()
    }
}

/// A Lipschitz bound for the gradient of the smooth part, valid for every frame:
/// `max_weight * lambda_max(Bvec' Bvec) + beta * lambda_max(Lap_F)`, where `Bvec` holds
/// `vec(B_i)` as columns. It holds because every `R_t` has orthonormal rows. With an
/// anchor, pass `frames + 1`: the anchored Laplacian is a principal submatrix of the
/// path Laplacian over the window and the anchor (with anchors on both sides,
/// `frames + 2`).
pub fn lipschitz_bound(basis_gram_max: f64, max_weight: f64, beta: f64, frames: usize) -> f64 {
    basis_gram_max * max_weight + beta * laplacian_max_eigenvalue(frames)
}

/// `lambda_max(Bvec' Bvec)` of a dictionary (the squared largest singular value of the
/// 3p x k matrix of vectorised bases), via faer.
pub fn basis_gram_max(dict: &Dictionary) -> f64 {
    let n = 3 * dict.num_joints();
    let k = dict.num_bases();
    let m = faer::Mat::<f64>::from_fn(n, k, |r, i| dict.basis(i)[r]);
    match m.singular_values() {
        Ok(s) => s.first().map_or(0.0, |s| s * s),
        // Fallback: the Frobenius norm bounds the spectral norm.
        Err(_) => sq_norm(dict.bases()),
    }
}

impl CoefficientProblem {
    /// Fills the design for `frames` frames: centred joints `obs` minus each frame's
    /// translation, rotations `rotations`.
    pub fn build(
        &mut self,
        dict: &Dictionary,
        obs: &Observations,
        rotations: impl Iterator<Item = Matrix3<f64>>,
        translations: &[nalgebra::Vector2<f64>],
    ) {
        let p = dict.num_joints();
        let k = dict.num_bases();
        let rows = 2 * p;
        let frames = obs.frames();
        self.k = k;
        self.rows = rows;
        self.frames = frames;
        self.x.resize(frames * k * rows, 0.0);
        self.y.resize(frames * rows, 0.0);
        self.xty.resize(frames * k, 0.0);
        self.h.resize(frames * k, 0.0);
        let mut sw = std::mem::take(&mut self.sqrt_weights);
        sw.clear();
        sw.resize(p, 0.0);
        for (t, r) in rotations.enumerate().take(frames) {
            for (s, w) in sw.iter_mut().zip(obs.frame_weights(t)) {
                *s = w.sqrt();
            }
            let xy = obs.frame(t);
            let tr = translations[t];
            // Rows in planar order (every joint's x, then every joint's y): the loops
            // below then run over contiguous joints and vectorise.
            // The data less the translation and the image of the dictionary's offset
            // (zero but for an adapted dictionary, `super::adapt`).
            let y = &mut self.y[t * rows..(t + 1) * rows];
            let d = dict.offset();
            let (dx, rest) = d.split_at(p);
            let (dy, dz) = rest.split_at(p);
            for j in 0..p {
                let u = r[(0, 0)] * dx[j] + r[(0, 1)] * dy[j] + r[(0, 2)] * dz[j];
                let v = r[(1, 0)] * dx[j] + r[(1, 1)] * dy[j] + r[(1, 2)] * dz[j];
                y[j] = sw[j] * (xy[2 * j] - tr.x - u);
                y[p + j] = sw[j] * (xy[2 * j + 1] - tr.y - v);
            }
            let y = &self.y[t * rows..(t + 1) * rows];
            for i in 0..k {
                let b = dict.basis(i);
                let (bx, rest) = b.split_at(p);
                let (by, bz) = rest.split_at(p);
                let col = &mut self.x[(t * k + i) * rows..(t * k + i + 1) * rows];
                let (u, v) = col.split_at_mut(p);
                for j in 0..p {
                    u[j] = sw[j] * (r[(0, 0)] * bx[j] + r[(0, 1)] * by[j] + r[(0, 2)] * bz[j]);
                    v[j] = sw[j] * (r[(1, 0)] * bx[j] + r[(1, 1)] * by[j] + r[(1, 2)] * bz[j]);
                }
                self.xty[t * k + i] = dot(col, y);
                self.h[t * k + i] = dot(col, col);
            }
        }
        self.sqrt_weights = sw;
    }

    fn frame_x(&self, t: usize) -> &[f64] {
        &self.x[t * self.k * self.rows..(t + 1) * self.k * self.rows]
    }

    /// Sets (or clears) the anchor: the coefficients of the frozen frame just before the
    /// window, which the first frame is pulled towards by the smoothness term. Clears
    /// the anchor after the window.
    pub fn set_anchor(&mut self, anchor: Option<&[f64]>) {
        self.set_anchors(anchor, None);
    }

    /// Sets (or clears) both anchors: the coefficients of the frozen frames just before
    /// and just after the window, which its first and last frames are pulled towards.
    pub fn set_anchors(&mut self, before: Option<&[f64]>, after: Option<&[f64]>) {
        for (v, a) in [(&mut self.anchor, before), (&mut self.after, after)] {
            v.clear();
            if let Some(a) = a {
                v.extend_from_slice(a);
            }
        }
    }

    /// The anchor coefficients before frame 0, if any.
    fn anchor(&self) -> Option<&[f64]> {
        (!self.anchor.is_empty()).then_some(&self.anchor[..])
    }

    /// The anchor coefficients after the last frame, if any.
    fn after(&self) -> Option<&[f64]> {
        (!self.after.is_empty()).then_some(&self.after[..])
    }

    /// The frozen neighbours of frame `t` through the smoothness term: 0, 1 or 2 of the
    /// anchors (frame 0 may have the one before, the last frame the one after).
    fn anchors_of(&self, t: usize) -> impl Iterator<Item = &[f64]> {
        let before = self.anchor().filter(|_| t == 0);
        let after = self.after().filter(|_| t + 1 == self.frames);
        before.into_iter().chain(after)
    }

    /// True when the smoothness term couples anything (two frames, or an anchor).
    fn smoothness_active(&self, beta: f64) -> bool {
        beta > 0.0 && (self.frames > 1 || self.anchor().is_some() || self.after().is_some())
    }

    /// The smooth data part `1/2 sum_t |y_t - X_t c_t|^2`.
    pub fn loss(&self, c: &[f64], scratch: &mut Vec<f64>) -> f64 {
        scratch.resize(self.rows, 0.0);
        let mut loss = 0.0;
        for t in 0..self.frames {
            let u = &mut scratch[..];
            x_times(self.frame_x(t), &c[t * self.k..(t + 1) * self.k], u);
            let y = &self.y[t * self.rows..(t + 1) * self.rows];
            loss += u.iter().zip(y).map(|(u, y)| (u - y) * (u - y)).sum::<f64>();
        }
        0.5 * loss
    }

    /// `alpha ||C||_1 + beta/2 sum_t |c_t - c_t+1|^2`, plus `beta/2 |c_0 - a|^2` with an
    /// anchor `a` before and `beta/2 |c_F-1 - b|^2` with an anchor `b` after.
    pub fn penalty(&self, c: &[f64], alpha: f64, beta: f64) -> f64 {
        let l1: f64 = c.iter().map(|v| v.abs()).sum();
        let mut smooth = 0.0;
        let k = self.k;
        let last = self.frames.saturating_sub(1);
        for (a, t) in [(self.anchor(), 0), (self.after(), last)] {
            if let Some(a) = a {
                smooth += a
                    .iter()
                    .zip(&c[t * k..(t + 1) * k])
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>();
            }
        }
        for t in 1..self.frames {
            let (a, b) = (
                &c[(t - 1) * self.k..t * self.k],
                &c[t * self.k..(t + 1) * self.k],
            );
            smooth += a.iter().zip(b).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
        }
        alpha * l1 + 0.5 * beta * smooth
    }

    /// Runs the chosen solver from `c`, in place.
    pub fn solve_with(
        &self,
        solver: CoefficientSolver,
        c: &mut [f64],
        alpha: f64,
        beta: f64,
        lipschitz: f64,
        tol: f64,
        objective_tol: f64,
        max_steps: usize,
        admit_per_frame: usize,
        ws: &mut CoefficientWorkspace,
    ) -> CoefficientInfo {
        match solver {
            CoefficientSolver::ActiveSet => self.solve_active_set(
                c,
                alpha,
                beta,
                objective_tol,
                max_steps,
                admit_per_frame,
                ws,
            ),
            CoefficientSolver::Apg => self.solve_apg(c, alpha, beta, lipschitz, tol, max_steps, ws),
            CoefficientSolver::CoordinateDescent => {
                self.solve_cd(c, alpha, beta, tol, objective_tol, max_steps, ws)
            }
        }
    }

    /// Gradient of the smooth part at `z` into `g`.
    fn gradient(&self, z: &[f64], beta: f64, g: &mut [f64], u: &mut [f64]) {
        let (k, f) = (self.k, self.frames);
        for t in 0..f {
            let x = self.frame_x(t);
            let zt = &z[t * k..(t + 1) * k];
            x_times(x, zt, u);
            let gt = &mut g[t * k..(t + 1) * k];
            xt_times(x, u, gt);
            for (g, b) in gt.iter_mut().zip(&self.xty[t * k..(t + 1) * k]) {
                *g -= b;
            }
        }
        if beta > 0.0 {
            if let Some(a) = self.anchor() {
                for ((g, z), a) in g[..k].iter_mut().zip(&z[..k]).zip(a) {
                    *g += beta * (z - a);
                }
            }
            if let (Some(b), true) = (self.after(), f > 0) {
                let last = (f - 1) * k..f * k;
                for ((g, z), b) in g[last.clone()].iter_mut().zip(&z[last]).zip(b) {
                    *g += beta * (z - b);
                }
            }
        }
        if beta > 0.0 && f > 1 {
            for t in 0..f {
                let gt = &mut g[t * k..(t + 1) * k];
                let zt = &z[t * k..(t + 1) * k];
                if t > 0 {
                    let zp = &z[(t - 1) * k..t * k];
                    for i in 0..k {
                        gt[i] += beta * (zt[i] - zp[i]);
                    }
                }
                if t + 1 < f {
                    let zn = &z[(t + 1) * k..(t + 2) * k];
                    for i in 0..k {
                        gt[i] += beta * (zt[i] - zn[i]);
                    }
                }
            }
        }
    }
}

/// Reusable buffers of the C-step solvers: allocate once, reuse for every window.
#[derive(Debug, Clone, Default)]
pub struct CoefficientWorkspace {
    active_set: active_set::ActiveSetWorkspace,
    z: Vec<f64>,
    grad: Vec<f64>,
    prev: Vec<f64>,
    start: Vec<f64>,
    u: Vec<f64>,
    resid: Vec<f64>,
}

impl CoefficientWorkspace {
    fn prepare(&mut self, n: usize, rows: usize) {
        self.z.resize(n, 0.0);
        self.grad.resize(n, 0.0);
        self.prev.resize(n, 0.0);
        self.start.resize(n, 0.0);
        self.u.resize(rows, 0.0);
    }
}

/// `out = X z` for column-major `x` (columns of `out.len()`), skipping zero coefficients.
#[inline]
fn x_times(x: &[f64], z: &[f64], out: &mut [f64]) {
    let rows = out.len();
    out.iter_mut().for_each(|v| *v = 0.0);
    for (col, &zi) in x.chunks_exact(rows).zip(z) {
        if zi != 0.0 {
            for (o, c) in out.iter_mut().zip(col) {
                *o += zi * c;
            }
        }
    }
}

/// `out = X' u`.
#[inline]
fn xt_times(x: &[f64], u: &[f64], out: &mut [f64]) {
    for (o, col) in out.iter_mut().zip(x.chunks_exact(u.len())) {
        *o = dot(col, u);
    }
}
