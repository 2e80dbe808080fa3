//! Evaluation metrics. Poses are `[x, y, z]` per joint, frame-major; 2D joints `[x, y]`.
//!
//! P-MPJPE aligns each predicted frame to the ground truth by a similarity transform
//! (centre, best *proper* rotation, best scale), the standard protocol. The reference's
//! own helper allows reflections; [`p_mpjpe_with_reflections`] reproduces it.

use nalgebra::Vector3;

use crate::geometry::fit_similarity;

/// Mean per-joint position error, no alignment.
pub fn mpjpe(pred: &[f64], truth: &[f64]) -> f64 {
    let n = pred.len() / 3;
    pred.chunks_exact(3)
        .zip(truth.chunks_exact(3))
        .map(|(a, b)| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .sum::<f64>()
        / n as f64
}

/// Similarity Procrustes of one frame: the aligned copy of `pred` (`p` joints).
pub fn procrustes_align(pred: &[f64], truth: &[f64], allow_reflection: bool) -> Vec<f64> {
    let pts = |v: &[f64]| -> Vec<Vector3<f64>> {
        v.chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect()
    };
    let (x, y) = (pts(pred), pts(truth));
    let Some(sim) = fit_similarity(&x, &y, None, allow_reflection) else {
        return truth.to_vec();
    };
    x.iter()
        .flat_map(|a| {
            let q = sim.apply(a);
            [q.x, q.y, q.z]
        })
        .collect()
}

fn aligned_error(pred: &[f64], truth: &[f64], joints: usize, allow_reflection: bool) -> f64 {
    let n = 3 * joints;
    let frames = pred.len() / n;
    let mut total = 0.0;
    for t in 0..frames {
        let (a, b) = (&pred[t * n..(t + 1) * n], &truth[t * n..(t + 1) * n]);
        total += mpjpe(&procrustes_align(a, b, allow_reflection), b);
    }
    total / frames as f64
}

/// P-MPJPE: per-frame similarity alignment with a proper rotation, then MPJPE.
pub fn p_mpjpe(pred: &[f64], truth: &[f64], joints: usize) -> f64 {
    aligned_error(pred, truth, joints, false)
}

/// P-MPJPE allowing reflections in the alignment (the reference helper's variant).
pub fn p_mpjpe_with_reflections(pred: &[f64], truth: &[f64], joints: usize) -> f64 {
    aligned_error(pred, truth, joints, true)
}

/// MPJPE after subtracting each frame's `root` joint from both poses (no rotation or
/// scale alignment): the Human3.6M protocol of the paper's Table 3.
pub fn root_aligned_mpjpe(pred: &[f64], truth: &[f64], joints: usize, root: usize) -> f64 {
    let n = 3 * joints;
    let frames = pred.len() / n;
    let mut total = 0.0;
    for t in 0..frames {
        let (a, b) = (&pred[t * n..(t + 1) * n], &truth[t * n..(t + 1) * n]);
        let (ra, rb) = (&a[3 * root..3 * root + 3], &b[3 * root..3 * root + 3]);
        for j in 0..joints {
            let d: f64 = (0..3)
                .map(|i| (a[3 * j + i] - ra[i] - b[3 * j + i] + rb[i]).powi(2))
                .sum();
            total += d.sqrt();
        }
    }
    total / (frames * joints) as f64
}

/// Mean 2D distance.
pub fn mean_error_2d(pred: &[f64], truth: &[f64]) -> f64 {
    let n = pred.len() / 2;
    pred.chunks_exact(2)
        .zip(truth.chunks_exact(2))
        .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
        .sum::<f64>()
        / n as f64
}

/// Percentage of correct keypoints: the fraction of 2D joints within `threshold`.
pub fn pck(pred: &[f64], truth: &[f64], threshold: f64) -> f64 {
    let n = pred.len() / 2;
    pred.chunks_exact(2)
        .zip(truth.chunks_exact(2))
        .filter(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() <= threshold)
        .count() as f64
        / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn procrustes_of_a_rotated_scaled_copy_is_zero() {
        let p = 11;
        let truth: Vec<f64> = (0..3 * p)
            .map(|i| ((i * 31 % 17) as f64 - 8.0) / 3.0)
            .collect();
        let r = Rotation3::from_euler_angles(0.7, -0.2, 2.1);
        let pred: Vec<f64> = truth
            .chunks_exact(3)
            .flat_map(|c| {
                let q = 2.5 * (r * Vector3::new(c[0], c[1], c[2])) + Vector3::new(1.0, -3.0, 0.5);
                [q.x, q.y, q.z]
            })
            .collect();
        assert!(p_mpjpe(&pred, &truth, p) < 1e-10);
        assert!(mpjpe(&pred, &truth) > 1.0);
        // A translated copy is zero once root-aligned; a rotated one is not.
        let shifted: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(i, v)| v + [1.0, -2.0, 3.0][i % 3])
            .collect();
        assert!(root_aligned_mpjpe(&shifted, &truth, p, 4) < 1e-12);
        assert!(root_aligned_mpjpe(&pred, &truth, p, 4) > 0.1);
    }

    #[test]
    fn a_mirrored_copy_is_only_zero_when_reflections_are_allowed() {
        let p = 9;
        let truth: Vec<f64> = (0..3 * p)
            .map(|i| ((i * 13 % 7) as f64 - 3.0) / 2.0)
            .collect();
        let pred: Vec<f64> = truth
            .chunks_exact(3)
            .flat_map(|c| [-c[0], c[1], c[2]])
            .collect();
        assert!(p_mpjpe_with_reflections(&pred, &truth, p) < 1e-10);
        assert!(p_mpjpe(&pred, &truth, p) > 0.1);
    }

    #[test]
    fn pck_counts_joints_within_the_threshold() {
        let truth = [0.0, 0.0, 10.0, 10.0];
        let pred = [1.0, 0.0, 10.0, 13.0];
        assert_eq!(pck(&pred, &truth, 2.0), 0.5);
        assert!((mean_error_2d(&pred, &truth) - 2.0).abs() < 1e-12);
    }
}
