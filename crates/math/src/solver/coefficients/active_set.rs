//! The default C-step solver: an active-set (feature-sign) method with exact Newton
//! steps over the whole window.
//!
//! The objective is a quadratic plus `alpha ||C||_1`. On a set `A` of non-zero
//! coefficients with fixed signs `theta` it is the smooth quadratic
//! `q(C) = L(C) + alpha theta' C_A`, whose Hessian `H_AA` is block-tridiagonal over the
//! frames (`X_t' X_t` on the active atoms of frame t, plus `beta` times the path
//! Laplacian, which couples an atom to itself in the neighbouring frames). Each
//! iteration (Lee et al., "Efficient sparse coding algorithms", NIPS 2006, extended to
//! the temporal term):
//!
//! 1. computes the gradient of the smooth part; stops when the KKT conditions hold
//!    (`|g_i + alpha theta_i|` small on `A`, `|g_i| <= alpha` off `A`);
//! 2. admits, in every frame, the zero coefficient that violates `|g_i| <= alpha` most,
//!    with sign `-sign(g_i)`;
//! 3. solves the Newton system `H_AA d = -(g_A + alpha theta_A)` by block Cholesky
//!    ([`BlockTridiagonal`]); a newly admitted coefficient whose direction leaves its
//!    orthant is dropped again;
//! 4. steps to the minimum of `q` along `d`, or to the first point where an active
//!    coefficient reaches zero, whichever comes first (that coefficient leaves `A`).
//!    Up to that point the true objective equals `q`, which decreases along `d`, so the
//!    objective never increases.
//!
//! The atoms of the authors' dictionaries are strongly correlated (K128:
//! `lambda_max(Bvec' Bvec)` = 7015 against 65 per atom), which makes first-order
//! methods creep; with fewer than ten active atoms per frame the Newton systems are tiny
//! and a warm-started C-step takes a few iterations.

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};

use super::{CoefficientInfo, CoefficientProblem, CoefficientWorkspace, dot};
use crate::solver::block_tridiagonal::BlockTridiagonal;
use crate::solver::zeroed_with_room;

/// KKT tolerance on the gradient, relative to `max(alpha, 1)`.
const KKT_TOLERANCE: f64 = 1e-9;
/// Relative pivot floor of the block Cholesky (guards against collinear atoms).
const PIVOT_FLOOR: f64 = 1e-12;
const NONE: u32 = u32::MAX;

/// Buffers of [`CoefficientProblem::solve_active_set`].
#[derive(Debug, Clone, Default)]
pub struct ActiveSetWorkspace {
    resid: Vec<f64>,
    grad: Vec<f64>,
    /// `theta` on the active set, 0 elsewhere (frame-major, like C).
    sign: Vec<f64>,
    /// Position of each coefficient in its frame's active list, or `NONE`.
    slot: Vec<u32>,
    active: Vec<Vec<u32>>,
    /// Coefficients admitted in this iteration (`t*k + i`).
    fresh: Vec<u32>,
    candidates: Vec<(f64, u32)>,
    dir: Vec<f64>,
    xd: Vec<f64>,
    /// The active columns of each frame's design, gathered (rows x a_t per frame).
    xa: Vec<f64>,
    trial: Vec<f64>,
    trial_resid: Vec<f64>,
    system: BlockTridiagonal,
    /// The most frames, and the largest active set of a frame, seen so far.
    peak: (usize, usize),
}

