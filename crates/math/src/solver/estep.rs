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
//!   contribution is far below the `eps` terms), and so are rows and columns outside the
//!   map's support (the box of its non-zero values, [`MapMoments::support`]), where
//!   `g h` is exactly 0: sparse maps (peaks on a zero background, as u8-quantised maps
//!   mostly are) cost a fraction of a dense one, with the same result;
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
    /// The box holding every non-zero value: rows `support[0]..support[1]`, columns
    /// `support[2]..support[3]` (empty for an all-zero map).
    pub support: [u32; 4],
}

impl MapMoments {
    /// Moments of a map (values already clipped at 0), `w` columns.
    pub fn new(map: &[f32], w: usize) -> Self {
        let mut m = Self::default();
        let (mut r0, mut r1, mut c0, mut c1) = (usize::MAX, 0, usize::MAX, 0);
        for (r, row) in map.chunks_exact(w).enumerate() {
            // Zero rows (most of a sparse map) add nothing.
            let Some(first) = row.iter().position(|&v| v != 0.0) else {
                continue;
            };
            let last = row.iter().rposition(|&v| v != 0.0).unwrap_or(first);
            (r0, r1) = (r0.min(r), r + 1);
            (c0, c1) = (c0.min(first), c1.max(last + 1));
            let ry = r as f64;
            let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
            for (c, &v) in row.iter().enumerate().take(last + 1).skip(first) {
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
        if r0 < r1 {
            m.support = [r0, r1, c0, c1].map(|v| v as u32);
        }
        m
    }
}

/// One joint's E-step result, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Expectation {
    /// Expected x.
    pub x: f64,
    /// Expected y.
    pub y: f64,
    /// Trace of the 2D covariance (pixels^2).
    pub variance: f64,
    /// `sum (g + eps)(h + eps)` over the grid (`g` the Gaussian with peak 1): how well the
    /// map explains a joint at the projection, up to a factor common to every map of
    /// the same size and `sigma` (what the left/right swap hypothesis compares).
    pub mass: f64,
}

impl Expectation {
    /// The expectation under a mixture: `a` with probability `1 - q`, `b` with `q`; the
    /// variance is the mixture's (each component's spread plus its mean's distance from
    /// the mixture's), so a joint whose hypotheses disagree is as uncertain as that
    /// makes it. The mass is `a`'s.
    pub fn mixture(a: Self, b: Self, q: f64) -> Self {
        if q <= 0.0 {
            return a;
        }
        let x = a.x + q * (b.x - a.x);
        let y = a.y + q * (b.y - a.y);
        let spread = |e: &Self| e.variance + (e.x - x).powi(2) + (e.y - y).powi(2);
        Self {
            x,
            y,
            variance: (1.0 - q) * spread(&a) + q * spread(&b),
            mass: a.mass,
        }
    }
}

/// The posterior probability that a left/right pair's maps are swapped: prior `prior`,
/// the pair's masses ([`Expectation::mass`] multiplied) `as_is` with each joint under its
/// own map and `swapped` under the other's. 0 when neither explains anything.
pub fn swap_probability(prior: f64, as_is: f64, swapped: f64) -> f64 {
    let (a, b) = ((1.0 - prior) * as_is, prior * swapped);
    if a + b > 0.0 && (a + b).is_finite() {
        b / (a + b)
    } else {
        0.0
    }
}

/// Reusable buffers of [`expectation`].
#[derive(Debug, Clone, Default)]
pub struct EStepWorkspace {
    gx: Vec<f64>,
    gy: Vec<f64>,
    v0: Vec<f64>,
    v1: Vec<f64>,
    v2: Vec<f64>,
}

const CUTOFF: f64 = 1e-20;

/// [`mass`]'s cutoff: the Gaussian beyond 4.3 sigma, whose share of the mass is below
/// 1e-4 of its peak's, is left out (the mass only weighs hypotheses against each other;
/// this skips most of a map).
const MASS_CUTOFF: f64 = 1e-4;

/// A sampled Gaussian: where it is not cut off, and its sums.
struct Profile {
    /// Indices `lo..hi` hold every value at or above the cutoff.
    lo: usize,
    hi: usize,
    /// `sum g_i`, `sum g_i i`, `sum g_i i^2`.
    sums: [f64; 3],
}

/// `g[i] = exp(-(i - mean)^2 / (2 sigma^2))` for `i` in `0..n`, values below [`CUTOFF`]
/// set to 0, by the recurrence `g[i+1] = g[i] q_i`, `q_{i+1} = q_i exp(-1/sigma^2)`,
/// outward from the grid point nearest the mean: four exponentials instead of `n`
/// (relative error ~ n ulp).
fn gaussian_profile(mean: f64, sigma: f64, n: usize, cutoff: f64, g: &mut Vec<f64>) -> Profile {
    g.clear();
    g.resize(n, 0.0);
    let mut profile = Profile {
        lo: 0,
        hi: 0,
        sums: [0.0; 3],
    };
    if n == 0 {
        return profile;
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
    // The values at or above the cutoff are contiguous (the Gaussian is unimodal).
    profile.lo = n;
    for (i, v) in g.iter_mut().enumerate() {
        // Below the cutoff, or NaN (from an infinite mean).
        if v.is_nan() || *v < cutoff {
            *v = 0.0;
            continue;
        }
        profile.lo = profile.lo.min(i);
        profile.hi = i + 1;
        let x = i as f64;
        profile.sums[0] += *v;
        profile.sums[1] += *v * x;
        profile.sums[2] += *v * x * x;
    }
    profile.hi = profile.hi.max(profile.lo.min(n));
    profile.lo = profile.lo.min(profile.hi);
    profile
}

const EPS: f64 = f64::EPSILON;

/// Expected location of a joint: `map` (h x w, clipped at 0) with moments `mom`, Gaussian
/// of standard deviation `sigma` (pixels) around `(px, py)` (pixels).
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
    let gx = gaussian_profile(px, sigma, w, CUTOFF, &mut ws.gx);
    let gy = gaussian_profile(py, sigma, h, CUTOFF, &mut ws.gy);
    // Where both the Gaussian and the map can be non-zero.
    let clip = |(lo, hi): (usize, usize), (s0, s1): (u32, u32)| {
        let lo = lo.max(s0 as usize);
        (lo, hi.min(s1 as usize).max(lo))
    };
    let (r0, r1) = clip((gy.lo, gy.hi), (mom.support[0], mom.support[1]));
    let (c0, c1) = clip((gx.lo, gx.hi), (mom.support[2], mom.support[3]));
    // Gaussian-weighted sums of the map. Rows first: per column, the sums over rows of
    // h gy, h gy r and h gy r^2 (three axpys per row, no reductions, so the compiler
    // vectorises them); then one pass over the columns with gx, gx c and gx c^2.
    for v in [&mut ws.v0, &mut ws.v1, &mut ws.v2] {
        v.clear();
        // Room for a whole row at once: the columns in reach vary with the map's
        // support, and a warm E-step allocates nothing.
        v.reserve(w);
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
    let (mut s, mut sx, mut sy, mut sr2) = (0.0, 0.0, 0.0, 0.0);
    for (i, g) in ws.gx[c0..c1].iter().enumerate() {
        let x = (c0 + i) as f64;
        let (v0, v1, v2) = (ws.v0[i], ws.v1[i], ws.v2[i]);
        s += g * v0;
        sx += g * x * v0;
        sy += g * v1;
        sr2 += g * (x * x * v0 + v2);
    }
    // Sums of the Gaussian alone, and of the grid.
    let [gxs, gxcs, gxc2s] = gx.sums;
    let [gys, gyrs, gyr2s] = gy.sums;
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
        mass: z,
    }
}

/// The E-step of one frame's joints: `expected[j]` under `maps(j)` (a map and its
/// moments) with the Gaussian of `sigma` around `projected[j]` (map pixels). With
/// `swap_prior` positive, each left/right pair of `pairs` is a mixture of its maps as
/// they are and swapped, weighed by how well each explains the pair at its projection
/// ([`swap_probability`]); `swapped` receives each pair's posterior. The single-camera
/// EM ([`super::em::e_step`]) and the multi-view one ([`crate::fusion`]) both call it.
pub fn expect_joints<'m>(
    maps: impl Fn(usize) -> (&'m [f32], &'m MapMoments),
    h: usize,
    w: usize,
    projected: &[[f64; 2]],
    sigma: f64,
    swap_prior: f64,
    pairs: &[(usize, usize)],
    ws: &mut EStepWorkspace,
    swapped: &mut Vec<f64>,
    expected: &mut [Expectation],
) {
    for (j, (e, &[u, v])) in expected.iter_mut().zip(projected).enumerate() {
        let (map, moments) = maps(j);
        *e = expectation(map, h, w, moments, u, v, sigma, ws);
    }
    if swap_prior <= 0.0 {
        return;
    }
    swapped.clear();
    for &(l, r) in pairs {
        // Each joint of the pair under the other's map: how well, first.
        let cross = |from, [u, v]: [f64; 2], ws: &mut EStepWorkspace| {
            let (map, moments) = maps(from);
            mass(map, h, w, moments, u, v, sigma, ws)
        };
        let [pl, pr] = [projected[l], projected[r]];
        let as_swapped = cross(r, pl, ws) * cross(l, pr, ws);
        let as_is = expected[l].mass * expected[r].mass;
        swapped.push(swap_probability(swap_prior, as_is, as_swapped));
    }
    // Most pairs "swapped" is the fit mirrored left for right, not the maps: the maps
    // then stand as they are (or the hypothesis would hold the fit on its mirrored
    // side).
    let decided = swapped.iter().filter(|&&q| q > 0.5).count();
    if 2 * decided > pairs.len() {
        swapped.fill(0.0);
    }
    for (&(l, r), &q) in pairs.iter().zip(swapped.iter()) {
        // Where, only if the swap is not negligible (it moves a joint by q times the
        // distance of the hypotheses' means: under 0.1 pixel of a 64-pixel map below
        // 1e-3).
        if q < 1e-3 {
            continue;
        }
        let under = |from, [u, v]: [f64; 2], ws: &mut EStepWorkspace| {
            let (map, moments) = maps(from);
            expectation(map, h, w, moments, u, v, sigma, ws)
        };
        let [pl, pr] = [projected[l], projected[r]];
        let lr = under(r, pl, ws);
        let rl = under(l, pr, ws);
        let (el, er) = (expected[l], expected[r]);
        expected[l] = Expectation::mixture(el, lr, q);
        expected[r] = Expectation::mixture(er, rl, q);
    }
}

