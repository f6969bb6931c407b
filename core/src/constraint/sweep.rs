//! The solve loop and one projected Gauss-Seidel sweep: each group's exact local update, the
//! residual kept in step with `λ`, the stopping test.

use super::project::Sym2;
use super::{
    Block, BlockGs, GsParams, KIND_BILATERAL, KIND_CONTACT, KIND_SLIDING, KIND_UNILATERAL,
    SolveReport,
};
use crate::math::{axpy, axpy3, dot, max_abs};

impl<const M: usize> BlockGs<M> {
    /// Solves `w = W λ − δ` under the group laws, warm-starting from `lambda`, which receives the
    /// result. `w` must be the matrix given to the last `prepare`; rows `m..` are left untouched.
    /// Never loops unbounded; finite input gives finite output.
    ///
    /// # Example
    /// ```
    /// use needle_core::{BlockGs, GsParams, RowGroup};
    ///
    /// // Two frictionless contacts with W = [[2, 1], [1, 2]]: δ = (1, −1) presses the first
    /// // and lifts the second, so only the first pushes: λ = (0.5, 0).
    /// let mut w = [[0.0; 4]; 4];
    /// w[0][..2].copy_from_slice(&[2.0, 1.0]);
    /// w[1][..2].copy_from_slice(&[1.0, 2.0]);
    /// let delta = [1.0, -1.0, 0.0, 0.0];
    /// let mut gs = BlockGs::<4>::new();
    /// gs.prepare(&w, 2, &[RowGroup::unilateral(0), RowGroup::unilateral(1)])?;
    /// let mut lambda = [0.0; 4];
    /// let report = gs.solve(&w, &delta, &mut lambda, &GsParams::default());
    /// assert!(report.converged);
    /// assert_eq!(&lambda[..2], &[0.5, 0.0]);
    /// // w = W λ − δ: zero where λ pushes, non-negative (opening) where it does not.
    /// assert_eq!(gs.last_residual(), &[0.0, 1.5]);
    /// # Ok::<(), needle_core::ValidationError>(())
    /// ```
    pub fn solve(
        &mut self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        params: &GsParams,
    ) -> SolveReport {
        self.solve_from(w, delta, lambda, None, params)
    }

    /// [`Self::solve`], given the product `W λ` of the starting `lambda` ([`Self::product`]) when
    /// several solves start from the same `λ`: the initial residual is then `product − δ`, the
    /// same numbers [`Self::solve`] computes, without its `m²` pass. The product is ignored
    /// when `lambda` has a non-finite entry (zeroed first, so the product would not match).
    pub(crate) fn solve_from(
        &mut self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        product: Option<&[f64; M]>,
        params: &GsParams,
    ) -> SolveReport {
        let m = self.m;
        if m == 0 {
            return SolveReport {
                converged: true,
                ..SolveReport::default()
            };
        }
        // Initial residual and the problem scale.
        let mut scale = max_abs(&delta[..m]);
        let mut cleaned = false;
        for i in 0..m {
            if !lambda[i].is_finite() {
                lambda[i] = 0.0;
                cleaned = true;
            }
            scale = scale.max(libm::fabs(self.diag[i] * lambda[i]));
        }
        match product {
            Some(p) if !cleaned => {
                for i in 0..m {
                    self.w[i] = p[i] - delta[i];
                }
            }
            _ => self.residual_dispatch(w, delta, lambda),
        }
        if !(scale > 0.0) {
            lambda[..m].fill(0.0);
            return SolveReport {
                converged: true,
                ..SolveReport::default()
            };
        }
        let tol = if params.tolerance.is_finite() {
            params.tolerance.max(0.0)
        } else {
            0.0
        };
        let mut report = SolveReport::default();
        while report.iterations < params.max_iterations {
            let omega = if params.relaxation.is_finite() {
                params.relaxation.clamp(0.1, 1.9)
            } else {
                1.0
            };
            let change = self.sweep_dispatch(w, lambda, omega);
            report.iterations += 1;
            report.residual = change / scale;
            if !(report.residual > tol) {
                report.converged = report.residual <= tol;
                break;
            }
        }
        if params.polish && !self.frictional && self.polish(w, delta, lambda, scale) {
            report.converged = true;
            report.polished = true;
            report.residual = 0.0;
        }
        report
    }

    /// `w = W λ − δ` over the used rows.
    fn residual_dispatch(&mut self, w: &[[f64; M]; M], delta: &[f64; M], lambda: &[f64; M]) {
        let m = self.m;
        product_rows(w, lambda, m, &mut self.w);
        for i in 0..m {
            self.w[i] -= delta[i];
        }
    }

    /// `out = W λ` over the used rows (rows `m..` untouched): the product that solves started
    /// from `λ` begin with ([`Self::solve_from`]).
    pub(crate) fn product(&self, w: &[[f64; M]; M], lambda: &[f64; M], out: &mut [f64; M]) {
        product_rows(w, lambda, self.m, out);
    }

