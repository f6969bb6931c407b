//! One inverse step, stage by stage ([`Controller::step`]), and the open-loop solve.

use super::solves::{Start, Target};
use super::{Controller, Objective, StepError, evaluate_objective};
use crate::constraint::SolveReport;
use crate::kinematics::Kinematics;
use crate::payload::{Command, ComplianceFrame, NCLEAR, SolverReport, StatusFlags, VERSION};
use nalgebra::{Matrix4, SMatrix, SVector, Vector4};

/// Largest ratio of the previous answer's force scale to a frame's `‖δ‖∞` for which the previous
/// answer warm-starts the frame's solves (consecutive frames of one insertion differ by far
/// less; a frame a million times off is abnormal, and so is the answer it produced).
pub const WARM_START_SCALE: f64 = 1e6;

/// Fraction of the tip error decrease the linear model promised that the constraint solve at
/// the planned joints must confirm for the [`super::StepMethod::Qp`] step to be kept (the
/// Armijo constant of a line search; small, so that only a step that does clearly worse than
/// its model is shortened).
pub const SUFFICIENT_DECREASE: f64 = 0.1;

/// Most halvings of the first stage's step `Δq₁` of a [`super::StepMethod::Qp`] step whose
/// final solve did not confirm it, before the joints are held.
pub const MAX_BACKTRACKS: usize = 3;

/// Most halvings of `Δq₁` a step at the joints of a held one goes to
/// ([`super::InverseParams::resume_held`]): after two held steps in a row at the same joints,
/// `Δq₁` down to 2⁻¹¹ of itself (beyond, a step at those joints tries the same candidates: the
/// tip's change along such a step is a thousandth of the full step's).
pub const MAX_HELD_HALVINGS: u32 = 2 * (MAX_BACKTRACKS as u32 + 1) + MAX_BACKTRACKS as u32;

/// Most re-plans of a rejected [`super::StepMethod::Qp`] step with the secant-corrected model
/// (with [`super::InverseParams::replan_rejected`]), before the first stage's step is tried.
pub const MAX_REPLANS: usize = 2;

/// The Jacobian `∂T/∂q`, 4 × N [mm/rad].
pub(super) type Jacobian<const N: usize> = SMatrix<f64, 4, N>;

/// What the QP update uses beyond `J`, from the same finite-difference columns: the frame's
/// obstacle clearances and the two rotation vectors of the angular objective, at the frame's
/// joints and their derivatives.
#[derive(Clone, Copy, Debug)]
pub(super) struct Clearances<const N: usize> {
    /// Number of clearances used (the frame's `clearance_count`).
    pub count: usize,
    /// `d_k(q)` [mm].
    pub value: [f64; NCLEAR],
    /// `∂d_k/∂q_i` [mm/rad].
    pub gradient: [[f64; N]; NCLEAR],
    /// `∂φ1/∂q` (tip direction to target tangent) [rad/rad].
    pub phi1: SMatrix<f64, 3, N>,
    /// `∂φ2/∂q` (base direction to entry direction) [rad/rad].
    pub phi2: SMatrix<f64, 3, N>,
}

