//! The joint update of [`super::StepMethod::Qp`]: the damped least squares of the paper's update
//! posed as a small quadratic program in `Δq` ([`crate::qp`]),
//!
//! ```text
//! minimise   |e + J_e Δq|² + w_θ² (k |φ1 + Φ1 Δq|² + (1 − k) |φ2 + Φ2 Δq|²) + ε² |Δq|²
//! subject to max(lower_i − q_i, −v_i dt) ≤ Δq_i ≤ min(upper_i − q_i, v_i dt)   joint limits and speeds
//!            |(J_tool,v Δq)_j| ≤ max_base_step,  j = x, y, z                     trust region (each axis)
//!            d_k + G_k Δq ≥ clearance_margin                                    obstacle k
//! ```
//!
//! `e` the tip's error to the target, `φ1`, `φ2` the rotation vectors whose norms are the paper's
//! angles θ1 (tip direction to the path's tangent) and θ2 (needle base to the entry point), `k`
//! the paper's blend; `J_e`, `Φ1`, `Φ2` and `G_k = ∂d_k/∂q` from the same finite-difference
//! columns as the paper's `J`; `ε` as in the paper's update (raised near a singularity).
//!
//! Two differences from the paper's update, both measured on the public suite
//! (`docs/benchmark.md`):
//! - the angles enter as the squares of their **rotation vectors**, not as the one residual
//!   `w_θ (k θ1 + (1 − k) θ2)`: a sum of norms cannot reach zero and is not smooth where an angle
//!   vanishes, so a Gauss-Newton step on it overshoots the kink and the angle alternates from
//!   step to step (period-2 chatter of the tip, several mm at its worst); the vectors are smooth
//!   and their least squares has its minimum where the linear model puts it;
//! - limits are rows of the program: the answer is the best step the linear model allows, not a
//!   scaled or clamped copy of the unconstrained one.
//!
//! When the rows have no common point (a clearance already below the margin that the speed
//! limits cannot restore in one step), the clearance rows are relaxed to "no closer than now"
//! (`G_k Δq ≥ min(margin − d_k, 0)`), which `Δq = 0` satisfies; should that fail too, the joints
//! are held and [`StatusFlags::QP_FAILED`] is raised.

use super::step::{Clearances, Jacobian};
use super::{Controller, Objective};
use crate::payload::{ComplianceFrame, NCLEAR, SolverReport, StatusFlags};
use crate::qp::{Qp, QpError};
use nalgebra::Vector4;

/// Largest joint count of the QP update (2 bound rows per joint).
pub const QP_MAX_JOINTS: usize = 9;

/// Row capacity of the program: the joint bounds, 6 trust-region rows, the clearances.
const QP_ROWS: usize = 2 * QP_MAX_JOINTS + 6 + NCLEAR;

/// Which rows of the program are which, to report the active ones.
#[derive(Clone, Copy, Debug, Default)]
struct RowRanges {
    /// First trust-region row, one past the last.
    trust: (usize, usize),
    /// First clearance row, one past the last.
    clearance: (usize, usize),
}

impl<const M: usize, const N: usize> Controller<M, N> {
    /// Stage 4 with [`super::StepMethod::Qp`] (module docs). Returns the commanded joints.
    pub(super) fn qp_step(
        &self,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        report: &mut SolverReport<N>,
    ) -> [f64; N] {
        let t0 = &Vector4::from(obj0.t);
        const {
            assert!(
                N <= QP_MAX_JOINTS,
                "the QP update takes at most QP_MAX_JOINTS joints"
            )
        };
        let eps2 = self.damping_squared(jac, report);
        let mut qp = Qp::<N, QP_ROWS>::new();
        let mut ranges = RowRanges::default();
        let mut solved =
            self.solve_program(&mut qp, frame, jac, clear, obj0, eps2, false, &mut ranges);
        if matches!(solved, Err(QpError::Infeasible { .. })) {
            solved = self.solve_program(&mut qp, frame, jac, clear, obj0, eps2, true, &mut ranges);
        }
        if solved.is_err() || !qp.solution().iter().all(|x| x.is_finite()) {
            report.flags |= StatusFlags::QP_FAILED | StatusFlags::TARGET_UNREACHABLE;
            return frame.q;
        }
        let mut q_new = frame.q;
        let mut dq = nalgebra::SVector::<f64, N>::zeros();
        for (i, x) in qp.solution().iter().enumerate().take(N) {
            dq[i] = *x;
            q_new[i] += *x;
        }
        self.flag_active(frame, &qp, &ranges, &q_new, report);
        let predicted = t0 + jac * dq;
        if predicted.norm() > 0.99 * t0.norm() {
            report.flags |= StatusFlags::TARGET_UNREACHABLE;
        }
        q_new
    }

