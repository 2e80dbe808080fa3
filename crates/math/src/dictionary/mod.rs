//! The pose dictionary: `k` basis poses `B_i` (3 x p each) and a mean shape, over a
//! [`Skeleton`]. A pose is `S = sum_i c_i B_i` (paper, eq. 1), plus the offset of a
//! track's shape beyond the bases when one is set ([`crate::solver::adapt`]).
//!
//! Two file formats load into it:
//! - the authors' MATLAB release (`.mat`, variables `B` (3k x p), `mu` (3 x p) and
//!   `skel` with `tree(i).name`, `tree(i).children` and `torso`, 1-based), see [`mat`];
//! - posestream's own JSON format, see [`json`].
//!
//! Bases are centred on load (each basis has zero mean over the joints on every axis),
//! as the reference solver assumes.

pub mod learn;

use crate::skeleton::Skeleton;

/// `k` basis poses of `p` joints and a mean shape.
#[derive(Debug, Clone, PartialEq)]
pub struct Dictionary {
    skeleton: Skeleton,
    k: usize,
    /// Basis `i` occupies `bases[3p*i .. 3p*(i+1)]`, row-major 3 x p (x row, y row, z row).
    bases: Vec<f64>,
    /// Mean shape, row-major 3 x p.
    mean: Vec<f64>,
    /// The person's shape beyond the bases (row-major 3 x p, centred; zero unless set):
    /// every composed pose is `offset + sum_i c_i B_i`. See [`crate::solver::adapt`].
    offset: Vec<f64>,
    /// The skeleton's left/right joint pairs, found once (the E-step's swap hypothesis
    /// reads them every iteration).
    pairs: Vec<(usize, usize)>,
}

impl Dictionary {
    /// Builds a dictionary from row-major bases (`k` blocks of 3 x p) and a mean (3 x p).
    /// Centres every basis and the mean over the joints.
    pub fn new(skeleton: Skeleton, bases: Vec<f64>, mean: Vec<f64>) -> Result<Self, String> {
        let p = skeleton.len();
        if bases.is_empty() || !bases.len().is_multiple_of(3 * p) {
            return Err(format!(
                "bases hold {} values, not a multiple of 3 x {p} joints",
                bases.len()
            ));
        }
        if mean.len() != 3 * p {
            return Err(format!(
                "mean holds {} values, expected 3 x {p}",
                mean.len()
            ));
        }
        if bases.iter().chain(mean.iter()).any(|v| !v.is_finite()) {
            return Err("non-finite value in bases or mean".into());
        }
        let k = bases.len() / (3 * p);
        let pairs = skeleton.left_right_pairs();
        let mut d = Self {
            pairs,
            skeleton,
            k,
            bases,
            mean,
            offset: vec![0.0; 3 * p],
        };
        for row in d
            .bases
            .chunks_exact_mut(p)
            .chain(d.mean.chunks_exact_mut(p))
        {
            let m = row.iter().sum::<f64>() / p as f64;
            let size = row.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
            // Leave rows that are centred to rounding alone, so loading is idempotent.
            if m.abs() > 1e-12 * size {
                row.iter_mut().for_each(|v| *v -= m);
            }
        }
        Ok(d)
    }

    /// The joint layout.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// The skeleton's left/right joint pairs ([`Skeleton::left_right_pairs`]).
    pub fn left_right_pairs(&self) -> &[(usize, usize)] {
        &self.pairs
    }

    /// Number of basis poses.
    pub fn num_bases(&self) -> usize {
        self.k
    }

    /// Number of joints.
    pub fn num_joints(&self) -> usize {
        self.skeleton.len()
    }

    /// Basis `i`, row-major 3 x p.
    pub fn basis(&self, i: usize) -> &[f64] {
        let n = 3 * self.num_joints();
        &self.bases[n * i..n * (i + 1)]
    }

    /// All bases, `k` row-major 3 x p blocks.
    pub fn bases(&self) -> &[f64] {
        &self.bases
    }

    /// The mean shape, row-major 3 x p.
    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// The average of the bases (row-major 3 x p): the reference's starting shape for the
    /// alternating initialisation.
    pub fn average_basis(&self) -> Vec<f64> {
        let n = 3 * self.num_joints();
        let mut s = vec![0.0; n];
        for b in self.bases.chunks_exact(n) {
            s.iter_mut().zip(b).for_each(|(s, b)| *s += b);
        }
        s.iter_mut().for_each(|v| *v /= self.k as f64);
        s
    }

    /// The person's shape beyond the bases (row-major 3 x p, centred; zero unless set by
    /// [`Self::set_offset`]).
    pub fn offset(&self) -> &[f64] {
        &self.offset
    }

    /// True when the offset is not zero (false: the paper's model, poses in the bases'
    /// span).
    pub fn has_offset(&self) -> bool {
        self.offset.iter().any(|&v| v != 0.0)
    }

    /// Sets the offset every composed pose starts from (row-major 3 x p), centred over
    /// the joints on every axis (a shift of all joints is the translation's).
    pub fn set_offset(&mut self, offset: &[f64]) {
        let p = self.num_joints();
        debug_assert_eq!(offset.len(), 3 * p);
        self.offset.copy_from_slice(offset);
        for row in self.offset.chunks_exact_mut(p) {
            let m = row.iter().sum::<f64>() / p as f64;
            row.iter_mut().for_each(|v| *v -= m);
        }
    }

    /// Writes `offset + sum_i c_i B_i` into `out` (row-major 3 x p), skipping zero
    /// coefficients.
    pub fn compose_into(&self, c: &[f64], out: &mut [f64]) {
        let n = 3 * self.num_joints();
        debug_assert_eq!(c.len(), self.k);
        debug_assert_eq!(out.len(), n);
        out.copy_from_slice(&self.offset);
        for (ci, b) in c.iter().zip(self.bases.chunks_exact(n)) {
            if *ci != 0.0 {
                out.iter_mut().zip(b).for_each(|(o, b)| *o += ci * b);
            }
        }
    }

    /// `offset + sum_i c_i B_i`, row-major 3 x p.
    pub fn compose(&self, c: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; 3 * self.num_joints()];
        self.compose_into(c, &mut out);
        out
    }
}
