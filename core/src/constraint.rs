//! Constraint solve: projected **block** Gauss-Seidel on `w = W λ − δ` (paper §III-D, step 4).
//!
//! Rows come in groups (see [`GroupKind`]); each sweep visits the groups in order and solves each
//! group's local problem exactly with the other groups' forces fixed:
//!
//! * bilateral (1…6 rows, e.g. the 6 needle-base rows): `λ_g ← λ_g − W_gg⁻¹ w_g` (`w_g = 0`);
//! * unilateral row: `λ ← max(0, λ − w / W_ii)`;
//! * contact `[n, t1, t2]` with Coulomb friction: the normal row as a unilateral row, then the
//!   tangential pair as the disk-constrained problem `min ½ xᵀ W_tt x + gᵀ x, |x| ≤ μ λ_n` solved
//!   exactly (a 2-D trust-region problem, secular equation by Newton). Its optimality conditions
//!   are the sliding law (`w_t` opposite to `λ_t` on the disk edge), so fixed points of the sweep
//!   are Coulomb solutions — a Euclidean projection after a `W_tt⁻¹` step would not be;
//! * sliding point `[l1, l2, axial]`: the lateral pair as a bilateral 2×2 block, then the axial
//!   row clamped to `|λ_a| ≤ μ_n |λ_l| + r_0`.
//!
//! The block inverses are computed once per frame by [`BlockGs::prepare`] and reused by every
//! solve of the step. `w` is kept up to date with row updates (`W` symmetric: column = row, a
//! contiguous `axpy`), so one sweep costs `m²` multiply-adds.
//!
//! The stopping test is the largest `|W_ii Δλ_i|` of a sweep relative to the problem scale
//! (`‖δ‖∞`); running out of iterations is reported, not an error. Optionally, when the problem has
//! no friction rows, a **polish** solves the equality system of the active set found by GS
//! (bilateral rows and unilateral rows with `λ > 0`) by conjugate gradients and updates the active
//! set primal-dual style until the LCP conditions hold to round-off; the polish result is kept
//! only if it is feasible, otherwise the GS iterate is returned.

use crate::math::{axpy, axpy3, dot, max_abs, spd_inverse_in_place};
use crate::payload::{
    ComplianceFrame, GroupKind, RowGroup, ValidationError, validate_compliance, validate_groups,
};

/// Tuning of one constraint solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GsParams {
    /// Stop when the largest `|W_ii Δλ_i|` of a sweep is below `tolerance · ‖δ‖∞` [-].
    pub tolerance: f64,
    /// Largest number of sweeps.
    pub max_iterations: u32,
    /// Polish frictionless problems on the active set (see the module docs).
    pub polish: bool,
    /// Over-relaxation ω of the bilateral, unilateral and sliding updates (projected SOR;
    /// 1 = plain Gauss-Seidel, useful range 1…1.5). The fixed point — the solution — does not
    /// depend on ω; contact (Coulomb) groups always use ω = 1.
    pub relaxation: f64,
}

impl Default for GsParams {
    fn default() -> Self {
        Self {
            tolerance: 1e-7,
            max_iterations: 400,
            polish: false,
            relaxation: 1.0,
        }
    }
}

/// Outcome of one constraint solve.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SolveReport {
    /// Sweeps performed.
    pub iterations: u32,
    /// Largest `|W_ii Δλ_i|` of the last sweep over the problem scale [-] (0 after a polish).
    pub residual: f64,
    /// Whether the tolerance was reached (or the polish succeeded).
    pub converged: bool,
    /// Whether the result comes from the active-set polish.
    pub polished: bool,
}

const KIND_BILATERAL: u8 = 1;
const KIND_UNILATERAL: u8 = 2;
const KIND_CONTACT: u8 = 3;
const KIND_SLIDING: u8 = 4;

#[derive(Clone, Copy, Debug, Default)]
struct Block {
    kind: u8,
    len: u8,
    start: u32,
    mu: f64,
    r0: f64,
}

