//! Active-set polish of a frictionless problem: from the Gauss-Seidel iterate, solve the
//! equality system of the active set (bilateral rows and unilateral rows with `λ > 0`) by
//! conjugate gradients, update the set primal-dual style, and keep the result only if it
//! satisfies the LCP conditions to round-off.

use super::{BlockGs, KIND_UNILATERAL};
use crate::math::{axpy, dot};

/// Outcome of one complementarity check of a polish round.
enum Check {
    /// Every condition holds: the CG solution is the answer.
    Feasible,
    /// Rows moved between active and inactive: solve again.
    Changed,
    /// Infeasible with nothing to change, or a non-finite solution: give up.
    Failed,
}

impl<const M: usize> BlockGs<M> {
    /// Active-set polish of a frictionless problem (primal-dual active set + CG). Returns `true`
    /// and overwrites `lambda` when a feasible solution to round-off was found.
    pub(super) fn polish(
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
        for _round in 0..12 {
            cg_on_active_set(w, delta, lambda, &self.active, &mut self.scratch, m);
            let x = &self.scratch[0];
            match check_complementarity(w, delta, x, &row_kind, &mut self.active, m, scale) {
                Check::Feasible => {
                    lambda[..m].copy_from_slice(&x[..m]);
                    for i in 0..m {
                        self.w[i] = dot(&w[i][..m], &lambda[..m]) - delta[i];
                    }
                    return true;
                }
                Check::Changed => {}
                Check::Failed => return false,
            }
        }
        false
    }
}

/// CG on `W_AA x_A = δ_A`, `x_I = 0`, from the current `λ`, into `scratch[0]` (the other rows of
/// `scratch` are the CG vectors).
fn cg_on_active_set<const M: usize>(
    w: &[[f64; M]; M],
    delta: &[f64; M],
    lambda: &[f64; M],
    active: &[u8; M],
    scratch: &mut [[f64; M]; 4],
    m: usize,
) {
    let [x, r, p, ap] = scratch;
    for i in 0..m {
        x[i] = if active[i] != 0 { lambda[i] } else { 0.0 };
    }
    let mut rr = 0.0;
    for i in 0..m {
        r[i] = if active[i] != 0 {
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
            ap[i] = if active[i] != 0 {
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
}

/// Complementarity check of the CG solution `x` and active-set update: an active unilateral row
/// with `x < 0` leaves the set, an inactive one with `w < −1e-13 · scale` joins it.
fn check_complementarity<const M: usize>(
    w: &[[f64; M]; M],
    delta: &[f64; M],
    x: &[f64; M],
    row_kind: &[u8; M],
    active: &mut [u8; M],
    m: usize,
    scale: f64,
) -> Check {
    let tol = 1e-13 * scale;
    let mut changed = false;
    let mut feasible = true;
    for i in 0..m {
        if !x[i].is_finite() {
            return Check::Failed;
        }
        if row_kind[i] != KIND_UNILATERAL {
            continue;
        }
        let wi = dot(&w[i][..m], &x[..m]) - delta[i];
        if active[i] != 0 {
            if x[i] < 0.0 {
                feasible = false;
                active[i] = 0;
                changed = true;
            }
        } else if wi < -tol {
            feasible = false;
            active[i] = 1;
            changed = true;
        }
    }
    if feasible {
        Check::Feasible
    } else if changed {
        Check::Changed
    } else {
        Check::Failed
    }
}
