//! The factor's solve for right-hand sides that are zero on most rows, as the compliance
//! columns' `Pᵀ` are (a constrained point touches the dofs of a few nodes).
//!
//! faer's supernodal solve `L Lᵀ x = b` runs the forward substitution over every supernode,
//! in order: a supernode's rows of `x` are solved with its diagonal block, then its
//! sub-diagonal block's product with them is subtracted from the rows below. A supernode whose
//! rows of `x` are all zero when it is reached keeps them zero and subtracts zero: it can be
//! skipped with no change to any value. With a few nonzero rows, only the supernodes on their
//! paths to the elimination tree's root are reached, so the forward half of a compliance
//! solve costs a fraction of the factor instead of the whole of it. The backward substitution
//! is faer's own, whole (the columns are wanted on every dof, for the corrective motion).
//!
//! Every supernode that is not skipped runs the kernels faer's solve runs, with the same
//! arguments, so the solution is faer's to the last bit (a zero may keep another sign).

use faer::dyn_stack::MemStack;
use faer::linalg::matmul::matmul_with_conj;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place_with_conj, solve_upper_triangular_in_place_with_conj,
};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::linalg::cholesky::supernodal::SupernodalLltRef;
use faer::sparse::linalg::cholesky::{SymbolicCholesky, SymbolicCholeskyRaw};
use faer::{Accum, Conj, MatMut, MatRef, Par};

/// The factor's real number types.
pub(super) trait Real:
    faer::traits::ComplexField + Copy + PartialEq + core::ops::SubAssign
{
    const ZERO: Self;
    const ONE: Self;
    /// `v` rounded to this type.
    fn from_f64(v: f64) -> Self;
    /// Widened to `f64`.
    fn to_f64(self) -> f64;
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// Scratch of [`solve_in_place`]: the permuted right-hand sides and one supernode's update.
/// Grows to the largest solve, then is reused.
pub(super) struct Scratch<T> {
    x: Vec<T>,
    tmp: Vec<T>,
}

impl<T> Scratch<T> {
    /// Empty: grown by the first solve.
    pub(super) fn new() -> Self {
        Self {
            x: Vec::new(),
            tmp: Vec::new(),
        }
    }
}

/// Solves `A X = B` in place for the `ncols` column-major right-hand sides `rhs` with the
/// supernodal `L` of `symbolic` (`values`), skipping the supernodes of the forward substitution
/// whose rows are still zero (module docs); `stack` holds faer's solve scratch for `ncols`.
/// Returns how many supernodes the forward substitution skipped, or `None`, `rhs` untouched,
/// for a simplicial factor.
pub(super) fn solve_in_place<T: Real>(
    symbolic: &SymbolicCholesky<usize>,
    values: &[T],
    rhs: &mut [T],
    ncols: usize,
    scratch: &mut Scratch<T>,
    stack: &mut MemStack,
) -> Option<usize> {
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        return None;
    };
    let n = symbolic.nrows();
    let llt = SupernodalLltRef::new(sn, values);
    let skipped = permuted_forward(&llt, symbolic, rhs, ncols, scratch);
    let x = &mut scratch.x[..n * ncols];
    // faer's backward loop, as its whole solve calls it (`Conj::Yes`: the transpose of a real
    // factor).
    let xm = MatMut::from_column_major_slice_mut(&mut *x, n, ncols);
    llt.l_transpose_solve_with_conj(Conj::Yes, xm, Par::Seq, stack);
    unpermute(symbolic, x, rhs, n, ncols);
    Some(skipped)
}

/// The start of both solves: `P b` into the scratch, then the skipping forward substitution
/// (the first `n × ncols` values of `scratch.x`). Returns how many supernodes it skipped.
fn permuted_forward<T: Real>(
    llt: &SupernodalLltRef<'_, usize, T>,
    symbolic: &SymbolicCholesky<usize>,
    rhs: &[T],
    ncols: usize,
    scratch: &mut Scratch<T>,
) -> usize {
    let n = symbolic.nrows();
    if scratch.x.len() < n * ncols {
        scratch.x.resize(n * ncols, T::ZERO);
    }
    let x = &mut scratch.x[..n * ncols];
    permute(symbolic, rhs, x, n, ncols);
    forward(llt, x, n, ncols, &mut scratch.tmp)
}