impl<const M: usize, const N: usize> Controller<M, N> {
    /// One inverse step for `frame`, written into the caller-owned `cmd`. Allocates nothing.
    ///
    /// The stages (module docs for the equations):
    /// 1. validate the parameters and the frame, factor the diagonal blocks, warm start
    ///    (`prepare`);
    /// 2. base solve at the frame's joints and its objective `T(q)` (`base_solve`);
    ///    within tolerance: hold (`hold`) and skip to 6;
    /// 3. Jacobian by forward differences (`jacobian`);
    /// 4. damped Newton step within the trust region, speed and joint limits
    ///    (`newton_step`);
    /// 5. final solve at the commanded joints (`final_solve`); with the QP update, once
    ///    inserted, the step is kept only when that solve confirms it, else shortened or the
    ///    joints held (`accept_step`), 1–5 more solves;
    /// 6. answer: check and write the command (`answer`).
    ///
    /// # Errors
    /// [`StepError`] when the frame or the parameters are invalid, `W` is not positive
    /// definite, or a result is not finite; `cmd` is then untouched.
    ///
    /// # Example
    /// ```
    /// use needle_core::synthetic::random_frame;
    /// use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};
    ///
    /// let chain = DhChain::rv1a();
    /// let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    /// // 30 rows: the 6 base rows, a tip contact and sliding points, W random SPD.
    /// let mut frame = ComplianceFrame::<48>::new_boxed();
    /// random_frame(&mut frame, &chain, &q, 30, 1, true);
    /// let mut cmd = Command::<48>::new_boxed();
    /// let mut ctrl = Controller::<48>::new_boxed(chain, InverseParams::default());
    ///
    /// let report = ctrl.step(&frame, &mut cmd)?;
    /// assert_eq!(report.solves, 8); // base solve, 6 Jacobian columns, final solve
    /// assert_eq!(cmd.frame_sequence, frame.sequence);
    /// assert!(cmd.lambda[..30].iter().all(|l| l.is_finite()));
    /// // The commanded motion respects every joint's speed limit.
    /// for (dq, limit) in report.delta_q.iter().zip(&chain.limits) {
    ///     assert!(dq.abs() <= limit.max_speed * frame.dt * (1.0 + 1e-12));
    /// }
    /// # Ok::<(), needle_core::StepError>(())
    /// ```
    pub fn step(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        cmd: &mut Command<M, N>,
    ) -> Result<SolverReport<N>, StepError> {
        let m = self.prepare(frame)?;
        let resume = self.resume_held(frame);
        self.held.halvings = 0;
        let mut report = SolverReport::default();
        let (obj0, base_rep) = self.base_solve(frame, &mut report);
        let (q_new, final_rep) = if Vector4::from(obj0.t).norm_squared() <= self.params.tolerance {
            self.hold(m, &obj0, &mut report);
            self.settling.observe(None);
            (frame.q, base_rep)
        } else {
            let (jac, clear) = self.jacobian(frame, &obj0, &mut report);
            self.settling
                .observe((0..clear.count).map(|k| clear.value[k]).reduce(f64::min));
            let (q_new, dq1) = self.newton_step(frame, &jac, &clear, &obj0, &mut report);
            let kept = self.accept_step(
                frame,
                &jac,
                &clear,
                &obj0,
                (q_new, dq1, resume),
                base_rep,
                &mut report,
            );
            // The smallest clearance the answer's λ predicts, for the next frame's comparison.
            if let Some(c) = (0..clear.count)
                .map(|k| frame.clearance(k, &self.lambda.work))
                .reduce(f64::min)
            {
                self.settling.predicted = c;
                self.settling.known = true;
            }
            kept
        };
        self.answer(frame, &q_new, &final_rep, report, cmd)
    }

    /// The obstacle margin of this step: `clearance_margin`, widened by the settling allowance
    /// with [`super::InverseParams::settling_margin`].
    pub(super) fn margin(&self) -> f64 {
        let p = &self.params;
        if p.settling_margin && p.method == super::StepMethod::Qp {
            p.clearance_margin + self.settling.allowance
        } else {
            p.clearance_margin
        }
    }

    /// Stage 1: validates the parameters and the frame, factors the diagonal blocks (of the
    /// reduced problem when the base rows are eliminated) and warm-starts `λ_q` from the previous
    /// step's answer. Returns `m`.
    fn prepare(&mut self, frame: &ComplianceFrame<M, N>) -> Result<usize, StepError> {
        self.params.validate()?;
        self.prepare_blocks(frame)?;
        let m = frame.rows();
        self.delta[..m].copy_from_slice(&frame.delta_free[..m]);
        let warm = self.params.warm_start && self.warm_start_fits(frame, m);
        self.sens.age();
        if !warm || !self.params.sensitivity_start {
            self.sens.clear();
        }
        let l = &mut self.lambda;
        if warm {
            let n = l.prev_rows.min(m);
            l.base[..n].copy_from_slice(&l.prev[..n]);
            l.base[n..m].fill(0.0);
        } else {
            l.base[..m].fill(0.0);
        }
        Ok(m)
    }

    /// Whether the previous answer may start this frame's solves: there is one, and its force
    /// scale `max |W_ii λ_i|` is within [`WARM_START_SCALE`] of this frame's `‖δ‖∞`. A warm start
    /// from an abnormal frame (`δ = 10³⁰⁰`) would otherwise enter the solver's convergence scale
    /// and let wrong answers pass as converged for many frames.
    fn warm_start_fits(&self, frame: &ComplianceFrame<M, N>, m: usize) -> bool {
        let l = &self.lambda;
        let n = l.prev_rows.min(m);
        if n == 0 {
            return false;
        }
        let delta = frame.delta_free[..m]
            .iter()
            .fold(0.0_f64, |a, d| a.max(libm::fabs(*d)));
        let force = (0..n).fold(0.0_f64, |a, i| a.max(libm::fabs(frame.w[i][i] * l.prev[i])));
        force.is_finite() && force <= WARM_START_SCALE * delta.max(f64::MIN_POSITIVE)
    }