/// Projected block Gauss-Seidel solver with capacity `M` rows; owns the per-frame block factors
/// and the solve scratch (no allocation).
#[derive(Clone, Debug)]
pub struct BlockGs<const M: usize> {
    m: usize,
    n_blocks: usize,
    frictional: bool,
    blocks: [Block; M],
    /// Per block, at row `start`: packed factors (≤ 6 values per row of the block).
    factors: [[f64; 6]; M],
    diag: [f64; M],
    w: [f64; M],
    scratch: [[f64; M]; 4],
    active: [u8; M],
}

crate::zeroed::impl_zeroable!(GsParams {
    tolerance,
    max_iterations,
    polish,
    relaxation
});
crate::zeroed::impl_zeroable!(Block {
    kind,
    len,
    start,
    mu,
    r0
});
crate::zeroed::impl_zeroable!(BlockGs<const M> {
    m,
    n_blocks,
    frictional,
    blocks,
    factors,
    diag,
    w,
    scratch,
    active,
});

impl<const M: usize> Default for BlockGs<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const M: usize> BlockGs<M> {
    /// An empty solver (no frame prepared: solves return at once).
    pub const fn new() -> Self {
        Self {
            m: 0,
            n_blocks: 0,
            frictional: false,
            blocks: [Block {
                kind: 0,
                len: 0,
                start: 0,
                mu: 0.0,
                r0: 0.0,
            }; M],
            factors: [[0.0; 6]; M],
            diag: [0.0; M],
            w: [0.0; M],
            scratch: [[0.0; M]; 4],
            active: [0; M],
        }
    }

    /// Rows of the prepared problem.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// Validates a frame ([`ComplianceFrame::validate`]) and prepares its block factors.
    ///
    /// # Errors
    /// The frame's validation error.
    pub fn prepare_frame(&mut self, frame: &ComplianceFrame<M>) -> Result<(), ValidationError> {
        frame.validate()?;
        self.prepare_unchecked(&frame.w, frame.rows(), frame.used_groups());
        Ok(())
    }

    /// Validates a group table and the used block of `w`, then factors every diagonal block.
    /// Unlike a frame, the table need not start with the 6 base rows.
    ///
    /// # Errors
    /// A [`ValidationError`] for an inconsistent table or a bad `w`.
    pub fn prepare(
        &mut self,
        w: &[[f64; M]; M],
        m: usize,
        groups: &[RowGroup],
    ) -> Result<(), ValidationError> {
        self.m = 0;
        self.n_blocks = 0;
        validate_groups(groups, m, M, false)?;
        validate_compliance(w, m)?;
        self.prepare_unchecked(w, m, groups);
        Ok(())
    }

    fn prepare_unchecked(&mut self, w: &[[f64; M]; M], m: usize, groups: &[RowGroup]) {
        self.m = m.min(M);
        self.n_blocks = groups.len().min(M);
        self.frictional = false;
        for i in 0..self.m {
            self.diag[i] = w[i][i];
        }
        for (b, g) in self.blocks.iter_mut().zip(groups) {
            *b = Block {
                kind: g.kind as u8,
                len: g.len as u8,
                start: g.start,
                mu: g.mu,
                r0: g.r0,
            };
            let s = g.start as usize;
            let f = self.factors[s..].as_flattened_mut();
            match GroupKind::from_raw(g.kind) {
                Some(GroupKind::Bilateral) => {
                    let n = g.len as usize;
                    for i in 0..n {
                        for j in 0..n {
                            f[i * n + j] = w[s + i][s + j];
                        }
                    }
                    spd_inverse_in_place(&mut f[..n * n], n);
                }
                Some(GroupKind::Unilateral) => f[0] = 1.0 / w[s][s],
                Some(GroupKind::Contact) => {
                    self.frictional = true;
                    f[0] = 1.0 / w[s][s];
                    let (a, bb, c) = (w[s + 1][s + 1], w[s + 1][s + 2], w[s + 2][s + 2]);
                    let e = Sym2::new(a, bb, c);
                    f[1..11].copy_from_slice(&e.pack());
                }
                Some(GroupKind::Sliding) => {
                    let e = Sym2::new(w[s][s], w[s][s + 1], w[s + 1][s + 1]);
                    f[0..10].copy_from_slice(&e.pack());
                    f[10] = 1.0 / w[s + 2][s + 2];
                }
                None => {}
            }
        }
    }