    /// One sweep, with the AVX-512 or the AVX2 copy of the loops when the CPU has it (the same
    /// operations on wider vectors: the same result).
    fn sweep_dispatch(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx512() {
            // SAFETY: AVX-512F support was checked at run time.
            return unsafe { self.sweep_avx512(w, lambda, omega) };
        }
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { self.sweep_avx2(w, lambda, omega) };
        }
        self.sweep(w, lambda, omega, 4)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn sweep_avx2(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        self.sweep(w, lambda, omega, 4)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn sweep_avx512(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        self.sweep(w, lambda, omega, 8)
    }

    /// One sweep over every group; returns the largest `|W_ii Δλ_i|`. Each group computes its
    /// update from its own diagonal block, then applies it to `w` in one fused pass over the
    /// group's rows of `W` (one read-modify-write of `w` per group, not per row).
    #[inline(always)]
    fn sweep(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64, lanes: usize) -> f64 {
        let groups = Groups {
            blocks: &self.blocks[..self.n_blocks],
            factors: &self.factors,
            diag: &self.diag,
            m: padded(self.m, lanes, M),
        };
        let lambda = core::array::from_mut(lambda);
        let res = core::array::from_mut(&mut self.w);
        groups.sweep::<1>(w, lambda, res, &[0], omega)[0]
    }

    /// `count ≤ K` solves, each with its own `δ` (`batch.delta[k]`, rows `0..m`), run in lock
    /// step: each sweep visits the groups once and updates every unfinished solve at each, so the
    /// rows of `W` a group reads come from memory once for all of them (from the cache for the
    /// others). Each solve does exactly the operations of [`Self::solve_from`] from its start
    /// (the same λ, sweep count and report) and stops at its own convergence. Where they start:
    /// [`BatchStart`]. The results are in `batch.lambda[k]`.
    pub(crate) fn solve_batch<const K: usize>(
        &mut self,
        w: &[[f64; M]; M],
        start: BatchStart<'_, M>,
        batch: &mut GsBatch<M, K>,
        count: usize,
        params: &GsParams,
    ) -> [SolveReport; K] {
        let (m, count) = (self.m, count.min(K));
        let mut reports = [SolveReport::default(); K];
        if m == 0 {
            for r in &mut reports[..count] {
                r.converged = true;
            }
            return reports;
        }
        // Each solve's start into `batch.lambda[k]` and its residual `W λ − δ` into
        // `batch.res[k]`, as `solve_from` would: non-finite entries zeroed, the product then
        // computed rather than taken.
        let mut own = [0.0; M];
        let shared = match start {
            BatchStart::Shared { lambda0, product } => {
                let mut cleaned = false;
                for i in 0..m {
                    own[i] = if lambda0[i].is_finite() {
                        lambda0[i]
                    } else {
                        cleaned = true;
                        0.0
                    };
                }
                for k in 0..count {
                    batch.lambda[k][..m].copy_from_slice(&own[..m]);
                }
                let mut product = *product;
                if cleaned {
                    self.product(w, &own, &mut product);
                }
                Some(product)
            }
            BatchStart::Own => None,
        };
        if shared.is_none() {
            // Every solve's own `W λ`, in one pass over `W` (each row's dots as
            // `product_rows`'s).
            for lambda in &mut batch.lambda[..count] {
                for x in &mut lambda[..m] {
                    if !x.is_finite() {
                        *x = 0.0;
                    }
                }
            }
            product_many(w, &batch.lambda, count, m, &mut batch.res);
        }
        let mut scale = [0.0; K];
        let mut active = [false; K];
        for k in 0..count {
            let (delta, lambda, res) = (&batch.delta[k], &mut batch.lambda[k], &mut batch.res[k]);
            let mut sc = max_abs(&delta[..m]);
            match &shared {
                Some(product) => {
                    for i in 0..m {
                        res[i] = product[i] - delta[i];
                    }
                }
                None => {
                    for i in 0..m {
                        res[i] -= delta[i];
                    }
                }
            }
            for i in 0..m {
                sc = sc.max(libm::fabs(self.diag[i] * lambda[i]));
            }
            if sc > 0.0 {
                active[k] = true;
            } else {
                lambda[..m].fill(0.0);
                reports[k].converged = true;
            }
            scale[k] = sc;
        }
        let tol = if params.tolerance.is_finite() {
            params.tolerance.max(0.0)
        } else {
            0.0
        };
        let mut iterations = 0;
        while iterations < params.max_iterations && active.iter().any(|a| *a) {
            let omega = if params.relaxation.is_finite() {
                params.relaxation.clamp(0.1, 1.9)
            } else {
                1.0
            };
            let change = self.sweep_batch_dispatch(w, batch, &active, omega);
            iterations += 1;
            for k in 0..count {
                if active[k] {
                    let r = &mut reports[k];
                    r.iterations = iterations;
                    r.residual = change[k] / scale[k];
                    if !(r.residual > tol) {
                        r.converged = r.residual <= tol;
                        active[k] = false;
                    }
                }
            }
        }
        for k in 0..count {
            if scale[k] > 0.0 {
                self.w[..m].copy_from_slice(&batch.res[k][..m]);
                if params.polish
                    && !self.frictional
                    && self.polish(w, &batch.delta[k], &mut batch.lambda[k], scale[k])
                {
                    let r = &mut reports[k];
                    r.converged = true;
                    r.polished = true;
                    r.residual = 0.0;
                }
            }
        }
        reports
    }

    /// One lock-step sweep of a batch ([`Self::solve_batch`]), with the AVX-512 or the AVX2
    /// copy of the loops when the CPU has it.
    fn sweep_batch_dispatch<const K: usize>(
        &self,
        w: &[[f64; M]; M],
        batch: &mut GsBatch<M, K>,
        active: &[bool; K],
        omega: f64,
    ) -> [f64; K] {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx512() {
            // SAFETY: AVX-512F support was checked at run time.
            return unsafe { self.sweep_batch_avx512(w, batch, active, omega) };
        }
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { self.sweep_batch_avx2(w, batch, active, omega) };
        }
        self.sweep_batch(w, batch, active, omega, 4)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn sweep_batch_avx2<const K: usize>(
        &self,
        w: &[[f64; M]; M],
        batch: &mut GsBatch<M, K>,
        active: &[bool; K],
        omega: f64,
    ) -> [f64; K] {
        self.sweep_batch(w, batch, active, omega, 4)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn sweep_batch_avx512<const K: usize>(
        &self,
        w: &[[f64; M]; M],
        batch: &mut GsBatch<M, K>,
        active: &[bool; K],
        omega: f64,
    ) -> [f64; K] {
        self.sweep_batch(w, batch, active, omega, 8)
    }

    /// [`Self::sweep`] for every active solve of a batch, group by group: each solve sees the
    /// same sequence of group updates as alone.
    ///
    /// At a sliding point (the bulk of the reduced problems) the local updates of all the
    /// solves come first, computed together lane by lane ([`sliding_lanes`]), then one pass
    /// over the point's three rows of `W` updates all the residuals ([`axpy3_batch`]: each
    /// vector of `W` loaded once for three solves). Every entry of `λ` and of the residuals gets
    /// the operations, in the order, of the solve alone: the same results.
    #[inline(always)]
    fn sweep_batch<const K: usize>(
        &self,
        w: &[[f64; M]; M],
        batch: &mut GsBatch<M, K>,
        active: &[bool; K],
        omega: f64,
        lanes: usize,
    ) -> [f64; K] {
        let groups = Groups {
            blocks: &self.blocks[..self.n_blocks],
            factors: &self.factors,
            diag: &self.diag,
            m: padded(self.m, lanes, M),
        };
        let mut list = [0usize; K];
        let mut n = 0;
        for k in 0..K {
            if active[k] {
                list[n] = k;
                n += 1;
            }
        }
        let GsBatch { lambda, res, .. } = batch;
        groups.sweep(w, lambda, res, &list[..n], omega)
    }
}

/// What a sweep reads of a prepared [`BlockGs`]: the groups, their factors, `diag(W)`, and the
/// rows of the residual the passes update ([`padded`]).
struct Groups<'a, const M: usize> {
    blocks: &'a [Block],
    factors: &'a [[f64; 6]; M],
    diag: &'a [f64; M],
    m: usize,
}

impl<const M: usize> Groups<'_, M> {
    /// One sweep of the solves `list` (distinct, `< K`): `lambda[k]` and its residual `res[k]`;
    /// returns each solve's largest change.
    #[inline(always)]
    fn sweep<const K: usize>(
        &self,
        w: &[[f64; M]; M],
        lambda: &mut [[f64; M]; K],
        res: &mut [[f64; M]; K],
        list: &[usize],
        omega: f64,
    ) -> [f64; K] {
        let (m, diag) = (self.m, self.diag);
        let mut change = [0.0f64; K];
        for b in self.blocks {
            let f = self.factors[b.start as usize..].as_flattened();
            let start = b.start as usize;
            if b.kind == KIND_SLIDING {
                // The factors unpacked once for all the solves; every local update first (each
                // solve's own chain), then one pass over the point's rows of `W` for all.
                let (e, inv_axial) = (Sym2::unpack(&f[0..10]), f[10]);
                let d = if 1 < K && K <= LANES {
                    let point = (start, b.mu, b.r0, &e, inv_axial, omega);
                    sliding_lanes(w, lambda, res, diag, &mut change, list, point)
                } else {
                    let mut d = [[0.0; 3]; K];
                    for &k in list {
                        let rk = &res[k];
                        let r = [rk[start], rk[start + 1], rk[start + 2]];
                        let mut s = Local {
                            w,
                            lambda: &mut lambda[k],
                            diag,
                            change: change[k],
                        };
                        d[k] = s.sliding(start, b.mu, b.r0, &e, inv_axial, omega, &r);
                        change[k] = s.change;
                    }
                    d
                };
                let rows = (&w[start][..m], &w[start + 1][..m], &w[start + 2][..m]);
                axpy3_batch(&d, list, rows, res, m);
                continue;
            }
            // The group's kind chosen once for all the solves.
            macro_rules! each {
                ($s:ident => $op:expr) => {
                    for &k in list {
                        let mut $s = Sweep {
                            w,
                            res: &mut res[k],
                            lambda: &mut lambda[k],
                            diag,
                            m,
                            change: change[k],
                        };
                        $op;
                        change[k] = $s.change;
                    }
                };
            }
            match b.kind {
                KIND_CONTACT => each!(s => s.contact(start, b.mu, f)),
                KIND_UNILATERAL => each!(s => s.unilateral(start, f[0], omega)),
                KIND_BILATERAL => each!(s => s.bilateral(start, b.len as usize, f, omega)),
                _ => {}
            }
        }
        change.map(finite_change)
    }
}

