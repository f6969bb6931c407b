//! Sparse symmetric matrices with a fixed pattern and their Cholesky factorisation.
//!
//! This is the one module that talks to `faer` (0.24): an upstream rename touches only this file.
//! The pattern is built once; each step only the values change. The fill-reducing ordering and
//! the symbolic factorisation are computed once ([`Cholesky::try_new`]); each step runs the
//! numeric `L Lᵀ` factorisation into preallocated storage ([`Cholesky::factorize`]) and the
//! solves reuse preallocated scratch ([`Cholesky::solve_in_place`]). Single-threaded
//! (`Par::Seq`): at the sizes of this project one thread is faster than two.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side, Spec};
use std::fmt;

/// Why a sparse operation failed.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LinalgError {
    /// The matrix is not numerically positive definite: the pivot of this (permuted) column was ≤ 0.
    #[error("matrix is not positive definite (non-positive pivot at permuted column {pivot})")]
    NotPositiveDefinite {
        /// Index of the failing pivot in the permuted ordering.
        pivot: usize,
    },
    /// The symbolic analysis failed (out of memory or index overflow).
    #[error("symbolic Cholesky analysis failed")]
    Symbolic,
    /// No numeric factorisation is available yet ([`Cholesky::factorize`] was not called or failed).
    #[error("no numeric factorisation available")]
    NotFactorized,
    /// A vector has the wrong length.
    #[error("vector length {got}, expected {expected}")]
    DimensionMismatch {
        /// Expected length.
        expected: usize,
        /// Length given.
        got: usize,
    },
}

/// Upper-triangular compressed-column pattern of a symmetric `n × n` matrix (row ≤ column),
/// with every diagonal entry present and row indices sorted within each column.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SymmetricPattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
}

impl SymmetricPattern {
    /// Builds the pattern from `(row, col)` entries in any order, either triangle; duplicates are
    /// merged and every diagonal entry is added.
    ///
    /// # Panics
    /// Panics if an index is `≥ n` (a programming error: entries come from the caller's own maps).
    pub fn from_entries(n: usize, entries: impl IntoIterator<Item = (usize, usize)>) -> Self {
        let mut cols: Vec<Vec<usize>> = (0..n).map(|j| vec![j]).collect();
        for (r, c) in entries {
            assert!(
                r < n && c < n,
                "pattern entry ({r}, {c}) out of range for n = {n}"
            );
            let (r, c) = if r <= c { (r, c) } else { (c, r) };
            cols[c].push(r);
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for mut col in cols {
            col.sort_unstable();
            col.dedup();
            row_idx.extend_from_slice(&col);
            col_ptr.push(row_idx.len());
        }
        Self {
            n,
            col_ptr,
            row_idx,
        }
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Number of stored (upper-triangular) entries.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Index in the value array of entry `(row, col)` or `(col, row)`; `None` if not in the pattern.
    pub fn slot(&self, row: usize, col: usize) -> Option<usize> {
        let (r, c) = if row <= col { (row, col) } else { (col, row) };
        if c >= self.n {
            return None;
        }
        let (a, b) = (self.col_ptr[c], self.col_ptr[c + 1]);
        self.row_idx[a..b].binary_search(&r).ok().map(|k| a + k)
    }

    fn symbolic(&self) -> SymbolicSparseColMatRef<'_, usize> {
        SymbolicSparseColMatRef::new_checked(self.n, self.n, &self.col_ptr, None, &self.row_idx)
    }
}

/// A symmetric sparse matrix: a fixed [`SymmetricPattern`] (upper triangle stored) and its values.
#[derive(Clone, Debug, PartialEq)]
pub struct SymmetricMatrix {
    pattern: SymmetricPattern,
    /// Values of the stored upper-triangular entries, indexed by [`SymmetricPattern::slot`].
    pub values: Vec<f64>,
}

impl SymmetricMatrix {
    /// A zero matrix with the given pattern.
    pub fn zeros(pattern: SymmetricPattern) -> Self {
        let values = vec![0.0; pattern.nnz()];
        Self { pattern, values }
    }

