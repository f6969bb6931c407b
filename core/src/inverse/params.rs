//! Tuning of the inverse update: [`InverseParams`] (one `Default`, the documented values) and
//! how the Jacobian columns are computed ([`JacobianMode`]).

use super::StepError;
use crate::constraint::GsParams;

/// How the Jacobian columns are obtained.
///
/// `#[repr(u8)]` with `Solve = 0`, so that a zeroed [`InverseParams`] (inside a controller built
/// in place) holds a valid mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum JacobianMode {
    /// The paper's eq. 14: a full constraint solve at each `q + δq e_i` (Gauss-Seidel, W fixed).
    /// Exact finite differences of the constrained simulation — including the contacts that
    /// open or close within the perturbation, which with `δq = 0.01 rad` (several mm at the
    /// needle base) makes `J` jump at the moment the tip touches the surface.
    Solve = 0,
    /// The same solve with the active set of the base solve frozen (rows at a bound stay there,
    /// free rows stay free, sliding friction stays saturated): a direct solve of the linearised
    /// problem, i.e. the exact one-sided derivative of `T` at `q` evaluated at the same `δq`.
    /// No contact flips inside a column, and 6 back-substitutions replace 6 Gauss-Seidel solves.
    /// Falls back to `Solve` when the active-set matrix is singular.
    Linearized,
    /// `Linearized` until the tip has punctured the surface (the contact opening and closing
    /// inside a finite difference is what makes `Solve` chatter there), `Solve` once inserted
    /// (where the frozen set mispredicts the shaft friction switching between stick and slip).
    Hybrid,
}

/// How the joint update is chosen from the Jacobian.
///
/// `#[repr(u8)]` with `Paper = 0`, so that a zeroed [`InverseParams`] holds a valid method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum StepMethod {
    /// The paper's update: damped least squares `Δq = −Jᵀ (J Jᵀ + ε² I)⁻¹ T`, then scaled into
    /// the trust region and the speed limits, clamped into the joint limits and shortened to
    /// the best multiple for the linear model. Obstacles are not seen.
    Paper = 0,
    /// The same damped least squares posed as a small quadratic program ([`crate::qp`]): joint
    /// limits and joint speeds as bounds, the trust region on the needle base as linear rows,
    /// and every obstacle clearance of the frame as a linearised inequality
    /// `d_k + G_k Δq ≥ clearance_margin` (`G_k` from the same finite-difference columns as `J`),
    /// so the step never plans the needle into an obstacle to first order.
    Qp,
}