/// The deferred solve of [`solve_in_place`]'s kind for one right-hand side: the forward
/// substitution whole (skipping), then the backward substitution over the supernodes from
/// `split` on only (the rows eliminated last, from permuted row `split_row`). `keep` receives
/// the permuted forward result `y`, whose rows before `split_row` [`complete_far`] needs;
/// `rhs` returns the solution on the rows from `split_row` on (exact: the backward substitution
/// reaches them first) and zero on the others. `None`, `rhs` untouched, for a simplicial factor.
pub(super) fn solve_near_in_place<T: Real>(
    symbolic: &SymbolicCholesky<usize>,
    values: &[T],
    rhs: &mut [T],
    ncols: usize,
    split: (usize, usize),
    keep: Option<&mut Vec<T>>,
    scratch: &mut Scratch<T>,
) -> Option<usize> {
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        return None;
    };
    let n = symbolic.nrows();
    let llt = SupernodalLltRef::new(sn, values);
    let skipped = permuted_forward(&llt, symbolic, rhs, ncols, scratch);
    let x = &mut scratch.x[..n * ncols];
    if let Some(keep) = keep {
        keep.clear();
        keep.extend_from_slice(&x[..n]);
    }
    backward(
        &llt,
        x,
        n,
        ncols,
        split.0..sn.n_supernodes(),
        &mut scratch.tmp,
    );
    for j in 0..ncols {
        x[j * n..][..split.1].fill(T::ZERO);
    }
    unpermute(symbolic, x, rhs, n, ncols);
    Some(skipped)
}

/// The rest of a [`solve_near_in_place`] of one right-hand side: with `x` permuted, holding
/// the kept forward result `y` on the rows before `split.1` and the solution (possibly
/// changed since, e.g. by a corrective motion's own near rows) on the others, the backward
/// substitution over the supernodes before `split.0`. Afterwards the rows before `split.1` of
/// `x` hold the solution of the whole system for that right-hand side.
pub(super) fn complete_far<T: Real>(
    symbolic: &SymbolicCholesky<usize>,
    values: &[T],
    x: &mut [T],
    split: (usize, usize),
    scratch: &mut Scratch<T>,
) -> Option<()> {
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        return None;
    };
    let n = symbolic.nrows();
    let llt = SupernodalLltRef::new(sn, values);
    backward(&llt, x, n, 1, 0..split.0, &mut scratch.tmp);
    Some(())
}

/// The first supernode of a supernodal factor that reaches permuted column `first` and its
/// first column: the backward substitution from that supernode on gives the solution on every
/// row from that column on. `None` for a simplicial factor.
pub(super) fn split_at(symbolic: &SymbolicCholesky<usize>, first: usize) -> Option<(usize, usize)> {
    let SymbolicCholeskyRaw::Supernodal(sn) = symbolic.raw() else {
        return None;
    };
    let s = (0..sn.n_supernodes()).find(|&s| sn.supernode_end()[s] > first)?;
    Some((s, sn.supernode_begin()[s]))
}

/// `x ← P b` for `ncols` column-major columns.
fn permute<T: Real>(
    symbolic: &SymbolicCholesky<usize>,
    rhs: &[T],
    x: &mut [T],
    n: usize,
    ncols: usize,
) {
    match symbolic.perm() {
        Some(perm) => {
            let fwd = perm.arrays().0;
            for j in 0..ncols {
                let (xj, bj) = (&mut x[j * n..][..n], &rhs[j * n..][..n]);
                for (xi, &f) in xj.iter_mut().zip(fwd) {
                    *xi = bj[f];
                }
            }
        }
        None => x.copy_from_slice(&rhs[..n * ncols]),
    }
}

/// `b ← Pᵀ x` for `ncols` column-major columns.
fn unpermute<T: Real>(
    symbolic: &SymbolicCholesky<usize>,
    x: &[T],
    rhs: &mut [T],
    n: usize,
    ncols: usize,
) {
    match symbolic.perm() {
        Some(perm) => {
            let inv = perm.arrays().1;
            for j in 0..ncols {
                let (xj, bj) = (&x[j * n..][..n], &mut rhs[j * n..][..n]);
                for (bi, &v) in bj.iter_mut().zip(inv) {
                    *bi = xj[v];
                }
            }
        }
        None => rhs[..n * ncols].copy_from_slice(x),
    }
}