/// Lanes of [`sliding_lanes`]: the solves of a batch updated together (at most [`LANES`]).
const LANES: usize = 8;

/// The local update of sliding point `(s, μ, r_0, e, 1 / W_aa, ω)` ([`Local::sliding`]) for every
/// solve of `list` (`K ≤ LANES`), computed lane by lane across the solves: the same operations
/// on each lane, so the same `λ`, changes and returned `[d1, d2, da]` as one solve at a time,
/// with one chain of vector operations (one vector division, one vector square root) instead
/// of `K` scalar chains. Lanes of inactive solves and lanes `K..` are computed and discarded.
#[inline(always)]
fn sliding_lanes<const M: usize, const K: usize>(
    w: &[[f64; M]; M],
    lambda: &mut [[f64; M]; K],
    res: &[[f64; M]; K],
    diag: &[f64; M],
    change: &mut [f64; K],
    list: &[usize],
    (s, mu, r0, e, inv_axial, omega): (usize, f64, f64, &Sym2, f64, f64),
) -> [[f64; 3]; K] {
    let a = s + 2;
    let (mut nr0, mut nr1, mut r2) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let (mut l0, mut l1, mut la) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    for k in 0..K.min(LANES) {
        (nr0[k], nr1[k], r2[k]) = (-res[k][s], -res[k][s + 1], res[k][a]);
        (l0[k], l1[k], la[k]) = (lambda[k][s], lambda[k][s + 1], lambda[k][a]);
    }
    let (mut d1, mut d2) = e.solve_lanes(&nr0, &nr1);
    let (wsa, ws1a) = (w[s][a], w[s + 1][a]);
    let mut da = [0.0; LANES];
    for i in 0..LANES {
        d1[i] *= omega;
        d2[i] *= omega;
        l0[i] += d1[i];
        l1[i] += d2[i];
        // As `Local::sliding`: plain sqrt of the lateral force, the axial row clamped.
        let lat = crate::math::sqrt(l0[i] * l0[i] + l1[i] * l1[i]);
        let bound = mu * lat + r0;
        let wa = r2[i] + d1[i] * wsa + d2[i] * ws1a;
        let new = (la[i] - omega * wa * inv_axial).max(-bound).min(bound);
        da[i] = new - la[i];
        la[i] = new;
    }
    let mut d = [[0.0; 3]; K];
    debug_assert!(K <= LANES);
    for &k in list {
        if k >= LANES {
            // Never: callers keep `K ≤ LANES`.
            continue;
        }
        (lambda[k][s], lambda[k][s + 1], lambda[k][a]) = (l0[k], l1[k], la[k]);
        for (i, x) in [(s, d1[k]), (s + 1, d2[k]), (a, da[k])] {
            let x = libm::fabs(x * diag[i]);
            if x > change[k] {
                change[k] = x;
            }
        }
        d[k] = [d1[k], d2[k], da[k]];
    }
    d
}