    /// Stage 2: `λ_q` at the frame's joints and the objective `T(q)` there.
    fn base_solve(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        report: &mut SolverReport<N>,
    ) -> (Objective, SolveReport) {
        let tolerance = self.params.gs.tolerance;
        let (b0, rep) = self.solve(frame, &frame.q, Target::Base, Start::Current, tolerance);
        count_solve(report, &rep);
        let obj0 = evaluate_objective(frame, &self.lambda.base, &b0, &self.params);
        report.objective = obj0.t;
        (obj0, rep)
    }

    /// The halvings of `Δq₁` the last step tried when it held the joints and this frame comes
    /// at the same joints ([`super::InverseParams::resume_held`]); 0 otherwise.
    fn resume_held(&self, frame: &ComplianceFrame<M, N>) -> u32 {
        let h = &self.held;
        if self.params.resume_held && h.halvings > 0 && h.q == frame.q {
            h.halvings
        } else {
            0
        }
    }

    /// Within tolerance: no motion, `λ_q` is the answer.
    fn hold(&mut self, m: usize, obj0: &Objective, report: &mut SolverReport<N>) {
        report.flags |= StatusFlags::WITHIN_TOLERANCE;
        self.lambda.work[..m].copy_from_slice(&self.lambda.base[..m]);
        report.objective_after = obj0.t;
    }

    /// Stage 3: `J_i = (T(q + δq e_i) − T(q)) / δq` with `W` fixed, each column from a solve
    /// started at the prediction, or from the prediction alone when linearised
    /// ([`super::JacobianMode`]); the angular row through the rotation vectors
    /// ([`Objective::angle_derivative`]).
    fn jacobian(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        obj0: &Objective,
        report: &mut SolverReport<N>,
    ) -> (Jacobian<N>, Clearances<N>) {
        let p = self.params;
        let mut clear = self.clearances_at_base(frame);
        let linearize = match p.jacobian {
            super::JacobianMode::Solve => false,
            super::JacobianMode::Linearized => true,
            super::JacobianMode::Hybrid => frame.inserted == 0,
        };
        let linear = linearize && self.factor_linearized(frame);
        let tolerance = p.jacobian_tolerance.max(p.gs.tolerance);
        let mut jac = Jacobian::<N>::zeros();
        let qs: [[f64; N]; N] = core::array::from_fn(|i| {
            let mut qi = frame.q;
            qi[i] += p.joint_step;
            qi
        });
        let columns = if linear {
            None
        } else {
            self.solve_columns(frame, &qs, tolerance)
        };
        for (i, qi) in qs.iter().enumerate() {
            let bi = if linear {
                report.solves += 1;
                self.predict_at(frame, qi)
            } else if let Some((poses, ds, reps, from_sens)) = &columns {
                let mut r = self.finish_column(frame, i, &ds[i], reps[i], tolerance);
                if *from_sens && !r.converged {
                    // As `solve` does: again from `λ_q` (this step's sensitivities are not
                    // taken yet), the sweeps of both counted.
                    let (_, again) =
                        self.solve(frame, qi, Target::Work, Start::Predicted, tolerance);
                    let iterations = r.iterations.saturating_add(again.iterations);
                    r = SolveReport {
                        iterations,
                        ..again
                    };
                }
                count_solve(report, &r);
                poses[i]
            } else {
                let (bi, r) = self.solve(frame, qi, Target::Work, Start::Predicted, tolerance);
                count_solve(report, &r);
                bi
            };
            self.record_column(frame, obj0, &bi, i, (&mut jac, &mut clear));
            let m = frame.rows();
            self.sens
                .record(i, &self.lambda.work, &self.lambda.base, m, p.joint_step);
        }
        if self.params.sensitivity_start {
            self.sens.complete(frame.rows());
        }
        (jac, clear)
    }

    /// The frame's clearances at `λ_q`, their derivatives not yet taken.
    fn clearances_at_base(&self, frame: &ComplianceFrame<M, N>) -> Clearances<N> {
        let mut clear = Clearances {
            count: frame.clearances(),
            value: [0.0; NCLEAR],
            gradient: [[0.0; N]; NCLEAR],
            phi1: SMatrix::zeros(),
            phi2: SMatrix::zeros(),
        };
        for k in 0..clear.count {
            clear.value[k] = frame.clearance(k, &self.lambda.base);
        }
        clear
    }