    /// Solves `w = W λ − δ` under the group laws, warm-starting from `lambda`, which receives the
    /// result. `w` must be the matrix given to the last `prepare`; rows `m..` are left untouched.
    /// Never loops unbounded; finite input gives finite output.
    pub fn solve(
        &mut self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
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
        for i in 0..m {
            if !lambda[i].is_finite() {
                lambda[i] = 0.0;
            }
            scale = scale.max(libm::fabs(self.diag[i] * lambda[i]));
        }
        self.residual_dispatch(w, delta, lambda);
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

    /// `w = W λ − δ` over the used rows, with the AVX2 copy when available.
    fn residual_dispatch(&mut self, w: &[[f64; M]; M], delta: &[f64; M], lambda: &[f64; M]) {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            unsafe { self.residual_avx2(w, delta, lambda) };
            return;
        }
        self.residual_inline(w, delta, lambda);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn residual_avx2(&mut self, w: &[[f64; M]; M], delta: &[f64; M], lambda: &[f64; M]) {
        self.residual_inline(w, delta, lambda);
    }

    #[inline(always)]
    fn residual_inline(&mut self, w: &[[f64; M]; M], delta: &[f64; M], lambda: &[f64; M]) {
        let m = self.m;
        for i in 0..m {
            self.w[i] = dot(&w[i][..m], &lambda[..m]) - delta[i];
        }
    }

    /// One sweep, with the AVX2 copy of the loops when the CPU has it (same arithmetic, so
    /// the same result up to the order of the additions inside `dot`).
    fn sweep_dispatch(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { self.sweep_avx2(w, lambda, omega) };
        }
        self.sweep(w, lambda, omega)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn sweep_avx2(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        self.sweep(w, lambda, omega)
    }

    /// One sweep over every group; returns the largest `|W_ii Δλ_i|`. Each group computes its
    /// update from its own diagonal block, then applies it to `w` in one fused pass over the
    /// group's rows of `W` (one read-modify-write of `w` per group, not per row).
    #[inline(always)]
    fn sweep(&mut self, w: &[[f64; M]; M], lambda: &mut [f64; M], omega: f64) -> f64 {
        let m = self.m;
        let mut change = 0.0f64;
        for bi in 0..self.n_blocks {
            let b = self.blocks[bi];
            let s = b.start as usize;
            let f = self.factors[s..].as_flattened();
            match b.kind {
                KIND_BILATERAL => {
                    let n = b.len as usize;
                    let mut d = [0.0f64; 6];
                    for i in 0..n {
                        let mut acc = 0.0;
                        for j in 0..n {
                            acc += f[i * n + j] * self.w[s + j];
                        }
                        d[i] = -omega * acc;
                    }
                    for i in 0..n {
                        lambda[s + i] += d[i];
                        change = change.max(libm::fabs(d[i] * self.diag[s + i]));
                    }
                    let mut i = 0;
                    while i < n {
                        let r = |k: usize| &w[s + (i + k).min(n - 1)][..m];
                        let c = |k: usize| if i + k < n { d[i + k] } else { 0.0 };
                        axpy3([c(0), c(1), c(2)], r(0), r(1), r(2), &mut self.w[..m]);
                        i += 3;
                    }
                }
                KIND_UNILATERAL => {
                    let new = (lambda[s] - omega * self.w[s] * f[0]).max(0.0);
                    let d = new - lambda[s];
                    if d != 0.0 {
                        lambda[s] = new;
                        axpy(d, &w[s][..m], &mut self.w[..m]);
                        change = change.max(libm::fabs(d * self.diag[s]));
                    }
                }
                KIND_CONTACT => {
                    let new_n = (lambda[s] - self.w[s] * f[0]).max(0.0);
                    let dn = new_n - lambda[s];
                    lambda[s] = new_n;
                    let e = Sym2::unpack(&f[1..11]);
                    let (t1, t2) = (lambda[s + 1], lambda[s + 2]);
                    // w_t after the normal update, minus its λ_t part.
                    let g1 = self.w[s + 1] + dn * w[s][s + 1] - (e.a * t1 + e.b * t2);
                    let g2 = self.w[s + 2] + dn * w[s][s + 2] - (e.b * t1 + e.c * t2);
                    let (x1, x2) = e.disk_minimiser(g1, g2, b.mu * new_n);
                    let (d1, d2) = (x1 - t1, x2 - t2);
                    lambda[s + 1] = x1;
                    lambda[s + 2] = x2;
                    if dn != 0.0 || d1 != 0.0 || d2 != 0.0 {
                        axpy3(
                            [dn, d1, d2],
                            &w[s][..m],
                            &w[s + 1][..m],
                            &w[s + 2][..m],
                            &mut self.w[..m],
                        );
                    }
                    change = change.max(libm::fabs(dn * self.diag[s]));
                    change = change.max(libm::fabs(d1 * self.diag[s + 1]));
                    change = change.max(libm::fabs(d2 * self.diag[s + 2]));
                }
                KIND_SLIDING => {
                    let e = Sym2::unpack(&f[0..10]);
                    let (d1, d2) = e.solve(-self.w[s], -self.w[s + 1]);
                    let (d1, d2) = (omega * d1, omega * d2);
                    lambda[s] += d1;
                    lambda[s + 1] += d2;
                    // Plain sqrt, not `hypot` (5× cheaper; overflow would need |λ| > 1e154 N,
                    // and an infinite bound still clamps to a finite λ_a).
                    let lat = libm::sqrt(lambda[s] * lambda[s] + lambda[s + 1] * lambda[s + 1]);
                    let bound = b.mu * lat + b.r0;
                    let a = s + 2;
                    // w_a after the lateral update.
                    let wa = self.w[a] + d1 * w[s][a] + d2 * w[s + 1][a];
                    let new = (lambda[a] - omega * wa * f[10]).max(-bound).min(bound);
                    let da = new - lambda[a];
                    lambda[a] = new;
                    axpy3(
                        [d1, d2, da],
                        &w[s][..m],
                        &w[s + 1][..m],
                        &w[a][..m],
                        &mut self.w[..m],
                    );
                    change = change.max(libm::fabs(d1 * self.diag[s]));
                    change = change.max(libm::fabs(d2 * self.diag[s + 1]));
                    change = change.max(libm::fabs(da * self.diag[a]));
                }
                _ => {}
            }
        }
        // NaN-safe: a NaN change must not read as converged.
        if change.is_nan() {
            f64::INFINITY
        } else {
            change
        }
    }

    /// Active-set polish of a frictionless problem (primal-dual active set + CG). Returns `true`
    /// and overwrites `lambda` when a feasible solution to round-off was found.
    fn polish(
        &mut self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        scale: f64,
    ) -> bool {
        let m = self.m;
        let mut row_kind = [0u8; M];
        for b in &self.blocks[..self.n_blocks] {
            for r in 0..b.len as usize {
                let i = b.start as usize + r;
                if i < m {
                    row_kind[i] = b.kind;
                }
            }
        }
        for i in 0..m {
            self.active[i] =
                u8::from(row_kind[i] != KIND_UNILATERAL || lambda[i] > 0.0 || self.w[i] < 0.0);
        }
        let [x, r, p, ap] = &mut self.scratch;
        for _round in 0..12 {
            // CG on W_AA x_A = δ_A, x_I = 0, from the current λ.
            for i in 0..m {
                x[i] = if self.active[i] != 0 { lambda[i] } else { 0.0 };
            }
            let mut rr = 0.0;
            for i in 0..m {
                r[i] = if self.active[i] != 0 {
                    delta[i] - dot(&w[i][..m], &x[..m])
                } else {
                    0.0
                };
                p[i] = r[i];
                rr += r[i] * r[i];
            }
            let bnorm = dot(&delta[..m], &delta[..m]).max(f64::MIN_POSITIVE);
            let cap = 10 * m + 50;
            let mut k = 0;
            while k < cap && rr > 1e-32 * bnorm {
                for i in 0..m {
                    ap[i] = if self.active[i] != 0 {
                        dot(&w[i][..m], &p[..m])
                    } else {
                        0.0
                    };
                }
                let pap = dot(&p[..m], &ap[..m]);
                if !(pap > 0.0) {
                    break;
                }
                let alpha = rr / pap;
                axpy(alpha, &p[..m], &mut x[..m]);
                axpy(-alpha, &ap[..m], &mut r[..m]);
                let rr_new = dot(&r[..m], &r[..m]);
                let beta = rr_new / rr;
                for i in 0..m {
                    p[i] = r[i] + beta * p[i];
                }
                rr = rr_new;
                k += 1;
            }
            // Complementarity check and active-set update.
            let tol = 1e-13 * scale;
            let mut changed = false;
            let mut feasible = true;
            for i in 0..m {
                if !x[i].is_finite() {
                    return false;
                }
                if row_kind[i] != KIND_UNILATERAL {
                    continue;
                }
                let wi = dot(&w[i][..m], &x[..m]) - delta[i];
                if self.active[i] != 0 {
                    if x[i] < 0.0 {
                        feasible = false;
                        self.active[i] = 0;
                        changed = true;
                    }
                } else if wi < -tol {
                    feasible = false;
                    self.active[i] = 1;
                    changed = true;
                }
            }
            if feasible {
                lambda[..m].copy_from_slice(&x[..m]);
                for i in 0..m {
                    self.w[i] = dot(&w[i][..m], &lambda[..m]) - delta[i];
                }
                return true;
            }
            if !changed {
                return false;
            }
        }
        false
    }

    /// The residual `w = W λ − δ` of the last solve (rows `0..m`).
    pub fn last_residual(&self) -> &[f64] {
        &self.w[..self.m]
    }

    /// Sorts the rows by what `lambda` does with them: *free* rows (bilateral rows,
    /// unilateral/normal rows with `λ > 0`, sticking tangential rows, axial rows strictly inside
    /// their bound), *tied* rows (axial rows on their bound: `λ_a = ±(μ_n |λ_l| + r_0)` follows
    /// the lateral rows) and *held* rows (the rest: zero, or a sliding contact's tangential
    /// force, kept at its current value).
    fn classify(&self, lambda: &[f64; M], set: &mut ActiveSet<M>) {
        let inside = |x: f64, bound: f64| x < bound * (1.0 - 1e-9);
        set.n = 0;
        set.n_tied = 0;
        let push = |set: &mut ActiveSet<M>, row: usize| {
            set.rows[set.n] = row as u32;
            set.n += 1;
        };
        for b in &self.blocks[..self.n_blocks] {
            let s = b.start as usize;
            match b.kind {
                KIND_BILATERAL => (0..b.len as usize).for_each(|i| push(set, s + i)),
                KIND_UNILATERAL if lambda[s] > 0.0 => push(set, s),
                KIND_CONTACT if lambda[s] > 0.0 => {
                    push(set, s);
                    let t = libm::hypot(lambda[s + 1], lambda[s + 2]);
                    if inside(t, b.mu * lambda[s]) {
                        push(set, s + 1);
                        push(set, s + 2);
                    }
                }
                KIND_SLIDING => {
                    let k = set.n;
                    push(set, s);
                    push(set, s + 1);
                    let lat = libm::hypot(lambda[s], lambda[s + 1]);
                    let bound = b.mu * lat + b.r0;
                    if inside(libm::fabs(lambda[s + 2]), bound) {
                        push(set, s + 2);
                    } else if lat > 0.0 {
                        let sigma = if lambda[s + 2] < 0.0 { -1.0 } else { 1.0 };
                        let c = sigma * b.mu / lat;
                        set.tied[set.n_tied] = Tied {
                            row: (s + 2) as u32,
                            lat: k as u32,
                            c: [c * lambda[s], c * lambda[s + 1]],
                        };
                        set.n_tied += 1;
                    }
                }
                _ => {}
            }
        }
    }

    /// Factors the linearised problem of the rows `lambda` leaves free: with `u = dλ_F`,
    /// `K u = dδ_F`, `K = W_FF + W_FT G` where `G` gives the tied axial rows' change from their
    /// lateral rows (`dλ_a = ±μ_n λ̂_l · dλ_l`). `K` is not symmetric: dense LU with partial
    /// pivoting (`2n³/3`). Also computes the free rows' response to the 6 base rows,
    /// `Z = K⁻¹ E_base` (rows 0..6 must be bilateral and first, as in a frame). Returns `false`
    /// (set invalid) when `K` is numerically singular or the base rows are not free.
    pub fn factor_active_set(
        &self,
        w: &[[f64; M]; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { self.factor_avx2(w, lambda, set) };
        }
        self.factor_inline(w, lambda, set)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn factor_avx2(
        &self,
        w: &[[f64; M]; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        self.factor_inline(w, lambda, set)
    }

    #[inline(always)]
    fn factor_inline(&self, w: &[[f64; M]; M], lambda: &[f64; M], set: &mut ActiveSet<M>) -> bool {
        set.valid = false;
        self.classify(lambda, set);
        let n = set.n;
        if n < BASE || (0..BASE).any(|i| set.rows[i] as usize != i) {
            return false;
        }
        let mut kmax = 0.0f64;
        for i in 0..n {
            let ri = set.rows[i] as usize;
            let k = &mut set.lu[i];
            for j in 0..n {
                k[j] = w[ri][set.rows[j] as usize];
            }
            for t in &set.tied[..set.n_tied] {
                let wa = w[ri][t.row as usize];
                k[t.lat as usize] += t.c[0] * wa;
                k[t.lat as usize + 1] += t.c[1] * wa;
            }
            kmax = kmax.max(max_abs(&k[..n]));
        }
        // Right-looking LU, row-major, rows swapped physically.
        for k in 0..n {
            let mut p = k;
            let mut best = libm::fabs(set.lu[k][k]);
            for i in (k + 1)..n {
                let v = libm::fabs(set.lu[i][k]);
                if v > best {
                    best = v;
                    p = i;
                }
            }
            if !(best > 1e-14 * kmax) {
                return false;
            }
            set.perm[k] = p as u32;
            if p != k {
                set.lu.swap(p, k);
            }
            let (top, bottom) = set.lu.split_at_mut(k + 1);
            let pivot_row = &top[k];
            let inv = 1.0 / pivot_row[k];
            for row in bottom[..n - k - 1].iter_mut() {
                let l = row[k] * inv;
                row[k] = l;
                if l != 0.0 {
                    axpy(-l, &pivot_row[k + 1..n], &mut row[k + 1..n]);
                }
            }
        }
        for c in 0..BASE {
            let x = &mut set.x;
            x[..n].fill(0.0);
            x[c] = 1.0;
            lu_solve(&set.lu, &set.perm, n, x);
            for k in 0..n {
                set.response[k][c] = x[k];
            }
        }
        set.valid = set.response[..n]
            .iter()
            .all(|z| z.iter().all(|v| v.is_finite()));
        set.valid
    }

    /// One Newton step on the free and tied rows of `set` from `lambda` (held rows fixed):
    /// `u = K⁻¹ (δ_F − (W λ)_F)`, `λ_F += u`, then each tied row is put back exactly on its bound
    /// `±(μ_n |λ_l| + r_0)`. From a Gauss-Seidel iterate with the right statuses this lands on the
    /// solution to round-off (the bound is the only nonlinearity). Returns `false` when the set
    /// is invalid or the step is not finite (then `lambda` is unchanged).
    pub fn refine_on_active_set(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        if !set.valid {
            return false;
        }
        let (n, m) = (set.n, self.m);
        for k in 0..n {
            let r = set.rows[k] as usize;
            set.x[k] = delta[r] - dot(&w[r][..m], &lambda[..m]);
        }
        lu_solve(&set.lu, &set.perm, n, &mut set.x);
        if !set.x[..n].iter().all(|v| v.is_finite()) {
            return false;
        }
        for k in 0..n {
            lambda[set.rows[k] as usize] += set.x[k];
        }
        for t in &set.tied[..set.n_tied] {
            let a = t.row as usize;
            let l = set.rows[t.lat as usize] as usize;
            let (mu, r0) = self.sliding_law(a);
            let sigma = if lambda[a] < 0.0 { -1.0 } else { 1.0 };
            lambda[a] = sigma * (mu * libm::hypot(lambda[l], lambda[l + 1]) + r0);
        }
        true
    }

    /// `(μ_n, r_0)` of the sliding group owning axial row `a`.
    fn sliding_law(&self, a: usize) -> (f64, f64) {
        self.blocks[..self.n_blocks]
            .iter()
            .find(|b| b.kind == KIND_SLIDING && b.start as usize + 2 == a)
            .map_or((0.0, 0.0), |b| (b.mu, b.r0))
    }

    /// Linear prediction of the solution after the base-row violation changes by `d_base`:
    /// `λ_F = λ_ref,F + Z d_base`, tied rows follow their lateral rows, held rows unchanged
    /// (exact to first order while no row changes status). Returns `false` when the set is
    /// invalid (then `out = λ_ref`).
    pub fn predict_base_change(
        &self,
        set: &ActiveSet<M>,
        lambda_ref: &[f64; M],
        d_base: &[f64; BASE],
        out: &mut [f64; M],
    ) -> bool {
        let m = self.m;
        out[..m].copy_from_slice(&lambda_ref[..m]);
        if !set.valid {
            return false;
        }
        let mut du = [0.0f64; M];
        for k in 0..set.n {
            let z = &set.response[k];
            let mut acc = 0.0;
            for c in 0..BASE {
                acc += z[c] * d_base[c];
            }
            du[k] = acc;
            out[set.rows[k] as usize] += acc;
        }
        for t in &set.tied[..set.n_tied] {
            let l = t.lat as usize;
            out[t.row as usize] += t.c[0] * du[l] + t.c[1] * du[l + 1];
        }
        true
    }
}

const BASE: usize = crate::payload::BASE_ROWS;

/// Solves `K x = b` in place from the LU factors (`P K = L U`, `L` unit lower and `U` upper
/// stored together row-major, `perm[k]` the row swapped with `k` at step `k`).
fn lu_solve<const M: usize>(lu: &[[f64; M]; M], perm: &[u32; M], n: usize, x: &mut [f64; M]) {
    for k in 0..n {
        x.swap(k, perm[k] as usize);
    }
    for i in 0..n {
        x[i] -= dot(&lu[i][..i], &x[..i]);
    }
    // Column-oriented back substitution would need columns of U; rows are contiguous, so
    // solve row by row from the bottom.
    for i in (0..n).rev() {
        let s = dot(&lu[i][i + 1..n], &x[i + 1..n]);
        x[i] = (x[i] - s) / lu[i][i];
    }
}

/// A tied axial row: `dλ_row = c · dλ_(lat, lat+1)` (indices of the lateral rows in the free set).
#[derive(Clone, Copy, Debug, Default)]
struct Tied {
    row: u32,
    lat: u32,
    c: [f64; 2],
}

/// Dense LU factor of the linearised problem of the rows a solve left free (tied sliding rows
/// folded in) and their linear response to the 6 base rows
/// ([`BlockGs::factor_active_set`]). `M × M` storage (≈ `8 M²` bytes): keep it inside an
/// owning struct that lives in a `static` or a `Box`.
///
/// Within one inverse step only the base rows' violation changes; while no row changes status
/// the solution follows it affinely to first order, `λ(δ_b) ≈ λ_q + Z (δ_b − δ_b(q))`. The
/// inverse step uses this to start each perturbed solve next to its answer, so Gauss-Seidel
/// only has to confirm it (or repair a status change).
#[derive(Clone, Debug)]
pub struct ActiveSet<const M: usize> {
    n: usize,
    n_tied: usize,
    valid: bool,
    rows: [u32; M],
    perm: [u32; M],
    tied: [Tied; M],
    lu: [[f64; M]; M],
    response: [[f64; BASE]; M],
    x: [f64; M],
}

crate::zeroed::impl_zeroable!(Tied { row, lat, c });
crate::zeroed::impl_zeroable!(ActiveSet<const M> {
    n,
    n_tied,
    valid,
    rows,
    perm,
    tied,
    lu,
    response,
    x,
});

impl<const M: usize> Default for ActiveSet<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const M: usize> ActiveSet<M> {
    /// An empty (invalid) set.
    pub const fn new() -> Self {
        Self {
            n: 0,
            n_tied: 0,
            valid: false,
            rows: [0; M],
            perm: [0; M],
            tied: [Tied {
                row: 0,
                lat: 0,
                c: [0.0; 2],
            }; M],
            lu: [[0.0; M]; M],
            response: [[0.0; BASE]; M],
            x: [0.0; M],
        }
    }

    /// Number of free rows of the last factorisation.
    pub fn free_rows(&self) -> usize {
        self.n
    }

    /// Number of tied (friction-saturated axial) rows of the last factorisation.
    pub fn tied_rows(&self) -> usize {
        self.n_tied
    }

    /// Whether the last factorisation succeeded.
    pub fn is_valid(&self) -> bool {
        self.valid
    }
}

/// A symmetric 2×2 block `[[a, b], [b, c]]` with its eigen-decomposition (eigenvalues floored at
/// `1e-13 ·` the largest, so that solves stay finite on singular blocks).
#[derive(Clone, Copy, Debug)]
struct Sym2 {
    a: f64,
    b: f64,
    c: f64,
    l1: f64,
    l2: f64,
    cs: f64,
    sn: f64,
}

impl Sym2 {
    fn new(a: f64, b: f64, c: f64) -> Self {
        let th = 0.5 * libm::atan2(2.0 * b, a - c);
        let (sn, cs) = libm::sincos(th);
        let l1 = a * cs * cs + 2.0 * b * cs * sn + c * sn * sn;
        let l2 = a * sn * sn - 2.0 * b * cs * sn + c * cs * cs;
        let floor = 1e-13 * l1.max(l2).max(f64::MIN_POSITIVE);
        Self {
            a,
            b,
            c,
            l1: l1.max(floor),
            l2: l2.max(floor),
            cs,
            sn,
        }
    }

    fn pack(&self) -> [f64; 10] {
        [
            self.a, self.b, self.c, self.l1, self.l2, self.cs, self.sn, 0.0, 0.0, 0.0,
        ]
    }

    fn unpack(f: &[f64]) -> Self {
        Self {
            a: f[0],
            b: f[1],
            c: f[2],
            l1: f[3],
            l2: f[4],
            cs: f[5],
            sn: f[6],
        }
    }

    /// Solves `A x = (r1, r2)` through the (floored) eigen-decomposition.
    #[inline]
    fn solve(&self, r1: f64, r2: f64) -> (f64, f64) {
        let (u1, u2) = (self.cs * r1 + self.sn * r2, -self.sn * r1 + self.cs * r2);
        let (y1, y2) = (u1 / self.l1, u2 / self.l2);
        (self.cs * y1 - self.sn * y2, self.sn * y1 + self.cs * y2)
    }

    /// `argmin ½ xᵀ A x + gᵀ x` subject to `|x| ≤ rho` (2-D trust-region problem).
    fn disk_minimiser(&self, g1: f64, g2: f64, rho: f64) -> (f64, f64) {
        if !(rho > 0.0) {
            return (0.0, 0.0);
        }
        let (h1, h2) = (self.cs * g1 + self.sn * g2, -self.sn * g1 + self.cs * g2);
        let norm = |nu: f64| libm::hypot(h1 / (self.l1 + nu), h2 / (self.l2 + nu));
        let (mut y1, mut y2);
        if norm(0.0) <= rho {
            y1 = -h1 / self.l1;
            y2 = -h2 / self.l2;
        } else {
            // Newton on φ(ν) = 1/|x(ν)| − 1/ρ (Moré–Sorensen): increasing and concave, so the
            // iterates rise monotonically to the root from ν = 0.
            let mut nu = 0.0f64;
            for _ in 0..60 {
                let (a1, a2) = (self.l1 + nu, self.l2 + nu);
                let (z1, z2) = (h1 / a1, h2 / a2);
                let n2 = z1 * z1 + z2 * z2;
                let n = libm::sqrt(n2);
                let phi = 1.0 / n - 1.0 / rho;
                let dphi = (z1 * z1 / a1 + z2 * z2 / a2) / (n2 * n);
                if !(dphi > 0.0) {
                    break;
                }
                let step = phi / dphi;
                nu -= step;
                if !(nu >= 0.0) {
                    nu = 0.0;
                }
                if libm::fabs(step) <= 1e-15 * (nu + self.l1.max(self.l2)) {
                    break;
                }
            }
            y1 = -h1 / (self.l1 + nu);
            y2 = -h2 / (self.l2 + nu);
            let n = libm::hypot(y1, y2);
            if n > rho && n > 0.0 {
                y1 *= rho / n;
                y2 *= rho / n;
            }
        }
        if !(y1.is_finite() && y2.is_finite()) {
            return (0.0, 0.0);
        }
        (self.cs * y1 - self.sn * y2, self.sn * y1 + self.cs * y2)
    }
}