/// `res[k] += d[k][0] x0 + d[k][1] x1 + d[k][2] x2` over rows `0..m` for every `k` of `list`,
/// solves taken three at a time so that each vector of the three rows of `W` is loaded once for
/// the three residuals: per entry exactly the operations of [`axpy3`], the same result.
#[inline(always)]
fn axpy3_batch<const M: usize, const K: usize>(
    d: &[[f64; 3]; K],
    list: &[usize],
    (x0, x1, x2): (&[f64], &[f64], &[f64]),
    res: &mut [[f64; M]; K],
    m: usize,
) {
    let m = m.min(M).min(x0.len()).min(x1.len()).min(x2.len());
    let (x0, x1, x2) = (&x0[..m], &x1[..m], &x2[..m]);
    let mut it = list.chunks_exact(3);
    for t in &mut it {
        let Ok([ya, yb, yc]) = res.get_disjoint_mut([t[0], t[1], t[2]]) else {
            // Not three distinct solves (never, `list` is): one at a time.
            for &k in t {
                axpy3(d[k], x0, x1, x2, &mut res[k][..m]);
            }
            continue;
        };
        let (da, db, dc) = (d[t[0]], d[t[1]], d[t[2]]);
        let (ya, yb, yc) = (&mut ya[..m], &mut yb[..m], &mut yc[..m]);
        for i in 0..m {
            let (u0, u1, u2) = (x0[i], x1[i], x2[i]);
            ya[i] += da[0] * u0 + da[1] * u1 + da[2] * u2;
            yb[i] += db[0] * u0 + db[1] * u1 + db[2] * u2;
            yc[i] += dc[0] * u0 + dc[1] * u1 + dc[2] * u2;
        }
    }
    let rest = it.remainder();
    if let [a, b] = *rest
        && let Ok([ya, yb]) = res.get_disjoint_mut([a, b])
    {
        let (da, db) = (d[a], d[b]);
        let (ya, yb) = (&mut ya[..m], &mut yb[..m]);
        for i in 0..m {
            let (u0, u1, u2) = (x0[i], x1[i], x2[i]);
            ya[i] += da[0] * u0 + da[1] * u1 + da[2] * u2;
            yb[i] += db[0] * u0 + db[1] * u1 + db[2] * u2;
        }
    } else {
        for &k in rest {
            axpy3(d[k], x0, x1, x2, &mut res[k][..m]);
        }
    }
}