    /// Column `i` of `J` and of the clearances' and angles' derivatives, from the solution at
    /// `q + δq e_i` in `lambda.work` with the needle base at `bi`.
    fn record_column(
        &self,
        frame: &ComplianceFrame<M, N>,
        obj0: &Objective,
        bi: &crate::kinematics::Pose,
        i: usize,
        (jac, clear): (&mut Jacobian<N>, &mut Clearances<N>),
    ) {
        let p = &self.params;
        let ti = evaluate_objective(frame, &self.lambda.work, bi, p);
        for r in 0..3 {
            jac[(r, i)] = (ti.t[r] - obj0.t[r]) / p.joint_step;
        }
        jac[(3, i)] = obj0.angle_derivative(&ti, p.joint_step, p.angle_weight);
        for r in 0..3 {
            clear.phi1[(r, i)] = (ti.phi1[r] - obj0.phi1[r]) / p.joint_step;
            clear.phi2[(r, i)] = (ti.phi2[r] - obj0.phi2[r]) / p.joint_step;
        }
        for k in 0..clear.count {
            clear.gradient[k][i] =
                (frame.clearance(k, &self.lambda.work) - clear.value[k]) / p.joint_step;
        }
    }

    /// The linearised model of [`super::InverseParams::second_opinion`]: `J` and the
    /// clearances' and angles' derivatives of the frozen active set of the base solve (each
    /// column a prediction, no solve); `None` when that active set cannot be factored. Records
    /// no sensitivity.
    fn linearized_model(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        obj0: &Objective,
    ) -> Option<(Jacobian<N>, Clearances<N>)> {
        if !self.factor_linearized(frame) {
            return None;
        }
        let mut clear = self.clearances_at_base(frame);
        let mut jac = Jacobian::<N>::zeros();
        for i in 0..N {
            let mut qi = frame.q;
            qi[i] += self.params.joint_step;
            let bi = self.predict_at(frame, &qi);
            self.record_column(frame, obj0, &bi, i, (&mut jac, &mut clear));
        }
        Some((jac, clear))
    }

    /// Stage 4: with [`super::StepMethod::Paper`], the damped least-squares step
    /// ([`Self::damped_step`]) brought within the trust region, the speed and the joint limits
    /// ([`Self::limit_step`]); with [`super::StepMethod::Qp`] (the default), the quadratic
    /// program of `qp_step.rs` with those limits and the obstacle clearances as rows. Returns the
    /// commanded joints, and for the QP its first stage's step (the tip alone).
    fn newton_step(
        &self,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        report: &mut SolverReport<N>,
    ) -> ([f64; N], SVector<f64, N>) {
        let t0 = Vector4::from(obj0.t);
        match self.params.method {
            super::StepMethod::Paper => {
                let dq = self.damped_step(&frame.q, jac, &t0, report);
                (
                    self.limit_step(frame, jac, &t0, dq, report),
                    SVector::zeros(),
                )
            }
            super::StepMethod::Qp => self.qp_step(frame, jac, clear, obj0, report),
        }
    }

    /// `ε²` of the damped least squares: `damping²`, raised towards `damping_max²` when the
    /// smallest singular value of `J` falls below `singular_threshold`.
    pub(super) fn damping_squared(&self, jac: &Jacobian<N>, report: &mut SolverReport<N>) -> f64 {
        let p = &self.params;
        let jjt: Matrix4<f64> = jac * jac.transpose();
        let sigma_min = libm::sqrt(smallest_eigenvalue(&jjt).max(0.0));
        let mut eps2 = p.damping * p.damping;
        if sigma_min < p.singular_threshold {
            let r = sigma_min / p.singular_threshold;
            eps2 += (1.0 - r * r) * p.damping_max * p.damping_max;
            report.flags |= StatusFlags::NEAR_SINGULAR;
        }
        eps2
    }