    /// The pattern.
    pub fn pattern(&self) -> &SymmetricPattern {
        &self.pattern
    }

    /// Sets every value to zero (the pattern stays).
    pub fn fill_zero(&mut self) {
        self.values.iter_mut().for_each(|v| *v = 0.0);
    }

    /// Entry `(row, col)` (0 outside the pattern).
    pub fn get(&self, row: usize, col: usize) -> f64 {
        self.pattern.slot(row, col).map_or(0.0, |s| self.values[s])
    }

    /// `out = A x` using both triangles.
    ///
    /// # Errors
    /// [`LinalgError::DimensionMismatch`] if `x` or `out` has the wrong length.
    pub fn mul_vec(&self, x: &[f64], out: &mut [f64]) -> Result<(), LinalgError> {
        let n = self.pattern.n;
        for len in [x.len(), out.len()] {
            if len != n {
                return Err(LinalgError::DimensionMismatch {
                    expected: n,
                    got: len,
                });
            }
        }
        out.iter_mut().for_each(|v| *v = 0.0);
        for c in 0..n {
            for k in self.pattern.col_ptr[c]..self.pattern.col_ptr[c + 1] {
                let r = self.pattern.row_idx[k];
                let a = self.values[k];
                out[r] += a * x[c];
                if r != c {
                    out[c] += a * x[r];
                }
            }
        }
        Ok(())
    }
}

/// Sparse Cholesky `A = L Lᵀ` with the symbolic part computed once and the numeric part
/// refreshed by [`Cholesky::factorize`]; all memory is allocated at construction.
pub struct Cholesky {
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    factor_mem: MemBuffer,
    solve_mem: MemBuffer,
    solve_cols: usize,
    factorized: bool,
}

impl fmt::Debug for Cholesky {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Cholesky")
            .field("dim", &self.dim())
            .field("factor_nnz", &self.l_values.len())
            .field("factorized", &self.factorized)
            .finish()
    }
}

impl Cholesky {
    /// Fill-reducing ordering (AMD) and symbolic factorisation of `pattern`; scratch for the
    /// numeric factorisation and for solves with up to `max_rhs` right-hand sides at once.
    ///
    /// # Errors
    /// [`LinalgError::Symbolic`] if faer's analysis fails.
    pub fn try_new(pattern: &SymmetricPattern, max_rhs: usize) -> Result<Self, LinalgError> {
        Self::try_new_ordered(pattern, None, max_rhs)
    }

