//! The joint update of [`super::StepMethod::Qp`]: the tip's position first, the angles in the
//! joint motion that remains, each stage a small quadratic program in `Δq` ([`crate::qp`]),
//! both under the same rows:
//!
//! ```text
//! stage 1   minimise |e + J_e Δq|² + ε² |Δq|²                                   → Δq₁
//! stage 2   Δq = Δq₁ + P y,  P = I − J_eᵀ (J_e J_eᵀ + ε² I)⁻¹ J_e,
//!           minimise w² (h |φ1 + Φ1 Δq|² + (1 − k) |φ2 + Φ2 Δq|²) + ε² |y|²
//! stage 3   (N > 6 only) Δq = Δq₂ + P₃ y, P₃ the projector on the null space of [J_e; w √h Φ1;
//!           w √(1 − k) Φ2], minimise w² |P₃ y − g|² + ε² |y|², g_i = −κ x_i v_i dt with
//!           x_i = (q_i − mid_i) / half range_i, κ = InverseParams::limit_avoidance
//! + every stage   w_s² (ẑᵀ J_ω Δq)²   the needle's spin about its own axis (w_s > 0 only)
//! rows      max(lower_i − q_i, −v_i dt) ≤ Δq_i ≤ min(upper_i − q_i, v_i dt)   joint limits and speeds
//!           |(J_tool,v Δq)_j| ≤ max_base_step,  j = x, y, z                     trust region (each axis)
//!           |((J_tool,v − [r]× J_ω) Δq)_j| ≤ max_base_step   before the puncture: the tip as part
//!                                                            of a rigid needle, r = tip − base
//!           d_k + G_k Δq ≥ clearance_margin                                    obstacle k
//! ```
//!
//! `e` the tip's error to the target (with [`super::InverseParams::qp_horizon`] `S` > 0, once
//! inserted, predicted `S` further along, `e + S (t̂ − ĥ)`: the target along the path's tangent,
//! the tip along its heading; `J_e` its derivative, from the same differences), `φ1`, `φ2` the
//! rotation vectors whose norms are the paper's angles θ1 (tip direction to the path's tangent)
//! and θ2 (needle base to the entry point), `k` the paper's blend, `h` = 1
//! ([`super::InverseParams::qp_heading`], the default) or `k` (the paper's blend), `w` [`super::InverseParams::qp_angle_weight`]; `ẑ` the tool's (the needle's)
//! axis, `J_ω` the tool's angular Jacobian, `w_s` [`super::InverseParams::qp_spin_weight`] (a
//! round needle's spin moves neither its tip nor its angles, so without the term only the
//! damping holds it; 0 by default, the term left out); `J_e`, `Φ1`, `Φ2` and
//! `G_k = ∂d_k/∂q` from the same finite-difference columns as the paper's `J`; `ε` as in the
//! paper's update (raised near a singularity; in stage 2's `ε² |y|²` by at most
//! [`super::InverseParams::qp_angle_damping_max`]). `P` projects on the (damped) null space of `J_e`,
//! so stage 2 leaves the tip's predicted position where stage 1 put it; `y = 0` is stage 1's
//! step, so stage 2 is feasible whenever stage 1 is.
//!
//! Differences from the paper's update, all measured on the public suite and the held-out
//! scenes (`docs/benchmark.md`):
//! - **priority instead of a weighted sum.** The paper's objective weighs the angles against the
//!   tip error (`w_θ` = 100 mm/rad: 1° counts like 1.75 mm). Shallower than the blend depth the
//!   tip and both angles ask for 7 independent motions of 6 joints, so the tip lags (simple
//!   scene, 5–20 mm deep: 0.2–0.5 mm behind with one weighted program, 0.08 mm with the paper's
//!   scalar angle). Ranked, the tip gets what the joints can give and the angles the rest.
//! - **the angles as rotation vectors**, not the one residual `w_θ (k θ1 + (1 − k) θ2)`: a sum of
//!   norms cannot reach zero and is not smooth where an angle vanishes, so a Gauss-Newton step on
//!   it overshoots the kink and the angle alternates from step to step (period-2 chatter);
//! - **limits are rows of the program**: the answer is the best step the linear model allows,
//!   not a scaled or clamped copy of the unconstrained one;
//! - **the heading θ1 counts at every depth** (`h` = 1), where the paper's blend drops it beyond
//!   `blend_depth`: deep in the gel the sliding points hold the shaft and the direction in which
//!   the tip cuts is what steers it;
//! - **the constrained model confirms the step** before it is sent ([`super::Controller::step`]'s stage 5):
//!   a step whose constraint solve leaves the tip's error short of a tenth of the promised
//!   decrease, or an obstacle closer than the margin, is replaced by the first stage's step,
//!   then halved, then the joints are held.
//!
//! When the rows have no common point (a clearance already below the margin that the speed
//! limits cannot restore in one step), the clearance rows are relaxed to "no closer than now"
//! (`G_k Δq ≥ min(margin − d_k, 0)`), which `Δq = 0` satisfies; should that fail too, the joints
//! are held and [`StatusFlags::QP_FAILED`] is raised. Should stage 2 fail (round-off), stage 1's
//! step stands.

