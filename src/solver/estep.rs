//! The E-step (paper eq. 15): the expected location of each joint under
//! `heat map x Gaussian(current projection, sigma)`, over the pixel grid.
//!
//! The reference weights pixel `(x, y)` by `(g(x, y) + eps) (h(x, y) + eps)` with `g` the
//! Gaussian, `h` the clipped map and `eps` machine epsilon, and returns the weighted mean
//! of pixel centres and the weighted trace of the covariance. We compute exactly that,
//! but fast:
//! - the Gaussian is separable, `g = gx(c) gy(r)`: 2 x 64 exponentials, not 4096;
//! - the `eps` terms need only sums of `h`, `h x`, `h y`, `h (x^2+y^2)`, computed once per
//!   map ([`MapMoments`]) and grid sums in closed form;
//! - rows and columns where the Gaussian factor is below 1e-20 are skipped (their
//!   contribution is far below the `eps` terms);
//! - what remains is three axpys per row and six dot products.

/// Sums of a clipped map that the E-step reuses every EM iteration.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MapMoments {
    /// `sum h`.
    pub h: f64,
    /// `sum h x`.
    pub hx: f64,
    /// `sum h y`.
    pub hy: f64,
    /// `sum h (x^2 + y^2)`.
    pub hr2: f64,
}

impl MapMoments {
    /// Moments of a map (values already clipped at 0), `w` columns.
    pub fn new(map: &[f32], w: usize) -> Self {
        let mut m = Self::default();
        for (r, row) in map.chunks_exact(w).enumerate() {
            let ry = r as f64;
            let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
            for (c, &v) in row.iter().enumerate() {
                let (v, x) = (v as f64, c as f64);
                s0 += v;
                s1 += v * x;
                s2 += v * x * x;
            }
            m.h += s0;
            m.hx += s1;
            m.hy += s0 * ry;
            m.hr2 += s2 + s0 * ry * ry;
        }
        m
    }
}

/// One joint's E-step result, in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Expectation {
    /// Expected x.
    pub x: f64,
    /// Expected y.
    pub y: f64,
    /// Trace of the 2D covariance (pixels^2).
    pub variance: f64,
}

/// Reusable buffers of [`expectation`].
#[derive(Debug, Clone, Default)]
pub struct EStepWorkspace {
    gx: Vec<f64>,
    gxc: Vec<f64>,
    gxc2: Vec<f64>,
    gy: Vec<f64>,
    v0: Vec<f64>,
    v1: Vec<f64>,
    v2: Vec<f64>,
}

use super::dot;

const CUTOFF: f64 = 1e-20;

/// `g[i] = exp(-(i - mean)^2 / (2 sigma^2))` for `i` in `0..n`, by the recurrence
/// `g[i+1] = g[i] q_i`, `q_{i+1} = q_i exp(-1/sigma^2)`, outward from the grid point
/// nearest the mean: four exponentials instead of `n` (relative error ~ n ulp; values
/// below the smallest normal flush to zero as the exponential's would).
fn gaussian_profile(mean: f64, sigma: f64, n: usize, g: &mut Vec<f64>) {
    g.clear();
    g.resize(n, 0.0);
    if n == 0 {
        return;
    }
    let inv = 0.5 / (sigma * sigma);
    let centre = mean.round().clamp(0.0, (n - 1) as f64) as usize;
    let d0 = centre as f64 - mean;
    g[centre] = (-d0 * d0 * inv).exp();
    let step = (-2.0 * inv).exp();
    // Upward: g[i+1]/g[i] = exp(-(2 (i - mean) + 1) inv).
    let mut q = (-(2.0 * d0 + 1.0) * inv).exp();
    for i in centre + 1..n {
        g[i] = g[i - 1] * q;
        q *= step;
    }
    // Downward: g[i-1]/g[i] = exp((2 (i - mean) - 1) inv).
    let mut q = ((2.0 * d0 - 1.0) * inv).exp();
    for i in (0..centre).rev() {
        g[i] = g[i + 1] * q;
        q *= step;
    }
    for v in g.iter_mut() {
        if !v.is_normal() {
            *v = 0.0;
        }
    }
}

const EPS: f64 = f64::EPSILON;

