//! Data normalisation, which sets the meaning of every weight (as in the reference):
//! heat-map pixels are divided by `h / 6` (a map spans 6 units); given 2D joints are
//! divided by the mean, over the 2F coordinate rows, of each row's standard deviation
//! across the joints.

/// Height of a heat map in normalised units.
pub const HEATMAP_UNITS: f64 = 6.0;

/// Pixels per normalised unit for heat maps of height `h`.
pub fn heatmap_scale(h: usize) -> f64 {
    h as f64 / HEATMAP_UNITS
}

/// The keypoint scale: mean over frames and axes of the (population) standard deviation
/// across the joints with positive weight. `xy` is `[x, y]` per joint, frame-major.
pub fn keypoint_scale(xy: &[f64], weights: &[f64], joints: usize) -> f64 {
    let frames = xy.len() / (2 * joints);
    let (mut total, mut rows) = (0.0, 0usize);
    for t in 0..frames {
        for axis in 0..2 {
            let vals: Vec<f64> = (0..joints)
                .filter(|&j| weights[t * joints + j] > 0.0)
                .map(|j| xy[2 * (t * joints + j) + axis])
                .collect();
            if vals.is_empty() {
                continue;
            }
            let n = vals.len() as f64;
            let mean = vals.iter().sum::<f64>() / n;
            let var = vals.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
            total += var.sqrt();
            rows += 1;
        }
    }
    if rows == 0 { 0.0 } else { total / rows as f64 }
}