    /// `Δq = −Jᵀ (J Jᵀ + ε² I)⁻¹ T` with `ε` raised near a singularity. Joints at a limit that
    /// the step pushes further out are locked (their column removed) and the step recomputed, so
    /// that the clamp of [`Self::limit_step`] never turns the Newton step into one that does not
    /// descend (e.g. J2 and J3 at their limits: the wrist alone tilting the needle away from an
    /// unreachable target).
    fn damped_step(
        &self,
        q: &[f64; N],
        jac: &Jacobian<N>,
        t0: &Vector4<f64>,
        report: &mut SolverReport<N>,
    ) -> SVector<f64, N> {
        let eps2 = self.damping_squared(jac, report);
        let mut jac_free = *jac;
        let mut dq = SVector::<f64, N>::zeros();
        for _ in 0..=N {
            let jjt: Matrix4<f64> = jac_free * jac_free.transpose();
            dq = match (jjt + Matrix4::identity() * eps2).cholesky() {
                Some(ch) => -(jac_free.transpose() * ch.solve(t0)),
                None => SVector::zeros(),
            };
            let mut locked = false;
            for i in 0..N {
                let l = &self.robot.limits()[i];
                let out = (q[i] >= l.upper && dq[i] > 0.0) || (q[i] <= l.lower && dq[i] < 0.0);
                if out {
                    jac_free.set_column(i, &Vector4::zeros());
                    dq[i] = 0.0;
                    locked = true;
                }
            }
            if !locked {
                break;
            }
            report.flags |= StatusFlags::SATURATED_LIMIT;
        }
        if !dq.iter().all(|x| x.is_finite()) || dq.iter().all(|x| *x == 0.0) {
            dq.fill(0.0);
            report.flags |= StatusFlags::TARGET_UNREACHABLE;
        }
        dq
    }

    /// Brings `q + Δq` within the trust region on the base motion (`max_base_step`), the speed
    /// limits (uniform scaling, keeps the direction) and the joint limits (clamp), then keeps the
    /// best multiple of what is left for the linear model. Returns the commanded joints.
    fn limit_step(
        &self,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        t0: &Vector4<f64>,
        mut dq: SVector<f64, N>,
        report: &mut SolverReport<N>,
    ) -> [f64; N] {
        let (p, q) = (&self.params, &frame.q);
        let (jt, _) = self.robot.jacobian_tool(q);
        let base_motion = (jt.fixed_rows::<3>(0) * dq).norm();
        if base_motion > p.max_base_step {
            dq *= p.max_base_step / base_motion;
            report.flags |= StatusFlags::STEP_LIMITED;
        }
        let mut scale = 1.0f64;
        for i in 0..N {
            let lim = self.robot.limits()[i].max_speed * frame.dt;
            let a = libm::fabs(dq[i]);
            if a > lim {
                scale = scale.min(if lim > 0.0 { lim / a } else { 0.0 });
            }
        }
        if scale < 1.0 {
            dq *= scale;
            report.flags |= StatusFlags::SATURATED_SPEED;
        }
        let mut q_new = *q;
        for i in 0..N {
            q_new[i] = q[i] + dq[i];
        }
        if self.robot.clamp_to_limits(&mut q_new) {
            report.flags |= StatusFlags::SATURATED_LIMIT;
        }
        // A frame outside the limits must still respect the speed limit.
        for i in 0..N {
            let lim = self.robot.limits()[i].max_speed * frame.dt;
            q_new[i] = q_new[i].max(q[i] - lim).min(q[i] + lim);
        }
        let mut applied = SVector::<f64, N>::zeros();
        for i in 0..N {
            applied[i] = q_new[i] - q[i];
        }
        // The clamps may have bent the step: keep the best multiple α ∈ [0, 1] of what is
        // left for the linear model, never a step it predicts to make the objective worse.
        let ja = jac * applied;
        let jj = ja.norm_squared();
        if jj > 0.0 {
            let alpha = (-t0.dot(&ja) / jj).clamp(0.0, 1.0);
            if alpha < 1.0 {
                for i in 0..N {
                    q_new[i] = q[i] + alpha * applied[i];
                    applied[i] *= alpha;
                }
            }
        }
        let predicted = t0 + jac * applied;
        if predicted.norm() > 0.99 * t0.norm() {
            report.flags |= StatusFlags::TARGET_UNREACHABLE;
        }
        q_new
    }

