//! The active set of a solution: which rows are free, tied to a friction bound or held, the
//! dense LU factor of the free rows' linearised problem and their response `Z` to the base rows
//! — used to refine a Gauss-Seidel iterate to round-off and to predict how the solution follows
//! a change of the base rows.

use super::{BASE, BlockGs, KIND_BILATERAL, KIND_CONTACT, KIND_SLIDING, KIND_UNILATERAL};
use crate::math::{axpy, dot, max_abs};

/// A status correction of [`BlockGs::correct_statuses`].
#[derive(Clone, Copy, Debug)]
enum Fix {
    /// Every force of the group to zero.
    Close,
    /// The normal force to the smallest positive value (free at the next factor).
    Open,
    /// The tangential pair scaled onto the friction disk.
    Scale(f64),
    /// The axial force to this value.
    Axial(f64),
}

/// A tied row: `dλ_row = c · dλ_(lat, lat+1)` (indices of free variables): an axial row on its
/// bound follows its two lateral rows; a sliding contact's tangential row follows its normal
/// row and its slip angle.
#[derive(Clone, Copy, Debug, Default)]
struct Tied {
    row: u32,
    lat: u32,
    c: [f64; 2],
}

/// A sliding Coulomb contact (tangential pair on its disk `|λ_t| = μ λ_n`): its pair is
/// `λ_t = μ λ_n û(θ)`, so its free variables are the normal force and the slip angle, the latter
/// as `φ = μ λ_n dθ` (variable `var`, a force). Its equation is the sliding law's: the pair's
/// residual `w_t` has no component along `û⊥` (it opposes `û`). Linearised about the current
/// pair: `dλ_t = μ û dλ_n + û⊥ φ`, and `d(w_t · û⊥) = (W dλ)_t · û⊥ + ν φ` with
/// `ν = −(w_t · û) / (μ λ_n) ≥ 0` (the slip rate over the force: the angle's own stiffness).
#[derive(Clone, Copy, Debug, Default)]
struct Slide {
    /// First row of the contact (its normal row).
    start: u32,
    /// Index of the angle variable among the free variables.
    var: u32,
    /// The pair's direction `û` when classified.
    u: [f64; 2],
    /// `μ λ_n` when classified (the pair's length).
    radius: f64,
    /// `μ`.
    mu: f64,
}

/// Dense LU factor of the linearised problem of the rows a solve left free (tied rows folded
/// in: axial rows on their bound, and the pairs of sliding contacts, whose slip angles are free
/// variables of their own) and their linear response to the 6 base rows
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
    /// The LU factor of the last factorisation succeeded.
    factored: bool,
    /// ... and the response `Z` to the base rows is computed and finite.
    valid: bool,
    rows: [u32; M],
    perm: [u32; M],
    tied: [Tied; M],
    n_slides: usize,
    slides: [Slide; M],
    /// Free variable `k` is a sliding contact's angle (`rows[k]` is then its first tangential
    /// row, not a row of λ).
    angle: [bool; M],
    lu: [[f64; M]; M],
    response: [[f64; BASE]; M],
    x: [f64; M],
}

