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

mod sparse_rhs;
mod trailing;
pub use trailing::TrailingBlock;

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
    /// A deferred solve that cannot be made or finished ([`Cholesky::complete_far`]).
    #[error("deferred solve: {0}")]
    Deferred(&'static str),
}

/// The precision a [`Cholesky`] factor is stored and solved in.
///
/// `Single` stores `L` in `f32`: half the memory and memory traffic of the factorisation and
/// of every triangular solve. The matrix and right-hand sides are rounded to `f32` on the way
/// in and the solution widened back, so a solve has the factor's relative error (about
/// `κ(A) · 6e-8`) instead of `κ(A) · 1e-16`: fine for a preconditioner or for a Newton step
/// whose matrix is already approximate, checked after every factorisation (see
/// [`SINGLE_PROBE_TOLERANCE`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// `f64` factor (the default).
    #[default]
    Double,
    /// `f32` factor, checked after each factorisation; falls back to `Double` for good when a
    /// check fails.
    Single,
}

/// Single-precision factor: after each factorisation a probe solve `A x = b` with a fixed
/// pseudo-random `x` and `b = A x` formed in `f64` measures the factor's relative error
/// `‖x̂ − x‖ / ‖x‖`. Above this (or a non-finite value) the factor is redone in `f64` and the
/// factor stays double from then on. At 1e-3 the error of a step solved with the factor is
/// far below the error a lagged factor already makes (`2θ` per element rotation `θ`).
pub const SINGLE_PROBE_TOLERANCE: f64 = 1e-3;

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

/// The source of [`Cholesky::stamp`]: every numeric factorisation in the process takes the
/// next value.
static FACTOR_STAMPS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Sparse Cholesky `A = L Lᵀ` with the symbolic part computed once and the numeric part
/// refreshed by [`Cholesky::factorize`]; all memory is allocated at construction (a
/// single-precision factor that falls back to double allocates its `f64` factor then, once).
pub struct Cholesky {
    symbolic: SymbolicCholesky<usize>,
    /// The `f64` factor (empty while the factor is single precision).
    l_values: Vec<f64>,
    /// The `f32` factor and its scratch while the factor is single precision.
    single: Option<SingleFactor>,
    factor_mem: MemBuffer,
    solve_mem: MemBuffer,
    solve_cols: usize,
    /// Scratch of the `f64` solves ([`sparse_rhs::solve_in_place`]).
    solve_scratch: sparse_rhs::Scratch<f64>,
    factorized: bool,
    /// Which numeric factorisation this is: a fresh value of [`FACTOR_STAMPS`] each time
    /// (0 before the first). Survives swaps of whole factors between buffers.
    stamp: u64,
    fallbacks: u64,
    probe_error: Option<f64>,
    /// The deferred solve ([`Cholesky::solve_deferring_far`]): the stamp of the factor it was
    /// made with (0: none), its permuted forward result (`f64` factor) and the permuted
    /// vector [`Cholesky::complete_far`] works on.
    pending_stamp: u64,
    pending: Vec<f64>,
    far_x: Vec<f64>,
}

/// A single-precision factor: `L` in `f32`, the matrix values rounded to `f32`, the solve's
/// `f32` right-hand sides, and the probe vectors.
struct SingleFactor {
    l: Vec<f32>,
    a: Vec<f32>,
    rhs: Vec<f32>,
    solve_scratch: sparse_rhs::Scratch<f32>,
    probe_x: Vec<f64>,
    probe_b: Vec<f64>,
    /// The deferred solve's forward result and [`Cholesky::complete_far`]'s vector, in `f32`.
    pending: Vec<f32>,
    far_x: Vec<f32>,
}

