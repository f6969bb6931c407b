//! How the constraint solution follows the joints: `S_i = ∂λ/∂q_i`, the forward differences the
//! Jacobian's solves already make, `(λ(q + δq e_i) − λ_q) / δq`, kept to start later solves next
//! to their answer.
//!
//! - Within a step, the final solve at `q + Δq` (and every candidate the step confirms) starts
//!   from `λ_q + Σ_i Δq_i S_i` rather than from `λ_q`.
//! - In the next step, Jacobian column `i` starts from `λ_q + δq S_i` of the previous step:
//!   consecutive frames of an insertion are close, and so are their sensitivities.
//!
//! Only where a solve starts changes: each still runs to its tolerance, so the answers agree
//! with those from `λ_q` to that tolerance.

use super::step::WARM_START_SCALE;

/// `∂λ/∂q_i` of the last Jacobian, per column, over the rows `0..rows` of the frame it was taken
/// on.
#[derive(Clone, Debug)]
pub(super) struct Sensitivity<const M: usize, const N: usize> {
    /// `∂λ/∂q_i` [N/rad, N·mm/rad].
    d: [[f64; M]; N],
    /// Rows of the frame the columns were taken on; 0: none.
    rows: usize,
    /// Taken in the current step's Jacobian (else: the previous step's, or none).
    fresh: bool,
}

crate::zeroed::impl_zeroable!(Sensitivity<const M, const N> { d, rows, fresh });

impl<const M: usize, const N: usize> Sensitivity<M, N> {
    /// None yet.
    pub(super) const fn new() -> Self {
        Self {
            d: [[0.0; M]; N],
            rows: 0,
            fresh: false,
        }
    }

    /// Forgets the columns (a reset of the warm start: the next frame may be another problem).
    pub(super) fn clear(&mut self) {
        self.rows = 0;
        self.fresh = false;
    }

    /// A new step: the columns, if any, are the previous step's.
    pub(super) fn age(&mut self) {
        self.fresh = false;
    }

    /// Records column `i`, `(lambda_i − lambda_q) / step` over rows `0..m`. The columns count as
    /// this step's once [`Self::complete`] is called after the last.
    pub(super) fn record(
        &mut self,
        i: usize,
        lambda_i: &[f64; M],
        lambda_q: &[f64; M],
        m: usize,
        step: f64,
    ) {
        let m = m.min(M);
        if let Some(d) = self.d.get_mut(i) {
            for ((d, a), b) in d[..m].iter_mut().zip(&lambda_i[..m]).zip(&lambda_q[..m]) {
                *d = (a - b) / step;
            }
        }
    }

    /// Every column of this step's Jacobian recorded on a frame of `m` rows; `false` (and the
    /// columns dropped) if one is not finite.
    pub(super) fn complete(&mut self, m: usize) -> bool {
        let m = m.min(M);
        let finite = self.d.iter().all(|d| d[..m].iter().all(|x| x.is_finite()));
        self.rows = if finite { m } else { 0 };
        self.fresh = finite;
        finite
    }

    /// Whether this step's columns exist (for the final solve's start).
    pub(super) fn is_fresh(&self) -> bool {
        self.fresh && self.rows > 0
    }

    /// `out = λ_q + Σ_i dq_i S_i` over rows `0..m`, when columns taken on a frame of `m` rows
    /// exist and the start they give is of the problem's scale: its force scale
    /// `max |W_ii λ_i|` within [`WARM_START_SCALE`] of `scale` (the frame's `‖δ‖∞` or `λ_q`'s,
    /// whichever is larger), as for the warm start. Otherwise `out` is untouched and `false` is
    /// returned.
    pub(super) fn predict(
        &self,
        lambda_q: &[f64; M],
        dq: &[f64; N],
        m: usize,
        diag: impl Fn(usize) -> f64,
        scale: f64,
        out: &mut [f64; M],
    ) -> bool {
        if self.rows == 0 || self.rows != m || m > M {
            return false;
        }
        let mut pred = [0.0; M];
        pred[..m].copy_from_slice(&lambda_q[..m]);
        for (d, &dqi) in self.d.iter().zip(dq) {
            for (p, x) in pred[..m].iter_mut().zip(&d[..m]) {
                *p += dqi * x;
            }
        }
        let force = (0..m).fold(0.0_f64, |a, i| a.max(libm::fabs(diag(i) * pred[i])));
        if !(force.is_finite() && force <= WARM_START_SCALE * scale.max(f64::MIN_POSITIVE)) {
            return false;
        }
        out[..m].copy_from_slice(&pred[..m]);
        true
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn prediction_is_the_linear_combination_of_the_columns() {
        let mut s = Sensitivity::<4, 2>::new();
        let lq = [1.0, 2.0, 3.0, 9.0];
        s.record(0, &[1.5, 2.0, 2.0, 0.0], &lq, 3, 0.5);
        s.record(1, &[1.0, 3.0, 3.0, 0.0], &lq, 3, 0.5);
        assert!(s.complete(3) && s.is_fresh());
        let mut out = [7.0; 4];
        assert!(s.predict(&lq, &[0.2, -0.1], 3, |_| 1.0, 1.0, &mut out));
        // S_0 = (1, 0, -2), S_1 = (0, 2, 0).
        let want = [1.0 + 0.2, 2.0 - 0.2, 3.0 - 0.4, 7.0];
        for (a, b) in out.iter().zip(&want) {
            assert!((a - b).abs() < 1e-15, "{out:?} against {want:?}");
        }
        // Another row count: no prediction.
        assert!(!s.predict(&lq, &[0.2, -0.1], 2, |_| 1.0, 1.0, &mut out));
        s.age();
        assert!(!s.is_fresh());
        s.clear();
        assert!(!s.predict(&lq, &[0.2, -0.1], 3, |_| 1.0, 1.0, &mut out));
    }

    #[test]
    fn non_finite_or_oversized_columns_predict_nothing() {
        let mut s = Sensitivity::<3, 1>::new();
        let lq = [1.0, 1.0, 1.0];
        s.record(0, &[f64::NAN, 1.0, 1.0], &lq, 3, 0.01);
        assert!(!s.complete(3));
        let mut out = [0.0; 3];
        assert!(!s.predict(&lq, &[1.0], 3, |_| 1.0, 1.0, &mut out));
        // Finite, but a million times the problem's scale: not a start.
        s.record(0, &[1.0e5, 1.0, 1.0], &lq, 3, 0.01);
        assert!(s.complete(3));
        assert!(!s.predict(&lq, &[1.0], 3, |_| 1.0, 1.0, &mut out));
        assert!(s.predict(&lq, &[1.0e-8], 3, |_| 1.0, 1.0, &mut out));
    }
}