    /// Stage 5 with [`super::StepMethod::Qp`]: the final solve at the planned joints, and the
    /// step is kept only if that solve — the constrained model itself, not its linearisation —
    /// confirms it (a sufficient-decrease test, as a line-search Newton method makes):
    /// - the tip's error falls by at least [`SUFFICIENT_DECREASE`] of what the linear model
    ///   promised (`|e_after|² ≤ |e₀|² − c (|e₀|² − |e_pred|²)`), or is within the objective's
    ///   tolerance;
    /// - no obstacle clearance ends below `min(clearance_margin, its value before the step)`.
    ///
    /// The candidates, in order: the planned step (tip and angles), the first stage's step `Δq₁`
    /// (the tip alone), then `Δq₁` halved, up to [`MAX_BACKTRACKS`] times; when none passes, the
    /// joints are held (the base solve is the answer). A step that comes at the joints the last
    /// step held, which had halved `Δq₁` down to `resume` times
    /// ([`super::InverseParams::resume_held`]), tries the same candidates and then goes on
    /// halving, [`MAX_BACKTRACKS`] + 1 times further (at most [`MAX_HELD_HALVINGS`] in all),
    /// and holds the joints only when none of those passes either. Each candidate keeps the joint limits and
    /// speeds, the trust region and the linearised clearance rows, which hold at the planned
    /// step, at `Δq₁` and at 0. Before the puncture there is no test: pushing on the surface
    /// builds the force that punctures it without bringing the tip closer. The paper's method
    /// keeps its own step (the final solve alone).
    #[allow(clippy::too_many_arguments)]
    fn accept_step(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        jac: &Jacobian<N>,
        clear: &Clearances<N>,
        obj0: &Objective,
        (q_new, dq1, resume): ([f64; N], SVector<f64, N>, u32),
        base_rep: SolveReport,
        report: &mut SolverReport<N>,
    ) -> ([f64; N], SolveReport) {
        if self.params.method != super::StepMethod::Qp || frame.inserted == 0 {
            let rep = self.final_solve(frame, &q_new, report);
            return (q_new, rep);
        }
        let mut dq = SVector::<f64, N>::zeros();
        for i in 0..N {
            dq[i] = q_new[i] - frame.q[i];
        }
        // The model the candidate was planned with: secant-corrected after each rejected plan
        // when `replan_rejected` is on.
        let (mut jac, mut clear, mut dq1) = (*jac, *clear, dq1);
        let mut replans = if self.params.replan_rejected {
            MAX_REPLANS
        } else {
            0
        };
        let mut second =
            self.params.second_opinion && self.params.jacobian != super::JacobianMode::Linearized;
        let mut fallback = 0;
        while fallback <= MAX_BACKTRACKS + 1 {
            if let Some(kept) = self.confirm(frame, (&jac, &clear, obj0), &dq, report) {
                return kept;
            }
            report.flags |= StatusFlags::BACKTRACKED;
            if second {
                // Once, after the first plan: the same program on the frozen active set's model,
                // its candidate confirmed against that model's promise.
                second = false;
                if let Some((jl, cl)) = self.linearized_model(frame, obj0) {
                    let mut scratch = SolverReport::default();
                    let (q2, _) = self.qp_step(frame, &jl, &cl, obj0, &mut scratch);
                    if scratch.flags & StatusFlags::QP_FAILED == 0 {
                        let mut d2 = SVector::<f64, N>::zeros();
                        for i in 0..N {
                            d2[i] = q2[i] - frame.q[i];
                        }
                        if let Some(kept) = self.confirm(frame, (&jl, &cl, obj0), &d2, report) {
                            return kept;
                        }
                    }
                }
            }
            if replans > 0 {
                replans -= 1;
                let after = report.objective_after;
                secant_update(&mut jac, &mut clear, &dq, obj0, &after, |k| {
                    frame.clearance(k, &self.lambda.work)
                });
                // The plan's flags stay those of the first plan.
                let mut scratch = SolverReport::default();
                let (q2, d1) = self.qp_step(frame, &jac, &clear, obj0, &mut scratch);
                if scratch.flags & StatusFlags::QP_FAILED == 0 {
                    for i in 0..N {
                        dq[i] = q2[i] - frame.q[i];
                    }
                    dq1 = d1;
                    continue;
                }
            }
            dq = if fallback == 0 { dq1 } else { dq * 0.5 };
            fallback += 1;
        }
        // At the joints of a held step: `Δq₁` halved on beyond where the held step stopped.
        let mut last = MAX_BACKTRACKS as u32;
        if resume > 0 {
            last = (resume + MAX_BACKTRACKS as u32 + 1).min(MAX_HELD_HALVINGS);
            for h in MAX_BACKTRACKS as u32 + 1..=last {
                let dq = dq1 * libm::ldexp(1.0, -(h as i32));
                if let Some(kept) = self.confirm(frame, (&jac, &clear, obj0), &dq, report) {
                    return kept;
                }
            }
        }
        // Held: how far the halvings went, for a next step at the same joints.
        self.held = super::Held {
            q: frame.q,
            halvings: last,
        };
        let m = frame.rows();
        self.lambda.work[..m].copy_from_slice(&self.lambda.base[..m]);
        report.objective_after = obj0.t;
        (frame.q, base_rep)
    }