use super::step::{Clearances, Jacobian};
use super::{Controller, Objective};
use crate::kinematics::Kinematics;
use crate::payload::{ComplianceFrame, NCLEAR, ObsIndex, SolverReport, StatusFlags};
use crate::qp::{Qp, QpError};
use nalgebra::{SMatrix, SVector, Vector3, Vector4};

/// Weight `h` of the heading θ1 in the second stage: 1 with
/// [`super::InverseParams::qp_heading`], else the paper's blend `k`.
fn heading_weight(obj0: &Objective, p: &super::InverseParams) -> f64 {
    if p.qp_heading { 1.0 } else { obj0.k }
}

/// Largest joint count of the QP update (2 bound rows per joint).
pub const QP_MAX_JOINTS: usize = 9;

/// Row capacity of the program: the joint bounds, 12 trust-region rows (the needle's base, and
/// its tip before the puncture), the clearances.
const QP_ROWS: usize = 2 * QP_MAX_JOINTS + 12 + NCLEAR;

/// Which rows of the program are which, to report the active ones.
#[derive(Clone, Copy, Debug, Default)]
struct RowRanges {
    /// First trust-region row, one past the last.
    trust: (usize, usize),
    /// First clearance row, one past the last.
    clearance: (usize, usize),
}

/// Rows from the tool's Jacobian, the same in every stage.
#[derive(Default)]
pub(super) struct ToolRows<const N: usize> {
    /// The translational rows `J_tool,v` (the trust region), with a finite `max_base_step`.
    trust: Option<SMatrix<f64, 3, N>>,
    /// Before the puncture (the frame not inserted), the tip's motion were the needle a rigid
    /// body carried by the tool, `J_tool,v − [r]× J_ω` (`r` the free motion's tip less the
    /// needle base), bounded like the base's: the tip is then held at most by a one-sided
    /// contact with the surface, which a turn of the needle about its base lifts it off (public
    /// `tilt_large`: 17.8 mm into the air in one step with the base's bound alone). Once
    /// inserted, the gel holds the shaft and the rigid motion is no bound of the real one (kept
    /// then, 5 targets fewer of 609 were reached: `docs/benchmark.md`).
    pub(super) tip: Option<SMatrix<f64, 3, N>>,
    /// `ẑᵀ J_ω`: the needle's spin about its axis per unit `Δq`, with a positive
    /// `qp_spin_weight`.
    spin: Option<[f64; N]>,
}

/// What a stage minimises.
#[derive(Clone, Copy, PartialEq)]
enum Goal<const N: usize> {
    /// Stage 1: the tip's position.
    Position,
    /// Stage 2: the two angles.
    Angles,
    /// Stage 3 (more than 6 joints): `|P y − g|²`, `g` the step away from the joint limits.
    Limits([f64; N]),
}

/// The change of variables of a stage: `Δq = Δq₀ + P y`.
struct Stage<const N: usize> {
    goal: Goal<N>,
    dq0: SVector<f64, N>,
    p: SMatrix<f64, N, N>,
}

/// `I − Aᵀ (A Aᵀ + ε² I)⁻¹ A`, the (damped) projector on the null space of `A`; `None` when it
/// is not finite.
fn null_projector<const R: usize, const N: usize>(
    a: &SMatrix<f64, R, N>,
    eps2: f64,
) -> Option<SMatrix<f64, N, N>> {
    let aat: SMatrix<f64, R, R> =
        a * a.transpose() + SMatrix::<f64, R, R>::identity() * eps2.max(1e-12);
    let x: SMatrix<f64, R, N> = aat.cholesky()?.solve(a);
    let p = SMatrix::<f64, N, N>::identity() - a.transpose() * x;
    p.iter().all(|v| v.is_finite()).then_some(p)
}

