//! The constraint solves of a step. Every solve goes one path, [`Controller::solve`], told which
//! λ it writes ([`Target`]) and where it starts ([`Start`]); the path solves the full problem
//! or, with `eliminate_base`, the problem with the 6 base rows eliminated ([`crate::reduce`]),
//! and polishes a slow reduced solve on its active set.
//!
//! Only the base rows' violation `δ_base(q)` changes with `q` within a step; the frozen
//! active set of the base solve ([`ActiveSet`]) predicts how the solution follows it,
//! `λ ≈ λ_q + Z (δ_b(q') − δ_b(q))`, which starts the perturbed solves next to their answer and
//! is the whole "solve" of a linearised Jacobian column.
//!
//! Without that factor (the base rows eliminated, the default), the Jacobian's own forward
//! differences give `∂λ/∂q_i` ([`super::sensitivity`]): the final solve at `q + Δq` starts from
//! `λ_q + Σ Δq_i ∂λ/∂q_i`, the next step's columns from `λ_q + δq ∂λ/∂q_i`. A solve so started
//! that does not converge is done again from `λ_q`.

use super::{Controller, StepError};
use crate::constraint::{ActiveSet, BatchStart, BlockGs, GsParams, SolveReport};
use crate::kinematics::{Kinematics, Pose};
use crate::math::rotation_log;
use crate::payload::{ComplianceFrame, ValidationError};
use nalgebra::{Matrix3, Vector3};

/// The needle-base block `W_bb` of `W` (errors).
const BASE_BLOCK: &str = "needle-base block W_bb";
/// `W` without the base rows (errors).
const SCHUR: &str = "W without the base rows, W_oo - W_ob W_bb^-1 W_bo";

/// Sweeps after which a reduced solve that has not converged is polished on its active set.
const POLISH_AFTER: u32 = 60;

/// Most active-set polishes of one reduced solve, [`POLISH_AFTER`] sweeps apart.
const POLISH_TIMES: u32 = 3;

/// Most rounds (factor, Newton step, status correction) of an active-set polish
/// ([`BlockGs::solve_on_active_sets`]). On the frames whose solves hit the sweep cap in the suite's
/// hardest scenes (sliding points along a curving path) it needs 2–10.
const ACTIVE_SET_ROUNDS: usize = 12;

/// Most rounds of the feasible active-set polish ([`BlockGs::solve_on_active_sets_feasible`]),
/// one status change each.
const FEASIBLE_ROUNDS: usize = 40;

/// Which λ a solve writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Target {
    /// `λ_q`, the solution at the frame's joints (`lambda.base`). Solving it records
    /// `δ_base(q)` and drops the active-set factor of the previous one.
    Base,
    /// A solution at other joints (`lambda.work`): Jacobian columns, the final solve.
    Work,
}

/// Where a solve's iterate starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Start {
    /// From the target's current content (the previous step's λ, or zeros).
    Current,
    /// From the prediction of `λ` at the new joints ([`Controller::predict`]): `λ_q` moved along
    /// the frozen active set when a valid factor exists, else `λ_q` itself.
    Predicted,
}

/// Rotation matrix from the frame's row-major array.
fn r_free(frame_r: &[[f64; 3]; 3]) -> Matrix3<f64> {
    let r = frame_r;
    Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    )
}

/// The base-row violation `δ_base(q)` for the needle-base pose `b`: translation `p_B − p_free`
/// [mm], rotation `log(R_B R_freeᵀ)` [rad], world frame.
pub fn base_violation(b: &Pose, p_free: &[f64; 3], r_free_rows: &[[f64; 3]; 3]) -> [f64; 6] {
    let dp = b.translation - Vector3::from(*p_free);
    let dr = rotation_log(&(b.rotation * r_free(r_free_rows).transpose()));
    [dp[0], dp[1], dp[2], dr[0], dr[1], dr[2]]
}
impl<const M: usize, const N: usize> Controller<M, N> {
    /// One constraint solve at joints `q` into `target`, started from `start`, to `tolerance`
    /// (relative, as [`GsParams::tolerance`]); the other Gauss-Seidel settings are `params.gs`.
    /// Returns the tool pose at `q` and the report.
    pub(super) fn solve(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q: &[f64; N],
        target: Target,
        start: Start,
        tolerance: f64,
    ) -> (Pose, SolveReport) {
        let (b, rep, from_sens) = self.solve_once(frame, q, target, start, tolerance, true);
        if from_sens && !rep.converged {
            // The sensitivities' start led Gauss-Seidel astray (statuses that cycle): the solve
            // again from the prediction without them, its sweeps counted with the first's.
            let (b, again, _) = self.solve_once(frame, q, target, start, tolerance, false);
            let iterations = rep.iterations.saturating_add(again.iterations);
            return (
                b,
                SolveReport {
                    iterations,
                    ..again
                },
            );
        }
        (b, rep)
    }

