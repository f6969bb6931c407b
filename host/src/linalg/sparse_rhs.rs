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
use faer::linalg::triangular_solve::solve_lower_triangular_in_place_with_conj;
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
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
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
    if scratch.x.len() < n * ncols {
        scratch.x.resize(n * ncols, T::ZERO);
    }
    let x = &mut scratch.x[..n * ncols];
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
        None => x.copy_from_slice(rhs),
    }
    let skipped = forward(&llt, x, n, ncols, &mut scratch.tmp);
    // faer's backward loop, as its whole solve calls it (`Conj::Yes`: the transpose of a real
    // factor).
    let xm = MatMut::from_column_major_slice_mut(x, n, ncols);
    llt.l_transpose_solve_with_conj(Conj::Yes, xm, Par::Seq, stack);
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
        None => rhs.copy_from_slice(x),
    }
    Some(skipped)
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
