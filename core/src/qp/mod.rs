//! A small dense strictly convex quadratic program, solved exactly by the dual active-set method
//! of Goldfarb and Idnani (Math. Programming 27, 1983; the algorithm behind `quadprog`):
//!
//! ```text
//! minimise ½ xᵀ H x + gᵀ x   subject to   a_iᵀ x ≥ b_i,  i = 0 … m−1
//! ```
//!
//! with `H` symmetric positive definite, `n ≤ N` unknowns and `m ≤ C` inequality rows (bounds
//! are rows too: [`Qp::add_bounds`]). The inverse step poses its joint update this way: tracking
//! objectives as least squares in `H`, `g`; joint limits, joint speeds, the trust region on the
//! needle base and the obstacle clearances as rows.
//!
//! The method starts from the unconstrained minimum and adds violated rows one at a time,
//! keeping the iterate optimal for the rows in its active set (dual feasible) and dropping a row
//! whose multiplier would turn negative. Each change of the active set updates an orthogonal
//! factorisation `J = L⁻ᵀ Q` and the triangle `R` with Givens rotations, so no system is
//! refactorised. It ends at the exact optimum, or proves the rows infeasible (no point satisfies
//! them all), in a finite number of steps; a cap on the steps guards against round-off cycling.
//!
//! Fixed capacity, no allocation, no panics: the struct holds about `(3 N + C) N` floats
//! (3.6 KiB at `N = 8, C = 32`). Keep it in a long-lived owner and refill it each step.

use core::fmt;

/// Why a program could not be solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum QpError {
    /// `n` or `m` exceeds the capacity.
    CapacityExceeded {
        /// Requested count.
        requested: usize,
        /// Capacity.
        capacity: usize,
    },
    /// `H` is not positive definite (a non-positive pivot in its Cholesky factorisation).
    NotPositiveDefinite {
        /// Pivot at which the factorisation failed.
        pivot: usize,
    },
    /// A value of the problem is NaN or infinite.
    NonFinite,
    /// The rows have no common point: adding `row` to the active set is impossible.
    Infeasible {
        /// The row that could not be satisfied.
        row: usize,
    },
}

impl fmt::Display for QpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::CapacityExceeded {
                requested,
                capacity,
            } => write!(f, "{requested} exceeds the QP capacity {capacity}"),
            Self::NotPositiveDefinite { pivot } => {
                write!(f, "the QP Hessian is not positive definite (pivot {pivot})")
            }
            Self::NonFinite => write!(f, "non-finite value in the QP"),
            Self::Infeasible { row } => write!(f, "the QP rows are infeasible (row {row})"),
        }
    }
}

impl core::error::Error for QpError {}

/// Outcome of a solve.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct QpReport {
    /// Active-set changes made (additions and removals).
    pub iterations: u32,
    /// Rows active at the solution.
    pub active: usize,
    /// Objective `½ xᵀ H x + gᵀ x` at the solution.
    pub objective: f64,
    /// Whether the optimum was reached (false: the step cap stopped a round-off cycle; the
    /// iterate is then optimal for its active set but may violate a row by
    /// [`QpReport::max_violation`]).
    pub optimal: bool,
    /// Largest violation `max(0, b_i − a_iᵀ x)` over the rows.
    pub max_violation: f64,
}

/// A convex QP of at most `N` unknowns and `C` rows, with its solver workspace.
#[derive(Clone, Debug)]
pub struct Qp<const N: usize, const C: usize> {
    n: usize,
    m: usize,
    /// Hessian (lower triangle read), overwritten by nothing: the factor lives in `j`.
    h: [[f64; N]; N],
    g: [f64; N],
    a: [[f64; N]; C],
    b: [f64; C],
    /// Solution.
    x: [f64; N],
    /// `J = L⁻ᵀ Qᵀ`, columns `0..q` span the active normals' image.
    j: [[f64; N]; N],
    /// Upper triangle `R` (`q × q` used): `J₁ᵀ [a_active] = R`.
    r: [[f64; N]; N],
    /// Multipliers of the active rows.
    u: [f64; N],
    /// Active rows, in the order of `R`'s columns.
    active: [usize; N],
    q: usize,
    is_active: [bool; C],
    d: [f64; N],
    z: [f64; N],
    rr: [f64; N],
}