/// Expected location of a joint: `map` (h x w, clipped at 0) with moments `mom`, Gaussian
/// of standard deviation `sigma` (pixels) around `(px, py)` (pixels).
#[allow(clippy::too_many_arguments)]
pub fn expectation(
    map: &[f32],
    h: usize,
    w: usize,
    mom: &MapMoments,
    px: f64,
    py: f64,
    sigma: f64,
    ws: &mut EStepWorkspace,
) -> Expectation {
    gaussian_profile(px, sigma, w, &mut ws.gx);
    gaussian_profile(py, sigma, h, &mut ws.gy);
    let window = |g: &[f64]| -> (usize, usize) {
        let lo = g.iter().position(|&v| v >= CUTOFF).unwrap_or(g.len());
        let hi = g.iter().rposition(|&v| v >= CUTOFF).map_or(lo, |i| i + 1);
        (lo, hi.max(lo))
    };
    let (c0, c1) = window(&ws.gx);
    let (r0, r1) = window(&ws.gy);
    ws.gxc.clear();
    ws.gxc2.clear();
    for c in 0..w {
        let (g, x) = (if (c0..c1).contains(&c) { ws.gx[c] } else { 0.0 }, c as f64);
        ws.gx[c] = g;
        ws.gxc.push(g * x);
        ws.gxc2.push(g * x * x);
    }
    for r in 0..h {
        if !(r0..r1).contains(&r) {
            ws.gy[r] = 0.0;
        }
    }
    // Gaussian-weighted sums of the map. Rows first: per column, the sums over rows of
    // h gy, h gy r and h gy r^2 (three axpys per row, no reductions, so the compiler
    // vectorises them); then three dot products with gx, gx c and gx c^2.
    for v in [&mut ws.v0, &mut ws.v1, &mut ws.v2] {
        v.clear();
        v.resize(c1 - c0, 0.0);
    }
    for r in r0..r1 {
        let row = &map[r * w + c0..r * w + c1];
        let (g0, y) = (ws.gy[r], r as f64);
        let (g1, g2) = (g0 * y, g0 * y * y);
        for (((v0, v1), v2), &h) in ws.v0.iter_mut().zip(&mut ws.v1).zip(&mut ws.v2).zip(row) {
            let h = f64::from(h);
            *v0 += g0 * h;
            *v1 += g1 * h;
            *v2 += g2 * h;
        }
    }
    let (gx, gxc, gxc2) = (&ws.gx[c0..c1], &ws.gxc[c0..c1], &ws.gxc2[c0..c1]);
    let s = dot(gx, &ws.v0);
    let sx = dot(gxc, &ws.v0);
    let sy = dot(gx, &ws.v1);
    let sr2 = dot(gxc2, &ws.v0) + dot(gx, &ws.v2);
    // Sums of the Gaussian alone, and of the grid.
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    let (gxs, gxcs, gxc2s) = (sum(&ws.gx), sum(&ws.gxc), sum(&ws.gxc2));
    let gys = sum(&ws.gy);
    let gyrs: f64 = ws.gy.iter().enumerate().map(|(r, g)| g * r as f64).sum();
    let gyr2s: f64 = ws
        .gy
        .iter()
        .enumerate()
        .map(|(r, g)| g * (r * r) as f64)
        .sum();
    let (hf, wf) = (h as f64, w as f64);
    let n = hf * wf;
    let grid_x = hf * wf * (wf - 1.0) / 2.0;
    let grid_y = wf * hf * (hf - 1.0) / 2.0;
    let grid_r2 = hf * (wf - 1.0) * wf * (2.0 * wf - 1.0) / 6.0
        + wf * (hf - 1.0) * hf * (2.0 * hf - 1.0) / 6.0;
    let z = s + EPS * gxs * gys + EPS * mom.h + EPS * EPS * n;
    let zx = sx + EPS * gxcs * gys + EPS * mom.hx + EPS * EPS * grid_x;
    let zy = sy + EPS * gxs * gyrs + EPS * mom.hy + EPS * EPS * grid_y;
    let zr2 = sr2 + EPS * (gxc2s * gys + gxs * gyr2s) + EPS * mom.hr2 + EPS * EPS * grid_r2;
    let (x, y) = (zx / z, zy / z);
    Expectation {
        x,
        y,
        variance: (zr2 / z - x * x - y * y).max(0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference's formula, pixel by pixel.
    fn brute_force(map: &[f32], h: usize, w: usize, px: f64, py: f64, sigma: f64) -> Expectation {
        let (mut z, mut zx, mut zy) = (0.0, 0.0, 0.0);
        let mut weights = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let d2 = (c as f64 - px).powi(2) + (r as f64 - py).powi(2);
                let g = (-d2 / (2.0 * sigma * sigma)).exp();
                let v = (map[r * w + c].max(0.0)) as f64;
                let wt = (g + EPS) * (v + EPS);
                weights.push((c as f64, r as f64, wt));
                z += wt;
                zx += wt * c as f64;
                zy += wt * r as f64;
            }
        }
        let (x, y) = (zx / z, zy / z);
        let var = weights
            .iter()
            .map(|(c, r, wt)| wt * ((c - x).powi(2) + (r - y).powi(2)))
            .sum::<f64>()
            / z;
        Expectation {
            x,
            y,
            variance: var,
        }
    }

    #[test]
    fn matches_the_pixel_by_pixel_reference() {
        let (h, w) = (64, 48);
        // Two blobs, noise-like ripple, negatives to clip.
        let map: Vec<f32> = (0..h * w)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                let b1 = (-((c - 20.3).powi(2) + (r - 30.7).powi(2)) / 8.0).exp();
                let b2 = 0.8 * (-((c - 40.0).powi(2) + (r - 10.0).powi(2)) / 8.0).exp();
                let ripple = 0.03 * ((i * 7919 % 101) as f64 / 50.0 - 1.0);
                (b1 + b2 + ripple) as f32
            })
            .collect();
        let clipped: Vec<f32> = map.iter().map(|v| v.max(0.0)).collect();
        let mom = MapMoments::new(&clipped, w);
        let mut ws = EStepWorkspace::default();
        for &(px, py, sigma) in &[
            (21.0, 29.0, 5.33),
            (38.0, 12.0, 2.0),
            (30.0, 20.0, 20.0),
            (-100.0, 300.0, 3.0), // far outside: only the eps terms remain
        ] {
            let fast = expectation(&clipped, h, w, &mom, px, py, sigma, &mut ws);
            let slow = brute_force(&map, h, w, px, py, sigma);
            assert!((fast.x - slow.x).abs() < 1e-9, "{fast:?} vs {slow:?}");
            assert!((fast.y - slow.y).abs() < 1e-9, "{fast:?} vs {slow:?}");
            assert!(
                (fast.variance - slow.variance).abs() < 1e-7 * slow.variance.max(1.0),
                "{fast:?} vs {slow:?}"
            );
        }
    }
}