    /// One candidate `Δq` of [`Self::accept_step`]: the final solve at `q + Δq`, kept (the joints
    /// and the solve's report) when it confirms the step: a sufficient decrease of the tip's
    /// error against the linear model's promise and no clearance below `min(margin, before)`.
    fn confirm(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        (jac, clear, obj0): (&Jacobian<N>, &Clearances<N>, &Objective),
        dq: &SVector<f64, N>,
        report: &mut SolverReport<N>,
    ) -> Option<([f64; N], SolveReport)> {
        let tip_sq = |t: &[f64; 4]| t[0] * t[0] + t[1] * t[1] + t[2] * t[2];
        let e0 = tip_sq(&obj0.t);
        let mut q_try = frame.q;
        for i in 0..N {
            q_try[i] += dq[i];
        }
        let rep = self.final_solve(frame, &q_try, report);
        let predicted = Vector4::from(obj0.t) + jac * dq;
        let e_pred = tip_sq(&[predicted[0], predicted[1], predicted[2], 0.0]);
        let e_after = tip_sq(&report.objective_after);
        let decrease = e_after <= e0 - SUFFICIENT_DECREASE * (e0 - e_pred).max(0.0)
            || e_after <= self.params.tolerance;
        let clear_ok = (0..clear.count).all(|k| {
            let after = frame.clearance(k, &self.lambda.work);
            after >= self.margin().min(clear.value[k])
        });
        (decrease && clear_ok).then_some((q_try, rep))
    }

    /// Stage 5: the solve at the commanded joints (started from the prediction) → the `λ` the
    /// host applies, and the objective there.
    fn final_solve(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q_new: &[f64; N],
        report: &mut SolverReport<N>,
    ) -> SolveReport {
        let tolerance = self.params.gs.tolerance;
        let (bf, rep) = self.solve(frame, q_new, Target::Work, Start::Predicted, tolerance);
        count_solve(report, &rep);
        report.objective_after = evaluate_objective(frame, &self.lambda.work, &bf, &self.params).t;
        rep
    }

    /// Stage 6: completes the report, checks that the joints and `λ` are finite, and writes the
    /// command.
    fn answer(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q_new: &[f64; N],
        final_rep: &SolveReport,
        mut report: SolverReport<N>,
        cmd: &mut Command<M, N>,
    ) -> Result<SolverReport<N>, StepError> {
        report.final_iterations = final_rep.iterations;
        report.final_residual = final_rep.residual;
        for i in 0..N {
            report.delta_q[i] = q_new[i] - frame.q[i];
        }
        let m = frame.rows();
        if !q_new.iter().all(|x| x.is_finite())
            || !self.lambda.work[..m].iter().all(|x| x.is_finite())
        {
            self.reset_warm_start();
            return Err(StepError::NonFinite {
                stage: "final solve",
            });
        }
        let finite_report = report.final_residual.is_finite()
            && report.objective.iter().all(|x| x.is_finite())
            && report.objective_after.iter().all(|x| x.is_finite());
        if !finite_report {
            self.reset_warm_start();
            return Err(StepError::NonFinite {
                stage: "objective (report)",
            });
        }
        self.write_command(frame, q_new, report, cmd);
        Ok(report)
    }

    /// One constraint solve at the given joints, without the inverse update: the open-loop step
    /// of a replayed trajectory. The same preparation, warm start and solver (base elimination,
    /// active-set polish) as the base solve of [`Self::step`]; the command carries `q` and λ.
    ///
    /// # Errors
    /// As [`Self::step`]: an invalid frame or parameters, a non-finite result.
    ///
    /// # Example
    /// ```
    /// use needle_core::synthetic::random_frame;
    /// use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};
    ///
    /// let chain = DhChain::rv1a();
    /// let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    /// let mut frame = ComplianceFrame::<32>::new_boxed();
    /// random_frame(&mut frame, &chain, &q, 24, 3, false);
    /// let mut cmd = Command::<32>::new_boxed();
    /// let mut ctrl = Controller::<32>::new_boxed(chain, InverseParams::default());
    /// let report = ctrl.solve_open_loop(&frame, &q, &mut cmd)?;
    /// assert_eq!((report.solves, cmd.q), (1, q)); // one solve, the joints as given
    /// # Ok::<(), needle_core::StepError>(())
    /// ```
    pub fn solve_open_loop(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q: &[f64; N],
        cmd: &mut Command<M, N>,
    ) -> Result<SolverReport<N>, StepError> {
        let m = self.prepare(frame)?;
        let tolerance = self.params.gs.tolerance;
        let (_, rep) = self.solve(frame, q, Target::Base, Start::Current, tolerance);
        if !self.lambda.base[..m].iter().all(|x| x.is_finite()) {
            return Err(StepError::NonFinite {
                stage: "open-loop solve",
            });
        }
        self.lambda.work[..m].copy_from_slice(&self.lambda.base[..m]);
        let mut report = SolverReport::default();
        count_solve(&mut report, &rep);
        report.final_iterations = rep.iterations;
        report.final_residual = rep.residual;
        self.write_command(frame, q, report, cmd);
        Ok(report)
    }