/// `Lᵀ x = y` in place over the permuted `x` for the supernodes of `range` only, last first,
/// with the kernels of faer's backward loop (over every supernode: faer's loop).
fn backward<T: Real>(
    llt: &SupernodalLltRef<'_, usize, T>,
    x: &mut [T],
    n: usize,
    ncols: usize,
    range: core::ops::Range<usize>,
    tmp: &mut Vec<T>,
) {
    for s in range.rev() {
        let sup = llt.supernode(s);
        let (start, pattern, ls) = (sup.start(), sup.pattern(), sup.val());
        let size = ls.ncols();
        let (ls_top, ls_bot) = ls.split_at_row(size);
        let rows = pattern.len();
        if tmp.len() < rows * ncols {
            tmp.resize(rows * ncols, T::ZERO);
        }
        let t = &mut tmp[..rows * ncols];
        for j in 0..ncols {
            let xj = &x[j * n..][..n];
            for (ti, &i) in t[j * rows..][..rows].iter_mut().zip(pattern) {
                *ti = xj[i];
            }
        }
        let xm = MatMut::from_column_major_slice_mut(&mut *x, n, ncols);
        let mut x_top = xm.subrows_mut(start, size);
        let tm = MatRef::from_column_major_slice(&*t, rows, ncols);
        matmul_with_conj(
            x_top.rb_mut(),
            Accum::Add,
            ls_bot.transpose(),
            Conj::Yes,
            tm,
            Conj::No,
            -T::ONE,
            Par::Seq,
        );
        solve_upper_triangular_in_place_with_conj(
            ls_top.transpose(),
            Conj::Yes,
            x_top.rb_mut(),
            Par::Seq,
        );
    }
}

/// `L y = x` in place over the permuted `x` (`n` × `ncols`, column-major), supernode by
/// supernode as faer's forward loop, skipping those whose rows of `x` are all zero. Returns
/// how many it skipped.
fn forward<T: Real>(
    llt: &SupernodalLltRef<'_, usize, T>,
    x: &mut [T],
    n: usize,
    ncols: usize,
    tmp: &mut Vec<T>,
) -> usize {
    let mut skipped = 0;
    for s in 0..llt.symbolic().n_supernodes() {
        let sup = llt.supernode(s);
        let (start, pattern, ls) = (sup.start(), sup.pattern(), sup.val());
        let size = ls.ncols();
        let zero = (0..ncols).all(|j| x[j * n + start..][..size].iter().all(|v| *v == T::ZERO));
        if zero {
            skipped += 1;
            continue;
        }
        let (ls_top, ls_bot) = ls.split_at_row(size);
        let rows = pattern.len();
        if tmp.len() < rows * ncols {
            tmp.resize(rows * ncols, T::ZERO);
        }
        let t = &mut tmp[..rows * ncols];
        {
            let xm = MatMut::from_column_major_slice_mut(&mut *x, n, ncols);
            let mut x_top = xm.subrows_mut(start, size);
            solve_lower_triangular_in_place_with_conj(ls_top, Conj::No, x_top.rb_mut(), Par::Seq);
            let tm = MatMut::from_column_major_slice_mut(&mut *t, rows, ncols);
            let x_top: MatRef<'_, T> = x_top.rb();
            matmul_with_conj(
                tm,
                Accum::Replace,
                ls_bot,
                Conj::No,
                x_top,
                Conj::No,
                T::ONE,
                Par::Seq,
            );
        }
        for j in 0..ncols {
            let (xj, tj) = (&mut x[j * n..][..n], &t[j * rows..][..rows]);
            for (&i, &v) in pattern.iter().zip(tj) {
                xj[i] -= v;
            }
        }
    }
    skipped
}

#[cfg(test)]
mod tests {
    use super::super::{Cholesky, Precision, SymmetricMatrix, SymmetricPattern};
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::cholesky::LltRef;
    use faer::{Conj, MatMut, Par};