impl CoefficientProblem {
    /// Minimises by the active-set method from `c`, in place; at most `max_iterations`
    /// Newton steps, each admitting at most `admit_per_frame` coefficients per frame
    /// (at least 1). Stops at a KKT point, or when an iteration lowers the objective by
    /// less than `objective_tol` (relative).
    pub fn solve_active_set(
        &self,
        c: &mut [f64],
        alpha: f64,
        beta: f64,
        objective_tol: f64,
        max_iterations: usize,
        admit_per_frame: usize,
        ws: &mut CoefficientWorkspace,
    ) -> CoefficientInfo {
        let (k, f, rows) = (self.k, self.frames, self.rows);
        let admit = admit_per_frame.max(1);
        let beta = if self.smoothness_active(beta) {
            beta
        } else {
            0.0
        };
        let a = &mut ws.active_set;
        a.resid.resize(f * rows, 0.0);
        a.grad.resize(f * k, 0.0);
        a.sign.clear();
        a.sign.extend(c.iter().map(|&v| sign_of(v)));
        a.slot.resize(f * k, NONE);
        // Never shrunk (a window of f frames after one of more keeps their lists), and
        // each list holds up to k: once warm, nothing here allocates.
        if a.active.len() < f {
            a.active.resize_with(f, Vec::new);
        }
        for t in 0..f {
            a.active[t].clear();
            a.active[t].reserve(k);
            a.active[t].extend((0..k as u32).filter(|&i| c[t * k + i as usize] != 0.0));
        }
        a.candidates.clear();
        a.candidates.reserve(k);
        a.fresh.clear();
        a.fresh.reserve(f * k);
        self.residual(c, &mut a.resid);
        let penalty = |c: &[f64]| self.penalty(c, alpha, beta);
        let objective_before = 0.5 * dot(&a.resid, &a.resid) + penalty(c);
        let mut fval = objective_before;
        let kkt_tol = KKT_TOLERANCE * alpha.max(1.0);
        let mut iterations = 0;
        while iterations < max_iterations {
            iterations += 1;
            self.smooth_gradient(c, beta, &a.resid, &mut a.grad);
            // 1. KKT on the active set; 2. admit the worst violators of each frame.
            let mut worst = 0.0_f64;
            a.fresh.clear();
            for t in 0..f {
                let g = &a.grad[t * k..(t + 1) * k];
                let s = &mut a.sign[t * k..(t + 1) * k];
                a.candidates.clear();
                for i in 0..k {
                    if s[i] != 0.0 {
                        worst = worst.max((g[i] + alpha * s[i]).abs());
                    } else if g[i].abs() > alpha + kkt_tol {
                        a.candidates.push((g[i].abs(), i as u32));
                    }
                }
                if a.candidates.len() > admit {
                    a.candidates
                        .select_nth_unstable_by(admit, |x, y| y.0.total_cmp(&x.0));
                    a.candidates.truncate(admit);
                }
                for &(_, i) in &a.candidates {
                    s[i as usize] = -sign_of(g[i as usize]);
                    a.active[t].push(i);
                    a.fresh.push((t * k) as u32 + i);
                }
            }
            let admitted = !a.fresh.is_empty();
            if !admitted && worst <= kkt_tol {
                break;
            }
            // 3. Newton direction; drop admitted coefficients that would leave their orthant.
            loop {
                self.newton_direction(beta, alpha, a);
                let before = a.fresh.len();
                let (dir, sign, slot, system, active) =
                    (&a.dir, &mut a.sign, &a.slot, &a.system, &mut a.active);
                a.fresh.retain(|&idx| {
                    let (idx, t) = (idx as usize, idx as usize / k);
                    let d = dir[system.offset(t) + slot[idx] as usize];
                    let keep = d * sign[idx] > 0.0;
                    if !keep {
                        sign[idx] = 0.0;
                        active[t].retain(|&j| j as usize != idx % k);
                    }
                    keep
                });
                if a.fresh.len() == before {
                    break;
                }
            }
            // 4. Step: minimum of q along d, or the first coefficient reaching zero.
            let (mut gd, mut s_break, mut breaking) = (0.0, f64::INFINITY, usize::MAX);
            for t in 0..f {
                let off = a.system.offset(t);
                for (pos, &i) in a.active[t].iter().enumerate() {
                    let idx = t * k + i as usize;
                    let d = a.dir[off + pos];
                    gd += (a.grad[idx] + alpha * a.sign[idx]) * d;
                    if c[idx] != 0.0 && d * a.sign[idx] < 0.0 && -c[idx] / d < s_break {
                        s_break = -c[idx] / d;
                        breaking = idx;
                    }
                }
            }
            if gd.is_nan() || gd >= 0.0 {
                break; // no descent direction left (numerically converged)
            }
            let curvature = self.direction_curvature(beta, a);
            let s_min = if curvature > 0.0 {
                -gd / curvature
            } else {
                f64::INFINITY
            };
            if !s_min.is_finite() && !s_break.is_finite() {
                break;
            }
            // 4a. Steps that cross zero in several frames at once: try the full step with
            // crossing coefficients set to zero (orthant projection), kept only if it
            // lowers the objective.
            if s_break < s_min && s_min.is_finite() {
                a.trial.clear();
                a.trial.extend_from_slice(c);
                for t in 0..f {
                    let off = a.system.offset(t);
                    for (pos, &i) in a.active[t].iter().enumerate() {
                        let idx = t * k + i as usize;
                        let v = c[idx] + s_min * a.dir[off + pos];
                        a.trial[idx] = if v * a.sign[idx] > 0.0 { v } else { 0.0 };
                    }
                }
                a.trial_resid.resize(f * rows, 0.0);
                self.residual(&a.trial, &mut a.trial_resid);
                let trial_f = 0.5 * dot(&a.trial_resid, &a.trial_resid) + penalty(&a.trial);
                if trial_f < fval {
                    c.copy_from_slice(&a.trial);
                    std::mem::swap(&mut a.resid, &mut a.trial_resid);
                    self.drop_zeros(c, a);
                    let settled = fval - trial_f <= objective_tol * trial_f.abs();
                    fval = trial_f;
                    if settled && !admitted {
                        break;
                    }
                    continue;
                }
            }
            // 4b. Exact step along d, to the minimum of q or the first zero crossing.
            let step = s_min.min(s_break);
            if step <= 0.0 {
                break;
            }
            for t in 0..f {
                let off = a.system.offset(t);
                for (pos, &i) in a.active[t].iter().enumerate() {
                    c[t * k + i as usize] += step * a.dir[off + pos];
                }
                let r = &mut a.resid[t * rows..(t + 1) * rows];
                for (r, xd) in r.iter_mut().zip(&a.xd[t * rows..(t + 1) * rows]) {
                    *r -= step * xd;
                }
            }
            if step >= s_break {
                // The coefficient that reached zero (and any that crossed it by
                // rounding) leaves A.
                c[breaking] = 0.0;
                self.drop_zeros(c, a);
                self.residual(c, &mut a.resid);
            }
            let new_fval = 0.5 * dot(&a.resid, &a.resid) + penalty(c);
            let settled = fval - new_fval <= objective_tol * new_fval.abs();
            fval = new_fval;
            if settled && !admitted {
                break;
            }
        }
        // `fval` tracks the objective at `c` after every change (residuals kept up to date).
        CoefficientInfo {
            steps: iterations,
            objective_before,
            objective_after: fval,
            penalty: penalty(c),
        }
    }