    /// [`Self::solve`] once; a `Start::Predicted` solve without a valid active set starts from
    /// this step's sensitivities when `sensitivities` allows and they exist. Returns whether it
    /// did.
    fn solve_once(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        q: &[f64; N],
        target: Target,
        start: Start,
        tolerance: f64,
        sensitivities: bool,
    ) -> (Pose, SolveReport, bool) {
        debug_assert!(!(target == Target::Base && start == Start::Predicted));
        let b = self.robot.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        // Without a valid active set the prediction is this step's sensitivities' or, without
        // those, `λ_q` itself (whose product `W' λ_q` the reduced solve then reuses).
        let predicted = start == Start::Predicted;
        let from_sens = predicted
            && sensitivities
            && !self.set_valid
            && self.predict_from_sensitivity(frame, q);
        let from_base = target == Target::Work && predicted && !self.set_valid && !from_sens;
        if target == Target::Base {
            self.delta_base = d;
            self.set_valid = false;
            self.start_product_ok = false;
        }
        if predicted && !from_sens {
            self.predict(frame, &d);
        }
        let gs = GsParams {
            tolerance,
            ..self.params.gs
        };
        let rep = if self.params.eliminate_base {
            self.solve_reduced(frame, &d, target, &gs, from_base)
        } else {
            self.delta[..6].copy_from_slice(&d);
            match target {
                Target::Base if self.params.active_set => self.solve_base_on_active_set(frame, &gs),
                _ => self
                    .gs
                    .solve(&frame.w, &self.delta, self.lambda.of(target), &gs),
            }
        };
        (b, rep, from_sens)
    }

    /// `λ_q` on the full problem through its active set: a loose Gauss-Seidel pass finds which
    /// rows are free, the free rows are solved exactly by a dense factorisation (also giving their
    /// response `Z` to the base rows), and Gauss-Seidel confirms the result to the full tolerance
    /// (repairing any status change).
    fn solve_base_on_active_set(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        gs: &GsParams,
    ) -> SolveReport {
        let loose = GsParams {
            tolerance: gs.tolerance.max(self.params.presolve_tolerance),
            ..*gs
        };
        let r1 = self
            .gs
            .solve(&frame.w, &self.delta, &mut self.lambda.base, &loose);
        newton_on_active_set(
            &self.gs,
            &mut self.set,
            &frame.w,
            &self.delta,
            &mut self.lambda.base,
        );
        let left = GsParams {
            max_iterations: gs.max_iterations.saturating_sub(r1.iterations),
            ..*gs
        };
        let r2 = self
            .gs
            .solve(&frame.w, &self.delta, &mut self.lambda.base, &left);
        // A status changed during the confirmation: factor again at the final answer.
        if r2.iterations > 2 {
            self.gs
                .factor_active_set(&frame.w, &self.delta, &self.lambda.base, &mut self.set);
        }
        self.set_valid = self.set.complete_response();
        SolveReport {
            iterations: r1.iterations + r2.iterations,
            ..r2
        }
    }

    /// A solve of the reduced problem for the base violation `d`, started from the target's
    /// rows `6..m` (`from_base`: they are `λ_q`'s, so the solve starts from `W' λ_q`); the full λ
    /// (base rows recovered) is written back into the target.
    fn solve_reduced(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        d: &[f64; 6],
        target: Target,
        gs: &GsParams,
        from_base: bool,
    ) -> SolveReport {
        self.red.reduce_delta(frame, d);
        let n = self.red.rows();
        self.lr[..n].copy_from_slice(&self.lambda.of(target)[6..6 + n]);
        let first = GsParams {
            max_iterations: gs.max_iterations.min(POLISH_AFTER),
            ..*gs
        };
        let rep = if n > 0 {
            let product = if from_base {
                self.update_start_product();
                Some(&self.start_product)
            } else {
                None
            };
            self.gs
                .solve_from(&self.red.w, &self.red.delta, &mut self.lr, product, &first)
        } else {
            SolveReport {
                converged: true,
                ..SolveReport::default()
            }
        };
        self.finish_reduced(frame, d, target, gs, rep)
    }

