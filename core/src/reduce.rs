//! Exact elimination of the 6 needle-base rows before the iterative solve.
//!
//! The needle hangs on its base constraint χ only, so the host's `K_n` is regularised by a tiny
//! `M/h²` and its rigid-body modes have a *huge* compliance. Every needle-side row (base, tip
//! contact, sliding points) shares those modes: in `W` the base rows and, e.g., a contact row are
//! nearly collinear (`W ≈ [[a, a], [a, a + ε]]` with `a/ε ~ 10³`), and Gauss-Seidel crawls or
//! stalls. The base rows are bilateral and always present, so they can be eliminated exactly
//! (Schur complement):
//!
//! ```text
//! W' = W_oo − W_ob W_bb⁻¹ W_bo,     δ'(q) = δ_o − W_ob W_bb⁻¹ δ_b(q)
//! λ_o = LCP(W', δ'(q)),             λ_b = W_bb⁻¹ (δ_b(q) − W_bo λ_o)
//! ```
//!
//! `W'` is the compliance of the other rows *with the needle clamped at its base*: physical,
//! well conditioned (needle bending + gel), and the same for every `q` of a step, so it is built
//! once per frame (`O(m² · 6)`) and each of the step's solves only forms `δ'` (`O(6 m)`).

use crate::payload::{BASE_ROWS, ComplianceFrame, RowGroup};
use nalgebra::{Matrix6, Vector6};

/// The reduced problem of one frame: `W'`, the groups after the base, and the maps between full
/// and reduced quantities. About `8 M² + 64 M` bytes.
#[derive(Clone, Debug)]
pub struct BaseElimination<const M: usize> {
    /// `W'` in rows/columns `0..n` (`n = m − 6`).
    pub w: [[f64; M]; M],
    /// `S = W_ob W_bb⁻¹`, one row per reduced row.
    s: [[f64; 6]; M],
    /// `W_bb⁻¹`.
    wbb_inv: [[f64; 6]; 6],
    /// The frame's groups after the base, starts shifted by −6.
    groups: [RowGroup; M],
    n_groups: usize,
    n: usize,
    /// `δ'` of the last [`Self::reduce_delta`].
    pub delta: [f64; M],
}

crate::zeroed::impl_zeroable!(BaseElimination<const M> {
    w,
    s,
    wbb_inv,
    groups,
    n_groups,
    n,
    delta,
});

impl<const M: usize> BaseElimination<M> {
    /// An empty reduction.
    pub const fn new() -> Self {
        const EMPTY: RowGroup = RowGroup {
            kind: 0,
            start: 0,
            len: 0,
            reserved: 0,
            mu: 0.0,
            r0: 0.0,
        };
        Self {
            w: [[0.0; M]; M],
            s: [[0.0; 6]; M],
            wbb_inv: [[0.0; 6]; 6],
            groups: [EMPTY; M],
            n_groups: 0,
            n: 0,
            delta: [0.0; M],
        }
    }

    /// Rows of the reduced problem.
    pub fn rows(&self) -> usize {
        self.n
    }

    /// Groups of the reduced problem.
    pub fn groups(&self) -> &[RowGroup] {
        &self.groups[..self.n_groups]
    }

    /// Builds `W'`, `S` and the groups for a *validated* frame. Returns `false` (and leaves an
    /// empty reduction) if `W_bb` is not positive definite.
    pub fn prepare<const N: usize>(&mut self, frame: &ComplianceFrame<M, N>) -> bool {
        let m = frame.rows().min(M);
        let w = &frame.w;
        self.n = 0;
        self.n_groups = 0;
        let wbb = Matrix6::from_fn(|i, j| 0.5 * (w[i][j] + w[j][i]));
        let Some(ch) = wbb.cholesky() else {
            return false;
        };
        let inv = ch.inverse();
        if !inv.iter().all(|x| x.is_finite()) {
            return false;
        }
        for i in 0..6 {
            for j in 0..6 {
                self.wbb_inv[i][j] = inv[(i, j)];
            }
        }
        let n = m.saturating_sub(BASE_ROWS);
        for i in 0..n {
            let r = &w[BASE_ROWS + i];
            for k in 0..6 {
                let mut v = 0.0;
                for j in 0..6 {
                    v += r[j] * self.wbb_inv[j][k];
                }
                self.s[i][k] = v;
            }
        }
        self.schur_dispatch(w, n);
        for (k, g) in frame.used_groups().iter().skip(1).enumerate() {
            self.groups[k] = RowGroup {
                start: g.start.saturating_sub(BASE_ROWS as u32),
                ..*g
            };
            self.n_groups = k + 1;
        }
        self.n = n;
        true
    }