impl<const N: usize, const C: usize> Default for Qp<N, C> {
    fn default() -> Self {
        Self::new()
    }
}

fn hypot(a: f64, b: f64) -> f64 {
    libm::hypot(a, b)
}

impl<const N: usize, const C: usize> Qp<N, C> {
    /// An empty program (`n = 0`).
    pub const fn new() -> Self {
        Self {
            n: 0,
            m: 0,
            h: [[0.0; N]; N],
            g: [0.0; N],
            a: [[0.0; N]; C],
            b: [0.0; C],
            x: [0.0; N],
            j: [[0.0; N]; N],
            r: [[0.0; N]; N],
            u: [0.0; N],
            active: [0; N],
            q: 0,
            is_active: [false; C],
            d: [0.0; N],
            z: [0.0; N],
            rr: [0.0; N],
        }
    }

    /// Starts a new program of `n` unknowns: `H = 0`, `g = 0`, no rows.
    ///
    /// # Errors
    /// [`QpError::CapacityExceeded`] when `n > N`.
    pub fn reset(&mut self, n: usize) -> Result<(), QpError> {
        if n > N {
            return Err(QpError::CapacityExceeded {
                requested: n,
                capacity: N,
            });
        }
        self.n = n;
        self.m = 0;
        for row in &mut self.h {
            row.fill(0.0);
        }
        self.g.fill(0.0);
        Ok(())
    }