    /// The end of a reduced solve whose first `POLISH_AFTER` sweeps left `self.lr` (and
    /// `self.red.delta` its `δ'`) with report `rep`: when it has not converged, polished on its
    /// active set and confirmed (twice at most), then expanded into the target.
    fn finish_reduced(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        d: &[f64; 6],
        target: Target,
        gs: &GsParams,
        mut rep: SolveReport,
    ) -> SolveReport {
        // Polish, then Gauss-Seidel for at most as many sweeps again; should that not converge
        // (the rounds ran out on statuses that cycle), polish again from the new iterate with
        // the feasible method (short steps, one status change at a time: it does not cycle
        // where the first one does), up to POLISH_TIMES polishes in all, the last followed by
        // Gauss-Seidel for whatever the cap leaves.
        for polish in 0..POLISH_TIMES {
            if rep.converged {
                break;
            }
            self.polish_reduced(frame, d, target, polish > 0);
            let left = gs.max_iterations.saturating_sub(rep.iterations);
            let left = GsParams {
                max_iterations: if polish + 1 < POLISH_TIMES {
                    left.min(POLISH_AFTER)
                } else {
                    left
                },
                ..*gs
            };
            let r2 = self
                .gs
                .solve(&self.red.w, &self.red.delta, &mut self.lr, &left);
            rep = SolveReport {
                iterations: rep.iterations + r2.iterations,
                ..r2
            };
        }
        self.red.expand(frame, d, &self.lr, self.lambda.of(target));
        rep
    }

    /// `W' λ_q` into `start_product`, unless it is there already.
    fn update_start_product(&mut self) {
        if !self.start_product_ok {
            let n = self.red.rows();
            let mut lq = [0.0; M];
            lq[..n].copy_from_slice(&self.lambda.base[6..6 + n]);
            self.gs.product(&self.red.w, &lq, &mut self.start_product);
            self.start_product_ok = true;
        }
    }

    /// The solves of the Jacobian's columns at joints `qs[i]`, started from the previous step's
    /// sensitivities when they fit ([`Self::column_starts`]), else from `λ_q`, to `tolerance`,
    /// run together on the reduced problem ([`BlockGs::solve_batch`]: each one the same
    /// operations and the same result as alone, the rows of `W'` read once a sweep for all).
    /// Returns the tool poses, the base violations, the reports of the first `POLISH_AFTER`
    /// sweeps, to be finished column by column by [`Self::finish_column`], and whether the
    /// sensitivities started them; `None`
    /// when the solves do not start from `λ_q` or the base rows are not eliminated (then each
    /// column is its own solve).
    #[allow(clippy::type_complexity)]
    pub(super) fn solve_columns(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        qs: &[[f64; N]; N],
        tolerance: f64,
    ) -> Option<([Pose; N], [[f64; 6]; N], [SolveReport; N], bool)> {
        let n = self.red.rows();
        if !self.params.eliminate_base || self.set_valid || n == 0 {
            return None;
        }
        let poses: [Pose; N] = core::array::from_fn(|i| self.robot.tool_pose(&qs[i]));
        let ds: [[f64; 6]; N] =
            core::array::from_fn(|i| base_violation(&poses[i], &frame.p_free, &frame.r_free));
        for (d, delta) in ds.iter().zip(self.columns.delta.iter_mut()) {
            self.red.reduce_delta_into(frame, d, delta);
        }
        let first = GsParams {
            tolerance,
            max_iterations: self.params.gs.max_iterations.min(POLISH_AFTER),
            ..self.params.gs
        };
        // From the previous step's sensitivities when they fit this frame, else all from `λ_q`.
        let from_sens = self.column_starts(frame);
        let reports = if from_sens {
            self.gs
                .solve_batch(&self.red.w, BatchStart::Own, &mut self.columns, N, &first)
        } else {
            self.update_start_product();
            let mut lq = [0.0; M];
            lq[..n].copy_from_slice(&self.lambda.base[6..6 + n]);
            let start = BatchStart::Shared {
                lambda0: &lq,
                product: &self.start_product,
            };
            self.gs
                .solve_batch(&self.red.w, start, &mut self.columns, N, &first)
        };
        Some((poses, ds, reports, from_sens))
    }