/// [`Expectation::mass`] alone, approximately (a third of [`expectation`]'s sums, over
/// the Gaussian's centre, [`MASS_CUTOFF`]): how well `map` explains a joint at `(px, py)`.
pub fn mass(
    map: &[f32],
    h: usize,
    w: usize,
    mom: &MapMoments,
    px: f64,
    py: f64,
    sigma: f64,
    ws: &mut EStepWorkspace,
) -> f64 {
    let gx = gaussian_profile(px, sigma, w, MASS_CUTOFF, &mut ws.gx);
    let gy = gaussian_profile(py, sigma, h, MASS_CUTOFF, &mut ws.gy);
    let clip = |(lo, hi): (usize, usize), (s0, s1): (u32, u32)| {
        let lo = lo.max(s0 as usize);
        (lo, hi.min(s1 as usize).max(lo))
    };
    let (r0, r1) = clip((gy.lo, gy.hi), (mom.support[0], mom.support[1]));
    let (c0, c1) = clip((gx.lo, gx.hi), (mom.support[2], mom.support[3]));
    ws.v0.clear();
    ws.v0.reserve(w);
    ws.v0.resize(c1 - c0, 0.0);
    for r in r0..r1 {
        let row = &map[r * w + c0..r * w + c1];
        let g = ws.gy[r];
        for (v, &h) in ws.v0.iter_mut().zip(row) {
            *v += g * f64::from(h);
        }
    }
    let s: f64 = ws.gx[c0..c1].iter().zip(&ws.v0).map(|(g, v)| g * v).sum();
    s + EPS * gx.sums[0] * gy.sums[0] + EPS * mom.h + EPS * EPS * (h * w) as f64
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
            mass: z,
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
            assert!(
                (fast.mass - slow.mass).abs() < 1e-9 * slow.mass,
                "{fast:?} vs {slow:?}"
            );
            let alone = mass(&clipped, h, w, &mom, px, py, sigma, &mut ws);
            assert!(
                (alone - slow.mass).abs() < 1e-3 * slow.mass,
                "{alone} vs {slow:?}"
            );
        }
    }

    #[test]
    fn sparse_and_empty_maps_match_the_pixel_by_pixel_reference() {
        let (h, w) = (40, 56);
        // A blob on an exactly zero background (its support is a small box), and a map
        // with nothing on it.
        let blob: Vec<f32> = (0..h * w)
            .map(|i| {
                let (r, c) = ((i / w) as f64, (i % w) as f64);
                let v = (-((c - 41.2).powi(2) + (r - 7.6).powi(2)) / 4.0).exp();
                if v > 0.01 { v as f32 } else { 0.0 }
            })
            .collect();
        let empty = vec![0.0_f32; h * w];
        let mut ws = EStepWorkspace::default();
        for map in [&blob, &empty] {
            let mom = MapMoments::new(map, w);
            for &(px, py, sigma) in &[(40.0, 8.0, 5.33), (10.0, 30.0, 4.0), (-50.0, 90.0, 3.0)] {
                let fast = expectation(map, h, w, &mom, px, py, sigma, &mut ws);
                let slow = brute_force(map, h, w, px, py, sigma);
                assert!((fast.x - slow.x).abs() < 1e-9, "{fast:?} vs {slow:?}");
                assert!((fast.y - slow.y).abs() < 1e-9, "{fast:?} vs {slow:?}");
                assert!(
                    (fast.variance - slow.variance).abs() < 1e-7 * slow.variance.max(1.0),
                    "{fast:?} vs {slow:?}"
                );
            }
        }
        let mom = MapMoments::new(&blob, w);
        assert!(mom.support[1] - mom.support[0] < 10 && mom.support[3] - mom.support[2] < 10);
        assert_eq!(MapMoments::new(&empty, w).support, [0; 4]);
    }
}