/// A sweep's largest change, NaN-safe: a NaN change must not read as converged.
#[inline(always)]
fn finite_change(change: f64) -> f64 {
    if change.is_nan() {
        f64::INFINITY
    } else {
        change
    }
}

/// Where the solves of [`BlockGs::solve_batch`] start.
#[derive(Clone, Copy, Debug)]
pub(crate) enum BatchStart<'a, const M: usize> {
    /// Every solve from `lambda0`, given its product `W lambda0` ([`BlockGs::product`]), which
    /// saves the `m²` pass of each solve's initial residual (ignored when `lambda0` has a
    /// non-finite entry).
    Shared {
        lambda0: &'a [f64; M],
        product: &'a [f64; M],
    },
    /// Each solve from its own `batch.lambda[k]`, set by the caller (rows `0..m`).
    Own,
}

/// The iterates of `K` solves run together by [`BlockGs::solve_batch`]: each one's `δ` (filled
/// by the caller), its λ and its residual. `3 K M` values: keep it inside an owning struct.
#[derive(Clone, Debug)]
pub(crate) struct GsBatch<const M: usize, const K: usize> {
    /// `δ` of each solve (rows `0..m`).
    pub(crate) delta: [[f64; M]; K],
    /// λ of each solve: the result.
    pub(crate) lambda: [[f64; M]; K],
    /// The residual `w = W λ − δ` of each solve.
    res: [[f64; M]; K],
}

crate::zeroed::impl_zeroable!(GsBatch<const M, const K> { delta, lambda, res });

impl<const M: usize, const K: usize> GsBatch<M, K> {
    /// Zero iterates.
    pub(crate) const fn new() -> Self {
        Self {
            delta: [[0.0; M]; K],
            lambda: [[0.0; M]; K],
            res: [[0.0; M]; K],
        }
    }
}