    /// The starts of the column solves, `λ_q + δq ∂λ/∂q_i` from the previous step's
    /// sensitivities, into the reduced rows of `columns.lambda[i]`; `false` (the columns then
    /// start from `λ_q`) when there are none for a frame of this many rows or one start is out of
    /// the problem's scale.
    fn column_starts(&mut self, frame: &ComplianceFrame<M, N>) -> bool {
        let (m, n) = (frame.rows(), self.red.rows());
        let scale = self.problem_scale(frame);
        let w = &frame.w;
        for i in 0..N {
            let mut dq = [0.0; N];
            dq[i] = self.params.joint_step;
            let mut start = [0.0; M];
            if !self
                .sens
                .predict(&self.lambda.base, &dq, m, |r| w[r][r], scale, &mut start)
            {
                return false;
            }
            self.columns.lambda[i][..n].copy_from_slice(&start[6..6 + n]);
        }
        true
    }

    /// Column `i` of [`Self::solve_columns`] (base violation `d`, report `rep`) finished as
    /// [`Self::solve`] would finish it, into `lambda.work`.
    pub(super) fn finish_column(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        i: usize,
        d: &[f64; 6],
        rep: SolveReport,
        tolerance: f64,
    ) -> SolveReport {
        let (m, n) = (frame.rows(), self.red.rows());
        self.lambda.work[..m].copy_from_slice(&self.lambda.base[..m]);
        self.lr[..n].copy_from_slice(&self.columns.lambda[i][..n]);
        if !rep.converged {
            self.red.reduce_delta(frame, d);
        }
        let gs = GsParams {
            tolerance,
            ..self.params.gs
        };
        self.finish_reduced(frame, d, Target::Work, &gs, rep)
    }

    /// Slow convergence of a reduced solve (sliding points coupled through the stiff needle:
    /// rows close to parallel): Newton's method on the active set from the current iterate —
    /// stick rows bilateral, slipping axial rows tied to their bound, the statuses corrected
    /// between steps — on the full problem, written back into the reduced iterate; Gauss-Seidel
    /// then confirms it (and repairs any status the rounds left wrong). `feasible`: by the
    /// feasible active-set method instead ([`BlockGs::solve_on_active_sets_feasible`]), for a
    /// solve the first polish left unconverged.
    fn polish_reduced(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        d: &[f64; 6],
        target: Target,
        feasible: bool,
    ) {
        let n = self.red.rows();
        let full = self.lambda.of(target);
        self.red.expand(frame, d, &self.lr, full);
        if self.params.active_set && self.gs_full.prepare_frame(frame).is_ok() {
            self.delta[..6].copy_from_slice(d);
            // Even when the rounds run out, their last iterate (finite, by construction) is far
            // closer than the slow Gauss-Seidel iterate it started from.
            if feasible {
                self.gs_full.solve_on_active_sets_feasible(
                    &frame.w,
                    &self.delta,
                    full,
                    &mut self.set,
                    FEASIBLE_ROUNDS,
                )
            } else {
                newton_on_active_set(&self.gs_full, &mut self.set, &frame.w, &self.delta, full)
            };
            if full[6..6 + n].iter().all(|x| x.is_finite()) {
                self.lr[..n].copy_from_slice(&full[6..6 + n]);
            }
            self.set_valid = false;
        }
    }

    /// The prediction of λ for the base violation `d` into `lambda.work`: `λ_q + Z (d − δ_b(q))`
    /// on the frozen active set when its factor is valid, else `λ_q`.
    pub(super) fn predict(&mut self, frame: &ComplianceFrame<M, N>, d: &[f64; 6]) {
        if !self.set_valid {
            let m = frame.rows();
            self.lambda.work[..m].copy_from_slice(&self.lambda.base[..m]);
            return;
        }
        let mut dd = [0.0; 6];
        for i in 0..6 {
            dd[i] = d[i] - self.delta_base[i];
        }
        // The solver prepared on the full frame (the reduced one has other rows).
        let full = if self.params.eliminate_base {
            &self.gs_full
        } else {
            &self.gs
        };
        full.predict_base_change(&self.set, &self.lambda.base, &dd, &mut self.lambda.work);
    }

