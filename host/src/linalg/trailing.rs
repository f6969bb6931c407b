//! Refactorisation of a factor's trailing block: when `A` changes only in the rows and columns
//! eliminated last, only those columns of `L` change.
//!
//! Order a matrix so that the rows that change (e.g. the gel's dofs near the needle) come last,
//! from permuted column `first` on. With `A = [A_ff A_ft; A_tf A_tt]` and its factor
//! `L = [L_ff 0; L_tf L_tt]`, the columns `L_ff`, `L_tf` depend on `A_ff` and `A_tf` alone, and
//! `L_tt L_ttᵀ = A_tt − C` with `C = L_tf L_tfᵀ`, the far rows' contribution. After a full
//! factorisation of `A₀`, [`TrailingBlock::capture`] keeps `C = A₀_tt − L_tt L_ttᵀ`; a matrix
//! `A` equal to `A₀` outside the block is then factorised by [`TrailingBlock::refactor`]: one
//! sparse Cholesky of `A_tt − C` (the block's size, not the matrix's), written over `L_tt`.
//! The result is the factor of `A` to the rounding of the full factorisation (for a
//! single-precision factor, `C` carries the factor's own `f32` error, as a full factorisation
//! does).
//!
//! faer factorises the block with its own symbolic analysis over the block's filled pattern
//! (identity ordering: the pattern of `L_tt` has no further fill), and the values are copied
//! into the main factor's storage entry by entry.

use super::{Cholesky, LinalgError, SymmetricMatrix, SymmetricPattern};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::linalg::matmul::triangular::{self, BlockStructure};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Accum, Mat, Par, Side, Spec};

/// The trailing block of a [`Cholesky`] factor from permuted column `first` on: its pattern,
/// the far rows' contribution `C` and the block's own factorisation (see the module docs).
pub struct TrailingBlock {
    /// First permuted column of the block.
    first: usize,
    /// Dimension and number of stored entries of `A`.
    dim: usize,
    a_nnz: usize,
    /// Every stored entry of `A` inside the block: (slot in `A`'s values, slot in the block's).
    a_map: Vec<(usize, usize)>,
    /// The block's upper-triangular pattern (block indices), compressed columns.
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    symbolic: SymbolicCholesky<usize>,
    /// `C = A₀_tt − L_tt L_ttᵀ` on the block's pattern.
    c: Vec<f64>,
    /// The slot in `c` of every lower-triangular entry of each panel's `Y Yᵀ` in
    /// [`TrailingBlock::capture`] (panels in order, column by column), found at the first
    /// capture: the pattern is the block's for good.
    capture_slots: Vec<u32>,
    /// The stamp of the full factorisation `C` was captured from (0: none).
    captured: u64,
    /// Each entry of `L_tt`: (index in the main factor's values, index in the block factor's).
    l_map: Vec<(usize, usize)>,
    /// The block's matrix `A_tt − C` and its factor, in `f64` and (for a single-precision
    /// main factor) in `f32`.
    a: Vec<f64>,
    l: Vec<f64>,
    a32: Vec<f32>,
    l32: Vec<f32>,
    mem: MemBuffer,
}

impl std::fmt::Debug for TrailingBlock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrailingBlock")
            .field("first", &self.first)
            .field("size", &self.size())
            .field("factor_nnz", &self.l.len().max(self.l32.len()))
            .field("captured", &self.captured)
            .finish_non_exhaustive()
    }
}

/// One stored entry of `L`: row, column (permuted) and its index in the values.
#[derive(Clone, Copy)]
struct Entry {
    row: usize,
    col: usize,
    idx: usize,
}

/// A supernode of a factor that reaches the columns `first..`: its columns `begin..end`, the
/// rows below them, and where its dense column-major block of `(end − begin) + rows.len()`
/// rows starts in the values.
struct Panel<'a> {
    begin: usize,
    end: usize,
    rows: &'a [usize],
    base: usize,
}

impl Panel<'_> {
    /// Rows of the panel's dense block.
    fn nrows(&self) -> usize {
        (self.end - self.begin) + self.rows.len()
    }
}

/// The supernodes of a supernodal factor that reach the columns `first..` (`None`: a
/// simplicial factor).
fn panels(symbolic: &SymbolicCholesky<usize>, first: usize) -> Option<Vec<Panel<'_>>> {
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        return None;
    };
    let panels = (0..sn.n_supernodes())
        .filter(|&s| sn.supernode_end()[s] > first)
        .map(|s| Panel {
            begin: sn.supernode_begin()[s],
            end: sn.supernode_end()[s],
            rows: sn.supernode(s).pattern(),
            base: sn.col_ptr_for_val()[s],
        });
    Some(panels.collect())
}