impl<const N: usize> Stage<N> {
    /// Stage 1: `Δq = y`.
    fn identity() -> Self {
        Self {
            goal: Goal::Position,
            dq0: SVector::zeros(),
            p: SMatrix::identity(),
        }
    }

    /// Stage 2: `Δq = Δq₁ + P y`, `P = I − J_eᵀ (J_e J_eᵀ + ε² I)⁻¹ J_e` the (damped) projector
    /// on the null space of the tip's position Jacobian. `None` when the 3 × 3 system is not
    /// positive definite (non-finite `J`).
    fn null_space(jac: &Jacobian<N>, dq1: SVector<f64, N>, eps2: f64) -> Option<Self> {
        let je: SMatrix<f64, 3, N> = jac.fixed_rows::<3>(0).into_owned();
        Some(Self {
            goal: Goal::Angles,
            dq0: dq1,
            p: null_projector(&je, eps2)?,
        })
    }

    /// Stage 3: `Δq = Δq₂ + P y`, `P` the projector on the null space of the whole task (the tip's position and the angles that count, each weighed as in its stage), the
    /// goal `g` a step away from the joint limits (regularised by 1e-9 of the largest row
    /// norm², not by the step's damping). `None` when `P` is not finite.
    fn limits(
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        (w, h): (f64, f64),
        dq2: SVector<f64, N>,
        g: [f64; N],
    ) -> Option<Self> {
        let mut a = SMatrix::<f64, 9, N>::zeros();
        a.fixed_rows_mut::<3>(0).copy_from(&jac.fixed_rows::<3>(0));
        a.fixed_rows_mut::<3>(3)
            .copy_from(&(clear.phi1 * (w * libm::sqrt(h.max(0.0)))));
        a.fixed_rows_mut::<3>(6)
            .copy_from(&(clear.phi2 * (w * libm::sqrt((1.0 - obj0.k).max(0.0)))));
        // Nearly exact: the step's damping (raised near a singularity) would let the stage
        // move the task's weakest directions.
        let scale = (a * a.transpose()).diagonal().max();
        Some(Self {
            goal: Goal::Limits(g),
            dq0: dq2,
            p: null_projector(&a, 1e-9 * scale)?,
        })
    }

    /// `w (cᵀ Δq + e)²` in `y`.
    fn square<const C: usize>(&self, qp: &mut Qp<N, C>, c: &[f64; N], e: f64, w: f64) {
        let c = SVector::<f64, N>::from(*c);
        let cy: SVector<f64, N> = self.p.transpose() * c;
        qp.add_square(cy.as_slice(), e + c.dot(&self.dq0), w);
    }

    /// `aᵀ Δq ≥ b` in `y`.
    fn row<const C: usize>(
        &self,
        qp: &mut Qp<N, C>,
        a: &[f64; N],
        b: f64,
    ) -> Result<usize, QpError> {
        let a = SVector::<f64, N>::from(*a);
        let ay: SVector<f64, N> = self.p.transpose() * a;
        qp.add_row(ay.as_slice(), b - a.dot(&self.dq0))
    }

    /// `Δq` for the program's solution `y`.
    fn dq<const C: usize>(&self, qp: &Qp<N, C>) -> SVector<f64, N> {
        let mut y = SVector::<f64, N>::zeros();
        for (i, x) in qp.solution().iter().enumerate().take(N) {
            y[i] = *x;
        }
        self.dq0 + self.p * y
    }
}

