//! Accelerated proximal gradient (FISTA) with adaptive restart: the paper's C-step.
//!
//! Step `1/L` with `L` from [`super::lipschitz_bound`], soft threshold `alpha/L`,
//! Nesterov momentum, restart when the step points against the last move (the gradient
//! scheme of O'Donoghue & Candès), stop on relative change of C. Slow on the authors'
//! dictionaries, whose atoms are strongly correlated: kept as the paper's method and as
//! an independent check of the other solvers.

use super::{CoefficientInfo, CoefficientProblem, CoefficientWorkspace};
use crate::solver::soft;

impl CoefficientProblem {
    /// Runs APG from `c` (F*k values, frame-major) and leaves the result in `c`.
    /// Never returns a worse point than it was given.
    pub fn solve_apg(
        &self,
        c: &mut [f64],
        alpha: f64,
        beta: f64,
        lipschitz: f64,
        tol: f64,
        max_steps: usize,
        ws: &mut CoefficientWorkspace,
    ) -> CoefficientInfo {
        let n = self.frames * self.k;
        debug_assert_eq!(c.len(), n);
        ws.prepare(n, self.rows);
        let objective_before = self.loss(c, &mut ws.u) + self.penalty(c, alpha, beta);
        ws.start.copy_from_slice(c);
        ws.prev.copy_from_slice(c);
        let step = 1.0 / lipschitz.max(f64::MIN_POSITIVE);
        let thresh = alpha * step;
        let (mut t_prev, mut t_cur) = (1.0_f64, 1.0_f64);
        let mut steps = 0;
        for _ in 0..max_steps {
            steps += 1;
            // Extrapolated point z = c + (t_prev - 1)/t_cur (c - prev).
            let mom = (t_prev - 1.0) / t_cur;
            for ((z, &ci), &pi) in ws.z.iter_mut().zip(c.iter()).zip(ws.prev.iter()) {
                *z = ci + mom * (ci - pi);
            }
            self.gradient(&ws.z, beta, &mut ws.grad, &mut ws.u);
            // Proximal step; restart test (z - c_new)'(c_new - c) > 0.
            let (mut restart, mut change, mut norm_old) = (0.0, 0.0, 0.0);
            for i in 0..n {
                let new = soft(ws.z[i] - step * ws.grad[i], thresh);
                let old = c[i];
                restart += (ws.z[i] - new) * (new - old);
                change += (new - old) * (new - old);
                norm_old += old * old;
                ws.prev[i] = old;
                c[i] = new;
            }
            if restart > 0.0 {
                t_prev = 1.0;
                t_cur = 1.0;
            } else {
                t_prev = t_cur;
                t_cur = 0.5 * (1.0 + (1.0 + 4.0 * t_cur * t_cur).sqrt());
            }
            if change.sqrt() < tol * (norm_old.sqrt() + f64::EPSILON) {
                break;
            }
        }
        self.conclude(c, steps, objective_before, alpha, beta, ws)
    }
}