/// The entries of a supernodal factor's columns `first..` (lower triangle: row ≥ column).
fn entries_from(symbolic: &SymbolicCholesky<usize>, first: usize) -> Option<Vec<Entry>> {
    let mut out = Vec::new();
    for p in panels(symbolic, first)? {
        let (b, e, nrows) = (p.begin, p.end, p.nrows());
        for col in b.max(first)..e {
            let j = col - b;
            for row in col..e {
                let idx = p.base + j * nrows + (row - b);
                out.push(Entry { row, col, idx });
            }
            for (k, &row) in p.rows.iter().enumerate() {
                let idx = p.base + j * nrows + (e - b) + k;
                out.push(Entry { row, col, idx });
            }
        }
    }
    Some(out)
}

/// Upper-triangular compressed columns of the `n × n` pattern with the lower entries
/// `(row ≥ col)` given, sorted and deduplicated.
fn upper_pattern(
    n: usize,
    lower: impl Iterator<Item = (usize, usize)>,
) -> (Vec<usize>, Vec<usize>) {
    let mut cols: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (r, c) in lower {
        cols[r].push(c);
    }
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0);
    for c in &mut cols {
        c.sort_unstable();
        c.dedup();
        row_idx.extend_from_slice(c);
        col_ptr.push(row_idx.len());
    }
    (col_ptr, row_idx)
}