    /// Removes from the active set the coefficients that are zero or crossed zero.
    fn drop_zeros(&self, c: &mut [f64], a: &mut ActiveSetWorkspace) {
        let k = self.k;
        for t in 0..self.frames {
            let (sign, active) = (&mut a.sign, &mut a.active[t]);
            active.retain(|&i| {
                let idx = t * k + i as usize;
                let keep = c[idx] * sign[idx] > 0.0;
                if !keep {
                    c[idx] = 0.0;
                    sign[idx] = 0.0;
                }
                keep
            });
        }
    }

    /// `r_t = y_t - X_t c_t` for every frame.
    fn residual(&self, c: &[f64], resid: &mut [f64]) {
        let (k, rows) = (self.k, self.rows);
        for t in 0..self.frames {
            let r = &mut resid[t * rows..(t + 1) * rows];
            r.copy_from_slice(&self.y[t * rows..(t + 1) * rows]);
            let x = self.frame_x(t);
            for (col, &ci) in x.chunks_exact(rows).zip(&c[t * k..(t + 1) * k]) {
                if ci != 0.0 {
                    for (r, x) in r.iter_mut().zip(col) {
                        *r -= ci * x;
                    }
                }
            }
        }
    }

    /// Gradient of the smooth part from the residuals: `-X_t' r_t + beta (Lap C)_t`.
    fn smooth_gradient(&self, c: &[f64], beta: f64, resid: &[f64], g: &mut [f64]) {
        let (k, f, rows) = (self.k, self.frames, self.rows);
        for t in 0..f {
            let r = MatRef::from_column_major_slice(&resid[t * rows..(t + 1) * rows], rows, 1);
            let x = MatRef::from_column_major_slice(self.frame_x(t), rows, k);
            let gt = &mut g[t * k..(t + 1) * k];
            let gm = MatMut::from_column_major_slice_mut(gt, k, 1);
            matmul(gm, Accum::Replace, x.transpose(), r, -1.0, Par::Seq);
            if beta > 0.0 {
                for anchor in self.anchors_of(t) {
                    for ((g, c), a) in gt.iter_mut().zip(&c[t * k..(t + 1) * k]).zip(anchor) {
                        *g += beta * (c - a);
                    }
                }
                for i in 0..k {
                    let cur = c[t * k + i];
                    if t > 0 {
                        gt[i] += beta * (cur - c[(t - 1) * k + i]);
                    }
                    if t + 1 < f {
                        gt[i] += beta * (cur - c[(t + 1) * k + i]);
                    }
                }
            }
        }
    }