/// Tuning of the inverse update, `Default` gives the documented values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseParams {
    /// Finite-difference joint perturbation δq [rad] (default 0.01).
    pub joint_step: f64,
    /// Depth d over which the angular objective blends from θ1 to θ2 [mm] (default 20).
    pub blend_depth: f64,
    /// Weight w_θ of the angular objective [mm/rad] (default 100: 1° counts like 1.75 mm).
    pub angle_weight: f64,
    /// Damping ε of the pseudo-inverse away from singularities [mm/rad] (default 1).
    pub damping: f64,
    /// Extra damping added at a singularity [mm/rad] (default 20).
    pub damping_max: f64,
    /// Smallest singular value of J below which the damping rises towards `damping_max`
    /// [mm/rad] (default 5).
    pub singular_threshold: f64,
    /// Skip the Jacobian when `‖T‖² ≤ tolerance` [mm²] (default 1e-6).
    pub tolerance: f64,
    /// Constraint-solve tuning for every solve of the step (default tolerance 1e-6, 400 sweeps,
    /// no over-relaxation: ω = 1). 1e-6 of a millimetre-sized violation is 1 nm, far below the
    /// FE error; against 1e-7 it keeps both benchmarks' figures to every printed digit with
    /// 9-14 % fewer sweeps (docs/benchmark.md). ω = 1.2 takes ~20 % fewer sweeps on the
    /// synthetic frames of [`crate::synthetic::random_frame`] but not on the host's frames
    /// (the suite's 201 runs: 156.0 sweeps per step against 151.8 at ω = 1), so the default is
    /// the host's ω = 1 and the core's benches time what the product runs.
    pub gs: GsParams,
    /// Warm-start the first solve of a step from the previous step's `λ` (default true).
    pub warm_start: bool,
    /// Use the active-set factorisation to start every solve of the step at its linear
    /// prediction (default true; see [`ActiveSet`]). Gauss-Seidel still runs every solve to
    /// `gs.tolerance`, so this changes the cost, not the answer.
    pub active_set: bool,
    /// Start solves from the sensitivities `∂λ/∂q_i` the Jacobian's forward differences give
    /// (default true; see `inverse/sensitivity.rs`): the final solve at `q + Δq` (and each
    /// candidate the step confirms) from `λ_q + Σ Δq_i ∂λ/∂q_i`, the next step's Jacobian
    /// columns from `λ_q + δq ∂λ/∂q_i`. Every solve still runs to its tolerance, so this
    /// changes the cost, and the answers only within that tolerance.
    pub sensitivity_start: bool,
    /// Tolerance of the first, loose Gauss-Seidel pass that finds the active set (default 1e-5).
    pub presolve_tolerance: f64,
    /// Eliminate the 6 base rows exactly before Gauss-Seidel (default true; see
    /// [`crate::reduce`]): removes the free needle's rigid-body compliance that every
    /// needle-side row shares, without which Gauss-Seidel stalls on real host frames. The
    /// active-set prediction is not used in this mode.
    pub eliminate_base: bool,
    /// Largest motion of the needle base per step [mm] (default `+∞`: off; the benchmark scenes
    /// use 3): `Δq` is scaled down so that
    /// the tool point moves at most this far (first order, `|J_tool,v Δq|`). A trust region for
    /// the one-iteration Newton step: where the constrained model is far from linear (a contact
    /// opening, friction saturating) the step stays where the linearisation holds, and the next
    /// step corrects from the new state. 3 mm per step is 75 mm/s at 40 ms per step.
    pub max_base_step: f64,
    /// How the Jacobian columns are computed (default [`JacobianMode::Hybrid`]).
    pub jacobian: JacobianMode,
    /// Gauss-Seidel tolerance of the 6 Jacobian solves (default 1e-5): their error enters `J`
    /// divided by `δq`, and a relative solve error of 1e-5 is far below the forward difference's
    /// own truncation error (of order `δq`). The base and final solves use `gs.tolerance`.
    pub jacobian_tolerance: f64,
    /// How the joint update is chosen (default [`StepMethod::Qp`]).
    pub method: StepMethod,
    /// Smallest clearance the [`StepMethod::Qp`] update plans between the needle's centre line
    /// and an obstacle's surface [mm] (default 0.2).
    pub clearance_margin: f64,
    /// Weight of the two angles in the second stage of the [`StepMethod::Qp`] update [mm/rad]
    /// (default 10): that update moves the tip first and corrects the angles only within the
    /// joint motion that leaves the tip's predicted position unchanged, where the angles are
    /// weighed against the damping ε (not against the tip error, as `angle_weight` is in the
    /// paper's update).
    pub qp_angle_weight: f64,
    /// Gain of the [`StepMethod::Qp`] update's third stage, for arms of more than 6 joints
    /// (default 0.5; 0: off): each joint is asked to move towards the middle of its range by
    /// this gain times its distance from the middle (as a fraction of the half range) times its
    /// speed budget `v_i dt`, within the joint motion that leaves the tip and the angles where the
    /// first two stages put them (the damped null space of the task). 6-joint arms have no such
    /// motion to spare, and the stage is skipped.
    pub limit_avoidance: f64,
    /// Keep the tip's heading θ1 in the second stage of the [`StepMethod::Qp`] update at every
    /// depth (θ1 weighted 1, θ2 `1 − k`) instead of the paper's blend (θ1 weighted `k`, gone
    /// beyond the blend depth) (default true). Deep in the gel the sliding points hold the
    /// shaft, and the direction in which the tip cuts is what steers it: without θ1 the tip
    /// drifts off a curving path and cannot be brought back (the complex scene ended 4.3 mm
    /// from its target with the blend, 0.001 mm with θ1 kept; `docs/benchmark.md`).
    pub qp_heading: bool,
    /// Look-ahead of the heading θ1 once inserted [mm] (default 10; 0: the path's tangent
    /// alone): the tip is asked to point along `L t̂ + e`, the path's tangent `t̂` at the target
    /// plus the tip's error `e` to the target over this distance, so that a tip off the path
    /// cuts back towards it over about `L` of insertion (a pure-pursuit law) instead of running
    /// parallel to it. Deep in the gel the tip goes where it points and the target moves with
    /// the gel, so a sideways error closes by cutting back, not by pushing the shaft. On five
    /// suites of 24–33 scenes (two generated after the value was chosen) the mean e_mean fell
    /// 17–39 % with the same 109 of 129 targets reached (`docs/benchmark.md`).
    pub aim_ahead: f64,
    /// Horizon of the tip's position objective once inserted [mm] (default 0: the error now).
    /// With `S` > 0 the position rows of `T` are the tip's predicted error `S` further along,
    /// `e + S |t| (t̂ − ĥ)`: the target carried along the path's tangent `t̂`, the tip along its
    /// heading `ĥ` (`|t|`, the tangent's quotient over 1 mm, closes the horizon over the path's
    /// last millimetre). Deep in the gel the tip goes where it points, and an error the heading is
    /// already closing is then not corrected a second time by turning the heading away from
    /// the path, which the needle cannot turn back in time (public `needle_thin`: 0.3 mm inside
    /// its bend at step 306, the heading straightened to erase that lead, then 0.19 behind the
    /// path's slope for good). Where the joints still turn the tip freely, the error now tracks
    /// the path more closely (`complex`: 0.094 mm e_mean at `S` = 0, 0.253 mm at 3), so the host
    /// sets `S` from the needle's steering length in the gel (`inverse.qp_horizon = "auto"`: 3 mm
    /// for a steering length up to 18 mm, none from 21 mm; `docs/benchmark.md`). The core's own
    /// default is 0.
    pub qp_horizon: f64,
    /// Re-plan a [`StepMethod::Qp`] step that its confirming solve rejected (default false):
    /// the solve at the rejected joints gives the constrained map's actual change along the
    /// step, which corrects the tip rows of `J` and the clearance gradients by a rank-one
    /// secant (Broyden) update along it; the program is solved again with them, up to
    /// [`super::MAX_REPLANS`] times, before the first stage's step and its halvings are tried.
    /// Where the map is nonsmooth (the shaft sticking in the gel), the forward difference of
    /// `joint_step` can send the step the wrong way; the secant along the rejected step sees
    /// the response the step actually met.
    pub replan_rejected: bool,
    /// When a [`StepMethod::Qp`] step held the joints (its confirming solves rejected the plan,
    /// the first stage's step `Δq₁` and its [`super::MAX_BACKTRACKS`] halvings) and the next
    /// frame comes at the same joints, that step tries the same candidates and then goes on
    /// halving `Δq₁` from where the held one stopped, up to [`super::MAX_HELD_HALVINGS`] times
    /// (default true since 2026-12-07: on the 609 runs of the public suite and 24 generated
    /// sets, the same targets reached, every mean error lower, the public `place_ahead` no longer
    /// stalled at its obstacle; on an older controller it had spent a held-out scene's obstacle
    /// margin, `docs/benchmark.md`). A frame at held joints is the
    /// one the hold was decided on (the gel at rest, the target a step further), so the same
    /// candidates are rejected again: on `helix_half` for 96 steps in a row, while 1/16 of `Δq₁`
    /// would have passed (`docs/benchmark.md`). Every candidate passes the same confirmation
    /// (sufficient decrease, clearances); a step that the usual candidates confirm is unchanged.
    pub resume_held: bool,
    /// When the confirming solve rejects a [`StepMethod::Qp`] step planned with the hybrid or
    /// solved Jacobian, plan once more with the linearised one ([`JacobianMode::Linearized`]:
    /// the exact one-sided derivative of the constraint solution with the base solve's contact,
    /// stick and slip statuses frozen, from one factor of its active set) and confirm that
    /// candidate too, before the first stage's step and its halvings (default false). Where the
    /// shaft sticks, the finite-difference slope over `joint_step` can promise a motion the
    /// step does not get; the frozen active set's slope is the one of a small step.
    pub second_opinion: bool,
    /// Largest damping `ε` of the second stage of the [`StepMethod::Qp`] update (the angles)
    /// [mm/rad] (default 5): that stage is damped by the step's `ε`, raised towards
    /// `damping_max` while `J` is near singular, but by at most this (and never less than
    /// `damping`). Once the needle is in the gel, `J`'s smallest singular value is below
    /// `singular_threshold` at nearly every step of every suite scene (the gel holds the shaft
    /// sideways), so the raise meant for the tip's weak directions also damped the heading that
    /// steers the tip: with the angles' stage capped at 5 mm/rad, 170 instead of 169 of 201
    /// suite runs reach their target, the mean final error falls by a third and the smallest
    /// clearance rises from 0.064 to 0.179 mm (`docs/benchmark.md`). A value above
    /// `√(damping² + damping_max²)` (21 with the defaults) gives the first stage's `ε` (the
    /// update before 2026-12-02); `damping` or less, `damping` alone.
    pub qp_angle_damping_max: f64,
    /// Widen the obstacle margin of a [`StepMethod::Qp`] step by what the model missed of late
    /// (default true): after each step the smallest clearance its final solve predicted is
    /// kept, and the next frame's smallest clearance is compared with it; the shortfall (the
    /// gel settling, the needle ringing at held joints: motion the frame's linear model does
    /// not see) is added to `clearance_margin`, in the QP's rows and in the confirmation, and
    /// decays by [`super::SETTLING_DECAY`] per step. On the suites it raised the smallest
    /// clearance (249 runs: 0.090 → 0.185 mm) with the same targets reached
    /// (`docs/benchmark.md`).
    pub settling_margin: bool,
    /// Weight `w_s` of the spin of the needle about its own axis in every stage of the
    /// [`StepMethod::Qp`] update [mm/rad] (default 0: off): each stage adds
    /// `w_s² (ẑᵀ J_ω Δq)²`, `ẑ` the tool's axis (the needle's) and `J_ω` the tool's angular
    /// Jacobian. A round needle's spin about its axis moves neither its tip nor its angles, so
    /// nothing but the damping holds it. Measured with 100 on 585 suite runs: half as many runs
    /// put a joint at a limit (69 → 39) and the public `helix_half` tracks closer (e_mean
    /// 1.61 → 0.91 mm), but 5 targets fewer are reached, so it is left off
    /// (`docs/benchmark.md`, "The needle's spin held").
    pub qp_spin_weight: f64,
}