impl fmt::Debug for Cholesky {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Cholesky")
            .field("dim", &self.dim())
            .field("factor_nnz", &self.factor_nnz())
            .field("precision", &self.precision())
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
        Self::try_new_with_precision(pattern, order, max_rhs, Precision::Double)
    }

    /// As [`Cholesky::try_new_ordered`], with the factor stored in `precision` (see
    /// [`Precision`]).
    ///
    /// # Errors
    /// As [`Cholesky::try_new_ordered`].
    pub fn try_new_with_precision(
        pattern: &SymmetricPattern,
        order: Option<&[usize]>,
        max_rhs: usize,
        precision: Precision,
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
        let (l_values, single) = match precision {
            Precision::Double => (vec![0.0; symbolic.len_val()], None),
            Precision::Single => (
                Vec::new(),
                Some(SingleFactor {
                    l: vec![0.0; symbolic.len_val()],
                    a: vec![0.0; pattern.nnz()],
                    rhs: vec![0.0; n * max_rhs.max(1)],
                    solve_scratch: sparse_rhs::Scratch::new(),
                    probe_x: probe_vector(n),
                    probe_b: vec![0.0; n],
                    pending: Vec::new(),
                    far_x: Vec::new(),
                }),
            ),
        };
        let factor_req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Spec::default()),
            symbolic.factorize_numeric_llt_scratch::<f32>(Par::Seq, Spec::default()),
        ]);
        let factor_mem = MemBuffer::try_new(factor_req).map_err(|_| LinalgError::Symbolic)?;
        let solve_cols = max_rhs.max(1);
        let solve_mem = MemBuffer::try_new(Self::solve_req(&symbolic, solve_cols))
            .map_err(|_| LinalgError::Symbolic)?;
        Ok(Self {
            symbolic,
            l_values,
            single,
            factor_mem,
            solve_mem,
            solve_cols,
            solve_scratch: sparse_rhs::Scratch::new(),
            factorized: false,
            stamp: 0,
            fallbacks: 0,
            probe_error: None,
            pending_stamp: 0,
            pending: Vec::new(),
            far_x: Vec::new(),
        })
    }

    fn solve_req(symbolic: &SymbolicCholesky<usize>, cols: usize) -> StackReq {
        StackReq::any_of(&[
            symbolic.solve_in_place_scratch::<f64>(cols, Par::Seq),
            symbolic.solve_in_place_scratch::<f32>(cols, Par::Seq),
        ])
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.symbolic.nrows()
    }

    /// Number of stored values of the factor `L`.
    pub fn factor_nnz(&self) -> usize {
        self.symbolic.len_val()
    }

    /// Whether a valid numeric factorisation is available.
    pub fn is_factorized(&self) -> bool {
        self.factorized
    }

    /// The identity of the numeric factorisation held (0: none yet): two equal stamps are
    /// the same factor of the same matrix, whichever buffer holds it now.
    pub fn stamp(&self) -> u64 {
        self.stamp
    }

    /// The precision the factor is stored in now (`Double` after a fallback).
    pub fn precision(&self) -> Precision {
        if self.single.is_some() {
            Precision::Single
        } else {
            Precision::Double
        }
    }

    /// How many single-precision factorisations failed their check and were redone in double
    /// (0 or 1: the factor stays double after a fallback).
    pub fn precision_fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// The relative error of the last single-precision factor's probe solve: `None` before the
    /// first and for a factor made double from the start; after a fallback, the error of the
    /// probe that failed.
    pub fn single_probe_error(&self) -> Option<f64> {
        self.probe_error
    }

    /// Numeric factorisation of `a`, which must have the pattern given to [`Cholesky::try_new`].
    /// A single-precision factor is checked by a probe solve and redone in double (for good)
    /// when the check fails (see [`SINGLE_PROBE_TOLERANCE`]).
    ///
    /// # Errors
    /// [`LinalgError::NotPositiveDefinite`] if a pivot is not positive (the previous factor is
    /// then invalid), [`LinalgError::DimensionMismatch`] for a matrix of another size.
    pub fn factorize(&mut self, a: &SymmetricMatrix) -> Result<(), LinalgError> {
        self.factorized = false;
        self.stamp = FACTOR_STAMPS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if a.pattern.n != self.dim() {
            return Err(LinalgError::DimensionMismatch {
                expected: self.dim(),
                got: a.pattern.n,
            });
        }
        if self.single.is_some() {
            if self.factorize_single(a) {
                self.factorized = true;
                return Ok(());
            }
            // The check failed: double from now on.
            self.single = None;
            self.fallbacks += 1;
            self.l_values = vec![0.0; self.symbolic.len_val()];
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

    /// The single-precision factorisation of `a` and its probe; `false` when the matrix does
    /// not round to finite `f32` values, a pivot is not positive in `f32`, or the probe's
    /// error is above [`SINGLE_PROBE_TOLERANCE`] (or not finite).
    fn factorize_single(&mut self, a: &SymmetricMatrix) -> bool {
        let Some(sf) = self.single.as_mut() else {
            return false;
        };
        for (d, &v) in sf.a.iter_mut().zip(&a.values) {
            *d = v as f32;
        }
        if !sf.a.iter().all(|v| v.is_finite()) {
            return false;
        }
        let mat = SparseColMatRef::new(a.pattern.symbolic(), &sf.a);
        let res = self.symbolic.factorize_numeric_llt::<f32>(
            &mut sf.l,
            mat,
            Side::Upper,
            LltRegularization::default(),
            Par::Seq,
            MemStack::new(&mut self.factor_mem),
            Spec::default(),
        );
        if res.is_err() {
            return false;
        }
        // The probe: b = A x in f64, x̂ = (L Lᵀ)⁻¹ b with the f32 factor, as any solve.
        let mut b = std::mem::take(&mut sf.probe_b);
        if a.mul_vec(&sf.probe_x, &mut b).is_err() {
            sf.probe_b = b;
            return false;
        }
        sf.solve_in_place(&self.symbolic, &mut b, 1, &mut self.solve_mem);
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for (&xh, &x) in b.iter().zip(&sf.probe_x) {
            err += (xh - x).powi(2);
            norm += x * x;
        }
        sf.probe_b = b;
        let rel = (err / norm).sqrt();
        self.probe_error = Some(rel);
        rel.is_finite() && rel <= SINGLE_PROBE_TOLERANCE
    }

    /// The permuted position of each column (`None`: no permutation), fixed at construction.
    pub fn inverse_permutation(&self) -> Option<&[usize]> {
        self.symbolic.perm().map(|p| p.arrays().1)
    }

    /// Where a solve can stop before the rows eliminated before permuted column `first` (a
    /// trailing block's, [`TrailingBlock::first`]): the first supernode reaching `first` and
    /// its first column, from which on [`Cholesky::solve_deferring_far`] and
    /// [`Cholesky::solve_near_many`] solve exactly. `None` for a simplicial factor.
    pub fn deferral_split(&self, first: usize) -> Option<(usize, usize)> {
        sparse_rhs::split_at(&self.symbolic, first)
    }

    /// Whether reduced row `i` lies from permuted column `split.1` on (where the deferred
    /// solves are exact).
    pub fn is_after_split(&self, i: usize, split: (usize, usize)) -> bool {
        self.inverse_permutation().map_or(i, |p| p[i]) >= split.1
    }

    /// Solves `A x = b` for one right-hand side on the rows from `split.1` on only
    /// ([`Cholesky::deferral_split`]): `rhs` returns `x` there and zero on the other rows,
    /// whose solve [`Cholesky::complete_far`] finishes later from the forward substitution
    /// kept here, for the whole solution or for the solution with other values on the rows
    /// from `split.1` on (the same factor's solution plus a response to loads on those rows).
    /// The rows it returns are, bit for bit, those of [`Cholesky::solve_in_place`].
    ///
    /// # Errors
    /// [`LinalgError::NotFactorized`], [`LinalgError::DimensionMismatch`],
    /// [`LinalgError::Deferred`] for a simplicial factor.
    pub fn solve_deferring_far(
        &mut self,
        rhs: &mut [f64],
        split: (usize, usize),
    ) -> Result<(), LinalgError> {
        self.check_solve(rhs, 1)?;
        self.pending_stamp = 0;
        let done = match self.single.as_mut() {
            None => sparse_rhs::solve_near_in_place(
                &self.symbolic,
                &self.l_values,
                rhs,
                1,
                split,
                Some(&mut self.pending),
                &mut self.solve_scratch,
            ),
            Some(sf) => sf.solve_near(&self.symbolic, rhs, 1, split, true),
        };
        done.ok_or(LinalgError::Deferred("a simplicial factor"))?;
        self.pending_stamp = self.stamp;
        Ok(())
    }

    /// Solves `A X = B` for `ncols` column-major right-hand sides on the rows from `split.1`
    /// on only: zero on the other rows, nothing kept. With loads on those rows only (the
    /// compliance columns of points there), these are the columns' exact rows, bit for bit
    /// those of [`Cholesky::solve_many_in_place`], at the cost of the factor's trailing part.
    ///
    /// # Errors
    /// As [`Cholesky::solve_deferring_far`].
    pub fn solve_near_many(
        &mut self,
        rhs: &mut [f64],
        ncols: usize,
        split: (usize, usize),
    ) -> Result<(), LinalgError> {
        self.check_solve(rhs, ncols)?;
        if ncols == 0 {
            return Ok(());
        }
        let done = match self.single.as_mut() {
            None => sparse_rhs::solve_near_in_place(
                &self.symbolic,
                &self.l_values,
                rhs,
                ncols,
                split,
                None,
                &mut self.solve_scratch,
            ),
            Some(sf) => sf.solve_near(&self.symbolic, rhs, ncols, split, false),
        };
        done.ok_or(LinalgError::Deferred("a simplicial factor"))?;
        Ok(())
    }

    /// Finishes the last [`Cholesky::solve_deferring_far`] (same `split`): given `x` on the
    /// rows from `split.1` on (that solve's values, or others: its solution plus a response
    /// to loads on those rows only, whose forward substitution is zero on the other rows),
    /// writes the rows before `split.1` so that `x` solves `A x = b + r` for that response's
    /// load `r`. The rows from `split.1` on are left as they are.
    ///
    /// # Errors
    /// [`LinalgError::DimensionMismatch`]; [`LinalgError::Deferred`] when the factor changed
    /// since, or no deferred solve was made with it.
    pub fn complete_far(
        &mut self,
        x: &mut [f64],
        split: (usize, usize),
    ) -> Result<(), LinalgError> {
        let n = self.dim();
        if x.len() != n {
            return Err(LinalgError::DimensionMismatch {
                expected: n,
                got: x.len(),
            });
        }
        if self.pending_stamp == 0 || self.pending_stamp != self.stamp {
            return Err(LinalgError::Deferred(
                "no deferred solve with the factor in use",
            ));
        }
        let done = match self.single.as_mut() {
            None => complete_far_widened(
                &self.symbolic,
                &self.l_values,
                &self.pending,
                &mut self.far_x,
                x,
                split,
                &mut self.solve_scratch,
            ),
            Some(sf) => complete_far_widened(
                &self.symbolic,
                &sf.l,
                &sf.pending,
                &mut sf.far_x,
                x,
                split,
                &mut sf.solve_scratch,
            ),
        };
        done.ok_or(LinalgError::Deferred("a simplicial factor"))
    }

    /// The checks of a solve of `ncols` right-hand sides in `rhs`.
    fn check_solve(&self, rhs: &[f64], ncols: usize) -> Result<(), LinalgError> {
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
        Ok(())
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
        self.check_solve(rhs, ncols)?;
        let n = self.dim();
        if ncols == 0 {
            return Ok(());
        }
        if ncols > self.solve_cols {
            self.solve_mem = MemBuffer::try_new(Self::solve_req(&self.symbolic, ncols))
                .map_err(|_| LinalgError::Symbolic)?;
            self.solve_cols = ncols;
        }
        match self.single.as_mut() {
            None => {
                let stack = MemStack::new(&mut self.solve_mem);
                let (sym, l) = (&self.symbolic, &self.l_values);
                let scratch = &mut self.solve_scratch;
                if sparse_rhs::solve_in_place(sym, l, rhs, ncols, scratch, stack).is_none() {
                    let llt = LltRef::<'_, usize, f64>::new(sym, l);
                    let mat = MatMut::from_column_major_slice_mut(rhs, n, ncols);
                    llt.solve_in_place_with_conj(Conj::No, mat, Par::Seq, stack);
                }
            }
            Some(sf) => sf.solve_in_place(&self.symbolic, rhs, ncols, &mut self.solve_mem),
        }
        Ok(())
    }
}

/// [`Cholesky::complete_far`] with a factor in `T`: the permuted vector from the kept forward
/// result `pending` (rows before `split.1`) and `x` (rounded to `T`, the other rows), the far
/// backward substitution, and its rows widened back into `x`.
fn complete_far_widened<T: sparse_rhs::Real>(
    symbolic: &SymbolicCholesky<usize>,
    l: &[T],
    pending: &[T],
    far_x: &mut Vec<T>,
    x: &mut [f64],
    split: (usize, usize),
    scratch: &mut sparse_rhs::Scratch<T>,
) -> Option<()> {
    let n = symbolic.nrows();
    let fwd = symbolic.perm().map(|p| p.arrays().0);
    let at = |k: usize| fwd.map_or(k, |f| f[k]);
    far_x.clear();
    far_x.extend((0..n).map(|k| {
        if k < split.1 {
            pending[k]
        } else {
            T::from_f64(x[at(k)])
        }
    }));
    sparse_rhs::complete_far(symbolic, l, far_x, split, scratch)?;
    for k in 0..split.1 {
        x[at(k)] = far_x[k].to_f64();
    }
    Some(())
}

impl SingleFactor {
    /// [`sparse_rhs::solve_near_in_place`] of `ncols` `f64` right-hand sides with the `f32`
    /// factor (rounded, solved, widened), keeping the forward result when `keep`.
    fn solve_near(
        &mut self,
        symbolic: &SymbolicCholesky<usize>,
        rhs: &mut [f64],
        ncols: usize,
        split: (usize, usize),
        keep: bool,
    ) -> Option<usize> {
        let n = symbolic.nrows();
        if self.rhs.len() < n * ncols {
            self.rhs.resize(n * ncols, 0.0);
        }
        let buf = &mut self.rhs[..n * ncols];
        for (d, &v) in buf.iter_mut().zip(rhs.iter()) {
            *d = v as f32;
        }
        let keep = keep.then_some(&mut self.pending);
        let done = sparse_rhs::solve_near_in_place(
            symbolic,
            &self.l,
            buf,
            ncols,
            split,
            keep,
            &mut self.solve_scratch,
        )?;
        for (d, &v) in rhs.iter_mut().zip(buf.iter()) {
            *d = f64::from(v);
        }
        Some(done)
    }

    /// Solves `ncols` column-major `f64` right-hand sides in place with the `f32` factor:
    /// rounded to `f32`, solved, widened back. `mem` must hold the solve scratch for `ncols`.
    fn solve_in_place(
        &mut self,
        symbolic: &SymbolicCholesky<usize>,
        rhs: &mut [f64],
        ncols: usize,
        mem: &mut MemBuffer,
    ) {
        let n = symbolic.nrows();
        if self.rhs.len() < n * ncols {
            self.rhs.resize(n * ncols, 0.0);
        }
        let buf = &mut self.rhs[..n * ncols];
        for (d, &v) in buf.iter_mut().zip(rhs.iter()) {
            *d = v as f32;
        }
        let stack = MemStack::new(mem);
        let scratch = &mut self.solve_scratch;
        if sparse_rhs::solve_in_place(symbolic, &self.l, buf, ncols, scratch, stack).is_none() {
            let llt = LltRef::<'_, usize, f32>::new(symbolic, &self.l);
            let mat = MatMut::from_column_major_slice_mut(buf, n, ncols);
            llt.solve_in_place_with_conj(Conj::No, mat, Par::Seq, stack);
        }
        for (d, &v) in rhs.iter_mut().zip(buf.iter()) {
            *d = f64::from(v);
        }
    }
}

/// The probe's fixed pseudo-random vector, entries in [−1, 1) (a linear congruential sequence:
/// the same on every run and machine).
fn probe_vector(n: usize) -> Vec<f64> {
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    (0..n)
        .map(|_| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        })
        .collect()
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
    let adj = adjacency(pattern);
    dissect(&adj, coords, (0..pattern.dim()).collect())
}

