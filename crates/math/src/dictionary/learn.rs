//! Learning a pose [`Dictionary`] from 3D poses (Zhou et al., "Sparse representation for
//! 3D shape estimation"; the authors' practice in `../shared/notes/algorithm.md`):
//!
//! 1. [`normalise_poses`]: centre every pose, divide by the mean over the axes of its
//!    per-axis standard deviation across joints, and rotate it onto a reference pose by
//!    Procrustes on the torso joints. The reference is the first pose turned to the
//!    dictionary axes: y down, the body facing +z, left joints at negative x.
//! 2. [`learn`]: non-negative sparse coding, `min 1/2 ||X - C B||^2 + lambda sum C` over
//!    `C >= 0` and atoms `B_i` with norms capped at their initial mean: alternate
//!    projected proximal-gradient steps on the codes `C` and a gradient step on `B`;
//!    atoms start as evenly spaced training poses.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use nalgebra::Vector3;

use super::Dictionary;
use crate::geometry::fit_similarity;
use crate::skeleton::Skeleton;

/// Options of [`learn`].
#[derive(Debug, Clone, PartialEq)]
pub struct LearnParams {
    /// Number of atoms (basis poses).
    pub atoms: usize,
    /// L1 weight on the codes (units of the normalised poses).
    pub lambda: f64,
    /// Outer iterations (one dictionary step each).
    pub iterations: usize,
    /// Projected-gradient steps on the codes per outer iteration.
    pub coding_steps: usize,
}

impl Default for LearnParams {
    fn default() -> Self {
        Self {
            atoms: 128,
            lambda: 1.0,
            iterations: 150,
            coding_steps: 40,
        }
    }
}

/// How well the learned dictionary represents its training poses.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LearnReport {
    /// Training poses.
    pub poses: usize,
    /// Mean per-joint distance between a pose and its reconstruction, normalised units
    /// (1 = the pose's own per-axis standard deviation).
    pub mean_joint_error: f64,
    /// `||X - C B|| / ||X||` over all poses.
    pub relative_error: f64,
    /// Mean number of atoms with a positive code per pose.
    pub mean_active_atoms: f64,
    /// The objective after each outer iteration.
    pub objective: Vec<f64>,
}

/// Normalises world-frame poses (`[x, y, z]` per joint, frame-major, z up) for learning:
/// returns row-major 3 x p poses (x row, y row, z row) in the dictionary's axes, centred,
/// unit mean per-axis std, aligned on the torso. `None` when a pose does not spread or
/// the skeleton has no left/right torso joints to define the facing direction.
pub fn normalise_poses(skeleton: &Skeleton, world: &[f64]) -> Option<Vec<f64>> {
    let p = skeleton.len();
    let n = world.len() / (3 * p);
    if n == 0 {
        return None;
    }
    let torso = &skeleton.torso;
    if torso.len() < 3 {
        return None;
    }
    let normalised = |t: usize| -> Option<Vec<Vector3<f64>>> {
        let pts: Vec<Vector3<f64>> = (0..p)
            .map(|j| Vector3::from_column_slice(&world[3 * (t * p + j)..3 * (t * p + j) + 3]))
            .collect();
        let mean = pts.iter().sum::<Vector3<f64>>() / p as f64;
        let var = pts
            .iter()
            .map(|q| (q - mean).component_mul(&(q - mean)))
            .sum::<Vector3<f64>>()
            / p as f64;
        let scale = (var.x.sqrt() + var.y.sqrt() + var.z.sqrt()) / 3.0;
        (scale > 0.0 && scale.is_finite()).then(|| pts.iter().map(|q| (q - mean) / scale).collect())
    };
    // The reference: the first pose, turned so that y points down (world -z) and the
    // body's right is +x (then it faces +z).
    let first = normalised(0)?;
    let x = skeleton.facing(&world[..3 * p])?.cross(&Vector3::z());
    let down = -Vector3::z();
    let z = x.cross(&down);
    let to_dict = nalgebra::Matrix3::from_rows(&[x.transpose(), down.transpose(), z.transpose()]);
    let reference: Vec<Vector3<f64>> = first.iter().map(|q| to_dict * q).collect();
    let ref_torso: Vec<Vector3<f64>> = torso.iter().map(|&j| reference[j]).collect();
    let mut out = Vec::with_capacity(n * 3 * p);
    for t in 0..n {
        let pts = normalised(t)?;
        let src: Vec<Vector3<f64>> = torso.iter().map(|&j| pts[j]).collect();
        let r = fit_similarity(&src, &ref_torso, None, false)?.rotation;
        let aligned: Vec<Vector3<f64>> = pts.iter().map(|q| r * q).collect();
        for axis in 0..3 {
            out.extend(aligned.iter().map(|q| q[axis]));
        }
    }
    Some(out)
}