impl<const M: usize, const N: usize> Controller<M, N> {
    /// Stage 4 with [`super::StepMethod::Qp`] (module docs). Returns the commanded joints and
    /// the first stage's step `Δq₁` (the tip alone), the fallback of [`Self::step`]'s
    /// confirmation.
    pub(super) fn qp_step(
        &self,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        report: &mut SolverReport<N>,
    ) -> ([f64; N], SVector<f64, N>) {
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
        let tool = self.tool_rows(frame);
        let solve = |qp: &mut Qp<N, QP_ROWS>, relaxed, stage: &Stage<N>, ranges: &mut RowRanges| {
            self.solve_program(
                qp, frame, jac, clear, obj0, eps2, relaxed, stage, &tool, ranges,
            )
        };
        // Stage 1: the tip's position.
        let first = Stage::identity();
        let mut relaxed = false;
        let mut solved = solve(&mut qp, relaxed, &first, &mut ranges);
        if matches!(solved, Err(QpError::Infeasible { .. })) {
            relaxed = true;
            solved = solve(&mut qp, relaxed, &first, &mut ranges);
        }
        let dq1 = first.dq(&qp);
        if solved.is_err() || !dq1.iter().all(|x| x.is_finite()) {
            report.flags |= StatusFlags::QP_FAILED | StatusFlags::TARGET_UNREACHABLE;
            return (frame.q, SVector::zeros());
        }
        self.flag_active(&qp, &ranges, report);
        // Stage 2: the angles, in what the position leaves free. Should it fail (round-off), the
        // first stage's step stands.
        let mut dq = dq1;
        if let Some(second) = Stage::null_space(jac, dq1, eps2)
            && solve(&mut qp, relaxed, &second, &mut ranges).is_ok()
        {
            let dq2 = second.dq(&qp);
            if dq2.iter().all(|x| x.is_finite()) {
                dq = dq2;
                self.flag_active(&qp, &ranges, report);
            }
        }
        // Stage 3, a redundant arm only: away from the joint limits in the motion that leaves
        // the tip and the angles where the first two stages put them (to first order).
        let gain = self.params.limit_avoidance;
        if N > 6 && gain > 0.0 {
            let g = self.away_from_limits(frame, gain);
            let w = self.params.qp_angle_weight;
            if let Some(third) = Stage::limits(
                jac,
                clear,
                obj0,
                (w, heading_weight(obj0, &self.params)),
                dq,
                g,
            ) && solve(&mut qp, relaxed, &third, &mut ranges).is_ok()
            {
                let dq3 = third.dq(&qp);
                if dq3.iter().all(|x| x.is_finite()) {
                    dq = dq3;
                }
            }
        }
        let mut q_new = frame.q;
        for (i, x) in dq.iter().enumerate() {
            q_new[i] += *x;
        }
        self.flag_saturated(frame, &q_new, report);
        // Unreachable: the step cannot bring the tip closer (the angles rank second, so they
        // do not count here).
        let predicted = (t0 + jac * dq).fixed_rows::<3>(0).norm();
        let e = t0.fixed_rows::<3>(0).norm();
        if e * e > self.params.tolerance && predicted > 0.99 * e {
            report.flags |= StatusFlags::TARGET_UNREACHABLE;
        }
        (q_new, dq1)
    }