impl TrailingBlock {
    /// The block of `chol`'s permuted columns `first..`; `pattern` is the one `chol` was built
    /// for. The factor must be supernodal (faer chooses it for all but small or very sparse
    /// matrices).
    ///
    /// # Errors
    /// [`LinalgError::Symbolic`] for a simplicial factor, `first` beyond the dimension, a
    /// pattern of another size, or a failed analysis of the block.
    pub fn new(
        chol: &Cholesky,
        pattern: &SymmetricPattern,
        first: usize,
    ) -> Result<Self, LinalgError> {
        let n = chol.dim();
        if first >= n || pattern.n != n {
            return Err(LinalgError::Symbolic);
        }
        let size = n - first;
        let main = entries_from(&chol.symbolic, first).ok_or(LinalgError::Symbolic)?;
        let (col_ptr, row_idx) =
            upper_pattern(size, main.iter().map(|e| (e.row - first, e.col - first)));
        let block =
            SymbolicSparseColMat::new_checked(size, size, col_ptr.clone(), None, row_idx.clone());
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..CholeskySymbolicParams::default()
        };
        let symbolic = factorize_symbolic_cholesky(
            block.as_ref(),
            Side::Upper,
            SymmetricOrdering::Identity,
            params,
        )
        .map_err(|_| LinalgError::Symbolic)?;
        // Where each entry of L_tt sits in the block's own factor.
        let sub = entries_from(&symbolic, 0).ok_or(LinalgError::Symbolic)?;
        let mut at = std::collections::HashMap::with_capacity(sub.len());
        for e in &sub {
            at.insert((e.row, e.col), e.idx);
        }
        let l_map = main
            .iter()
            .map(|e| {
                at.get(&(e.row - first, e.col - first))
                    .map(|&i| (e.idx, i))
                    .ok_or(LinalgError::Symbolic)
            })
            .collect::<Result<Vec<_>, _>>()?;
        // Every entry of A inside the block, by the main factor's permutation.
        let a_pattern = pattern;
        let inv: Vec<usize> = match chol.symbolic.perm() {
            Some(p) => p.arrays().1.to_vec(),
            None => (0..n).collect(),
        };
        let mut a_map = Vec::new();
        for j in 0..n {
            for p in a_pattern.col_ptr[j]..a_pattern.col_ptr[j + 1] {
                let i = a_pattern.row_idx[p];
                let (pi, pj) = (inv[i], inv[j]);
                if pi >= first && pj >= first {
                    let (r, c) = (pi.max(pj) - first, pi.min(pj) - first);
                    let slot = col_ptr[r]
                        + row_idx[col_ptr[r]..col_ptr[r + 1]]
                            .binary_search(&c)
                            .map_err(|_| LinalgError::Symbolic)?;
                    a_map.push((p, slot));
                }
            }
        }
        let mem = MemBuffer::try_new(StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Spec::default()),
            symbolic.factorize_numeric_llt_scratch::<f32>(Par::Seq, Spec::default()),
        ]))
        .map_err(|_| LinalgError::Symbolic)?;
        let single = chol.single.is_some();
        let len = symbolic.len_val();
        let nnz = row_idx.len();
        Ok(Self {
            first,
            dim: n,
            a_nnz: pattern.nnz(),
            a_map,
            l: if single { Vec::new() } else { vec![0.0; len] },
            l32: if single { vec![0.0; len] } else { Vec::new() },
            a32: if single { vec![0.0; nnz] } else { Vec::new() },
            col_ptr,
            row_idx,
            symbolic,
            c: vec![0.0; nnz],
            capture_slots: Vec::new(),
            captured: 0,
            l_map,
            a: vec![0.0; nnz],
            mem,
        })
    }

    /// First permuted column of the block.
    pub fn first(&self) -> usize {
        self.first
    }

    /// Number of columns of the block.
    pub fn size(&self) -> usize {
        self.col_ptr.len() - 1
    }

    /// The stamp of the factorisation the block's `C` was captured from (0: none).
    pub fn captured(&self) -> u64 {
        self.captured
    }

    /// `chol` was refactorised from the factor of stamp `from` in columns at or after this
    /// block's first alone (a later-starting [`TrailingBlock`]'s refresh): its columns before
    /// the block are the captured ones, so the capture holds for `chol` too. Nothing when the
    /// capture was not of `from`.
    pub fn carry_capture(&mut self, from: u64, chol: &Cholesky) {
        if self.captured != 0 && self.captured == from && chol.factorized {
            self.captured = chol.stamp;
        }
    }

    /// `chol` and `a` of the size and pattern the block was made for.
    fn check(&self, chol: &Cholesky, a: &SymmetricMatrix) -> Result<(), LinalgError> {
        for (expected, got) in [
            (self.dim, chol.dim()),
            (self.dim, a.pattern.n),
            (self.a_nnz, a.values.len()),
        ] {
            if expected != got {
                return Err(LinalgError::DimensionMismatch { expected, got });
            }
        }
        Ok(())
    }

    /// Slot of block entry `(r, c)` in the block's pattern values.
    fn slot(&self, r: usize, c: usize) -> Option<usize> {
        let (r, c) = (r.max(c), r.min(c));
        let range = self.col_ptr[r]..self.col_ptr[r + 1];
        self.row_idx[range.clone()]
            .binary_search(&c)
            .ok()
            .map(|k| range.start + k)
    }

    /// The slots in `c` of each panel's lower-triangular `Y Yᵀ` entries, in the order
    /// [`TrailingBlock::capture`] visits them.
    fn find_capture_slots(&self, panels: &[Panel<'_>]) -> Result<Vec<u32>, LinalgError> {
        let first = self.first;
        let mut slots = Vec::new();
        let mut rows = Vec::new();
        for p in panels {
            let (b, e) = (p.begin, p.end);
            let j0 = first.max(b) - b;
            rows.clear();
            rows.extend((b + j0)..e);
            rows.extend_from_slice(p.rows);
            for j in 0..rows.len() {
                for i in j..rows.len() {
                    let slot = self
                        .slot(rows[i] - first, rows[j] - first)
                        .ok_or(LinalgError::Symbolic)?;
                    slots.push(u32::try_from(slot).map_err(|_| LinalgError::Symbolic)?);
                }
            }
        }
        Ok(slots)
    }

    /// Keeps `C = A₀_tt − L_tt L_ttᵀ` from `chol`, freshly factorised from `a0`, for later
    /// [`TrailingBlock::refactor`]s.
    ///
    /// # Errors
    /// [`LinalgError::NotFactorized`]; [`LinalgError::DimensionMismatch`] for another size.
    pub fn capture(&mut self, chol: &Cholesky, a0: &SymmetricMatrix) -> Result<(), LinalgError> {
        if !chol.factorized {
            return Err(LinalgError::NotFactorized);
        }
        self.check(chol, a0)?;
        self.c.fill(0.0);
        for &(p, s) in &self.a_map {
            self.c[s] += a0.values[p];
        }
        // − L_tt L_ttᵀ, supernode by supernode: Y Yᵀ of the block's rows of its columns.
        let first = self.first;
        let panels = panels(&chol.symbolic, first).ok_or(LinalgError::Symbolic)?;
        if self.capture_slots.is_empty() {
            self.capture_slots = self.find_capture_slots(&panels)?;
        }
        let mut next = 0;
        for p in &panels {
            let (b, e, nrows, base) = (p.begin, p.end, p.nrows(), p.base);
            let j0 = first.max(b) - b;
            let (ny, nc) = (nrows - j0, (e - b) - j0);
            let value = |i: usize, j: usize| -> f64 {
                let idx = base + (j0 + j) * nrows + (j0 + i);
                match chol.single.as_ref() {
                    Some(sf) => f64::from(sf.l[idx]),
                    None => chol.l_values[idx],
                }
            };
            let y = Mat::<f64>::from_fn(ny, nc, |i, j| if i >= j { value(i, j) } else { 0.0 });
            let mut yyt = Mat::<f64>::zeros(ny, ny);
            // The lower triangle alone: C is symmetric and stored so.
            triangular::matmul(
                yyt.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Replace,
                y.as_ref(),
                BlockStructure::Rectangular,
                y.as_ref().transpose(),
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
            for j in 0..ny {
                let column = &yyt.col_as_slice(j)[j..];
                let slots = &self.capture_slots[next..next + column.len()];
                next += column.len();
                for (&slot, v) in slots.iter().zip(column) {
                    self.c[slot as usize] -= v;
                }
            }
        }
        self.captured = chol.stamp;
        Ok(())
    }

    /// Refactorises `chol` for `a`, which must equal the matrix of the factorisation captured
    /// last ([`TrailingBlock::capture`]) outside the block's rows and columns: only the block's
    /// columns of `L` are computed and written. The factor gets a new stamp, and the capture
    /// holds for it (its far columns are the captured factor's): refactorise again as often as
    /// the block changes.
    ///
    /// # Errors
    /// [`LinalgError::NotFactorized`] when `chol` is not the factor captured last or one
    /// refactorised from it;
    /// [`LinalgError::NotPositiveDefinite`] (the factor is then invalid);
    /// [`LinalgError::DimensionMismatch`] for another size.
    pub fn refactor(
        &mut self,
        chol: &mut Cholesky,
        a: &SymmetricMatrix,
    ) -> Result<(), LinalgError> {
        if self.captured == 0 || self.captured != chol.stamp || !chol.factorized {
            return Err(LinalgError::NotFactorized);
        }
        self.check(chol, a)?;
        for (d, c) in self.a.iter_mut().zip(&self.c) {
            *d = -c;
        }
        for &(p, s) in &self.a_map {
            self.a[s] += a.values[p];
        }
        let size = self.size();
        let pattern = block_pattern(size, &self.col_ptr, &self.row_idx);
        chol.factorized = false;
        chol.stamp = super::FACTOR_STAMPS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let first = self.first;
        let pivot = |e: faer::linalg::cholesky::llt::factor::LltError| match e {
            faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
                LinalgError::NotPositiveDefinite {
                    pivot: first + index,
                }
            }
        };
        // The block in the main factor's precision: a single-precision factor's block is
        // factorised in `f32` too (the block is the bulk of the work).
        match chol.single.as_mut() {
            Some(sf) => {
                // Sized at construction for the factor's precision then (a no-op but after a
                // change of precision).
                self.a32.resize(self.a.len(), 0.0);
                self.l32.resize(self.symbolic.len_val(), 0.0);
                for (d, &v) in self.a32.iter_mut().zip(&self.a) {
                    *d = v as f32;
                }
                if !self.a32.iter().all(|v| v.is_finite()) {
                    return Err(LinalgError::NotPositiveDefinite { pivot: first });
                }
                let mat = SparseColMatRef::new(pattern, self.a32.as_slice());
                factor_block(&self.symbolic, &mut self.l32, mat, &mut self.mem).map_err(pivot)?;
                for &(m, s) in &self.l_map {
                    sf.l[m] = self.l32[s];
                }
            }
            None => {
                self.l.resize(self.symbolic.len_val(), 0.0);
                let mat = SparseColMatRef::new(pattern, self.a.as_slice());
                factor_block(&self.symbolic, &mut self.l, mat, &mut self.mem).map_err(pivot)?;
                for &(m, s) in &self.l_map {
                    chol.l_values[m] = self.l[s];
                }
            }
        }
        chol.factorized = true;
        // The far part is the captured factor's: the contribution holds for the new one.
        self.captured = chol.stamp;
        Ok(())
    }
}

/// The block's pattern as faer's view (checked once in [`TrailingBlock::new`]).
fn block_pattern<'a>(
    n: usize,
    col_ptr: &'a [usize],
    row_idx: &'a [usize],
) -> faer::sparse::SymbolicSparseColMatRef<'a, usize> {
    faer::sparse::SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx)
}

/// The numeric factorisation of the block `a` into `l` (`f32` or `f64`).
fn factor_block<T: faer::traits::ComplexField>(
    symbolic: &SymbolicCholesky<usize>,
    l: &mut [T],
    a: SparseColMatRef<'_, usize, T>,
    mem: &mut MemBuffer,
) -> Result<(), faer::linalg::cholesky::llt::factor::LltError> {
    symbolic
        .factorize_numeric_llt::<T>(
            l,
            a,
            Side::Upper,
            LltRegularization::default(),
            Par::Seq,
            MemStack::new(mem),
            Spec::default(),
        )
        .map(|_| ())
}