// SAFETY: `#[repr(u8)]` and the variant `Solve` has the discriminant 0.
unsafe impl crate::zeroed::Zeroable for JacobianMode {}
// SAFETY: `#[repr(u8)]` and the variant `Paper` has the discriminant 0.
unsafe impl crate::zeroed::Zeroable for StepMethod {}

crate::zeroed::impl_zeroable!(InverseParams {
    joint_step,
    blend_depth,
    angle_weight,
    damping,
    damping_max,
    singular_threshold,
    tolerance,
    gs,
    warm_start,
    active_set,
    sensitivity_start,
    presolve_tolerance,
    eliminate_base,
    max_base_step,
    jacobian,
    jacobian_tolerance,
    method,
    clearance_margin,
    qp_angle_weight,
    limit_avoidance,
    qp_heading,
    aim_ahead,
    qp_horizon,
    replan_rejected,
    resume_held,
    second_opinion,
    qp_angle_damping_max,
    settling_margin,
    qp_spin_weight,
});

impl Default for InverseParams {
    fn default() -> Self {
        Self {
            joint_step: 0.01,
            blend_depth: 20.0,
            angle_weight: 100.0,
            damping: 1.0,
            damping_max: 20.0,
            singular_threshold: 5.0,
            tolerance: 1e-6,
            gs: GsParams {
                tolerance: 1e-6,
                max_iterations: 400,
                polish: false,
                relaxation: 1.0,
            },
            warm_start: true,
            active_set: true,
            sensitivity_start: true,
            eliminate_base: true,
            max_base_step: f64::INFINITY,
            jacobian: JacobianMode::Hybrid,
            presolve_tolerance: 1e-5,
            jacobian_tolerance: 1e-5,
            method: StepMethod::Qp,
            clearance_margin: 0.2,
            qp_angle_weight: 10.0,
            limit_avoidance: 0.5,
            qp_heading: true,
            aim_ahead: 10.0,
            qp_horizon: 0.0,
            replan_rejected: false,
            resume_held: true,
            second_opinion: false,
            qp_angle_damping_max: 5.0,
            settling_margin: true,
            qp_spin_weight: 0.0,
        }
    }
}

