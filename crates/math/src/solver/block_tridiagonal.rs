//! Symmetric positive definite block-tridiagonal systems: the Newton systems of the
//! C-step over a window, with one diagonal block per frame (the active coefficients of
//! that frame) and the temporal coupling between neighbouring frames off the diagonal.
//!
//! Block Cholesky (the block form of the Thomas algorithm): `D_0 = L_0 L_0'`, then for
//! each frame `E_t = C_t L_{t-1}^-T` and `L_t L_t' = D_t - E_t E_t'`. A solve is one
//! forward and one backward block substitution. Every dense step goes through `faer`
//! (in-place Cholesky, triangular solves, products); the
//! cost is `O(sum_t a_t^3)` for blocks of size `a_t`, against `O((sum_t a_t)^3)` dense.

use crate::solver::zeroed_with_room;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{LltRegularization, cholesky_in_place};
use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, MatMut, MatRef, Par};

/// A block-tridiagonal symmetric matrix and, after [`Self::factor`], its block Cholesky
/// factor. Buffers are reused between systems of any block sizes.
#[derive(Default)]
pub struct BlockTridiagonal {
    sizes: Vec<usize>,
    diag_at: Vec<usize>,
    lower_at: Vec<usize>,
    /// Diagonal blocks, column-major, then the factors `L_t`.
    diag: Vec<f64>,
    /// Blocks `(t, t-1)`, `a_t x a_{t-1}`, column-major, then `E_t`.
    lower: Vec<f64>,
    /// Offsets of each block's entries in a stacked vector.
    vec_at: Vec<usize>,
    scratch: Option<MemBuffer>,
    /// A diagonal block before a failed factorisation.
    backup: Vec<f64>,
    scratch_dim: usize,
    /// The most blocks, and the largest block, seen so far.
    peak: (usize, usize),
}

impl std::fmt::Debug for BlockTridiagonal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockTridiagonal")
            .field("sizes", &self.sizes)
            .finish_non_exhaustive()
    }
}

impl Clone for BlockTridiagonal {
    fn clone(&self) -> Self {
        Self {
            sizes: self.sizes.clone(),
            diag_at: self.diag_at.clone(),
            lower_at: self.lower_at.clone(),
            diag: self.diag.clone(),
            lower: self.lower.clone(),
            vec_at: self.vec_at.clone(),
            scratch: None,
            backup: Vec::new(),
            scratch_dim: 0,
            peak: self.peak,
        }
    }
}

impl BlockTridiagonal {
    /// Sets the block sizes and zeroes every block.
    pub fn reset(&mut self, sizes: impl IntoIterator<Item = usize>) {
        self.sizes.clear();
        self.sizes.extend(sizes);
        self.diag_at.clear();
        self.lower_at.clear();
        self.vec_at.clear();
        let (mut d, mut l, mut v, mut prev) = (0, 0, 0, 0);
        for &a in &self.sizes {
            self.diag_at.push(d);
            self.lower_at.push(l);
            self.vec_at.push(v);
            d += a * a;
            l += a * prev;
            v += a;
            prev = a;
        }
        self.vec_at.push(v);
        let max = self.sizes.iter().copied().max().unwrap_or(0);
        // Room for the most blocks seen, each twice the largest size seen
        // (`zeroed_with_room`): an active set that grows a little past the largest of
        // the warm-up (another track's motion) allocates nothing.
        self.peak.0 = self.peak.0.max(self.sizes.len());
        self.peak.1 = self.peak.1.max(max);
        let room = 2 * self.peak.1;
        let worst = self.peak.0 * room * room;
        zeroed_with_room(&mut self.diag, d, worst);
        zeroed_with_room(&mut self.lower, l, worst);
        // One block at a time.
        if self.backup.capacity() < self.peak.1 * self.peak.1 {
            self.backup.reserve_exact(room * room);
        }
        if self.scratch.is_none() || self.scratch_dim < max {
            // Room for blocks twice the largest seen, as the blocks' buffers.
            let dim = 2 * max;
            let req = faer::linalg::cholesky::llt::factor::cholesky_in_place_scratch::<f64>(
                dim,
                Par::Seq,
                Default::default(),
            );
            self.scratch = Some(MemBuffer::new(req));
            self.scratch_dim = dim;
        }
    }

    /// Number of blocks.
    pub fn blocks(&self) -> usize {
        self.sizes.len()
    }

    /// Size of block `t`.
    pub fn size(&self, t: usize) -> usize {
        self.sizes[t]
    }

    /// Total dimension (length of a stacked vector).
    pub fn dim(&self) -> usize {
        self.vec_at.last().copied().unwrap_or(0)
    }