    /// The objective `T(q)` at joints `q` for `frame` (one constraint solve, from zero). For
    /// tests and diagnostics; not part of the real-time path.
    ///
    /// # Errors
    /// [`StepError::InvalidFrame`] when the frame fails validation.
    pub fn objective_at(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q: &[f64; N],
    ) -> Result<Objective, StepError> {
        self.prepare_blocks(frame)?;
        let m = frame.rows();
        self.delta[..m].copy_from_slice(&frame.delta_free[..m]);
        self.lambda.work.fill(0.0);
        let tolerance = self.params.gs.tolerance;
        let (b, _) = self.solve(frame, q, Target::Work, Start::Current, tolerance);
        Ok(evaluate_objective(
            frame,
            &self.lambda.work,
            &b,
            &self.params,
        ))
    }

    /// Keeps λ (`lambda.work`) for the next warm start and writes the command.
    fn write_command(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q: &[f64; N],
        report: SolverReport<N>,
        cmd: &mut Command<M, N>,
    ) {
        let m = frame.rows();
        let l = &mut self.lambda;
        l.prev[..m].copy_from_slice(&l.work[..m]);
        l.prev_rows = m;
        cmd.version = VERSION;
        cmd.m = frame.m;
        cmd.frame_sequence = frame.sequence;
        cmd.q = *q;
        cmd.lambda[..m].copy_from_slice(&l.work[..m]);
        cmd.lambda[m..].fill(0.0);
        cmd.report = report;
    }
}

/// Adds one constraint solve to the step's report.
fn count_solve<const N: usize>(report: &mut SolverReport<N>, r: &SolveReport) {
    report.iterations = report.iterations.saturating_add(r.iterations);
    report.solves += 1;
    if !r.converged {
        report.flags |= StatusFlags::NOT_CONVERGED;
    }
}

/// Smallest eigenvalue of a symmetric 4×4 matrix (NaN-safe: 0 for non-finite input).
fn smallest_eigenvalue(a: &Matrix4<f64>) -> f64 {
    if !a.iter().all(|x| x.is_finite()) {
        return 0.0;
    }
    let eig = nalgebra::SymmetricEigen::new(*a);
    eig.eigenvalues.iter().fold(f64::INFINITY, |m, &x| m.min(x))
}

/// The rank-one secant (Broyden) correction of the tip rows of `jac` and of the clearance
/// gradients along a rejected step `dq`, from what the constraint solve at `q + dq` gave (`after`
/// the objective there, `clearance_after(k)` the clearances): afterwards `J dq` is the tip's
/// actual change along `dq`, and `J` is unchanged on every direction orthogonal to `dq`. The
/// angular row and the rotation-vector derivatives are kept.
pub(super) fn secant_update<const N: usize>(
    jac: &mut Jacobian<N>,
    clear: &mut Clearances<N>,
    dq: &SVector<f64, N>,
    obj0: &Objective,
    after: &[f64; 4],
    clearance_after: impl Fn(usize) -> f64,
) {
    let n2 = dq.norm_squared();
    if !(n2 > 0.0) || !after.iter().all(|x| x.is_finite()) {
        return;
    }
    let jdq = *jac * dq;
    for r in 0..3 {
        let residual = (after[r] - obj0.t[r] - jdq[r]) / n2;
        for i in 0..N {
            jac[(r, i)] += residual * dq[i];
        }
    }
    for k in 0..clear.count {
        let g = &mut clear.gradient[k];
        let predicted: f64 = (0..N).map(|i| g[i] * dq[i]).sum();
        let residual = (clearance_after(k) - clear.value[k] - predicted) / n2;
        if residual.is_finite() {
            for i in 0..N {
                g[i] += residual * dq[i];
            }
        }
    }
}