impl InverseParams {
    /// Checks every value: positive `joint_step` and `max_base_step`, finite non-negative
    /// weights, dampings and tolerances.
    ///
    /// # Errors
    /// [`StepError::InvalidParameter`] naming the first bad value.
    ///
    /// # Example
    /// ```
    /// use needle_core::{InverseParams, StepError};
    ///
    /// assert_eq!(InverseParams::default().validate(), Ok(()));
    /// let p = InverseParams { joint_step: 0.0, ..InverseParams::default() };
    /// assert_eq!(p.validate(), Err(StepError::InvalidParameter { name: "joint_step" }));
    /// ```
    pub fn validate(&self) -> Result<(), StepError> {
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let nonneg = |x: f64| x.is_finite() && x >= 0.0;
        let checks = [
            (pos(self.joint_step), "joint_step"),
            (nonneg(self.blend_depth), "blend_depth"),
            (nonneg(self.angle_weight), "angle_weight"),
            (nonneg(self.damping), "damping"),
            (nonneg(self.damping_max), "damping_max"),
            (nonneg(self.singular_threshold), "singular_threshold"),
            (nonneg(self.tolerance), "tolerance"),
            (nonneg(self.presolve_tolerance), "presolve_tolerance"),
            (nonneg(self.jacobian_tolerance), "jacobian_tolerance"),
            (self.max_base_step > 0.0, "max_base_step"),
            (nonneg(self.clearance_margin), "clearance_margin"),
            (nonneg(self.qp_angle_weight), "qp_angle_weight"),
            (nonneg(self.limit_avoidance), "limit_avoidance"),
            (nonneg(self.aim_ahead), "aim_ahead"),
            (nonneg(self.qp_horizon), "qp_horizon"),
            (nonneg(self.qp_angle_damping_max), "qp_angle_damping_max"),
            (nonneg(self.qp_spin_weight), "qp_spin_weight"),
        ];
        for (ok, name) in checks {
            if !ok {
                return Err(StepError::InvalidParameter { name });
            }
        }
        Ok(())
    }
}