    /// As [`Cholesky::try_new`] with a given elimination order (`order[k]` = the row eliminated
    /// `k`-th, e.g. from [`nested_dissection_order`]); `None` uses AMD.
    ///
    /// # Errors
    /// [`LinalgError::Symbolic`] if faer's analysis fails or `order` is not a permutation.
    pub fn try_new_ordered(
        pattern: &SymmetricPattern,
        order: Option<&[usize]>,
        max_rhs: usize,
    ) -> Result<Self, LinalgError> {
        let n = pattern.dim();
        let inverse = match order {
            Some(fwd) => {
                let mut inv = vec![usize::MAX; n];
                if fwd.len() != n {
                    return Err(LinalgError::Symbolic);
                }
                for (k, &i) in fwd.iter().enumerate() {
                    if i >= n || inv[i] != usize::MAX {
                        return Err(LinalgError::Symbolic);
                    }
                    inv[i] = k;
                }
                inv
            }
            None => Vec::new(),
        };
        let ordering = match order {
            Some(fwd) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, &inverse, n)),
            None => SymmetricOrdering::Amd,
        };
        let symbolic = factorize_symbolic_cholesky(
            pattern.symbolic(),
            Side::Upper,
            ordering,
            CholeskySymbolicParams::default(),
        )
        .map_err(|_| LinalgError::Symbolic)?;
        let l_values = vec![0.0; symbolic.len_val()];
        let factor_req = symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Spec::default());
        let factor_mem = MemBuffer::try_new(factor_req).map_err(|_| LinalgError::Symbolic)?;
        let solve_cols = max_rhs.max(1);
        let solve_mem = MemBuffer::try_new(Self::solve_req(&symbolic, solve_cols))
            .map_err(|_| LinalgError::Symbolic)?;
        Ok(Self {
            symbolic,
            l_values,
            factor_mem,
            solve_mem,
            solve_cols,
            factorized: false,
        })
    }

    fn solve_req(symbolic: &SymbolicCholesky<usize>, cols: usize) -> StackReq {
        symbolic.solve_in_place_scratch::<f64>(cols, Par::Seq)
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.symbolic.nrows()
    }

    /// Number of stored values of the factor `L`.
    pub fn factor_nnz(&self) -> usize {
        self.l_values.len()
    }

    /// Whether a valid numeric factorisation is available.
    pub fn is_factorized(&self) -> bool {
        self.factorized
    }

    /// Numeric factorisation of `a`, which must have the pattern given to [`Cholesky::try_new`].
    ///
    /// # Errors
    /// [`LinalgError::NotPositiveDefinite`] if a pivot is not positive (the previous factor is
    /// then invalid), [`LinalgError::DimensionMismatch`] for a matrix of another size.
    pub fn factorize(&mut self, a: &SymmetricMatrix) -> Result<(), LinalgError> {
        self.factorized = false;
        if a.pattern.n != self.dim() {
            return Err(LinalgError::DimensionMismatch {
                expected: self.dim(),
                got: a.pattern.n,
            });
        }
        let mat = SparseColMatRef::new(a.pattern.symbolic(), &a.values);
        let stack = MemStack::new(&mut self.factor_mem);
        let res = self.symbolic.factorize_numeric_llt::<f64>(
            &mut self.l_values,
            mat,
            Side::Upper,
            LltRegularization::default(),
            Par::Seq,
            stack,
            Spec::default(),
        );
        match res {
            Ok(_) => {
                self.factorized = true;
                Ok(())
            }
            Err(faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index }) => {
                Err(LinalgError::NotPositiveDefinite { pivot: index })
            }
        }
    }

    /// Solves `A x = b` in place (`rhs` holds `b` on entry, `x` on return).
    ///
    /// # Errors
    /// [`LinalgError::NotFactorized`], [`LinalgError::DimensionMismatch`].
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<(), LinalgError> {
        self.solve_many_in_place(rhs, 1)
    }

    /// Solves `A X = B` in place for `ncols` right-hand sides stored column-major in `rhs`
    /// (`rhs.len() == n · ncols`). Scratch grows (once) if `ncols` exceeds the size given at
    /// construction.
    ///
    /// # Errors
    /// [`LinalgError::NotFactorized`], [`LinalgError::DimensionMismatch`].
    pub fn solve_many_in_place(
        &mut self,
        rhs: &mut [f64],
        ncols: usize,
    ) -> Result<(), LinalgError> {
        if !self.factorized {
            return Err(LinalgError::NotFactorized);
        }
        let n = self.dim();
        if rhs.len() != n * ncols {
            return Err(LinalgError::DimensionMismatch {
                expected: n * ncols,
                got: rhs.len(),
            });
        }
        if ncols == 0 {
            return Ok(());
        }
        if ncols > self.solve_cols {
            self.solve_mem = MemBuffer::try_new(Self::solve_req(&self.symbolic, ncols))
                .map_err(|_| LinalgError::Symbolic)?;
            self.solve_cols = ncols;
        }
        let llt = LltRef::<'_, usize, f64>::new(&self.symbolic, &self.l_values);
        let mat = MatMut::from_column_major_slice_mut(rhs, n, ncols);
        llt.solve_in_place_with_conj(Conj::No, mat, Par::Seq, MemStack::new(&mut self.solve_mem));
        Ok(())
    }
}