crate::zeroed::impl_zeroable!(Tied { row, lat, c });
crate::zeroed::impl_zeroable!(Slide {
    start,
    var,
    u,
    radius,
    mu
});
crate::zeroed::impl_zeroable!(ActiveSet<const M> {
    n,
    n_tied,
    factored,
    valid,
    rows,
    perm,
    tied,
    n_slides,
    slides,
    angle,
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
            factored: false,
            valid: false,
            rows: [0; M],
            perm: [0; M],
            tied: [Tied {
                row: 0,
                lat: 0,
                c: [0.0; 2],
            }; M],
            n_slides: 0,
            slides: [Slide {
                start: 0,
                var: 0,
                u: [0.0; 2],
                radius: 0.0,
                mu: 0.0,
            }; M],
            angle: [false; M],
            lu: [[0.0; M]; M],
            response: [[0.0; BASE]; M],
            x: [0.0; M],
        }
    }

    /// Number of free rows of the last factorisation.
    pub fn free_rows(&self) -> usize {
        self.n
    }

    /// Number of tied rows of the last factorisation (friction-saturated axial rows, sliding
    /// contacts' tangential rows).
    pub fn tied_rows(&self) -> usize {
        self.n_tied
    }

    /// Whether the last factorisation succeeded and its response `Z` to the base rows is known
    /// (the active-set methods' rounds factor without it: [`Self::complete_response`]).
    pub fn is_valid(&self) -> bool {
        self.valid
    }

    /// Computes the response `Z = K⁻¹ E_base` of the last factorisation when it is not yet
    /// known (after [`BlockGs::solve_on_active_sets`] or
    /// [`BlockGs::solve_on_active_sets_feasible`], whose rounds need only the factor);
    /// returns [`Self::is_valid`].
    pub fn complete_response(&mut self) -> bool {
        if self.valid || !self.factored {
            return self.valid;
        }
        let n = self.n;
        for c in 0..BASE {
            let x = &mut self.x;
            x[..n].fill(0.0);
            x[c] = 1.0;
            lu_solve(&self.lu, &self.perm, n, x);
            for k in 0..n {
                self.response[k][c] = x[k];
            }
        }
        self.valid = self.response[..n]
            .iter()
            .all(|z| z.iter().all(|v| v.is_finite()));
        self.valid
    }

    /// A fingerprint of the last factorisation's statuses (which rows are free, which tied), to
    /// tell two rounds' sets apart (FNV-1a over the row indices).
    fn statuses(&self) -> u64 {
        let free = self.rows[..self.n].iter();
        let tied = self.tied[..self.n_tied].iter().map(|t| &t.row);
        let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ self.n as u64;
        for r in free.chain(core::iter::once(&u32::MAX)).chain(tied) {
            h ^= u64::from(*r);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h
    }
}