    /// A 3D grid Laplacian of `k³` nodes, 3 dofs each, shifted to be positive definite, with
    /// seeded off-diagonal weights: supernodal in faer, as the gel's matrices are.
    fn grid(k: usize) -> SymmetricMatrix {
        let id = |x: usize, y: usize, z: usize| (x * k + y) * k + z;
        let mut entries = Vec::new();
        let mut edges = Vec::new();
        for x in 0..k {
            for y in 0..k {
                for z in 0..k {
                    let a = id(x, y, z);
                    for (dx, dy, dz) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        let (x2, y2, z2) = (x + dx, y + dy, z + dz);
                        if x2 < k && y2 < k && z2 < k {
                            edges.push((a, id(x2, y2, z2)));
                        }
                    }
                }
            }
        }
        let n = 3 * k * k * k;
        for i in 0..n {
            entries.push((i, i));
        }
        for &(a, b) in &edges {
            for (da, db) in (0..3).flat_map(|u| (0..3).map(move |v| (u, v))) {
                entries.push((3 * a + da, 3 * b + db));
            }
        }
        let pattern = SymmetricPattern::from_entries(n, entries);
        let mut m = SymmetricMatrix::zeros(pattern.clone());
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut rand = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for &(a, b) in &edges {
            for (da, db) in (0..3).flat_map(|u| (0..3).map(move |v| (u, v))) {
                let (i, j) = (3 * a + da, 3 * b + db);
                let slot = pattern.slot(i, j).expect("in the pattern");
                m.values[slot] = -(0.5 + rand()) / 3.0;
            }
        }
        for i in 0..n {
            let slot = pattern.slot(i, i).expect("diagonal");
            m.values[slot] = 14.0 + rand();
        }
        m
    }

    /// The skipping solve gives faer's whole solve to the last bit (zeros compared by value),
    /// in both precisions, for right-hand sides on a few dofs (as a point's compliance columns)
    /// and for dense ones, and skips supernodes only for the former.
    #[test]
    fn skipping_solve_is_faers_solve_bit_for_bit() {
        let a = grid(12);
        let n = a.pattern.n;
        for precision in [Precision::Double, Precision::Single] {
            let mut chol =
                Cholesky::try_new_with_precision(&a.pattern, None, 6, precision).expect("symbolic");
            chol.factorize(&a).expect("SPD");
            // A point's 3 columns on the dofs of two nodes, 2 points; then dense columns.
            let mut sparse = vec![0.0; n * 6];
            for (c, (node, w)) in [(17, 0.3), (400, 0.7), (1500, 1.0)].iter().enumerate() {
                for d in 0..2 {
                    let col = 2 * c + d;
                    sparse[col * n + 3 * node + d] = *w;
                    sparse[col * n + 3 * (node + 1) + d] = 1.0 - *w;
                }
            }
            let mut state = 7_u64;
            let dense: Vec<f64> = (0..n * 6)
                .map(|_| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .collect();
            for (rhs, expect_skips) in [(&sparse, true), (&dense, false)] {
                let mut ours = rhs.clone();
                chol.solve_many_in_place(&mut ours, 6).expect("solve");
                let (theirs, skipped) = faer_solve(&chol, rhs, 6);
                assert!(
                    ours.iter().zip(&theirs).all(|(x, y)| x == y),
                    "{precision:?}"
                );
                assert!(ours.iter().any(|x| *x != 0.0));
                std::println!("{precision:?}, skips expected {expect_skips}: {skipped} skipped");
                assert_eq!(skipped > 0, expect_skips, "{precision:?}");
            }
        }
    }

    /// The deferred solve (`Cholesky::solve_deferring_far`) gives the whole solve's rows from
    /// its split on bit for bit and zero before; finished unchanged it is the whole solve bit
    /// for bit; finished after adding the near rows of a response to loads on those rows
    /// (`Cholesky::solve_near_many`, itself the whole solve's rows bit for bit), it is the
    /// solve of the summed load to round-off; a factor changed in between refuses to finish.
    #[test]
    fn deferred_far_rows_finish_into_the_whole_solve() {
        let a = grid(12);
        let n = a.pattern.n;
        for precision in [Precision::Double, Precision::Single] {
            let mut chol =
                Cholesky::try_new_with_precision(&a.pattern, None, 6, precision).expect("symbolic");
            chol.factorize(&a).expect("SPD");
            let split = chol.deferral_split(n - 400).expect("supernodal");
            assert!(split.1 <= n - 400 && split.1 > 0, "{split:?}");
            let after: Vec<usize> = (0..n).filter(|&i| chol.is_after_split(i, split)).collect();
            assert_eq!(after.len(), n - split.1);
            let mut state = 11_u64;
            let b: Vec<f64> = (0..n)
                .map(|_| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .collect();
            let mut whole = b.clone();
            chol.solve_in_place(&mut whole).expect("solve");
            let mut x = b.clone();
            chol.solve_deferring_far(&mut x, split).expect("deferred");
            for i in 0..n {
                let expect = if chol.is_after_split(i, split) {
                    whole[i]
                } else {
                    0.0
                };
                assert!(
                    x[i] == expect,
                    "{precision:?} row {i}: {} vs {expect}",
                    x[i]
                );
            }
            let mut unchanged = x.clone();
            chol.complete_far(&mut unchanged, split).expect("finish");
            assert!(
                unchanged.iter().zip(&whole).all(|(u, w)| u == w),
                "{precision:?}"
            );
            // A response to loads on three rows after the split, added on those rows only.
            let mut r = vec![0.0; n * 3];
            for (c, &i) in [after[5], after[200], after[399]].iter().enumerate() {
                r[c * n + i] = 1.0 + c as f64;
            }
            let mut cols = r.clone();
            chol.solve_near_many(&mut cols, 3, split)
                .expect("near columns");
            let mut full_cols = r.clone();
            chol.solve_many_in_place(&mut full_cols, 3)
                .expect("columns");
            for c in 0..3 {
                for i in 0..n {
                    let expect = if chol.is_after_split(i, split) {
                        full_cols[c * n + i]
                    } else {
                        0.0
                    };
                    assert!(
                        cols[c * n + i] == expect,
                        "{precision:?} column {c} row {i}"
                    );
                }
            }
            let f = [0.7, -1.3, 2.1];
            let mut total = x.clone();
            let mut load = b.clone();
            for c in 0..3 {
                for i in 0..n {
                    total[i] += f[c] * cols[c * n + i];
                    load[i] += f[c] * r[c * n + i];
                }
            }
            chol.complete_far(&mut total, split).expect("finish");
            chol.solve_in_place(&mut load).expect("solve");
            let scale = load.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            let err = total
                .iter()
                .zip(&load)
                .fold(0.0_f64, |m, (u, v)| m.max((u - v).abs()));
            let tol = match precision {
                Precision::Double => 1e-13,
                Precision::Single => 1e-5,
            };
            assert!(err <= tol * scale, "{precision:?}: {err:e} of {scale:e}");
            // A new factor: nothing to finish.
            chol.factorize(&a).expect("SPD");
            let mut again = x.clone();
            assert!(matches!(
                chol.complete_far(&mut again, split),
                Err(super::super::LinalgError::Deferred(_))
            ));
        }
    }

    /// faer's own whole solve of `rhs` with `chol`'s factor (widened to `f64`), and how many
    /// supernodes the skipping solve skips for it.
    fn faer_solve(chol: &Cholesky, rhs: &[f64], k: usize) -> (Vec<f64>, usize) {
        fn both<T: super::Real>(chol: &Cholesky, l: &[T], x: &[T], k: usize) -> (Vec<T>, usize) {
            let n = chol.dim();
            let req = chol.symbolic.solve_in_place_scratch::<T>(k, Par::Seq);
            let mut mem = MemBuffer::new(req);
            let mut theirs = x.to_vec();
            let llt = LltRef::<'_, usize, T>::new(&chol.symbolic, l);
            let m = MatMut::from_column_major_slice_mut(&mut theirs, n, k);
            llt.solve_in_place_with_conj(Conj::No, m, Par::Seq, MemStack::new(&mut mem));
            let (mut ours, mut scratch) = (x.to_vec(), super::Scratch::new());
            let stack = MemStack::new(&mut mem);
            let skipped =
                super::solve_in_place(&chol.symbolic, l, &mut ours, k, &mut scratch, stack)
                    .expect("a supernodal factor");
            (theirs, skipped)
        }
        match &chol.single {
            None => both(chol, &chol.l_values, rhs, k),
            Some(sf) => {
                let x: Vec<f32> = rhs.iter().map(|v| *v as f32).collect();
                let (theirs, skipped) = both(chol, &sf.l, &x, k);
                (theirs.iter().map(|v| f64::from(*v)).collect(), skipped)
            }
        }
    }
}