    /// `λ_q + Σ_i Δq_i ∂λ/∂q_i` for `Δq = q − q_frame` into `lambda.work`, from this step's
    /// Jacobian ([`Sensitivity`](super::sensitivity::Sensitivity)); `false` (and nothing
    /// written) when there is none or its start is out of the problem's scale.
    fn predict_from_sensitivity(&mut self, frame: &ComplianceFrame<M, N>, q: &[f64; N]) -> bool {
        if !self.sens.is_fresh() {
            return false;
        }
        let m = frame.rows();
        let dq: [f64; N] = core::array::from_fn(|i| q[i] - frame.q[i]);
        let scale = self.problem_scale(frame);
        let w = &frame.w;
        self.sens.predict(
            &self.lambda.base,
            &dq,
            m,
            |i| w[i][i],
            scale,
            &mut self.lambda.work,
        )
    }

    /// The scale a start must stay within: the larger of the frame's `‖δ‖∞` and `λ_q`'s force
    /// scale `max |W_ii λ_i|`.
    fn problem_scale(&self, frame: &ComplianceFrame<M, N>) -> f64 {
        let m = frame.rows();
        (0..m).fold(0.0_f64, |a, i| {
            a.max(libm::fabs(frame.delta_free[i]))
                .max(libm::fabs(frame.w[i][i] * self.lambda.base[i]))
        })
    }

    /// The prediction at joints `q` into `lambda.work` (a linearised Jacobian column); returns
    /// the tool pose.
    pub(super) fn predict_at(&mut self, frame: &ComplianceFrame<M, N>, q: &[f64; N]) -> Pose {
        let b = self.robot.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        self.predict(frame, &d);
        b
    }

    /// Factors the active set of the base solve (`lambda.base`) on the full frame for the
    /// linearised Jacobian; `false` if it is singular or the frame cannot be prepared.
    pub(super) fn factor_linearized(&mut self, frame: &ComplianceFrame<M, N>) -> bool {
        if self.gs_full.prepare_frame(frame).is_err() {
            return false;
        }
        let ok =
            self.gs_full
                .factor_active_set(&frame.w, &self.delta, &self.lambda.base, &mut self.set);
        self.set_valid = ok && self.set.is_valid();
        self.set_valid
    }

    /// Validates the frame and factors the diagonal blocks: of the reduced problem when the base
    /// rows are eliminated (the full frame is then only validated), else of the frame.
    ///
    /// # Errors
    /// [`StepError::InvalidFrame`]; [`StepError::NotPositiveDefinite`] when `W_bb` or its Schur
    /// complement is not positive definite.
    pub(super) fn prepare_blocks(
        &mut self,
        frame: &ComplianceFrame<M, N>,
    ) -> Result<(), StepError> {
        self.start_product_ok = false;
        if !self.params.eliminate_base {
            self.gs.prepare_frame(frame)?;
            return Ok(());
        }
        // The reduced problem's factors replace the full frame's: of the full frame, only its
        // checks (unless nothing is left after the base rows).
        frame.validate()?;
        if !self.red.prepare(frame) {
            return Err(StepError::NotPositiveDefinite { stage: BASE_BLOCK });
        }
        let n = self.red.rows();
        if n > 0 {
            // The frame's own W passed validation (and its groups with it), so a failure here
            // is the Schur complement of the base block: a non-positive diagonal means W is not
            // positive definite (e.g. a corrupted diagonal), an overflow is non-finite.
            self.gs
                .prepare_symmetric(&self.red.w, n, self.red.groups())
                .map_err(|e| match e {
                    ValidationError::NonPositiveDiagonal { .. } => {
                        StepError::NotPositiveDefinite { stage: SCHUR }
                    }
                    ValidationError::NonFinite { .. } => StepError::NonFinite { stage: SCHUR },
                    e => StepError::InvalidFrame(e),
                })?;
        } else {
            self.gs.prepare_frame(frame)?;
        }
        Ok(())
    }
}

/// Newton's method on the active set of `lambda` (the full problem of `solver`), the statuses
/// corrected between steps ([`BlockGs::solve_on_active_sets`], at most [`ACTIVE_SET_ROUNDS`]
/// rounds). `false` when a set is singular, a step is not finite or the rounds run out; `lambda`
/// is then the last finite iterate, which Gauss-Seidel goes on from.
fn newton_on_active_set<const M: usize>(
    solver: &BlockGs<M>,
    set: &mut ActiveSet<M>,
    w: &[[f64; M]; M],
    delta: &[f64; M],
    lambda: &mut [f64; M],
) -> bool {
    solver.solve_on_active_sets(w, delta, lambda, set, ACTIVE_SET_ROUNDS)
}