/// Learns `params.atoms` basis poses from normalised poses (row-major 3 x p each, as
/// [`normalise_poses`] returns). `progress` is called after each outer iteration with its
/// index and the objective.
pub fn learn(
    skeleton: Skeleton,
    poses: &[f64],
    params: &LearnParams,
    mut progress: impl FnMut(usize, f64),
) -> Result<(Dictionary, LearnReport), String> {
    let d = 3 * skeleton.len();
    let n = poses.len() / d;
    let k = params.atoms;
    if !poses.len().is_multiple_of(d) || n == 0 {
        return Err(format!(
            "{} values are not whole poses of 3 x {} joints",
            poses.len(),
            skeleton.len()
        ));
    }
    if k == 0 || k > n {
        return Err(format!(
            "{k} atoms from {n} poses: need 1 <= atoms <= poses"
        ));
    }
    if !(params.lambda.is_finite() && params.lambda >= 0.0) {
        return Err(format!(
            "lambda must be finite and >= 0, got {}",
            params.lambda
        ));
    }
    if poses.iter().any(|v| !v.is_finite()) {
        return Err("a training pose holds a non-finite value".into());
    }
    let x = Mat::<f64>::from_fn(n, d, |i, c| poses[i * d + c]);
    // Atoms: evenly spaced training poses; their mean norm caps every atom's norm.
    let mut b = Mat::<f64>::from_fn(k, d, |i, c| x[(i * n / k, c)]);
    let cap = (0..k).map(|i| row_norm(&b, i)).sum::<f64>() / k as f64;
    let mut c = Mat::<f64>::zeros(n, k);
    let mut residual = Mat::<f64>::zeros(n, d);
    let mut grad_c = Mat::<f64>::zeros(n, k);
    let mut y = Mat::<f64>::zeros(n, k);
    let mut grad_b = Mat::<f64>::zeros(k, d);
    let mut gram = Mat::<f64>::zeros(k, k);
    let mut objective = Vec::with_capacity(params.iterations);
    let lambda = params.lambda;
    for it in 0..params.iterations {
        // Codes: projected proximal gradient, step 1 / ||B B'||.
        matmul(
            gram.as_mut(),
            Accum::Replace,
            b.as_ref(),
            b.transpose(),
            1.0,
            Par::Seq,
        );
        let step = 1.0 / largest_eigenvalue(&gram).max(1e-12);
        // FISTA from the previous codes: `y` is the extrapolated point.
        y.copy_from(&c);
        let mut theta = 1.0_f64;
        for _ in 0..params.coding_steps {
            residual_into(&mut residual, &y, &b, &x);
            matmul(
                grad_c.as_mut(),
                Accum::Replace,
                residual.as_ref(),
                b.transpose(),
                1.0,
                Par::Seq,
            );
            let next_theta = 0.5 * (1.0 + (1.0 + 4.0 * theta * theta).sqrt());
            let momentum = (theta - 1.0) / next_theta;
            theta = next_theta;
            for col in 0..k {
                for row in 0..n {
                    let new = (y[(row, col)] - step * (grad_c[(row, col)] + lambda)).max(0.0);
                    let old = c[(row, col)];
                    c[(row, col)] = new;
                    y[(row, col)] = (new + momentum * (new - old)).max(0.0);
                }
            }
        }
        // Atoms: a gradient step, step 1 / ||C' C||, then cap the norms.
        residual_into(&mut residual, &c, &b, &x);
        matmul(
            gram.as_mut(),
            Accum::Replace,
            c.transpose(),
            c.as_ref(),
            1.0,
            Par::Seq,
        );
        let step_b = 1.0 / largest_eigenvalue(&gram).max(1e-12);
        matmul(
            grad_b.as_mut(),
            Accum::Replace,
            c.transpose(),
            residual.as_ref(),
            1.0,
            Par::Seq,
        );
        for col in 0..d {
            for row in 0..k {
                b[(row, col)] -= step_b * grad_b[(row, col)];
            }
        }
        for i in 0..k {
            let norm = row_norm(&b, i);
            if norm > cap {
                for col in 0..d {
                    b[(i, col)] *= cap / norm;
                }
            }
        }
        residual_into(&mut residual, &c, &b, &x);
        let fit = 0.5 * residual.norm_l2().powi(2);
        let l1: f64 = (0..k).map(|col| c.col(col).sum()).sum();
        objective.push(fit + lambda * l1);
        progress(it, fit + lambda * l1);
    }
    residual_into(&mut residual, &c, &b, &x);
    let p = skeleton.len();
    let mut joint_error = 0.0;
    for row in 0..n {
        for j in 0..p {
            let e: f64 = (0..3).map(|a| residual[(row, a * p + j)].powi(2)).sum();
            joint_error += e.sqrt();
        }
    }
    let active = (0..k)
        .map(|col| (0..n).filter(|&row| c[(row, col)] > 0.0).count())
        .sum::<usize>();
    let report = LearnReport {
        poses: n,
        mean_joint_error: joint_error / (n * p) as f64,
        relative_error: residual.norm_l2() / x.norm_l2(),
        mean_active_atoms: active as f64 / n as f64,
        objective,
    };
    let bases: Vec<f64> = (0..k)
        .flat_map(|i| (0..d).map(move |c| (i, c)))
        .map(|(i, col)| b[(i, col)])
        .collect();
    let mean: Vec<f64> = (0..d).map(|col| x.col(col).sum() / n as f64).collect();
    let dict = Dictionary::new(skeleton, bases, mean)?;
    Ok((dict, report))
}