    /// Fills and solves the program; `relaxed`: the clearance rows ask for "no closer" and the
    /// joint bounds always admit `Δq = 0`.
    #[allow(clippy::too_many_arguments)]
    fn solve_program(
        &self,
        qp: &mut Qp<N, QP_ROWS>,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        eps2: f64,
        relaxed: bool,
        ranges: &mut RowRanges,
    ) -> Result<(), QpError> {
        let p = &self.params;
        qp.reset(N)?;
        let mut row = [0.0; N];
        for r in 0..3 {
            for (i, x) in row.iter_mut().enumerate() {
                *x = jac[(r, i)];
            }
            qp.add_square(&row, obj0.t[r], 1.0);
        }
        let w2 = p.angle_weight * p.angle_weight;
        let angles = [
            (&clear.phi1, &obj0.phi1, obj0.k),
            (&clear.phi2, &obj0.phi2, 1.0 - obj0.k),
        ];
        for (dphi, phi, weight) in angles {
            if weight > 0.0 {
                for r in 0..3 {
                    for (i, x) in row.iter_mut().enumerate() {
                        *x = dphi[(r, i)];
                    }
                    qp.add_square(&row, phi[r], w2 * weight);
                }
            }
        }
        qp.add_diagonal(2.0 * eps2);
        let (mut lower, mut upper) = ([0.0; N], [0.0; N]);
        for i in 0..N {
            let l = &self.chain.limits[i];
            let v = l.max_speed * frame.dt;
            let q = frame.q[i];
            lower[i] = (l.lower - q).max(-v).min(v);
            upper[i] = (l.upper - q).min(v).max(-v);
            if relaxed {
                lower[i] = lower[i].min(0.0);
                upper[i] = upper[i].max(0.0);
            }
        }
        qp.add_bounds(&lower, &upper)?;
        let start = qp.rows();
        if p.max_base_step.is_finite() {
            let (jt, _) = self.chain.jacobian_tool(&frame.q);
            for j in 0..3 {
                for (i, x) in row.iter_mut().enumerate() {
                    *x = jt[(j, i)];
                }
                qp.add_row(&row, -p.max_base_step)?;
                for x in row.iter_mut() {
                    *x = -*x;
                }
                qp.add_row(&row, -p.max_base_step)?;
            }
        }
        ranges.trust = (start, qp.rows());
        let start = qp.rows();
        for k in 0..clear.count {
            let need = p.clearance_margin - clear.value[k];
            let b = if relaxed { need.min(0.0) } else { need };
            qp.add_row(&clear.gradient[k], b)?;
        }
        ranges.clearance = (start, qp.rows());
        qp.solve().map(|_| ())
    }

    /// Sets the report's flags from the rows active at the solution.
    fn flag_active(
        &self,
        frame: &ComplianceFrame<M, N>,
        qp: &Qp<N, QP_ROWS>,
        ranges: &RowRanges,
        q_new: &[f64; N],
        report: &mut SolverReport<N>,
    ) {
        let any = |(a, b): (usize, usize)| (a..b).any(|k| qp.is_active(k));
        if any(ranges.trust) {
            report.flags |= StatusFlags::STEP_LIMITED;
        }
        if any(ranges.clearance) {
            report.flags |= StatusFlags::CLEARANCE_ACTIVE;
        }
        for i in 0..N {
            let l = &self.chain.limits[i];
            let v = l.max_speed * frame.dt;
            let dq = q_new[i] - frame.q[i];
            if libm::fabs(dq) >= v * (1.0 - 1e-9) {
                report.flags |= StatusFlags::SATURATED_SPEED;
            }
            if q_new[i] >= l.upper - 1e-12 || q_new[i] <= l.lower + 1e-12 {
                report.flags |= StatusFlags::SATURATED_LIMIT;
            }
        }
    }
}