    /// `W' = W_oo − S W_bo` into `self.w` (rows and columns `0..n`), with the AVX-512 or the
    /// AVX2 copy of the loop when the CPU has it (the same operations in the same order: the
    /// same result).
    fn schur_dispatch(&mut self, w: &[[f64; M]; M], n: usize) {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx512() {
            // SAFETY: AVX-512F support was checked at run time.
            unsafe { self.schur_avx512(w, n) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            unsafe { self.schur_avx2(w, n) };
            return;
        }
        self.schur(w, n);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn schur_avx2(&mut self, w: &[[f64; M]; M], n: usize) {
        self.schur(w, n);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn schur_avx512(&mut self, w: &[[f64; M]; M], n: usize) {
        self.schur(w, n);
    }

    /// Row `i` of the lower triangle in one pass over the base rows' columns (contiguous, so it
    /// vectorises), entry by entry the same operations in the same order; then mirrored, so
    /// that `W'` is exactly symmetric.
    #[inline(always)]
    fn schur(&mut self, w: &[[f64; M]; M], n: usize) {
        for i in 0..n {
            let si = self.s[i];
            let cols = BASE_ROWS..BASE_ROWS + i + 1;
            let src = &w[BASE_ROWS + i][cols.clone()];
            let b: [&[f64]; 6] = core::array::from_fn(|k| &w[k][cols.clone()]);
            let row = &mut self.w[i][..=i];
            let (b0, b1, b2, b3, b4, b5) = (
                &b[0][..=i],
                &b[1][..=i],
                &b[2][..=i],
                &b[3][..=i],
                &b[4][..=i],
                &b[5][..=i],
            );
            let cols = row
                .iter_mut()
                .zip(src)
                .zip(b0.iter().zip(b1).zip(b2))
                .zip(b3.iter().zip(b4).zip(b5));
            for (((r, x), ((y0, y1), y2)), ((y3, y4), y5)) in cols {
                let mut v = *x;
                v -= si[0] * y0;
                v -= si[1] * y1;
                v -= si[2] * y2;
                v -= si[3] * y3;
                v -= si[4] * y4;
                v -= si[5] * y5;
                *r = v;
            }
        }
        mirror_lower(&mut self.w, n);
    }

    /// `δ' = δ_o − S δ_b` from the frame's other rows and the base violation `delta_b`.
    pub fn reduce_delta<const N: usize>(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        delta_b: &[f64; 6],
    ) {
        reduce_into(&self.s[..self.n], frame, delta_b, &mut self.delta);
    }

    /// [`Self::reduce_delta`] into `out` (rows `0..n`) instead of [`Self::delta`].
    pub fn reduce_delta_into<const N: usize>(
        &self,
        frame: &ComplianceFrame<M, N>,
        delta_b: &[f64; 6],
        out: &mut [f64; M],
    ) {
        reduce_into(&self.s[..self.n], frame, delta_b, out);
    }

    /// The full `λ` from the reduced `lambda_o` (rows `0..n`): `λ_b = W_bb⁻¹ (δ_b − W_bo λ_o)`,
    /// `λ_o` copied after it.
    pub fn expand<const N: usize>(
        &self,
        frame: &ComplianceFrame<M, N>,
        delta_b: &[f64; 6],
        lambda_o: &[f64; M],
        full: &mut [f64; M],
    ) {
        let mut rhs = Vector6::from(*delta_b);
        // The 6 sums side by side (each one in its own order, as alone): 6 independent chains
        // of additions rather than 6 in a row.
        let rows: [&[f64]; 6] =
            core::array::from_fn(|k| &frame.w[k][BASE_ROWS..BASE_ROWS + self.n]);
        let mut v = [0.0f64; 6];
        for (j, b) in lambda_o[..self.n].iter().enumerate() {
            for k in 0..6 {
                v[k] += rows[k][j] * b;
            }
        }
        for k in 0..6 {
            rhs[k] -= v[k];
        }
        for k in 0..6 {
            let mut v = 0.0;
            for j in 0..6 {
                v += self.wbb_inv[k][j] * rhs[j];
            }
            full[k] = v;
        }
        full[BASE_ROWS..BASE_ROWS + self.n].copy_from_slice(&lambda_o[..self.n]);
    }
}

/// Copies the strict lower triangle of the `n × n` block onto the upper one (`w[j][i] =
/// w[i][j]` for `j < i < n`), by tiles of 8 × 8 so that the column writes of a tile stay in
/// the few cache lines of its rows instead of touching one line of another row per entry (at
/// n = 186 the plain column loop was 60 % of the Schur complement's time). The same copies:
/// the same matrix.
#[inline(always)]
fn mirror_lower<const M: usize>(w: &mut [[f64; M]; M], n: usize) {
    const T: usize = 8;
    let n = n.min(M);
    let mut i0 = 0;
    while i0 < n {
        let i1 = (i0 + T).min(n);
        let mut j0 = 0;
        while j0 < i1 {
            let j1 = (j0 + T).min(i1);
            for i in i0..i1 {
                for j in j0..j1.min(i) {
                    w[j][i] = w[i][j];
                }
            }
            j0 += T;
        }
        i0 += T;
    }
}

/// `out_i = δ_o,i − S_i δ_b` for the rows of `s`.
fn reduce_into<const M: usize, const N: usize>(
    s: &[[f64; 6]],
    frame: &ComplianceFrame<M, N>,
    delta_b: &[f64; 6],
    out: &mut [f64; M],
) {
    for (i, si) in s.iter().enumerate() {
        let mut d = frame.delta_free[BASE_ROWS + i];
        for k in 0..6 {
            d -= si[k] * delta_b[k];
        }
        out[i] = d;
    }
}

impl<const M: usize> Default for BaseElimination<M> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::mirror_lower;

    /// The tiled mirror copies exactly what the plain column loop copies, for sizes on and off
    /// the tile width, and leaves the diagonal, the lower triangle and rows/columns `n..` alone.
    #[test]
    fn tiled_mirror_is_the_plain_column_loop() {
        const M: usize = 40;
        for n in [0, 1, 2, 7, 8, 9, 15, 16, 17, 23, 31, 33, 39, 40] {
            let mut a = [[0.0f64; M]; M];
            for (i, row) in a.iter_mut().enumerate() {
                for (j, x) in row.iter_mut().enumerate() {
                    // Distinct values, a different pattern above the diagonal.
                    *x = if j <= i {
                        (i * M + j) as f64 + 0.5
                    } else {
                        -((i * M + j) as f64)
                    };
                }
            }
            let mut b = a;
            for i in 0..n {
                for j in 0..i {
                    b[j][i] = b[i][j];
                }
            }
            mirror_lower(&mut a, n);
            assert!(a == b, "n = {n}");
        }
    }
}