fn row_norm(m: &Mat<f64>, i: usize) -> f64 {
    (0..m.ncols())
        .map(|c| m[(i, c)].powi(2))
        .sum::<f64>()
        .sqrt()
}

/// `C B - X` into `out`.
fn residual_into(out: &mut Mat<f64>, c: &Mat<f64>, b: &Mat<f64>, x: &Mat<f64>) {
    matmul(
        out.as_mut(),
        Accum::Replace,
        c.as_ref(),
        b.as_ref(),
        1.0,
        Par::Seq,
    );
    for col in 0..out.ncols() {
        for row in 0..out.nrows() {
            out[(row, col)] -= x[(row, col)];
        }
    }
}

/// The largest eigenvalue of a symmetric positive semi-definite matrix (power iteration).
fn largest_eigenvalue(a: &Mat<f64>) -> f64 {
    let n = a.nrows();
    let mut v = vec![1.0 / (n as f64).sqrt(); n];
    let mut lambda = 0.0;
    for _ in 0..100 {
        let w: Vec<f64> = (0..n)
            .map(|r| (0..n).map(|c| a[(r, c)] * v[c]).sum())
            .collect();
        let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            return 0.0;
        }
        let next = norm;
        v = w.into_iter().map(|x| x / norm).collect();
        if (next - lambda).abs() <= 1e-9 * next {
            return next * 1.01;
        }
        lambda = next;
    }
    // A small safety margin: the iteration approaches the eigenvalue from below.
    lambda * 1.01
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::skeleton::default_layout;

    #[test]
    fn learns_a_sparse_dictionary_that_reconstructs_its_poses() {
        // Poses that are non-negative mixes of 4 hidden shapes: 8 atoms must fit them well.
        let skel = default_layout();
        let d = 3 * skel.len();
        let shapes: Vec<Vec<f64>> = (0..4)
            .map(|s| {
                (0..d)
                    .map(|i| ((i * 7 + s * 13) % 11) as f64 - 5.0)
                    .collect()
            })
            .collect();
        let mut poses = Vec::new();
        for t in 0..200 {
            let w = [(t % 5) as f64, ((t / 5) % 3) as f64, (t % 2) as f64, 0.5];
            for i in 0..d {
                poses.push((0..4).map(|s| w[s] * shapes[s][i]).sum::<f64>());
            }
        }
        let params = LearnParams {
            atoms: 8,
            lambda: 0.01,
            iterations: 300,
            coding_steps: 10,
        };
        let (dict, report) = learn(skel, &poses, &params, |_, _| {}).expect("learns");
        assert_eq!(dict.num_bases(), 8);
        assert!(report.relative_error < 0.1, "{report:?}");
        assert!(report.mean_active_atoms <= 8.0);
        // The objective falls overall.
        assert!(report.objective.last() < report.objective.first());
    }
}