/// Scratch of [`pcg_solve`]: four vectors of the system's size, allocated once.
#[derive(Clone, Debug, Default)]
pub struct PcgWork {
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl PcgWork {
    /// Scratch for systems of dimension `n`.
    pub fn new(n: usize) -> Self {
        Self {
            r: vec![0.0; n],
            z: vec![0.0; n],
            p: vec![0.0; n],
            q: vec![0.0; n],
        }
    }
}

/// What a [`pcg_solve`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PcgOutcome {
    /// Iterations made (matrix-vector products); 0 for a zero right-hand side.
    pub iterations: usize,
    /// `‖b − A x‖ / ‖b‖` at the end (0 for a zero right-hand side).
    pub relative_residual: f64,
    /// Whether the residual reached the tolerance. `false`: the iteration cap was hit, or the
    /// iteration broke down (`pᵀAp ≤ 0` or a non-finite value: `A` or the preconditioner is
    /// not positive definite); `x` then holds the last finite iterate.
    pub converged: bool,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Preconditioned conjugate gradients on `A x = b` from `x = 0`, with the factor `pre` of a
/// nearby matrix as preconditioner (`z = pre⁻¹ r`): stops when `‖b − A x‖ ≤ tolerance ‖b‖`
/// (Euclidean norms) or after `max_iterations` iterations. With `pre` the factor of `A` itself
/// it converges in one iteration.
///
/// # Errors
/// [`LinalgError::DimensionMismatch`] for vectors or a factor of another size,
/// [`LinalgError::NotFactorized`] when `pre` holds no factorisation.
pub fn pcg_solve(
    a: &SymmetricMatrix,
    pre: &mut Cholesky,
    b: &[f64],
    x: &mut [f64],
    work: &mut PcgWork,
    tolerance: f64,
    max_iterations: usize,
) -> Result<PcgOutcome, LinalgError> {
    pcg_iterate(a, pre, b, x, work, tolerance, max_iterations, false)
}

/// [`pcg_solve`] from the initial guess `x` (on entry) instead of zero: one more product with
/// `A` for the initial residual `b − A x`. A guess that already meets the tolerance returns at
/// once, with 0 iterations and `x` unchanged.
///
/// # Errors
/// As [`pcg_solve`].
pub fn pcg_solve_from(
    a: &SymmetricMatrix,
    pre: &mut Cholesky,
    b: &[f64],
    x: &mut [f64],
    work: &mut PcgWork,
    tolerance: f64,
    max_iterations: usize,
) -> Result<PcgOutcome, LinalgError> {
    pcg_iterate(a, pre, b, x, work, tolerance, max_iterations, true)
}

#[allow(clippy::too_many_arguments)]
fn pcg_iterate(
    a: &SymmetricMatrix,
    pre: &mut Cholesky,
    b: &[f64],
    x: &mut [f64],
    work: &mut PcgWork,
    tolerance: f64,
    max_iterations: usize,
    warm: bool,
) -> Result<PcgOutcome, LinalgError> {
    let n = a.pattern.dim();
    for len in [b.len(), x.len(), pre.dim(), work.r.len()] {
        if len != n {
            return Err(LinalgError::DimensionMismatch {
                expected: n,
                got: len,
            });
        }
    }
    let b_norm = dot(b, b).sqrt();
    if b_norm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return Ok(PcgOutcome {
            iterations: 0,
            relative_residual: 0.0,
            converged: true,
        });
    }
    let PcgWork { r, z, p, q } = work;
    let mut outcome = PcgOutcome {
        iterations: 0,
        relative_residual: 1.0,
        converged: false,
    };
    if warm {
        a.mul_vec(x, q)?;
        for ((ri, bi), qi) in r.iter_mut().zip(b).zip(q.iter()) {
            *ri = bi - qi;
        }
        outcome.relative_residual = dot(r, r).sqrt() / b_norm;
        if !outcome.relative_residual.is_finite() {
            return Ok(outcome);
        }
        if outcome.relative_residual <= tolerance {
            outcome.converged = true;
            return Ok(outcome);
        }
    } else {
        x.iter_mut().for_each(|v| *v = 0.0);
        r.copy_from_slice(b);
    }
    z.copy_from_slice(r);
    pre.solve_in_place(z)?;
    p.copy_from_slice(z);
    let mut rz = dot(r, z);
    while outcome.iterations < max_iterations {
        a.mul_vec(p, q)?;
        let pq = dot(p, q);
        let alpha = rz / pq;
        if !(pq > 0.0 && alpha.is_finite()) {
            return Ok(outcome);
        }
        outcome.iterations += 1;
        for ((xi, ri), (pi, qi)) in x.iter_mut().zip(r.iter_mut()).zip(p.iter().zip(q.iter())) {
            *xi += alpha * pi;
            *ri -= alpha * qi;
        }
        outcome.relative_residual = dot(r, r).sqrt() / b_norm;
        if !outcome.relative_residual.is_finite() {
            return Ok(outcome);
        }
        if outcome.relative_residual <= tolerance {
            outcome.converged = true;
            return Ok(outcome);
        }
        z.copy_from_slice(r);
        pre.solve_in_place(z)?;
        let rz_next = dot(r, z);
        let beta = rz_next / rz;
        rz = rz_next;
        for (pi, zi) in p.iter_mut().zip(z.iter()) {
            *pi = zi + beta * *pi;
        }
    }
    Ok(outcome)
}