    /// Fills and solves the program of a stage: its objective (stage 1 the tip's position,
    /// stage 2 the angles) and every row, in the stage's variables. `relaxed`: the clearance rows
    /// ask for "no closer" and the joint bounds always admit `Δq = 0`.
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
        stage: &Stage<N>,
        tool: &ToolRows<N>,
        ranges: &mut RowRanges,
    ) -> Result<(), QpError> {
        let p = &self.params;
        qp.reset(N)?;
        let mut row = [0.0; N];
        if let Goal::Limits(g) = stage.goal {
            // |P y − g|²: `square` adds Δq₂ to the constant, so it is taken off here.
            let w2 = p.qp_angle_weight * p.qp_angle_weight;
            for i in 0..N {
                row.fill(0.0);
                row[i] = 1.0;
                stage.square(qp, &row, -g[i] - stage.dq0[i], w2);
            }
        } else if stage.goal == Goal::Position {
            for r in 0..3 {
                for (i, x) in row.iter_mut().enumerate() {
                    *x = jac[(r, i)];
                }
                stage.square(qp, &row, obj0.t[r], 1.0);
            }
        } else {
            let w2 = p.qp_angle_weight * p.qp_angle_weight;
            let angles = [
                (&clear.phi1, &obj0.phi1, heading_weight(obj0, p)),
                (&clear.phi2, &obj0.phi2, 1.0 - obj0.k),
            ];
            for (dphi, phi, weight) in angles {
                if weight > 0.0 {
                    for r in 0..3 {
                        for (i, x) in row.iter_mut().enumerate() {
                            *x = dphi[(r, i)];
                        }
                        stage.square(qp, &row, phi[r], w2 * weight);
                    }
                }
            }
        }
        // The angles' stage damped by at most `qp_angle_damping_max` (the field's docs); the
        // tip's and the limits' stages by the step's `ε`.
        let eps2 = if stage.goal == Goal::Angles {
            let cap = p.qp_angle_damping_max;
            eps2.min((cap * cap).max(p.damping * p.damping))
        } else {
            eps2
        };
        qp.add_diagonal(2.0 * eps2);
        // The needle's spin about its own axis, which neither the tip nor the angles hold.
        if let Some(spin) = &tool.spin {
            stage.square(qp, spin, 0.0, p.qp_spin_weight * p.qp_spin_weight);
        }
        for i in 0..N {
            let l = &self.robot.limits()[i];
            let v = l.max_speed * frame.dt;
            let q = frame.q[i];
            let mut lower = (l.lower - q).max(-v).min(v);
            let mut upper = (l.upper - q).min(v).max(-v);
            if relaxed {
                lower = lower.min(0.0);
                upper = upper.max(0.0);
            }
            row.fill(0.0);
            if lower > f64::NEG_INFINITY {
                row[i] = 1.0;
                stage.row(qp, &row, lower)?;
            }
            if upper < f64::INFINITY {
                row[i] = -1.0;
                stage.row(qp, &row, -upper)?;
            }
        }
        let start = qp.rows();
        for jt in tool.trust.iter().chain(tool.tip.iter()) {
            for j in 0..3 {
                for (i, x) in row.iter_mut().enumerate() {
                    *x = jt[(j, i)];
                }
                stage.row(qp, &row, -p.max_base_step)?;
                for x in row.iter_mut() {
                    *x = -*x;
                }
                stage.row(qp, &row, -p.max_base_step)?;
            }
        }
        ranges.trust = (start, qp.rows());
        let start = qp.rows();
        for k in 0..clear.count {
            let need = self.margin() - clear.value[k];
            let b = if relaxed { need.min(0.0) } else { need };
            stage.row(qp, &clear.gradient[k], b)?;
        }
        ranges.clearance = (start, qp.rows());
        qp.solve().map(|_| ())
    }

    /// The rows of the tool's Jacobian the stages need: the trust region's (with a finite
    /// `max_base_step`: the base's, and before the puncture the tip's as part of a rigid needle)
    /// and the needle's spin about its axis (with a positive `qp_spin_weight`).
    pub(super) fn tool_rows(&self, frame: &ComplianceFrame<M, N>) -> ToolRows<N> {
        let p = &self.params;
        let spin_on = p.qp_spin_weight > 0.0;
        if !spin_on && !p.max_base_step.is_finite() {
            return ToolRows::default();
        }
        let (jt, pose) = self.robot.jacobian_tool(&frame.q);
        let z = pose.z_axis();
        let tip = Vector3::from_column_slice(&frame.o_free[ObsIndex::TIP_POSITION..][..3]);
        let r = tip - pose.translation;
        // v_tip = v + ω × r = v − r × ω.
        let tip_rows =
            frame.inserted == 0 && p.max_base_step.is_finite() && r.iter().all(|x| x.is_finite());
        let tip_rows = tip_rows.then(|| {
            let jv = jt.fixed_rows::<3>(0);
            let jw = jt.fixed_rows::<3>(3);
            jv - r.cross_matrix() * jw
        });
        let mut spin = [0.0; N];
        for (i, x) in spin.iter_mut().enumerate() {
            *x = z[0] * jt[(3, i)] + z[1] * jt[(4, i)] + z[2] * jt[(5, i)];
        }
        ToolRows {
            trust: p
                .max_base_step
                .is_finite()
                .then(|| jt.fixed_rows::<3>(0).into_owned()),
            tip: tip_rows,
            spin: spin_on.then_some(spin),
        }
    }

    /// The step of stage 3: each joint towards the middle of its range, `gain` times its
    /// normalised distance from the middle times its speed budget `v_i dt` [rad] (0 for a joint
    /// without finite limits).
    fn away_from_limits(&self, frame: &ComplianceFrame<M, N>, gain: f64) -> [f64; N] {
        let mut g = [0.0; N];
        for (i, l) in self.robot.limits().iter().enumerate() {
            let half = 0.5 * (l.upper - l.lower);
            if half.is_finite() && half > 0.0 {
                let x = (frame.q[i] - l.mid()) / half;
                g[i] = -gain * x * l.max_speed * frame.dt;
            }
        }
        g
    }

    /// Sets the report's flags from the rows active at the solution.
    fn flag_active(&self, qp: &Qp<N, QP_ROWS>, ranges: &RowRanges, report: &mut SolverReport<N>) {
        let any = |(a, b): (usize, usize)| (a..b).any(|k| qp.is_active(k));
        if any(ranges.trust) {
            report.flags |= StatusFlags::STEP_LIMITED;
        }
        if any(ranges.clearance) {
            report.flags |= StatusFlags::CLEARANCE_ACTIVE;
        }
    }

    /// Sets the report's flags of joints at a speed or position limit.
    fn flag_saturated(
        &self,
        frame: &ComplianceFrame<M, N>,
        q_new: &[f64; N],
        report: &mut SolverReport<N>,
    ) {
        for i in 0..N {
            let l = &self.robot.limits()[i];
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