    /// Offset of block `t` in a stacked vector.
    pub fn offset(&self, t: usize) -> usize {
        self.vec_at[t]
    }

    /// Diagonal block `t` (only its lower triangle is read).
    pub fn diag_mut(&mut self, t: usize) -> MatMut<'_, f64> {
        let a = self.sizes[t];
        let at = self.diag_at[t];
        MatMut::from_column_major_slice_mut(&mut self.diag[at..at + a * a], a, a)
    }

    /// Off-diagonal block `(t, t-1)`, `t >= 1`.
    pub fn lower_mut(&mut self, t: usize) -> MatMut<'_, f64> {
        let (a, b) = (self.sizes[t], self.sizes[t - 1]);
        let at = self.lower_at[t];
        MatMut::from_column_major_slice_mut(&mut self.lower[at..at + a * b], a, b)
    }

    /// Factorises in place. A block that is not numerically positive definite (collinear
    /// atoms) gets a ridge of `epsilon` times the largest diagonal entry, grown tenfold
    /// until it factorises, so the factor is always of a positive definite matrix close
    /// to the input; returns how many blocks needed one.
    pub fn factor(&mut self, epsilon: f64) -> usize {
        let scale = self.max_diagonal().max(f64::MIN_POSITIVE);
        let mut ridged = 0;
        let Some(buf) = self.scratch.as_mut() else {
            return 0;
        };
        for t in 0..self.sizes.len() {
            let a = self.sizes[t];
            if a == 0 {
                continue;
            }
            let (d0, d1) = (self.diag_at[t], self.diag_at[t] + a * a);
            if t > 0 && self.sizes[t - 1] > 0 {
                let b = self.sizes[t - 1];
                let (p0, p1) = (self.diag_at[t - 1], self.diag_at[t - 1] + b * b);
                let (l0, l1) = (self.lower_at[t], self.lower_at[t] + a * b);
                let l_prev = MatRef::from_column_major_slice(&self.diag[p0..p1], b, b);
                let mut e = MatMut::from_column_major_slice_mut(&mut self.lower[l0..l1], a, b);
                // E_t' = L_{t-1}^-1 C_t'.
                solve_lower_triangular_in_place(l_prev, e.as_mut().transpose_mut(), Par::Seq);
                let e = e.as_ref();
                let d = MatMut::from_column_major_slice_mut(&mut self.diag[d0..d1], a, a);
                triangular::matmul(
                    d,
                    BlockStructure::TriangularLower,
                    Accum::Add,
                    e,
                    BlockStructure::Rectangular,
                    e.transpose(),
                    BlockStructure::Rectangular,
                    -1.0,
                    Par::Seq,
                );
            }
            self.backup.clear();
            self.backup.extend_from_slice(&self.diag[d0..d1]);
            let mut ridge = 0.0;
            for _ in 0..32 {
                let d = MatMut::from_column_major_slice_mut(&mut self.diag[d0..d1], a, a);
                let ok = cholesky_in_place(
                    d,
                    LltRegularization::default(),
                    Par::Seq,
                    MemStack::new(buf),
                    Default::default(),
                )
                .is_ok();
                if ok {
                    break;
                }
                ridge = if ridge == 0.0 {
                    epsilon * scale
                } else {
                    10.0 * ridge
                };
                self.diag[d0..d1].copy_from_slice(&self.backup);
                for i in 0..a {
                    self.diag[d0 + i * a + i] += ridge;
                }
            }
            if ridge > 0.0 {
                ridged += 1;
            }
        }
        ridged
    }

    fn max_diagonal(&self) -> f64 {
        let mut m = 0.0_f64;
        for (t, &a) in self.sizes.iter().enumerate() {
            let d = &self.diag[self.diag_at[t]..self.diag_at[t] + a * a];
            for i in 0..a {
                m = m.max(d[i * a + i].abs());
            }
        }
        m
    }

    /// Solves `A x = b` in place (`b` stacked by blocks) with the factor.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let n = self.sizes.len();
        // Forward: z_t = L_t^-1 (b_t - E_t z_{t-1}).
        for t in 0..n {
            let a = self.sizes[t];
            if a == 0 {
                continue;
            }
            let (v0, v1) = (self.vec_at[t], self.vec_at[t + 1]);
            if t > 0 && self.sizes[t - 1] > 0 {
                let bprev = self.sizes[t - 1];
                let (head, tail) = b.split_at_mut(v0);
                let z_prev = MatRef::from_column_major_slice(&head[self.vec_at[t - 1]..], bprev, 1);
                let e = self.e(t);
                let bt = MatMut::from_column_major_slice_mut(&mut tail[..v1 - v0], a, 1);
                matmul(bt, Accum::Add, e, z_prev, -1.0, Par::Seq);
            }
            let bt = MatMut::from_column_major_slice_mut(&mut b[v0..v1], a, 1);
            solve_lower_triangular_in_place(self.l(t), bt, Par::Seq);
        }
        // Backward: x_t = L_t^-T (z_t - E_{t+1}' x_{t+1}).
        for t in (0..n).rev() {
            let a = self.sizes[t];
            if a == 0 {
                continue;
            }
            let (v0, v1) = (self.vec_at[t], self.vec_at[t + 1]);
            if t + 1 < n && self.sizes[t + 1] > 0 {
                let bnext = self.sizes[t + 1];
                let (head, tail) = b.split_at_mut(v1);
                let x_next = MatRef::from_column_major_slice(&tail[..bnext], bnext, 1);
                let e = self.e(t + 1);
                let bt = MatMut::from_column_major_slice_mut(&mut head[v0..v1], a, 1);
                matmul(bt, Accum::Add, e.transpose(), x_next, -1.0, Par::Seq);
            }
            let bt = MatMut::from_column_major_slice_mut(&mut b[v0..v1], a, 1);
            solve_upper_triangular_in_place(self.l(t).transpose(), bt, Par::Seq);
        }
    }

    fn l(&self, t: usize) -> MatRef<'_, f64> {
        let a = self.sizes[t];
        MatRef::from_column_major_slice(&self.diag[self.diag_at[t]..][..a * a], a, a)
    }

    fn e(&self, t: usize) -> MatRef<'_, f64> {
        let (a, b) = (self.sizes[t], self.sizes[t - 1]);
        MatRef::from_column_major_slice(&self.lower[self.lower_at[t]..][..a * b], a, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random-looking SPD block-tridiagonal matrix, dense, with blocks of `sizes`.
    fn example(sizes: &[usize]) -> (BlockTridiagonal, Vec<Vec<f64>>) {
        let n: usize = sizes.iter().sum();
        let mut dense = vec![vec![0.0; n]; n];
        let mut at = vec![0];
        for s in sizes {
            at.push(at.last().copied().unwrap_or(0) + s);
        }
        let val = |i: usize, j: usize| (((i * 31 + j * 17) % 23) as f64 / 23.0) - 0.5;
        for t in 0..sizes.len() {
            for i in at[t]..at[t + 1] {
                for j in at[t]..at[t + 1] {
                    let v = val(i.min(j), i.max(j));
                    dense[i][j] = v;
                }
                dense[i][i] = 4.0;
            }
            if t > 0 {
                for i in at[t]..at[t + 1] {
                    for j in at[t - 1]..at[t] {
                        let v = 0.7 * val(i, j);
                        dense[i][j] = v;
                        dense[j][i] = v;
                    }
                }
            }
        }
        let mut bt = BlockTridiagonal::default();
        bt.reset(sizes.iter().copied());
        for t in 0..sizes.len() {
            let mut d = bt.diag_mut(t);
            for i in 0..sizes[t] {
                for j in 0..sizes[t] {
                    d[(i, j)] = dense[at[t] + i][at[t] + j];
                }
            }
            if t > 0 {
                let mut l = bt.lower_mut(t);
                for i in 0..sizes[t] {
                    for j in 0..sizes[t - 1] {
                        l[(i, j)] = dense[at[t] + i][at[t - 1] + j];
                    }
                }
            }
        }
        (bt, dense)
    }

    #[test]
    fn solves_like_the_dense_system() {
        for sizes in [vec![3], vec![2, 0, 4, 1], vec![5, 3, 3, 2, 6]] {
            let (mut bt, dense) = example(&sizes);
            let n = bt.dim();
            assert_eq!(bt.factor(1e-14), 0);
            let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
            let mut x = b.clone();
            bt.solve_in_place(&mut x);
            for i in 0..n {
                let ax: f64 = (0..n).map(|j| dense[i][j] * x[j]).sum();
                assert!(
                    (ax - b[i]).abs() < 1e-12,
                    "{sizes:?}: row {i}: {ax} vs {}",
                    b[i]
                );
            }
        }
    }

    #[test]
    fn singular_blocks_are_regularised_not_fatal() {
        let mut bt = BlockTridiagonal::default();
        bt.reset([2]);
        let mut d = bt.diag_mut(0);
        d[(0, 0)] = 1.0;
        d[(1, 0)] = 1.0;
        d[(1, 1)] = 1.0;
        assert_eq!(bt.factor(1e-10), 1);
        let mut x = vec![1.0, -1.0];
        bt.solve_in_place(&mut x);
        assert!(x.iter().all(|v| v.is_finite()));
    }
}