/// Geometric nested-dissection elimination order for the matrix graph of `pattern`, with a
/// position per row (`coords[i]`, e.g. the node of a dof) [mm].
///
/// Recursively: split the rows at the median coordinate along the longest extent, take as
/// separator the rows of one half adjacent to the other, order both halves first and the
/// separator last, down to blocks of fewer than 6 rows (two nodes), which keep their natural order. On 3-D meshes this gives
/// less fill than minimum degree (the separators are planes).
pub fn nested_dissection_order(pattern: &SymmetricPattern, coords: &[[f64; 3]]) -> Vec<usize> {
    let n = pattern.dim();
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
    for c in 0..n {
        for &r in &pattern.row_idx[pattern.col_ptr[c]..pattern.col_ptr[c + 1]] {
            if r != c {
                adj[r].push(c);
                adj[c].push(r);
            }
        }
    }
    let mut order = Vec::with_capacity(n);
    let mut side = vec![0u8; n];
    let mut stack: Vec<(Vec<usize>, bool)> = vec![((0..n).collect(), false)];
    // Iterative post-order: (set, expanded?) — an expanded set pushes [separator, right, left].
    while let Some((set, leaf)) = stack.pop() {
        if leaf || set.len() < 6 {
            order.extend_from_slice(&set);
            continue;
        }
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for &i in &set {
            for k in 0..3 {
                lo[k] = lo[k].min(coords[i][k]);
                hi[k] = hi[k].max(coords[i][k]);
            }
        }
        let axis = (0..3)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap_or(0);
        let mut vals: Vec<f64> = set.iter().map(|&i| coords[i][axis]).collect();
        vals.sort_unstable_by(f64::total_cmp);
        let median = vals[vals.len() / 2];
        for &i in &set {
            side[i] = if coords[i][axis] < median { 1 } else { 2 };
        }
        let mut left = Vec::new();
        let mut right = Vec::new();
        let mut sep = Vec::new();
        for &i in &set {
            if side[i] == 1 {
                left.push(i);
            } else if adj[i].iter().any(|&j| side[j] == 1) {
                sep.push(i);
            } else {
                right.push(i);
            }
        }
        for &i in &set {
            side[i] = 0;
        }
        if left.is_empty() || right.is_empty() {
            order.extend_from_slice(&set);
            continue;
        }
        stack.push((sep, true));
        stack.push((right, false));
        stack.push((left, false));
    }
    order
}
