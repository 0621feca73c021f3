//! Sparse Cholesky factorization of a symmetric positive-definite matrix in 6×6 blocks:
//! the normal equations over poses, as the [`pose_graph`](super::pose_graph)'s `H` and
//! [`bundle`](super::bundle) adjustment's reduced keyframe system (the Schur complement
//! on the landmarks) are. Both are sparse: a keyframe is coupled to the few it shares
//! landmarks (or edges) with, plus the loop closures.
//!
//! - [`BlockStructure`] is the symbolic part: an exact **minimum-degree** ordering of the
//!   block graph (ties broken by the lowest variable index), computed while simulating
//!   the elimination, which also gives the structure of `L` (the neighbours of a node
//!   when it is eliminated are the rows of its column) and the list of block updates the
//!   numeric factorization makes. A chain closed by one loop edge is eliminated from its
//!   start around the cycle, two off-diagonal blocks per column; with couplings across
//!   the chain (a serpentine's neighbouring rows) it fills far less than the natural
//!   order's envelope (the [`pose_graph`](super::pose_graph) documentation has figures).
//! - [`BlockCholesky`] is the numeric part, right-looking over 6×6 blocks: each diagonal
//!   block is factored and inverted (`L_jj⁻¹`), the column below is scaled and its outer
//!   products are subtracted from the later blocks, in the precomputed list; the two
//!   triangular solves follow. A structure serves any number of factorizations (each
//!   Levenberg-Marquardt iteration and damping).
//!
//! Everything runs on one thread in a fixed order, so the result is bit-identical run to
//! run.
//!
//! ```
//! use nalgebra::{Matrix6, Vector6};
//! use vinebench_onboard::slam::block_cholesky::{BlockCholesky, BlockStructure};
//!
//! // A chain of three poses, 0 - 1 - 2: H = [[2I, -I, 0], [-I, 2I, -I], [0, -I, 2I]].
//! let s = BlockStructure::new(3, [(0, 1), (1, 2)]);
//! let diag = vec![Matrix6::identity() * 2.0; 3];
//! let mut off = vec![Matrix6::zeros(); s.n_blocks()];
//! for (a, b) in [(0, 1), (1, 2)] {
//!     off[s.block(a, b).0] = -Matrix6::identity();
//! }
//! let mut chol = BlockCholesky::new(&s);
//! assert!(chol.factor(&s, &diag, &off));
//! // Solve H x = (1, 0, 1)·1 (by position): x = (1, 1, 1)·1.
//! let mut x: Vec<Vector6<f64>> = (0..3)
//!     .map(|p| Vector6::repeat(if s.variable_at(p) == 1 { 0.0 } else { 1.0 }))
//!     .collect();
//! chol.solve(&s, &mut x);
//! assert!(x.iter().all(|v| (v - Vector6::repeat(1.0)).amax() < 1e-12));
//! ```

use std::collections::BTreeSet;
use std::ops::Range;

use nalgebra::{Matrix6, Vector6};

/// The block structure of a symmetric matrix over `n` variables (6×6 blocks) in its
/// elimination order, and the structure of its Cholesky factor `L`, whose off-diagonal
/// blocks hold those of the matrix where it has them (the others are fill).
///
/// Matrices and vectors handed to [`BlockCholesky`] are indexed by **position** in the
/// elimination order ([`BlockStructure::position`], [`BlockStructure::variable_at`]):
/// diagonal blocks and vector entries by position, off-diagonal blocks by slot
/// ([`BlockStructure::block`]).
#[derive(Clone, Debug)]
pub struct BlockStructure {
    /// Position in the elimination order of each variable.
    position: Vec<usize>,
    /// The variable at each position.
    variable_at: Vec<usize>,
    /// Column `j`'s off-diagonal blocks are the slots `col_start[j]..col_start[j + 1]`.
    col_start: Vec<usize>,
    /// The row (position, increasing within a column, all below the diagonal) of each slot.
    rows: Vec<usize>,
    /// Column `j`'s block updates are `updates[update_start[j]..update_start[j + 1]]`.
    update_start: Vec<usize>,
    /// `(target, s, t)`: `block[target] -= block[s] · block[t]ᵀ`, the rows of `s` and `t`
    /// being the row and column of `target`.
    updates: Vec<(usize, usize, usize)>,
}