/// [`nested_dissection_order`] with the rows marked in `last` eliminated last: the other rows
/// in their nested-dissection order, then the marked rows in theirs. A factor so ordered keeps
/// its columns before the marked rows when only the marked rows' block of the matrix changes
/// ([`TrailingBlock`], first column: the number of unmarked rows).
pub fn nested_dissection_order_with_last(
    pattern: &SymmetricPattern,
    coords: &[[f64; 3]],
    last: &[bool],
) -> Vec<usize> {
    nested_dissection_order_with_last_two(pattern, coords, last, &[])
}

/// [`nested_dissection_order_with_last`] with a second set `inner` (a subset of `last`)
/// eliminated after the rest of `last`: the unmarked rows, then the rows of `last` not in
/// `inner`, then `inner`, each in its nested-dissection order. Both the block of `last` and the
/// block of `inner` are then trailing blocks of the factor ([`TrailingBlock`]); rows of `inner`
/// not in `last` count as in `last`.
pub fn nested_dissection_order_with_last_two(
    pattern: &SymmetricPattern,
    coords: &[[f64; 3]],
    last: &[bool],
    inner: &[bool],
) -> Vec<usize> {
    let adj = adjacency(pattern);
    let n = pattern.dim();
    let flag = |set: &[bool], i: usize| set.get(i).copied().unwrap_or(false);
    let group = |i: &usize| {
        if flag(inner, *i) {
            2
        } else if flag(last, *i) {
            1
        } else {
            0
        }
    };
    let mut order = Vec::with_capacity(n);
    for g in 0..3 {
        order.extend(dissect(
            &adj,
            coords,
            (0..n).filter(|i| group(i) == g).collect(),
        ));
    }
    order
}

/// Each row's neighbours in the matrix graph of `pattern` (the diagonal left out).
fn adjacency(pattern: &SymmetricPattern) -> Vec<Vec<usize>> {
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
    adj
}

/// The nested-dissection order of the rows `set` (see [`nested_dissection_order`]); a row's
/// neighbours outside `set` never enter its separators.
fn dissect(adj: &[Vec<usize>], coords: &[[f64; 3]], set: Vec<usize>) -> Vec<usize> {
    let n = adj.len();
    let mut order = Vec::with_capacity(n);
    let mut side = vec![0u8; n];
    let mut stack: Vec<(Vec<usize>, bool)> = vec![(set, false)];
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
