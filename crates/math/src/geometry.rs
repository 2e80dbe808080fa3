//! Point-set alignment shared by the metrics and the solver: the least-squares
//! similarity (Procrustes) between two sets of 3D points.

use nalgebra::{Matrix3, Vector3};

/// A similarity taking point `x` to `scale R (x - source_centroid) + target_centroid`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// The rotation `R` (proper unless reflections were allowed).
    pub rotation: Matrix3<f64>,
    /// The scale (0 when the source points do not spread).
    pub scale: f64,
    /// Weighted centroid of the source points.
    pub source_centroid: Vector3<f64>,
    /// Weighted centroid of the target points.
    pub target_centroid: Vector3<f64>,
}

impl Similarity {
    /// The image of `x`.
    pub fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.scale * self.rotation * (x - self.source_centroid) + self.target_centroid
    }
}

/// The weighted least-squares similarity taking `source` onto `target` (weights `w`,
/// `None` = all 1): minimises `sum_j w_j |s R x_j + t - y_j|^2`. The rotation is proper
/// unless `allow_reflection`. `None` when the weights sum to 0 or the SVD fails.
pub fn fit_similarity(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    w: Option<&[f64]>,
    allow_reflection: bool,
) -> Option<Similarity> {
    let weight = |j: usize| w.map_or(1.0, |w| w[j]);
    let (mut mx, mut my, mut total) = (Vector3::zeros(), Vector3::zeros(), 0.0);
    for (j, (x, y)) in source.iter().zip(target).enumerate() {
        mx += x * weight(j);
        my += y * weight(j);
        total += weight(j);
    }
    if total <= 0.0 {
        return None;
    }
    mx /= total;
    my /= total;
    let mut h = Matrix3::zeros();
    let mut spread = 0.0;
    for (j, (x, y)) in source.iter().zip(target).enumerate() {
        if weight(j) > 0.0 {
            let a = x - mx;
            h += (y - my) * a.transpose() * weight(j);
            spread += weight(j) * a.norm_squared();
        }
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if !allow_reflection && (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let trace: f64 = (0..3).map(|i| svd.singular_values[i] * d[(i, i)]).sum();
    Some(Similarity {
        rotation: u * d * vt,
        scale: if spread > 0.0 { trace / spread } else { 0.0 },
        source_centroid: mx,
        target_centroid: my,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn recovers_a_weighted_similarity_and_ignores_zero_weight_points() {
        let r = Rotation3::from_euler_angles(0.4, -1.1, 0.3).into_inner();
        let x: Vec<Vector3<f64>> = (0..7)
            .map(|i| Vector3::new(i as f64, (i * i % 5) as f64, (3 * i % 4) as f64))
            .collect();
        let mut y: Vec<Vector3<f64>> = x
            .iter()
            .map(|p| 1.7 * r * p + Vector3::new(0.5, -2.0, 3.0))
            .collect();
        // An outlier with weight 0 changes nothing.
        y[6] += Vector3::new(10.0, 0.0, 0.0);
        let mut w = vec![1.0, 2.0, 0.5, 1.0, 3.0, 1.0, 0.0];
        let s = fit_similarity(&x, &y, Some(&w), false).expect("fit");
        assert!((s.rotation - r).norm() < 1e-12);
        assert!((s.scale - 1.7).abs() < 1e-12);
        for j in 0..6 {
            assert!((s.apply(&x[j]) - y[j]).norm() < 1e-12);
        }
        w.iter_mut().for_each(|w| *w = 0.0);
        assert!(fit_similarity(&x, &y, Some(&w), false).is_none());
    }
}