/// `out[i] = W_i · λ` for rows `0..m`, with the AVX2 copy when the CPU has it (the same
/// operations: the same result).
fn product_rows<const M: usize>(
    w: &[[f64; M]; M],
    lambda: &[f64; M],
    m: usize,
    out: &mut [f64; M],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::math::use_avx2() {
        // SAFETY: AVX2 support was checked at run time.
        unsafe { product_avx2(w, lambda, m, out) };
        return;
    }
    product_inline(w, lambda, m, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn product_avx2<const M: usize>(
    w: &[[f64; M]; M],
    lambda: &[f64; M],
    m: usize,
    out: &mut [f64; M],
) {
    product_inline(w, lambda, m, out);
}

/// `out[k] = W λ_k` over the used rows for the first `count` of `lambdas`, each row's dots
/// exactly [`product_rows`]'s, in one pass over `W`: a row is read once for all of them (from
/// the cache for the others), where `count` separate products would stream `W` `count` times.
fn product_many<const M: usize, const K: usize>(
    w: &[[f64; M]; M],
    lambdas: &[[f64; M]; K],
    count: usize,
    m: usize,
    out: &mut [[f64; M]; K],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::math::use_avx2() {
        // SAFETY: AVX2 support was checked at run time.
        unsafe { product_many_avx2(w, lambdas, count, m, out) };
        return;
    }
    product_many_inline(w, lambdas, count, m, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn product_many_avx2<const M: usize, const K: usize>(
    w: &[[f64; M]; M],
    lambdas: &[[f64; M]; K],
    count: usize,
    m: usize,
    out: &mut [[f64; M]; K],
) {
    product_many_inline(w, lambdas, count, m, out);
}

#[inline(always)]
fn product_many_inline<const M: usize, const K: usize>(
    w: &[[f64; M]; M],
    lambdas: &[[f64; M]; K],
    count: usize,
    m: usize,
    out: &mut [[f64; M]; K],
) {
    let (m, count) = (m.min(M), count.min(K));
    // Each row's `K` dots side by side: the same four partial sums per dot as `dot`, in the
    // same order, the same tail, but `K` independent chains of additions instead of one.
    let whole = m - m % 4;
    for i in 0..m {
        let row = &w[i][..m];
        let mut acc = [[0.0f64; 4]; K];
        let mut c = 0;
        while c < whole {
            let x = &row[c..c + 4];
            for (a, l) in acc.iter_mut().zip(lambdas) {
                let y = &l[c..c + 4];
                a[0] += x[0] * y[0];
                a[1] += x[1] * y[1];
                a[2] += x[2] * y[2];
                a[3] += x[3] * y[3];
            }
            c += 4;
        }
        for k in 0..count {
            let a = &acc[k];
            let mut tail = 0.0;
            for (x, y) in row[whole..].iter().zip(&lambdas[k][whole..m]) {
                tail += x * y;
            }
            out[k][i] = (a[0] + a[2]) + (a[1] + a[3]) + tail;
        }
    }
}

#[inline(always)]
fn product_inline<const M: usize>(
    w: &[[f64; M]; M],
    lambda: &[f64; M],
    m: usize,
    out: &mut [f64; M],
) {
    let m = m.min(M);
    // Four rows at a time: each row's sums are exactly `dot`'s (the same four partial sums in
    // the same order, the same tail), but the four rows' chains of additions are independent,
    // so they overlap instead of each waiting on its own latency.
    // Whole blocks of four: of rows, and of columns within each row (as in `dot`).
    let whole = m - m % 4;
    let mut i = 0;
    while i < whole {
        let rows = [&w[i][..m], &w[i + 1][..m], &w[i + 2][..m], &w[i + 3][..m]];
        let mut acc = [[0.0f64; 4]; 4];
        let mut k = 0;
        while k < whole {
            let y = &lambda[k..k + 4];
            for (a, r) in acc.iter_mut().zip(&rows) {
                let x = &r[k..k + 4];
                a[0] += x[0] * y[0];
                a[1] += x[1] * y[1];
                a[2] += x[2] * y[2];
                a[3] += x[3] * y[3];
            }
            k += 4;
        }
        for (r, (a, row)) in acc.iter().zip(&rows).enumerate() {
            let mut tail = 0.0;
            for (x, y) in row[whole..].iter().zip(&lambda[whole..m]) {
                tail += x * y;
            }
            out[i + r] = (a[0] + a[2]) + (a[1] + a[3]) + tail;
        }
        i += 4;
    }
    for i in whole..m {
        out[i] = dot(&w[i][..m], &lambda[..m]);
    }
}

/// The length of the residual a sweep updates: the `m` used rows rounded up to whole vectors
/// of `lanes` when the capacity `cap` allows. Rows `m..` of the residual are never read, so the
/// vector loops may update them too (with whatever `W` holds there) rather than finish the used
/// rows one by one; rows `..m` get exactly the same operations.
#[inline(always)]
fn padded(m: usize, lanes: usize, cap: usize) -> usize {
    let p = m.next_multiple_of(lanes);
    if p <= cap { p } else { m }
}

/// What one sweep updates: `λ`, the residual `w = W λ − δ` kept in step with it, and the largest
/// `|W_ii Δλ_i|` so far. Each method is the exact local update of one group kind, `f` its packed
/// factors (from `prepare`), `s` its first row.
struct Sweep<'a, const M: usize> {
    w: &'a [[f64; M]; M],
    res: &'a mut [f64; M],
    lambda: &'a mut [f64; M],
    diag: &'a [f64; M],
    /// Rows of the residual updated ([`padded`]).
    m: usize,
    change: f64,
}

impl<const M: usize> Sweep<'_, M> {
    /// Records the change `d` of row `i`. A compare and select rather than `f64::max` (one
    /// `maxsd`, no NaN fix-up): the same result, since `change` starts at 0 and is never NaN,
    /// and a NaN `|W_ii d|` is skipped by both.
    #[inline(always)]
    fn record(&mut self, i: usize, d: f64) {
        let x = libm::fabs(d * self.diag[i]);
        if x > self.change {
            self.change = x;
        }
    }

    /// Bilateral block of `n` rows: `λ_g ← λ_g − ω W_gg⁻¹ w_g`.
    #[inline(always)]
    fn bilateral(&mut self, s: usize, n: usize, f: &[f64], omega: f64) {
        let (w, m) = (self.w, self.m);
        let mut d = [0.0f64; 6];
        for i in 0..n {
            let mut acc = 0.0;
            for j in 0..n {
                acc += f[i * n + j] * self.res[s + j];
            }
            d[i] = -omega * acc;
        }
        for i in 0..n {
            self.lambda[s + i] += d[i];
            self.record(s + i, d[i]);
        }
        let mut i = 0;
        while i < n {
            let r = |k: usize| &w[s + (i + k).min(n - 1)][..m];
            let c = |k: usize| if i + k < n { d[i + k] } else { 0.0 };
            axpy3([c(0), c(1), c(2)], r(0), r(1), r(2), &mut self.res[..m]);
            i += 3;
        }
    }

    /// Unilateral row: `λ ← max(0, λ − ω w / W_ii)`, `inv_diag = 1 / W_ii`.
    #[inline(always)]
    fn unilateral(&mut self, s: usize, inv_diag: f64, omega: f64) {
        let (w, m) = (self.w, self.m);
        let new = (self.lambda[s] - omega * self.res[s] * inv_diag).max(0.0);
        let d = new - self.lambda[s];
        if d != 0.0 {
            self.lambda[s] = new;
            axpy(d, &w[s][..m], &mut self.res[..m]);
            self.record(s, d);
        }
    }

    /// Coulomb contact `[n, t1, t2]`: the normal row as a unilateral row (ω = 1), then the
    /// tangential pair projected exactly onto the disk `|λ_t| ≤ μ λ_n`.
    #[inline(always)]
    fn contact(&mut self, s: usize, mu: f64, f: &[f64]) {
        let (w, m) = (self.w, self.m);
        let lambda = &mut *self.lambda;
        let new_n = (lambda[s] - self.res[s] * f[0]).max(0.0);
        let dn = new_n - lambda[s];
        lambda[s] = new_n;
        let e = Sym2::unpack(&f[1..11]);
        let (t1, t2) = (lambda[s + 1], lambda[s + 2]);
        // w_t after the normal update, minus its λ_t part.
        let g1 = self.res[s + 1] + dn * w[s][s + 1] - (e.a * t1 + e.b * t2);
        let g2 = self.res[s + 2] + dn * w[s][s + 2] - (e.b * t1 + e.c * t2);
        let (x1, x2) = e.disk_minimiser(g1, g2, mu * new_n);
        let (d1, d2) = (x1 - t1, x2 - t2);
        lambda[s + 1] = x1;
        lambda[s + 2] = x2;
        if dn != 0.0 || d1 != 0.0 || d2 != 0.0 {
            axpy3(
                [dn, d1, d2],
                &w[s][..m],
                &w[s + 1][..m],
                &w[s + 2][..m],
                &mut self.res[..m],
            );
        }
        self.record(s, dn);
        self.record(s + 1, d1);
        self.record(s + 2, d2);
    }
}

/// The local update of a group given its rows `r` of the residual: `λ` and the largest change
/// so far (as [`Sweep`], without the residual).
struct Local<'a, const M: usize> {
    w: &'a [[f64; M]; M],
    lambda: &'a mut [f64; M],
    diag: &'a [f64; M],
    change: f64,
}

impl<const M: usize> Local<'_, M> {
    /// As [`Sweep::record`].
    #[inline(always)]
    fn record(&mut self, i: usize, d: f64) {
        let x = libm::fabs(d * self.diag[i]);
        if x > self.change {
            self.change = x;
        }
    }

    /// Sliding point at row `s` whose residual rows are `r`: updates `λ` and the change,
    /// returns the changes `[d1, d2, da]` to apply to the residual (always applied, even all
    /// zero).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn sliding(
        &mut self,
        s: usize,
        mu: f64,
        r0: f64,
        e: &Sym2,
        inv_axial: f64,
        omega: f64,
        r: &[f64; 3],
    ) -> [f64; 3] {
        let w = self.w;
        let lambda = &mut *self.lambda;
        let (d1, d2) = e.solve(-r[0], -r[1]);
        let (d1, d2) = (omega * d1, omega * d2);
        lambda[s] += d1;
        lambda[s + 1] += d2;
        // Plain sqrt, not `hypot` (5× cheaper; overflow would need |λ| > 1e154 N,
        // and an infinite bound still clamps to a finite λ_a).
        let lat = crate::math::sqrt(lambda[s] * lambda[s] + lambda[s + 1] * lambda[s + 1]);
        let bound = mu * lat + r0;
        let a = s + 2;
        // w_a after the lateral update.
        let wa = r[2] + d1 * w[s][a] + d2 * w[s + 1][a];
        let new = (lambda[a] - omega * wa * inv_axial).max(-bound).min(bound);
        let da = new - lambda[a];
        lambda[a] = new;
        self.record(s, d1);
        self.record(s + 1, d2);
        self.record(a, da);
        [d1, d2, da]
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::kinematics::DhChain;
    use crate::payload::ComplianceFrame;
    use crate::synthetic::random_frame;

    /// The product four rows at a time is `dot` row by row, bit for bit, for every `m` (whole
    /// blocks of four and the rows and columns left over), in the dispatched copy and the plain
    /// one.
    #[test]
    fn blocked_product_is_the_rows_dots_bit_for_bit() {
        const M: usize = 24;
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut w = [[0.0; M]; M];
        for row in &mut w {
            for x in row.iter_mut() {
                *x = next() * 1e3;
            }
        }
        let mut lambda = [0.0; M];
        for x in &mut lambda {
            *x = next() * 1e-2;
        }
        for m in 0..=M {
            let mut want = [7.0; M];
            for i in 0..m {
                want[i] = dot(&w[i][..m], &lambda[..m]);
            }
            let (mut plain, mut dispatched) = ([7.0; M], [7.0; M]);
            product_inline(&w, &lambda, m, &mut plain);
            product_rows(&w, &lambda, m, &mut dispatched);
            let mut many = [[7.0; M]; 3];
            let lambdas = [lambda, [0.0; M], lambda];
            product_many(&w, &lambdas, 2, m, &mut many);
            for i in 0..M {
                assert_eq!(plain[i].to_bits(), want[i].to_bits(), "m {m}, row {i}");
                assert_eq!(dispatched[i].to_bits(), want[i].to_bits(), "m {m}, row {i}");
                assert_eq!(many[0][i].to_bits(), want[i].to_bits(), "m {m}, row {i}");
                let zero = if i < m { 0.0 } else { 7.0 };
                assert_eq!(many[1][i].to_bits(), f64::to_bits(zero), "m {m}, row {i}");
                assert_eq!(many[2][i], 7.0, "beyond count: untouched");
            }
        }
    }

    /// `K` solves of a batch against the same solves one at a time, bit for bit: on a frame with
    /// the base block, a tip contact (`with_contact`) and sliding points, `δ`s scaled apart so
    /// that the solves stop at different sweeps (the batch's active set shrinks through 3-, 2-
    /// and 1-solve passes) and some hit the sweep cap.
    fn batch_matches_alone<const K: usize>(m: usize, seed: u64, with_contact: bool) {
        batch_matches_alone_from::<K>(m, seed, with_contact, false);
        batch_matches_alone_from::<K>(m, seed, with_contact, true);
    }

    /// As [`batch_matches_alone`], every solve from the same start or (`own`) each from its
    /// own, one of them with a non-finite entry.
    fn batch_matches_alone_from<const K: usize>(
        m: usize,
        seed: u64,
        with_contact: bool,
        own: bool,
    ) {
        const M: usize = 48;
        let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
        let mut frame = ComplianceFrame::<M>::new_boxed();
        random_frame(&mut frame, &DhChain::rv1a(), &q, m, seed, with_contact);
        let mut gs = BlockGs::<M>::new();
        gs.prepare_frame(&frame).expect("valid frame");
        let rows = frame.rows();
        let mut lambda0 = [0.0; M];
        for i in 0..rows {
            lambda0[i] = 0.01 * ((i * 7 + 3) % 11) as f64;
        }
        let mut product = [0.0; M];
        gs.product(&frame.w, &lambda0, &mut product);
        let params = GsParams {
            tolerance: 1e-7,
            max_iterations: 25,
            polish: false,
            relaxation: 1.2,
        };
        let mut batch = GsBatch::<M, K>::new();
        for k in 0..K {
            let scale = 1.0 + 0.7 * k as f64;
            for i in 0..rows {
                batch.delta[k][i] = frame.delta_free[i] * scale + 0.01 * (k as f64 - 1.0);
            }
        }
        let mut starts = [lambda0; K];
        if own {
            for (k, start) in starts.iter_mut().enumerate() {
                for (i, x) in start[..rows].iter_mut().enumerate() {
                    *x *= 1.0 + 0.3 * k as f64 - 0.01 * i as f64;
                }
            }
            starts[K - 1][rows / 2] = f64::NAN;
            batch.lambda = starts;
        }
        let start = if own {
            BatchStart::Own
        } else {
            BatchStart::Shared {
                lambda0: &lambda0,
                product: &product,
            }
        };
        let reports = gs.solve_batch(&frame.w, start, &mut batch, K, &params);
        let mut sweeps = [0u32; K];
        for k in 0..K {
            let mut lambda = starts[k];
            let given = (!own).then_some(&product);
            let alone = gs.solve_from(&frame.w, &batch.delta[k], &mut lambda, given, &params);
            assert_eq!(reports[k], alone, "report of solve {k}");
            for i in 0..rows {
                assert_eq!(
                    batch.lambda[k][i].to_bits(),
                    lambda[i].to_bits(),
                    "λ[{i}] of solve {k}"
                );
            }
            sweeps[k] = alone.iterations;
        }
        std::println!("K = {K}, m = {rows}, own starts {own}: sweeps {sweeps:?}");
    }

    #[test]
    fn batch_is_bitwise_the_solves_alone() {
        batch_matches_alone::<6>(45, 11, false);
        batch_matches_alone::<6>(45, 5, true);
        batch_matches_alone::<7>(42, 3, true);
        batch_matches_alone::<5>(30, 8, false);
        batch_matches_alone::<2>(45, 2, true);
        batch_matches_alone::<1>(45, 4, false);
    }
}