impl BlockStructure {
    /// The minimum-degree ordering of `n` variables coupled by `pairs` (either order,
    /// repeats and `(a, a)` allowed; every index below `n`) and the structure of its
    /// Cholesky factor.
    ///
    /// # Panics
    /// If a pair names a variable `≥ n`.
    pub fn new(n: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> BlockStructure {
        let mut adj: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
        for (u, v) in pairs {
            assert!(u < n && v < n, "pair ({u}, {v}) outside {n} variables");
            if u != v {
                adj[u].insert(v);
                adj[v].insert(u);
            }
        }
        // Exact minimum degree on the elimination graph; ties by the lowest variable.
        let mut queue: BTreeSet<(usize, usize)> = (0..n).map(|v| (adj[v].len(), v)).collect();
        let mut order = Vec::with_capacity(n);
        let mut column_of_var = vec![Vec::new(); n];
        while let Some((_, v)) = queue.pop_first() {
            let nbrs: Vec<usize> = std::mem::take(&mut adj[v]).into_iter().collect();
            for &u in &nbrs {
                queue.remove(&(adj[u].len(), u));
                adj[u].remove(&v);
                adj[u].extend(nbrs.iter().copied().filter(|&w| w != u));
                queue.insert((adj[u].len(), u));
            }
            order.push(v);
            column_of_var[v] = nbrs;
        }
        let mut position = vec![0; n];
        for (p, &v) in order.iter().enumerate() {
            position[v] = p;
        }
        let mut col_start = Vec::with_capacity(n + 1);
        let mut rows = Vec::new();
        for &v in &order {
            col_start.push(rows.len());
            let start = rows.len();
            rows.extend(column_of_var[v].iter().map(|&u| position[u]));
            rows[start..].sort_unstable();
        }
        col_start.push(rows.len());
        let mut structure = BlockStructure {
            position,
            variable_at: order,
            col_start,
            rows,
            update_start: Vec::with_capacity(n + 1),
            updates: Vec::new(),
        };
        for j in 0..n {
            structure.update_start.push(structure.updates.len());
            let (start, end) = (structure.col_start[j], structure.col_start[j + 1]);
            for s in start..end {
                for t in start..s {
                    let target = structure.slot(structure.rows[t], structure.rows[s]);
                    structure.updates.push((target, s, t));
                }
            }
        }
        structure.update_start.push(structure.updates.len());
        structure
    }

    /// Variables.
    pub fn len(&self) -> usize {
        self.variable_at.len()
    }

    /// No variables.
    pub fn is_empty(&self) -> bool {
        self.variable_at.is_empty()
    }

    /// Off-diagonal blocks of `L` (slots), fill included.
    pub fn n_blocks(&self) -> usize {
        self.rows.len()
    }

    /// Block products of one factorization (a measure of its cost).
    pub fn n_updates(&self) -> usize {
        self.updates.len()
    }

    /// The position of `variable` in the elimination order.
    pub fn position(&self, variable: usize) -> usize {
        self.position[variable]
    }

    /// The variable at `position`.
    pub fn variable_at(&self, position: usize) -> usize {
        self.variable_at[position]
    }

    /// The slots of column `position` (its off-diagonal blocks, rows increasing).
    pub fn column(&self, position: usize) -> Range<usize> {
        self.col_start[position]..self.col_start[position + 1]
    }

    /// The rows (positions, increasing) of column `position`'s slots.
    pub fn column_rows(&self, position: usize) -> &[usize] {
        &self.rows[self.column(position)]
    }

    /// The row (a position) of `slot`.
    pub fn row(&self, slot: usize) -> usize {
        self.rows[slot]
    }

    /// The slot of block `(row, col)`, positions, `row > col`. The elimination makes the
    /// neighbours of an eliminated node a clique, so every pair of rows of a column, and
    /// every coupled pair, has its block in the column eliminated first.
    ///
    /// # Panics
    /// If the block is not in `L`'s structure.
    pub fn slot(&self, col: usize, row: usize) -> usize {
        let range = self.column(col);
        range.start
            + self.rows[range]
                .binary_search(&row)
                .expect("the elimination graph holds every fill block")
    }

    /// The slot of the block coupling variables `a` and `b` (a pair given to
    /// [`BlockStructure::new`]), and whether `a` is its row: the slot holds the matrix's
    /// block `(a, b)` if so, else `(b, a)` (its transpose).
    ///
    /// # Panics
    /// If `a == b` or the pair is not coupled.
    pub fn block(&self, a: usize, b: usize) -> (usize, bool) {
        let (pa, pb) = (self.position[a], self.position[b]);
        assert_ne!(pa, pb, "a diagonal block has no slot");
        (self.slot(pa.min(pb), pa.max(pb)), pa > pb)
    }
}

/// `L⁻¹` for the lower Cholesky factor `L` of the symmetric 6×6 `m` (its lower triangle
/// is read); `None` unless positive definite.
pub fn lower_cholesky_inverse(m: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    let mut l = Matrix6::zeros();
    for j in 0..6 {
        let mut d = m[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        if d.is_nan() || d <= 0.0 || d.is_infinite() {
            return None;
        }
        let djj = d.sqrt();
        l[(j, j)] = djj;
        for i in j + 1..6 {
            let mut s = m[(i, j)];
            for k in 0..j {
                s -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = s / djj;
        }
    }
    let mut inv = Matrix6::zeros();
    for j in 0..6 {
        inv[(j, j)] = 1.0 / l[(j, j)];
        for i in j + 1..6 {
            let mut s = 0.0;
            for k in j..i {
                s -= l[(i, k)] * inv[(k, j)];
            }
            inv[(i, j)] = s / l[(i, i)];
        }
    }
    Some(inv)
}

/// The Cholesky factor `L` of a matrix of a [`BlockStructure`], reusable across
/// factorizations of the same structure.
#[derive(Clone, Debug)]
pub struct BlockCholesky {
    /// `L_jj⁻¹`, by position.
    diag_inv: Vec<Matrix6<f64>>,
    /// `L`'s off-diagonal blocks, by slot.
    off: Vec<Matrix6<f64>>,
}

impl BlockCholesky {
    /// Buffers for `structure`.
    pub fn new(structure: &BlockStructure) -> BlockCholesky {
        BlockCholesky {
            diag_inv: vec![Matrix6::zeros(); structure.len()],
            off: vec![Matrix6::zeros(); structure.n_blocks()],
        }
    }

    /// Factors the matrix with diagonal blocks `diag` (by position; lower triangles read)
    /// and off-diagonal blocks `off` (by slot: block `(row, column)` of the slot, zero at
    /// fill slots); `false` when a pivot block is not positive definite (the matrix is
    /// not, to rounding).
    ///
    /// # Panics
    /// If the lengths do not match `structure`.
    pub fn factor(
        &mut self,
        structure: &BlockStructure,
        diag: &[Matrix6<f64>],
        off: &[Matrix6<f64>],
    ) -> bool {
        let s = structure;
        assert_eq!(diag.len(), s.len(), "one diagonal block per variable");
        assert_eq!(off.len(), s.n_blocks(), "one block per slot");
        if self.diag_inv.len() != s.len() || self.off.len() != s.n_blocks() {
            *self = BlockCholesky::new(s);
        }
        self.diag_inv.copy_from_slice(diag);
        self.off.copy_from_slice(off);
        for j in 0..s.len() {
            let Some(l_inv) = lower_cholesky_inverse(&self.diag_inv[j]) else {
                return false;
            };
            self.diag_inv[j] = l_inv;
            let l_inv_t = l_inv.transpose();
            let column = s.column(j);
            for slot in column.clone() {
                self.off[slot] *= l_inv_t;
            }
            for slot in column {
                let b = self.off[slot];
                self.diag_inv[s.rows[slot]] -= b * b.transpose();
            }
            for &(target, a, b) in &s.updates[s.update_start[j]..s.update_start[j + 1]] {
                let u = self.off[a] * self.off[b].transpose();
                self.off[target] -= u;
            }
        }
        true
    }

    /// Solves `L Lᵀ x = b` in place (`x` holds `b`, by position, on entry) after a
    /// successful [`BlockCholesky::factor`].
    ///
    /// # Panics
    /// If `x`'s length does not match `structure`.
    pub fn solve(&self, structure: &BlockStructure, x: &mut [Vector6<f64>]) {
        let s = structure;
        assert_eq!(x.len(), s.len(), "one entry per variable");
        for j in 0..s.len() {
            let y = self.diag_inv[j] * x[j];
            x[j] = y;
            for slot in s.column(j) {
                x[s.rows[slot]] -= self.off[slot] * y;
            }
        }
        for j in (0..s.len()).rev() {
            let mut y = x[j];
            for slot in s.column(j) {
                y -= self.off[slot].tr_mul(&x[s.rows[slot]]);
            }
            x[j] = self.diag_inv[j].tr_mul(&y);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector, Matrix6};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_block(rng: &mut ChaCha8Rng) -> Matrix6<f64> {
        Matrix6::from_fn(|_, _| rng.random_range(-1.0..1.0))
    }

    /// A block-sparse matrix in [`BlockCholesky::factor`]'s form and densely.
    struct Problem {
        s: BlockStructure,
        diag: Vec<Matrix6<f64>>,
        off: Vec<Matrix6<f64>>,
        dense: DMatrix<f64>,
    }

    /// A random block-sparse SPD matrix over `n` variables coupled by `pairs`: each
    /// coupled pair gets a random block, and each diagonal block dominates its row.
    fn random_problem(n: usize, pairs: &[(usize, usize)], seed: u64) -> Problem {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let s = BlockStructure::new(n, pairs.iter().copied());
        let mut dense = DMatrix::<f64>::zeros(6 * n, 6 * n);
        let mut off = vec![Matrix6::zeros(); s.n_blocks()];
        for &(a, b) in pairs {
            if a == b {
                continue;
            }
            let m = random_block(&mut rng);
            let (slot, a_is_row) = s.block(a, b);
            off[slot] += if a_is_row { m } else { m.transpose() };
            let mut ab = dense.view_mut((6 * a, 6 * b), (6, 6));
            ab += m;
            let mut ba = dense.view_mut((6 * b, 6 * a), (6, 6));
            ba += m.transpose();
        }
        let mut diag = vec![Matrix6::zeros(); n];
        for v in 0..n {
            let row_sum: f64 = (0..6 * n)
                .filter(|&c| c / 6 != v)
                .map(|c| {
                    (0..6)
                        .map(|r| dense[(6 * v + r, c)].abs())
                        .fold(0.0, f64::max)
                })
                .sum();
            let r = random_block(&mut rng);
            let d = r * r.transpose() + Matrix6::identity() * (row_sum + 1.0);
            diag[s.position(v)] = d;
            dense.view_mut((6 * v, 6 * v), (6, 6)).copy_from(&d);
        }
        Problem {
            s,
            diag,
            off,
            dense,
        }
    }

    /// The sparse solve against nalgebra's dense Cholesky on random sparse SPD systems.
    #[test]
    fn sparse_solve_matches_dense_cholesky() {
        for seed in 0..5u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            let n = 40;
            let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
            for _ in 0..30 {
                pairs.push((rng.random_range(0..n), rng.random_range(0..n)));
            }
            let Problem {
                s,
                diag,
                off,
                dense,
            } = random_problem(n, &pairs, seed);
            let b = DVector::from_fn(6 * n, |_, _| rng.random_range(-1.0..1.0));
            let expected = dense.cholesky().expect("SPD by construction").solve(&b);
            let mut chol = BlockCholesky::new(&s);
            assert!(chol.factor(&s, &diag, &off));
            let mut x: Vec<Vector6<f64>> = (0..n)
                .map(|p| b.fixed_rows::<6>(6 * s.variable_at(p)).into_owned())
                .collect();
            chol.solve(&s, &mut x);
            for v in 0..n {
                let got = x[s.position(v)];
                let want = expected.fixed_rows::<6>(6 * v);
                assert!(
                    (got - want).amax() < 1e-10 * (1.0 + want.amax()),
                    "seed {seed}, variable {v}: {got} vs {want}"
                );
            }
        }
    }

    /// A chain closed by a loop fills nothing beyond one row: the minimum-degree order
    /// eliminates around the cycle, at most two off-diagonal blocks per column.
    #[test]
    fn a_closed_chain_factors_with_two_blocks_per_column() {
        let n = 200;
        let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        pairs.push((n - 1, 0));
        let s = BlockStructure::new(n, pairs);
        assert!((0..n).all(|p| s.column(p).len() <= 2));
        assert_eq!(s.n_blocks(), 2 * n - 3);
        // An unconnected variable has an empty column.
        let s = BlockStructure::new(3, [(0, 1), (1, 1)]);
        assert_eq!(s.n_blocks(), 1);
        assert_eq!(s.column(s.position(2)).len(), 0);
    }

    /// A matrix that is not positive definite is refused, not factored into NaN.
    #[test]
    fn an_indefinite_matrix_is_refused() {
        let s = BlockStructure::new(2, [(0, 1)]);
        let diag = vec![Matrix6::identity(); 2];
        let off = vec![Matrix6::identity() * 2.0];
        let mut chol = BlockCholesky::new(&s);
        assert!(!chol.factor(&s, &diag, &off));
        assert!(chol.factor(&s, &diag, &[Matrix6::identity() * 0.5]));
    }
}