    /// Builds and solves `H_AA d = -(g_A + alpha theta_A)` into `a.dir`.
    fn newton_direction(&self, beta: f64, alpha: f64, a: &mut ActiveSetWorkspace) {
        let (k, f, rows) = (self.k, self.frames, self.rows);
        for t in 0..f {
            for (pos, &i) in a.active[t].iter().enumerate() {
                a.slot[t * k + i as usize] = pos as u32;
            }
        }
        a.system.reset(a.active[..f].iter().map(Vec::len));
        // Room for the most frames seen, each with the largest active set seen.
        a.peak.0 = a.peak.0.max(f);
        a.peak.1 = a
            .peak
            .1
            .max(a.active[..f].iter().map(Vec::len).max().unwrap_or(0));
        let worst = a.peak.0 * a.peak.1;
        zeroed_with_room(&mut a.xa, rows * a.system.dim(), rows * worst);
        zeroed_with_room(&mut a.dir, a.system.dim(), worst);
        a.dir.clear();
        for t in 0..f {
            // Neighbours in time, the anchors included (they sit at the ends).
            let degree = usize::from(t > 0 || self.anchor().is_some())
                + usize::from(t + 1 < f || self.after().is_some());
            let x = self.frame_x(t);
            let atoms = &a.active[t];
            let na = atoms.len();
            // Gather the active columns, then D_t = X_A' X_A + beta deg(t) I.
            let xa = &mut a.xa[rows * a.system.offset(t)..rows * a.system.offset(t + 1)];
            for (col, &i) in xa.chunks_exact_mut(rows).zip(atoms) {
                col.copy_from_slice(&x[i as usize * rows..(i as usize + 1) * rows]);
            }
            let xa = MatRef::from_column_major_slice(xa, rows, na);
            let mut d = a.system.diag_mut(t);
            // Lower triangle only: the Cholesky factorisation reads nothing else.
            triangular::matmul(
                d.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Replace,
                xa.transpose(),
                BlockStructure::Rectangular,
                xa,
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
            for p in 0..na {
                d[(p, p)] += beta * degree as f64;
            }
            if beta > 0.0 && t > 0 {
                let mut l = a.system.lower_mut(t);
                for (p, &i) in atoms.iter().enumerate() {
                    let q = a.slot[(t - 1) * k + i as usize];
                    if q != NONE && a.sign[(t - 1) * k + i as usize] != 0.0 {
                        l[(p, q as usize)] = -beta;
                    }
                }
            }
            for &i in atoms {
                let idx = t * k + i as usize;
                a.dir.push(-(a.grad[idx] + alpha * a.sign[idx]));
            }
        }
        a.system.factor(PIVOT_FLOOR);
        a.system.solve_in_place(&mut a.dir);
    }

    /// `d' H d` for the direction in `a.dir`; also leaves `X_t d_t` in `a.xd`.
    fn direction_curvature(&self, beta: f64, a: &mut ActiveSetWorkspace) -> f64 {
        let (k, f, rows) = (self.k, self.frames, self.rows);
        a.xd.resize(f * rows, 0.0);
        let mut curvature = 0.0;
        for t in 0..f {
            let off = a.system.offset(t);
            let na = a.active[t].len();
            let xd = &mut a.xd[t * rows..(t + 1) * rows];
            let xa =
                MatRef::from_column_major_slice(&a.xa[rows * off..rows * (off + na)], rows, na);
            let dt = MatRef::from_column_major_slice(&a.dir[off..off + na], na, 1);
            matmul(
                MatMut::from_column_major_slice_mut(xd, rows, 1),
                Accum::Replace,
                xa,
                dt,
                1.0,
                Par::Seq,
            );
            curvature += dot(xd, xd);
            for _ in self.anchors_of(t).filter(|_| beta > 0.0) {
                // beta |d_t|^2 from each anchor term of frame t (the anchors are fixed).
                curvature += beta * dot(&a.dir[off..off + na], &a.dir[off..off + na]);
            }
            if beta > 0.0 && t > 0 {
                // beta |d_t - d_{t-1}|^2 over the union of both frames' atoms.
                let prev_off = a.system.offset(t - 1);
                let mut diff = 0.0;
                for (pos, &i) in a.active[t].iter().enumerate() {
                    let dt = a.dir[off + pos];
                    let q = a.slot[(t - 1) * k + i as usize];
                    let dp = if q != NONE && a.sign[(t - 1) * k + i as usize] != 0.0 {
                        a.dir[prev_off + q as usize]
                    } else {
                        0.0
                    };
                    diff += (dt - dp) * (dt - dp);
                }
                for (pos, &i) in a.active[t - 1].iter().enumerate() {
                    let q = a.slot[t * k + i as usize];
                    if q == NONE || a.sign[t * k + i as usize] == 0.0 {
                        let dp = a.dir[prev_off + pos];
                        diff += dp * dp;
                    }
                }
                curvature += beta * diff;
            }
        }
        curvature
    }
}

fn sign_of(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}