impl<const M: usize> BlockGs<M> {
    /// Sorts the rows by what `lambda` does with them: *free* rows (bilateral rows,
    /// unilateral/normal rows with `λ > 0`, sticking tangential rows, axial rows strictly inside
    /// their bound), *tied* rows (axial rows on their bound: `λ_a = ±(μ_n |λ_l| + r_0)` follows
    /// the lateral rows; a sliding contact's pair on its disk follows its normal force and its
    /// slip angle, a free variable of its own, see [`Slide`]) and *held* rows (the rest: zero,
    /// or the pair of a frictionless contact).
    fn classify(&self, lambda: &[f64; M], set: &mut ActiveSet<M>) {
        let inside = |x: f64, bound: f64| x < bound * (1.0 - 1e-9);
        set.n = 0;
        set.n_tied = 0;
        set.n_slides = 0;
        let push = |set: &mut ActiveSet<M>, row: usize| {
            set.rows[set.n] = row as u32;
            set.angle[set.n] = false;
            set.n += 1;
        };
        for b in &self.blocks[..self.n_blocks] {
            let s = b.start as usize;
            match b.kind {
                KIND_BILATERAL => (0..b.len as usize).for_each(|i| push(set, s + i)),
                KIND_UNILATERAL if lambda[s] > 0.0 => push(set, s),
                KIND_CONTACT if lambda[s] > 0.0 => {
                    let k = set.n;
                    push(set, s);
                    let t = libm::hypot(lambda[s + 1], lambda[s + 2]);
                    let radius = b.mu * lambda[s];
                    if inside(t, radius) {
                        push(set, s + 1);
                        push(set, s + 2);
                    } else if radius > 0.0 && t > 0.0 {
                        // Sliding: the angle variable, then the pair tied to (λ_n, φ).
                        push(set, s + 1);
                        set.angle[k + 1] = true;
                        let u = [lambda[s + 1] / t, lambda[s + 2] / t];
                        set.slides[set.n_slides] = Slide {
                            start: s as u32,
                            var: (k + 1) as u32,
                            u,
                            radius,
                            mu: b.mu,
                        };
                        set.n_slides += 1;
                        for (i, c) in [[b.mu * u[0], -u[1]], [b.mu * u[1], u[0]]]
                            .into_iter()
                            .enumerate()
                        {
                            set.tied[set.n_tied] = Tied {
                                row: (s + 1 + i) as u32,
                                lat: k as u32,
                                c,
                            };
                            set.n_tied += 1;
                        }
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
    /// `Z = K⁻¹ E_base` (rows 0..6 must be bilateral and first, as in a frame). A sliding
    /// contact's angle row is its pair's rows along `û⊥`, with the angle's stiffness `ν` (from
    /// the residual `W λ − δ`) on its diagonal. Returns `false` (set invalid) when `K` is
    /// numerically singular or the base rows are not free.
    pub fn factor_active_set(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        self.factor_lu(w, delta, lambda, set) && set.complete_response()
    }

    /// [`Self::factor_active_set`] without the response `Z` (six triangular solves, as many
    /// flops as the LU itself at the suite's sizes): what a round of the active-set methods
    /// needs. `false` when `K` is singular or the base rows are not free.
    fn factor_lu(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if crate::math::use_avx2() {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { self.factor_avx2(w, delta, lambda, set) };
        }
        self.factor_inline(w, delta, lambda, set)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn factor_avx2(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        self.factor_inline(w, delta, lambda, set)
    }

    #[inline(always)]
    fn factor_inline(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        set.valid = false;
        set.factored = false;
        self.classify(lambda, set);
        let n = set.n;
        if n < BASE || (0..BASE).any(|i| set.rows[i] as usize != i) {
            return false;
        }
        let m = self.m;
        let mut kmax = 0.0f64;
        for i in 0..n {
            let ri = set.rows[i] as usize;
            // A sliding contact's angle row: its pair's rows along û⊥ (`rows[i]` is the first).
            let slide = if set.angle[i] {
                set.slides[..set.n_slides]
                    .iter()
                    .find(|sl| sl.var as usize == i)
                    .copied()
            } else {
                None
            };
            let p = slide.map_or([0.0; 2], |sl| [-sl.u[1], sl.u[0]]);
            let row = |c: usize| match slide {
                Some(_) => p[0] * w[ri][c] + p[1] * w[ri + 1][c],
                None => w[ri][c],
            };
            let k = &mut set.lu[i];
            if slide.is_some() {
                for j in 0..n {
                    k[j] = row(set.rows[j] as usize);
                }
            } else {
                for j in 0..n {
                    k[j] = w[ri][set.rows[j] as usize];
                }
            }
            // An angle has no row of λ: its column is its tied pair's alone.
            for sl in &set.slides[..set.n_slides] {
                k[sl.var as usize] = 0.0;
            }
            for t in &set.tied[..set.n_tied] {
                let wa = row(t.row as usize);
                k[t.lat as usize] += t.c[0] * wa;
                k[t.lat as usize + 1] += t.c[1] * wa;
            }
            if let Some(sl) = slide {
                let r = |c: usize| dot(&w[c][..m], &lambda[..m]) - delta[c];
                let slip = sl.u[0] * r(ri) + sl.u[1] * r(ri + 1);
                // The angle's stiffness ν (≥ 0 while it slips against its force; a slip the
                // wrong way is a status change, made between rounds).
                k[i] += (-slip / sl.radius).max(0.0);
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
                // The first n entries only: a whole row is M, ten times n at the suite's sizes.
                let (top, bottom) = set.lu.split_at_mut(p);
                top[k][..n].swap_with_slice(&mut bottom[0][..n]);
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
        set.factored = true;
        true
    }

    /// One Newton step on the free and tied rows of `set` from `lambda` (held rows fixed):
    /// `u = K⁻¹ (δ_F − (W λ)_F)`, `λ_F += u`, then each tied row is put back exactly on its bound
    /// `±(μ_n |λ_l| + r_0)`. From a Gauss-Seidel iterate with the right statuses this lands on the
    /// solution to round-off (the bound is the only nonlinearity). Returns `false` when the set
    /// is not factored or the step is not finite (then `lambda` is unchanged).
    pub fn refine_on_active_set(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        set: &mut ActiveSet<M>,
    ) -> bool {
        if !set.factored || self.newton_step(w, delta, lambda, set).is_none() {
            return false;
        }
        self.apply_step(lambda, set, 1.0);
        true
    }

    /// `λ` moved by `alpha` times the Newton step in `set.x`: free rows along it, each sliding
    /// contact's pair turned by its angle's step and put on its disk `μ λ_n` (the step is
    /// linear in the angle, not in the pair), tied axial rows on their bounds.
    fn apply_step(&self, lambda: &mut [f64; M], set: &ActiveSet<M>, alpha: f64) {
        for k in 0..set.n {
            if !set.angle[k] {
                lambda[set.rows[k] as usize] += alpha * set.x[k];
            }
        }
        for sl in &set.slides[..set.n_slides] {
            let s = sl.start as usize;
            let (sn, cs) = libm::sincos(alpha * set.x[sl.var as usize] / sl.radius);
            let radius = sl.mu * lambda[s];
            lambda[s + 1] = radius * (sl.u[0] * cs - sl.u[1] * sn);
            lambda[s + 2] = radius * (sl.u[0] * sn + sl.u[1] * cs);
        }
        self.put_tied_on_bounds(lambda, set);
    }

    /// The Newton step of the free rows of `set` (factored) from `lambda` into `set.x`:
    /// `K⁻¹ (δ_F − (W λ)_F)`; the largest residual of those rows before the step (`None` when
    /// the step is not finite).
    fn newton_step(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        set: &mut ActiveSet<M>,
    ) -> Option<f64> {
        let (n, m) = (set.n, self.m);
        let minus_residual = |r: usize| delta[r] - dot(&w[r][..m], &lambda[..m]);
        for k in 0..n {
            set.x[k] = minus_residual(set.rows[k] as usize);
        }
        // A sliding contact's angle: its pair's residual along û⊥.
        for sl in &set.slides[..set.n_slides] {
            let (k, t) = (sl.var as usize, sl.start as usize + 1);
            set.x[k] = -sl.u[1] * set.x[k] + sl.u[0] * minus_residual(t + 1);
        }
        let residual = max_abs(&set.x[..n]);
        lu_solve(&set.lu, &set.perm, n, &mut set.x);
        set.x[..n].iter().all(|v| v.is_finite()).then_some(residual)
    }

    /// Newton's method on the active set with the statuses updated between steps (a
    /// primal-dual active-set method): each round factors the set `lambda` gives
    /// ([`Self::factor_active_set`], without the response `Z`: [`ActiveSet::complete_response`]
    /// computes it after), takes one Newton step on it
    /// ([`Self::refine_on_active_set`]), then corrects the statuses the step got wrong
    /// ([`Self::correct_statuses`]): a unilateral or normal force pulled below zero is set to
    /// zero, a tangential force pushed out of its friction disk back onto it, a closed
    /// unilateral row that the residual says must push is opened, a free axial force carried
    /// beyond its bound is put on it (tied), a tied one whose slip runs the wrong way is untied.
    /// Stops when a round changes no status and its Newton step is below round-off (`true`), or after `max_rounds` rounds or on a singular set (`false`; `lambda` holds the
    /// last iterate, finite). Gauss-Seidel from a converged answer confirms it in one sweep.
    ///
    /// One Newton step alone (what a single refine makes) lands on the solution only when the
    /// Gauss-Seidel iterate it starts from already has every status right; sliding points
    /// coupled through a stiff needle make rows nearly parallel, Gauss-Seidel then needs many
    /// thousands of sweeps to sort the statuses out, and the step's solves hit their cap.
    pub fn solve_on_active_sets(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        set: &mut ActiveSet<M>,
        max_rounds: usize,
    ) -> bool {
        // The statuses of the last two rounds, and the previous round's Newton iterate with the
        // size of the correction it called for: to see a cycle of two and leave it.
        let mut seen = [None; 2];
        let mut previous = (f64::INFINITY, [0.0; M]);
        for round in 0..max_rounds {
            if !(self.factor_lu(w, delta, lambda, set)
                && self.refine_on_active_set(w, delta, lambda, set))
            {
                return false;
            }
            let statuses = set.statuses();
            let n = set.n;
            let scale = max_abs(&lambda[..self.m]);
            let step = max_abs(&set.x[..n]);
            let newton = *lambda;
            // All corrections at once converge fastest, but may cycle (every axial row tied,
            // then every one free, ...): from the fourth round, one at a time.
            let Some(size) = self.correct_statuses(w, delta, lambda, round >= 3) else {
                if step <= 1e-12 * scale {
                    return true;
                }
                continue;
            };
            // Only one at a time: a cycle of all-at-once rounds is what one at a time breaks.
            if round >= 5 && seen[0] == Some(statuses) {
                // A cycle of two status sets, which one at a time cannot leave either: a row at
                // the transition, e.g. an axial row whose slip runs the wrong way (slightly)
                // when tied and whose force passes its bound when free. The Newton iterate of
                // the set that calls for the smaller correction is the nearer answer; Gauss-
                // Seidel confirms or repairs it.
                *lambda = if size <= previous.0 {
                    newton
                } else {
                    previous.1
                };
                return false;
            }
            seen = [seen[1], Some(statuses)];
            previous = (size, newton);
        }
        false
    }

    /// A primal active-set method that keeps every iterate feasible: each round factors the set
    /// `lambda` gives and takes its Newton step only as far as the first force that would leave
    /// its admissible set (a normal force through zero, a sticking tangential pair out of its
    /// friction disk, a free axial force beyond its bound `μ_n |λ_l| + r_0`); that force then
    /// changes status (closed, sliding, tied). A full step with every force admissible is
    /// followed by the largest correction the residual calls for (a closed row that must push
    /// opened, a tied axial row whose slip runs the wrong way freed), one at a time. `true` when a
    /// full step leaves nothing to correct; `false` on a singular set or when `max_rounds` run
    /// out (`lambda` then holds the last iterate, feasible, for Gauss-Seidel to go on from).
    ///
    /// [`Self::solve_on_active_sets`] changes every wrong status at once after a full step,
    /// which converges in a few rounds when the Gauss-Seidel iterate it starts from has nearly
    /// every status right; when several axial rows sit at the transition between tied and free,
    /// its full steps overshoot (a freed axial force several times past its bound) and its
    /// statuses cycle. Short steps cannot overshoot; they cost a round per status change.
    ///
    /// A sliding Coulomb contact's pair stays on its disk through a step (it is tied to the
    /// normal force and the slip angle, see [`ActiveSet`]): only its normal force can stop a
    /// step (the contact then opens). Tied rows are nonlinear in the free ones, so with any
    /// tied row a full step ends the method only once it is below round-off.
    pub fn solve_on_active_sets_feasible(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        set: &mut ActiveSet<M>,
        max_rounds: usize,
    ) -> bool {
        // A residual this small against the problem's scale is round-off (as in
        // `correct_statuses`).
        let tol = 1e-10 * max_abs(&delta[..self.m]);
        for _ in 0..max_rounds {
            if !self.factor_lu(w, delta, lambda, set) {
                return false;
            }
            let Some(residual) = self.newton_step(w, delta, lambda, set) else {
                return false;
            };
            // The free rows' Newton step as a direction over all rows (tied and held: 0).
            let (n, mut dir) = (set.n, [0.0; M]);
            for k in 0..n {
                if !set.angle[k] {
                    dir[set.rows[k] as usize] = set.x[k];
                }
            }
            let tied = |row: usize| set.tied[..set.n_tied].iter().any(|t| t.row as usize == row);
            // The longest step every block admits, and the block that stops it.
            let mut alpha = 1.0;
            let mut blocking = None;
            for (k, b) in self.blocks[..self.n_blocks].iter().enumerate() {
                let s = b.start as usize;
                if b.kind == KIND_SLIDING && tied(s + 2) {
                    continue;
                }
                // A sliding contact's pair stays on its disk (`apply_step`): only its normal
                // force can leave its set.
                let sliding = b.kind == KIND_CONTACT && tied(s + 1);
                let excess = |a: f64| {
                    if sliding {
                        -(lambda[s] + a * dir[s]) - 1e-12 * libm::fabs(lambda[s])
                    } else {
                        block_excess(b, lambda, &dir, a)
                    }
                };
                if excess(alpha) <= 0.0 {
                    continue;
                }
                // The first step at which the block leaves its set (bisection; excess(0) ≤ 0
                // for the feasible iterates this method keeps, up to round-off).
                let (mut lo, mut hi) = (0.0, alpha);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if excess(mid) > 0.0 {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                alpha = lo;
                blocking = Some(k);
            }
            self.apply_step(lambda, set, alpha);
            match blocking {
                Some(k) => {
                    let b = &self.blocks[k];
                    let s = b.start as usize;
                    if b.kind == KIND_CONTACT && tied(s + 1) {
                        // A sliding contact whose normal force reached zero opens.
                        lambda[s..s + 3].fill(0.0);
                    } else {
                        self.block_on_boundary(b, lambda, &dir);
                    }
                }
                None => {
                    // A tied row is nonlinear in the free ones (an axial bound in the lateral
                    // forces, a sliding pair in its angle): a full step lands on the solution
                    // only from an iterate whose rows were solved already, up to round-off.
                    let settled = set.n_tied == 0 || residual <= tol;
                    if self.correct_statuses(w, delta, lambda, true).is_none() && settled {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Every tied axial row of `set` exactly on its bound `±(μ_n |λ_l| + r_0)` (a sliding
    /// contact's tied pair, whose `lat + 1` is its angle, is [`Self::apply_step`]'s).
    fn put_tied_on_bounds(&self, lambda: &mut [f64; M], set: &ActiveSet<M>) {
        for t in &set.tied[..set.n_tied] {
            if set.angle[t.lat as usize + 1] {
                continue;
            }
            let a = t.row as usize;
            let l = set.rows[t.lat as usize] as usize;
            let (mu, r0) = self.sliding_law(a);
            let sigma = if lambda[a] < 0.0 { -1.0 } else { 1.0 };
            lambda[a] = sigma * (mu * libm::hypot(lambda[l], lambda[l + 1]) + r0);
        }
    }

    /// The forces of block `b`, which a step along `dir` has just brought onto the boundary of
    /// its admissible set, put exactly on it, so that the next factorisation gives them their
    /// new status: a normal force at zero closes the block, a tangential pair on its disk
    /// slides (held; a pair at zero that the step would have turned outward is put on the disk
    /// in that direction), an axial force on its bound is tied.
    fn block_on_boundary(&self, b: &super::Block, lambda: &mut [f64; M], dir: &[f64; M]) {
        let s = b.start as usize;
        match b.kind {
            KIND_UNILATERAL => lambda[s] = 0.0,
            KIND_CONTACT => {
                let bound = b.mu * lambda[s];
                let t = libm::hypot(lambda[s + 1], lambda[s + 2]);
                let d = libm::hypot(dir[s + 1], dir[s + 2]);
                // The normal force blocks when the disk would not have: the tangential pair is
                // inside the disk with room to spare, or the normal force is what shrinks it.
                let normal_blocks =
                    lambda[s] <= 0.0 || bound <= 0.0 || (dir[s] < 0.0 && t <= bound * (1.0 - 1e-6));
                if normal_blocks {
                    lambda[s..s + 3].fill(0.0);
                } else if t > 0.0 {
                    lambda[s + 1] *= bound / t;
                    lambda[s + 2] *= bound / t;
                } else if d > 0.0 {
                    lambda[s + 1] = bound * dir[s + 1] / d;
                    lambda[s + 2] = bound * dir[s + 2] / d;
                }
            }
            KIND_SLIDING => {
                let bound = b.mu * libm::hypot(lambda[s], lambda[s + 1]) + b.r0;
                let sigma = if lambda[s + 2] < 0.0 { -1.0 } else { 1.0 };
                lambda[s + 2] = sigma * bound;
            }
            _ => {}
        }
    }

    /// The status corrections of [`Self::solve_on_active_sets`] after a Newton step, all of
    /// them or (`single`) only the largest, measured as Gauss-Seidel measures a change
    /// (`|W_ii Δλ_i|`, or the residual that calls for it); the largest correction's size when any
    /// status changed.
    fn correct_statuses(
        &self,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &mut [f64; M],
        single: bool,
    ) -> Option<f64> {
        let m = self.m;
        // A residual this small against the problem's scale is round-off, not a wrong status
        // (a row exactly on its bound with zero slip would otherwise flip at every round).
        let tol = 1e-10 * max_abs(&delta[..m]);
        let mut largest: Option<(f64, usize)> = None;
        for (k, b) in self.blocks[..self.n_blocks].iter().enumerate() {
            if let Some((size, _)) = self.status_fix(b, w, delta, lambda, tol)
                && largest.is_none_or(|(l, _)| size > l)
            {
                largest = Some((size, k));
            }
        }
        let (size, only) = largest?;
        for (k, b) in self.blocks[..self.n_blocks].iter().enumerate() {
            if single && k != only {
                continue;
            }
            if let Some((_, fix)) = self.status_fix(b, w, delta, lambda, tol) {
                let s = b.start as usize;
                match fix {
                    Fix::Close => lambda[s..s + b.len as usize].fill(0.0),
                    Fix::Open => lambda[s] = f64::MIN_POSITIVE,
                    Fix::Scale(f) => {
                        lambda[s + 1] *= f;
                        lambda[s + 2] *= f;
                    }
                    Fix::Axial(v) => lambda[s + 2] = v,
                }
            }
        }
        Some(size)
    }

    /// The status correction group `b` needs after a Newton step, with its size, if any: a
    /// unilateral or normal force below zero closes; a closed row the others press (`w < 0`
    /// would penetrate) opens; a tangential force out of its disk goes back onto it; a free
    /// axial force beyond its bound goes onto it (tied next); a tied one whose slip runs the
    /// wrong way (on `+b` the axial update's fixed point needs `w_a ≤ 0`, on `−b` `w_a ≥ 0`)
    /// is freed just inside.
    fn status_fix(
        &self,
        b: &super::Block,
        w: &[[f64; M]; M],
        delta: &[f64; M],
        lambda: &[f64; M],
        tol: f64,
    ) -> Option<(f64, Fix)> {
        let (m, s) = (self.m, b.start as usize);
        let residual = |r: usize| dot(&w[r][..m], &lambda[..m]) - delta[r];
        match b.kind {
            KIND_UNILATERAL | KIND_CONTACT => {
                if lambda[s] < 0.0 {
                    Some((libm::fabs(w[s][s] * lambda[s]), Fix::Close))
                } else if lambda[s] == 0.0 {
                    let r = residual(s);
                    (r < -tol).then_some((-r, Fix::Open))
                } else if b.kind == KIND_CONTACT {
                    let t = libm::hypot(lambda[s + 1], lambda[s + 2]);
                    let bound = b.mu * lambda[s];
                    if t > bound * (1.0 + 1e-9) {
                        Some((w[s + 1][s + 1] * (t - bound), Fix::Scale(bound / t)))
                    } else if bound > 0.0 && t >= bound * (1.0 - 1e-9) {
                        // Sliding: the slip must run against the force (`w_t · û ≤ 0`), else
                        // the pair sticks, just inside its disk.
                        let slip =
                            (lambda[s + 1] * residual(s + 1) + lambda[s + 2] * residual(s + 2)) / t;
                        (slip > tol).then_some((slip, Fix::Scale(1.0 - 1e-6)))
                    } else {
                        None
                    }
                } else {
                    None
                }
            }
            KIND_SLIDING => {
                let a = s + 2;
                let bound = b.mu * libm::hypot(lambda[s], lambda[s + 1]) + b.r0;
                let x = libm::fabs(lambda[a]);
                let sigma = if lambda[a] < 0.0 { -1.0 } else { 1.0 };
                if x > bound * (1.0 + 1e-9) {
                    Some((w[a][a] * (x - bound), Fix::Axial(sigma * bound)))
                } else if bound > 0.0 && x >= bound * (1.0 - 1e-9) {
                    let r = sigma * residual(a);
                    (r > tol).then_some((r, Fix::Axial(sigma * bound * (1.0 - 1e-6))))
                } else {
                    None
                }
            }
            _ => None,
        }
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
            if !set.angle[k] {
                out[set.rows[k] as usize] += acc;
            }
        }
        for t in &set.tied[..set.n_tied] {
            let l = t.lat as usize;
            out[t.row as usize] += t.c[0] * du[l] + t.c[1] * du[l + 1];
        }
        true
    }
}

/// How far the forces of block `b` at `λ + α d` are outside its admissible set (≤ 0: inside): a
/// negative normal force, a tangential pair beyond `μ λ_n`, an axial force beyond
/// `μ_n |λ_l| + r_0`; bilateral blocks are always inside. Relative to the block's force scale
/// with a round-off allowance, so a force left on its boundary by the last step is inside.
fn block_excess<const M: usize>(
    b: &super::Block,
    lambda: &[f64; M],
    d: &[f64; M],
    alpha: f64,
) -> f64 {
    let s = b.start as usize;
    let at = |i: usize| lambda[s + i] + alpha * d[s + i];
    let scale = |v: f64| 1e-12 * v + 1e-300;
    match b.kind {
        KIND_UNILATERAL => -at(0) - scale(libm::fabs(lambda[s])),
        KIND_CONTACT => {
            let n = at(0);
            if lambda[s] == 0.0 && d[s] == 0.0 {
                return -1.0; // closed and held closed
            }
            let t = libm::hypot(at(1), at(2));
            let allowance = scale(libm::fabs(lambda[s]) + t);
            (-n).max(t - b.mu * n) - allowance
        }
        KIND_SLIDING => {
            let bound = b.mu * libm::hypot(at(0), at(1)) + b.r0;
            libm::fabs(at(2)) - bound - scale(bound + libm::fabs(lambda[s + 2]))
        }
        _ => -1.0,
    }
}

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