    /// Number of unknowns.
    pub fn unknowns(&self) -> usize {
        self.n
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// Adds `w · (cᵀ x + e)²` to the objective, i.e. `2w c cᵀ` to `H` and `2w e c` to `g`
    /// (the factor 2 makes `½ xᵀ H x + gᵀ x` equal the sum of the squares up to a constant).
    pub fn add_square(&mut self, c: &[f64], e: f64, w: f64) {
        let n = self.n.min(c.len());
        for i in 0..n {
            self.g[i] += 2.0 * w * e * c[i];
            for k in 0..n {
                self.h[i][k] += 2.0 * w * c[i] * c[k];
            }
        }
    }

    /// Adds `w` to the diagonal of `H` (a Tikhonov term `½ w |x|²`).
    pub fn add_diagonal(&mut self, w: f64) {
        for i in 0..self.n {
            self.h[i][i] += w;
        }
    }

    /// Adds `w_i` to `H_ii` and `−w_i t_i` to `g_i`: the term `½ Σ w_i (x_i − t_i)²`.
    pub fn add_pull(&mut self, w: &[f64], t: &[f64]) {
        for i in 0..self.n.min(w.len()).min(t.len()) {
            self.h[i][i] += w[i];
            self.g[i] -= w[i] * t[i];
        }
    }

    /// Mutable Hessian entry `H_ik` (symmetric: write both triangles).
    pub fn hessian_mut(&mut self) -> &mut [[f64; N]; N] {
        &mut self.h
    }

    /// Mutable linear term `g`.
    pub fn linear_mut(&mut self) -> &mut [f64; N] {
        &mut self.g
    }

    /// Adds the row `aᵀ x ≥ b` (`a` of length `n`); returns its index.
    ///
    /// # Errors
    /// [`QpError::CapacityExceeded`] when the program already has `C` rows.
    pub fn add_row(&mut self, a: &[f64], b: f64) -> Result<usize, QpError> {
        if self.m >= C {
            return Err(QpError::CapacityExceeded {
                requested: self.m + 1,
                capacity: C,
            });
        }
        let k = self.m;
        let n = self.n.min(a.len());
        self.a[k].fill(0.0);
        self.a[k][..n].copy_from_slice(&a[..n]);
        self.b[k] = b;
        self.m += 1;
        Ok(k)
    }

    /// Adds `lower_i ≤ x_i ≤ upper_i` as two rows per unknown (infinite bounds are skipped).
    ///
    /// # Errors
    /// [`QpError::CapacityExceeded`] when the rows do not fit.
    pub fn add_bounds(&mut self, lower: &[f64], upper: &[f64]) -> Result<(), QpError> {
        let mut e = [0.0; N];
        for i in 0..self.n.min(lower.len()).min(upper.len()) {
            e.fill(0.0);
            if lower[i] > f64::NEG_INFINITY {
                e[i] = 1.0;
                self.add_row(&e[..self.n], lower[i])?;
            }
            if upper[i] < f64::INFINITY {
                e[i] = -1.0;
                self.add_row(&e[..self.n], -upper[i])?;
            }
        }
        Ok(())
    }

    /// The solution of the last [`Self::solve`] (first `n` entries).
    pub fn solution(&self) -> &[f64] {
        &self.x[..self.n]
    }

    /// The multiplier of row `k` at the last solution (0 for an inactive row).
    pub fn multiplier(&self, k: usize) -> f64 {
        (0..self.q)
            .find(|&l| self.active[l] == k)
            .map_or(0.0, |l| self.u[l])
    }

    /// Whether row `k` is active at the last solution.
    pub fn is_active(&self, k: usize) -> bool {
        k < self.m && self.is_active[k]
    }

    /// Solves the program. Allocates nothing.
    ///
    /// # Errors
    /// [`QpError`]: a non-finite input, `H` not positive definite, or infeasible rows.
    pub fn solve(&mut self) -> Result<QpReport, QpError> {
        let (n, m) = (self.n, self.m);
        let finite = self.h[..n]
            .iter()
            .all(|r| r[..n].iter().all(|v| v.is_finite()))
            && self.g[..n].iter().all(|v| v.is_finite())
            && self.a[..m]
                .iter()
                .all(|r| r[..n].iter().all(|v| v.is_finite()))
            && self.b[..m].iter().all(|v| v.is_finite());
        if !finite {
            return Err(QpError::NonFinite);
        }
        self.factor()?;
        self.unconstrained_minimum();
        self.q = 0;
        self.is_active[..m].fill(false);
        let mut report = QpReport::default();
        // Each row enters at most once per drop; the cap only breaks round-off cycles.
        let cap = 10 * (n + m) as u32 + 20;
        loop {
            let Some(p) = self.most_violated() else {
                report.optimal = true;
                break;
            };
            if report.iterations >= cap {
                break;
            }
            self.add_violated(p, &mut report.iterations, cap)?;
        }
        report.active = self.q;
        report.objective = self.objective();
        report.max_violation = (0..m)
            .map(|i| (self.b[i] - self.row_dot(i)).max(0.0))
            .fold(0.0, f64::max);
        if !self.x[..n].iter().all(|v| v.is_finite()) {
            return Err(QpError::NonFinite);
        }
        Ok(report)
    }

    /// `½ xᵀ H x + gᵀ x` at the current `x`.
    fn objective(&self) -> f64 {
        let n = self.n;
        let mut f = 0.0;
        for i in 0..n {
            let mut hx = 0.0;
            for k in 0..n {
                hx += self.h[i][k] * self.x[k];
            }
            f += self.x[i] * (0.5 * hx + self.g[i]);
        }
        f
    }

    fn row_dot(&self, i: usize) -> f64 {
        let mut s = 0.0;
        for k in 0..self.n {
            s += self.a[i][k] * self.x[k];
        }
        s
    }

    /// Cholesky `H = L Lᵀ` (lower triangle of `H` read) and `J = L⁻ᵀ`.
    fn factor(&mut self) -> Result<(), QpError> {
        let n = self.n;
        // L into `r` (scratch), lower triangle.
        let l = &mut self.r;
        for i in 0..n {
            for k in 0..=i {
                let mut s = self.h[i][k];
                for p in 0..k {
                    s -= l[i][p] * l[k][p];
                }
                if i == k {
                    if !(s > 0.0) {
                        return Err(QpError::NotPositiveDefinite { pivot: i });
                    }
                    l[i][i] = libm::sqrt(s);
                } else {
                    l[i][k] = s / l[k][k];
                }
            }
        }
        // J = L⁻ᵀ: solve Lᵀ J = I column by column (J upper triangular).
        for row in &mut self.j {
            row.fill(0.0);
        }
        for c in 0..n {
            for i in (0..=c).rev() {
                let mut s = if i == c { 1.0 } else { 0.0 };
                for p in i + 1..=c {
                    s -= l[p][i] * self.j[p][c];
                }
                self.j[i][c] = s / l[i][i];
            }
        }
        for row in &mut self.r {
            row.fill(0.0);
        }
        Ok(())
    }

    /// `x = −H⁻¹ g = −J Jᵀ g`.
    fn unconstrained_minimum(&mut self) {
        let n = self.n;
        for c in 0..n {
            let mut s = 0.0;
            for i in 0..n {
                s += self.j[i][c] * self.g[i];
            }
            self.d[c] = s;
        }
        for i in 0..n {
            let mut s = 0.0;
            for c in 0..n {
                s += self.j[i][c] * self.d[c];
            }
            self.x[i] = -s;
        }
    }

    /// Tolerance below which a row counts as satisfied.
    fn tolerance(&self, i: usize) -> f64 {
        let n = self.n;
        let an: f64 = self.a[i][..n].iter().map(|v| libm::fabs(*v)).sum();
        let xn = self.x[..n]
            .iter()
            .fold(0.0f64, |a, v| a.max(libm::fabs(*v)));
        1e-12 * (1.0 + libm::fabs(self.b[i]) + an * xn)
    }

    /// The inactive row with the largest violation relative to its norm, if any.
    fn most_violated(&self) -> Option<usize> {
        let mut best = None;
        let mut worst = 0.0;
        for i in 0..self.m {
            if self.is_active[i] {
                continue;
            }
            let s = self.row_dot(i) - self.b[i];
            if s < -self.tolerance(i) {
                let norm = libm::sqrt(self.a[i][..self.n].iter().map(|v| v * v).sum());
                let v = s / norm.max(f64::MIN_POSITIVE);
                if v < worst {
                    worst = v;
                    best = Some(i);
                }
            }
        }
        best
    }

    /// `d = Jᵀ a_p`, the primal direction `z = J₂ d₂` and the dual direction `r = R⁻¹ d₁`.
    fn directions(&mut self, p: usize) {
        let (n, q) = (self.n, self.q);
        for c in 0..n {
            let mut s = 0.0;
            for i in 0..n {
                s += self.j[i][c] * self.a[p][i];
            }
            self.d[c] = s;
        }
        for i in 0..n {
            let mut s = 0.0;
            for c in q..n {
                s += self.j[i][c] * self.d[c];
            }
            self.z[i] = s;
        }
        for i in (0..q).rev() {
            let mut s = self.d[i];
            for k in i + 1..q {
                s -= self.r[i][k] * self.rr[k];
            }
            self.rr[i] = s / self.r[i][i];
        }
    }

    /// Brings the violated row `p` into the active set (dropping blocking rows on the way).
    fn add_violated(&mut self, p: usize, steps: &mut u32, cap: u32) -> Result<(), QpError> {
        let n = self.n;
        let mut u_plus = 0.0;
        loop {
            *steps += 1;
            self.directions(p);
            // Partial (dual) step: the largest before an active multiplier reaches zero.
            let mut t1 = f64::INFINITY;
            let mut drop = None;
            for l in 0..self.q {
                if self.rr[l] > 0.0 {
                    let t = self.u[l] / self.rr[l];
                    if t < t1 {
                        t1 = t;
                        drop = Some(l);
                    }
                }
            }
            // Full (primal) step: the step that satisfies row p.
            let za: f64 = (0..n).map(|i| self.z[i] * self.a[p][i]).sum();
            let znorm = self.z[..n]
                .iter()
                .fold(0.0f64, |a, v| a.max(libm::fabs(*v)));
            let anorm = self.a[p][..n]
                .iter()
                .fold(0.0f64, |a, v| a.max(libm::fabs(*v)));
            let primal = znorm > 1e-14 * (1.0 + anorm) && za > 0.0;
            let s = self.row_dot(p) - self.b[p];
            let t2 = if primal { -s / za } else { f64::INFINITY };
            let t = t1.min(t2);
            if !t.is_finite() {
                return Err(QpError::Infeasible { row: p });
            }
            if primal {
                for i in 0..n {
                    self.x[i] += t * self.z[i];
                }
            }
            for l in 0..self.q {
                self.u[l] -= t * self.rr[l];
            }
            u_plus += t;
            if primal && t2 <= t1 {
                if self.append(p, u_plus) {
                    return Ok(());
                }
                // Numerically dependent on the active rows: treat as satisfied.
                return Ok(());
            }
            if let Some(l) = drop {
                self.remove(l);
            }
            if *steps >= cap {
                return Ok(());
            }
        }
    }

    /// Appends row `p` (direction `d` computed) to the active set; false when it is dependent.
    fn append(&mut self, p: usize, u_p: f64) -> bool {
        let (n, q) = (self.n, self.q);
        for c in (q + 1..n).rev() {
            let (a, b) = (self.d[c - 1], self.d[c]);
            if b == 0.0 {
                continue;
            }
            let h = hypot(a, b);
            let (cs, sn) = (a / h, b / h);
            self.d[c - 1] = h;
            self.d[c] = 0.0;
            for i in 0..n {
                let (x, y) = (self.j[i][c - 1], self.j[i][c]);
                self.j[i][c - 1] = cs * x + sn * y;
                self.j[i][c] = -sn * x + cs * y;
            }
        }
        if q >= n {
            return false;
        }
        let scale = self.d[..=q]
            .iter()
            .fold(0.0f64, |a, v| a.max(libm::fabs(*v)));
        if !(libm::fabs(self.d[q]) > 1e-14 * scale) {
            return false;
        }
        for i in 0..=q {
            self.r[i][q] = self.d[i];
        }
        self.u[q] = u_p;
        self.active[q] = p;
        self.is_active[p] = true;
        self.q += 1;
        true
    }

    /// Removes the active row at position `l` and restores `R`'s triangle.
    fn remove(&mut self, l: usize) {
        let (n, q) = (self.n, self.q);
        self.is_active[self.active[l]] = false;
        for c in l..q - 1 {
            for i in 0..q {
                self.r[i][c] = self.r[i][c + 1];
            }
            self.u[c] = self.u[c + 1];
            self.active[c] = self.active[c + 1];
        }
        for i in 0..q {
            self.r[i][q - 1] = 0.0;
        }
        // R is now upper Hessenberg in columns l..q−1: rotate rows c, c+1 (and J's columns).
        for c in l..q - 1 {
            let (a, b) = (self.r[c][c], self.r[c + 1][c]);
            if b == 0.0 {
                continue;
            }
            let h = hypot(a, b);
            let (cs, sn) = (a / h, b / h);
            for k in c..q - 1 {
                let (x, y) = (self.r[c][k], self.r[c + 1][k]);
                self.r[c][k] = cs * x + sn * y;
                self.r[c + 1][k] = -sn * x + cs * y;
            }
            for i in 0..n {
                let (x, y) = (self.j[i][c], self.j[i][c + 1]);
                self.j[i][c] = cs * x + sn * y;
                self.j[i][c + 1] = -sn * x + cs * y;
            }
        }
        self.q -= 1;
    }
}

#[cfg(test)]
mod tests;
